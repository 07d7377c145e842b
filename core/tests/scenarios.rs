//! Safety and behaviour scenarios as data: each row is (time in ms, input) → the checks
//! on what that one input produced and on the state after it. The controller runs with
//! the manual's default registers and gear_ratio 10, motor_dir 2 (right motor mirrored),
//! so 500 mm/s is 336 motor r/min: +336 on the left drive, −336 on the right.

use base_core::calibration::{OdometryCalibrationCommand, ScaleCalibrationCommand};
use base_core::can::{Command, ControlSource, FrameError, Mode, RawFrame, ReadEcho, Report, id};
use base_core::controller::{Controller, Input, Output};
use base_core::gamepad::{Buttons, Dpad, GamepadState};
use base_core::kinematics::MotorRpm;
use base_core::odometry::EncoderCounts;
use base_core::power::SwitchLevel;
use base_core::registers::{Reg, Registers};
use base_core::remote::Pad;
use base_core::supervisor::Wheel;
use base_core::time::Timestamp;

/// What one row expects.
#[derive(Debug, Clone, Copy)]
enum Check {
    /// A wheel command with these motor r/min and per-wheel accelerations.
    Wheels {
        left: i32,
        right: i32,
        left_accel: u32,
        right_accel: u32,
    },
    /// A zero-speed command whose accelerations are at most `accel` (the wheel with the
    /// bigger change gets exactly `accel`).
    Stop {
        accel: u32,
    },
    NoWheels,
    Excite(bool),
    NoExcite,
    SetupDrives,
    NoSetupDrives,
    Mode(Mode),
    Control(ControlSource),
    PcSwitch(SwitchLevel),
    NoPcSwitch,
    /// None of 0x0EA..0x0ED in this output.
    NoFeedback,
    /// This output carries the frame.
    Sends(Report),
    Persists(Reg, u16),
    NothingPersisted,
    Register(Reg, u16),
    /// The status frame's last rejection code and subject.
    Rejected {
        code: u8,
        subject: u8,
    },
    RejectedCount(u8),
    Pose {
        x_mm: i32,
        y_mm: i32,
        heading_mrad: i32,
    },
    PcOn(bool),
    /// The output asks the BLE task to disconnect the gamepad.
    Disconnect,
    NoDisconnect,
    /// The output says the pairing window opened (`true`) or closed (`false`).
    PairingWindow(bool),
    NoPairingChange,
}

use Check::*;

type Row<'a> = (u64, Input, &'a [Check]);

fn can(command: Command) -> Input {
    Input::CanFrame(command.encode())
}

fn raw(id: u16, data: &[u8]) -> Input {
    Input::CanFrame(RawFrame::new(id, data).expect("test frame fits CAN"))
}

fn enable() -> Input {
    can(Command::Enable { refresh: true })
}

fn velocity(linear_mm_s: i16, rotation_mrad_s: i16) -> Input {
    can(Command::Velocity {
        linear_mm_s,
        rotation_mrad_s,
    })
}

/// The BLE task reports the bonded gamepad connected, or its link down.
fn pad_link(connected: bool) -> Input {
    Input::RemoteLink {
        pad: Pad::Ble,
        bonded: true,
        connected,
    }
}

fn pad(state: GamepadState) -> Input {
    Input::Gamepad {
        pad: Pad::Ble,
        state,
    }
}

/// A gamepad report with these buttons held and the sticks and triggers at rest.
fn buttons(buttons: Buttons) -> Input {
    pad(GamepadState {
        buttons,
        ..GamepadState::default()
    })
}

/// The same with L2 pulled fully.
fn l2_and(buttons: Buttons) -> Input {
    pad(GamepadState {
        buttons,
        left_trigger: 1.0,
        ..GamepadState::default()
    })
}

/// The dead-man (RB) held, the left stick at `forward` and the right stick at `right`
/// (−1 … 1; + is forward and right).
fn dead_man(forward: f32, right: f32) -> Input {
    pad(held(forward, right))
}

fn held(forward: f32, right: f32) -> GamepadState {
    GamepadState {
        left_y: forward,
        right_x: right,
        buttons: Buttons::RIGHT_BUMPER,
        ..GamepadState::default()
    }
}

/// The dead-man held at full stick forward with the D-pad pressed up or down.
fn level_press(up: bool) -> Input {
    pad(GamepadState {
        dpad: Dpad {
            up,
            down: !up,
            ..Dpad::default()
        },
        ..held(1.0, 0.0)
    })
}

/// Drive feedback with both wheels turning at `rpm` (as measured, any sign).
///
/// The counters are an honest drive's: [`run`] replaces [`HONEST_COUNTERS`] with the
/// position the speeds reported so far add up to, so the feedback plausibility check
/// sees drives whose counters and speeds agree.
fn moving(rpm: i32) -> Input {
    Input::DriveFeedback {
        counts: HONEST_COUNTERS,
        rpm: MotorRpm {
            left: rpm,
            right: -rpm,
        },
    }
}

fn counts(left: i32, right: i32) -> Input {
    Input::DriveFeedback {
        counts: EncoderCounts { left, right },
        rpm: MotorRpm { left: 0, right: 0 },
    }
}

fn odometry_calibration(step: OdometryCalibrationCommand) -> Input {
    can(Command::OdometryCalibration(step))
}

fn scale_calibration(step: ScaleCalibrationCommand) -> Input {
    can(Command::ScaleCalibration(step))
}

fn defaults() -> Registers {
    Registers::defaults()
}

/// Defaults with all three odometry correction factors at 1.0, so poses are exact.
fn uncorrected() -> Registers {
    let mut registers = Registers::defaults();
    for reg in [Reg::FCw, Reg::FCcw, Reg::FLin] {
        registers
            .write(reg.address(), 10_000)
            .expect("1.0 is a valid factor");
    }
    registers
}

fn is_feedback(frame: &RawFrame) -> bool {
    matches!(
        frame.id(),
        id::WEIGHT | id::BATTERY | id::POSITION | id::HEADING | id::POSE_TIME | id::MEASURED_SPEED
    )
}

fn check(controller: &Controller, now: Timestamp, out: &Output, check: Check, row: usize) {
    let status = controller.status(now);
    match check {
        Wheels {
            left,
            right,
            left_accel,
            right_accel,
        } => {
            let wheels = out
                .wheels
                .unwrap_or_else(|| panic!("row {row}: no wheel command"));
            assert_eq!(
                (
                    wheels.rpm.left,
                    wheels.rpm.right,
                    wheels.left_accel,
                    wheels.right_accel
                ),
                (left, right, left_accel, right_accel),
                "row {row}: wheel command"
            );
        }
        Stop { accel } => {
            let wheels = out
                .wheels
                .unwrap_or_else(|| panic!("row {row}: no stop command"));
            assert_eq!(
                wheels.rpm,
                MotorRpm { left: 0, right: 0 },
                "row {row}: not a stop"
            );
            assert_eq!(
                wheels.left_accel.max(wheels.right_accel),
                accel,
                "row {row}: stop acceleration"
            );
        }
        NoWheels => assert_eq!(out.wheels, None, "row {row}: unexpected wheel command"),
        Excite(level) => assert_eq!(out.excite, Some(level), "row {row}: excitation"),
        NoExcite => assert_eq!(out.excite, None, "row {row}: unexpected excitation change"),
        SetupDrives => assert!(out.setup_drives, "row {row}: drive setup not requested"),
        NoSetupDrives => assert!(!out.setup_drives, "row {row}: unexpected drive setup"),
        Mode(mode) => assert_eq!(status.mode, mode, "row {row}: mode"),
        Control(source) => assert_eq!(status.control, source, "row {row}: control source"),
        PcSwitch(level) => assert_eq!(out.pc_switch, Some(level), "row {row}: PC switch"),
        NoPcSwitch => assert_eq!(out.pc_switch, None, "row {row}: unexpected PC switch"),
        NoFeedback => assert!(
            !out.frames.iter().any(is_feedback),
            "row {row}: feedback frame sent: {:?}",
            out.frames
        ),
        Sends(report) => assert!(
            out.frames.contains(&report.encode()),
            "row {row}: {report:?} not in {:?}",
            out.frames
        ),
        Persists(reg, value) => assert!(
            out.persist.changed.contains(&(reg.address(), value)),
            "row {row}: {reg:?} = {value} not persisted: {:?}",
            out.persist
        ),
        NothingPersisted => assert!(
            out.persist.changed.is_empty() && !out.persist.defaults_restored,
            "row {row}: unexpected persist {:?}",
            out.persist
        ),
        Register(reg, value) => {
            assert_eq!(controller.registers().get(reg), value, "row {row}: {reg:?}")
        }
        Rejected { code, subject } => assert_eq!(
            (status.last_rejection, status.last_rejection_subject),
            (code, subject),
            "row {row}: last rejection"
        ),
        RejectedCount(count) => {
            assert_eq!(status.rejected_count, count, "row {row}: rejected count")
        }
        Pose {
            x_mm,
            y_mm,
            heading_mrad,
        } => {
            let pose = controller.odometry().pose();
            assert_eq!(
                (pose.x_mm, pose.y_mm, pose.heading_mrad),
                (x_mm, y_mm, heading_mrad),
                "row {row}: pose"
            );
        }
        PcOn(on) => assert_eq!(status.flags.pc_on, on, "row {row}: PC on"),
        Disconnect => assert_eq!(
            out.disconnect_remote,
            Some(Pad::Ble),
            "row {row}: no disconnect request"
        ),
        NoDisconnect => assert_eq!(
            out.disconnect_remote, None,
            "row {row}: unexpected disconnect"
        ),
        PairingWindow(open) => {
            assert_eq!(out.pairing_window, Some(open), "row {row}: pairing window")
        }
        NoPairingChange => assert_eq!(out.pairing_window, None, "row {row}: pairing window"),
    }
}

