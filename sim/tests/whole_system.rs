//! The real firmware tasks on the virtual robot: CAN in, Modbus bytes out, odometry
//! back, all on a virtual clock. Each test is a story a user of the robot would tell.

use base_core::calibration::{OdometryCalibrationCommand, ScaleCalibrationCommand};
use base_core::can::{Command, Mode, Report, id};
use base_core::drives::reg;
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant};
use virtual_robot::can::{SimFrame, frame_time};
use virtual_robot::io::SimLoadCell;
use virtual_robot::robot::{Pc, VirtualRobot, wait_ms};
use virtual_robot::runtime::stall;

/// The drives answer 1 s after power-on; their setup takes a few transactions more.
const BOOT_MS: u64 = 1_500;

/// Motor r/min for `mm_s` at the wheel with the default registers: radius 142 mm,
/// gear 10:1.
fn motor_rpm(mm_s: f64) -> f64 {
    mm_s / (2.0 * std::f64::consts::PI * 142.0) * 60.0 * 10.0
}

/// What the odometry reports for `revolutions` of a motor: the default `f_lin`
/// correction (1.0071) applies.
fn reported_mm(revolutions: f64) -> f64 {
    revolutions / 10.0 * 2.0 * std::f64::consts::PI * 142.0 * 1.0071
}

async fn stop_and_settle(pc: &Pc) {
    pc.enable();
    pc.velocity(0, 0);
    wait_ms(2_000).await;
}

#[test]
fn driving_500_mm_s_for_2_s_commands_the_drives_and_reports_a_metre() {
    let robot = VirtualRobot::new();
    let (x, y, heading, travelled) = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_000).await;
        // Mid-drive: both drives run the rounded motor speed, the right one mirrored,
        // with CAN_accel (700 (1/min)/s) as their rate.
        let left = robot.drives.drive(1).command.expect("left commanded");
        let right = robot.drives.drive(2).command.expect("right commanded");
        let rpm = motor_rpm(500.0).round() as i32;
        assert_eq!((left.speed_rpm, right.speed_rpm), (rpm, -rpm));
        assert_eq!((left.accel_rpm_per_s, left.decel_rpm_per_s), (700, 700));
        assert_eq!((right.accel_rpm_per_s, right.decel_rpm_per_s), (700, 700));
        pc.drive(500, 0, 1_000).await;
        stop_and_settle(pc).await;
        let (x, y) = pc.position().expect("position frames");
        let travelled = reported_mm(robot.drives.drive(1).forward_revolutions());
        (x, y, pc.heading().expect("heading frames"), travelled)
    });
    // Speeding up and slowing down at the same rate cancel out, so 2 s at 500 mm/s is
    // 1000 mm, times f_lin (1007 mm), less the brake release: the first command
    // excites the drives (two S-ON writes, 3 ms) and waits 50 ms for the brakes before
    // any speed, 26 mm at 500 mm/s. Tolerance 8 mm: the speed is rounded to whole
    // r/min (336.25 → 336, 0.8 mm), and each command reaches the drives within one
    // Modbus transaction (≤ 15 ms, 7 mm at 500 mm/s; the same delay at start and
    // stop mostly cancels).
    let expected = 1_000.0 * 1.0071 - 26.5;
    assert!(
        (f64::from(x) - expected).abs() <= 8.0,
        "x = {x} mm, expected {expected:.0}"
    );
    // The odometry itself is exact: it matches the wheels' real travel to the mm.
    assert!(
        (f64::from(x) - travelled).abs() <= 1.0,
        "x = {x}, wheels {travelled:.1}"
    );
    assert_eq!((y, heading), (0, 0));
}

#[test]
fn a_clockwise_rotation_command_turns_clockwise_and_reports_a_positive_heading() {
    let robot = VirtualRobot::new();
    let heading = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(0, 500, 1_000).await;
        // Clockwise seen from above: the left wheel rolls forward, the right backward.
        // 500 mrad/s on a 250 mm track is 62.5 mm/s at each wheel: ±42 r/min.
        assert!(robot.drives.drive(1).forward_rpm() > 40.0);
        assert!(robot.drives.drive(2).forward_rpm() < -40.0);
        pc.drive(0, 500, 1_000).await;
        stop_and_settle(pc).await;
        pc.heading().expect("heading frames")
    });
    // 2 s at 500 mrad/s, times the clockwise correction f_cw (0.9938) and within 5 %
    // for the command rounding and timing.
    assert!((950..=1_050).contains(&heading), "heading = {heading} mrad");
}

