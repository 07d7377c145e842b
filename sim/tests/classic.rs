//! The PlayStation pads end to end: the firmware's Classic host (`classic-host`, in
//! `base_runtime::classic`) and its BLE host share one HCI transport (H4 over TCP)
//! through the HCI splitter, to Google Bumble's virtual controllers, where a virtual
//! DualShock 4 or DualSense (sim/ble-peer/classic_pads.py) streams its reports over
//! Bluetooth Classic. The pad drives the virtual robot.
//!
//! As the BLE scenarios: each starts its own peer, one at a time on the wall clock;
//! without Bumble they are skipped with a message, except in CI (CI=true).

#[path = "ble/peer.rs"]
mod peer;

use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use base_core::can::{Command, Mode, Status};
use base_core::registers::{OPEN_PAIRING_WINDOW_KEY, Reg};
use embassy_time::Timer;
use peer::Peer;
use virtual_robot::ble::{BOND_FLASH_SIZE, RemoteRobot};
use virtual_robot::robot::Pc;

/// The pads' public addresses (Sony's prefix).
const PAD_ADDRESS: &str = "A4:AE:12:00:00:01";
const STRANGER_ADDRESS: &str = "A4:AE:12:00:00:02";
/// A BLE pad's random static address.
const BLE_PAD_ADDRESS: &str = "C1:11:22:33:44:55";

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn scenario() -> Option<MutexGuard<'static, ()>> {
    let guard = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    peer::bumble_available().then_some(guard)
}

fn write_register(pc: &Pc, reg: Reg, value: u16) {
    pc.command(Command::RegisterWrite {
        address: reg as u8,
        value,
    });
}

async fn status(pc: &Pc, timeout_ms: u64, what: &str, check: impl Fn(&Status) -> bool) -> Status {
    match pc.wait_for_status(timeout_ms, check).await {
        Some(status) => status,
        None => panic!(
            "within {timeout_ms} ms: {what}; last status {:?}",
            pc.status()
        ),
    }
}

async fn drives_ready(pc: &Pc) {
    status(pc, 5_000, "the drives are set up", |s| {
        s.mode != Mode::Starting
    })
    .await;
}

async fn open_pairing_window(pc: &Pc) {
    // Flash (the bond too) waits until the drives confirmed their brakes.
    drives_ready(pc).await;
    write_register(pc, Reg::Command, OPEN_PAIRING_WINDOW_KEY);
}

/// Creates PlayStation pad `name` of `kind` (ds4, dualsense), puts it in pairing mode,
/// opens the pairing window and waits until it is paired, streaming full reports and
/// counted as connected. Returns how long the pairing took from the window's opening.
async fn pair(peer: &mut Peer, pc: &Pc, name: &str, kind: &str, address: &str) -> Duration {
    peer.cmd(&format!("ps {name} {kind} {address}")).await;
    let mark = peer.mark();
    peer.cmd(&format!("pairing {name}")).await;
    drives_ready(pc).await;
    let opened = Instant::now();
    open_pairing_window(pc).await;
    peer.wait_for(mark, &["paired", name], 20_000).await;
    peer.wait_for(mark, &["feature-read", name, "0x05"], 10_000)
        .await;
    status(pc, 5_000, "the paired pad is connected", |s| {
        s.flags.remote_bonded && s.flags.remote_connected
    })
    .await;
    opened.elapsed()
}

/// Holds the dead-man (R1) and waits until the controller hands control to the remote.
async fn take_control(peer: &mut Peer, pc: &Pc, name: &str) {
    drives_ready(pc).await;
    peer.cmd(&format!("release {name} R1")).await;
    Timer::after_millis(50).await;
    peer.cmd(&format!("press {name} R1")).await;
    status(pc, 2_000, "the dead-man gives the remote control", |s| {
        s.flags.remote_in_control
    })
    .await;
}

/// Waits until both wheels turn forward (or, `forward == false`, stand still).
async fn wheels(robot: &RemoteRobot, timeout_ms: u64, forward: bool) {
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

/// Pulls the left stick forward with the dead-man held: the robot drives.
async fn drive_forward(peer: &mut Peer, robot: &RemoteRobot, pc: &Pc, name: &str) {
    take_control(peer, pc, name).await;
    peer.cmd(&format!("stick {name} LY 1.0")).await;
    wheels(robot, 3_000, true).await;
}

/// When the drives were last told to stand still (zero speed on the wire), waiting
/// up to `timeout_ms` for it.
async fn zero_on_the_wire(robot: &RemoteRobot, timeout_ms: u64) -> Instant {
    let deadline = Instant::now() + Duration::from_millis(timeout_ms);
    loop {
        let commanded = robot.robot.drives.drive(1).command;
        if commanded.is_some_and(|command| command.speed_rpm == 0) {
            return Instant::now();
        }
        assert!(
            Instant::now() < deadline,
            "no zero speed on the wire within {timeout_ms} ms: {commanded:?}"
        );
        Timer::after_millis(1).await;
    }
}

/// The deceleration of the drives' last command, (1/min)/s.
fn last_decel(robot: &RemoteRobot) -> i32 {
    robot
        .robot
        .drives
        .drive(1)
        .command
        .expect("the left drive was commanded")
        .decel_rpm_per_s
}

/// A value of `Contr_acc_high` no other rule uses, to recognise its braking.
const RELEASE_BRAKING: u16 = 2777;

/// Whether the bond partition holds the pad's address as the Classic bond record
/// stores it (least significant byte first).
fn bond_stored_for(robot: &RemoteRobot, address: &str) -> bool {
    let mut raw: Vec<u8> = address
        .split(':')
        .map(|pair| u8::from_str_radix(pair, 16).expect("hex address"))
        .collect();
    raw.reverse();
    let flash = robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32);
    flash.windows(raw.len()).any(|window| window == raw)
}

#[test]
fn a_dualshock4_pairs_in_the_window_drives_with_r1_held_and_release_stops() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        let before = status(pc, 5_000, "the controller is up", |_| true).await;
        assert!(!before.flags.remote_bonded, "no bond on a blank flash");
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        let took = pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        eprintln!("classic pairing (window opened to connected): {took:?}");
        drive_forward(&mut peer, &robot, pc, "pad").await;
        peer.cmd("release pad R1").await;
        wheels(&robot, 3_000, false).await;
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
        status(
            pc,
            2_000,
            "releasing the dead-man ends remote control",
            |s| !s.flags.remote_in_control,
        )
        .await;
    });
    assert!(
        bond_stored_for(&robot, PAD_ADDRESS),
        "the link key is in the bonds partition"
    );
}