/// Runs the rows in order on a controller whose drives became ready at t = 0.
/// Stands for the counters of drives that report their speeds honestly (see
/// [`moving`]); never a value a row means literally.
const HONEST_COUNTERS: EncoderCounts = EncoderCounts {
    left: i32::MIN,
    right: i32::MIN,
};

/// The counters of honest drives: the trapezoid of the reported speeds over time.
#[derive(Default)]
struct HonestDrives {
    counts: [f64; 2],
    last: Option<(u64, [i32; 2])>,
}

impl HonestDrives {
    /// Replaces [`HONEST_COUNTERS`] in a feedback row; every feedback row moves the
    /// counters along its speeds, and a setup from scratch restarts them at zero.
    fn feed(&mut self, ms: u64, input: Input) -> Input {
        match input {
            Input::DriveFeedback { counts, rpm } => {
                let speeds = [rpm.left, rpm.right];
                if let Some((last_ms, last)) = self.last {
                    for (count, (from, to)) in
                        self.counts.iter_mut().zip(last.into_iter().zip(speeds))
                    {
                        let mean_rpm = (f64::from(from) + f64::from(to)) / 2.0;
                        *count += mean_rpm * (ms - last_ms) as f64 * 36_000.0 / 60_000.0;
                    }
                }
                self.last = Some((ms, speeds));
                let counts = if counts == HONEST_COUNTERS {
                    EncoderCounts {
                        left: self.counts[0].round() as i32,
                        right: self.counts[1].round() as i32,
                    }
                } else {
                    counts
                };
                Input::DriveFeedback { counts, rpm }
            }
            Input::DrivesReady => {
                *self = HonestDrives::default();
                input
            }
            _ => input,
        }
    }
}

fn run(registers: Registers, rows: &[Row]) -> Controller {
    let mut controller = Controller::new(Timestamp::BOOT, registers);
    // The setup's S-OFF was answered; so is every later S-ON and S-OFF, at once.
    controller.set_drive_brakes_confirmed(true);
    controller.handle(Timestamp::BOOT, Input::Estop(false));
    controller.handle(Timestamp::BOOT, Input::SafetyZone(false));
    controller.handle(Timestamp::BOOT, Input::DrivesReady);
    let mut drives = HonestDrives::default();
    for (index, (ms, input, checks)) in rows.iter().enumerate() {
        let now = Timestamp::from_millis(*ms);
        let out = controller.handle(now, drives.feed(*ms, *input));
        if let Some(excite) = out.excite {
            controller.set_drive_brakes_confirmed(!excite);
        }
        for check in checks.iter() {
            self::check(&controller, now, &out, *check, index);
        }
    }
    controller
}

const FORWARD_500: Check = Wheels {
    left: 336,
    right: -336,
    left_accel: 700,
    right_accel: 700,
};

#[test]
fn velocity_frame_without_enable_does_nothing() {
    run(
        defaults(),
        &[
            (0, Input::Tick, &[Mode(Mode::Standby)]),
            (
                10,
                velocity(500, 0),
                &[NoWheels, NoExcite, Control(ControlSource::None)],
            ),
            // The enable alone does not replay the velocity that arrived without it.
            (20, enable(), &[NoWheels, NoExcite]),
            (
                30,
                velocity(500, 0),
                &[FORWARD_500, Excite(true), Mode(Mode::Active)],
            ),
        ],
    );
}

#[test]
fn enable_lapse_brakes_and_closes_the_brakes_after_disable_time() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (
                0,
                velocity(500, 0),
                &[FORWARD_500, Excite(true), Control(ControlSource::Can)],
            ),
            (100, moving(336), &[NoWheels]),
            // enable_timeout is 500 ms: fresh at 499, lapsed at 500.
            (499, Input::Tick, &[NoWheels]),
            (
                500,
                Input::Tick,
                &[
                    Stop { accel: STOP_DECEL },
                    NoExcite,
                    Control(ControlSource::None),
                ],
            ),
            (600, moving(150), &[NoExcite]),
            (980, moving(0), &[NoExcite, Mode(Mode::Active)]),
            // Measured standstill: the speed reads 0 and the counters stood since the
            // previous sample. disable_time is 300 ms from there.
            (1000, moving(0), &[NoExcite, Mode(Mode::Active)]),
            (1299, Input::Tick, &[NoExcite]),
            (1300, Input::Tick, &[Excite(false), Mode(Mode::Standby)]),
        ],
    );
}

#[test]
fn a_stale_command_never_resumes_after_the_enable_returns() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (500, Input::Tick, &[Stop { accel: STOP_DECEL }]),
            (600, enable(), &[NoWheels, NoExcite]),
            (650, enable(), &[NoWheels]),
            (700, Input::Tick, &[NoWheels]),
            (
                750,
                velocity(250, 0),
                &[Wheels {
                    left: 168,
                    right: -168,
                    left_accel: 700,
                    right_accel: 700,
                }],
            ),
        ],
    );
}

#[test]
fn withdrawn_enable_stops_at_once() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (
                20,
                raw(id::ENABLE, &[0, 0, 0, 0, 0, 0, 0, 0]),
                &[Stop { accel: STOP_DECEL }],
            ),
        ],
    );
}

#[test]
fn estop_while_driving_stops_at_once_and_needs_release_confirm_and_setup() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (40, moving(336), &[]),
            // At once, with estop_decel, in the output of the e-stop edge itself.
            (
                50,
                Input::Estop(true),
                &[Stop { accel: 4500 }, Mode(Mode::Emergency), NoFeedback],
            ),
            // CAN and remote are ignored, nothing is buffered.
            (60, enable(), &[NoWheels, NoFeedback]),
            (70, velocity(300, 0), &[NoWheels, NoExcite, NoFeedback]),
            (75, pad_link(true), &[NoWheels]),
            (80, buttons(Buttons::NONE), &[NoWheels]),
            (
                90,
                dead_man(1.0, 0.0),
                &[NoWheels, Control(ControlSource::None)],
            ),
            // The drives lose power: expected, not a fault.
            (
                350,
                Input::DriveSilent(Wheel::Left),
                &[Mode(Mode::Emergency), NoWheels],
            ),
            (
                350,
                Input::DriveSilent(Wheel::Right),
                &[Mode(Mode::Emergency)],
            ),
            // Feedback stays off through the whole emergency; the status frame does not.
            (
                1000,
                Input::Tick,
                &[
                    NoFeedback,
                    Sends(Report::Status(base_core::can::Status {
                        mode: Mode::Emergency,
                        control: ControlSource::None,
                        flags: base_core::can::StatusFlags {
                            remote_bonded: true,
                            remote_connected: true,
                            // Held (since 90 ms): CAN would be ignored.
                            remote_in_control: true,
                            estop_pressed: true,
                            brakes_applied: true,
                            ..Default::default()
                        },
                        ..Default::default()
                    })),
                ],
            ),
            // A confirm while the e-stop is still pressed does nothing.
            (1100, Input::Button(true), &[]),
            (
                1200,
                Input::Button(false),
                &[NoSetupDrives, Mode(Mode::Emergency)],
            ),
            (
                2000,
                Input::Estop(false),
                &[Mode(Mode::AwaitingConfirm), NoWheels],
            ),
            (2050, Input::Tick, &[NoFeedback]),
            (2100, enable(), &[]),
            (2110, velocity(300, 0), &[NoWheels]),
            (2200, Input::Button(true), &[]),
            (
                2300,
                Input::Button(false),
                &[SetupDrives, Mode(Mode::Recovering)],
            ),
            // Recovering: back to normal mode (feedback flows) but nothing moves yet.
            (2310, enable(), &[NoWheels]),
            (2320, velocity(300, 0), &[NoWheels, NoExcite]),
            (
                2800,
                Input::DrivesReady,
                &[Mode(Mode::Standby), NoWheels, NoExcite],
            ),
            // The dead-man held since 90 ms keeps control from CAN (it does not drive:
            // not armed) until it is released, and then CAN waits for a feedback that
            // measures the wheels at rest.
            (2805, enable(), &[]),
            (
                2805,
                velocity(500, 0),
                &[NoWheels, Control(ControlSource::Remote)],
            ),
            (2806, buttons(Buttons::NONE), &[NoWheels]),
            (2807, moving(0), &[NoWheels]),
            // The command sent during the recovery is not replayed.
            (2810, enable(), &[NoWheels]),
            (
                2820,
                velocity(500, 0),
                &[FORWARD_500, Excite(true), Mode(Mode::Active)],
            ),
        ],
    );
}

