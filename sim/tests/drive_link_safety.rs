//! The drive link's fail-safe behaviour on the virtual robot: the wheels stop whenever
//! the controller cannot vouch for them (a controller reset while driving, a drive
//! that stays silent, a group frame that keeps failing), and the drives end every
//! recovery de-excited. Each test is a fault a reviewer reproduced on the old firmware.

use base_core::can::Mode;
use base_core::drives::{DriveSettings, reg, settings};
use embassy_time::{Duration, Instant};
use virtual_robot::drives::DrivesConfig;
use virtual_robot::robot::{VirtualRobot, wait_ms};

/// The drives answer 1 s after power-on; their setup takes a few transactions more.
const BOOT_MS: u64 = 1_500;

/// Wheel travel in mm for `revolutions` of a motor (radius 142 mm, gear 10:1).
fn wheel_mm(revolutions: f64) -> f64 {
    revolutions / 10.0 * 2.0 * std::f64::consts::PI * 142.0
}

/// The most either wheel travelled since `before` (forward revolutions per slave).
fn run_on_mm(robot: &VirtualRobot, before: [f64; 2]) -> f64 {
    let left = robot.drives.drive(1).forward_revolutions() - before[0];
    let right = robot.drives.drive(2).forward_revolutions() - before[1];
    wheel_mm(left.abs().max(right.abs()))
}

/// The register words of every FC 10h write to `register` of `slave` that ended after
/// `after`, with the moment it ended.
fn writes(
    robot: &VirtualRobot,
    slave: u8,
    register: u16,
    after: Instant,
) -> Vec<(Instant, Vec<u16>)> {
    robot
        .drives
        .requests()
        .into_iter()
        .filter(|request| {
            let bytes = &request.bytes;
            request.at > after
                && bytes.len() > 9
                && bytes[0] == slave
                && bytes[1] == 0x10
                && bytes[2..4] == register.to_be_bytes()
        })
        .map(|request| {
            let data = &request.bytes[7..request.bytes.len() - 2];
            let words = data
                .chunks(2)
                .map(|pair| u16::from_be_bytes([pair[0], pair[1]]))
                .collect();
            (request.at, words)
        })
        .collect()
}

/// DDO operation type (NET-ID 45), the first of the DDO fields a hold writes.
const DDO_OPERATION_TYPE: u16 = 0x005A;

/// The DDO fields a hold writes: operation type 16, position 0, speed 0, and
/// `estop_decel` (4500) as acceleration and deceleration, 32 bits each.
const HOLD_FIELDS: [u16; 10] = [0, 16, 0, 0, 0, 0, 0, 4_500, 0, 4_500];

fn revolutions(robot: &VirtualRobot) -> [f64; 2] {
    [1, 2].map(|slave| robot.drives.drive(slave).forward_revolutions())
}

/// Boots, drives at 500 mm/s until both wheels run at speed, and returns (the
/// controller then loses power: the next `run` is an immediate reboot).
fn drive_at_500(robot: &VirtualRobot) {
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 2_000).await;
        assert!(robot.drives.drive(1).forward_rpm() > 330.0);
        assert!(robot.drives.drive(2).forward_rpm() > 330.0);
    });
}

#[test]
fn a_controller_reset_while_driving_stops_both_wheels_within_100_mm() {
    let robot = VirtualRobot::new();
    drive_at_500(&robot);
    let before = revolutions(&robot);
    let rebooted_at = Instant::now();
    robot.run(async |_pc| wait_ms(3_000).await);
    // The first frames to each drive: zero with estop_decel, trigger, S-OFF.
    for slave in [1, 2] {
        let holds = writes(&robot, slave, DDO_OPERATION_TYPE, rebooted_at);
        let (at, fields) = holds.first().expect("held after the reboot");
        assert_eq!(fields[..], HOLD_FIELDS);
        assert!(
            *at - rebooted_at < Duration::from_millis(50),
            "{:?}",
            *at - rebooted_at
        );
        let s_off = writes(&robot, slave, reg::DRIVER_INPUT_COMMAND, rebooted_at);
        assert_eq!(s_off.first().expect("S-OFF").1, [0, 0]);
    }
    let run_on = run_on_mm(&robot, before);
    assert!(run_on <= 100.0, "run-on after the reset: {run_on:.0} mm");
    for slave in [1, 2] {
        let drive = robot.drives.drive(slave);
        assert_eq!(drive.speed_rpm, 0.0, "drive {slave} stands");
        assert!(!drive.servo_on, "drive {slave} de-excited (brake holds)");
        let command = drive.command.expect("commanded after the reboot");
        assert_eq!(command.speed_rpm, 0);
    }
}

