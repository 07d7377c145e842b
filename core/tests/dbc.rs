//! docs/base-controller.dbc against the codec: every frame the encoders build, decoded
//! with nothing but the DBC's signal definitions, gives back the values the codec put
//! in. can-dbc only parses the file; the bit extraction is our own, so a wrong start bit,
//! length, byte order, sign or factor in the DBC fails here.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Debug;

use base_core::calibration::odometry::OdometryCalibrationError;
use base_core::calibration::scale::ScaleCalibrationError;
use base_core::calibration::{OdometryCalibrationCommand, ScaleCalibrationCommand};
use base_core::can::{
    Command, ControlSource, Faults, FrameError, Mode, RawFrame, ReadEcho, Rejection, Report,
    Status, StatusFlags, id,
};
use base_core::plausibility::Finding;
use base_core::registers::{self, Reg, RegisterError, TABLE};
use can_dbc::{
    AttributeValue, ByteOrder, Dbc, Message, MessageId, MultiplexIndicator, Signal, ValueType,
};

const DBC_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/base-controller.dbc");

/// The DBC's two nodes.
const PC: &str = "PC";
const BASE_CONTROLLER: &str = "BaseController";

fn parse_dbc() -> Dbc {
    let text =
        std::fs::read_to_string(DBC_PATH).unwrap_or_else(|error| panic!("{DBC_PATH}: {error}"));
    Dbc::try_from(text.as_str()).unwrap_or_else(|error| panic!("{DBC_PATH}: {error}"))
}

// ---- The signal extractor ----

/// The bit positions a signal occupies, least significant first. Intel (`@1`): the start
/// bit is the LSB and the signal counts up through the frame. Motorola (`@0`): the start
/// bit is the MSB in DBC's sawtooth numbering (bit 7 of byte 0 is 7, bit 0 of byte 1 is
/// 8); the signal runs down to bit 0 of its byte, then on from bit 7 of the next byte.
fn bit_positions(signal: &Signal) -> Vec<u64> {
    let start = signal.start_bit;
    match signal.byte_order {
        ByteOrder::LittleEndian => (start..start + signal.size).collect(),
        ByteOrder::BigEndian => {
            let mut most_significant_first = Vec::new();
            let mut position = start;
            for _ in 0..signal.size {
                most_significant_first.push(position);
                // From bit 0 of a byte on to bit 7 of the next.
                position = if position.is_multiple_of(8) {
                    position + 15
                } else {
                    position - 1
                };
            }
            most_significant_first.reverse();
            most_significant_first
        }
    }
}

/// The raw value of `signal` in `data`, sign-extended if the signal is signed; `None` if
/// the signal reaches past the frame's data bytes.
fn raw_value(signal: &Signal, data: &[u8]) -> Option<i128> {
    let mut raw: u64 = 0;
    for (significance, position) in bit_positions(signal).into_iter().enumerate() {
        let byte = data.get(usize::try_from(position / 8).ok()?)?;
        raw |= u64::from((byte >> (position % 8)) & 1) << significance;
    }
    Some(match signal.value_type {
        ValueType::Unsigned => i128::from(raw),
        ValueType::Signed => {
            // Move the sign bit to bit 63 and back: the arithmetic shift copies it down.
            let unused = 64 - signal.size;
            i128::from(((raw << unused) as i64) >> unused)
        }
    })
}

fn physical_value(signal: &Signal, raw: i128) -> f64 {
    raw as f64 * signal.factor + signal.offset
}

/// The signals the DBC says `data` carries: the plain ones, the multiplexor, and the
/// multiplexed ones its value selects.
fn active_signals<'m>(message: &'m Message, data: &[u8]) -> Vec<&'m Signal> {
    let selector = message
        .signals
        .iter()
        .find(|signal| signal.multiplexer_indicator == MultiplexIndicator::Multiplexor)
        .map(|multiplexor| {
            raw_value(multiplexor, data).unwrap_or_else(|| {
                panic!(
                    "{}: multiplexor {} outside the frame",
                    message.name, multiplexor.name
                )
            })
        });
    message
        .signals
        .iter()
        .filter(|signal| match signal.multiplexer_indicator {
            MultiplexIndicator::Plain | MultiplexIndicator::Multiplexor => true,
            MultiplexIndicator::MultiplexedSignal(selected_by) => {
                selector == Some(i128::from(selected_by))
            }
            MultiplexIndicator::MultiplexorAndMultiplexedSignal(_) => panic!(
                "{}: extended multiplexing is not part of this protocol",
                signal.name
            ),
        })
        .collect()
}

fn message_for(dbc: &Dbc, can_id: u16) -> &Message {
    dbc.messages
        .iter()
        .find(|message| message.id == MessageId::Standard(can_id))
        .unwrap_or_else(|| panic!("no DBC message for {can_id:03X}"))
}