#[test]
fn remote_dead_man_overrides_can_and_its_release_brakes_with_at_least_stop_decel() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (
                0,
                velocity(500, 0),
                &[FORWARD_500, Control(ControlSource::Can)],
            ),
            (5, pad_link(true), &[NoWheels, Control(ControlSource::Can)]),
            (
                10,
                buttons(Buttons::NONE),
                &[NoWheels, Control(ControlSource::Can)],
            ),
            // Dead-man held: the remote takes over with Contr_acc_norm (full stick is
            // the speed level PS_rel_max_vel, 250 mm/s).
            (
                20,
                dead_man(1.0, 0.0),
                &[
                    Wheels {
                        left: 168,
                        right: -168,
                        left_accel: 350,
                        right_accel: 350,
                    },
                    Control(ControlSource::Remote),
                ],
            ),
            (30, enable(), &[NoWheels]),
            (
                40,
                velocity(500, 0),
                &[NoWheels, Control(ControlSource::Remote)],
            ),
            // Released: brake with Contr_acc_high (500), at least stop_decel; the CAN
            // command was dropped on takeover.
            (
                50,
                buttons(Buttons::NONE),
                &[Stop { accel: STOP_DECEL }, Control(ControlSource::None)],
            ),
            (60, enable(), &[NoWheels]),
            // No feedback since: the wheels are not known to stand, CAN waits.
            (70, velocity(500, 0), &[NoWheels]),
            (100, moving(0), &[NoWheels]),
            (
                110,
                velocity(500, 0),
                &[FORWARD_500, Control(ControlSource::Can)],
            ),
        ],
    );
}

#[test]
fn remote_link_loss_while_driving_brakes_with_at_least_stop_decel() {
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, dead_man(1.0, 0.0), &[Control(ControlSource::Remote)]),
            (
                20,
                pad_link(false),
                &[Stop { accel: STOP_DECEL }, Control(ControlSource::None)],
            ),
            // Back with the dead-man still held: it must be seen released before it
            // drives, but it has control.
            (30, pad_link(true), &[NoWheels]),
            (
                40,
                dead_man(1.0, 0.0),
                &[NoWheels, Control(ControlSource::Remote)],
            ),
        ],
    );
}

/// Full stick forward under remote control at a speed level of `mm_s`, both wheels
/// ramping with Contr_acc_norm.
fn remote_forward(mm_s: u16) -> Check {
    // The motor r/min of the speed levels at r = 142 mm, gear ratio 10.
    let rpm = match mm_s {
        50 => 34,
        100 => 67,
        150 => 101,
        200 => 134,
        250 => 168,
        300 => 202,
        350 => 235,
        400 => 269,
        _ => panic!("no r/min worked out for {mm_s} mm/s"),
    };
    Wheels {
        left: rpm,
        right: -rpm,
        left_accel: 350,
        right_accel: 350,
    }
}

#[test]
fn dead_man_drives_with_contr_acc_norm_and_its_release_brakes_then_closes_the_brakes() {
    run(
        defaults(),
        &[
            (0, pad_link(true), &[NoWheels, Control(ControlSource::None)]),
            // Sticks without the dead-man do nothing.
            (
                10,
                pad(GamepadState {
                    buttons: Buttons::NONE,
                    ..held(1.0, 1.0)
                }),
                &[NoWheels],
            ),
            (
                20,
                dead_man(1.0, 0.0),
                &[
                    remote_forward(250),
                    Excite(true),
                    Control(ControlSource::Remote),
                ],
            ),
            // Right stick right turns clockwise on the spot (docs/behaviour.md: + clockwise):
            // the left wheel forward, the right one backward (its motor is mirrored, so
            // both motors turn positive), each at the level's 250 mm/s. 10 ms into the
            // ramp the wheels run (+4, −4): the left changes by 164, the right by 172,
            // so the left gets 350 · 164 / 172 = 334.
            (
                30,
                dead_man(0.0, 1.0),
                &[Wheels {
                    left: 168,
                    right: 168,
                    left_accel: 334,
                    right_accel: 350,
                }],
            ),
            (40, moving(168), &[NoWheels]),
            (
                50,
                buttons(Buttons::NONE),
                &[
                    Stop { accel: STOP_DECEL },
                    Control(ControlSource::None),
                    NoExcite,
                ],
            ),
            // disable_time (300 ms) from the measured standstill, as under CAN: the
            // speed reads 0 at 60 ms, the counters stood between 60 and 70 ms.
            (60, moving(0), &[NoExcite]),
            (70, moving(0), &[NoExcite]),
            (369, Input::Tick, &[NoExcite]),
            (370, Input::Tick, &[Excite(false), Mode(Mode::Standby)]),
        ],
    );
}

#[test]
fn gamepad_reports_drive_only_from_a_connected_pad_seen_released_first() {
    run(
        defaults(),
        &[
            // The BLE task has not reported a connection: reports are dropped.
            (0, buttons(Buttons::NONE), &[NoWheels]),
            (
                10,
                dead_man(1.0, 0.0),
                &[NoWheels, Control(ControlSource::None)],
            ),
            // Connected with the dead-man already down: not a press, no driving; but
            // held, it has control (CAN is ignored).
            (20, pad_link(true), &[NoWheels]),
            (
                30,
                dead_man(1.0, 0.0),
                &[NoWheels, Control(ControlSource::Remote)],
            ),
            (40, buttons(Buttons::NONE), &[NoWheels]),
            (50, dead_man(1.0, 0.0), &[remote_forward(250)]),
        ],
    );
}

#[test]
fn dpad_steps_the_speed_level_within_its_limits_and_each_connection_starts_over() {
    let mut registers = defaults();
    registers
        .write(Reg::PsAbsMaxVel.address(), 400)
        .expect("400 mm/s is a valid PS_abs_max_vel");
    let rows: &[Row] = &[
        (0, pad_link(true), &[]),
        (0, buttons(Buttons::NONE), &[]),
        // PS_rel_max_vel (250 mm/s) after the connection.
        (10, dead_man(1.0, 0.0), &[remote_forward(250)]),
        // Each press is one step of 50 mm/s; holding the D-pad is no second press.
        (20, level_press(true), &[remote_forward(300)]),
        (30, dead_man(1.0, 0.0), &[NoWheels]),
        (40, level_press(true), &[remote_forward(350)]),
        (50, dead_man(1.0, 0.0), &[]),
        (60, level_press(true), &[remote_forward(400)]),
        (70, dead_man(1.0, 0.0), &[]),
        // PS_abs_max_vel is the top.
        (80, level_press(true), &[NoWheels]),
        (90, dead_man(1.0, 0.0), &[]),
        (100, level_press(false), &[remote_forward(350)]),
        (110, dead_man(1.0, 0.0), &[]),
        (120, level_press(false), &[remote_forward(300)]),
        (130, dead_man(1.0, 0.0), &[]),
        (140, level_press(false), &[remote_forward(250)]),
        (150, dead_man(1.0, 0.0), &[]),
        (160, level_press(false), &[remote_forward(200)]),
        (170, dead_man(1.0, 0.0), &[]),
        (180, level_press(false), &[remote_forward(150)]),
        (190, dead_man(1.0, 0.0), &[]),
        (200, level_press(false), &[remote_forward(100)]),
        (210, dead_man(1.0, 0.0), &[]),
        (220, level_press(false), &[remote_forward(50)]),
        (230, dead_man(1.0, 0.0), &[]),
        // 50 mm/s is the bottom.
        (240, level_press(false), &[NoWheels]),
        (250, dead_man(1.0, 0.0), &[]),
        (260, level_press(true), &[remote_forward(100)]),
        (270, buttons(Buttons::NONE), &[Stop { accel: STOP_DECEL }]),
        // A new connection starts at PS_rel_max_vel again.
        (280, pad_link(false), &[]),
        (290, pad_link(true), &[]),
        (300, buttons(Buttons::NONE), &[]),
        (310, dead_man(1.0, 0.0), &[remote_forward(250)]),
    ];
    run(registers, rows);
}

#[test]
fn lowering_ps_abs_max_vel_below_the_level_slows_the_held_stick_at_once() {
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, level_press(true), &[remote_forward(300)]),
            (20, dead_man(1.0, 0.0), &[]),
            (30, level_press(true), &[remote_forward(350)]),
            (40, dead_man(1.0, 0.0), &[]),
            // PS_rel_max_vel must stay ≤ PS_abs_max_vel: lower it first.
            (50, raw(id::REGISTER_WRITE, &[8, 0x00, 0x64]), &[NoWheels]),
            (
                60,
                raw(id::REGISTER_WRITE, &[7, 0x01, 0x2C]),
                &[remote_forward(300), Persists(Reg::PsAbsMaxVel, 300)],
            ),
            (70, level_press(true), &[NoWheels]),
            // Raised again: the level stays where the clamp put it until a press.
            (80, raw(id::REGISTER_WRITE, &[7, 0x04, 0xB0]), &[NoWheels]),
            (90, dead_man(1.0, 0.0), &[NoWheels]),
            (100, level_press(true), &[remote_forward(350)]),
        ],
    );
}