#[test]
fn an_estop_stops_at_once_then_the_drives_are_set_up_again_and_driving_resumes() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_500).await;

        let pressed_at = Instant::now();
        robot.press_estop();
        pc.enable();
        pc.velocity(500, 0);
        wait_ms(50).await;
        for slave in [1, 2] {
            let drive = robot.drives.drive(slave);
            let command = drive.command.expect("commanded");
            assert_eq!(command.speed_rpm, 0, "drive {slave} got zero speed");
            assert_eq!(
                command.decel_rpm_per_s, 4_500,
                "drive {slave} brakes with estop_decel"
            );
            let latency = drive.last_new_speed_at.expect("new speed") - pressed_at;
            assert!(latency.as_millis() < 20, "zero speed after {latency:?}");
        }
        // No feedback in an emergency: nothing after the stop reached the bus.
        let frames_before = pc.reports(id::POSITION).len();
        // The e-stop circuit cuts the drives' power 300 ms after the press.
        wait_ms(250).await;
        robot.drives.power(false);
        wait_ms(1_000).await;
        assert_eq!(pc.reports(id::POSITION).len(), frames_before);

        robot.release_estop();
        robot.drives.power(true);
        wait_ms(200).await;
        let requests_before_confirm = robot.drives.request_count();
        robot.press_button(200).await;
        let ready = pc
            .wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await;
        assert!(ready.is_some(), "back in standby after the confirm press");
        // The setup frames went out again: share control to both slaves.
        let setups: Vec<u8> = robot.drives.requests()[requests_before_confirm..]
            .iter()
            .filter(|request| {
                request.bytes[1] == 0x10 && request.bytes[2..4] == reg::SHARE_CONTROL.to_be_bytes()
            })
            .map(|request| request.bytes[0])
            .collect();
        assert_eq!(setups, [1, 2]);

        // The pose continues where the wheels stopped, braking included: no jump from
        // the counters that restarted at zero with the drives' power.
        wait_ms(200).await;
        let after = pc.position().expect("position after recovery").0;
        let travelled = reported_mm(robot.drives.drive(1).forward_revolutions());
        assert!(
            (f64::from(after) - travelled).abs() <= 1.0,
            "pose {after} mm, wheels travelled {travelled:.1} mm"
        );

        // 1 s at 300 mm/s, times f_lin (302 mm), less the brake release: the recovery
        // left the drives de-excited, so the first command excites them (two S-ON
        // writes) and waits 50 ms before any speed, about 20 mm at 300 mm/s.
        pc.drive(300, 0, 1_000).await;
        stop_and_settle(pc).await;
        let driven = pc.position().expect("position").0 - after;
        assert!(
            (275..=310).contains(&driven),
            "drove {driven} mm after the recovery"
        );
    });
}

#[test]
fn a_drive_that_stops_answering_stops_the_other_and_recovers_after_the_confirm_press() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 1_000).await;
        robot.drives.set_silent(2, true);
        pc.drive(300, 0, 500).await;
        let left = robot.drives.drive(1);
        assert_eq!(
            left.command.expect("commanded").speed_rpm,
            0,
            "the left drive stopped"
        );
        let status = pc
            .wait_for_status(1_500, |status| status.faults.right_drive_silent)
            .await
            .expect("fault in the status frame");
        assert_eq!(status.mode, Mode::Fault);
        assert!(!status.faults.left_drive_silent);

        robot.drives.set_silent(2, false);
        wait_ms(500).await;
        robot.press_button(200).await;
        let status = pc
            .wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await
            .expect("standby after the confirm press");
        assert!(!status.faults.right_drive_silent && !status.faults.left_drive_silent);
        let start = pc.position().expect("position").0;
        pc.drive(300, 0, 1_000).await;
        stop_and_settle(pc).await;
        assert!(pc.position().expect("position").0 - start > 250);
    });
}

/// A drive that never answers after boot keeps the base in Starting; the status frame
/// says which one, and the bit clears once it answers and the setup is done.
#[test]
fn a_drive_silent_at_boot_is_shown_in_the_status_frame_until_it_answers() {
    let robot = VirtualRobot::new();
    robot.drives.set_silent(1, true);
    robot.run(async |pc| {
        let status = pc
            .wait_for_status(5_000, |status| status.faults.left_drive_silent)
            .await
            .expect("the silent drive is reported");
        assert_eq!(status.mode, Mode::Starting);
        assert!(!status.faults.right_drive_silent);
        robot.drives.set_silent(1, false);
        let status = pc
            .wait_for_status(5_000, |status| status.mode == Mode::Standby)
            .await
            .expect("the base gets ready once the drive answers");
        assert!(!status.faults.left_drive_silent);
    });
}