/// The 11-bit ID of `message`; the protocol has no extended IDs.
fn message_id(message: &Message) -> u16 {
    match message.id {
        MessageId::Standard(can_id) => can_id,
        MessageId::Extended(can_id) => panic!("{}: extended ID {can_id:08X}", message.name),
    }
}

/// The message's sender and those of its `BO_TX_BU_` line.
fn transmitters(dbc: &Dbc, message: &Message) -> BTreeSet<String> {
    let extra = dbc
        .message_transmitters
        .iter()
        .filter(|line| line.message_id == message.id)
        .flat_map(|line| line.transmitter.iter().cloned());
    message.transmitter.iter().cloned().chain(extra).collect()
}

// ---- What each frame must decode to ----

/// What one signal must decode to.
#[derive(Debug)]
enum Expect {
    /// The physical value: raw × factor + offset.
    Value(f64),
    /// The name the signal's value table (`VAL_`) gives its raw value.
    Named(String),
}

fn value(physical: impl Into<f64>) -> Expect {
    Expect::Value(physical.into())
}

fn named(name: &str) -> Expect {
    Expect::Named(name.to_owned())
}

fn flag(set: bool) -> Expect {
    value(u8::from(set))
}

/// The codec's own name of an enumeration value (`EndLinear` for
/// `EndLinear { real_mm: 1000 }`), so a value table cannot drift from the types.
fn variant_name(variant: &impl Debug) -> Expect {
    let debug = format!("{variant:?}");
    let name = debug.split([' ', '(', '{']).next().unwrap_or_default();
    named(name)
}

/// A register address decodes to the register's name; one the table does not know, to
/// its number.
fn register_address(address: u8) -> Expect {
    registers::info(address).map_or(value(address), |info| named(info.name))
}

const FRAME_ERRORS: [FrameError; 4] = [
    FrameError::WrongLength,
    FrameError::BadVelocityMarker,
    FrameError::UnknownSubcommand,
    FrameError::BadReadCount,
];
const REGISTER_ERRORS: [RegisterError; 5] = [
    RegisterError::UnknownAddress,
    RegisterError::ReadOnly,
    RegisterError::OutOfRange,
    RegisterError::Inconsistent,
    RegisterError::NotAtRest,
];
const ODOMETRY_CALIBRATION_ERRORS: [OdometryCalibrationError; 4] = [
    OdometryCalibrationError::EndWithoutStart,
    OdometryCalibrationError::ZeroRawValue,
    OdometryCalibrationError::FactorOutOfRange,
    OdometryCalibrationError::NothingPending,
];
const SCALE_CALIBRATION_ERRORS: [ScaleCalibrationError; 6] = [
    ScaleCalibrationError::NotStarted,
    ScaleCalibrationError::NotTared,
    ScaleCalibrationError::NoReading,
    ScaleCalibrationError::OffsetOutOfRange,
    ScaleCalibrationError::ZeroWeight,
    ScaleCalibrationError::ScaleValueOutOfRange,
];

/// Reasons that are no refused command but are shown the same way: the drive
/// feedback's (0x40..).
const FEEDBACK_REASONS: [Rejection; 4] = [
    Rejection::OdometryDiscontinuity,
    Rejection::Feedback(Finding::PositionStuck),
    Rejection::Feedback(Finding::SpeedStale),
    Rejection::Feedback(Finding::WrongDirection),
];

/// Motion refused while a firmware update runs or an image is on trial (0x50).
const UPDATE_REASONS: [Rejection; 1] = [Rejection::UpdateInProgress];

/// A pad's packet the radio guard refused (0x60).
const REMOTE_REASONS: [Rejection; 1] = [Rejection::RadioPacketRefused];

/// Status byte 4 before anything was rejected.
const NO_REJECTION: u8 = 0;

/// Every rejection code the firmware reports, with its name, from the enums that own them.
fn rejection_reasons() -> Vec<(u8, String)> {
    let reason = |code: u8, error: &dyn Debug| (code, format!("{error:?}"));
    let frame = FRAME_ERRORS.iter().map(|e| reason(e.code(), e));
    let register = REGISTER_ERRORS.iter().map(|e| reason(e.code(), e));
    let odometry = ODOMETRY_CALIBRATION_ERRORS
        .iter()
        .map(|e| reason(e.code(), e));
    let scale = SCALE_CALIBRATION_ERRORS.iter().map(|e| reason(e.code(), e));
    let feedback = FEEDBACK_REASONS
        .iter()
        .chain(UPDATE_REASONS.iter())
        .chain(REMOTE_REASONS.iter())
        .map(|r| (r.code(), r.name().to_string()));
    frame
        .chain(register)
        .chain(odometry)
        .chain(scale)
        .chain(feedback)
        .collect()
}

fn rejection_reason(code: u8) -> Expect {
    if code == NO_REJECTION {
        return named("None");
    }
    rejection_reasons()
        .into_iter()
        .find(|(known, _)| *known == code)
        .map_or(value(code), |(_, name)| Expect::Named(name))
}