#[test]
fn l2_with_menu_resets_the_odometry_menu_alone_does_not_also_in_an_emergency() {
    let at_1000 = Pose {
        x_mm: 1000,
        y_mm: 0,
        heading_mrad: 0,
    };
    let at_0 = Pose {
        x_mm: 0,
        y_mm: 0,
        heading_mrad: 0,
    };
    run(
        uncorrected(),
        &[
            (0, counts(0, 0), &[]),
            (1000, counts(403_491, -403_491), &[at_1000]),
            (2000, pad_link(true), &[]),
            (3000, buttons(Buttons::MENU), &[at_1000]),
            (4000, buttons(Buttons::NONE), &[]),
            (5000, l2_and(Buttons::NONE), &[at_1000]),
            (6000, l2_and(Buttons::MENU), &[at_0, NoWheels]),
            // Menu held first, then L2: no press while L2 was held.
            (7000, counts(806_982, -806_982), &[at_1000]),
            (8000, buttons(Buttons::MENU), &[]),
            (9000, l2_and(Buttons::MENU), &[at_1000]),
            // In an emergency too (docs/behaviour.md, Emergency stop).
            (10_000, Input::Estop(true), &[Mode(Mode::Emergency)]),
            (11_000, l2_and(Buttons::NONE), &[]),
            (12_000, l2_and(Buttons::MENU), &[at_0]),
        ],
    );
}

#[test]
fn l2_with_home_asks_for_the_disconnect_and_brakes_a_held_dead_man() {
    let l2_home = GamepadState {
        left_trigger: 1.0,
        buttons: Buttons::RIGHT_BUMPER.with(Buttons::HOME),
        ..held(1.0, 0.0)
    };
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, dead_man(1.0, 0.0), &[remote_forward(250)]),
            // Home alone is the pad's own button: nothing.
            (
                20,
                pad(GamepadState {
                    left_trigger: 0.0,
                    ..l2_home
                }),
                &[NoDisconnect, NoWheels],
            ),
            (30, dead_man(1.0, 0.0), &[]),
            (
                40,
                pad(GamepadState {
                    buttons: Buttons::RIGHT_BUMPER,
                    ..l2_home
                }),
                &[NoDisconnect],
            ),
            (
                50,
                pad(l2_home),
                &[
                    Disconnect,
                    Stop { accel: STOP_DECEL },
                    Control(ControlSource::None),
                ],
            ),
            // The pad keeps reporting until the BLE task drops it: nothing drives and
            // the request is repeated.
            (60, buttons(Buttons::NONE), &[Disconnect, NoWheels]),
            (70, dead_man(1.0, 0.0), &[Disconnect, NoWheels]),
            (80, pad_link(false), &[NoDisconnect]),
        ],
    );
}

#[test]
fn no_input_for_ps_afk_time_switches_the_pad_off_and_not_before() {
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (1_000, buttons(Buttons::A), &[NoDisconnect]),
            (2_000, Input::Tick, &[NoDisconnect]),
            // PS_afk_time is 30 s from the last report.
            (30_999, Input::Tick, &[NoDisconnect]),
            (31_000, Input::Tick, &[Disconnect]),
            (31_010, Input::Tick, &[NoDisconnect]),
            (31_020, dead_man(1.0, 0.0), &[Disconnect, NoWheels]),
            (31_100, pad_link(false), &[NoDisconnect]),
            // Connected again: the time counts from the connection.
            (40_000, pad_link(true), &[]),
            (69_999, Input::Tick, &[NoDisconnect]),
            (70_000, Input::Tick, &[Disconnect]),
        ],
    );
}

#[test]
fn a_held_dead_man_counts_as_input_so_a_long_straight_drive_is_not_cut_off() {
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            // Full stick ahead for two minutes: the pad sends nothing meanwhile.
            (10, dead_man(1.0, 0.0), &[remote_forward(250)]),
            (
                120_000,
                Input::Tick,
                &[NoDisconnect, NoWheels, Control(ControlSource::Remote)],
            ),
            (
                120_010,
                buttons(Buttons::NONE),
                &[Stop { accel: STOP_DECEL }],
            ),
            (150_009, Input::Tick, &[NoDisconnect]),
            (150_010, Input::Tick, &[Disconnect]),
        ],
    );
}

#[test]
fn pairing_window_opens_on_its_command_and_closes_after_a_minute_or_on_a_new_bond() {
    let open = || raw(id::REGISTER_WRITE, &[40, 0xB1, 0xE0]);
    run(
        defaults(),
        &[
            (0, Input::Tick, &[NoPairingChange]),
            // Closed at boot: a bond reported now was not allowed and opens nothing.
            (5, Input::RemotePaired, &[NoPairingChange]),
            (
                10,
                open(),
                &[PairingWindow(true), NothingPersisted, RejectedCount(0)],
            ),
            (60_009, Input::Tick, &[NoPairingChange]),
            (60_010, Input::Tick, &[PairingWindow(false)]),
            (60_020, Input::Tick, &[NoPairingChange]),
            // The first new bond closes it: one pad per opening.
            (70_000, open(), &[PairingWindow(true)]),
            (80_000, Input::RemotePaired, &[PairingWindow(false)]),
            (80_010, Input::RemotePaired, &[NoPairingChange]),
            (130_000, Input::Tick, &[NoPairingChange]),
            // Opening an open window starts its minute over.
            (200_000, open(), &[PairingWindow(true)]),
            (250_000, open(), &[PairingWindow(true)]),
            (260_000, Input::Tick, &[NoPairingChange]),
            (309_999, Input::Tick, &[NoPairingChange]),
            (310_000, Input::Tick, &[PairingWindow(false)]),
            // Only the exact key opens it.
            (
                320_000,
                raw(id::REGISTER_WRITE, &[40, 0xB1, 0xE2]),
                &[
                    NoPairingChange,
                    Rejected {
                        code: 0x12,
                        subject: 40,
                    },
                ],
            ),
        ],
    );
}

#[test]
fn safety_zone_clamps_speed_and_rotation() {
    run(
        defaults(),
        &[
            (0, Input::SafetyZone(true), &[NoWheels]),
            (0, enable(), &[]),
            // 500 mm/s and 300 mrad/s are clamped to 200 mm/s and 100 mrad/s: the left
            // wheel runs 212.5 mm/s (143 r/min), the right 187.5 mm/s (126 r/min); the
            // right wheel's acceleration is scaled so both arrive together.
            (
                10,
                velocity(500, 300),
                &[Wheels {
                    left: 143,
                    right: -126,
                    left_accel: 700,
                    right_accel: 617,
                }],
            ),
            // 10 ms into that ramp the wheels run (+7, −6): the left changes by 354,
            // the right by 305, so the right gets 700 · 305 / 354 = 603.
            (
                20,
                Input::SafetyZone(false),
                &[Wheels {
                    left: 361,
                    right: -311,
                    left_accel: 700,
                    right_accel: 603,
                }],
            ),
            // Entering the zone while driving re-clamps at once. The wheels are still
            // below the zone's speeds (+14, −12), so they speed up with CAN_accel:
            // changes of 129 and 114, the right gets 700 · 114 / 129 = 619.
            (
                30,
                Input::SafetyZone(true),
                &[Wheels {
                    left: 143,
                    right: -126,
                    left_accel: 700,
                    right_accel: 619,
                }],
            ),
        ],
    );
}

#[test]
fn drive_that_stops_answering_stops_the_other_wheel_and_latches_a_fault() {
    let controller = run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (
                100,
                Input::DriveSilent(Wheel::Right),
                &[Stop { accel: 4500 }, Mode(Mode::Fault)],
            ),
            (110, enable(), &[]),
            (120, velocity(500, 0), &[NoWheels]),
            // A confirm press counts once the stop has ended (300 ms at estop_decel).
            (450, Input::Button(true), &[]),
            (
                550,
                Input::Button(false),
                &[SetupDrives, Mode(Mode::Recovering)],
            ),
        ],
    );
    assert!(
        controller
            .status(Timestamp::from_millis(550))
            .faults
            .right_drive_silent
    );
}

#[test]
fn drive_alarm_is_reported_and_cleared_by_the_recovery() {
    let mut controller = run(
        defaults(),
        &[(
            0,
            Input::DriveAlarm {
                wheel: Wheel::Left,
                code: 0x84,
            },
            &[Mode(Mode::Fault)],
        )],
    );
    let status = controller.status(Timestamp::from_millis(1));
    assert!(status.faults.left_drive_alarm);
    assert_eq!(status.drive_alarm, 0x84);
    controller.handle(Timestamp::from_millis(10), Input::Button(true));
    controller.handle(Timestamp::from_millis(100), Input::Button(false));
    controller.handle(Timestamp::from_millis(900), Input::Estop(false));
    controller.handle(Timestamp::from_millis(900), Input::SafetyZone(false));
    controller.handle(Timestamp::from_millis(900), Input::DrivesReady);
    let status = controller.status(Timestamp::from_millis(900));
    assert!(!status.faults.any());
    assert_eq!(status.mode, Mode::Standby);
}

