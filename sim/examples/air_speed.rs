//! How fast the virtual robot runs with the air: virtual seconds per wall second while
//! a pad drives the base, against the robot alone. Each line drives for 60 virtual
//! seconds after the pad is paired (not timed):
//!
//! - the robot alone, the PC driving over CAN (no Bluetooth);
//! - the robot with the air and both remote tasks, no pad;
//! - a BLE pad driving (RB held, the stick moving every 50 ms: a notification each);
//! - a DualShock 4 driving, reporting every 4 ms as the real pad, and every 20 ms.
//!
//! Each line gives virtual seconds per second of this thread's CPU time (what one core
//! does, whatever else the machine runs; Linux's `/proc/thread-self/schedstat`) and per
//! wall second (what this run got).
//!
//! `cargo run -p virtual-robot --example air_speed [SECONDS]` (the figures in docs/figures.md
//! come from this). The wall clock only measures here; nothing depends on it.

use base_core::can::{Command, Mode};
use base_core::gamepad::Buttons;
use base_core::registers::{OPEN_PAIRING_WINDOW_KEY, Reg};
use embassy_time::{Duration, Instant, Timer};
use virtual_robot::air::{AirRobot, Pad, PadEvent, PadKind};
use virtual_robot::robot::{Pc, VirtualRobot};

/// How long each line drives (virtual time); `-- SECONDS` changes it.
fn drive_time() -> Duration {
    let seconds = std::env::args()
        .nth(1)
        .and_then(|text| text.parse().ok())
        .unwrap_or(60);
    Duration::from_secs(seconds)
}
const SEED: u64 = 31;

fn main() {
    let drive_for = drive_time();
    println!(
        "virtual s per CPU s / per wall s, {} s of driving each:",
        drive_for.as_secs()
    );
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        ready(pc).await;
        let speed = timed(async {
            pc.drive(300, 0, drive_for.as_millis()).await;
        })
        .await;
        println!("  robot alone, the PC driving over CAN       {speed}");
    });

    let robot = AirRobot::new(SEED);
    robot.run(async |pc| {
        ready(pc).await;
        let speed = timed(async {
            pc.drive(300, 0, drive_for.as_millis()).await;
        })
        .await;
        println!("  with the air and both remotes, no pad      {speed}");
    });

    let robot = AirRobot::new(SEED);
    let pad = robot
        .air
        .ble_pad("xbox", "C1:11:22:33:44:55")
        .expect("a pad");
    pad.advertise(true);
    robot.run(async |pc| {
        pair(&robot, pc, "xbox", PadEvent::Subscribed).await;
        let speed = timed(drive(&pad, drive_for)).await;
        println!("  a BLE pad driving, a change every 50 ms    {speed}");
    });

    for period_ms in [4, 20] {
        let robot = AirRobot::new(SEED);
        let pad = robot
            .air
            .playstation_pad("ds4", PadKind::DualShock4, "A4:AE:12:00:00:01")
            .expect("a pad");
        pad.report_period(Duration::from_millis(period_ms));
        pad.pairing_mode();
        robot.run(async |pc| {
            pair(&robot, pc, "ds4", PadEvent::FeatureRead(0x05)).await;
            let before = robot.air.counters().reports_sent;
            let speed = timed(drive(&pad, drive_for)).await;
            let reports = robot.air.counters().reports_sent - before;
            println!(
                "  a DualShock 4 driving, reports every {period_ms:2} ms {speed}   ({reports} reports)"
            );
        });
    }
}

/// Waits until the drives are set up.
async fn ready(pc: &Pc) {
    pc.wait_for_status(5_000, |status| status.mode != Mode::Starting)
        .await
        .expect("the drives are set up");
}

/// Opens the pairing window and waits for `event` from `name`.
async fn pair(robot: &AirRobot, pc: &Pc, name: &str, event: PadEvent) {
    ready(pc).await;
    pc.command(Command::RegisterWrite {
        address: Reg::Command as u8,
        value: OPEN_PAIRING_WINDOW_KEY,
    });
    robot
        .air
        .wait_for(0, name, |seen| *seen == event, Duration::from_secs(20))
        .await
        .expect("the pad is paired");
}

/// RB held, the left stick swinging between half and full forward every 50 ms.
async fn drive(pad: &Pad, how_long: Duration) {
    pad.hold(Buttons::RIGHT_BUMPER);
    let end = Instant::now() + how_long;
    let mut full = false;
    while Instant::now() < end {
        full = !full;
        pad.left_stick(0.0, if full { 1.0 } else { 0.5 });
        Timer::after_millis(50).await;
    }
    pad.release(Buttons::RIGHT_BUMPER);
}

/// Virtual seconds per second of CPU time and per wall second of `work`.
async fn timed(work: impl Future<Output = ()>) -> Speed {
    let wall = std::time::Instant::now();
    let cpu = thread_cpu_seconds();
    let start = Instant::now();
    work.await;
    let virtual_s = (Instant::now() - start).as_micros() as f64 / 1e6;
    Speed {
        per_cpu_s: cpu.and_then(|before| Some(virtual_s / (thread_cpu_seconds()? - before))),
        per_wall_s: virtual_s / wall.elapsed().as_secs_f64(),
    }
}

struct Speed {
    per_cpu_s: Option<f64>,
    per_wall_s: f64,
}

impl std::fmt::Display for Speed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.per_cpu_s {
            Some(per_cpu_s) => write!(f, "{per_cpu_s:6.0} / {:6.0}", self.per_wall_s),
            None => write!(f, "     ? / {:6.0}", self.per_wall_s),
        }
    }
}

/// This thread's CPU time so far (the first field of Linux's schedstat, in ns), or
/// `None` where that file is missing.
fn thread_cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let nanoseconds: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(nanoseconds / 1e9)
}