fn command_signals(command: &Command) -> Vec<(&'static str, Expect)> {
    match *command {
        Command::Enable { refresh } => {
            vec![(
                "EnableCommand",
                named(if refresh { "Refresh" } else { "Withdraw" }),
            )]
        }
        Command::Velocity {
            linear_mm_s,
            rotation_mrad_s,
        } => vec![
            ("LinearVelocity", value(linear_mm_s)),
            ("RotationVelocity", value(rotation_mrad_s)),
            ("VelocityMarker", named("Valid")),
        ],
        Command::RegisterWrite {
            address,
            value: register_value,
        } => vec![
            ("WriteAddress", register_address(address)),
            ("WriteValue", value(register_value)),
        ],
        Command::RegisterRead { address, tag } => vec![
            ("RegisterReadKind", variant_name(command)),
            ("ReadAddress", register_address(address)),
            ("ReadTag", value(tag)),
        ],
        Command::RegisterBulkRead { first, count, tag } => vec![
            ("RegisterReadKind", variant_name(command)),
            ("BulkFirstAddress", value(first)),
            ("BulkCount", value(count)),
            ("BulkTag", value(tag)),
        ],
        Command::ResetOdometry => vec![("ResetRequest", variant_name(command))],
        Command::Heartbeat => vec![("HeartbeatRequest", variant_name(command))],
        Command::ScaleCalibration(step) => {
            let mut signals = vec![("ScaleCalibrationStep", variant_name(&step))];
            if let ScaleCalibrationCommand::KnownWeight { grams } = step {
                signals.push(("KnownWeight", value(grams)));
            }
            signals
        }
        Command::OdometryCalibration(step) => {
            let mut signals = vec![("OdometryCalibrationStep", variant_name(&step))];
            match step {
                OdometryCalibrationCommand::EndLinear { real_mm } => {
                    signals.push(("RealDistance", value(real_mm)));
                }
                OdometryCalibrationCommand::EndClockwise { real_mrad } => {
                    signals.push(("RealClockwiseAngle", value(real_mrad)));
                }
                OdometryCalibrationCommand::EndCounterClockwise { real_mrad } => {
                    signals.push(("RealCounterClockwiseAngle", value(real_mrad)));
                }
                OdometryCalibrationCommand::StartLinear
                | OdometryCalibrationCommand::StartClockwise
                | OdometryCalibrationCommand::StartCounterClockwise
                | OdometryCalibrationCommand::Store => {}
            }
            signals
        }
    }
}

fn report_signals(report: &Report) -> Vec<(&'static str, Expect)> {
    match *report {
        Report::Position { x_mm, y_mm } => {
            vec![("PositionX", value(x_mm)), ("PositionY", value(y_mm))]
        }
        Report::Heading { heading_mrad } => vec![("Heading", value(heading_mrad))],
        Report::PoseTime { controller_ms } => vec![("PoseTime", value(controller_ms))],
        Report::MeasuredSpeed {
            linear_mm_s,
            rotation_mrad_s,
            left_wheel_crad_s,
            right_wheel_crad_s,
        } => vec![
            ("MeasuredLinear", value(linear_mm_s)),
            ("MeasuredRotation", value(rotation_mrad_s)),
            // The DBC's factor, applied as a DBC reader applies it.
            ("LeftWheelSpeed", value(f64::from(left_wheel_crad_s) * 0.01)),
            (
                "RightWheelSpeed",
                value(f64::from(right_wheel_crad_s) * 0.01),
            ),
        ],
        Report::Battery {
            percent,
            voltage_mv,
        } => vec![
            ("BatteryCharge", value(percent)),
            ("BatteryVoltage", value(voltage_mv)),
        ],
        Report::Weight { grams } => vec![("Weight", value(grams))],
        Report::RegisterValue {
            value: register_value,
            echo: Some(echo),
        } => vec![
            ("RegisterReadKind", variant_name(report)),
            ("ReadValue", value(register_value)),
            ("ReplyAddress", value(echo.address)),
            ("ReplyTag", value(echo.tag)),
        ],
        Report::RegisterReadError {
            address,
            reason,
            tag: Some(tag),
        } => vec![
            ("RegisterReadKind", variant_name(report)),
            ("RefusedAddress", value(address)),
            ("RefusalReason", rejection_reason(reason)),
            ("RefusalTag", value(tag)),
        ],
        // The DBC describes what the base controller sends: replies that say which
        // read they answer.
        Report::RegisterValue { echo: None, .. } | Report::RegisterReadError { tag: None, .. } => {
            panic!("{report:?}: the base controller never sends a reply without its echo")
        }
        Report::Status(status) => status_signals(&status),
    }
}