#[test]
fn a_register_written_over_can_survives_a_reboot() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(200).await;
        pc.command(Command::RegisterWrite {
            address: 11,
            value: 750,
        });
        // Flash waits until both drives confirmed S-OFF: they answer 1 s after
        // power-on (a controller that boots cannot know whether the wheels turn).
        wait_ms(1_200).await;
    });
    let value = robot.run(async |pc| pc.read_register(11).await);
    assert_eq!(value, Some(750));
}

#[test]
fn a_power_cut_during_a_register_write_leaves_the_old_or_the_new_value() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        pc.command(Command::RegisterWrite {
            address: 11,
            value: 500,
        });
        // Stored once the drives, powered on with the robot, confirmed S-OFF.
        wait_ms(1_200).await;
    });
    let mut outcomes = std::collections::BTreeMap::new();
    // Every flash step of the write, and then some: the cut lands before, inside and
    // after it.
    for cut_after in 0..80 {
        robot.run(async |pc| {
            robot.flash.cut_power_after(cut_after);
            pc.command(Command::RegisterWrite {
                address: 11,
                value: 900,
            });
            wait_ms(100).await;
        });
        robot.flash.restore_power();
        let value = robot
            .run(async |pc| pc.read_register(11).await)
            .expect("register 11 reads");
        assert!(
            value == 500 || value == 900,
            "cut after {cut_after} steps: {value}"
        );
        *outcomes.entry(value).or_insert(0) += 1;
        // Back to the old value for the next cut.
        robot.run(async |pc| {
            pc.command(Command::RegisterWrite {
                address: 11,
                value: 500,
            });
            wait_ms(100).await;
        });
    }
    assert!(outcomes.len() == 2, "both outcomes occur: {outcomes:?}");
}

#[test]
fn a_corrupt_store_boots_with_defaults_and_reports_the_flash_fault() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        pc.command(Command::RegisterWrite {
            address: 11,
            value: 750,
        });
        wait_ms(100).await;
    });
    let size = robot.flash.size() as u32;
    robot.flash.corrupt(0, &vec![0x5A; size as usize]);
    let (value, status) = robot.run(async |pc| {
        let value = pc.read_register(11).await;
        let status = pc.wait_for_status(1_500, |_| true).await;
        (value, status)
    });
    assert_eq!(value, Some(300), "disable_time back at its default");
    assert!(status.expect("status frame").faults.flash);
}

#[test]
fn garbled_modbus_replies_and_can_garbage_are_counted_and_driving_goes_on() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 500).await;
        robot.drives.garble_next_replies(2);
        // Wrong lengths on our IDs, unknown IDs, extended and remote frames.
        pc.peer.send(id::VELOCITY, &[1, 2, 3]);
        pc.peer.send(id::ENABLE, &[]);
        pc.peer.send(id::REGISTER_WRITE, &[200, 0, 1]);
        pc.peer.send(0x7FF, &[0xFF; 8]);
        pc.drive(300, 0, 1_000).await;
        let status = pc
            .wait_for_status(1_500, |status| status.modbus_errors >= 2)
            .await
            .expect("Modbus errors counted");
        assert!(status.rejected_count >= 3, "{status:?}");
        assert_eq!(status.mode, Mode::Active, "still driving");
        assert!(robot.drives.drive(1).forward_rpm() > 100.0);
    });
}

#[test]
fn the_scale_calibration_over_can_is_persisted() {
    let robot = VirtualRobot::new();
    // The weight frame comes every second and averages the last second of samples:
    // 2.5 s after a change, the last frame holds only new samples.
    let weigh = async |pc: &Pc| {
        wait_ms(2_500).await;
        pc.reports(id::WEIGHT).last().map(|(_, report)| *report)
    };
    robot.run(async |pc| {
        wait_ms(1_000).await;
        pc.command(Command::ScaleCalibration(ScaleCalibrationCommand::Start));
        pc.command(Command::ScaleCalibration(ScaleCalibrationCommand::Tare));
        robot.load_cell.set_load_grams(5_000.0);
        wait_ms(1_500).await;
        pc.command(Command::ScaleCalibration(
            ScaleCalibrationCommand::KnownWeight { grams: 5_000 },
        ));
        robot.load_cell.set_load_grams(2_000.0);
        assert_eq!(weigh(pc).await, Some(Report::Weight { grams: 2_000 }));
    });
    let after_reboot = robot.run(async |pc| weigh(pc).await);
    assert_eq!(after_reboot, Some(Report::Weight { grams: 2_000 }));
}

