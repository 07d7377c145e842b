//! Chattering safety inputs on the virtual robot: an e-stop contact or a safety
//! scanner output that flickers must still stop the base or hold its zone limit.
//! These are the patterns of the fault-injection review (issue 21, case 4); on the
//! symmetric debounce 8 of the 18 e-stop patterns drove on, the zone limit at
//! 9 ms on / 1 ms off was never applied, and at 50/50 ms it was exceeded.

use base_core::can::Mode;
use embassy_time::{Duration, Timer};
use embedded_hal::digital::PinState;
use virtual_robot::robot::{Pc, VirtualRobot, wait_ms};

/// The drives answer 1 s after power-on; their setup takes a few transactions more.
const BOOT_MS: u64 = 1_500;

/// Wheel surface speed for a motor speed, default radius 142 mm and gear 10:1.
fn wheel_mm(revolutions: f64) -> f64 {
    revolutions / 10.0 * 2.0 * std::f64::consts::PI * 142.0
}

/// The motor r/min for a wheel speed, with the default radius and gear.
fn motor_rpm(mm_s: f64) -> f64 {
    mm_s / (2.0 * std::f64::consts::PI * 142.0) * 60.0 * 10.0
}

/// The faster wheel's limit in the zone: `sec_lin_vel` 200 mm/s plus `sec_turn_vel`
/// 100 mrad/s on half the 250 mm track, 212.5 mm/s, 142.9 r/min.
fn zone_wheel_limit_rpm() -> f64 {
    motor_rpm(200.0 + 0.1 * 125.0)
}

/// Keeps the PC's enable and velocity coming every 50 ms for `ms`, and calls `each_ms`
/// after every millisecond.
async fn keep_driving(pc: &Pc, linear: i16, rotation: i16, ms: u64, mut each_ms: impl FnMut()) {
    for t in 0..ms {
        if t % 50 == 0 {
            pc.enable();
            pc.velocity(linear, rotation);
        }
        wait_ms(1).await;
        each_ms();
    }
}

/// How far the base rolled (the faster of the two wheels, mm) from the start of the
/// chatter, whether the mode became Emergency, and the wheels' speeds at the end.
struct EstopOutcome {
    rolled_mm: f64,
    emergency: bool,
    final_rpm: [f64; 2],
}

fn chatter_the_estop_while_driving(period_us: u64, pressed_us: u64, phase_us: u64) -> EstopOutcome {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_500).await;
        // Start at an arbitrary moment against the controller's sampling.
        Timer::after(Duration::from_micros(phase_us)).await;
        let before = [1, 2].map(|slave| robot.drives.drive(slave).forward_revolutions());
        robot.estop.chatter(
            PinState::Low,
            Duration::from_micros(period_us),
            Duration::from_micros(pressed_us),
        );
        keep_driving(pc, 500, 0, 1_000, || {}).await;
        let rolled_mm = [1, 2]
            .map(|slave| {
                wheel_mm(
                    robot.drives.drive(slave).forward_revolutions() - before[slave as usize - 1],
                )
            })
            .into_iter()
            .fold(0.0, f64::max);
        let emergency = pc
            .wait_for_status(1_100, |status| status.mode == Mode::Emergency)
            .await
            .is_some();
        EstopOutcome {
            rolled_mm,
            emergency,
            final_rpm: [1, 2].map(|slave| robot.drives.drive(slave).forward_rpm()),
        }
    })
}