#[test]
fn button_switches_the_pc_on_at_three_seconds_and_off_at_eight() {
    run(
        defaults(),
        &[
            (0, Input::Button(true), &[PcOn(false)]),
            (2999, Input::Tick, &[NoPcSwitch]),
            // Acts when the hold time is reached, not on release.
            (
                3000,
                Input::Tick,
                &[PcSwitch(SwitchLevel::Closed), PcOn(true)],
            ),
            (3499, Input::Tick, &[NoPcSwitch]),
            (3500, Input::Tick, &[PcSwitch(SwitchLevel::Open)]),
            // Held on past 8 s: one action per press.
            (9000, Input::Tick, &[NoPcSwitch]),
            (9100, Input::Button(false), &[NoPcSwitch, NoSetupDrives]),
            // Boot grace: the PC counts as on before its first heartbeat, so a second
            // 3 s press does not switch it again.
            (20_000, Input::Button(true), &[]),
            (23_000, Input::Tick, &[NoPcSwitch]),
            (24_000, Input::Button(false), &[NoPcSwitch]),
            (30_000, can(Command::Heartbeat), &[PcOn(true)]),
            // 8 s with the PC on: pulse at 8 s.
            (31_000, Input::Button(true), &[]),
            (33_000, can(Command::Heartbeat), &[]),
            (36_000, can(Command::Heartbeat), &[]),
            (38_999, Input::Tick, &[NoPcSwitch]),
            (39_000, Input::Tick, &[PcSwitch(SwitchLevel::Closed)]),
            (39_000, can(Command::Heartbeat), &[]),
            (39_500, Input::Tick, &[PcSwitch(SwitchLevel::Open)]),
            (40_000, Input::Button(false), &[]),
            // The PC shuts down: no heartbeat for heartbeat_time (5 s) and it counts as off.
            (43_999, Input::Tick, &[PcOn(true)]),
            (44_000, Input::Tick, &[PcOn(false)]),
        ],
    );
}

#[test]
fn boot_grace_expires_without_a_heartbeat() {
    run(
        defaults(),
        &[
            (0, Input::Button(true), &[]),
            (3000, Input::Tick, &[PcSwitch(SwitchLevel::Closed)]),
            (3100, Input::Button(false), &[]),
            // pc_boot_grace is 120 s from the pulse.
            (122_999, Input::Tick, &[PcOn(true)]),
            (123_000, Input::Tick, &[PcOn(false)]),
        ],
    );
}

#[test]
fn odometry_calibration_flow_stores_the_factors_on_04() {
    // 403 491 counts are 1000.0 mm of wheel travel at r = 142 mm and gear 10.
    run(
        defaults(),
        &[
            (0, counts(0, 0), &[]),
            (
                1000,
                odometry_calibration(OdometryCalibrationCommand::StartLinear),
                &[],
            ),
            (2000, counts(201_746, -201_746), &[]),
            (3000, counts(403_491, -403_491), &[]),
            (
                4000,
                odometry_calibration(OdometryCalibrationCommand::EndLinear { real_mm: 1007 }),
                &[NothingPersisted],
            ),
            // A clockwise spin: left forward, right backward (right motor mirrored).
            (
                5000,
                odometry_calibration(OdometryCalibrationCommand::StartClockwise),
                &[],
            ),
            (6000, counts(403_491 + 100_000, -403_491 + 100_000), &[]),
            (
                7000,
                odometry_calibration(OdometryCalibrationCommand::EndClockwise { real_mrad: 1570 }),
                &[NothingPersisted],
            ),
            (
                8000,
                odometry_calibration(OdometryCalibrationCommand::Store),
                &[
                    Persists(Reg::FLin, 10_070),
                    Register(Reg::FLin, 10_070),
                    // Raw clockwise rotation: 2 · 247.83 mm / 250 mm = 1982.6 mrad.
                    Persists(Reg::FCw, 7_919),
                    Register(Reg::FCcw, 9_894),
                ],
            ),
        ],
    );
}

#[test]
fn odometry_calibration_rejects_out_of_order_and_out_of_range_steps() {
    run(
        defaults(),
        &[
            (0, counts(0, 0), &[]),
            (
                1000,
                odometry_calibration(OdometryCalibrationCommand::EndLinear { real_mm: 1000 }),
                &[
                    Rejected {
                        code: 0x20,
                        subject: 0x08,
                    },
                    RejectedCount(1),
                ],
            ),
            (
                2000,
                odometry_calibration(OdometryCalibrationCommand::StartLinear),
                &[],
            ),
            (
                3000,
                odometry_calibration(OdometryCalibrationCommand::EndLinear { real_mm: 1000 }),
                &[Rejected {
                    code: 0x21,
                    subject: 0x08,
                }],
            ),
            (
                4000,
                odometry_calibration(OdometryCalibrationCommand::StartLinear),
                &[],
            ),
            (5000, counts(403_491, -403_491), &[]),
            // 1600 mm real for 1000 mm measured: a factor of 1.6 is refused.
            (
                6000,
                odometry_calibration(OdometryCalibrationCommand::EndLinear { real_mm: 1600 }),
                &[Rejected {
                    code: 0x22,
                    subject: 0x08,
                }],
            ),
            (
                7000,
                odometry_calibration(OdometryCalibrationCommand::Store),
                &[
                    Rejected {
                        code: 0x23,
                        subject: 0x08,
                    },
                    NothingPersisted,
                    Register(Reg::FLin, 10_071),
                    RejectedCount(4),
                ],
            ),
        ],
    );
}

#[test]
fn scale_calibration_flow_tares_and_scales() {
    let mut rows: Vec<Row> = vec![(0, scale_calibration(ScaleCalibrationCommand::Start), &[])];
    for ms in 1..=10 {
        rows.push((ms, Input::ScaleSample(20_000), &[]));
    }
    rows.push((
        20,
        scale_calibration(ScaleCalibrationCommand::Tare),
        &[
            Persists(Reg::WeightOffset, 20_000),
            Register(Reg::WeightOffset, 20_000),
        ],
    ));
    for ms in 21..=30 {
        rows.push((ms, Input::ScaleSample(20_000 + 38_000), &[]));
    }
    // 38 000 counts for 1000 g: 38 counts per gram, scale_value 3800.
    rows.push((
        40,
        scale_calibration(ScaleCalibrationCommand::KnownWeight { grams: 1000 }),
        &[
            Persists(Reg::ScaleValue, 3800),
            Register(Reg::ScaleValue, 3800),
        ],
    ));
    run(defaults(), &rows);
}

#[test]
fn a_tare_beyond_16_bits_persists_the_full_offset_and_weighs_from_it() {
    for (empty, reads_19, high, low) in [(80_000, 65_535, 0x01, 0x3880), (-15_000, 0, 0xFF, 0xC568)]
    {
        let mut rows: Vec<Row> = vec![(0, scale_calibration(ScaleCalibrationCommand::Start), &[])];
        for ms in 1..=10 {
            rows.push((ms, Input::ScaleSample(empty), &[]));
        }
        let persisted = [
            Persists(Reg::WeightOffset, reads_19),
            Persists(Reg::WeightOffsetHi, high),
            Persists(Reg::WeightOffsetLo, low),
            Register(Reg::WeightOffset, reads_19),
            RejectedCount(0),
        ];
        rows.push((
            20,
            scale_calibration(ScaleCalibrationCommand::Tare),
            &persisted,
        ));
        for ms in 21..=30 {
            rows.push((ms, Input::ScaleSample(empty + 38_000), &[]));
        }
        rows.push((
            40,
            scale_calibration(ScaleCalibrationCommand::KnownWeight { grams: 1000 }),
            &[Persists(Reg::ScaleValue, 3800), RejectedCount(0)],
        ));
        let controller = run(defaults(), &rows);
        assert_eq!(controller.registers().weight_offset(), empty);
    }
}

#[test]
fn the_counters_read_what_the_shell_reports() {
    let read = |address| can(Command::RegisterRead { address, tag: 0 });
    let mut controller = run(
        defaults(),
        &[
            (
                0,
                Input::FlashErases(0x0001_0002),
                &[Register(Reg::FlashErasesHi, 1)],
            ),
            (
                1,
                read(47),
                &[Sends(Report::RegisterValue {
                    value: 2,
                    echo: Some(ReadEcho {
                        address: 47,
                        tag: 0,
                    }),
                })],
            ),
        ],
    );
    controller.set_can_tx_dropped(70_000);
    assert_eq!(controller.registers().get(Reg::CanTxDropped), u16::MAX);
    controller.set_can_tx_dropped(3);
    assert_eq!(controller.registers().read(43), Ok(3));
}

#[test]
fn scale_calibration_rejects_out_of_order_steps_and_missing_readings() {
    run(
        defaults(),
        &[
            (
                0,
                scale_calibration(ScaleCalibrationCommand::Tare),
                &[Rejected {
                    code: 0x30,
                    subject: 0x07,
                }],
            ),
            (10, scale_calibration(ScaleCalibrationCommand::Start), &[]),
            (
                20,
                scale_calibration(ScaleCalibrationCommand::KnownWeight { grams: 500 }),
                &[Rejected {
                    code: 0x31,
                    subject: 0x07,
                }],
            ),
            // No HX711 reading yet.
            (
                30,
                scale_calibration(ScaleCalibrationCommand::Tare),
                &[
                    Rejected {
                        code: 0x32,
                        subject: 0x07,
                    },
                    NothingPersisted,
                    Register(Reg::WeightOffset, 20_490),
                ],
            ),
        ],
    );
}