fn status_signals(status: &Status) -> Vec<(&'static str, Expect)> {
    // Destructured in full: a new status field breaks this build until it has a signal here,
    // and so in the DBC.
    let Status {
        mode,
        control,
        persist_pending,
        flags,
        faults,
        rejected_count,
        last_rejection,
        last_rejection_subject,
        drive_alarm,
        modbus_errors,
    } = *status;
    let StatusFlags {
        enable_fresh,
        pc_on,
        safety_zone,
        remote_bonded,
        remote_connected,
        remote_in_control,
        estop_pressed,
        brakes_applied,
    } = flags;
    let Faults {
        left_drive_silent,
        left_drive_alarm,
        right_drive_silent,
        right_drive_alarm,
        flash,
        scale,
        can_bus,
        watchdog_reset,
    } = faults;
    vec![
        ("Mode", variant_name(&mode)),
        ("ControlSource", variant_name(&control)),
        ("PersistPending", flag(persist_pending)),
        ("EnableFresh", flag(enable_fresh)),
        ("PcOn", flag(pc_on)),
        ("SafetyZone", flag(safety_zone)),
        ("RemoteBonded", flag(remote_bonded)),
        ("RemoteConnected", flag(remote_connected)),
        ("RemoteInControl", flag(remote_in_control)),
        ("EstopPressed", flag(estop_pressed)),
        ("BrakesApplied", flag(brakes_applied)),
        ("LeftDriveSilent", flag(left_drive_silent)),
        ("LeftDriveAlarm", flag(left_drive_alarm)),
        ("RightDriveSilent", flag(right_drive_silent)),
        ("RightDriveAlarm", flag(right_drive_alarm)),
        ("FlashFault", flag(flash)),
        ("ScaleFault", flag(scale)),
        ("CanBusFault", flag(can_bus)),
        ("WatchdogReset", flag(watchdog_reset)),
        ("RejectedCount", value(rejected_count)),
        ("LastRejection", rejection_reason(last_rejection)),
        ("LastRejectionSubject", value(last_rejection_subject)),
        ("DriveAlarm", value(drive_alarm)),
        ("ModbusErrors", value(modbus_errors)),
    ]
}

// ---- The representative frames ----