#[test]
fn a_controller_reset_with_one_drive_silent_stops_the_other_and_the_estop_reaches_it() {
    let robot = VirtualRobot::new();
    drive_at_500(&robot);
    // The right drive's line breaks at the moment of the reset: it keeps running its
    // last command (only its own communication timeout could stop it).
    robot.drives.set_silent(2, true);
    let before = revolutions(&robot);
    robot.run(async |pc| {
        wait_ms(3_000).await;
        let left = robot.drives.drive(1);
        let moved = wheel_mm(left.forward_revolutions() - before[0]);
        assert!(moved <= 100.0, "left run-on after the reset: {moved:.0} mm");
        assert_eq!(left.speed_rpm, 0.0);
        assert!(!left.servo_on, "the answering drive is held de-excited");
        // The base does not get ready, and says which drive is missing.
        let status = pc
            .wait_for_status(1_000, |status| status.faults.right_drive_silent)
            .await
            .expect("the silent drive is reported");
        assert_eq!(status.mode, Mode::Starting);

        // The e-stop reaches the answering drive while the link still polls for both.
        let pressed_at = Instant::now();
        robot.press_estop();
        wait_ms(300).await;
        let left = robot.drives.drive(1);
        let command = left.command.expect("commanded");
        assert_eq!((command.speed_rpm, command.decel_rpm_per_s), (0, 4_500));
        let holds = writes(&robot, 1, DDO_OPERATION_TYPE, pressed_at);
        let (at, fields) = holds.first().expect("held after the e-stop");
        assert_eq!(fields[..], HOLD_FIELDS);
        assert!(
            *at - pressed_at < Duration::from_millis(100),
            "{:?}",
            *at - pressed_at
        );
    });
}

#[test]
fn the_first_frames_after_a_reset_are_zero_speed_and_s_off_to_each_drive() {
    let robot = VirtualRobot::new();
    drive_at_500(&robot);
    let rebooted_at = Instant::now();
    let requests_before = robot.drives.request_count();
    robot.run(async |_pc| wait_ms(900).await);
    let requests = robot.drives.requests();
    let after = &requests[requests.len() - (robot.drives.request_count() - requests_before)..];
    // The very first frame is the zero speed to slave 1, not a query or the group.
    assert_eq!(after[0].bytes[..4], [1, 0x10, 0x00, 0x5A]);
    // Within the 1 s power-up wait, repeated every poll interval (200 ms): zero with
    // estop_decel, the trigger and S-OFF to each slave, and nothing else.
    for slave in [1, 2] {
        let holds = writes(&robot, slave, DDO_OPERATION_TYPE, rebooted_at);
        assert!(holds.len() >= 4, "{} holds of drive {slave}", holds.len());
        assert!(holds.iter().all(|(_, fields)| fields[..] == HOLD_FIELDS));
        // The reboot's power-off may cut the last round short.
        let triggers = writes(&robot, slave, reg::DDO_TRIGGER, rebooted_at);
        assert!(holds.len() - triggers.len() <= 1);
        let s_off = writes(&robot, slave, reg::DRIVER_INPUT_COMMAND, rebooted_at);
        assert!(s_off.iter().all(|(_, words)| words[..] == [0, 0]));
        assert!(holds.len() - s_off.len() <= 1);
    }
    let holds = writes(&robot, 1, DDO_OPERATION_TYPE, rebooted_at).len();
    assert!(
        (6 * holds - 5..=6 * holds).contains(&after.len()),
        "only holds: {} frames",
        after.len()
    );
}

/// Waits for a status frame sent after now that satisfies `check`.
async fn next_status(
    pc: &virtual_robot::robot::Pc,
    timeout_ms: u64,
    check: impl Fn(&base_core::can::Status) -> bool,
) -> Option<base_core::can::Status> {
    let since = Instant::now();
    let end = since + Duration::from_millis(timeout_ms);
    while Instant::now() < end {
        wait_ms(10).await;
        let fresh = pc
            .reports(base_core::can::id::STATUS)
            .into_iter()
            .rev()
            .take_while(|(at, _)| *at > since)
            .find_map(|(_, report)| match report {
                base_core::can::Report::Status(status) if check(&status) => Some(status),
                _ => None,
            });
        if fresh.is_some() {
            return fresh;
        }
    }
    None
}