#[test]
fn register_writes_with_bad_values_are_rejected_and_change_nothing() {
    run(
        defaults(),
        &[
            (
                0,
                raw(id::REGISTER_WRITE, &[0, 0x00, 0x00]),
                &[
                    Rejected {
                        code: 0x12,
                        subject: 0,
                    },
                    Register(Reg::RadR, 142),
                    NothingPersisted,
                ],
            ),
            (
                10,
                raw(id::REGISTER_WRITE, &[2, 0x00, 0x00]),
                &[Rejected {
                    code: 0x12,
                    subject: 2,
                }],
            ),
            (
                20,
                raw(id::REGISTER_WRITE, &[15, 0x00, 0x00]),
                &[
                    Rejected {
                        code: 0x12,
                        subject: 15,
                    },
                    Register(Reg::LoopEndDelay, 50),
                ],
            ),
            (
                30,
                raw(id::REGISTER_WRITE, &[39, 0x00, 0x02]),
                &[Rejected {
                    code: 0x11,
                    subject: 39,
                }],
            ),
            (
                40,
                raw(id::REGISTER_WRITE, &[37, 0x00, 0x02]),
                &[
                    Rejected {
                        code: 0x10,
                        subject: 37,
                    },
                    RejectedCount(5),
                ],
            ),
            // A good write is applied at once and persisted.
            (
                50,
                raw(id::REGISTER_WRITE, &[15, 0x00, 0x14]),
                &[
                    Persists(Reg::LoopEndDelay, 20),
                    Register(Reg::LoopEndDelay, 20),
                ],
            ),
            (
                60,
                raw(id::REGISTER_READ, &[1, 15]),
                &[Sends(Report::RegisterValue {
                    value: 20,
                    echo: Some(ReadEcho {
                        address: 15,
                        tag: 0,
                    }),
                })],
            ),
            (
                70,
                raw(id::REGISTER_READ, &[1, 37]),
                &[Sends(Report::RegisterReadError {
                    address: 37,
                    reason: 0x10,
                    tag: Some(0),
                })],
            ),
        ],
    );
}

#[test]
fn a_bulk_read_answers_each_address_in_order_with_its_tag_and_counts_no_gap() {
    let mut controller = run(defaults(), &[]);
    let out = controller.handle(
        Timestamp::from_millis(10),
        can(Command::RegisterBulkRead {
            first: 36,
            count: 8,
            tag: 0xBEEF,
        }),
    );
    assert!(
        out.frames.is_empty(),
        "the replies go as one batch: {out:?}"
    );
    let replies: Vec<Report> = out
        .bulk_replies
        .iter()
        .map(|frame| Report::decode(frame.id(), frame.data()).unwrap().unwrap())
        .collect();
    let expected: Vec<Report> = (36..44)
        .map(|address| match controller.registers().read(address) {
            Ok(value) => Report::RegisterValue {
                value,
                echo: Some(ReadEcho {
                    address,
                    tag: 0xBEEF,
                }),
            },
            Err(error) => Report::RegisterReadError {
                address,
                reason: error.code(),
                tag: Some(0xBEEF),
            },
        })
        .collect();
    assert_eq!(replies, expected);
    // 37, 41 and 42 hold no register: refused in the batch, not counted as rejections.
    let refused: Vec<u8> = replies
        .iter()
        .filter_map(|reply| match reply {
            Report::RegisterReadError { address, .. } => Some(*address),
            _ => None,
        })
        .collect();
    assert_eq!(refused, [37, 41, 42]);
    assert_eq!(
        controller.status(Timestamp::from_millis(10)).rejected_count,
        0
    );
    // A malformed count is a frame rejection.
    controller.handle(
        Timestamp::from_millis(20),
        raw(id::REGISTER_READ, &[0x02, 36, 9, 0, 1]),
    );
    let status = controller.status(Timestamp::from_millis(20));
    assert_eq!(
        (status.rejected_count, status.last_rejection),
        (1, FrameError::BadReadCount.code())
    );
}

#[test]
fn malformed_frames_are_counted_and_named_in_the_status() {
    run(
        defaults(),
        &[
            (
                0,
                raw(id::VELOCITY, &[0xF4, 0x01, 0, 0, 0x04]),
                &[
                    Rejected {
                        code: 0x02,
                        subject: 0xC8,
                    },
                    NoWheels,
                ],
            ),
            (
                10,
                raw(id::REGISTER_WRITE, &[1, 2]),
                &[Rejected {
                    code: 0x01,
                    subject: 0x03,
                }],
            ),
            (
                20,
                raw(id::RESET_ODOMETRY, &[2]),
                &[
                    Rejected {
                        code: 0x03,
                        subject: 0x05,
                    },
                    RejectedCount(3),
                ],
            ),
            // Unknown IDs are ignored, not counted.
            (30, raw(0x123, &[1, 2, 3]), &[RejectedCount(3)]),
        ],
    );
}

#[test]
fn register_changes_take_effect_at_once() {
    run(
        defaults(),
        &[
            // max_motor_vel 200: 500 mm/s (336 r/min) is scaled down to the limit.
            (
                0,
                raw(id::REGISTER_WRITE, &[6, 0x00, 0xC8]),
                &[Persists(Reg::MaxMotorVel, 200)],
            ),
            (10, enable(), &[]),
            (
                20,
                velocity(500, 0),
                &[Wheels {
                    left: 200,
                    right: -200,
                    left_accel: 700,
                    right_accel: 700,
                }],
            ),
        ],
    );
}

#[test]
fn restore_defaults_command_is_reported_for_persisting() {
    let mut controller = run(
        defaults(),
        &[(
            0,
            raw(id::REGISTER_WRITE, &[15, 0x00, 0x14]),
            &[Register(Reg::LoopEndDelay, 20)],
        )],
    );
    let out = controller.handle(
        Timestamp::from_millis(10),
        raw(id::REGISTER_WRITE, &[40, 0xDE, 0xF0]),
    );
    assert!(out.persist.defaults_restored);
    assert_eq!(controller.registers().get(Reg::LoopEndDelay), 50);
}

#[test]
fn odometry_reports_clockwise_heading_and_resets_over_can_and_from_the_remote() {
    // A quarter turn clockwise in place: each wheel travels π/2 · 125 mm = 196.35 mm,
    // 79 225 counts; left forward, right backward (its motor is mirrored).
    run(
        uncorrected(),
        &[
            (0, counts(1_000, 1_000), &[]),
            (
                5000,
                counts(80_225, 80_225),
                &[Pose {
                    x_mm: 0,
                    y_mm: 0,
                    heading_mrad: 1571,
                }],
            ),
            // Then 1 m forward: along +y, to the right.
            (
                10_000,
                counts(483_716, -323_266),
                &[Pose {
                    x_mm: 0,
                    y_mm: 1000,
                    heading_mrad: 1571,
                }],
            ),
            (
                11_000,
                can(Command::ResetOdometry),
                &[Pose {
                    x_mm: 0,
                    y_mm: 0,
                    heading_mrad: 0,
                }],
            ),
            (
                12_000,
                counts(887_207, -726_757),
                &[Pose {
                    x_mm: 1000,
                    y_mm: 0,
                    heading_mrad: 0,
                }],
            ),
            (12_500, pad_link(true), &[]),
            (12_600, l2_and(Buttons::NONE), &[]),
            (
                13_000,
                l2_and(Buttons::MENU),
                &[Pose {
                    x_mm: 0,
                    y_mm: 0,
                    heading_mrad: 0,
                }],
            ),
        ],
    );
}

#[test]
fn odometry_does_not_jump_when_the_drives_come_back_with_new_counters() {
    run(
        uncorrected(),
        &[
            (0, counts(5_000_000, -5_000_000), &[]),
            (
                5000,
                counts(5_403_491, -5_403_491),
                &[Pose {
                    x_mm: 1000,
                    y_mm: 0,
                    heading_mrad: 0,
                }],
            ),
            (6000, Input::DrivesReady, &[]),
            // The drives restarted at zero: a baseline, not 5 km backwards.
            (
                7000,
                counts(0, 0),
                &[Pose {
                    x_mm: 1000,
                    y_mm: 0,
                    heading_mrad: 0,
                }],
            ),
            (
                8000,
                counts(403_491, -403_491),
                &[Pose {
                    x_mm: 2000,
                    y_mm: 0,
                    heading_mrad: 0,
                }],
            ),
        ],
    );
}

#[test]
fn feedback_frames_carry_pose_battery_and_weight_at_their_periods() {
    let mut controller = Controller::new(Timestamp::BOOT, defaults());
    // The input task tells the e-stop's level at boot.
    controller.handle(Timestamp::BOOT, Input::Estop(false));
    controller.handle(Timestamp::BOOT, Input::SafetyZone(false));
    controller.handle(Timestamp::BOOT, Input::DrivesReady);
    controller.handle(Timestamp::BOOT, Input::BatterySample { voltage_mv: 25_500 });
    for _ in 0..10 {
        controller.handle(Timestamp::BOOT, Input::ScaleSample(20_490 + 19 * 1234));
    }
    let mut sent = Vec::new();
    for ms in 1..=10_000 {
        let out = controller.handle(Timestamp::from_millis(ms), Input::Tick);
        sent.extend(out.frames.iter().map(|frame| frame.id()));
    }
    let count = |id| sent.iter().filter(|&&sent_id| sent_id == id).count();
    assert_eq!(count(id::POSITION), 200);
    assert_eq!(count(id::HEADING), 200);
    assert_eq!(count(id::BATTERY), 2);
    assert_eq!(count(id::WEIGHT), 10);
    assert_eq!(count(id::STATUS), 10);
    let out = controller.handle(Timestamp::from_millis(15_000), Input::Tick);
    assert!(
        out.frames.contains(
            &Report::Battery {
                percent: 100,
                voltage_mv: 25_500
            }
            .encode()
        )
    );
    assert!(
        out.frames
            .contains(&Report::Weight { grams: 1234 }.encode())
    );
}