#[test]
fn the_odometry_calibration_over_can_is_persisted() {
    let robot = VirtualRobot::new();
    let (raw_x, f_lin) = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.command(Command::OdometryCalibration(
            OdometryCalibrationCommand::StartLinear,
        ));
        let revolutions = robot.drives.drive(1).forward_revolutions();
        pc.drive(400, 0, 2_000).await;
        stop_and_settle(pc).await;
        // The tape measure says the robot drove 3 % further than the wheels think.
        let wheel_mm =
            reported_mm(robot.drives.drive(1).forward_revolutions() - revolutions) / 1.0071;
        let real_mm = (wheel_mm * 1.03).round() as u16;
        pc.command(Command::OdometryCalibration(
            OdometryCalibrationCommand::EndLinear { real_mm },
        ));
        pc.command(Command::OdometryCalibration(
            OdometryCalibrationCommand::Store,
        ));
        wait_ms(200).await;
        (wheel_mm, pc.read_register(18).await)
    });
    assert!(raw_x > 700.0);
    // The wheels' travel is measured from the test's side, a sample apart from the
    // controller's: 0.1 % tolerance.
    let f_lin = f_lin.expect("f_lin reads");
    assert!((10_290..=10_310).contains(&f_lin), "f_lin = {f_lin}");
    let after_reboot = robot.run(async |pc| pc.read_register(18).await);
    assert_eq!(after_reboot, Some(f_lin));
}

#[test]
fn the_first_status_frame_after_a_watchdog_reset_on_a_corrupt_flash_reports_both() {
    let mut robot = VirtualRobot::new();
    let size = robot.flash.size();
    robot.flash.corrupt(0, &vec![0x5A; size]);
    robot.reset_by_watchdog = true;
    let first = robot.run(async |pc| pc.wait_for_status(100, |_| true).await);
    let status = first.expect("a status frame right after boot");
    assert!(
        status.faults.flash && status.faults.watchdog_reset,
        "the first status frame names every boot fault: {status:?}"
    );
}

#[test]
fn the_watchdog_is_fed_while_every_task_runs() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        pc.drive(200, 0, 5_000).await;
    });
    assert!(!robot.watchdog.has_bitten());
    assert!(robot.watchdog.feeds() >= 8);
}

/// The drives' power-up wait is a commissioning setting; however long it is, the drive
/// link keeps checking in, so the watchdog (2 s) is fed through it.
#[test]
fn a_long_drive_power_up_wait_does_not_starve_the_watchdog() {
    let mut robot = VirtualRobot::new();
    robot.settings.drives.power_up_wait_ms = 5_000;
    robot.run(async |_pc| wait_ms(6_000).await);
    assert_eq!(robot.watchdog.bitten_at(), None);
}

#[test]
fn a_drive_alarm_stops_the_base_is_reported_and_reset_by_the_recovery() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 1_000).await;
        robot.drives.raise_alarm(1, 0x30);
        pc.drive(300, 0, 300).await;
        let status = pc
            .wait_for_status(1_500, |status| status.faults.left_drive_alarm)
            .await
            .expect("alarm in the status frame");
        assert_eq!((status.mode, status.drive_alarm), (Mode::Fault, 0x30));
        assert_eq!(
            robot.drives.drive(2).command.expect("commanded").speed_rpm,
            0
        );

        wait_ms(1_000).await;
        robot.press_button(200).await;
        let status = pc
            .wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await
            .expect("standby after the confirm press");
        assert!(!status.faults.left_drive_alarm);
        assert_eq!(robot.drives.drive(1).alarm, 0, "the setup reset the alarm");
    });
}