/// One frame the codec encoded, who sends it, who reads it, and what each of its
/// signals must decode to.
struct Case {
    frame: RawFrame,
    sender: &'static str,
    receiver: &'static str,
    expected: Vec<(&'static str, Expect)>,
}

/// Values whose two bytes differ catch a swapped byte order; values above 0x7FFF catch
/// an unsigned field read as signed.
const U16_EDGES: [u16; 5] = [0, 1, 0x1234, 0x8001, u16::MAX];

fn commands() -> Vec<Command> {
    let mut commands = vec![
        Command::Enable { refresh: true },
        Command::Enable { refresh: false },
        Command::ResetOdometry,
        Command::Heartbeat,
    ];
    for (linear_mm_s, rotation_mrad_s) in [
        (0, 0),
        (500, 0),
        (-300, -1000),
        (-1, 1),
        (0x1234, -0x1234),
        (i16::MAX, i16::MIN),
        (i16::MIN, i16::MAX),
    ] {
        commands.push(Command::Velocity {
            linear_mm_s,
            rotation_mrad_s,
        });
    }
    // Every register, and addresses no register has.
    for address in TABLE.iter().map(|info| info.address).chain([34, 41, 255]) {
        // The DBC has the tagged layout; a tag of 0 is the manual's two-byte request.
        commands.push(Command::RegisterRead {
            address,
            tag: 0xBEEF,
        });
        commands.push(Command::RegisterWrite {
            address,
            value: 0x1234,
        });
        commands.push(Command::RegisterBulkRead {
            first: address.min(248),
            count: 8,
            tag: 0xBEEF,
        });
    }
    for value in U16_EDGES {
        let address = Reg::LoopEndDelay as u8;
        commands.push(Command::RegisterWrite { address, value });
    }
    let scale_steps = [
        ScaleCalibrationCommand::Start,
        ScaleCalibrationCommand::Tare,
    ];
    let odometry_steps = [
        OdometryCalibrationCommand::StartLinear,
        OdometryCalibrationCommand::StartClockwise,
        OdometryCalibrationCommand::StartCounterClockwise,
        OdometryCalibrationCommand::Store,
    ];
    commands.extend(scale_steps.map(Command::ScaleCalibration));
    commands.extend(odometry_steps.map(Command::OdometryCalibration));
    for real in U16_EDGES.into_iter().chain([1000, 6284]) {
        commands.extend(
            [
                OdometryCalibrationCommand::EndLinear { real_mm: real },
                OdometryCalibrationCommand::EndClockwise { real_mrad: real },
                OdometryCalibrationCommand::EndCounterClockwise { real_mrad: real },
            ]
            .map(Command::OdometryCalibration),
        );
        commands.push(Command::ScaleCalibration(
            ScaleCalibrationCommand::KnownWeight { grams: real },
        ));
    }
    commands
}

fn statuses() -> Vec<Status> {
    let mut statuses = Vec::new();
    // Every mode with every control source, each in its nibble.
    for mode in (0..=u8::MAX).map_while(Mode::from_code) {
        for control in (0..=u8::MAX).map_while(ControlSource::from_code) {
            statuses.push(Status {
                mode,
                control,
                ..Status::default()
            });
        }
    }
    // Each flag and each fault alone, so a bit in the wrong place cannot hide.
    for bit in 0..8 {
        statuses.push(Status {
            flags: StatusFlags::from_byte(1 << bit),
            faults: Faults::from_byte(0x80 >> bit),
            ..Status::default()
        });
    }
    for (code, _) in rejection_reasons() {
        statuses.push(Status {
            rejected_count: 1,
            last_rejection: code,
            last_rejection_subject: 0xC8,
            ..Status::default()
        });
    }
    // docs/protocol.md's example, then every byte at its highest.
    statuses.push(Status {
        mode: Mode::AwaitingConfirm,
        control: ControlSource::Remote,
        persist_pending: false,
        flags: StatusFlags::from_byte(0x8D),
        faults: Faults::from_byte(0xA6),
        rejected_count: 200,
        last_rejection: FrameError::BadVelocityMarker.code(),
        last_rejection_subject: 0xC8,
        drive_alarm: 0x84,
        modbus_errors: 7,
    });
    statuses.push(Status {
        mode: Mode::Fault,
        control: ControlSource::Remote,
        persist_pending: true,
        flags: StatusFlags::from_byte(0xFF),
        faults: Faults::from_byte(0xFF),
        rejected_count: u8::MAX,
        last_rejection: u8::MAX,
        last_rejection_subject: u8::MAX,
        drive_alarm: u8::MAX,
        modbus_errors: u8::MAX,
    });
    statuses
}

fn reports() -> Vec<Report> {
    let mut reports = Vec::new();
    for (x_mm, y_mm) in [
        (0, 0),
        (1000, -2),
        (-1, 0x1234_5678),
        (i32::MAX, i32::MIN),
        (i32::MIN, i32::MAX),
    ] {
        reports.push(Report::Position { x_mm, y_mm });
    }
    for heading_mrad in [0, -1571, 12566, i32::MIN, i32::MAX] {
        reports.push(Report::Heading { heading_mrad });
    }
    for controller_ms in [0, 100_000, 0x8000_0000, u32::MAX] {
        reports.push(Report::PoseTime { controller_ms });
    }
    for (linear_mm_s, rotation_mrad_s, left_wheel_crad_s, right_wheel_crad_s) in [
        (0, 0, 0, 0),
        (300, -500, 250, 350),
        (i16::MIN, i16::MAX, i16::MAX, i16::MIN),
        (-1, 1, -1, 1),
    ] {
        reports.push(Report::MeasuredSpeed {
            linear_mm_s,
            rotation_mrad_s,
            left_wheel_crad_s,
            right_wheel_crad_s,
        });
    }
    for (percent, voltage_mv) in [(0, 0), (87, 25300), (100, 0x8001), (100, u16::MAX)] {
        reports.push(Report::Battery {
            percent,
            voltage_mv,
        });
    }
    for edge in U16_EDGES {
        reports.push(Report::Weight { grams: edge });
        reports.push(Report::RegisterValue {
            value: edge,
            echo: Some(ReadEcho {
                address: 18,
                tag: edge,
            }),
        });
    }
    for error in REGISTER_ERRORS {
        for address in [34, 0xFF] {
            reports.push(Report::RegisterReadError {
                address,
                reason: error.code(),
                tag: Some(0xBEEF),
            });
        }
    }
    reports.extend(statuses().into_iter().map(Report::Status));
    reports
}

/// The firmware update's frames: every command, data frame, reply, phase, step and error.
fn update_cases() -> Vec<Case> {
    use base_core::can::update::{
        BeginFlags, DataFrame, Phase, Step, UpdateCommand, UpdateError, UpdateReply,
    };
    let pc = |frame: RawFrame, expected: Vec<(&'static str, Expect)>| Case {
        frame,
        sender: PC,
        receiver: BASE_CONTROLLER,
        expected,
    };
    let bc = |reply: UpdateReply, expected: Vec<(&'static str, Expect)>| Case {
        frame: reply.encode(),
        sender: BASE_CONTROLLER,
        receiver: PC,
        expected,
    };
    let mut cases = vec![
        pc(
            UpdateCommand::Query.encode(),
            vec![("UpdateOpcode", named("Query"))],
        ),
        pc(
            UpdateCommand::Begin {
                session: 0xA5,
                size: 0x1F_0000,
                flags: BeginFlags {
                    force: false,
                    allow_downgrade: true,
                },
            }
            .encode(),
            vec![
                ("UpdateOpcode", named("Begin")),
                ("BeginSession", value(0xA5)),
                ("BeginSize", value(0x1F_0000)),
                ("BeginFlags", value(2)),
            ],
        ),
        pc(
            UpdateCommand::Digest {
                session: 7,
                part: 5,
                bytes: [0x01, 0x02, 0x03, 0xF4],
            }
            .encode(),
            vec![
                ("UpdateOpcode", named("Digest")),
                ("DigestSession", value(7)),
                ("DigestPart", value(5)),
                ("DigestBytes", value(0xF403_0201u32)),
            ],
        ),
        pc(
            UpdateCommand::Window {
                session: 7,
                index: 0x0102,
                crc: 0xDEAD_BEEF,
            }
            .encode(),
            vec![
                ("UpdateOpcode", named("Window")),
                ("WindowSession", value(7)),
                ("WindowIndex", value(0x0102)),
                ("WindowCrc", value(0xDEAD_BEEFu32)),
            ],
        ),
        pc(
            UpdateCommand::Finish { session: 7 }.encode(),
            vec![
                ("UpdateOpcode", named("Finish")),
                ("FinishSession", value(7)),
            ],
        ),
        pc(
            UpdateCommand::Activate { session: 8 }.encode(),
            vec![
                ("UpdateOpcode", named("Activate")),
                ("ActivateSession", value(8)),
            ],
        ),
        pc(
            UpdateCommand::Abort { session: 9 }.encode(),
            vec![("UpdateOpcode", named("Abort")), ("AbortSession", value(9))],
        ),
        pc(
            UpdateCommand::Confirm { session: 10 }.encode(),
            vec![
                ("UpdateOpcode", named("Confirm")),
                ("ConfirmSession", value(10)),
            ],
        ),
        pc(
            UpdateCommand::Rollback { session: 11 }.encode(),
            vec![
                ("UpdateOpcode", named("Rollback")),
                ("RollbackSession", value(11)),
            ],
        ),
        pc(
            DataFrame {
                seq: 0xC3,
                bytes: [1, 2, 3, 4, 5, 6, 0xF7],
            }
            .encode(),
            vec![
                ("DataSeq", value(0xC3)),
                ("DataBytes", value(0xF7_0605_0403_0201u64 as f64)),
            ],
        ),
        bc(
            UpdateReply::Version {
                part: 4,
                text: *b"0.3.1-",
            },
            vec![
                ("UpdateReplyKind", named("Version")),
                ("VersionPart", value(4)),
                (
                    "VersionText",
                    value(u64::from_le_bytes([b'0', b'.', b'3', b'.', b'1', b'-', 0, 0]) as f64),
                ),
            ],
        ),
        bc(
            UpdateReply::Ready {
                session: 7,
                window: 0x0102,
                next: 0x0203,
            },
            vec![
                ("UpdateReplyKind", named("Ready")),
                ("ReadySession", value(7)),
                ("ReadyWindow", value(0x0102)),
                ("ReadyNext", value(0x0203)),
            ],
        ),
        bc(
            UpdateReply::Written {
                session: 7,
                window: 0x0304,
            },
            vec![
                ("UpdateReplyKind", named("Written")),
                ("WrittenSession", value(7)),
                ("WrittenWindow", value(0x0304)),
            ],
        ),
    ];
    let phases = [
        (Phase::Idle, "Idle"),
        (Phase::Receiving, "Receiving"),
        (Phase::Writing, "Writing"),
        (Phase::Finished, "Finished"),
        (Phase::Activating, "Activating"),
        (Phase::OnTrial, "OnTrial"),
    ];
    for (phase, name) in phases {
        cases.push(bc(
            UpdateReply::State {
                phase,
                session: 7,
                running_slot: 1,
                windows_written: 0x0102,
                signatures_required: phase == Phase::OnTrial,
                security_version: 9,
            },
            vec![
                ("UpdateReplyKind", named("State")),
                ("UpdatePhase", named(name)),
                ("StateSession", value(7)),
                ("RunningSlot", value(1)),
                ("WindowsWritten", value(0x0102)),
                (
                    "SignaturesRequired",
                    value(u8::from(phase == Phase::OnTrial)),
                ),
                ("SecurityVersion", value(9)),
            ],
        ));
    }
    let steps = [
        (Step::Begun, "Begun"),
        (Step::Finished, "Finished"),
        (Step::Activated, "Activated"),
        (Step::Aborted, "Aborted"),
        (Step::Confirmed, "Confirmed"),
        (Step::RolledBack, "RolledBack"),
    ];
    for (step, name) in steps {
        cases.push(bc(
            UpdateReply::Done { session: 7, step },
            vec![
                ("UpdateReplyKind", named("Done")),
                ("DoneSession", value(7)),
                ("DoneStep", named(name)),
            ],
        ));
    }
    for error in UpdateError::ALL {
        cases.push(bc(
            UpdateReply::Refused {
                opcode: 4,
                error,
                detail: 3,
                session: 0x5A,
            },
            vec![
                ("UpdateReplyKind", named("Refused")),
                ("RefusedOpcode", value(4)),
                ("UpdateError", named(error.name())),
                ("RefusedDetail", value(3)),
                ("RefusedSession", value(0x5A)),
            ],
        ));
    }
    cases
}

fn cases() -> Vec<Case> {
    let commands = commands().into_iter().map(|command| Case {
        frame: command.encode(),
        sender: PC,
        receiver: BASE_CONTROLLER,
        expected: command_signals(&command),
    });
    let reports = reports().into_iter().map(|report| Case {
        frame: report.encode(),
        sender: BASE_CONTROLLER,
        receiver: PC,
        expected: report_signals(&report),
    });
    commands.chain(reports).chain(update_cases()).collect()
}

/// A signal a case checked, and the value-table name it matched, if any.
struct Checked<'m> {
    signal: &'m Signal,
    name: Option<String>,
}

