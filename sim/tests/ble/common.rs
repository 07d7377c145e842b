//! What the BLE and the Classic pad scenarios share: one scenario at a time, the PC's
//! register writes and status waits, the pairing window, the wheels, the bond flash.

use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use base_core::can::{Command, Mode, Status};
use base_core::registers::{OPEN_PAIRING_WINDOW_KEY, Reg};
use embassy_time::Timer;
use virtual_robot::ble::{BOND_FLASH_SIZE, RemoteRobot};
use virtual_robot::robot::Pc;

use crate::peer;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// The scenario lock, or `None` (skip) when Bumble is missing outside CI.
pub fn scenario() -> Option<MutexGuard<'static, ()>> {
    let guard = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    peer::bumble_available().then_some(guard)
}

/// Writes a register as the robot PC does.
pub fn write_register(pc: &Pc, reg: Reg, value: u16) {
    pc.command(Command::RegisterWrite {
        address: reg as u8,
        value,
    });
}

/// The first status frame within `timeout_ms` that passes `check`; fails the test with
/// `what` and the last status otherwise.
pub async fn status(
    pc: &Pc,
    timeout_ms: u64,
    what: &str,
    check: impl Fn(&Status) -> bool,
) -> Status {
    match pc.wait_for_status(timeout_ms, check).await {
        Some(status) => status,
        None => panic!(
            "within {timeout_ms} ms: {what}; last status {:?}",
            pc.status()
        ),
    }
}

pub async fn drives_ready(pc: &Pc) {
    status(pc, 5_000, "the drives are set up", |s| {
        s.mode != Mode::Starting
    })
    .await;
}

pub async fn open_pairing_window(pc: &Pc) {
    // Flash (the bond too) waits until the drives confirmed their brakes.
    drives_ready(pc).await;
    write_register(pc, Reg::Command, OPEN_PAIRING_WINDOW_KEY);
}

/// Waits until both wheels turn forward (or, `forward == false`, stand still).
pub async fn wheels(robot: &RemoteRobot, timeout_ms: u64, forward: bool) {
    let deadline = Instant::now() + Duration::from_millis(timeout_ms);
    loop {
        let left = robot.robot.drives.drive(1).forward_rpm();
        let right = robot.robot.drives.drive(2).forward_rpm();
        let done = if forward {
            left > 10.0 && right > 10.0
        } else {
            left.abs() < 0.5 && right.abs() < 0.5
        };
        if done {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "wheels not {} within {timeout_ms} ms: {left:.1} / {right:.1} rpm",
            if forward {
                "turning forward"
            } else {
                "stopped"
            }
        );
        Timer::after_millis(5).await;
    }
}

/// Whether the bond partition holds the pad's address as the Classic bond record
/// stores it (least significant byte first).
pub fn bond_stored_for(robot: &RemoteRobot, address: &str) -> bool {
    let mut raw: Vec<u8> = address
        .split(':')
        .map(|pair| u8::from_str_radix(pair, 16).expect("hex address"))
        .collect();
    raw.reverse();
    let flash = robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32);
    flash.windows(raw.len()).any(|window| window == raw)
}

/// The deceleration of the drives' last command, (1/min)/s.
pub fn last_decel(robot: &RemoteRobot) -> i32 {
    robot
        .robot
        .drives
        .drive(1)
        .command
        .expect("the left drive was commanded")
        .decel_rpm_per_s
}