#[test]
fn every_recovery_ends_with_the_drives_de_excited_and_the_status_reports_it() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_000).await;
        let driving = next_status(pc, 1_500, |_| true).await.expect("status");
        assert!(!driving.flags.brakes_applied);

        // An e-stop whose circuit leaves the drives powered: once estop_decel had its
        // time, the drives are told S-OFF, and only then the status says so.
        robot.press_estop();
        wait_ms(100).await;
        assert!(robot.drives.drive(1).servo_on, "no S-OFF at speed");
        wait_ms(900).await;
        for slave in [1, 2] {
            assert!(!robot.drives.drive(slave).servo_on, "drive {slave} S-OFF");
        }
        let status = next_status(pc, 1_500, |_| true).await.expect("status");
        assert!(status.flags.brakes_applied);
        robot.release_estop();
        robot.press_button(200).await;
        pc.wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await
            .expect("standby after the confirm press");
        wait_ms(2_000).await;
        for slave in [1, 2] {
            assert!(
                !robot.drives.drive(slave).servo_on,
                "drive {slave} de-excited after the e-stop recovery"
            );
        }
        let status = next_status(pc, 1_500, |_| true).await.expect("status");
        assert!(status.flags.brakes_applied);

        // A drive alarm: the other drive is de-excited once the base stands, and the
        // recovery leaves both de-excited.
        pc.drive(300, 0, 1_000).await;
        robot.drives.raise_alarm(1, 0x30);
        pc.drive(300, 0, 300).await;
        pc.wait_for_status(1_500, |status| status.mode == Mode::Fault)
            .await
            .expect("fault");
        wait_ms(1_000).await;
        assert!(
            !robot.drives.drive(2).servo_on,
            "the answering drive S-OFF in Fault"
        );
        robot.press_button(200).await;
        pc.wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await
            .expect("standby after the confirm press");
        wait_ms(2_000).await;
        for slave in [1, 2] {
            assert!(
                !robot.drives.drive(slave).servo_on,
                "drive {slave} de-excited after the fault recovery"
            );
        }
        let status = next_status(pc, 1_500, |_| true).await.expect("status");
        assert!(status.flags.brakes_applied);
    });
}

/// The blind stop's broadcast: operation type 16, position 0, speed 0, `estop_decel`
/// (4500) as both rates, torque limit 100 %, trigger, 32 bits each.
const BLIND_ZERO_FIELDS: [u16; 14] = [0, 16, 0, 0, 0, 0, 0, 4_500, 0, 4_500, 0, 1_000, 0, 1];

#[test]
fn a_group_frame_that_keeps_failing_stops_the_wheels_blind_and_raises_a_fault() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 1_000).await;
        // A marginal line: the group's command write (41 bytes and more) fails, the
        // short feedback read and unicast frames (8..29 bytes) still pass. At a
        // constant speed the drives have their command and nothing needs the write.
        robot.drives.fail_requests_longer_than(Some(40));
        pc.drive(300, 0, 500).await;
        // The PC stops: the write that carries the zero fails.
        let stop_at = Instant::now();
        pc.enable();
        pc.velocity(0, 0);
        wait_ms(400).await;
        // Zero to every drive at once, by broadcast (it needs no reply).
        let holds = writes(&robot, 0, DDO_OPERATION_TYPE, stop_at);
        let (at, fields) = holds.first().expect("zero by broadcast");
        assert_eq!(fields[..], BLIND_ZERO_FIELDS);
        assert!(
            *at - stop_at < Duration::from_millis(250),
            "{:?}",
            *at - stop_at
        );
        let status = pc
            .wait_for_status(1_000, |status| status.mode == Mode::Fault)
            .await
            .expect("a drive-link fault");
        assert!(status.faults.left_drive_silent && status.faults.right_drive_silent);
        wait_ms(500).await;
        for slave in [1, 2] {
            assert_eq!(
                robot.drives.drive(slave).speed_rpm,
                0.0,
                "drive {slave} stands"
            );
        }
    });
}

#[test]
fn both_drives_lost_while_driving_are_both_latched() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 1_000).await;
        robot.drives.set_silent(1, true);
        robot.drives.set_silent(2, true);
        let status = pc
            .wait_for_status(2_000, |status| {
                status.faults.left_drive_silent && status.faults.right_drive_silent
            })
            .await
            .expect("both drives reported");
        assert_eq!(status.mode, Mode::Fault);
    });
}

