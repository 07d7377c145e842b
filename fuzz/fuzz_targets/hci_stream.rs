//! Any bytes as the packets a peer's link brings, through the guard into the real BLE
//! host: the firmware's remote task (trouble-host behind `base_bluetooth::guard`) on the
//! simulator's scripted controller (`virtual_robot::fake_hci`), on the virtual clock.
//! The pairing window is open; once the task has connected the fake's gamepad, the
//! packets arrive. Nothing may panic, and the host must still make the next link (a
//! host that stopped would keep the owner's pad away until reboot).
//!
//! Input: records of `tag, length, bytes`; an even tag is an ACL packet whose first
//! byte gives the boundary flag (low two bits) and the rest its data; an odd tag an
//! event whose first byte is the code, the rest its parameters. Command Complete and
//! Command Status are not a peer's to send (they answer the host's own commands) and
//! become a vendor event.
#![no_main]

use base_core::can::Command;
use base_core::registers::{OPEN_PAIRING_WINDOW_KEY, Reg};
use embassy_time::{Duration, Instant, Timer};
use libfuzzer_sys::fuzz_target;
use virtual_robot::ble::RemoteRobot;
use virtual_robot::fake_hci::fake_controller;

fn packets(mut input: &[u8]) -> Vec<Vec<u8>> {
    let mut packets = Vec::new();
    while let [tag, len, rest @ ..] = input {
        let len = usize::from(*len).min(rest.len());
        let (bytes, next) = rest.split_at(len);
        input = next;
        if tag % 2 == 0 {
            let Some((flags, data)) = bytes.split_first() else {
                continue;
            };
            let mut packet = vec![0x02, 0x00, (flags & 0b11) << 4];
            packet.extend_from_slice(&(data.len() as u16).to_le_bytes());
            packet.extend_from_slice(data);
            packets.push(packet);
        } else {
            let Some((code, params)) = bytes.split_first() else {
                continue;
            };
            let code = if matches!(code, 0x0E | 0x0F) {
                0xFF
            } else {
                *code
            };
            let mut packet = vec![0x04, code, params.len() as u8];
            packet.extend_from_slice(params);
            packets.push(packet);
        }
    }
    packets
}

fuzz_target!(|input: &[u8]| {
    let script = packets(input);
    let robot = RemoteRobot::new();
    let (controller, fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        pc.command(Command::RegisterWrite {
            address: Reg::Command as u8,
            value: OPEN_PAIRING_WINDOW_KEY,
        });
        fake.script(script);
        let started = Instant::now();
        // This link, then the next one: the host still works after the packets.
        while fake.stats().connections < 2 {
            assert!(
                started.elapsed() < Duration::from_secs(60),
                "the host made no new link after the packets: {:?}",
                fake.stats()
            );
            if fake.script_done() && fake.connected() {
                Timer::after_millis(100).await;
                fake.peer_disconnects();
            }
            Timer::after_millis(20).await;
        }
    });
});