// ---------------------------------------------------------------------------------------
// Stops a safety engineer signs off: floors, the hand-over, motion registers at rest,
// ramps from the measured speeds
// ---------------------------------------------------------------------------------------

/// The defaults with these registers written (each write must be accepted).
fn with(writes: &[(Reg, u16)]) -> Registers {
    let mut registers = Registers::defaults();
    for (reg, value) in writes {
        registers
            .write(reg.address(), *value)
            .unwrap_or_else(|error| panic!("{reg:?} = {value}: {error:?}"));
    }
    registers
}

/// The floor of every stop but the e-stop: the `stop_decel` default, (1/min)/s.
const STOP_DECEL: u32 = 2000;

/// Why 1: an enable lapse braked with `CAN_accel`, down to 1 (1/min)/s: 334 s from
/// 500 mm/s. Every lost-source stop now brakes with at least `stop_decel`.
#[test]
fn an_enable_lapse_brakes_at_least_with_stop_decel_even_with_can_accel_1() {
    for can_accel in [1, 700] {
        run(
            with(&[(Reg::CanAccel, can_accel)]),
            &[
                (0, enable(), &[]),
                (0, velocity(500, 0), &[Control(ControlSource::Can)]),
                (100, moving(336), &[NoWheels]),
                (
                    500,
                    Input::Tick,
                    &[Stop { accel: STOP_DECEL }, Control(ControlSource::None)],
                ),
            ],
        );
    }
}

/// A source's own register wins when it brakes harder than the floor.
#[test]
fn a_stop_register_stronger_than_stop_decel_is_used_as_it_is() {
    run(
        with(&[(Reg::CanAccel, 3000)]),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[]),
            (100, moving(336), &[]),
            (500, Input::Tick, &[Stop { accel: 3000 }]),
        ],
    );
}

#[test]
fn a_withdrawn_enable_and_a_stale_velocity_brake_at_least_with_stop_decel() {
    run(
        with(&[(Reg::CanAccel, 1)]),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[]),
            (
                20,
                raw(id::ENABLE, &[0, 0, 0, 0, 0, 0, 0, 0]),
                &[Stop { accel: STOP_DECEL }],
            ),
        ],
    );
    run(
        with(&[(Reg::CanAccel, 1), (Reg::CmdTimeout, 200)]),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[]),
            (150, enable(), &[NoWheels]),
            (200, Input::Tick, &[Stop { accel: STOP_DECEL }]),
        ],
    );
}

/// Why 1: the dead-man's release and the remote's link loss braked with
/// `Contr_acc_high`; at 1 (1/min)/s that is 168 s from 336 r/min.
#[test]
fn a_dead_man_release_and_a_link_loss_brake_at_least_with_stop_decel() {
    let registers = with(&[(Reg::ContrAccHigh, 1)]);
    run(
        registers.clone(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, dead_man(1.0, 0.0), &[Control(ControlSource::Remote)]),
            (20, buttons(Buttons::NONE), &[Stop { accel: STOP_DECEL }]),
        ],
    );
    run(
        registers,
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, dead_man(1.0, 0.0), &[Control(ControlSource::Remote)]),
            (20, pad_link(false), &[Stop { accel: STOP_DECEL }]),
        ],
    );
}

/// Why 1: entering the safety zone at 1.2 m/s ramped down with `CAN_accel` (0.67 m
/// above `sec_lin_vel`). Now with `estop_decel`: 807 → 134 r/min in 150 ms, 75 mm
/// above 200 mm/s.
#[test]
fn entering_the_safety_zone_brakes_to_its_limits_with_estop_decel() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(1200, 0), &[]),
            (400, enable(), &[]),
            (800, enable(), &[]),
            (1200, enable(), &[]),
            (1200, moving(807), &[]),
            (
                1210,
                Input::SafetyZone(true),
                &[Wheels {
                    left: 134,
                    right: -134,
                    left_accel: 4500,
                    right_accel: 4500,
                }],
            ),
        ],
    );
    // Under the remote (with Contr_acc_norm it was 1.35 m): 250 mm/s → 200 mm/s.
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, dead_man(1.0, 0.0), &[remote_forward(250)]),
            (600, moving(168), &[]),
            (
                610,
                Input::SafetyZone(true),
                &[Wheels {
                    left: 134,
                    right: -134,
                    left_accel: 4500,
                    right_accel: 4500,
                }],
            ),
        ],
    );
}

/// Why 4: `rad_l = rad_r = 10` inside the zone gave 1338 mm/s at the real wheels: the
/// zone clamped the twist and trusted the geometry. The zone's own motor limit
/// `sec_motor_vel` (150 r/min) holds whatever the radius says.
#[test]
fn the_safety_zone_limits_the_motor_speed_whatever_the_geometry_registers_say() {
    run(
        with(&[(Reg::RadL, 10), (Reg::RadR, 10)]),
        &[
            (0, enable(), &[]),
            (
                0,
                velocity(500, 0),
                &[Wheels {
                    left: 900,
                    right: -900,
                    left_accel: 700,
                    right_accel: 700,
                }],
            ),
            (400, enable(), &[]),
            (800, enable(), &[]),
            (1200, enable(), &[]),
            (1500, enable(), &[]),
            (1500, moving(900), &[]),
            (
                1510,
                Input::SafetyZone(true),
                &[Wheels {
                    left: 150,
                    right: -150,
                    left_accel: 4500,
                    right_accel: 4500,
                }],
            ),
        ],
    );
}

/// Why 2: after the dead-man's release a PC that kept streaming drove again 50 ms
/// later, before standstill. Now CAN velocity is dropped until both wheels are
/// measured at rest, and a fresh frame is needed after that.
#[test]
fn after_a_dead_man_release_can_drives_only_after_standstill_with_a_fresh_frame() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[Control(ControlSource::Can)]),
            (5, pad_link(true), &[]),
            (10, buttons(Buttons::NONE), &[Control(ControlSource::Can)]),
            (20, dead_man(1.0, 0.0), &[Control(ControlSource::Remote)]),
            (40, moving(168), &[]),
            (
                50,
                buttons(Buttons::NONE),
                &[Stop { accel: STOP_DECEL }, Control(ControlSource::None)],
            ),
            (60, enable(), &[NoWheels]),
            (
                100,
                velocity(500, 0),
                &[NoWheels, NoExcite, Control(ControlSource::None)],
            ),
            (110, moving(60), &[NoWheels]),
            (150, enable(), &[NoWheels]),
            (150, velocity(500, 0), &[NoWheels]),
            // Both wheels measured at rest (the speed reads 0, then the counters stood
            // between two samples): nothing resumes by itself ...
            (160, moving(0), &[NoWheels, Control(ControlSource::None)]),
            (170, moving(0), &[NoWheels, Control(ControlSource::None)]),
            (200, enable(), &[NoWheels]),
            // ... the next frame drives.
            (
                200,
                velocity(500, 0),
                &[FORWARD_500, Control(ControlSource::Can)],
            ),
        ],
    );
}

/// Why 3: a dead-man held when the pad connected (not armed) did not take control from
/// CAN. Held, armed or not, it takes control and stops the base; it drives only once
/// it was seen released.
#[test]
fn a_held_dead_man_not_yet_armed_takes_control_from_can_and_stops_the_base() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (
                0,
                velocity(500, 0),
                &[FORWARD_500, Control(ControlSource::Can)],
            ),
            (40, moving(336), &[]),
            (45, pad_link(true), &[NoWheels]),
            (
                50,
                dead_man(1.0, 0.0),
                &[Stop { accel: STOP_DECEL }, Control(ControlSource::Remote)],
            ),
            (60, enable(), &[NoWheels]),
            (
                70,
                velocity(500, 0),
                &[NoWheels, Control(ControlSource::Remote)],
            ),
            (400, moving(0), &[NoWheels]),
            (410, enable(), &[]),
            (420, velocity(500, 0), &[NoWheels]),
            // Released (now armed) and held again: the remote drives.
            (500, buttons(Buttons::NONE), &[NoWheels]),
            (510, dead_man(1.0, 0.0), &[remote_forward(250)]),
        ],
    );
}