/// The commissioning check of the drives' own communication timeout: with the RS-485
/// line cut while the wheels turn slowly, the drives stop within the timeout (alarm
/// 85h), without the controller.
#[test]
fn a_cut_rs485_line_stops_the_wheels_by_the_drives_communication_timeout() {
    let robot = VirtualRobot::new();
    let timeout = robot.settings.drives.drive_comm_timeout_ms;
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(100, 0, 1_000).await;
        assert!(robot.drives.drive(1).forward_rpm() > 60.0);
        robot.drives.set_silent(1, true);
        robot.drives.set_silent(2, true);
        pc.drive(100, 0, u64::from(timeout) + 100).await;
        for slave in [1, 2] {
            let drive = robot.drives.drive(slave);
            assert_eq!(drive.alarm, 0x85, "drive {slave} timed out");
            assert_eq!(drive.speed_rpm, 0.0, "drive {slave} stands");
        }
        // Back on the line: the alarm is reset by the recovery like any other.
        robot.drives.set_silent(1, false);
        robot.drives.set_silent(2, false);
        wait_ms(500).await;
        robot.press_button(200).await;
        pc.wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await
            .expect("standby after the confirm press");
        for slave in [1, 2] {
            assert_eq!(robot.drives.drive(slave).alarm, 0);
        }
        pc.drive(100, 0, 1_000).await;
        assert!(robot.drives.drive(1).forward_rpm() > 60.0, "drives again");
    });
}

/// In normal operation the timeout never trips: a long drive at the default cycle,
/// a slow cycle (loop_end_delay 1000 ms), and a drive silent at boot with the other
/// held meanwhile.
#[test]
fn the_drives_communication_timeout_never_trips_in_normal_operation() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 5_000).await;
        pc.command(base_core::can::Command::RegisterWrite {
            address: 15,
            value: 1_000,
        });
        pc.drive(300, 0, 5_000).await;
        wait_ms(3_000).await;
        for slave in [1, 2] {
            assert_eq!(robot.drives.drive(slave).alarm, 0, "drive {slave}");
        }
    });
    robot.drives.set_silent(2, true);
    robot.run(async |_pc| wait_ms(5_000).await);
    assert_eq!(robot.drives.drive(1).alarm, 0, "held drive");
}

/// A drive whose share setup is saved in its NV memory and which reboots within a
/// cycle: the link never sees a reconnect, only its counter restarting at 0. The
/// odometry takes that step as a discontinuity, not as metres of motion.
#[test]
fn a_drive_that_reboots_unseen_does_not_make_the_pose_jump() {
    let robot = VirtualRobot::with_drives(virtual_robot::drives::DrivesConfig {
        share_setup_saved: true,
        boot_time: Duration::from_millis(20),
        ..Default::default()
    });
    robot.run(async |pc| {
        // The first boot waits the full second anyway (power_up_wait).
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 2_000).await;
        let rejected_before = pc.status().expect("status").rejected_count;
        robot.drives.power_cycle(1);
        pc.drive(500, 0, 500).await;
        pc.enable();
        pc.velocity(0, 0);
        wait_ms(1_500).await;
        let positions: Vec<i32> = pc
            .reports(base_core::can::id::POSITION)
            .into_iter()
            .filter_map(|(_, report)| match report {
                base_core::can::Report::Position { x_mm, .. } => Some(x_mm),
                _ => None,
            })
            .collect();
        // 500 mm/s is 25 mm per 50 ms frame.
        let largest = positions
            .windows(2)
            .map(|pair| (pair[1] - pair[0]).abs())
            .max()
            .expect("positions");
        assert!(largest <= 30, "the pose jumped {largest} mm in one frame");
        let headings: Vec<i32> = pc
            .reports(base_core::can::id::HEADING)
            .into_iter()
            .filter_map(|(_, report)| match report {
                base_core::can::Report::Heading { heading_mrad } => Some(heading_mrad),
                _ => None,
            })
            .collect();
        // The rebooted left drive stays de-excited: the base pivots on it at most at
        // 500 mm/s / 250 mm = 2 rad/s, 100 mrad per 50 ms cycle (a frame may carry a
        // little more than one cycle); the restarted counter alone would be 4 rad.
        let largest = headings
            .windows(2)
            .map(|pair| (pair[1] - pair[0]).abs())
            .max()
            .expect("headings");
        assert!(
            largest <= 150,
            "the heading jumped {largest} mrad in one frame"
        );
        let status = next_status(pc, 1_500, |_| true).await.expect("status");
        assert_ne!(
            status.rejected_count, rejected_before,
            "the discontinuity is counted"
        );
        assert_eq!(
            (status.last_rejection, status.last_rejection_subject),
            (0x40, 1)
        );
    });
}

