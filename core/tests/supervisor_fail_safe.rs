//! The supervisor's part of the fail-safe drive link: every drive fault latches, and
//! after an e-stop or a drive fault the drives are de-excited once `estop_decel` had
//! time to stop them, so the status frame's `brakes_applied` is what was commanded.

use base_core::can::Mode;
use base_core::kinematics::{SafetyLimits, Twist};
use base_core::supervisor::{Event, Params, STOPPED_AFTER_MS, Supervisor, Wheel};
use base_core::time::Timestamp;

const PARAMS: Params = Params {
    enable_timeout_ms: 500,
    cmd_timeout_ms: 0,
    disable_time_ms: 300,
    can_accel: 700,
    remote_accel: 350,
    remote_release_accel: 500,
    estop_decel: 4500,
    stop_decel: 2000,
    safety_limits: SafetyLimits {
        linear_mm_s: 200,
        rotation_mrad_s: 100,
    },
};

fn at(ms: u64) -> Timestamp {
    Timestamp::from_millis(ms)
}

/// Drives ready, CAN enabled and driving forward since 0 ms.
fn driving() -> Supervisor {
    let mut supervisor = Supervisor::new();
    supervisor.step(at(0), Event::Estop { pressed: false }, &PARAMS);
    supervisor.step(at(0), Event::SafetyZone { occupied: false }, &PARAMS);
    supervisor.step(at(0), Event::DrivesReady, &PARAMS);
    supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
    let effects = supervisor.step(
        at(0),
        Event::CanVelocity(Twist {
            linear_mm_s: 500,
            rotation_mrad_s: 0,
        }),
        &PARAMS,
    );
    assert_eq!(effects.excite, Some(true));
    supervisor.step(at(0), Event::AtRest(false), &PARAMS);
    assert!(!supervisor.brakes_applied());
    supervisor
}

#[test]
fn a_second_drive_fault_during_fault_is_latched_too() {
    let mut supervisor = driving();
    supervisor.step(at(10), Event::DriveSilent(Wheel::Left), &PARAMS);
    assert_eq!(supervisor.mode(), Mode::Fault);
    supervisor.step(at(20), Event::DriveSilent(Wheel::Right), &PARAMS);
    supervisor.step(
        at(30),
        Event::DriveAlarm {
            wheel: Wheel::Right,
            code: 0x85,
        },
        &PARAMS,
    );
    let faults = supervisor.faults();
    assert!(faults.left_silent && faults.right_silent && faults.right_alarm);
    assert_eq!(faults.last_alarm_code, 0x85);
}

#[test]
fn an_estop_de_excites_the_drives_once_estop_decel_had_its_time() {
    let mut supervisor = driving();
    supervisor.step(at(100), Event::Estop { pressed: true }, &PARAMS);
    // Still braking on the drive's ramp: no S-OFF at speed, and the status says so.
    let effects = supervisor.step(at(100 + STOPPED_AFTER_MS - 10), Event::Tick, &PARAMS);
    assert_eq!(effects.excite, None);
    assert!(!supervisor.brakes_applied());
    let effects = supervisor.step(at(100 + STOPPED_AFTER_MS), Event::Tick, &PARAMS);
    assert_eq!(effects.excite, Some(false));
    assert!(supervisor.brakes_applied());
}

#[test]
fn a_drive_fault_de_excites_the_answering_drive_without_feedback() {
    let mut supervisor = driving();
    supervisor.step(at(100), Event::DriveSilent(Wheel::Right), &PARAMS);
    // No feedback comes while the link holds the drives: the time decides.
    let effects = supervisor.step(at(100 + STOPPED_AFTER_MS), Event::Tick, &PARAMS);
    assert_eq!(effects.excite, Some(false));
    assert!(supervisor.brakes_applied());
}

/// Found by the whole-robot tester (`confirm-during-a-fault-stop-seed-61-rule-4`): a
/// confirm press while a stop still braked set the drives up at once, and the setup's
/// S-OFF closed the brake of a wheel still turning at 24 r/min. A press during the stop
/// is ignored; one after it recovers, the drives already de-excited.
#[test]
fn a_confirm_press_counts_only_once_the_stop_has_ended() {
    for fault in [
        Event::Estop { pressed: true },
        Event::DriveSilent(Wheel::Right),
    ] {
        let mut supervisor = driving();
        supervisor.step(at(100), fault, &PARAMS);
        supervisor.step(at(150), Event::Estop { pressed: false }, &PARAMS);
        let effects = supervisor.step(at(200), Event::ConfirmPressed, &PARAMS);
        assert!(
            !effects.setup_drives,
            "{fault:?}: confirmed during the stop"
        );
        assert_eq!(effects.excite, None, "{fault:?}: S-OFF while braking");
        assert!(!supervisor.brakes_applied());
        // The stop's time ends at the press itself: the drives are de-excited first.
        let effects = supervisor.step(at(100 + STOPPED_AFTER_MS), Event::ConfirmPressed, &PARAMS);
        assert!(effects.setup_drives, "{fault:?}");
        assert_eq!(effects.excite, Some(false), "{fault:?}");
        assert!(supervisor.brakes_applied());
        supervisor.step(at(1_000), Event::DrivesReady, &PARAMS);
        assert!(supervisor.brakes_applied());
    }
}
