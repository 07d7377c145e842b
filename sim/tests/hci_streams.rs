//! Random HCI streams from a peer through the guard into the real BLE host: the
//! firmware's remote task (`base_runtime::ble::run`, trouble-host behind the guard) on
//! a scripted controller in memory (`virtual_robot::fake_hci`), on the virtual clock.
//!
//! The pairing window is open, so the task scans, finds the fake's gamepad, connects
//! and starts pairing; on every link the fake then delivers a burst of seeded random
//! packets: ACL packets (mostly well-framed L2CAP on the ATT, signalling and SMP
//! channels with random contents and lengths, some fragmented, some malformed) and
//! events. The test passes if nothing panics (a panic in the host ends it) and the
//! links kept coming. A fixed seed and a fixed number of links keep it deterministic
//! and short; the fuzz target (fuzz/fuzz_targets/hci_stream.rs) explores further.

use base_core::can::Command;
use base_core::registers::{OPEN_PAIRING_WINDOW_KEY, Reg};
use embassy_time::{Duration, Instant, Timer};
use virtual_robot::ble::RemoteRobot;
use virtual_robot::fake_hci::{FakeHandle, fake_controller};

/// Links, each with one burst of random packets.
const LINKS: u32 = 1_000;
const PACKETS_PER_LINK: usize = 24;
const SEED: u64 = 0x5EED_B1E0_0A11_0025;

/// xorshift64*: a few lines instead of a crate, and the same stream everywhere.
struct Random(u64);

impl Random {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn byte(&mut self) -> u8 {
        self.next() as u8
    }

    fn bytes(&mut self, len: usize) -> Vec<u8> {
        (0..len).map(|_| self.byte()).collect()
    }

    fn bytes_up_to(&mut self, max: usize) -> Vec<u8> {
        let len = self.below(max);
        self.bytes(len)
    }

    fn pick<T: Copy>(&mut self, from: &[T]) -> T {
        from[self.below(from.len())]
    }
}

const ATT_OPCODES: [u8; 28] = [
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x10,
    0x11, 0x12, 0x13, 0x16, 0x17, 0x18, 0x19, 0x1B, 0x1D, 0x1E, 0x52, 0xD2,
];
const SIGNALLING_CODES: [u8; 10] = [0x01, 0x06, 0x07, 0x12, 0x13, 0x14, 0x15, 0x16, 0x0A, 0x20];

/// One L2CAP payload on a channel the host listens to, or on another.
fn l2cap_pdu(random: &mut Random) -> (u16, Vec<u8>) {
    match random.below(10) {
        0..=4 => {
            let mut pdu = vec![random.pick(&ATT_OPCODES)];
            let len = random.below(24);
            pdu.extend(random.bytes(len));
            (4, pdu)
        }
        5 | 6 => {
            let code = random.pick(&SIGNALLING_CODES);
            let any = random.below(16);
            let data_len = random.pick(&[0, 2, 4, 6, 8, 10, any]);
            // Mostly a matching length field, now and then not.
            let field = if random.below(4) == 0 {
                random.below(16)
            } else {
                data_len
            };
            let mut pdu = vec![code, random.byte()];
            pdu.extend_from_slice(&(field as u16).to_le_bytes());
            let mut data = random.bytes(data_len);
            if data_len >= 4 && random.below(2) == 0 {
                // A channel ID that might be real: 0x0040.., or 0.
                data[0] = random.pick(&[0x00, 0x40, 0x41]);
                data[1] = 0;
            }
            pdu.extend(data);
            (5, pdu)
        }
        7 | 8 => {
            let code = 1 + random.below(0x0F) as u8;
            let any = random.below(20);
            let len = random.pick(&[1, 2, 7, 11, 17, 65, any]);
            let mut pdu = random.bytes(len.max(1));
            pdu[0] = code;
            (6, pdu)
        }
        _ => (random.below(0x50) as u16, random.bytes_up_to(12)),
    }
}

/// One or two ACL packets (H4) carrying an L2CAP PDU, the handle left to the fake.
fn acl_packets(random: &mut Random) -> Vec<Vec<u8>> {
    let (channel, payload) = l2cap_pdu(random);
    let length = if random.below(12) == 0 {
        random.below(40)
    } else {
        payload.len()
    };
    let mut l2cap = Vec::new();
    l2cap.extend_from_slice(&(length as u16).to_le_bytes());
    l2cap.extend_from_slice(&channel.to_le_bytes());
    l2cap.extend(payload);
    let boundary = if random.below(16) == 0 {
        random.pick(&[0b00, 0b01, 0b11])
    } else {
        0b10
    };
    let acl = |flags: u8, data: &[u8]| {
        let mut packet = vec![0x02, 0x00, flags << 4];
        packet.extend_from_slice(&(data.len() as u16).to_le_bytes());
        packet.extend_from_slice(data);
        packet
    };
    // A controller with 27-byte buffers splits longer PDUs; so do we, sometimes anyway.
    if l2cap.len() > 27 || (l2cap.len() > 5 && random.below(8) == 0) {
        let split = if l2cap.len() > 27 {
            27
        } else {
            1 + random.below(l2cap.len() - 1)
        };
        vec![acl(boundary, &l2cap[..split]), acl(0b01, &l2cap[split..])]
    } else {
        vec![acl(boundary, &l2cap)]
    }
}