/// The largest gap between two control cycles (the feedback reads to the group) on the
/// wire in `window`.
fn worst_cycle_gap(robot: &VirtualRobot, from: Instant, to: Instant) -> Duration {
    let cycles: Vec<Instant> = robot
        .drives
        .requests()
        .into_iter()
        .filter(|request| {
            // The motion part of each cycle's feedback read.
            request.bytes[..4] == [15, 0x03, 0, 0] && request.at >= from && request.at <= to
        })
        .map(|request| request.at)
        .collect();
    cycles
        .windows(2)
        .map(|pair| pair[1] - pair[0])
        .max()
        .expect("cycles in the window")
}

/// On the chip a sector erase masks interrupts for up to 400 ms. Register writes while
/// driving are in force at once and reach the flash only at the next standstill, so
/// the control cycle never stalls; they are persisted then.
#[test]
fn flash_erases_wait_for_standstill_and_never_stall_the_control_cycle() {
    let robot = VirtualRobot::new();
    robot.flash.set_erase_stall(Duration::from_millis(400));
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 1_000).await;
        let erases_before = robot.flash.stats().erases;
        let from = Instant::now();
        // disable_time 300/301 ms, 2000 times: several pages of records.
        for round in 0..2_000u16 {
            pc.enable();
            pc.velocity(300, 0);
            pc.command(base_core::can::Command::RegisterWrite {
                address: 11,
                value: 300 + round % 2,
            });
            wait_ms(2).await;
        }
        let to = Instant::now();
        assert!(robot.drives.drive(1).forward_rpm() > 150.0, "still driving");
        let gap = worst_cycle_gap(&robot, from, to);
        assert!(
            gap <= Duration::from_millis(60),
            "control cycle stalled {gap:?}"
        );
        assert_eq!(
            robot.flash.stats().erases,
            erases_before,
            "no erase while driving"
        );
        let status = next_status(pc, 1_500, |_| true).await.expect("status");
        assert!(status.persist_pending, "the status frame says values wait");
        assert_eq!(status.mode, Mode::Active);

        // At standstill the last value goes to the flash.
        pc.command(base_core::can::Command::RegisterWrite {
            address: 11,
            value: 750,
        });
        pc.enable();
        pc.velocity(0, 0);
        wait_ms(3_000).await;
        let status = next_status(pc, 1_500, |_| true).await.expect("status");
        assert!(!status.persist_pending, "written at the standstill");
    });
    let value = robot.run(async |pc| {
        let before = pc.reports(base_core::can::id::REGISTER_READ).len();
        pc.command(base_core::can::Command::RegisterRead {
            address: 11,
            tag: 0,
        });
        wait_ms(50).await;
        pc.reports(base_core::can::id::REGISTER_READ)
            .into_iter()
            .skip(before)
            .find_map(|(_, report)| match report {
                base_core::can::Report::RegisterValue { value, .. } => Some(value),
                _ => None,
            })
    });
    assert_eq!(value, Some(750), "persisted at the standstill");
}

// ---------------------------------------------------------------------------------------
// When the controller cannot hear the drives (issue 21, cases 1-3): the wheels stop
// within 300 mm from 500 mm/s, whatever comes back, and stay stopped.
// ---------------------------------------------------------------------------------------

/// Drives at 500 mm/s, causes `fault`, and (with `then_stop`) has the PC stop at once;
/// returns the farthest either wheel rolled from the fault on, once both stand, and
/// the mode the status frame reports.
fn run_on_after(fault: impl Fn(&VirtualRobot), then_stop: bool) -> (f64, Mode) {
    run_on_after_on(VirtualRobot::new(), fault, then_stop)
}

