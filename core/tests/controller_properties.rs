//! The controller's safety invariants as properties over random event sequences: CAN
//! frames (well-formed and garbage), inputs, gamepad reports and links, drive feedback
//! and ticks are
//! fed to `Controller::handle` with time moving forward, and every invariant is checked
//! after every event. The module `model` holds the contract's rules for who may drive
//! (docs/behaviour.md, "Who may move the base"), tracked from the inputs alone.

use base_core::calibration::{OdometryCalibrationCommand, ScaleCalibrationCommand};
use base_core::can::{Command, ControlSource, Mode, RawFrame, ReadEcho, Report, Status, id};
use base_core::controller::{BootReport, Controller, Input, Output};
use base_core::drives::AT_REST_RPM;
use base_core::gamepad::{Buttons, Dpad, GamepadState};
use base_core::kinematics::{self, KinematicsParams, MotorRpm, SafetyLimits, Twist};
use base_core::odometry::{EncoderCounts, Pose};
use base_core::registers::{
    BLUETOOTH_ON_KEY, MOTOR_DIR_INVERT_LEFT, MOTOR_DIR_INVERT_RIGHT, OPEN_PAIRING_WINDOW_KEY,
    RESTORE_DEFAULTS_KEY, Reg, RegisterError, Registers,
};
use base_core::remote::{MODIFIER_THRESHOLD, PAIRING_WINDOW_MS, Pad};
use base_core::supervisor::Wheel;
use base_core::time::Timestamp;
use proptest::prelude::*;
use proptest::strategy::ValueTree;
use proptest::test_runner::{TestCaseError, TestRunner};

/// Sequences per property: enough to reach driving, emergencies, faults and register
/// changes in many combinations (see `event_sequences_reach_every_situation_checked`),
/// while the whole file runs in a few seconds.
const CASES: u32 = 1000;
const MAX_EVENTS: usize = 200;

// ---------------------------------------------------------------------------------------
// Strategies
// ---------------------------------------------------------------------------------------

/// Milliseconds between two events: mostly short (so enables stay fresh and the base
/// drives), sometimes long enough for every timeout.
fn gap_ms() -> impl Strategy<Value = u64> {
    prop_oneof![6 => 0..=30u64, 3 => 0..=300u64, 1 => 0..=1000u64]
}

fn frame(id: u16, data: &[u8]) -> RawFrame {
    RawFrame::new(id, data).expect("test frames are valid classic CAN frames")
}

/// `len` bytes of `bytes`, with `first` in front when given.
fn frame_with(id: u16, first: Option<u8>, bytes: [u8; 8], len: usize) -> RawFrame {
    let mut data = bytes;
    if let Some(first) = first {
        data[0] = first;
    }
    frame(id, &data[..len])
}

fn can_speed() -> impl Strategy<Value = i16> {
    prop_oneof![
        4 => -1500i16..=1500,
        1 => any::<i16>(),
        1 => prop::sample::select(vec![i16::MIN, i16::MAX, 0, 1, -1]),
    ]
}

fn velocity_frame() -> impl Strategy<Value = RawFrame> {
    (can_speed(), can_speed()).prop_map(|(linear_mm_s, rotation_mrad_s)| {
        Command::Velocity {
            linear_mm_s,
            rotation_mrad_s,
        }
        .encode()
    })
}

/// A stick axis as the HID decoder reports it, now and then garbage from a broken one.
fn stick() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -1.0f32..=1.0,
        2 => prop::sample::select(vec![-1.0f32, -0.5, 0.0, 0.5, 1.0]),
        1 => prop::sample::select(vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1.5, -3.0]),
    ]
}

/// Any gamepad state: the dead-man half of the time, L2 pulled (or not quite) with
/// Menu or Home now and then, D-pad presses.
fn gamepad() -> impl Strategy<Value = GamepadState> {
    let trigger = prop::sample::select(vec![0.0f32, 0.3, MODIFIER_THRESHOLD, 0.8, 1.0, f32::NAN]);
    let other_buttons = prop_oneof![
        12 => Just(Buttons::NONE),
        2 => Just(Buttons::MENU),
        2 => Just(Buttons::HOME),
        1 => Just(Buttons::A),
    ];
    let dpad = prop_oneof![
        5 => Just(Dpad::default()),
        2 => Just(Dpad { up: true, ..Dpad::default() }),
        1 => Just(Dpad { down: true, ..Dpad::default() }),
    ];
    (
        stick(),
        stick(),
        any::<bool>(),
        trigger,
        other_buttons,
        dpad,
    )
        .prop_map(
            |(left_y, right_x, dead_man, left_trigger, other, dpad)| GamepadState {
                left_y,
                right_x,
                left_trigger,
                buttons: if dead_man {
                    other.with(Buttons::RIGHT_BUMPER)
                } else {
                    other
                },
                dpad,
                ..GamepadState::default()
            },
        )
}

/// Registers worth changing mid-sequence: limits, geometry, accelerations, timeouts and
/// periods (what the wheels are told and when), the remote's speed levels and AFK time,
/// and the PC button hold times.
const DRIVING_REGISTERS: [Reg; 24] = [
    Reg::MaxMotorVel,
    Reg::GearRatio,
    Reg::RadL,
    Reg::RadR,
    Reg::WheelDist,
    Reg::EstopDecel,
    Reg::MotorDir,
    Reg::CanAccel,
    Reg::ContrAccNorm,
    Reg::ContrAccHigh,
    Reg::SecLinVel,
    Reg::SecTurnVel,
    Reg::EnableTimeout,
    Reg::CmdTimeout,
    Reg::DisableTime,
    Reg::LoopEndDelay,
    Reg::VoltTime,
    Reg::WeightTime,
    Reg::StatusTime,
    Reg::StartPc,
    Reg::ShutdownPc,
    Reg::PsAbsMaxVel,
    Reg::PsRelMaxVel,
    Reg::PsAfkTime,
];

/// The registers the motor speeds of a twist depend on.
const KINEMATIC_REGISTERS: [Reg; 6] = [
    Reg::MaxMotorVel,
    Reg::GearRatio,
    Reg::RadL,
    Reg::RadR,
    Reg::WheelDist,
    Reg::MotorDir,
];

/// An in-range write to a kinematic register (it may still break a cross-register rule).
fn kinematic_write() -> impl Strategy<Value = RawFrame> {
    prop::sample::select(KINEMATIC_REGISTERS.to_vec())
        .prop_flat_map(|reg| (Just(reg.address()), reg.info().min..=reg.info().max))
        .prop_map(|(address, value)| Command::RegisterWrite { address, value }.encode())
}

/// 0x003 frames: mostly in-range values of the registers that matter for driving (so
/// they are accepted and change the limits while the base moves), plus anything at all.
fn register_write() -> impl Strategy<Value = RawFrame> {
    let targeted = prop::sample::select(DRIVING_REGISTERS.to_vec()).prop_flat_map(|reg| {
        let info = reg.info();
        let value = prop_oneof![4 => info.min..=info.max, 1 => any::<u16>()];
        (Just(reg.address()), value)
    });
    prop_oneof![
        8 => targeted,
        2 => (any::<u8>(), any::<u16>()),
        1 => Just((Reg::Command.address(), RESTORE_DEFAULTS_KEY)),
        1 => Just((Reg::Command.address(), OPEN_PAIRING_WINDOW_KEY)),
    ]
    .prop_map(|(address, value)| Command::RegisterWrite { address, value }.encode())
}

fn scale_calibration() -> impl Strategy<Value = RawFrame> {
    prop_oneof![
        Just(ScaleCalibrationCommand::Start),
        Just(ScaleCalibrationCommand::Tare),
        any::<u16>().prop_map(|grams| ScaleCalibrationCommand::KnownWeight { grams }),
    ]
    .prop_map(|step| Command::ScaleCalibration(step).encode())
}

fn odometry_calibration() -> impl Strategy<Value = RawFrame> {
    use OdometryCalibrationCommand as Step;
    let value = prop_oneof![0u16..=5000, any::<u16>()];
    prop_oneof![
        Just(Step::StartLinear),
        value
            .clone()
            .prop_map(|real_mm| Step::EndLinear { real_mm }),
        Just(Step::StartClockwise),
        value
            .clone()
            .prop_map(|real_mrad| Step::EndClockwise { real_mrad }),
        Just(Step::StartCounterClockwise),
        value.prop_map(|real_mrad| Step::EndCounterClockwise { real_mrad }),
        Just(Step::Store),
    ]
    .prop_map(|step| Command::OdometryCalibration(step).encode())
}