/// 18 patterns: periods 0.5–2 ms, pressed 50–90 % of each, each started at its own
/// phase against the 1 ms grid. From 500 mm/s, `estop_decel` (4500 (1/min)/s) stops
/// 336 r/min in 75 ms (19 mm); with the first pressed sample and one Modbus
/// transaction before the zero goes out, the bound is 40 mm.
#[test]
fn an_estop_chattering_at_any_of_the_review_patterns_stops_the_base() {
    let mut failures = Vec::new();
    let mut worst_mm: f64 = 0.0;
    let mut pattern = 0u64;
    for period_us in [500u64, 700, 1_000, 1_300, 1_500, 2_000] {
        for percent in [50u64, 70, 90] {
            let pressed_us = period_us * percent / 100;
            let phase_us = (pattern * 137) % 1_000;
            pattern += 1;
            let outcome = chatter_the_estop_while_driving(period_us, pressed_us, phase_us);
            worst_mm = worst_mm.max(outcome.rolled_mm);
            let stopped = outcome.final_rpm.iter().all(|rpm| rpm.abs() < 0.5);
            if !outcome.emergency || !stopped || outcome.rolled_mm > 40.0 {
                failures.push(format!(
                    "{pressed_us}/{period_us} µs at +{phase_us} µs: emergency {}, rolled \
                     {:.0} mm, wheels at {:.0}/{:.0} r/min",
                    outcome.emergency,
                    outcome.rolled_mm,
                    outcome.final_rpm[0],
                    outcome.final_rpm[1]
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of 18 patterns not stopped:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(worst_mm <= 40.0, "rolled up to {worst_mm:.0} mm");
}

/// Turns at 500 mm/s and 500 mrad/s (the outer wheel at 378 r/min) while the zone input
/// chatters `on`/`off`; returns the highest commanded and the highest measured wheel
/// speed from `settle_ms` after the chatter began until its end (2 s), and whether the
/// status frame showed the zone.
fn turn_while_the_zone_chatters(on: Duration, off: Duration, settle_ms: u64) -> (f64, f64, bool) {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 500, 1_500).await;
        assert!(
            robot.drives.drive(1).forward_rpm() > 370.0,
            "turning at full speed first"
        );
        robot.safety_zone.chatter(PinState::Low, on + off, on);
        let mut elapsed = 0;
        let mut commanded: f64 = 0.0;
        let mut measured: f64 = 0.0;
        keep_driving(pc, 500, 500, 2_000, || {
            elapsed += 1;
            if elapsed < settle_ms {
                return;
            }
            for slave in [1, 2] {
                let drive = robot.drives.drive(slave);
                let command = drive.command.map_or(0, |command| command.speed_rpm);
                commanded = commanded.max(f64::from(command.unsigned_abs()));
                measured = measured.max(drive.forward_rpm().abs());
            }
        })
        .await;
        let shown = pc.status().is_some_and(|status| status.flags.safety_zone);
        (commanded, measured, shown)
    })
}

/// The scanner output at 9 ms occupied, 1 ms clear: it must read as occupied. From
/// 378 r/min `estop_decel` brakes to 143 r/min in 52 ms; 150 ms covers that and the
/// transaction in flight.
#[test]
fn a_zone_input_at_9_ms_on_1_ms_off_holds_the_zone_limit_in_a_turn() {
    let (commanded, measured, shown) =
        turn_while_the_zone_chatters(Duration::from_millis(9), Duration::from_millis(1), 150);
    // Commands are whole r/min: 142.9 goes out as 143.
    let limit = zone_wheel_limit_rpm().round();
    assert!(
        commanded <= limit && measured <= limit + 0.5,
        "limit {limit:.1} r/min, commanded up to {commanded:.0}, wheels up to {measured:.1}"
    );
    assert!(shown, "the status frame shows the zone");
}

/// The scanner output at 50 ms occupied, 50 ms clear: the zone limit holds whenever the
/// input was occupied within the last 100 ms, so throughout this chatter.
#[test]
fn a_zone_input_at_50_ms_on_50_ms_off_holds_the_zone_limit_throughout() {
    let (commanded, measured, shown) =
        turn_while_the_zone_chatters(Duration::from_millis(50), Duration::from_millis(50), 150);
    // Commands are whole r/min: 142.9 goes out as 143.
    let limit = zone_wheel_limit_rpm().round();
    assert!(
        commanded <= limit && measured <= limit + 0.5,
        "limit {limit:.1} r/min, commanded up to {commanded:.0}, wheels up to {measured:.1}"
    );
    assert!(shown, "the status frame shows the zone");
}

/// The other side of the window: once the scanner output stays clear, the limit lifts
/// after the 100 ms release window (not never, not at the first clear sample).
#[test]
fn the_zone_limit_lifts_once_the_input_stayed_clear_for_the_release_window() {
    let robot = VirtualRobot::new();
    let (limited_until, lifted_at) = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        robot.set_safety_zone(true);
        pc.drive(500, 0, 1_500).await;
        robot.set_safety_zone(false);
        let limit = motor_rpm(200.0).round() as i32;
        let mut limited_until = 0;
        let mut lifted_at = None;
        let mut elapsed = 0;
        keep_driving(pc, 500, 0, 500, || {
            elapsed += 1;
            let command = robot.drives.drive(1).command.map_or(0, |c| c.speed_rpm);
            if command <= limit {
                limited_until = elapsed;
            } else if lifted_at.is_none() {
                lifted_at = Some(elapsed);
            }
        })
        .await;
        (limited_until, lifted_at)
    });
    let lifted_at = lifted_at.expect("the limit lifted");
    assert!(
        limited_until >= 100 && lifted_at <= 130,
        "limited until {limited_until} ms, lifted at {lifted_at} ms after the release"
    );
}