fn run_on_after_on(
    robot: VirtualRobot,
    fault: impl Fn(&VirtualRobot),
    then_stop: bool,
) -> (f64, Mode) {
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 2_000).await;
        let before = revolutions(&robot);
        fault(&robot);
        if then_stop {
            pc.enable();
            pc.velocity(0, 0);
        }
        // The PC keeps its enable and its last command going, as a PC that noticed
        // nothing would.
        let speed = if then_stop { 0 } else { 500 };
        pc.drive(speed, 0, 3_000).await;
        for slave in [1, 2] {
            let drive = robot.drives.drive(slave);
            assert_eq!(drive.speed_rpm, 0.0, "drive {slave} still turns");
        }
        let run_on = run_on_mm(&robot, before);
        // Never on without bound: still standing a while later.
        pc.drive(speed, 0, 5_000).await;
        let later = run_on_mm(&robot, before);
        assert!(
            later - run_on < 1.0,
            "rolled on: {run_on:.0} → {later:.0} mm"
        );
        let mode = pc.status().expect("status").mode;
        (run_on, mode)
    })
}

fn assert_stops_within_300_mm(case: &str, (run_on, mode): (f64, Mode)) {
    assert!(run_on <= 300.0, "{case}: {run_on:.0} mm");
    assert_eq!(mode, Mode::Fault, "{case}");
}

#[test]
fn replies_lost_while_driving_stop_both_wheels_within_300_mm() {
    let result = run_on_after(|robot| robot.drives.lose_replies(true), false);
    assert_stops_within_300_mm("receive path dead", result);
}

#[test]
fn every_reply_garbled_while_driving_stops_both_wheels_within_300_mm() {
    let garble_both = |robot: &VirtualRobot| {
        robot.drives.garble_replies_of(1, true);
        robot.drives.garble_replies_of(2, true);
    };
    assert_stops_within_300_mm("every reply garbled", run_on_after(garble_both, false));
    let garble_right = |robot: &VirtualRobot| robot.drives.garble_replies_of(2, true);
    assert_stops_within_300_mm("right replies garbled", run_on_after(garble_right, false));
}

#[test]
fn a_drive_answering_busy_to_everything_stops_within_300_mm() {
    let result = run_on_after(|robot| robot.drives.set_busy(1, true), false);
    assert_stops_within_300_mm("left drive busy", result);
}

#[test]
fn a_stop_through_a_line_that_fails_long_requests_stops_within_300_mm() {
    let result = run_on_after(
        |robot| robot.drives.fail_requests_longer_than(Some(25)),
        true,
    );
    assert_stops_within_300_mm("requests over 25 bytes fail", result);
}

// ---------------------------------------------------------------------------------------
// Every line fault, whatever the accepted settings (issue 30, item 7): the base stops
// within 300 mm from 500 mm/s. Settings with which it could not (the drives' own
// timeout off or too long, too many failures before a loss, a long reply timeout, a
// slow line, a long frame gap) are refused: the drives are held and never set up.
// ---------------------------------------------------------------------------------------

/// The accepted settings at their edges: the shortest and the longest drives' timeout,
/// each with the slowest line, the longest reply timeout and frame gap and the most
/// failures before a loss; and the fastest line with the longest timeout.
fn edge_settings() -> Vec<(&'static str, DriveSettings)> {
    let slowest = |timeout_ms: u16| {
        let mut settings = DriveSettings::DEFAULT;
        settings.drive_comm_timeout_ms = timeout_ms;
        settings.line.baud = settings::MIN_BAUD;
        settings.line.min_silent_interval_us = settings::MAX_MIN_SILENT_INTERVAL_US;
        settings.reply_timeout_ms = *settings::REPLY_TIMEOUT_MS.end();
        settings.failures_before_loss = *settings::FAILURES_BEFORE_LOSS.end();
        settings
    };
    let mut fastest = DriveSettings::DEFAULT;
    fastest.drive_comm_timeout_ms = *settings::COMM_TIMEOUT_MS.end();
    fastest.line.baud = 230_400;
    vec![
        ("the defaults", DriveSettings::DEFAULT),
        (
            "shortest timeout, slowest line",
            slowest(*settings::COMM_TIMEOUT_MS.start()),
        ),
        (
            "longest timeout, slowest line",
            slowest(*settings::COMM_TIMEOUT_MS.end()),
        ),
        ("longest timeout, 230400 baud", fastest),
    ]
}

/// A robot whose controller uses `settings` and whose drives talk at their baud rate.
fn robot_with(settings: DriveSettings) -> VirtualRobot {
    let mut robot = VirtualRobot::with_drives(DrivesConfig {
        baud: settings.line.baud,
        ..DrivesConfig::commissioned()
    });
    robot.settings.drives = settings;
    robot
}