/// Any frame at an ID the base controller listens to or sends, with a random length and
/// a first byte that is often a real sub-command, so every rejection path is reached.
fn known_id_garbage() -> impl Strategy<Value = RawFrame> {
    let ids: Vec<u16> = id::COMMANDS
        .iter()
        .chain(id::REPORTS.iter())
        .copied()
        .collect();
    let first = prop_oneof![
        3 => prop::sample::select(vec![
            0x00u8, 0x01, 0x02, 0x03, 0x04, 0x0C, 0x16, 0x20, 0x40, 0xFF,
        ])
        .prop_map(Some),
        1 => Just(None),
    ];
    (
        prop::sample::select(ids),
        first,
        any::<[u8; 8]>(),
        0..=8usize,
    )
        .prop_map(|(id, first, bytes, len)| frame_with(id, first, bytes, len))
}

/// A completely random classic frame: any 11-bit ID, 0..=8 bytes.
fn any_frame() -> impl Strategy<Value = RawFrame> {
    (0..=0x7FFu16, any::<[u8; 8]>(), 0..=8usize)
        .prop_map(|(id, bytes, len)| frame(id, &bytes[..len]))
}

fn can_frame() -> impl Strategy<Value = RawFrame> {
    prop_oneof![
        8 => Just(Command::Enable { refresh: true }.encode()),
        1 => (any::<u8>().prop_filter("0x40 refreshes", |b| *b != 0x40), any::<[u8; 8]>(), 1..=8usize)
            .prop_map(|(first, bytes, len)| frame_with(id::ENABLE, Some(first), bytes, len)),
        8 => velocity_frame(),
        4 => register_write(),
        1 => (any::<u8>(), any::<u16>())
            .prop_map(|(address, tag)| Command::RegisterRead { address, tag }.encode()),
        1 => Just(Command::ResetOdometry.encode()),
        1 => Just(Command::Heartbeat.encode()),
        1 => scale_calibration(),
        1 => odometry_calibration(),
        2 => known_id_garbage(),
        1 => any_frame(),
    ]
}

fn wheel() -> impl Strategy<Value = Wheel> {
    prop_oneof![Just(Wheel::Left), Just(Wheel::Right)]
}

fn motor_rpm_sample() -> impl Strategy<Value = i32> {
    prop_oneof![
        4 => -3..=3i32,
        4 => -4000..=4000i32,
        1 => any::<i32>(),
        1 => prop::sample::select(vec![i32::MIN, i32::MAX, i32::MIN + 1]),
    ]
}

fn drive_feedback() -> impl Strategy<Value = Input> {
    (
        any::<i32>(),
        any::<i32>(),
        motor_rpm_sample(),
        motor_rpm_sample(),
    )
        .prop_map(|(left, right, rpm_left, rpm_right)| Input::DriveFeedback {
            counts: EncoderCounts { left, right },
            rpm: MotorRpm {
                left: rpm_left,
                right: rpm_right,
            },
        })
}

/// Which remote task: the BLE pads' or the PlayStation pads'.
fn pad_task() -> impl Strategy<Value = Pad> {
    prop_oneof![Just(Pad::Ble), Just(Pad::Classic)]
}

/// One event of any kind the shell can deliver.
fn input() -> impl Strategy<Value = Input> {
    prop_oneof![
        24 => can_frame().prop_map(Input::CanFrame),
        3 => any::<bool>().prop_map(Input::Estop),
        2 => any::<bool>().prop_map(Input::SafetyZone),
        3 => any::<bool>().prop_map(Input::Button),
        7 => (pad_task(), gamepad()).prop_map(|(pad, state)| Input::Gamepad { pad, state }),
        2 => (pad_task(), any::<bool>(), prop_oneof![3 => Just(true), 1 => Just(false)])
            .prop_map(|(pad, bonded, connected)| Input::RemoteLink { pad, bonded, connected }),
        // Mostly lifts: a lock held for most of a sequence would leave little to check.
        1 => prop_oneof![1 => Just(Input::UpdateLock(true)), 3 => Just(Input::UpdateLock(false))],
        1 => Just(Input::RemotePaired),
        // Bluetooth on after a panic loop (a confirm press does it too).
        1 => Just(Input::CanFrame(Command::RegisterWrite {
            address: Reg::Command.address(),
            value: BLUETOOTH_ON_KEY,
        }.encode())),
        4 => drive_feedback(),
        3 => Just(Input::DrivesReady),
        1 => wheel().prop_map(Input::DriveSilent),
        1 => (wheel(), any::<u8>()).prop_map(|(wheel, code)| Input::DriveAlarm { wheel, code }),
        1 => Just(Input::ModbusError),
        1 => any::<i32>().prop_map(Input::ScaleSample),
        1 => Just(Input::ScaleMissing),
        1 => any::<u16>().prop_map(|voltage_mv| Input::BatterySample { voltage_mv }),
        1 => prop_oneof![
            Just(Input::CanBusFault),
            Just(Input::FlashFault),
        ],
        8 => Just(Input::Tick),
    ]
}

fn connect(pad: Pad) -> Input {
    Input::RemoteLink {
        pad,
        bonded: true,
        connected: true,
    }
}

fn with_dead_man(state: GamepadState) -> GamepadState {
    GamepadState {
        buttons: state.buttons.with(Buttons::RIGHT_BUMPER),
        ..state
    }
}

/// A few events that belong together and rarely line up by chance.
fn episode() -> impl Strategy<Value = Vec<(u64, Input)>> {
    let enable = Input::CanFrame(Command::Enable { refresh: true }.encode());
    prop_oneof![
        // CAN drives: a refresh, then a velocity while it is fresh.
        (0..=50u64, velocity_frame().prop_map(Input::CanFrame))
            .prop_map(move |(gap, velocity)| vec![(0, enable), (gap, velocity)]),
        // CAN drives, then the e-stop is pressed or a drive faults.
        (
            0..=50u64,
            velocity_frame().prop_map(Input::CanFrame),
            0..=300u64,
            prop_oneof![
                Just(Input::Estop(true)),
                wheel().prop_map(Input::DriveSilent),
                (wheel(), 1..=255u8).prop_map(|(wheel, code)| Input::DriveAlarm { wheel, code }),
            ],
        )
            .prop_map(move |(gap, velocity, after, stop)| {
                vec![(0, enable), (gap, velocity), (after, stop)]
            }),
        // CAN drives, then the speed limit or the geometry changes.
        (
            0..=50u64,
            velocity_frame().prop_map(Input::CanFrame),
            0..=100u64,
            kinematic_write()
        )
            .prop_map(move |(gap, velocity, write_gap, write)| {
                vec![
                    (0, enable),
                    (gap, velocity),
                    (write_gap, Input::CanFrame(write)),
                ]
            }),
        // A pad connects, reports the dead-man released (perhaps with a speed level
        // step up), then held with the sticks.
        (pad_task(), 0..=200u64, any::<bool>(), gamepad()).prop_map(
            move |(pad, gap, level_up, state)| {
                let released = GamepadState {
                    dpad: Dpad {
                        up: level_up,
                        ..Dpad::default()
                    },
                    ..GamepadState::default()
                };
                vec![
                    (0, connect(pad)),
                    (
                        0,
                        Input::Gamepad {
                            pad,
                            state: released,
                        },
                    ),
                    (
                        gap,
                        Input::Gamepad {
                            pad,
                            state: with_dead_man(state),
                        },
                    ),
                ]
            }
        ),
        // Two pads at once: one drives, the other connects and presses its buttons,
        // then one of them lets go or leaves.
        (
            pad_task(),
            gamepad(),
            gamepad(),
            0..=100u64,
            prop_oneof![
                Just(Input::Gamepad {
                    pad: Pad::Ble,
                    state: GamepadState::default()
                }),
                Just(Input::Gamepad {
                    pad: Pad::Classic,
                    state: GamepadState::default()
                }),
                pad_task().prop_map(|pad| Input::RemoteLink {
                    pad,
                    bonded: true,
                    connected: false,
                }),
            ],
        )
            .prop_map(|(first, driving, other, gap, ending)| {
                let second = if first == Pad::Ble {
                    Pad::Classic
                } else {
                    Pad::Ble
                };
                vec![
                    (0, connect(first)),
                    (
                        0,
                        Input::Gamepad {
                            pad: first,
                            state: GamepadState::default(),
                        },
                    ),
                    (
                        gap,
                        Input::Gamepad {
                            pad: first,
                            state: with_dead_man(driving),
                        },
                    ),
                    (gap, connect(second)),
                    (
                        0,
                        Input::Gamepad {
                            pad: second,
                            state: GamepadState::default(),
                        },
                    ),
                    (
                        gap,
                        Input::Gamepad {
                            pad: second,
                            state: with_dead_man(other),
                        },
                    ),
                    (gap, ending),
                    (
                        gap,
                        Input::Gamepad {
                            pad: second,
                            state: with_dead_man(other),
                        },
                    ),
                ]
            }),
        // A firmware update locks motion while a pad connects, holds or lets go, and
        // the lock lifts.
        (pad_task(), gamepad(), any::<bool>(), 0..=300u64).prop_map(
            |(pad, state, release_in_lock, gap)| {
                let during = if release_in_lock {
                    GamepadState::default()
                } else {
                    with_dead_man(state)
                };
                vec![
                    (0, Input::UpdateLock(true)),
                    (0, connect(pad)),
                    (gap, Input::Gamepad { pad, state: during }),
                    (gap, Input::UpdateLock(false)),
                    (
                        gap,
                        Input::Gamepad {
                            pad,
                            state: with_dead_man(state),
                        },
                    ),
                ]
            }
        ),
        // The pairing window opens, then a new bond or its minute ends it.
        prop_oneof![
            6 => (0..=2000u64, Just(Input::RemotePaired)),
            1 => (PAIRING_WINDOW_MS - 100..=PAIRING_WINDOW_MS + 100, Just(Input::Tick)),
        ]
        .prop_map(|(gap, close)| {
            let open = Command::RegisterWrite {
                address: Reg::Command.address(),
                value: OPEN_PAIRING_WINDOW_KEY,
            };
            vec![(0, Input::CanFrame(open.encode())), (gap, close)]
        }),
        // Leaving an emergency: release, a short press, the drives set up again.
        (0..=500u64, 0..=2000u64, 0..=300u64).prop_map(|(release, hold, ready)| {
            vec![
                (release, Input::Estop(false)),
                (0, Input::Button(true)),
                (hold, Input::Button(false)),
                (ready, Input::DrivesReady),
            ]
        }),
    ]
}