/// Decodes `case` with the DBC and asserts that exactly the expected signals are there,
/// each with the expected value, sent and received by the right nodes.
fn check<'d>(dbc: &'d Dbc, case: &Case) -> Vec<Checked<'d>> {
    let frame = format!("{:03X}#{:02X?}", case.frame.id(), case.frame.data());
    let message = message_for(dbc, case.frame.id());
    assert!(
        transmitters(dbc, message).contains(case.sender),
        "{frame}: {} is not sent by {}",
        message.name,
        case.sender
    );
    let signals = active_signals(message, case.frame.data());
    let decoded: BTreeSet<&str> = signals.iter().map(|signal| signal.name.as_str()).collect();
    let expected: BTreeSet<&str> = case.expected.iter().map(|(name, _)| *name).collect();
    assert_eq!(decoded, expected, "{frame}: signals present");

    let expectations: BTreeMap<&str, &Expect> =
        case.expected.iter().map(|(name, e)| (*name, e)).collect();
    signals
        .into_iter()
        .map(|signal| {
            assert!(
                signal.receivers.iter().any(|node| node == case.receiver),
                "{frame}: {} is not received by {}",
                signal.name,
                case.receiver
            );
            let raw = raw_value(signal, case.frame.data())
                .unwrap_or_else(|| panic!("{frame}: {} reaches past the data", signal.name));
            let name = value_name(dbc, message, signal, raw);
            match expectations[signal.name.as_str()] {
                Expect::Value(expected) => assert_eq!(
                    physical_value(signal, raw),
                    *expected,
                    "{frame}: {}",
                    signal.name
                ),
                Expect::Named(expected) => assert_eq!(
                    name.as_ref(),
                    Some(expected),
                    "{frame}: {} (raw {raw})",
                    signal.name
                ),
            }
            Checked { signal, name }
        })
        .collect()
}