#[test]
fn a_bus_off_is_reported_recovered_from_and_reports_flow_again() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(1_000).await;
        pc.peer.force_bus_off();
        wait_ms(100).await;
        assert!(pc.peer.recoveries() >= 1);
        let frames = pc.reports(id::POSITION).len();
        let status = pc
            .wait_for_status(1_500, |status| status.faults.can_bus)
            .await
            .expect("the bus-off in the status frame");
        assert_eq!(status.mode, Mode::Standby);
        assert!(
            pc.reports(id::POSITION).len() > frames,
            "odometry frames flow again"
        );
    });
}

#[test]
fn holding_the_front_button_for_3_s_pulses_the_pc_power_switch() {
    let robot = VirtualRobot::new();
    robot.run(async |_| {
        wait_ms(500).await;
        robot.press_button(3_500).await;
        wait_ms(1_000).await;
    });
    let pulses = robot.pc_switch.high_pulses();
    assert_eq!(pulses.len(), 1, "{pulses:?}");
    // pc_switch_pulse = 500 ms, on the controller's 10 ms tick.
    let length = pulses[0].length.as_millis();
    assert!((500..=510).contains(&length), "pulse of {length} ms");
}

#[test]
fn battery_and_weight_frames_report_the_sensors() {
    let robot = VirtualRobot::new();
    robot.load_cell.set_load_grams(1_234.0);
    let (battery, weight) = robot.run(async |pc| {
        // Calibrate the scale for the virtual load cell (offset 8000, 100 counts/g).
        pc.command(Command::RegisterWrite {
            address: 19,
            value: 8_000,
        });
        pc.command(Command::RegisterWrite {
            address: 20,
            value: 10_000,
        });
        wait_ms(6_000).await;
        (
            pc.reports(id::BATTERY).last().map(|(_, report)| *report),
            pc.reports(id::WEIGHT).last().map(|(_, report)| *report),
        )
    });
    assert_eq!(weight, Some(Report::Weight { grams: 1_234 }));
    match battery {
        Some(Report::Battery { voltage_mv, .. }) => {
            assert!((24_400..=24_600).contains(&voltage_mv), "{voltage_mv} mV")
        }
        other => panic!("no battery frame: {other:?}"),
    }
}

#[test]
fn the_control_cycle_follows_loop_end_delay() {
    let robot = VirtualRobot::new();
    let cycles_per_s = robot.run(async |pc| {
        // The cycle's feedback read: FC 03h to the share group (its motion part).
        let count_reads = || {
            robot
                .drives
                .requests()
                .iter()
                .filter(|request| request.bytes[..4] == [15, 0x03, 0, 0])
                .count()
        };
        wait_ms(BOOT_MS).await;
        let start = count_reads();
        wait_ms(1_000).await;
        let at_default = count_reads() - start;
        // Shorter: a longer one is capped at a third of the drives' 150 ms timeout.
        pc.command(Command::RegisterWrite {
            address: 15,
            value: 25,
        });
        wait_ms(100).await;
        let start = count_reads();
        wait_ms(1_000).await;
        (at_default, count_reads() - start)
    });
    assert_eq!(cycles_per_s, (20, 40), "50 ms by default, then 25 ms");
}

// ---------------------------------------------------------------------------------------
// Stops a safety engineer signs off (each reproduced on this virtual robot first)
// ---------------------------------------------------------------------------------------

/// Wheel speed in mm/s of a motor at `rpm` with the default registers.
fn wheel_mm_s(rpm: f64) -> f64 {
    rpm / 60.0 / 10.0 * 2.0 * std::f64::consts::PI * 142.0
}

/// Drives 500 mm/s with the default `CAN_accel`, writes `can_accel` while driving (it
/// is no motion register), then stops refreshing the enable. Returns how long after
/// the last enable both drives stand, in ms, and how far the left wheel rolled since,
/// in mm.
fn lapse_at_500_mm_s(can_accel: u16) -> (u64, f64) {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_500).await;
        pc.command(Command::RegisterWrite {
            address: 3,
            value: can_accel,
        });
        pc.drive(500, 0, 200).await;
        pc.enable();
        pc.velocity(500, 0);
        let last_enable = Instant::now();
        let start = robot.drives.drive(1).forward_revolutions();
        loop {
            wait_ms(1).await;
            let stands = [1, 2]
                .iter()
                .all(|&slave| robot.drives.drive(slave).speed_rpm == 0.0);
            let elapsed = (Instant::now() - last_enable).as_millis();
            if stands || elapsed > 10_000 {
                let rolled = robot.drives.drive(1).forward_revolutions() - start;
                return (elapsed, reported_mm(rolled) / 1.0071);
            }
        }
    })
}

