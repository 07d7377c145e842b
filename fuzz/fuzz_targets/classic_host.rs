//! Any bytes as a stream of HCI events and ACL packets into the Classic host, with
//! the pairing window open or closed: no panic, and no pairing (IO capability or
//! confirmation reply) while the window is closed.
//! Each input is split into packets by a length byte; its top bit picks ACL or HCI,
//! the next marks a tick of 1 s before the packet.
#![no_main]

use base_bluetooth::hci::{BdAddr, Command, Event as HciEvent, LinkKey};
use base_bluetooth::{Bond, ClassicHost, Event, Packet, Params};
use base_core::time::Timestamp;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let Some((&flags, mut rest)) = input.split_first() else {
        return;
    };
    let params = Params {
        bond: Some(Bond {
            addr: BdAddr([1, 2, 3, 4, 5, 6]),
            key: LinkKey([7; 16]),
        }),
        pairing_window_open: flags & 1 != 0,
        supervision_timeout_slots: 160,
    };
    let forbidden = [
        Command::IoCapabilityRequestReply(BdAddr([0; 6])).opcode(),
        Command::UserConfirmationRequestReply(BdAddr([0; 6])).opcode(),
    ];
    let mut host = ClassicHost::new();
    let mut now = 0;
    while let Some((&header, tail)) = rest.split_first() {
        let len = usize::from(header & 0x3F).min(tail.len());
        let (packet, tail) = tail.split_at(len);
        rest = tail;
        if header & 0x40 != 0 {
            now += 1_000;
        }
        let event = if header & 0x80 != 0 {
            Event::Acl(packet)
        } else {
            Event::Hci(packet)
        };
        let mut packets = host
            .step(Timestamp::from_millis(now), event, &params)
            .packets;
        // The controller answers each command with a Command Status, as a real one
        // does, so that queued commands go out and are checked too.
        while let Some(packet) = packets.pop() {
            if let Packet::Command(bytes) = packet {
                let opcode = u16::from_le_bytes([bytes[0], bytes[1]]);
                assert!(params.pairing_window_open || !forbidden.contains(&opcode));
                let [o0, o1] = opcode.to_le_bytes();
                let status = [0x0F, 4, 0, 1, o0, o1];
                let answer = host.step(Timestamp::from_millis(now), Event::Hci(&status), &params);
                packets.extend(answer.packets);
            }
        }
        let _ = HciEvent::decode(packet);
    }
});