/// A boot followed by up to `MAX_EVENTS` events, single ones and (with weight
/// `episodes` against 8) short episodes. Most sequences start with the drives ready, so
/// the interesting part is not spent waiting for them.
fn sequence_of(
    input: impl Strategy<Value = Input>,
    episodes: u32,
) -> impl Strategy<Value = Sequence> {
    let single = (gap_ms(), input).prop_map(|event| vec![event]);
    let parts = prop_oneof![8 => single, episodes => episode()];
    (
        any::<bool>(),
        prop::bool::weighted(0.3),
        prop::collection::vec(parts, 1..=MAX_EVENTS),
    )
        .prop_map(|(ready_at_boot, bluetooth_off, parts)| {
            // The input task tells the safety inputs' levels at boot (a press or an
            // occupied zone comes later as an event of its own).
            let told = [(0, Input::Estop(false)), (0, Input::SafetyZone(false))];
            let boot = ready_at_boot.then_some((0, Input::DrivesReady));
            Sequence {
                bluetooth_off,
                events: told
                    .into_iter()
                    .chain(boot)
                    .chain(parts.into_iter().flatten())
                    .take(MAX_EVENTS)
                    .collect(),
            }
        })
}

/// A boot and what follows it.
#[derive(Debug, Clone)]
struct Sequence {
    /// The boot found a panic loop: Bluetooth is off until a confirm press or its key.
    bluetooth_off: bool,
    events: Vec<(u64, Input)>,
}

fn sequence() -> impl Strategy<Value = Sequence> {
    sequence_of(input(), 2)
}

/// Sequences dominated by CAN frames, most of them garbage.
fn frame_sequence() -> impl Strategy<Value = Sequence> {
    let frames = prop_oneof![
        4 => known_id_garbage(),
        2 => any_frame(),
        2 => can_frame(),
    ]
    .prop_map(Input::CanFrame);
    sequence_of(prop_oneof![8 => frames, 1 => input()], 0)
}

// ---------------------------------------------------------------------------------------
// The model: the contract's rules for who may drive, tracked from the inputs
// ---------------------------------------------------------------------------------------

mod model {
    use super::*;

    /// A CAN velocity stored while the enable was fresh.
    #[derive(Debug, Clone, Copy)]
    struct CanVelocity {
        twist: Twist,
        received: Timestamp,
        /// The enable session it arrived in: a lapse or a withdrawal starts a new one.
        session: u32,
    }

    /// The connection of the pad in control, as docs/remote.md describes it.
    #[derive(Debug, Clone, Copy, Default)]
    enum Session {
        #[default]
        Offline,
        Connected {
            level_mm_s: u16,
            /// The latest report since the connection.
            last: Option<GamepadState>,
            /// The latest report, or the connection: "no input" counts from here.
            last_input: Timestamp,
        },
        /// L2 + Home or AFK asked for the disconnect; nothing from the pad counts.
        SwitchingOff,
    }

    /// Speed levels (docs/remote.md): 50 mm/s steps within 50 … `PS_abs_max_vel`.
    fn level_within(level_mm_s: u16, registers: &Registers) -> u16 {
        level_mm_s.min(registers.get(Reg::PsAbsMaxVel)).max(50)
    }

    fn dead_man(pad: &GamepadState) -> bool {
        pad.buttons.contains(Buttons::RIGHT_BUMPER)
    }

    /// docs/remote.md: full left stick forward is the speed level forward, full right stick right
    /// is level · 2 / wheel_dist rad/s clockwise; a stick value outside −1 … 1 counts as
    /// the end it is beyond, garbage (NaN, infinite) as centred.
    fn stick_twist(pad: &GamepadState, level_mm_s: u16, registers: &Registers) -> Twist {
        let axis = |value: f32| {
            if value.is_finite() {
                value.clamp(-1.0, 1.0)
            } else {
                0.0
            }
        };
        let level = f32::from(level_mm_s);
        let full_turn_mrad_s = level * 2000.0 / f32::from(registers.get(Reg::WheelDist));
        Twist {
            linear_mm_s: (axis(pad.left_y) * level).round() as i32,
            rotation_mrad_s: (axis(pad.right_x) * full_turn_mrad_s).round() as i32,
        }
    }

    /// What the contract says about the sources, from the inputs and the mode each
    /// input met. It is never stricter than the contract: where the controller may
    /// legitimately have forgotten a command already (a lapse it noticed at some input
    /// before `enable_timeout` was raised again), the model may still allow it, so "the
    /// model forbids it" is a sound reason for a failure.
    #[derive(Debug, Clone, Default)]
    pub struct Model {
        pub estop_pressed: bool,
        pub safety_zone: bool,
        enable_refreshed: Option<Timestamp>,
        session: u32,
        can: Option<CanVelocity>,
        /// Which task's pad is connected (BLE, Classic).
        links: [bool; 2],
        /// The pad in control: the first one connected, until its link goes down; then
        /// the other one, if connected, as a fresh connection.
        in_control: Option<Pad>,
        /// Each pad's latest report while it waited, connected, held the dead-man: at a
        /// hand-over the new connection starts with it held (docs/remote.md).
        waiting_held: [bool; 2],
        pad: Session,
        /// A firmware update locks motion: no source counts, nothing is stored or armed;
        /// its lift arms only a dead-man seen up.
        locked: bool,
        /// A gamepad report arrived since boot or since the link was lost: until then
        /// the dead-man's state is unknown, not "released".
        remote_reported: bool,
        remote_held: bool,
        /// The dead-man was seen released while the base could drive (or was seen up
        /// when the drives came back): only then may holding it drive, so a pad that
        /// connects with the button held, or a button held through an e-stop, does not
        /// drive. Held, armed or not, it has control: CAN does not drive.
        remote_armed: bool,
        /// The dead-man let go (released, link lost): CAN velocity is dropped until a
        /// drive feedback measures both wheels at rest, or the drives are set up again.
        can_waits_for_rest: bool,
        /// The pad (the one in control) whose disconnect is due with the input just
        /// observed: L2 + Home, AFK, or a report from a pad already asked to go.
        pub disconnect_due: Option<Pad>,
        /// The pairing window is open until then.
        pairing_until: Option<Timestamp>,
        /// The pairing window opened (`true`) or closed (`false`) with the input just
        /// observed.
        pub pairing_change: Option<bool>,
    }

    fn may_drive(mode: Mode) -> bool {
        matches!(mode, Mode::Standby | Mode::Active)
    }

    impl Model {
        /// The last 0x2E4 `40` is younger than `enable_timeout`.
        pub fn enable_fresh(&self, now: Timestamp, registers: &Registers) -> bool {
            let timeout = u64::from(registers.get(Reg::EnableTimeout));
            self.enable_refreshed
                .is_some_and(|at| now.millis_since(at) < timeout)
        }

        /// The dead-man is held, armed or not: the remote has control.
        pub fn remote_holds(&self) -> bool {
            self.remote_reported && self.remote_held
        }

        /// The dead-man is held and armed: the sticks drive.
        pub fn remote_in_control(&self) -> bool {
            self.remote_armed && self.remote_holds()
        }

        /// The CAN velocity that may drive now, if any.
        pub fn can_twist(&self, now: Timestamp, registers: &Registers) -> Option<Twist> {
            let velocity = self.can?;
            let cmd_timeout = u64::from(registers.get(Reg::CmdTimeout));
            let current = cmd_timeout == 0 || now.millis_since(velocity.received) < cmd_timeout;
            (velocity.session == self.session
                && self.enable_fresh(now, registers)
                && current
                && !self.remote_holds())
            .then_some(velocity.twist)
        }