/// The `VAL_` name of `raw` on `signal`, if it has one.
fn value_name(dbc: &Dbc, message: &Message, signal: &Signal, raw: i128) -> Option<String> {
    dbc.value_descriptions_for_signal(message.id, &signal.name)?
        .iter()
        .find(|entry| i128::from(entry.id) == raw)
        .map(|entry| entry.description.clone())
}

// ---- The tests ----

#[test]
fn every_encoded_frame_decodes_with_the_dbc_to_the_values_the_codec_put_in() {
    let dbc = parse_dbc();
    for case in cases() {
        check(&dbc, &case);
    }
}

#[test]
fn every_dbc_signal_and_value_name_is_checked_by_some_frame() {
    let dbc = parse_dbc();
    let cases = cases();
    let mut checked_signals = BTreeSet::new();
    let mut checked_names = BTreeSet::new();
    for case in &cases {
        let id = case.frame.id();
        for Checked { signal, name } in check(&dbc, case) {
            checked_signals.insert((id, signal.name.clone()));
            if let Some(name) = name {
                checked_names.insert((id, signal.name.clone(), name));
            }
        }
    }

    // Checking a frame finds only what the DBC has, so the DBC's rest is what no frame checks.
    let mut unchecked = Vec::new();
    for message in &dbc.messages {
        let can_id = message_id(message);
        for signal in &message.signals {
            if !checked_signals.contains(&(can_id, signal.name.clone())) {
                unchecked.push(format!("{}.{}", message.name, signal.name));
            }
            let value_table = dbc.value_descriptions_for_signal(message.id, &signal.name);
            for entry in value_table.unwrap_or_default() {
                let name = (can_id, signal.name.clone(), entry.description.clone());
                if !checked_names.contains(&name) {
                    unchecked.push(format!(
                        "{}.{} = {}",
                        message.name, signal.name, entry.description
                    ));
                }
            }
        }
    }
    assert!(unchecked.is_empty(), "no frame checks {unchecked:?}");
}

