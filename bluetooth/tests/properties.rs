//! The fuzz targets' properties (fuzz/fuzz_targets/classic_*.rs), run by `cargo test`
//! on random inputs: any packet stream into the host, any bytes into the decoders.

use base_bluetooth::hci::{BdAddr, Command, Event as HciEvent, LinkKey};
use base_bluetooth::l2cap::{self, Signal};
use base_bluetooth::{Bond, ClassicHost, Event, Packet, Params};
use base_core::time::Timestamp;
use proptest::prelude::*;

const PAD: BdAddr = BdAddr([0x55, 0x44, 0x33, 0x22, 0x11, 0xC0]);

/// A well-formed event the host acts on, for the pad or a stranger, succeeding or not.
fn event(kind: u8, pad: bool, status: u8, flag: bool) -> Vec<u8> {
    let addr = if pad { PAD.0 } else { [1, 2, 3, 4, 5, 6] };
    let handle = [0x42, 0x00];
    let with_addr = |rest: &[u8]| [&addr[..], rest].concat();
    let (code, params): (u8, Vec<u8>) = match kind % 16 {
        0 => (0x04, with_addr(&[0x08, 0x25, 0x00, 0x01])),
        1 => (
            0x03,
            [&[status][..], &handle, &addr, &[0x01, 0x00]].concat(),
        ),
        2 => (0x12, [&[status][..], &addr, &[u8::from(!flag)]].concat()),
        3 => (0x17, addr.to_vec()),
        4 => (0x31, addr.to_vec()),
        5 => (0x33, with_addr(&[0, 0, 0, 0])),
        6 => (0x16, addr.to_vec()),
        7 => (0x18, with_addr(&[0xA5; 17])),
        8 => (0x06, [&[status][..], &handle].concat()),
        9 => (0x08, [&[status][..], &handle, &[u8::from(flag)]].concat()),
        10 => (0x05, [&[status][..], &handle, &[0x08]].concat()),
        11 => {
            let class: &[u8] = if flag {
                &[0x08, 0x25, 0x00]
            } else {
                &[0x0C, 0x02, 0x5A]
            };
            (
                0x02,
                [&[1][..], &addr, &[1, 0, 0], class, &[0x34, 0x12]].concat(),
            )
        }
        12 => (0x01, vec![status]),
        13 => (0x0F, vec![status, 1, kind, 0x04]),
        14 => (0x13, [&[1][..], &handle, &[2, 0]].concat()),
        _ => (0x10, vec![status]),
    };
    [&[code, params.len() as u8][..], &params].concat()
}

/// Mostly well-formed events (to get deep into the state machine), some raw bytes,
/// some ACL packets on the link's handle.
fn packet() -> impl Strategy<Value = (bool, Vec<u8>)> {
    let well_formed = (
        any::<u8>(),
        any::<bool>(),
        prop_oneof![3 => Just(0u8), 1 => any::<u8>()],
        any::<bool>(),
    )
        .prop_map(|(kind, pad, status, flag)| (false, event(kind, pad, status, flag)));
    let raw = prop::collection::vec(any::<u8>(), 0..24).prop_map(|raw| (false, raw));
    let acl = prop::collection::vec(any::<u8>(), 0..40).prop_map(|payload| {
        let mut packet = vec![0x42, 0x20];
        packet.extend((payload.len() as u16).to_le_bytes());
        packet.extend(payload);
        (true, packet)
    });
    prop_oneof![8 => well_formed, 1 => raw, 1 => acl]
}

/// A host whose controller answered its setup (Reset … Write Scan Enable), so that
/// the random stream meets page scan, not a host still starting.
fn ready(params: &Params) -> ClassicHost {
    let mut host = ClassicHost::new();
    host.step(Timestamp::BOOT, Event::Tick, params);
    let setup: [(u16, &[u8]); 8] = [
        (0x0C03, &[0]),
        (0x1005, &[0, 0xFD, 0x00, 0x00, 0x08, 0x00, 0x00, 0x00]),
        (0x0C01, &[0]),
        (0x0C56, &[0]),
        (0x0C24, &[0]),
        (0x0C18, &[0]),
        (0x080F, &[0]),
        (0x0C1A, &[0]),
    ];
    for (opcode, answer) in setup {
        let mut complete = vec![0x0E, 3 + answer.len() as u8, 1];
        complete.extend(opcode.to_le_bytes());
        complete.extend(answer);
        host.step(Timestamp::BOOT, Event::Hci(&complete), params);
    }
    host
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    #[test]
    fn any_packet_stream_is_survived_and_never_pairs_outside_the_window(
        window in any::<bool>(),
        stream in prop::collection::vec((packet(), 0u64..3_000), 0..60),
    ) {
        let params = Params {
            bond: Some(Bond { addr: PAD, key: LinkKey([7; 16]) }),
            pairing_window_open: window,
            supervision_timeout_slots: 160,
        };
        let pairing = [
            Command::IoCapabilityRequestReply(PAD).opcode(),
            Command::UserConfirmationRequestReply(PAD).opcode(),
        ];
        let mut host = ready(&params);
        let mut now = 0;
        for ((is_acl, bytes), pause) in stream {
            now += pause;
            let event = if is_acl { Event::Acl(&bytes) } else { Event::Hci(&bytes) };
            let mut packets = host.step(Timestamp::from_millis(now), event, &params).packets;
            // The controller answers each command with a Command Status, as a real one
            // does, so that queued commands go out and are checked too.
            while let Some(packet) = packets.pop() {
                if let Packet::Command(command) = packet {
                    let opcode = u16::from_le_bytes([command[0], command[1]]);
                    prop_assert!(window || !pairing.contains(&opcode), "pairing outside the window");
                    let [o0, o1] = opcode.to_le_bytes();
                    let status = [0x0F, 4, 0, 1, o0, o1];
                    let answer = host.step(Timestamp::from_millis(now), Event::Hci(&status), &params);
                    packets.extend(answer.packets);
                }
            }
            let _ = HciEvent::decode(&bytes);
        }
    }

    #[test]
    fn signalling_that_decodes_encodes_back_to_itself(
        frame in prop::collection::vec(any::<u8>(), 0..40),
    ) {
        for command in l2cap::commands(&frame).flatten() {
            let encoded = l2cap::encode(&command);
            let decoded = l2cap::commands(&encoded).next().unwrap().unwrap();
            prop_assert_eq!(decoded.identifier, command.identifier);
            match (command.signal, decoded.signal) {
                (
                    Signal::ConfigurationRequest { options: a, .. },
                    Signal::ConfigurationRequest { options: b, .. },
                )
                | (
                    Signal::ConfigurationResponse { options: a, .. },
                    Signal::ConfigurationResponse { options: b, .. },
                ) => {
                    prop_assert_eq!(a.mtu, b.mtu);
                    prop_assert_eq!(a.unknown, b.unknown);
                }
                (sent, back) => prop_assert_eq!(sent, back),
            }
        }
    }
}