/// Why 4: `motor_dir` 2 → 0 while driving straight spun the base in place. Motion
/// registers are refused with `NotAtRest` (0x14) while the base moves; at rest they
/// are accepted.
#[test]
fn motion_registers_are_refused_while_moving_and_accepted_at_rest() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (40, moving(336), &[]),
            (
                50,
                raw(id::REGISTER_WRITE, &[28, 0x00, 0x00]),
                &[
                    NoWheels,
                    NothingPersisted,
                    Register(Reg::MotorDir, 2),
                    Rejected {
                        code: 0x14,
                        subject: 28,
                    },
                    RejectedCount(1),
                ],
            ),
            // Every motion register, the same way.
            (
                60,
                raw(id::REGISTER_WRITE, &[1, 0x00, 0x0A]),
                &[
                    NoWheels,
                    Register(Reg::RadL, 142),
                    Rejected {
                        code: 0x14,
                        subject: 1,
                    },
                ],
            ),
            (
                70,
                raw(id::REGISTER_WRITE, &[24, 0x07, 0xD0]),
                &[
                    NoWheels,
                    Register(Reg::GearRatio, 1000),
                    Rejected {
                        code: 0x14,
                        subject: 24,
                    },
                ],
            ),
            (
                80,
                raw(id::REGISTER_WRITE, &[6, 0x00, 0x64]),
                &[
                    NoWheels,
                    Register(Reg::MaxMotorVel, 900),
                    Rejected {
                        code: 0x14,
                        subject: 6,
                    },
                ],
            ),
            (
                90,
                raw(id::REGISTER_WRITE, &[9, 0x01, 0xF4]),
                &[
                    NoWheels,
                    Register(Reg::SecLinVel, 200),
                    Rejected {
                        code: 0x14,
                        subject: 9,
                    },
                ],
            ),
            (
                100,
                raw(id::REGISTER_WRITE, &[2, 0x01, 0x00]),
                &[
                    NoWheels,
                    Register(Reg::WheelDist, 250),
                    Rejected {
                        code: 0x14,
                        subject: 2,
                    },
                    RejectedCount(6),
                ],
            ),
            // Writing the value a motion register already holds changes nothing: accepted.
            (
                110,
                raw(id::REGISTER_WRITE, &[28, 0x00, 0x02]),
                &[NoWheels, RejectedCount(6)],
            ),
            // Other registers stay writable while moving.
            (
                120,
                raw(id::REGISTER_WRITE, &[3, 0x01, 0xF4]),
                &[Persists(Reg::CanAccel, 500)],
            ),
            // Stopped and measured at rest: accepted.
            (130, velocity(0, 0), &[Stop { accel: 500 }]),
            (200, enable(), &[]),
            (200, moving(100), &[]),
            (
                210,
                raw(id::REGISTER_WRITE, &[28, 0x00, 0x00]),
                &[
                    Register(Reg::MotorDir, 2),
                    Rejected {
                        code: 0x14,
                        subject: 28,
                    },
                ],
            ),
            (300, enable(), &[]),
            (300, moving(0), &[]),
            (305, moving(0), &[]),
            (
                310,
                raw(id::REGISTER_WRITE, &[28, 0x00, 0x00]),
                &[
                    Persists(Reg::MotorDir, 0),
                    Register(Reg::MotorDir, 0),
                    NoWheels,
                ],
            ),
        ],
    );
}

/// Why 4: restore-defaults mid-motion also reset the direction and the gear ratio.
#[test]
fn restore_defaults_is_refused_while_moving() {
    run(
        with(&[(Reg::GearRatio, 2000), (Reg::LoopEndDelay, 20)]),
        &[
            (0, enable(), &[]),
            (
                0,
                velocity(250, 0),
                &[Wheels {
                    left: 336,
                    right: -336,
                    left_accel: 700,
                    right_accel: 700,
                }],
            ),
            (40, moving(336), &[]),
            (
                50,
                raw(id::REGISTER_WRITE, &[40, 0xDE, 0xF0]),
                &[
                    NoWheels,
                    NothingPersisted,
                    Register(Reg::GearRatio, 2000),
                    Register(Reg::LoopEndDelay, 20),
                    Rejected {
                        code: 0x14,
                        subject: 40,
                    },
                ],
            ),
        ],
    );
}

/// Why 5: a synchronized ramp started from the previous target, not from the speed the
/// wheels had: a spin 100 ms into a ramp made them arrive 187 ms apart. Now it starts
/// from the measured speed (moved along the ramp in force since the measurement).
#[test]
fn a_ramp_starts_from_the_measured_wheel_speeds_so_both_arrive_together() {
    // 100 ms into the 700 (1/min)/s ramp to 336 r/min the wheels run 70 r/min. A
    // clockwise spin of 1 rad/s wants +84 on both motors: the left one changes by 14,
    // the right one by 154, so the left gets 700 · 14 / 154 = 64.
    let spin = Wheels {
        left: 84,
        right: 84,
        left_accel: 64,
        right_accel: 700,
    };
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (100, moving(70), &[]),
            (100, velocity(0, 1000), &[spin]),
        ],
    );
    // The same from a measurement 50 ms old: 35 r/min then, 70 now.
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (50, moving(35), &[]),
            (100, velocity(0, 1000), &[spin]),
        ],
    );
}

/// The hand-over after a link loss is the same as after a release.
#[test]
fn after_a_remote_link_loss_can_drives_only_after_standstill_with_a_fresh_frame() {
    run(
        defaults(),
        &[
            (0, pad_link(true), &[]),
            (0, buttons(Buttons::NONE), &[]),
            (10, dead_man(1.0, 0.0), &[remote_forward(250)]),
            (100, moving(30), &[]),
            (
                110,
                pad_link(false),
                &[Stop { accel: STOP_DECEL }, Control(ControlSource::None)],
            ),
            (120, enable(), &[]),
            (120, velocity(500, 0), &[NoWheels, NoExcite]),
            (150, moving(10), &[NoWheels]),
            (160, enable(), &[]),
            (160, velocity(500, 0), &[NoWheels]),
            (200, moving(1), &[NoWheels]),
            // The counters stood since the previous sample too: at rest.
            (205, moving(0), &[NoWheels]),
            (210, enable(), &[]),
            (
                210,
                velocity(500, 0),
                &[FORWARD_500, Control(ControlSource::Can)],
            ),
        ],
    );
}

/// Issue 21, case 5: the left encoder sticks at 500 mm/s (its counter stands while its
/// speed reads 336 r/min). Two 100 ms windows disagree, then the base stops with
/// `estop_decel` and the mode is Fault, the reason PositionStuck (0x41) on wheel 1.
#[test]
fn a_stuck_encoder_latches_a_drive_fault_and_stops_with_estop_decel() {
    let stuck = |ms: i32| Input::DriveFeedback {
        counts: EncoderCounts {
            left: 0,
            right: -(336 * 36_000 / 60_000 * ms),
        },
        rpm: MotorRpm {
            left: 336,
            right: -336,
        },
    };
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (100, stuck(0), &[NoWheels, Mode(Mode::Active)]),
            (150, stuck(50), &[NoWheels]),
            (200, stuck(100), &[NoWheels, Mode(Mode::Active)]),
            (250, stuck(150), &[NoWheels]),
            (
                300,
                stuck(200),
                &[
                    Stop { accel: 4_500 },
                    Mode(Mode::Fault),
                    Rejected {
                        code: 0x41,
                        subject: 1,
                    },
                ],
            ),
            (310, enable(), &[]),
            (310, velocity(500, 0), &[NoWheels, Mode(Mode::Fault)]),
        ],
    );
}

/// Issue 21, case 5: both speed registers read 0 while the wheels still turn down
/// from 336 r/min. The counters run, so the base is not at rest: a motion register is
/// refused and the brakes stay released.
#[test]
fn counters_that_run_while_the_speeds_read_zero_are_no_standstill() {
    let rolling = |left: i32| Input::DriveFeedback {
        counts: EncoderCounts { left, right: -left },
        rpm: MotorRpm::ZERO,
    };
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (100, moving(336), &[]),
            (100, velocity(0, 0), &[Stop { accel: 700 }]),
            // 336 → 0 r/min at 700 (1/min)/s takes 480 ms; 20 ms later the counters
            // have run about 4000 counts while the speeds already read 0.
            (120, rolling(4_000), &[NoWheels]),
            (140, rolling(8_000), &[NoWheels]),
            (
                150,
                raw(id::REGISTER_WRITE, &[1, 0x00, 0x64]),
                &[
                    Register(Reg::RadL, 142),
                    Rejected {
                        code: 0x14,
                        subject: 1,
                    },
                ],
            ),
            (450, Input::Tick, &[NoExcite]),
        ],
    );
}

/// Issue 21: a register that shapes a stop (`estop_decel` 3000 here) written while
/// moving is refused like a motion register, so the e-stop right after it still brakes
/// with 4500; once the base stands the value is accepted.
#[test]
fn a_stop_shaping_register_is_refused_while_moving_and_accepted_at_rest() {
    run(
        defaults(),
        &[
            (0, enable(), &[]),
            (0, velocity(500, 0), &[FORWARD_500]),
            (40, moving(336), &[]),
            (
                50,
                raw(id::REGISTER_WRITE, &[26, 0x0B, 0xB8]),
                &[
                    NothingPersisted,
                    Register(Reg::EstopDecel, 4_500),
                    Rejected {
                        code: 0x14,
                        subject: 26,
                    },
                ],
            ),
            (60, Input::Estop(true), &[Stop { accel: 4_500 }]),
            (300, moving(0), &[]),
            (320, moving(0), &[]),
            (
                330,
                raw(id::REGISTER_WRITE, &[26, 0x0B, 0xB8]),
                &[
                    Persists(Reg::EstopDecel, 3_000),
                    Register(Reg::EstopDecel, 3_000),
                ],
            ),
        ],
    );
}