/// Why 1: an enable lapse at 500 mm/s braked with `CAN_accel`: here 986 ms and 372 mm
/// after the last enable at 700, and at 1 (1/min)/s 336 s. Now `stop_decel` (2000) is
/// the floor: the 500 ms enable timeout, then 336 r/min in 168 ms, 250 + 42 mm (674 ms
/// and 295 mm measured).
#[test]
fn an_enable_lapse_stops_within_the_stop_decel_bound_whatever_can_accel_says() {
    for can_accel in [700, 1] {
        let (ms, mm) = lapse_at_500_mm_s(can_accel);
        assert!(
            (650..=700).contains(&ms),
            "CAN_accel {can_accel}: stood {ms} ms after the last enable"
        );
        assert!(
            (280.0..=310.0).contains(&mm),
            "CAN_accel {can_accel}: rolled {mm:.0} mm after the last enable"
        );
    }
}

/// What the flood in [`flooded_enable_lapse`] measured.
struct Flood {
    /// How long after the last enable both drives stood.
    stood_after: Option<Duration>,
    reads_sent: usize,
    reads_answered: usize,
    /// `can_tx_dropped` after the flood.
    replies_dropped: Option<u16>,
    /// Watchdog feeds during the flood, and how long after the last enable it bit,
    /// if it did by the flood's end.
    feeds: u32,
    bitten_after: Option<Duration>,
}

/// Drives 500 mm/s, sends a last enable, then fills the bus with register reads back
/// to back (one per frame time at 500 kbit/s) for `flood`, with no enable.
fn flooded_enable_lapse(flood: Duration) -> Flood {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 2_000).await;
        pc.enable();
        pc.velocity(500, 0);
        let last_enable = Instant::now();
        let feeds_before = robot.watchdog.feeds();
        let replies_before = pc.reports(id::REGISTER_READ).len();
        let read = Command::RegisterRead {
            address: 11,
            tag: 0,
        }
        .encode();
        let wire = frame_time(&SimFrame::standard(read.id(), read.data()).expect("a frame"));
        let mut stood_after = None;
        let mut reads_sent = 0;
        while Instant::now() - last_enable < flood {
            pc.send(read);
            reads_sent += 1;
            // A frame arrives before each of the controller's turns, so the executor
            // never idles and the virtual clock would stand still: the frame's time on
            // the wire passes here instead.
            stall(wire);
            yield_now().await;
            let stands = [1, 2]
                .iter()
                .all(|&slave| robot.drives.drive(slave).speed_rpm == 0.0);
            if stands && stood_after.is_none() {
                stood_after = Some(Instant::now() - last_enable);
            }
        }
        let feeds = robot.watchdog.feeds() - feeds_before;
        let bitten_after = robot.watchdog.bitten_at().map(|at| at - last_enable);
        // The reads still queued are answered once the bus is quiet.
        wait_ms(500).await;
        let reads_answered = pc
            .reports(id::REGISTER_READ)
            .into_iter()
            .skip(replies_before)
            .filter(|(_, report)| matches!(report, Report::RegisterValue { .. }))
            .count();
        Flood {
            stood_after,
            reads_sent,
            reads_answered,
            replies_dropped: pc.read_register(43).await,
            feeds,
            bitten_after,
        }
    })
}

/// A sustained input backlog starves neither the stops nor the watchdog: with the bus
/// full of register reads (a new frame before each of the controller's turns) an
/// enable lapse stops the base within the same bound as on a quiet bus, and every
/// critical task keeps checking in. Why: the controller checked in only on its 10 ms
/// tick, and took the tick only when its timer won against an empty queue; each turn
/// made a new timer, whose first poll always waits, so with a frame before every turn
/// the tick never came and the watchdog, last fed as the flood began, bit 2 s into it
/// (the enable lapse still stopped the base, on the drive feedback).
#[test]
fn a_bus_full_of_frames_neither_delays_the_enable_stop_nor_starves_the_watchdog() {
    let flood = Duration::from_secs(3);
    let measured = flooded_enable_lapse(flood);
    // Every read reached the controller: answered, or its reply dropped and counted.
    let dropped = usize::from(measured.replies_dropped.expect("can_tx_dropped reads"));
    assert!(
        measured.reads_answered + dropped >= measured.reads_sent,
        "{} reads sent, {} answered, {dropped} replies dropped",
        measured.reads_sent,
        measured.reads_answered
    );
    // The same bound as without the flood: the 500 ms enable timeout, then 336 r/min
    // in 168 ms with stop_decel.
    let stood_after = measured
        .stood_after
        .expect("the base stopped during the flood");
    assert!(
        (650..=700).contains(&stood_after.as_millis()),
        "stood {} ms after the last enable",
        stood_after.as_millis()
    );
    // The liveness task feeds every 500 ms while every critical task checks in.
    let expected_feeds = (flood.as_millis() / 500 - 1) as u32;
    assert!(
        measured.feeds >= expected_feeds && measured.bitten_after.is_none(),
        "the watchdog was fed {} times in {} ms of backlog, bitten {:?} ms into it: a \
         critical task stopped checking in",
        measured.feeds,
        flood.as_millis(),
        measured.bitten_after.map(|after| after.as_millis())
    );
}