/// An event a controller could send about a peer's link: disconnection, encryption,
/// parameter and data length updates, remote features, in shapes good and bad, and
/// any other event code.
fn event(random: &mut Random) -> Vec<u8> {
    let (code, mut params) = match random.below(6) {
        0 => (
            0x08,
            vec![random.pick(&[0, 6]), 0x41, 0x00, random.below(2) as u8],
        ),
        1 => (0x30, vec![0, 0x41, 0x00]),
        2 => (0x3E, {
            let sub = random.pick(&[0x03, 0x04, 0x06, 0x07, 0x0C, 0x14, 0x02]);
            let mut params = vec![sub, 0, 0x41, 0x00];
            let len = random.below(12);
            params.extend(random.bytes(len));
            params
        }),
        3 => (0x13, vec![1, 0x41, 0x00, random.byte(), 0]),
        4 => (0x57, random.bytes_up_to(6)),
        // Any other code but Command Complete and Command Status: those answer our own
        // commands and are taken by bt-hci's controller below the guard (a malformed
        // one is a controller fault, and stops the host).
        _ => (
            match random.byte() {
                0x0E | 0x0F => 0xFF,
                code => code,
            },
            random.bytes_up_to(10),
        ),
    };
    params.truncate(255);
    let mut packet = vec![0x04, code, params.len() as u8];
    packet.extend(params);
    packet
}

fn burst(random: &mut Random) -> Vec<Vec<u8>> {
    (0..PACKETS_PER_LINK)
        .flat_map(|_| {
            if random.below(8) == 0 {
                vec![event(random)]
            } else {
                acl_packets(random)
            }
        })
        .collect()
}

fn hex(packets: &[Vec<u8>]) -> String {
    let lines: Vec<String> = packets
        .iter()
        .map(|packet| packet.iter().map(|b| format!("{b:02x}")).collect())
        .collect();
    lines.join(" | ")
}

async fn open_pairing_window(pc: &virtual_robot::robot::Pc) {
    pc.command(Command::RegisterWrite {
        address: Reg::Command as u8,
        value: OPEN_PAIRING_WINDOW_KEY,
    });
}

/// Delivers a burst on each new link and ends the link if it is still up; returns once
/// `LINKS` links were made.
async fn bursts(fake: &FakeHandle, pc: &virtual_robot::robot::Pc, random: &mut Random) {
    let mut window_opened = Instant::now();
    open_pairing_window(pc).await;
    let mut last_burst = Vec::new();
    for link in 0..LINKS {
        let packets = burst(random);
        fake.script(packets.clone());
        let started = Instant::now();
        while fake.stats().connections <= link || !fake.script_done() {
            // The host stopped (its runner ended): this burst or the one before did it.
            assert!(
                started.elapsed() < Duration::from_secs(120),
                "no link {link} within 120 s: {:?}; the burst before: {}; this one: {}",
                fake.stats(),
                hex(&last_burst),
                hex(&packets)
            );
            // The window lasts 60 s; keep it open.
            if window_opened.elapsed() > Duration::from_secs(50) {
                open_pairing_window(pc).await;
                window_opened = Instant::now();
            }
            Timer::after_millis(20).await;
        }
        last_burst = packets;
        // Let the host digest the burst, then the peer goes.
        Timer::after_millis(200).await;
        fake.peer_disconnects();
    }
}

#[test]
fn random_packets_from_a_peer_never_panic_the_host_behind_the_guard() {
    let robot = RemoteRobot::new();
    let (controller, fake) = fake_controller();
    let mut random = Random(SEED);
    robot.run_virtual(controller, async |pc| {
        pc.wait_for_status(5_000, |_| true)
            .await
            .expect("the controller is up");
        bursts(&fake, pc, &mut random).await;
    });
    let stats = fake.stats();
    eprintln!("random streams: {stats:?}");
    assert!(stats.connections >= LINKS);
    assert!(stats.packets_delivered as usize >= LINKS as usize * PACKETS_PER_LINK);
}