#[test]
fn every_codec_id_has_a_dbc_message_from_its_sender_with_the_longest_encoded_dlc() {
    let dbc = parse_dbc();
    let cases = cases();
    let directions = [
        (PC, &id::COMMANDS[..]),
        (BASE_CONTROLLER, &id::REPORTS[..]),
        (PC, &id::UPDATE[..]),
        (BASE_CONTROLLER, &[id::UPDATE_REPLY][..]),
    ];
    for (sender, ids) in directions {
        for &can_id in ids {
            let message = message_for(&dbc, can_id);
            assert!(
                transmitters(&dbc, message).contains(sender),
                "{can_id:03X} not sent by {sender}"
            );
            assert!(
                cases
                    .iter()
                    .any(|case| case.frame.id() == can_id && case.sender == sender),
                "no frame from {sender} on {can_id:03X} checked"
            );
        }
    }
    // One DLC per ID: the longest layout, so 0x004 (request 4, replies 6) and the
    // calibration frames (steps 1, values 3) get 3.
    for message in &dbc.messages {
        let can_id = message_id(message);
        let longest = cases
            .iter()
            .filter(|case| case.frame.id() == can_id)
            .map(|case| case.frame.data().len())
            .max();
        assert_eq!(
            longest,
            usize::try_from(message.size).ok(),
            "{can_id:03X} DLC"
        );
    }
    let shared = transmitters(&dbc, message_for(&dbc, id::REGISTER_READ));
    assert_eq!(shared, BTreeSet::from([PC.into(), BASE_CONTROLLER.into()]));
}

#[test]
fn the_dbc_has_no_message_the_codec_does_not_know() {
    let dbc = parse_dbc();
    let known: BTreeSet<u16> = id::COMMANDS
        .into_iter()
        .chain(id::REPORTS)
        .chain(id::UPDATE)
        .chain([id::UPDATE_REPLY])
        .collect();
    let in_dbc: Vec<u16> = dbc.messages.iter().map(message_id).collect();
    let unique: BTreeSet<u16> = in_dbc.iter().copied().collect();
    assert_eq!(unique.len(), in_dbc.len(), "an ID has two messages");
    assert_eq!(unique, known);
}

#[test]
fn signals_of_one_layout_share_no_bit_and_stay_inside_the_dlc() {
    let dbc = parse_dbc();
    for message in &dbc.messages {
        let dlc_bits = message.size * 8;
        // Bits used by the plain signals and the multiplexor, and by each multiplexed layout.
        let mut common = BTreeMap::new();
        let mut layouts: BTreeMap<u64, BTreeMap<u64, &str>> = BTreeMap::new();
        for signal in &message.signals {
            let bits = match signal.multiplexer_indicator {
                MultiplexIndicator::MultiplexedSignal(selector) => {
                    layouts.entry(selector).or_default()
                }
                _ => &mut common,
            };
            for position in bit_positions(signal) {
                assert!(
                    position < dlc_bits,
                    "{}.{}: bit {position} past the DLC",
                    message.name,
                    signal.name
                );
                if let Some(other) = bits.insert(position, signal.name.as_str()) {
                    panic!(
                        "{}: {} and {other} share bit {position}",
                        message.name, signal.name
                    );
                }
            }
        }
        for (selector, layout) in &layouts {
            for position in layout.keys() {
                assert!(
                    !common.contains_key(position),
                    "{} layout {selector}: bit {position} also in {}",
                    message.name,
                    common[position]
                );
            }
        }
    }
}

#[test]
fn cycle_times_are_the_defaults_of_the_period_registers() {
    let dbc = parse_dbc();
    let periodic = [
        (id::POSE_TIME, Reg::LoopEndDelay),
        (id::MEASURED_SPEED, Reg::LoopEndDelay),
        (id::POSITION, Reg::LoopEndDelay),
        (id::HEADING, Reg::LoopEndDelay),
        (id::BATTERY, Reg::VoltTime),
        (id::WEIGHT, Reg::WeightTime),
        (id::STATUS, Reg::StatusTime),
    ];
    for (can_id, period) in periodic {
        let cycle_time = dbc.message_attribute(MessageId::Standard(can_id), "GenMsgCycleTime");
        let expected = AttributeValue::Uint(u64::from(period.info().default));
        assert_eq!(cycle_time, Some(&expected), "{can_id:03X}");
    }
}

#[test]
fn every_message_and_signal_is_commented_and_extensions_say_so() {
    let dbc = parse_dbc();
    for message in &dbc.messages {
        assert!(
            dbc.message_comment(message.id).is_some(),
            "{}",
            message.name
        );
        for signal in &message.signals {
            assert!(
                dbc.signal_comment(message.id, &signal.name).is_some(),
                "{}.{}",
                message.name,
                signal.name
            );
        }
    }
    // The status frame and the register read error reply are this firmware's, not the manual's.
    let is_marked = |comment: Option<&str>| comment.is_some_and(|c| c.starts_with("(ext)"));
    assert!(is_marked(
        dbc.message_comment(MessageId::Standard(id::STATUS))
    ));
    for signal in ["RefusedAddress", "RefusalReason"] {
        let register_read = MessageId::Standard(id::REGISTER_READ);
        assert!(
            is_marked(dbc.signal_comment(register_read, signal)),
            "{signal}"
        );
    }
}