        /// The source that may drive now and the twist it asks for (before the
        /// safety-zone clamp), ignoring the mode.
        pub fn source(
            &self,
            now: Timestamp,
            registers: &Registers,
        ) -> Option<(ControlSource, Twist)> {
            if self.estop_pressed || self.locked {
                None
            } else if self.remote_in_control() {
                Some((ControlSource::Remote, self.remote_twist(registers)))
            } else if self.remote_holds() {
                // Held but not armed: control without motion.
                Some((ControlSource::Remote, Twist::ZERO))
            } else {
                self.can_twist(now, registers)
                    .map(|twist| (ControlSource::Can, twist))
            }
        }

        /// The twist the pad's sticks ask for at its speed level.
        fn remote_twist(&self, registers: &Registers) -> Twist {
            match self.pad {
                Session::Connected {
                    level_mm_s,
                    last: Some(pad),
                    ..
                } => stick_twist(&pad, level_mm_s, registers),
                _ => Twist::ZERO,
            }
        }

        /// The pad in control.
        pub fn in_control(&self) -> Option<Pad> {
            self.in_control
        }

        /// The connected pad's speed level.
        pub fn remote_level_mm_s(&self) -> Option<u16> {
            match self.pad {
                Session::Connected { level_mm_s, .. } => Some(level_mm_s),
                _ => None,
            }
        }

        /// A pad takes control: a fresh connection at the start level.
        fn connect(&mut self, now: Timestamp, registers: &Registers) {
            self.pad = Session::Connected {
                level_mm_s: level_within(registers.get(Reg::PsRelMaxVel), registers),
                last: None,
                last_input: now,
            };
        }

        fn switch_off(&mut self) {
            self.pad = Session::SwitchingOff;
            self.disconnect_due = self.in_control;
            self.remote_lost();
        }

        /// The remote stops counting: the link is down or the pad is being switched off.
        fn remote_lost(&mut self) {
            if self.remote_holds() {
                self.can_waits_for_rest = true;
            }
            self.remote_reported = false;
            self.remote_held = false;
            self.remote_armed = false;
        }

        /// After every input: registers that changed (the register write itself)
        /// clamp the speed level into the new range at once.
        pub fn registers_now(&mut self, registers: &Registers) {
            if let Session::Connected { level_mm_s, .. } = &mut self.pad {
                *level_mm_s = level_within(*level_mm_s, registers);
            }
        }

        /// A report from a connected pad: L2 + Home switches it off; otherwise the D-pad
        /// steps the level, and the dead-man and sticks go to the supervisor.
        fn gamepad(
            &mut self,
            pad: GamepadState,
            now: Timestamp,
            before: Mode,
            registers: &Registers,
        ) {
            let Session::Connected {
                level_mm_s, last, ..
            } = self.pad
            else {
                // The task has not dropped it yet: ask again.
                if matches!(self.pad, Session::SwitchingOff) {
                    self.disconnect_due = self.in_control;
                }
                return;
            };
            let previous = last.unwrap_or_default();
            let pressed = |button: Buttons| {
                pad.buttons.contains(button) && !previous.buttons.contains(button)
            };
            if pad.left_trigger > MODIFIER_THRESHOLD && pressed(Buttons::HOME) {
                self.switch_off();
                return;
            }
            let mut level_mm_s = level_within(level_mm_s, registers);
            match (
                pad.dpad.up && !previous.dpad.up,
                pad.dpad.down && !previous.dpad.down,
            ) {
                (true, false) => level_mm_s += 50,
                (false, true) => level_mm_s -= 50,
                _ => {}
            }
            self.pad = Session::Connected {
                level_mm_s: level_within(level_mm_s, registers),
                last: Some(pad),
                last_input: now,
            };

            let dead_man = dead_man(&pad);
            let was_holding = self.remote_holds();
            if !dead_man && may_drive(before) && !self.locked {
                self.remote_armed = true;
            }
            self.remote_reported = true;
            self.remote_held = dead_man;
            if self.remote_holds() && !was_holding {
                // The remote takes over, armed or not: CAN needs a fresh velocity
                // afterwards.
                self.can = None;
            }
            if was_holding && !self.remote_holds() {
                self.can_waits_for_rest = true;
            }
        }

        /// Updates the model with one input; `before` is the mode the input met.
        pub fn observe(
            &mut self,
            input: &Input,
            now: Timestamp,
            before: Mode,
            registers: &Registers,
        ) {
            self.disconnect_due = None;
            self.pairing_change = None;
            if registers.get(Reg::BluetoothOff) != 0 && input.is_from_a_remote_task() {
                // Bluetooth is off: no pad exists for the controller.
                return;
            }
            match *input {
                Input::CanFrame(frame) => match Command::decode(frame.id(), frame.data()) {
                    // A refreshing enable and a velocity are refused while locked.
                    Ok(Some(Command::Enable { refresh: true } | Command::Velocity { .. }))
                        if self.locked => {}
                    Ok(Some(Command::Enable { refresh: true })) => {
                        if !self.enable_fresh(now, registers) {
                            self.session += 1;
                        }
                        self.enable_refreshed = Some(now);
                    }
                    Ok(Some(Command::Enable { refresh: false })) => {
                        self.enable_refreshed = None;
                        self.session += 1;
                    }
                    Ok(Some(Command::RegisterWrite {
                        address: 40,
                        value: OPEN_PAIRING_WINDOW_KEY,
                    })) => {
                        self.pairing_until = Some(now.plus_millis(PAIRING_WINDOW_MS));
                        self.pairing_change = Some(true);
                    }
                    // Stored only when it may drive, as the supervisor's rules say.
                    Ok(Some(Command::Velocity {
                        linear_mm_s,
                        rotation_mrad_s,
                    })) if self.enable_fresh(now, registers)
                        && may_drive(before)
                        && !self.remote_holds()
                        && !self.can_waits_for_rest =>
                    {
                        self.can = Some(CanVelocity {
                            twist: Twist {
                                linear_mm_s: linear_mm_s.into(),
                                rotation_mrad_s: rotation_mrad_s.into(),
                            },
                            received: now,
                            session: self.session,
                        });
                    }
                    _ => {}
                },
                // Only the pad in control's reports count; of a connected waiting
                // pad's, its dead-man is kept.
                Input::Gamepad { pad, state } if self.in_control == Some(pad) => {
                    self.gamepad(state, now, before, registers)
                }
                Input::Gamepad { pad, state } if self.links[pad as usize] => {
                    self.waiting_held[pad as usize] = dead_man(&state);
                }
                Input::RemoteLink { pad, connected, .. } => {
                    self.links[pad as usize] = connected;
                    if !connected {
                        self.waiting_held[pad as usize] = false;
                    }
                    let other = if pad == Pad::Ble {
                        Pad::Classic
                    } else {
                        Pad::Ble
                    };
                    if connected && self.in_control.is_none() {
                        self.in_control = Some(pad);
                        self.connect(now, registers);
                    } else if !connected && self.in_control == Some(pad) {
                        self.pad = Session::Offline;
                        self.remote_lost();
                        self.in_control = None;
                        if self.links[other as usize] {
                            self.in_control = Some(other);
                            self.connect(now, registers);
                            // A dead-man held while the pad waited counts as held from
                            // the hand-over, alone (sticks centred): it takes control
                            // from CAN, and drives only after a release.
                            if std::mem::take(&mut self.waiting_held[other as usize]) {
                                let dead_man_alone = GamepadState {
                                    buttons: Buttons::RIGHT_BUMPER,
                                    ..GamepadState::default()
                                };
                                self.gamepad(dead_man_alone, now, before, registers);
                            }
                        }
                    }
                }
                Input::UpdateLock(locked) if locked != self.locked => {
                    self.locked = locked;
                    if locked {
                        self.can = None;
                        self.remote_armed = false;
                    } else {
                        self.remote_armed =
                            may_drive(before) && self.remote_reported && !self.remote_held;
                    }
                }
                // One new bond per opening of the window.
                Input::RemotePaired => {
                    if self.pairing_until.take().is_some() {
                        self.pairing_change = Some(false);
                    }
                }
                // No input for PS_afk_time switches the pad off; a held dead-man is
                // input (checked on the tick).
                Input::Tick => {
                    if self.pairing_until.is_some_and(|until| now >= until) {
                        self.pairing_until = None;
                        self.pairing_change = Some(false);
                    }
                    if let Session::Connected {
                        last, last_input, ..
                    } = self.pad
                    {
                        let afk_ms = u64::from(registers.get(Reg::PsAfkTime));
                        if !last.is_some_and(|pad| dead_man(&pad))
                            && now.millis_since(last_input) >= afk_ms
                        {
                            self.switch_off();
                        }
                    }
                }
                Input::Estop(pressed) => {
                    self.estop_pressed = pressed;
                    if pressed {
                        // Nothing is buffered through an emergency.
                        self.can = None;
                        self.remote_armed = false;
                    }
                }
                Input::SafetyZone(occupied) => self.safety_zone = occupied,
                Input::DrivesReady if matches!(before, Mode::Starting | Mode::Recovering) => {
                    self.remote_armed = self.remote_reported && !self.remote_held && !self.locked;
                    self.can_waits_for_rest = false;
                }
                Input::DriveFeedback { rpm, .. } => {
                    let standing = -AT_REST_RPM..=AT_REST_RPM;
                    if standing.contains(&rpm.left) && standing.contains(&rpm.right) {
                        self.can_waits_for_rest = false;
                    }
                }
                // A drive fault outside an emergency forgets every command, like an e-stop.
                Input::DriveSilent(_) | Input::DriveAlarm { .. } if may_drive(before) => {
                    self.can = None;
                    self.remote_armed = false;
                }
                _ => {}
            }
        }
    }
}