/// What stops the base after a line fault.
#[derive(Debug, Clone, Copy)]
enum Stop {
    /// Nobody: the PC keeps asking for 500 mm/s; only the link can tell.
    None,
    Pc,
    Estop,
}

/// Drives at 500 mm/s, causes `fault`, then `stop`; returns the farthest either
/// wheel rolled from the fault on, after checking that both stand 3 s later and
/// stay standing.
fn run_on_mm_after(robot: &VirtualRobot, fault: &dyn Fn(&VirtualRobot), stop: Stop) -> f64 {
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 2_000).await;
        let before = revolutions(robot);
        fault(robot);
        let speed = match stop {
            Stop::None => 500,
            Stop::Pc => 0,
            Stop::Estop => {
                robot.press_estop();
                500
            }
        };
        pc.drive(speed, 0, 3_000).await;
        let run_on = run_on_mm(robot, before);
        for slave in [1, 2] {
            let rpm = robot.drives.drive(slave).speed_rpm;
            assert_eq!(rpm, 0.0, "drive {slave} still turns after {run_on:.0} mm");
        }
        pc.drive(speed, 0, 3_000).await;
        let later = run_on_mm(robot, before);
        assert!(
            later - run_on < 1.0,
            "rolled on: {run_on:.0} → {later:.0} mm"
        );
        run_on
    })
}

/// A line that fails every request longer than N bytes, for N from "everything" to
/// "only the command write": the reads (8 bytes) pass from N = 8 on, so the link sees
/// nothing wrong until the stop has to go out. Then the faults that break the
/// feedback (replies lost or garbled, a busy drive, silent drives), where the link
/// has to stop the base while the PC still asks for 500 mm/s.
#[test]
fn every_line_fault_stops_the_base_within_300_mm_at_the_edges_of_the_accepted_settings() {
    type Fault = Box<dyn Fn(&VirtualRobot)>;
    let mut faults: Vec<(String, Fault, &[Stop])> = Vec::new();
    for max_len in [7, 8, 12, 13, 17, 25, 29, 37, 40] {
        faults.push((
            format!("requests over {max_len} bytes fail"),
            Box::new(move |robot| robot.drives.fail_requests_longer_than(Some(max_len))),
            &[Stop::Pc, Stop::Estop],
        ));
    }
    let every: &[Stop] = &[Stop::None, Stop::Pc, Stop::Estop];
    faults.push((
        "replies lost".into(),
        Box::new(|robot| robot.drives.lose_replies(true)),
        every,
    ));
    faults.push((
        "every reply garbled".into(),
        Box::new(|robot| {
            robot.drives.garble_replies_of(1, true);
            robot.drives.garble_replies_of(2, true);
        }),
        every,
    ));
    faults.push((
        "the right drive's replies garbled".into(),
        Box::new(|robot| robot.drives.garble_replies_of(2, true)),
        every,
    ));
    faults.push((
        "the left drive busy".into(),
        Box::new(|robot| robot.drives.set_busy(1, true)),
        every,
    ));
    faults.push((
        "the right drive cut off".into(),
        Box::new(|robot| robot.drives.set_silent(2, true)),
        every,
    ));
    faults.push((
        "both drives cut off".into(),
        Box::new(|robot| {
            robot.drives.set_silent(1, true);
            robot.drives.set_silent(2, true);
        }),
        every,
    ));
    for (name, settings) in edge_settings() {
        assert_eq!(settings.check(), Ok(()), "{name}");
        let mut worst = (0.0, String::new());
        for (fault, cause, stops) in &faults {
            for &stop in *stops {
                let run_on = run_on_mm_after(&robot_with(settings), cause.as_ref(), stop);
                if run_on > worst.0 {
                    worst = (run_on, format!("{fault}, stop {stop:?}"));
                }
            }
        }
        assert!(worst.0 <= 300.0, "{name}: {:.0} mm ({})", worst.0, worst.1);
    }
}