/// Why 1: entering the safety zone at 1.2 m/s ramped down with `CAN_accel` (here the
/// wheels rolled 496 mm more than at 200 mm/s would have). Now with `estop_decel`
/// (4500): 807 → 134 r/min in 150 ms, 75 mm above 200 mm/s, plus the zone input's
/// debounce and one Modbus transaction (91 mm measured).
#[test]
fn entering_the_safety_zone_at_1200_mm_s_brakes_to_its_limit_within_a_tenth_of_a_metre() {
    let robot = VirtualRobot::new();
    let (above_mm, settled_rpm) = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(1_200, 0, 2_000).await;
        assert!(
            robot.drives.drive(1).forward_rpm() > 800.0,
            "at 1.2 m/s first"
        );
        robot.set_safety_zone(true);
        let mut above_mm = 0.0;
        for ms in 0..1_000u64 {
            if ms % 50 == 0 {
                pc.enable();
                pc.velocity(1_200, 0);
            }
            wait_ms(1).await;
            let speed = wheel_mm_s(robot.drives.drive(1).forward_rpm());
            above_mm += (speed - 200.0).max(0.0) / 1000.0;
        }
        (above_mm, robot.drives.drive(1).forward_rpm())
    });
    assert!(above_mm <= 100.0, "{above_mm:.0} mm above sec_lin_vel");
    // 200 mm/s is 134.5 r/min, rounded to 134.
    assert_eq!(settled_rpm.round(), 134.0);
}

/// Why 4: `motor_dir` 2 → 0 while driving straight spun the base in place. The write
/// is refused (NotAtRest, 0x14), the base drives on straight, and the value is
/// accepted once the base stands.
#[test]
fn motor_dir_written_while_driving_is_refused_and_the_base_drives_on_straight() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_000).await;
        pc.command(Command::RegisterWrite {
            address: 28,
            value: 0,
        });
        pc.drive(500, 0, 1_000).await;
        assert_eq!(pc.heading(), Some(0), "still straight");
        let refused = pc
            .wait_for_status(1_100, |status| {
                (status.last_rejection, status.last_rejection_subject) == (0x14, 28)
            })
            .await;
        assert!(refused.is_some(), "the refusal is in the status frame");
        assert_eq!(pc.read_register(28).await, Some(2));
        stop_and_settle(pc).await;
        pc.command(Command::RegisterWrite {
            address: 28,
            value: 0,
        });
        wait_ms(100).await;
        assert_eq!(pc.read_register(28).await, Some(0), "accepted at rest");
    });
}

