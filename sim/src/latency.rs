//! The command path's latencies on the virtual robot, measured at many phases of the
//! 50 ms control cycle: the figures example prints them (docs/figures.md) and
//! `sim/tests/command_rate.rs` holds them to their goals. Virtual time: the bytes on
//! the RS-485 line at its baud rate, the CAN frames at 500 kbit/s; the firmware
//! computes in no time.
//!
//! Each measurement ends when both drives have taken the new speed (the moment the
//! virtual drive applied the write that changed it).

use std::cell::Cell;

use base_core::gamepad::{Buttons, GamepadState};
use base_core::remote::Pad;
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Timer};

use crate::robot::{Pc, ScriptedPads, VirtualRobot, wait_ms};

/// Events at phases 0.1 ms apart over a 50 ms cycle: fine enough to catch one just
/// after a transaction's first byte, the worst case.
pub const PHASES: u64 = 500;
/// The virtual pad streams its state this often, as a DualShock 4 does over
/// Bluetooth Classic (a BLE pad reports on change instead, within its connection
/// interval of 7.5 to 15 ms).
pub const PAD_REPORT_INTERVAL_MS: u64 = 4;
/// Until the drives are set up and the sensors have a first reading.
const BOOT_MS: u64 = 1_500;

/// The latest moment both drives took a new speed.
fn applied(robot: &VirtualRobot) -> Instant {
    [1, 2]
        .map(|slave| {
            robot
                .drives
                .drive(slave)
                .last_new_speed_at
                .expect("a speed")
        })
        .into_iter()
        .max()
        .expect("two drives")
}

/// CAN velocity frame → both drives have the new speed (the base drives at 300 and
/// 400 mm/s in turn), and e-stop edge → zero speed on the wire: one sample per phase.
pub fn can_latencies(robot: &VirtualRobot) -> (Vec<Duration>, Vec<Duration>) {
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 500).await;
        let mut velocity = Vec::new();
        for phase in 0..PHASES {
            pc.enable();
            let sent = Instant::now();
            pc.velocity(if phase % 2 == 0 { 400 } else { 300 }, 0);
            // A cycle and 0.1 ms: the next command lands at a new phase of the drive
            // link's own 50 ms cycle, sometimes while a transaction is on the wire.
            Timer::after(Duration::from_micros(50_100)).await;
            velocity.push(applied(robot) - sent);
        }
        let mut estop = Vec::new();
        for phase in 0..PHASES {
            pc.drive(300, 0, 300).await;
            Timer::after(Duration::from_micros(phase * 100)).await;
            let pressed = Instant::now();
            robot.press_estop();
            wait_ms(60).await;
            estop.push(applied(robot) - pressed);
            robot.release_estop();
            wait_ms(100).await;
            robot.press_button(200).await;
            wait_ms(800).await;
        }
        (velocity, estop)
    })
}

/// The pad's path, as the CAN command's: pad report → both drives have the new speed
/// (the dead-man held, the stick between half and 0.7 forward in turn), and dead-man
/// release → zero speed on the wire. The virtual pad streams its state every
/// [`PAD_REPORT_INTERVAL_MS`]; each sample starts with the report that carries the
/// change, handed to the controller where the remote tasks hand theirs (the radio and
/// the decoding come before that). One sample per phase.
pub fn pad_latencies(robot: &VirtualRobot) -> (Vec<Duration>, Vec<Duration>) {
    let stick = |forward: f32, dead_man: bool| GamepadState {
        left_y: forward,
        buttons: if dead_man {
            Buttons::RIGHT_BUMPER
        } else {
            Buttons::NONE
        },
        ..GamepadState::default()
    };
    robot.run_with_pads(async |_pc: &Pc, pads: &ScriptedPads<'_>| {
        wait_ms(BOOT_MS).await;
        let state = Cell::new(stick(0.0, false));
        let pad = Pad::Classic;
        pads.link(pad, true).await;
        // The pad streams whatever it holds; the trials change what it holds and send
        // the changed report at once, as its next report carries it.
        let stream = async {
            loop {
                pads.report(pad, state.get()).await;
                wait_ms(PAD_REPORT_INTERVAL_MS).await;
            }
        };
        let change = async |to: GamepadState| -> Instant {
            state.set(to);
            let sent = Instant::now();
            pads.report(pad, to).await;
            sent
        };
        let trials = async {
            wait_ms(100).await;
            change(stick(0.5, true)).await;
            wait_ms(500).await;
            let mut report = Vec::new();
            for phase in 0..PHASES {
                let sent = change(stick(if phase % 2 == 0 { 0.7 } else { 0.5 }, true)).await;
                Timer::after(Duration::from_micros(50_100)).await;
                report.push(applied(robot) - sent);
            }
            let mut release = Vec::new();
            for phase in 0..PHASES {
                change(stick(0.5, true)).await;
                wait_ms(300).await;
                Timer::after(Duration::from_micros(phase * 100)).await;
                let let_go = change(stick(0.5, false)).await;
                wait_ms(60).await;
                release.push(applied(robot) - let_go);
                wait_ms(500).await;
            }
            (report, release)
        };
        match select(stream, trials).await {
            Either::First(never) => never,
            Either::Second(samples) => samples,
        }
    })
}