use model::Model;

// ---------------------------------------------------------------------------------------
// The harness
// ---------------------------------------------------------------------------------------

/// What can be observed of the controller at one moment.
#[derive(Debug, Clone)]
struct Snapshot {
    registers: Registers,
    mode: Mode,
    emergency: bool,
    status: Status,
    pose: Pose,
    /// What the controller takes the drives to run at: a new ramp starts here.
    estimated: MotorRpm,
}

impl Snapshot {
    fn of(controller: &Controller, now: Timestamp) -> Self {
        Self {
            estimated: controller.estimated_rpm(now),
            registers: controller.registers().clone(),
            mode: controller.supervisor().mode(),
            emergency: controller.supervisor().in_emergency(),
            status: controller.status(now),
            pose: controller.odometry().pose(),
        }
    }
}

/// One event and everything around it.
struct Step<'a> {
    now: Timestamp,
    input: &'a Input,
    out: &'a Output,
    before: &'a Snapshot,
    after: &'a Snapshot,
    /// The motor speeds the drives were told last, before this event.
    in_force_before: MotorRpm,
    /// The same after this event: what the drives run at from now on.
    in_force: MotorRpm,
    /// The drives were told to excite (brakes released) and not to de-excite since.
    excited: bool,
    /// The latest drive feedback before this event measured a wheel turning (and the
    /// drives were not set up from scratch since).
    measured_moving: bool,
    /// The model after this event.
    model: &'a Model,
}

/// Feeds `sequence` to a controller booted at 0 with the register defaults (and
/// Bluetooth off if the sequence says so) and calls `check` after every event.
fn run(
    sequence: &Sequence,
    mut check: impl FnMut(&Step) -> Result<(), TestCaseError>,
) -> Result<(), TestCaseError> {
    let mut now = Timestamp::BOOT;
    let boot = BootReport {
        bluetooth_off_after_panics: sequence.bluetooth_off,
        ..BootReport::default()
    };
    let mut controller = Controller::boot(now, Registers::defaults(), &boot);
    let events = &sequence.events;
    let mut model = Model::default();
    let mut in_force = MotorRpm::ZERO;
    let mut excited = false;
    // The drive link sets the drives up at boot and when the controller asks; only then
    // does its DrivesReady mean "set up from scratch". The sequences also carry
    // unrequested ones, which must not break any invariant either.
    let mut setup_requested = true;
    let mut measured_moving = false;
    for (gap, input) in events {
        now = now.plus_millis(*gap);
        let before = Snapshot::of(&controller, now);
        let out = controller.handle(now, *input);
        let after = Snapshot::of(&controller, now);

        let in_force_before = in_force;
        let measured_moving_before = measured_moving;
        if *input == Input::DrivesReady && setup_requested {
            // The drives were set up from scratch: they stand, de-excited, until told
            // otherwise.
            in_force = MotorRpm::ZERO;
            excited = false;
            setup_requested = false;
            measured_moving = false;
        }
        if let Input::DriveFeedback { rpm, .. } = input {
            let standing = -AT_REST_RPM..=AT_REST_RPM;
            measured_moving = !(standing.contains(&rpm.left) && standing.contains(&rpm.right));
        }
        setup_requested |= out.setup_drives;
        if let Some(command) = out.wheels {
            in_force = command.rpm;
        }
        if let Some(excite) = out.excite {
            excited = excite;
        }
        model.observe(input, now, before.mode, &before.registers);
        model.registers_now(&after.registers);

        check(&Step {
            now,
            input,
            out: &out,
            before: &before,
            after: &after,
            in_force_before,
            in_force,
            excited,
            measured_moving: measured_moving_before,
            model: &model,
        })?;
    }
    Ok(())
}

fn is_zero(rpm: MotorRpm) -> bool {
    rpm == MotorRpm::ZERO
}

fn is_feedback(frame: &RawFrame) -> bool {
    matches!(
        frame.id(),
        id::WEIGHT | id::BATTERY | id::POSITION | id::HEADING | id::POSE_TIME | id::MEASURED_SPEED
    )
}

fn is_periodic(frame: &RawFrame) -> bool {
    is_feedback(frame) || frame.id() == id::STATUS
}

/// The kinematics the registers describe (docs/behaviour.md, "Wheel speeds", and the register units).
fn kinematics_params(registers: &Registers) -> KinematicsParams {
    let motor_dir = registers.get(Reg::MotorDir);
    KinematicsParams {
        left_radius_mm: registers.get(Reg::RadL).into(),
        right_radius_mm: registers.get(Reg::RadR).into(),
        wheel_distance_mm: registers.get(Reg::WheelDist).into(),
        gear_ratio: f32::from(registers.get(Reg::GearRatio)) / 100.0,
        max_motor_rpm: registers.get(Reg::MaxMotorVel).into(),
        invert_left: motor_dir & MOTOR_DIR_INVERT_LEFT != 0,
        invert_right: motor_dir & MOTOR_DIR_INVERT_RIGHT != 0,
    }
}

/// The motor speeds `twist` asks for under the registers and the safety zone: in the
/// zone the twist is clamped and the motors are limited to `sec_motor_vel` as well.
fn expected_rpm(twist: Twist, safety_zone: bool, registers: &Registers) -> MotorRpm {
    let mut params = kinematics_params(registers);
    let twist = if safety_zone {
        params.max_motor_rpm = params
            .max_motor_rpm
            .min(registers.get(Reg::SecMotorVel).into());
        twist.clamped(SafetyLimits {
            linear_mm_s: registers.get(Reg::SecLinVel),
            rotation_mrad_s: registers.get(Reg::SecTurnVel),
        })
    } else {
        twist
    };
    kinematics::motor_rpm(&params, twist)
}

/// Inputs the supervisor never sees: they must never touch the wheels. (A frame that
/// changes a register, calibrations included, gives the supervisor a step so the change
/// applies to the running command.)
fn never_commands_wheels(input: &Input) -> bool {
    match input {
        Input::CanFrame(frame) => !matches!(
            Command::decode(frame.id(), frame.data()),
            Ok(Some(
                Command::Enable { .. }
                    | Command::Velocity { .. }
                    | Command::RegisterWrite { .. }
                    | Command::ScaleCalibration(_)
                    | Command::OdometryCalibration(_)
            ))
        ),
        Input::RemoteLink {
            connected: true, ..
        }
        | Input::ModbusError
        | Input::ScaleSample(_)
        | Input::ScaleMissing
        | Input::BatterySample { .. }
        | Input::CanBusFault
        | Input::FlashFault => true,
        _ => false,
    }
}

/// Inputs that always give the supervisor a step (timeouts are checked in every step).
fn supervisor_sees(input: &Input) -> bool {
    match input {
        Input::CanFrame(frame) => matches!(
            Command::decode(frame.id(), frame.data()),
            Ok(Some(Command::Enable { .. } | Command::Velocity { .. }))
        ),
        Input::Estop(_)
        | Input::SafetyZone(_)
        | Input::UpdateLock(_)
        | Input::DriveFeedback { .. }
        | Input::DrivesReady
        | Input::DriveSilent(_)
        | Input::DriveAlarm { .. }
        | Input::Tick => true,
        _ => false,
    }
}

/// Inputs that can only ever stop the wheels. Every other input the supervisor sees
/// (even a confirm press or a duplicate e-stop release) re-applies the safety-zone
/// limits in force, so it may legitimately change a running command.
fn never_starts_wheels(input: &Input) -> bool {
    never_commands_wheels(input)
        || matches!(
            input,
            Input::Estop(true) | Input::DriveSilent(_) | Input::DriveAlarm { .. }
        )
}