/// Why 5: a spin command 100 ms into a ramp made the wheels arrive apart (79 ms here;
/// the scenario table has the 187 ms case worked out): the ramp started from the
/// previous target (+336, −336), not from the wheels' speed. Now it starts from the
/// measured speed moved along the ramp since: both arrive after 192 ms.
#[test]
fn a_spin_100_ms_into_a_ramp_brings_both_wheels_to_their_speeds_together() {
    let robot = VirtualRobot::new();
    let (left_ms, right_ms) = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.enable();
        pc.velocity(500, 0);
        // The drives start ramping once the brakes are released.
        while robot.drives.drive(1).last_new_speed_at.is_none() {
            wait_ms(1).await;
        }
        let ramp_start = robot.drives.drive(1).last_new_speed_at.expect("ramping");
        while Instant::now() < ramp_start + embassy_time::Duration::from_millis(100) {
            wait_ms(1).await;
        }
        let spin_at = Instant::now();
        pc.enable();
        pc.velocity(0, 1_000);
        let mut arrived = [None, None];
        for ms in 1..=1_000u64 {
            if ms % 50 == 0 {
                pc.enable();
                pc.velocity(0, 1_000);
            }
            wait_ms(1).await;
            for (slave, arrival) in [1u8, 2].into_iter().zip(arrived.iter_mut()) {
                let drive = robot.drives.drive(slave);
                let target = drive.command.expect("commanded").speed_rpm;
                let there = (drive.speed_rpm - f64::from(target)).abs() < 0.5;
                if arrival.is_none() && there {
                    *arrival = Some((Instant::now() - spin_at).as_millis());
                }
                if !there {
                    *arrival = None;
                }
            }
        }
        (
            arrived[0].expect("left arrived"),
            arrived[1].expect("right arrived"),
        )
    });
    assert!(
        left_ms.abs_diff(right_ms) <= 20,
        "left at {left_ms} ms, right at {right_ms} ms"
    );
}
/// Sends `count` register reads at once (addresses 0, 1, …) and returns the values that
/// came back, in order.
async fn burst_of_reads(pc: &Pc, count: u8) -> Vec<u16> {
    let before = pc.reports(id::REGISTER_READ).len();
    for address in 0..count {
        pc.command(Command::RegisterRead {
            address: address % 34,
            tag: 0,
        });
    }
    wait_ms(200).await;
    pc.reports(id::REGISTER_READ)
        .into_iter()
        .skip(before)
        .filter_map(|(_, report)| match report {
            Report::RegisterValue { value, .. } => Some(value),
            _ => None,
        })
        .collect()
}

#[test]
fn a_burst_of_20_register_reads_is_answered_in_full() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        for _ in 0..5 {
            let values = burst_of_reads(pc, 20).await;
            let expected: Vec<u16> = (0..20u8)
                .map(|address| base_core::registers::info(address).unwrap().default)
                .collect();
            assert_eq!(values, expected);
        }
        // Nothing was dropped on the way.
        assert_eq!(pc.read_register(43).await, Some(0));
    });
}

#[test]
fn transmit_drops_are_counted_in_can_tx_dropped() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        // Far more replies at once than the transmit queue holds.
        let answered = burst_of_reads(pc, 200).await.len();
        assert!(answered < 200, "{answered} of 200 answered");
        let dropped = pc.read_register(43).await.expect("can_tx_dropped reads");
        // Every reply not answered was dropped (periodic frames may be dropped too).
        assert!(
            usize::from(dropped) >= 200 - answered,
            "{dropped} dropped, {answered} of 200 answered"
        );
    });
}

#[test]
fn a_tare_beyond_16_bits_works_and_register_19_reads_it_clamped() {
    for (empty, reads_19, high, low) in [(80_000, 65_535, 0x01, 0x3880), (-15_000, 0, 0xFF, 0xC568)]
    {
        let mut robot = VirtualRobot::new();
        robot.load_cell = SimLoadCell::new(empty, 19.0);
        let weigh = async |pc: &Pc| {
            wait_ms(2_500).await;
            pc.reports(id::WEIGHT).last().map(|(_, report)| *report)
        };
        robot.run(async |pc| {
            wait_ms(1_000).await;
            pc.command(Command::ScaleCalibration(ScaleCalibrationCommand::Start));
            pc.command(Command::ScaleCalibration(ScaleCalibrationCommand::Tare));
            // The empty scale weighs nothing: the tare was taken, not refused.
            assert_eq!(
                weigh(pc).await,
                Some(Report::Weight { grams: 0 }),
                "{empty}"
            );
            robot.load_cell.set_load_grams(5_000.0);
            wait_ms(1_500).await;
            pc.command(Command::ScaleCalibration(
                ScaleCalibrationCommand::KnownWeight { grams: 5_000 },
            ));
            robot.load_cell.set_load_grams(2_000.0);
            assert_eq!(weigh(pc).await, Some(Report::Weight { grams: 2_000 }));
            assert_eq!(pc.status().unwrap().rejected_count, 0);
        });
        robot.run(async |pc| {
            assert_eq!(
                weigh(pc).await,
                Some(Report::Weight { grams: 2_000 }),
                "{empty}"
            );
            assert_eq!(pc.read_register(19).await, Some(reads_19));
            assert_eq!(pc.read_register(44).await, Some(high));
            assert_eq!(pc.read_register(45).await, Some(low));
        });
    }
}