/// Settings with which a line fault could keep the base from stopping are refused:
/// the drives are held, stopped and de-excited, and never set up; the base stays in
/// Starting and does not move, whatever the PC asks. Before, with the drives' timeout
/// off, a line that failed requests over 12 bytes let the base roll on for 2,498 mm
/// after the PC's stop (and for ever).
#[test]
fn drive_settings_that_could_keep_the_base_from_stopping_keep_it_from_driving() {
    let mut off = DriveSettings::DEFAULT;
    off.drive_comm_timeout_ms = 0;
    let mut slow = DriveSettings::DEFAULT;
    slow.line.baud = 19_200;
    for (name, settings) in [("timeout off", off), ("19200 baud", slow)] {
        assert!(settings.check().is_err(), "{name}");
        let robot = robot_with(settings);
        robot.run(async |pc| {
            wait_ms(BOOT_MS).await;
            let before = revolutions(&robot);
            pc.drive(500, 0, 3_000).await;
            assert!(run_on_mm(&robot, before) < 1.0, "{name}: the base moved");
            for slave in [1, 2] {
                let drive = robot.drives.drive(slave);
                assert!(!drive.servo_on, "{name}: drive {slave} excited");
                assert!(!drive.share.is_member(), "{name}: drive {slave} set up");
            }
            let status = pc.status().expect("status");
            assert_eq!(status.mode, Mode::Starting, "{name}");
        });
    }
}

// ---------------------------------------------------------------------------------------
// Nothing goes to the flash and no brake is reported applied while a wheel may still
// turn (issue 21, case 6): a silent drive counts as turning until its own
// communication timeout has certainly tripped.
// ---------------------------------------------------------------------------------------

/// Flash operations and status frames seen while some wheel still turned or was
/// excited.
#[derive(Debug, Default)]
struct WhileTurning {
    flash_operations: u64,
    brakes_reported_applied: usize,
}

fn flash_operations(robot: &VirtualRobot) -> u64 {
    let stats = robot.flash.stats();
    stats.writes + stats.erases
}

/// A wheel turns, or its drive is excited (S-ON and no alarm: an alarm de-excites it
/// and closes its brake whatever the S-ON input says).
fn some_wheel_may_turn(robot: &VirtualRobot) -> bool {
    [1, 2].into_iter().any(|slave| {
        let drive = robot.drives.drive(slave);
        drive.speed_rpm != 0.0 || (drive.servo_on && drive.alarm == 0)
    })
}

/// Drives at 500 mm/s, cuts the right drive from the line and, for `watch_ms`, keeps
/// a register write pending (`disable_time`, changed every 20 ms) while the PC goes on
/// driving; counts what happened while a wheel turned.
async fn watch_a_silent_drive(
    robot: &VirtualRobot,
    pc: &virtual_robot::robot::Pc,
    watch_ms: u64,
) -> WhileTurning {
    wait_ms(BOOT_MS).await;
    pc.drive(500, 0, 2_000).await;
    robot.drives.set_silent(2, true);
    let mut seen = WhileTurning::default();
    let mut last_status = Instant::now();
    let mut operations = flash_operations(robot);
    let mut turning = some_wheel_may_turn(robot);
    for step in 0..watch_ms / 10 {
        pc.enable();
        pc.velocity(500, 0);
        if step % 2 == 0 {
            pc.command(base_core::can::Command::RegisterWrite {
                address: 11,
                value: 300 + (step / 2 % 2) as u16,
            });
        }
        wait_ms(10).await;
        let turning_now = some_wheel_may_turn(robot);
        let operations_now = flash_operations(robot);
        if turning || turning_now {
            seen.flash_operations += operations_now - operations;
            seen.brakes_reported_applied += pc
                .reports(base_core::can::id::STATUS)
                .into_iter()
                .filter(|(at, report)| {
                    *at > last_status
                        && matches!(report, base_core::can::Report::Status(status)
                            if status.flags.brakes_applied)
                })
                .count();
        }
        last_status = Instant::now();
        operations = operations_now;
        turning = turning_now;
    }
    seen
}

#[test]
fn no_flash_write_and_no_brake_reported_while_a_silent_drive_may_turn() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        let seen = watch_a_silent_drive(&robot, pc, 3_000).await;
        assert_eq!(seen.flash_operations, 0, "{seen:?}");
        assert_eq!(seen.brakes_reported_applied, 0, "{seen:?}");
        // The silent drive's own timeout stopped it: the values reach the flash.
        assert_eq!(robot.drives.drive(2).alarm, 0x85);
        let status = next_status(pc, 1_500, |status| !status.persist_pending).await;
        assert!(status.is_some(), "persisted once both wheels surely stand");
    });
}