fn proptest_config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        ..ProptestConfig::default()
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 1: the speed limit
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// Every wheel command respects `max_motor_vel` as it is at that moment, whatever
    /// the twist, the geometry registers and the writes to the limit itself.
    #[test]
    fn wheel_commands_never_exceed_max_motor_vel(events in sequence()) {
        run(&events, |step| {
            if let Some(command) = step.out.wheels {
                let max = i64::from(step.after.registers.get(Reg::MaxMotorVel));
                prop_assert!(
                    i64::from(command.rpm.left).abs() <= max
                        && i64::from(command.rpm.right).abs() <= max,
                    "{:?} exceeds max_motor_vel {} at {:?} after {:?}",
                    command, max, step.now, step.input
                );
            }
            Ok(())
        })?;
    }

    /// The speed the drives run at never exceeds `max_motor_vel` either: a limit (or
    /// geometry) written while the base moves applies to the command already running,
    /// not only to the next one (a write is applied at once, docs/registers.md).
    #[test]
    fn speed_in_force_never_exceeds_max_motor_vel(events in sequence()) {
        run(&events, |step| {
            let max = i64::from(step.after.registers.get(Reg::MaxMotorVel));
            prop_assert!(
                i64::from(step.in_force.left).abs() <= max
                    && i64::from(step.in_force.right).abs() <= max,
                "{:?} in force above max_motor_vel {} at {:?} after {:?}",
                step.in_force, max, step.now, step.input
            );
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 2: nothing but zero outside Active; the e-stop stops at once
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// Only `Active` may command motion: in every other mode (Starting, Standby,
    /// Emergency, AwaitingConfirm, Recovering, Fault), and while the e-stop is pressed,
    /// any wheel command is zero on both wheels and the drives are never excited.
    #[test]
    fn only_active_mode_commands_non_zero_speed(events in sequence()) {
        run(&events, |step| {
            let held_still = step.after.mode != Mode::Active
                || step.after.emergency
                || step.model.estop_pressed;
            if let Some(command) = step.out.wheels {
                prop_assert!(
                    !held_still || is_zero(command.rpm),
                    "{:?} in {:?} (emergency {}, e-stop {}) after {:?}",
                    command, step.after.mode, step.after.emergency,
                    step.model.estop_pressed, step.input
                );
            }
            if step.after.emergency || step.model.estop_pressed {
                prop_assert_ne!(step.out.excite, Some(true), "excited in an emergency");
                prop_assert!(is_zero(step.in_force), "{:?} in force in an emergency", step.in_force);
            }
            Ok(())
        })?;
    }

    /// An e-stop press, and a drive fault outside an emergency, put zero on both wheels
    /// in the same output, with `estop_decel`: the wheel with the larger change (and a
    /// wheel that does not change) ramps with exactly `estop_decel`, the other with its
    /// share of it, so both stop together.
    #[test]
    fn estop_and_drive_faults_stop_at_once_with_estop_decel(events in sequence()) {
        run(&events, |step| {
            let may_drive = matches!(step.before.mode, Mode::Standby | Mode::Active);
            let stops = match step.input {
                Input::Estop(true) => true,
                Input::DriveSilent(_) | Input::DriveAlarm { .. } => may_drive,
                _ => false,
            };
            if !stops {
                return Ok(());
            }
            let decel = u32::from(step.after.registers.get(Reg::EstopDecel));
            let Some(command) = step.out.wheels else {
                return Err(TestCaseError::fail(format!(
                    "no wheel command after {:?} in {:?}", step.input, step.before.mode
                )));
            };
            prop_assert!(is_zero(command.rpm), "{:?} after {:?}", command, step.input);
            // The ramp starts from the speed the drives run at.
            let from = step.before.estimated;
            let delta_left = i64::from(from.left).unsigned_abs();
            let delta_right = i64::from(from.right).unsigned_abs();
            let largest = delta_left.max(delta_right);
            for (delta, accel) in [(delta_left, command.left_accel), (delta_right, command.right_accel)] {
                if delta == largest || delta == 0 {
                    prop_assert_eq!(accel, decel, "from {:?}: {:?}", from, command);
                } else {
                    prop_assert!(
                        (1..=decel).contains(&accel),
                        "from {:?}: {:?} (estop_decel {})", from, command, decel
                    );
                }
            }
            if matches!(step.input, Input::Estop(true)) {
                prop_assert_eq!(step.after.mode, Mode::Emergency);
            } else {
                prop_assert_eq!(step.after.mode, Mode::Fault);
            }
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 3: no feedback frames in an emergency
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// No 0x0EA..0x0ED frame leaves in an output produced in emergency mode, the output
    /// of the e-stop press itself included (the mode after the event is the one in force
    /// when the output is composed); the status frame 0x0EE keeps coming. Emergency mode
    /// (Emergency, AwaitingConfirm) starts only with an e-stop press, lasts while it is
    /// held, and ends only with a confirm press (a short button press) after the release.
    #[test]
    fn no_feedback_frames_while_in_emergency(events in sequence()) {
        run(&events, |step| {
            if step.model.estop_pressed {
                prop_assert_eq!(step.after.mode, Mode::Emergency, "e-stop held");
            }
            prop_assert_eq!(
                step.after.emergency,
                matches!(step.after.mode, Mode::Emergency | Mode::AwaitingConfirm)
            );
            if step.after.emergency && !step.before.emergency {
                prop_assert_eq!(*step.input, Input::Estop(true), "emergency entered");
            }
            if step.before.emergency && !step.after.emergency {
                prop_assert_eq!(*step.input, Input::Button(false), "emergency left");
                prop_assert_eq!(step.after.mode, Mode::Recovering);
            }
            if step.after.emergency {
                let feedback: Vec<_> = step.out.frames.iter().filter(|f| is_feedback(f)).collect();
                prop_assert!(
                    feedback.is_empty(),
                    "{:?} sent in {:?} after {:?}", feedback, step.after.mode, step.input
                );
            }
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 4: any CAN input is safe; malformed frames are counted and change nothing
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(2 * CASES))]

    /// No CAN frame makes the controller panic (random IDs, every known ID with random
    /// lengths and bytes). A frame with a known ID that does not decode increments the
    /// status frame's rejected_count by one, names its reason and ID, and changes
    /// nothing else; a frame for someone else changes nothing at all.
    #[test]
    fn malformed_known_id_frames_are_counted_and_change_nothing(events in frame_sequence()) {
        run(&events, |step| {
            let Input::CanFrame(frame) = step.input else {
                return Ok(());
            };
            let decoded = Command::decode(frame.id(), frame.data());
            let before = &step.before.status;
            let after = &step.after.status;
            match decoded {
                Ok(Some(_)) => return Ok(()),
                Ok(None) => prop_assert_eq!(
                    after.rejected_count, before.rejected_count,
                    "{:?} is not for us", frame
                ),
                Err(error) => {
                    prop_assert_eq!(
                        after.rejected_count, before.rejected_count.wrapping_add(1),
                        "{:?} rejected as {:?}", frame, error
                    );
                    prop_assert_eq!(after.last_rejection, error.code());
                    prop_assert_eq!(after.last_rejection_subject, frame.id().to_le_bytes()[0]);
                }
            }
            let out = step.out;
            prop_assert!(out.frames.iter().all(is_periodic), "{:?} answered {:?}", frame, out.frames);
            prop_assert_eq!(out.wheels, None);
            prop_assert_eq!(out.excite, None);
            prop_assert!(!out.setup_drives);
            prop_assert_eq!(out.pc_switch, None);
            prop_assert_eq!(out.disconnect_remote, None);
            prop_assert_eq!(out.pairing_window, None);
            prop_assert_eq!(&out.persist, &Default::default());
            prop_assert_eq!(&step.after.registers, &step.before.registers);
            prop_assert_eq!(step.after.mode, step.before.mode);
            prop_assert_eq!(step.after.status.control, step.before.status.control);
            prop_assert_eq!(step.after.pose, step.before.pose);
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 5: who may move the wheels
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// A non-zero wheel command needs a source the contract allows: mode Active with the
    /// drives excited, the e-stop released, no drive fault, and either
    /// - the remote in control (dead-man held, and seen released since the base could
    ///   drive), the command being exactly the remote's twist, or
    /// - the remote not in control, a CAN enable fresh at this moment (no lapse or
    ///   withdrawal since the velocity arrived, `cmd_timeout` not expired), the command
    ///   being exactly that velocity,
    ///
    /// each clamped to the safety zone and turned into motor speeds with the registers
    /// in force; the status frame names that source. Inputs the supervisor never sees
    /// never carry a wheel command, and an e-stop press or a drive fault never a
    /// non-zero one.
    #[test]
    fn wheels_move_only_for_a_fresh_can_enable_or_an_armed_dead_man(events in sequence()) {
        run(&events, |step| {
            if never_commands_wheels(step.input) {
                prop_assert_eq!(step.out.wheels, None, "{:?} commanded the wheels", step.input);
            }
            let Some(command) = step.out.wheels.filter(|c| !is_zero(c.rpm)) else {
                return Ok(());
            };
            prop_assert!(!never_starts_wheels(step.input), "{:?} started {:?}", step.input, command);
            let status = &step.after.status;
            prop_assert_eq!(step.after.mode, Mode::Active);
            prop_assert!(
                step.excited && !status.flags.brakes_applied,
                "moving against the brakes"
            );
            prop_assert!(!step.model.estop_pressed);
            prop_assert!(!status.faults.left_drive_silent && !status.faults.left_drive_alarm
                && !status.faults.right_drive_silent && !status.faults.right_drive_alarm);
            let Some((source, twist)) = step.model.source(step.now, &step.after.registers) else {
                return Err(TestCaseError::fail(format!(
                    "{command:?} after {:?} with no source allowed: {:?}", step.input, step.model
                )));
            };
            prop_assert_eq!(status.control, source, "{:?}", step.model);
            if source == ControlSource::Can {
                prop_assert!(status.flags.enable_fresh);
            } else {
                prop_assert!(status.flags.remote_in_control);
            }
            prop_assert_eq!(
                command.rpm,
                expected_rpm(twist, step.model.safety_zone, &step.after.registers),
                "{:?} from {:?}", source, twist
            );
            Ok(())
        })?;
    }

    /// Once no source may drive (enable lapsed or withdrawn, velocity stale, dead-man
    /// released or link lost, e-stop, drive fault), the next tick, or any other input the
    /// supervisor sees, leaves the drives at zero: nothing keeps moving on an old command.
    #[test]
    fn without_a_source_the_next_supervised_step_stops_the_wheels(events in sequence()) {
        run(&events, |step| {
            if !supervisor_sees(step.input) {
                return Ok(());
            }
            let driving = matches!(step.after.mode, Mode::Active)
                && step.model.source(step.now, &step.after.registers).is_some();
            if !driving {
                prop_assert!(
                    is_zero(step.in_force),
                    "{:?} still in force at {:?} in {:?}: {:?}",
                    step.in_force, step.now, step.after.mode, step.model
                );
            }
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 6: only well-formed reports go out
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// Every frame the controller emits decodes as a report and encodes back to the same
    /// bytes; every register read request is answered by exactly one 0x004 frame that
    /// carries the register's value or the reason for the refusal.
    #[test]
    fn every_emitted_frame_is_a_well_formed_report(events in sequence()) {
        run(&events, |step| {
            for frame in &step.out.frames {
                let report = Report::decode(frame.id(), frame.data());
                let Ok(Some(report)) = report else {
                    return Err(TestCaseError::fail(format!("{frame:?} decodes as {report:?}")));
                };
                prop_assert_eq!(report.encode(), *frame);
            }
            let Input::CanFrame(frame) = step.input else {
                return Ok(());
            };
            if let Ok(Some(Command::RegisterRead { address, tag })) =
                Command::decode(frame.id(), frame.data())
            {
                let replies: Vec<_> = step
                    .out
                    .frames
                    .iter()
                    .filter(|f| f.id() == id::REGISTER_READ)
                    .map(|f| Report::decode(f.id(), f.data()))
                    .collect();
                let expected = match step.after.registers.read(address) {
                    Ok(value) => Report::RegisterValue {
                        value,
                        echo: Some(ReadEcho { address, tag }),
                    },
                    Err(error) => Report::RegisterReadError {
                        address,
                        reason: error.code(),
                        tag: Some(tag),
                    },
                };
                prop_assert_eq!(replies, vec![Ok(Some(expected))]);
            }
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 7: the gamepad is switched off when docs/remote.md says so, and only then; the
// pairing window opens only on its key
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// The BLE task is asked to disconnect the pad exactly when L2 + Home is pressed,
    /// when no input came for `PS_afk_time` with the dead-man up, and for each report
    /// the pad still sends after that; from then on the remote is not in control.
    #[test]
    fn the_gamepad_is_switched_off_by_l2_home_or_afk_only(events in sequence()) {
        run(&events, |step| {
            prop_assert_eq!(
                step.out.disconnect_remote, step.model.disconnect_due,
                "after {:?}: {:?}", step.input, step.model
            );
            if step.out.disconnect_remote.is_some() {
                prop_assert!(!step.after.status.flags.remote_in_control);
                prop_assert_ne!(step.after.status.control, ControlSource::Remote);
            }
            Ok(())
        })?;
    }

    /// While Bluetooth is off after a panic loop its tasks do not run; should a pad's
    /// link or report still arrive, it changes nothing: no wheel command, no control,
    /// no remote flag, no switch-off, no pairing change.
    #[test]
    fn pad_inputs_change_nothing_while_bluetooth_is_off(events in sequence()) {
        run(&events, |step| {
            if step.before.registers.get(Reg::BluetoothOff) == 0
                || !step.input.is_from_a_remote_task()
            {
                return Ok(());
            }
            prop_assert_eq!(step.out.wheels, None);
            prop_assert_eq!(step.out.excite, None);
            prop_assert_eq!(step.out.disconnect_remote, None);
            prop_assert_eq!(step.out.pairing_window, None);
            let (before, after) = (&step.before.status, &step.after.status);
            prop_assert_eq!(after.control, before.control);
            prop_assert!(!after.flags.remote_connected && !after.flags.remote_in_control);
            prop_assert!(!after.flags.remote_bonded);
            Ok(())
        })?;
    }

    /// The pairing window opens only on its `command` key and closes only when its
    /// minute is up (seen on a tick) or on the first new bond; the output says so with
    /// exactly those inputs, and no other input touches it.
    #[test]
    fn the_pairing_window_opens_only_on_its_key_and_closes_on_time_or_a_bond(events in sequence()) {
        run(&events, |step| {
            prop_assert_eq!(
                step.out.pairing_window, step.model.pairing_change,
                "after {:?} at {:?}", step.input, step.now
            );
            Ok(())
        })?;
    }
}

// ---------------------------------------------------------------------------------------
// Invariant 8: stops a safety engineer signs off
// ---------------------------------------------------------------------------------------

/// The longest any stop but the e-stop may take: `max_motor_vel` at `stop_decel`'s
/// lowest value, 4000 1/min at 2000 (1/min)/s.
const STOP_BOUND_MS: u64 = 2000;

/// A zero command that stops a moving base after every source went away (the model
/// allows none), other than the e-stop and a drive fault (checked above): its
/// command, and the speeds it ramps from.
fn lost_source_stop(step: &Step) -> Option<kinematics::WheelCommand> {
    let command = step.out.wheels.filter(|c| is_zero(c.rpm))?;
    let estop_or_fault = matches!(
        step.input,
        Input::Estop(true) | Input::DriveSilent(_) | Input::DriveAlarm { .. }
    );
    (!estop_or_fault
        && !is_zero(step.in_force_before)
        && step.before.mode == Mode::Active
        && step.model.source(step.now, &step.after.registers).is_none())
    .then_some(command)
}

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// Every stop of a source that went away (enable lapse or withdrawal, `cmd_timeout`,
    /// dead-man release, link loss) brakes with at least `stop_decel`, whatever
    /// `CAN_accel` and `Contr_acc_high` say, so both wheels stand within
    /// `max_motor_vel / stop_decel` ≤ 2 s of the command.
    #[test]
    fn every_stop_completes_within_its_bound(events in sequence()) {
        run(&events, |step| {
            let Some(command) = lost_source_stop(step) else {
                return Ok(());
            };
            let registers = &step.after.registers;
            let stop_decel = u32::from(registers.get(Reg::StopDecel));
            let accel = command.left_accel.max(command.right_accel);
            prop_assert!(
                accel >= stop_decel,
                "{:?} after {:?}: gentler than stop_decel {}", command, step.input, stop_decel
            );
            // The wheel with the larger change ramps with `accel`, the other arrives with
            // it; the drives never run faster than max_motor_vel.
            let from = step.before.estimated;
            let largest = i64::from(from.left).abs().max(i64::from(from.right).abs());
            let max = i64::from(registers.get(Reg::MaxMotorVel));
            prop_assert!(largest <= max, "estimate {:?} above max_motor_vel", from);
            let stop_ms = (max * 1000).unsigned_abs().div_ceil(u64::from(accel));
            prop_assert!(
                stop_ms <= STOP_BOUND_MS,
                "{:?}: {} ms to stop from max_motor_vel {}", command, stop_ms, max
            );
            Ok(())
        })?;
    }

    /// The motion registers (geometry, gear ratio, motor directions, speed and zone
    /// limits) never change while the base moves: commanded to move, or measured
    /// moving. A write then is refused with `NotAtRest`.
    #[test]
    fn motion_registers_change_only_at_standstill(events in sequence()) {
        run(&events, |step| {
            if is_zero(step.in_force_before) && !step.measured_moving {
                return Ok(());
            }
            for reg in Reg::ALL.into_iter().filter(|reg| reg.changes_motion()) {
                prop_assert_eq!(
                    step.before.registers.get(reg),
                    step.after.registers.get(reg),
                    "{:?} changed while moving ({:?} in force) after {:?}",
                    reg, step.in_force_before, step.input
                );
            }
            Ok(())
        })?;
    }
}

/// Drives as the controller's model of them: each ramps linearly from its speed towards
/// the command in force at the command's rate.
#[derive(Debug, Clone, Copy, Default)]
struct DriveModel {
    left: f64,
    right: f64,
    command: Option<kinematics::WheelCommand>,
}

impl DriveModel {
    fn advance(&mut self, ms: u64) {
        let Some(command) = self.command else { return };
        let toward = |speed: f64, target: i32, accel: u32| {
            let step = f64::from(accel) * ms as f64 / 1000.0;
            let target = f64::from(target);
            if speed < target {
                (speed + step).min(target)
            } else {
                (speed - step).max(target)
            }
        };
        self.left = toward(self.left, command.rpm.left, command.left_accel);
        self.right = toward(self.right, command.rpm.right, command.right_accel);
    }

    fn measured(&self) -> MotorRpm {
        MotorRpm {
            left: self.left.round() as i32,
            right: self.right.round() as i32,
        }
    }
}

proptest! {
    #![proptest_config(proptest_config(CASES))]

    /// The real wheel speed never exceeds the safety zone's limit, whatever the
    /// registers: the drives here ramp as real ones do and report their real speed in
    /// every drive feedback. Once someone is in the zone, every command is within
    /// `sec_motor_vel` (a motor limit: a wrong radius or gear ratio cannot defeat it;
    /// the wheel's real speed is this over the real gear times the real circumference),
    /// and within `max_motor_vel / estop_decel` (≤ 300 ms by the e-stop rule) the motors
    /// run within it, up to the 2 r/min the drives' readings wobble by.
    #[test]
    fn the_motor_speed_never_exceeds_the_safety_zone_limit(events in sequence()) {
        let mut now = Timestamp::BOOT;
        let mut controller = Controller::new(now, Registers::defaults());
        let mut drives = DriveModel::default();
        let mut zone_since: Option<Timestamp> = None;
        for (gap, input) in &events.events {
            drives.advance(*gap);
            now = now.plus_millis(*gap);
            let input = match *input {
                Input::DriveFeedback { counts, .. } => Input::DriveFeedback {
                    counts,
                    rpm: drives.measured(),
                },
                Input::DrivesReady if matches!(
                    controller.supervisor().mode(),
                    Mode::Starting | Mode::Recovering
                ) => {
                    // Set up from scratch: the drives stand.
                    drives = DriveModel::default();
                    Input::DrivesReady
                }
                // Unasked, it means nothing to the drives.
                Input::DrivesReady => Input::Tick,
                other => other,
            };
            let out = controller.handle(now, input);
            if out.wheels.is_some() {
                drives.command = out.wheels;
            }
            let registers = controller.registers();
            let zone = controller.supervisor().safety_zone();
            zone_since = match (zone, zone_since) {
                (false, _) => None,
                (true, None) => Some(now),
                (true, since) => since,
            };
            let Some(since) = zone_since else { continue };
            let limit = i32::from(registers.get(Reg::SecMotorVel).min(registers.get(Reg::MaxMotorVel)));
            if let Some(command) = out.wheels {
                prop_assert!(
                    command.rpm.left.abs() <= limit && command.rpm.right.abs() <= limit,
                    "{:?} in the zone (limit {}) after {:?}", command, limit, input
                );
            }
            let brake_ms = (u64::from(registers.get(Reg::MaxMotorVel)) * 1000)
                .div_ceil(u64::from(registers.get(Reg::EstopDecel)));
            if now.millis_since(since) > brake_ms {
                let tolerance = f64::from(limit + AT_REST_RPM) + 0.5;
                prop_assert!(
                    drives.left.abs() <= tolerance && drives.right.abs() <= tolerance,
                    "drives at ({:.1}, {:.1}) r/min {} ms into the zone (limit {}) at {:?}",
                    drives.left, drives.right, now.millis_since(since), limit, now
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// The strategies reach what the properties are about
// ---------------------------------------------------------------------------------------

fn moving_command(step: &Step) -> Option<MotorRpm> {
    step.out.wheels.map(|c| c.rpm).filter(|rpm| !is_zero(*rpm))
}

fn changes_kinematics(step: &Step) -> bool {
    KINEMATIC_REGISTERS
        .into_iter()
        .any(|reg| step.before.registers.get(reg) != step.after.registers.get(reg))
}

/// A situation the properties are about, recognised in one step.
type Situation = (&'static str, fn(&Step) -> bool);

/// How often the situations the properties check occur in `sequence()`: a property over
/// sequences that never drive, never enter an emergency or never reject a frame would
/// pass vacuously. Each must occur in at least a fifth of the sequences.
#[test]
fn event_sequences_reach_every_situation_checked() {
    const SITUATIONS: usize = 22;
    let situations: [Situation; SITUATIONS] = [
        ("CAN drives", |step| {
            moving_command(step).is_some() && step.after.status.control == ControlSource::Can
        }),
        ("remote drives", |step| {
            moving_command(step).is_some() && step.after.status.control == ControlSource::Remote
        }),
        ("remote drives above its start level", |step| {
            step.after.status.control == ControlSource::Remote
                && moving_command(step).is_some()
                && step.model.remote_level_mm_s() > Some(step.after.registers.get(Reg::PsRelMaxVel))
        }),
        ("gamepad asked to disconnect", |step| {
            step.out.disconnect_remote.is_some()
        }),
        ("pairing window closed", |step| {
            step.out.pairing_window == Some(false)
        }),
        ("speed limited to max_motor_vel", |step| {
            let max = i32::from(step.after.registers.get(Reg::MaxMotorVel));
            moving_command(step).is_some_and(|rpm| rpm.left.abs() == max || rpm.right.abs() == max)
        }),
        ("safety zone while moving", |step| {
            step.model.safety_zone && moving_command(step).is_some()
        }),
        ("motion register refused while moving", |step| {
            !is_zero(step.in_force_before)
                && step.after.status.rejected_count != step.before.status.rejected_count
                && step.after.status.last_rejection == RegisterError::NotAtRest.code()
        }),
        ("limit or geometry written at standstill", |step| {
            is_zero(step.in_force_before) && changes_kinematics(step)
        }),
        ("a lost source stopped with its floor", |step| {
            lost_source_stop(step).is_some()
        }),
        ("e-stop while moving", |step| {
            !is_zero(step.in_force_before) && *step.input == Input::Estop(true)
        }),
        ("drive fault while moving", |step| {
            !is_zero(step.in_force_before)
                && step.before.mode == Mode::Active
                && step.after.mode == Mode::Fault
        }),
        ("a lost source stopped by the next step", |step| {
            supervisor_sees(step.input) && !is_zero(step.in_force_before) && is_zero(step.in_force)
        }),
        ("recovery completed", |step| {
            step.before.mode == Mode::Recovering && step.after.mode == Mode::Standby
        }),
        ("feedback frames sent", |step| {
            step.out.frames.iter().any(is_feedback)
        }),
        ("emergency with status frames", |step| {
            step.after.emergency && step.out.frames.iter().any(|f| f.id() == id::STATUS)
        }),
        ("frame rejected", |step| {
            step.after.status.rejected_count != step.before.status.rejected_count
        }),
        ("a report of the pad not in control", |step| {
            matches!(step.input, Input::Gamepad { pad, .. }
                if step.model.in_control().is_some_and(|owner| owner != *pad))
        }),
        ("the pad in control handed over to the other", |step| {
            matches!(step.input, Input::RemoteLink { pad, connected: false, .. }
                if step.model.in_control().is_some_and(|owner| owner != *pad))
        }),
        ("a dead-man held on the waiting pad handed over", |step| {
            matches!(step.input, Input::RemoteLink { pad, connected: false, .. }
                if step.model.in_control().is_some_and(|owner| owner != *pad))
                && step.after.status.flags.remote_in_control
        }),
        ("the lock lifted with a dead-man held", |step| {
            *step.input == Input::UpdateLock(false) && step.before.status.flags.remote_in_control
        }),
        ("a pad input while Bluetooth is off", |step| {
            step.before.registers.get(Reg::BluetoothOff) != 0 && step.input.is_from_a_remote_task()
        }),
    ];
    let mut runner = TestRunner::deterministic();
    let strategy = sequence();
    let sequences = 200;
    let mut counts = [0u32; SITUATIONS];
    for _ in 0..sequences {
        let events = strategy
            .new_tree(&mut runner)
            .expect("the strategy generates")
            .current();
        let mut seen = [false; SITUATIONS];
        run(&events, |step| {
            for (seen, (_, occurs)) in seen.iter_mut().zip(&situations) {
                *seen |= occurs(step);
            }
            Ok(())
        })
        .expect("no check fails");
        for (count, seen) in counts.iter_mut().zip(seen) {
            *count += u32::from(seen);
        }
    }
    let report: Vec<_> = situations
        .iter()
        .map(|(what, _)| *what)
        .zip(counts)
        .collect();
    println!("of {sequences} sequences: {report:?}");
    for (what, count) in report {
        assert!(
            count >= sequences / 5,
            "only {count} of {sequences} sequences: {what}"
        );
    }
}
