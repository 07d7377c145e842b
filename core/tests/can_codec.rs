//! The CAN protocol as golden bytes: every frame of docs/protocol.md decoded from and
//! encoded to its exact bytes, every rejection, and properties over arbitrary input.

use base_core::calibration::{OdometryCalibrationCommand, ScaleCalibrationCommand};
use base_core::can::{
    BULK_READ_MAX, Command, ControlSource, Faults, FrameError, Mode, RawFrame, ReadEcho, Report,
    Status, StatusFlags, id,
};
use proptest::prelude::*;

/// Decoding `id#bytes` gives `command`, and encoding `command` gives exactly `id#bytes`.
fn assert_command_golden(id: u16, bytes: &[u8], command: Command) {
    assert_eq!(
        Command::decode(id, bytes),
        Ok(Some(command)),
        "decode {id:03X}#{bytes:02X?}"
    );
    let frame = command.encode();
    assert_eq!(
        (frame.id(), frame.data()),
        (id, bytes),
        "encode {command:?}"
    );
}

fn assert_report_golden(id: u16, bytes: &[u8], report: Report) {
    assert_eq!(
        Report::decode(id, bytes),
        Ok(Some(report)),
        "decode {id:03X}#{bytes:02X?}"
    );
    let frame = report.encode();
    assert_eq!((frame.id(), frame.data()), (id, bytes), "encode {report:?}");
}

fn command_error(id: u16, bytes: &[u8]) -> FrameError {
    match Command::decode(id, bytes) {
        Err(error) => error,
        other => panic!("{id:03X}#{bytes:02X?} decoded as {other:?}"),
    }
}

fn report_error(id: u16, bytes: &[u8]) -> FrameError {
    match Report::decode(id, bytes) {
        Err(error) => error,
        other => panic!("{id:03X}#{bytes:02X?} decoded as {other:?}"),
    }
}

// ---- Golden bytes, PC → BC ----

#[test]
fn enable_is_the_manuals_eight_byte_frame() {
    assert_command_golden(
        0x2E4,
        &[0x40, 0, 0, 0, 0, 0, 0, 0],
        Command::Enable { refresh: true },
    );
}

#[test]
fn enable_withdrawal_is_zero_then_seven_zero_bytes() {
    assert_command_golden(
        0x2E4,
        &[0x00, 0, 0, 0, 0, 0, 0, 0],
        Command::Enable { refresh: false },
    );
}

#[test]
fn enable_with_one_byte_is_accepted_and_any_byte0_but_0x40_withdraws() {
    assert_eq!(
        Command::decode(0x2E4, &[0x40]),
        Ok(Some(Command::Enable { refresh: true }))
    );
    for byte0 in [0x00, 0x01, 0x3F, 0x41, 0xFF] {
        assert_eq!(
            Command::decode(0x2E4, &[byte0, 0, 0]),
            Ok(Some(Command::Enable { refresh: false })),
            "byte0 {byte0:#04x}"
        );
    }
}

#[test]
fn velocity_500_mm_s_forward() {
    assert_command_golden(
        0x0C8,
        &[0xF4, 0x01, 0x00, 0x00, 0x03],
        Command::Velocity {
            linear_mm_s: 500,
            rotation_mrad_s: 0,
        },
    );
}

#[test]
fn velocity_with_negative_rotation_is_twos_complement_little_endian() {
    // -300 mm/s backwards while turning -1000 mrad/s (counter-clockwise).
    assert_command_golden(
        0x0C8,
        &[0xD4, 0xFE, 0x18, 0xFC, 0x03],
        Command::Velocity {
            linear_mm_s: -300,
            rotation_mrad_s: -1000,
        },
    );
}

#[test]
fn velocity_extremes_survive_the_wire() {
    assert_command_golden(
        0x0C8,
        &[0x00, 0x80, 0xFF, 0x7F, 0x03],
        Command::Velocity {
            linear_mm_s: i16::MIN,
            rotation_mrad_s: i16::MAX,
        },
    );
}

#[test]
fn velocity_accepts_trailing_bytes_up_to_eight() {
    assert_eq!(
        Command::decode(0x0C8, &[0xF4, 0x01, 0x64, 0x00, 0x03, 0xAA, 0xBB, 0xCC]),
        Ok(Some(Command::Velocity {
            linear_mm_s: 500,
            rotation_mrad_s: 100
        }))
    );
}

#[test]
fn register_write_50_to_register_15_is_big_endian() {
    assert_command_golden(
        0x003,
        &[0x0F, 0x00, 0x32],
        Command::RegisterWrite {
            address: 15,
            value: 50,
        },
    );
    assert_command_golden(
        0x003,
        &[0x12, 0x27, 0x57],
        Command::RegisterWrite {
            address: 18,
            value: 10071,
        },
    );
}

#[test]
fn register_read_of_register_15() {
    assert_command_golden(
        0x004,
        &[0x01, 0x0F],
        Command::RegisterRead {
            address: 15,
            tag: 0,
        },
    );
}

#[test]
fn tagged_register_read_carries_the_tag_after_the_address() {
    assert_command_golden(
        0x004,
        &[0x01, 0x0F, 0xBE, 0xEF],
        Command::RegisterRead {
            address: 15,
            tag: 0xBEEF,
        },
    );
}

#[test]
fn a_lone_third_byte_of_a_register_read_is_no_tag() {
    assert_eq!(
        Command::decode(0x004, &[0x01, 0x0F, 0x99]),
        Ok(Some(Command::RegisterRead {
            address: 15,
            tag: 0
        }))
    );
}

#[test]
fn bulk_register_read_names_first_address_count_and_tag() {
    assert_command_golden(
        0x004,
        &[0x02, 0x10, 0x08, 0xBE, 0xEF],
        Command::RegisterBulkRead {
            first: 16,
            count: 8,
            tag: 0xBEEF,
        },
    );
}

#[test]
fn a_bulk_read_of_no_register_too_many_or_past_255_is_refused() {
    for data in [
        [0x02, 0x10, 0x00, 0, 1],
        [0x02, 0x10, BULK_READ_MAX + 1, 0, 1],
        [0x02, 0xFA, 0x07, 0, 1],
    ] {
        assert_eq!(
            Command::decode(0x004, &data),
            Err(FrameError::BadReadCount),
            "{data:02X?}"
        );
    }
    // The last address is 255: first 248, 8 registers.
    assert!(matches!(
        Command::decode(0x004, &[0x02, 0xF8, 0x08, 0, 1]),
        Ok(Some(Command::RegisterBulkRead { count: 8, .. }))
    ));
    // The tag is not optional in a bulk read.
    assert_eq!(
        Command::decode(0x004, &[0x02, 0x10, 0x08, 0xBE]),
        Err(FrameError::WrongLength)
    );
}

#[test]
fn reset_odometry_is_005_01() {
    assert_command_golden(0x005, &[0x01], Command::ResetOdometry);
}

#[test]
fn heartbeat_is_006_01() {
    assert_command_golden(0x006, &[0x01], Command::Heartbeat);
}

#[test]
fn scale_calibration_steps() {
    use ScaleCalibrationCommand as Step;
    assert_command_golden(0x007, &[0x01], Command::ScaleCalibration(Step::Start));
    assert_command_golden(0x007, &[0x02], Command::ScaleCalibration(Step::Tare));
    assert_command_golden(
        0x007,
        &[0x03, 0x03, 0xE8],
        Command::ScaleCalibration(Step::KnownWeight { grams: 1000 }),
    );
}

#[test]
fn odometry_calibration_steps() {
    use OdometryCalibrationCommand as Step;
    let cases: [(&[u8], Step); 7] = [
        (&[0x01], Step::StartLinear),
        (&[0x0C, 0x03, 0xE8], Step::EndLinear { real_mm: 1000 }),
        (&[0x02], Step::StartClockwise),
        (&[0x16, 0x18, 0x8C], Step::EndClockwise { real_mrad: 6284 }),
        (&[0x03], Step::StartCounterClockwise),
        (
            &[0x20, 0x18, 0x8C],
            Step::EndCounterClockwise { real_mrad: 6284 },
        ),
        (&[0x04], Step::Store),
    ];
    for (bytes, step) in cases {
        assert_command_golden(0x008, bytes, Command::OdometryCalibration(step));
    }
}

#[test]
fn single_byte_commands_accept_trailing_bytes() {
    assert_eq!(
        Command::decode(0x005, &[0x01, 0xFF]),
        Ok(Some(Command::ResetOdometry))
    );
    assert_eq!(
        Command::decode(0x006, &[0x01, 0, 0, 0, 0, 0, 0, 0]),
        Ok(Some(Command::Heartbeat))
    );
    assert_eq!(
        Command::decode(0x007, &[0x02, 0x99]),
        Ok(Some(Command::ScaleCalibration(
            ScaleCalibrationCommand::Tare
        )))
    );
    assert_eq!(
        Command::decode(0x008, &[0x0C, 0x03, 0xE8, 0x00]),
        Ok(Some(Command::OdometryCalibration(
            OdometryCalibrationCommand::EndLinear { real_mm: 1000 }
        )))
    );
}

// ---- Golden bytes, BC → PC ----

#[test]
fn position_x_1000_y_minus_2() {
    assert_report_golden(
        0x0EC,
        &[0xE8, 0x03, 0x00, 0x00, 0xFE, 0xFF, 0xFF, 0xFF],
        Report::Position {
            x_mm: 1000,
            y_mm: -2,
        },
    );
}

#[test]
fn heading_minus_1571_mrad() {
    assert_report_golden(
        0x0ED,
        &[0xDD, 0xF9, 0xFF, 0xFF],
        Report::Heading {
            heading_mrad: -1571,
        },
    );
}

#[test]
fn pose_time_100000_ms() {
    assert_report_golden(
        0x0EF,
        &[0xA0, 0x86, 0x01, 0x00],
        Report::PoseTime {
            controller_ms: 100_000,
        },
    );
}

#[test]
fn measured_speed_300_mm_s_turning_counter_clockwise() {
    assert_report_golden(
        0x0F0,
        &[0x2C, 0x01, 0x0C, 0xFE, 0xFA, 0x00, 0x5E, 0x01],
        Report::MeasuredSpeed {
            linear_mm_s: 300,
            rotation_mrad_s: -500,
            left_wheel_crad_s: 250,
            right_wheel_crad_s: 350,
        },
    );
}

#[test]
fn battery_87_percent_25300_mv() {
    assert_report_golden(
        0x0EB,
        &[87, 0xD4, 0x62],
        Report::Battery {
            percent: 87,
            voltage_mv: 25300,
        },
    );
}

#[test]
fn weight_1234_g() {
    assert_report_golden(0x0EA, &[0xD2, 0x04], Report::Weight { grams: 1234 });
}

#[test]
fn register_value_reply_keeps_the_manuals_bytes_and_adds_address_and_tag() {
    assert_report_golden(
        0x004,
        &[0x00, 0x00, 0x32, 0x0F, 0x00, 0x00],
        Report::RegisterValue {
            value: 50,
            echo: Some(ReadEcho {
                address: 15,
                tag: 0,
            }),
        },
    );
    assert_report_golden(
        0x004,
        &[0x00, 0x27, 0x57, 0x12, 0xBE, 0xEF],
        Report::RegisterValue {
            value: 10071,
            echo: Some(ReadEcho {
                address: 18,
                tag: 0xBEEF,
            }),
        },
    );
}

#[test]
fn a_manual_three_byte_value_reply_decodes_without_an_echo() {
    assert_report_golden(
        0x004,
        &[0x00, 0x27, 0x57],
        Report::RegisterValue {
            value: 10071,
            echo: None,
        },
    );
}

#[test]
fn register_read_error_reply_names_address_reason_and_tag() {
    assert_report_golden(
        0x004,
        &[0xFF, 0x2A, 0x10, 0xBE, 0xEF],
        Report::RegisterReadError {
            address: 0x2A,
            reason: 0x10,
            tag: Some(0xBEEF),
        },
    );
    assert_report_golden(
        0x004,
        &[0xFF, 0x2A, 0x10],
        Report::RegisterReadError {
            address: 0x2A,
            reason: 0x10,
            tag: None,
        },
    );
}

#[test]
fn register_replies_of_other_lengths_are_refused() {
    for data in [
        &[0x00, 0x27, 0x57, 0x12][..],
        &[0x00, 0x27, 0x57, 0x12, 0xBE],
        &[0x00, 0x27, 0x57, 0x12, 0xBE, 0xEF, 0x00],
        &[0xFF, 0x2A, 0x10, 0xBE],
        &[0xFF, 0x2A, 0x10, 0xBE, 0xEF, 0x00],
    ] {
        assert_eq!(
            Report::decode(0x004, data),
            Err(FrameError::WrongLength),
            "{data:02X?}"
        );
    }
}

#[test]
fn status_frame_places_every_field_in_its_byte_and_bit() {
    let status = Status {
        mode: Mode::AwaitingConfirm,
        control: ControlSource::Remote,
        persist_pending: true,
        flags: StatusFlags {
            enable_fresh: true,
            pc_on: false,
            safety_zone: true,
            remote_bonded: true,
            remote_connected: false,
            remote_in_control: false,
            estop_pressed: false,
            brakes_applied: true,
        },
        faults: Faults {
            left_drive_silent: false,
            left_drive_alarm: true,
            right_drive_silent: true,
            right_drive_alarm: false,
            flash: false,
            scale: true,
            can_bus: false,
            watchdog_reset: true,
        },
        rejected_count: 200,
        last_rejection: FrameError::BadVelocityMarker.code(),
        last_rejection_subject: 0xC8,
        drive_alarm: 0x84,
        modbus_errors: 7,
    };
    assert_report_golden(
        0x0EE,
        // 0xA4: persist pending (bit 7), remote (2 in bits 4-6), awaiting confirm (4).
        &[0xA4, 0x8D, 0xA6, 200, 0x02, 0xC8, 0x84, 0x07],
        Report::Status(status),
    );
}

#[test]
fn status_frame_encodes_each_mode_and_control_source_in_its_nibble() {
    let modes = [
        (Mode::Starting, 0),
        (Mode::Standby, 1),
        (Mode::Active, 2),
        (Mode::Emergency, 3),
        (Mode::AwaitingConfirm, 4),
        (Mode::Recovering, 5),
        (Mode::Fault, 6),
    ];
    let sources = [
        (ControlSource::None, 0x00),
        (ControlSource::Can, 0x10),
        (ControlSource::Remote, 0x20),
    ];
    for (mode, mode_bits) in modes {
        for (control, control_bits) in sources {
            let status = Status {
                mode,
                control,
                ..Status::default()
            };
            let byte0 = mode_bits | control_bits;
            assert_report_golden(0x0EE, &[byte0, 0, 0, 0, 0, 0, 0, 0], Report::Status(status));
        }
    }
}

// ---- Frames that are not ours ----

#[test]
fn register_replies_on_0x004_are_not_commands() {
    assert_eq!(Command::decode(0x004, &[0x00, 0x00, 0x32]), Ok(None));
    assert_eq!(Command::decode(0x004, &[0xFF, 0x2A, 0x10]), Ok(None));
    assert_eq!(Command::decode(0x004, &[0x00]), Ok(None));
}

#[test]
fn register_read_requests_on_0x004_are_not_reports() {
    assert_eq!(Report::decode(0x004, &[0x01, 0x0F]), Ok(None));
    assert_eq!(Report::decode(0x004, &[0x02, 0x0F, 0x08, 0, 1]), Ok(None));
}

#[test]
fn unknown_ids_are_ignored_whatever_they_carry() {
    for id in [
        0x000,
        0x001,
        0x009,
        0x0C9,
        0x0E9,
        0x0F1,
        0x2E5,
        0x7FF,
        0x800,
        u16::MAX,
    ] {
        assert_eq!(
            Command::decode(id, &[0x01, 0x02, 0x03]),
            Ok(None),
            "{id:#x}"
        );
        assert_eq!(Command::decode(id, &[0; 12]), Ok(None), "{id:#x}");
        assert_eq!(Report::decode(id, &[]), Ok(None), "{id:#x}");
    }
}

#[test]
fn reports_are_not_commands_and_commands_are_not_reports() {
    for id in [
        id::WEIGHT,
        id::BATTERY,
        id::POSITION,
        id::HEADING,
        id::STATUS,
        id::POSE_TIME,
        id::MEASURED_SPEED,
    ] {
        assert_eq!(Command::decode(id, &[0x01, 0, 0, 0, 0, 0, 0, 0]), Ok(None));
    }
    for id in [id::ENABLE, id::VELOCITY, id::REGISTER_WRITE, id::HEARTBEAT] {
        assert_eq!(Report::decode(id, &[0x40, 0, 0, 0, 0, 0, 0, 0]), Ok(None));
    }
}

// ---- Rejections, PC → BC ----

#[test]
fn every_command_frame_shorter_than_its_minimum_is_wrong_length() {
    let too_short: [(u16, &[u8]); 16] = [
        (0x2E4, &[]),
        (0x0C8, &[]),
        (0x0C8, &[0xF4, 0x01, 0x00, 0x00]),
        (0x003, &[]),
        (0x003, &[0x0F, 0x00]),
        (0x004, &[]),
        (0x004, &[0x01]),
        (0x005, &[]),
        (0x006, &[]),
        (0x007, &[]),
        (0x007, &[0x03, 0x03]),
        (0x008, &[]),
        (0x008, &[0x0C, 0x03]),
        (0x008, &[0x16]),
        (0x008, &[0x20, 0x18]),
        (0x008, &[0x0C]),
    ];
    for (id, bytes) in too_short {
        assert_eq!(
            command_error(id, bytes),
            FrameError::WrongLength,
            "{id:03X}#{bytes:02X?}"
        );
    }
}

#[test]
fn more_than_eight_bytes_is_wrong_length_for_every_known_id() {
    let nine = [0x01, 0x0F, 0x00, 0x00, 0x03, 0, 0, 0, 0];
    for id in id::COMMANDS {
        assert_eq!(command_error(id, &nine), FrameError::WrongLength, "{id:#x}");
    }
    for id in id::REPORTS {
        assert_eq!(report_error(id, &nine), FrameError::WrongLength, "{id:#x}");
    }
    // Even a 0x004 "reply" that is too long for any CAN frame.
    assert_eq!(command_error(0x004, &[0x00; 9]), FrameError::WrongLength);
}

#[test]
fn velocity_without_marker_0x03_is_refused() {
    for marker in [0x00, 0x02, 0x04, 0x30, 0xFF] {
        assert_eq!(
            command_error(0x0C8, &[0xF4, 0x01, 0x00, 0x00, marker]),
            FrameError::BadVelocityMarker,
            "marker {marker:#04x}"
        );
    }
}

#[test]
fn unknown_sub_commands_are_refused() {
    let cases: [(u16, &[u8]); 12] = [
        (0x004, &[0x03, 0x0F]),
        (0x004, &[0xFE, 0x0F]),
        (0x005, &[0x00]),
        (0x005, &[0x02]),
        (0x006, &[0x00]),
        (0x006, &[0xFF]),
        (0x007, &[0x00]),
        (0x007, &[0x04, 0x03, 0xE8]),
        (0x008, &[0x00]),
        (0x008, &[0x05]),
        (0x008, &[0x0B, 0x03, 0xE8]),
        (0x008, &[0x21, 0x18, 0x8C]),
    ];
    for (id, bytes) in cases {
        assert_eq!(
            command_error(id, bytes),
            FrameError::UnknownSubcommand,
            "{id:03X}#{bytes:02X?}"
        );
    }
}

// ---- Rejections, BC → PC ----

#[test]
fn reports_need_their_exact_length() {
    let wrong: [(u16, &[u8]); 14] = [
        (0x0EF, &[0; 3]),
        (0x0EF, &[0; 5]),
        (0x0EC, &[0; 7]),
        (0x0EC, &[]),
        (0x0ED, &[0; 3]),
        (0x0ED, &[0; 5]),
        (0x0EB, &[0; 2]),
        (0x0EB, &[0; 4]),
        (0x0EA, &[0; 1]),
        (0x0EA, &[0; 3]),
        (0x004, &[]),
        (0x004, &[0x00, 0x00]),
        (0x004, &[0xFF, 0x2A, 0x10, 0x00]),
        (0x0EE, &[0; 7]),
    ];
    for (id, bytes) in wrong {
        assert_eq!(
            report_error(id, bytes),
            FrameError::WrongLength,
            "{id:03X}#{bytes:02X?}"
        );
    }
}

#[test]
fn register_reply_with_unknown_first_byte_is_refused() {
    assert_eq!(
        report_error(0x004, &[0x03, 0x00, 0x32]),
        FrameError::UnknownSubcommand
    );
}

#[test]
fn status_with_undefined_mode_or_control_source_is_refused() {
    assert_eq!(
        report_error(0x0EE, &[0x07, 0, 0, 0, 0, 0, 0, 0]),
        FrameError::UnknownSubcommand
    );
    assert_eq!(
        report_error(0x0EE, &[0x0F, 0, 0, 0, 0, 0, 0, 0]),
        FrameError::UnknownSubcommand
    );
    assert_eq!(
        report_error(0x0EE, &[0x31, 0, 0, 0, 0, 0, 0, 0]),
        FrameError::UnknownSubcommand
    );
}

#[test]
fn every_encoded_frame_is_a_valid_classic_can_frame() {
    let frames = [
        Command::Enable { refresh: true }.encode(),
        Report::Status(Status::default()).encode(),
        Report::Position { x_mm: 1, y_mm: 2 }.encode(),
    ];
    for frame in frames {
        assert_eq!(RawFrame::new(frame.id(), frame.data()), Some(frame));
    }
}

// ---- Properties ----

fn scale_step() -> impl Strategy<Value = ScaleCalibrationCommand> {
    use ScaleCalibrationCommand as Step;
    prop_oneof![
        Just(Step::Start),
        Just(Step::Tare),
        any::<u16>().prop_map(|grams| Step::KnownWeight { grams }),
    ]
}

fn odometry_step() -> impl Strategy<Value = OdometryCalibrationCommand> {
    use OdometryCalibrationCommand as Step;
    prop_oneof![
        Just(Step::StartLinear),
        any::<u16>().prop_map(|real_mm| Step::EndLinear { real_mm }),
        Just(Step::StartClockwise),
        any::<u16>().prop_map(|real_mrad| Step::EndClockwise { real_mrad }),
        Just(Step::StartCounterClockwise),
        any::<u16>().prop_map(|real_mrad| Step::EndCounterClockwise { real_mrad }),
        Just(Step::Store),
    ]
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        any::<bool>().prop_map(|refresh| Command::Enable { refresh }),
        (any::<i16>(), any::<i16>()).prop_map(|(linear_mm_s, rotation_mrad_s)| {
            Command::Velocity {
                linear_mm_s,
                rotation_mrad_s,
            }
        }),
        (any::<u8>(), any::<u16>())
            .prop_map(|(address, value)| Command::RegisterWrite { address, value }),
        (any::<u8>(), any::<u16>())
            .prop_map(|(address, tag)| Command::RegisterRead { address, tag }),
        (any::<u8>(), 1..=BULK_READ_MAX, any::<u16>()).prop_map(|(first, count, tag)| {
            Command::RegisterBulkRead {
                first: first.min(u8::MAX - (count - 1)),
                count,
                tag,
            }
        }),
        Just(Command::ResetOdometry),
        Just(Command::Heartbeat),
        scale_step().prop_map(Command::ScaleCalibration),
        odometry_step().prop_map(Command::OdometryCalibration),
    ]
}

fn mode() -> impl Strategy<Value = Mode> {
    prop_oneof![
        Just(Mode::Starting),
        Just(Mode::Standby),
        Just(Mode::Active),
        Just(Mode::Emergency),
        Just(Mode::AwaitingConfirm),
        Just(Mode::Recovering),
        Just(Mode::Fault),
    ]
}

fn control_source() -> impl Strategy<Value = ControlSource> {
    prop_oneof![
        Just(ControlSource::None),
        Just(ControlSource::Can),
        Just(ControlSource::Remote),
    ]
}

fn status() -> impl Strategy<Value = Status> {
    (mode(), control_source(), any::<bool>(), any::<[u8; 7]>()).prop_map(
        |(mode, control, persist_pending, bytes)| {
            let [
                flags,
                faults,
                rejected_count,
                last_rejection,
                subject,
                drive_alarm,
                modbus,
            ] = bytes;
            Status {
                mode,
                control,
                persist_pending,
                flags: StatusFlags::from_byte(flags),
                faults: Faults::from_byte(faults),
                rejected_count,
                last_rejection,
                last_rejection_subject: subject,
                drive_alarm,
                modbus_errors: modbus,
            }
        },
    )
}

fn report() -> impl Strategy<Value = Report> {
    prop_oneof![
        (any::<i32>(), any::<i32>()).prop_map(|(x_mm, y_mm)| Report::Position { x_mm, y_mm }),
        any::<i32>().prop_map(|heading_mrad| Report::Heading { heading_mrad }),
        (any::<u8>(), any::<u16>()).prop_map(|(percent, voltage_mv)| Report::Battery {
            percent,
            voltage_mv
        }),
        any::<u16>().prop_map(|grams| Report::Weight { grams }),
        (
            any::<u16>(),
            proptest::option::of((any::<u8>(), any::<u16>()))
        )
            .prop_map(|(value, echo)| Report::RegisterValue {
                value,
                echo: echo.map(|(address, tag)| ReadEcho { address, tag }),
            }),
        (any::<u8>(), any::<u8>(), proptest::option::of(any::<u16>())).prop_map(
            |(address, reason, tag)| Report::RegisterReadError {
                address,
                reason,
                tag
            }
        ),
        status().prop_map(Report::Status),
    ]
}

/// Mostly protocol IDs, so the interesting branches get most of the cases.
fn any_id() -> impl Strategy<Value = u16> {
    prop_oneof![
        prop::sample::select(id::COMMANDS.to_vec()),
        prop::sample::select(id::REPORTS.to_vec()),
        0..=0x7FFu16,
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    #[test]
    fn decoders_never_panic_on_any_frame(
        id in any_id(),
        data in prop::collection::vec(any::<u8>(), 0..=16),
    ) {
        let command = Command::decode(id, &data);
        let report = Report::decode(id, &data);
        if data.len() > 8 {
            prop_assert!(matches!(command, Ok(None) | Err(FrameError::WrongLength)));
            prop_assert!(matches!(report, Ok(None) | Err(FrameError::WrongLength)));
        }
    }

    #[test]
    fn a_decoded_command_reencodes_to_a_frame_that_decodes_the_same(
        id in any_id(),
        data in prop::collection::vec(any::<u8>(), 0..=8),
    ) {
        if let Ok(Some(command)) = Command::decode(id, &data) {
            let frame = command.encode();
            prop_assert_eq!(frame.id(), id);
            prop_assert_eq!(Command::decode(frame.id(), frame.data()), Ok(Some(command)));
        }
    }

    #[test]
    fn a_decoded_report_reencodes_to_the_same_bytes(
        id in any_id(),
        data in prop::collection::vec(any::<u8>(), 0..=8),
    ) {
        if let Ok(Some(report)) = Report::decode(id, &data) {
            let frame = report.encode();
            prop_assert_eq!((frame.id(), frame.data()), (id, data.as_slice()));
        }
    }

    #[test]
    fn every_command_round_trips_through_its_frame(command in command()) {
        let frame = command.encode();
        prop_assert!(frame.data().len() <= 8);
        prop_assert_eq!(Command::decode(frame.id(), frame.data()), Ok(Some(command)));
        // A command is never mistaken for a report on the same bus.
        prop_assert_eq!(Report::decode(frame.id(), frame.data()), Ok(None));
    }

    #[test]
    fn every_report_round_trips_through_its_frame(report in report()) {
        let frame = report.encode();
        prop_assert!(frame.data().len() <= 8);
        prop_assert_eq!(Report::decode(frame.id(), frame.data()), Ok(Some(report)));
        // The robot never takes its own reports for commands.
        prop_assert_eq!(Command::decode(frame.id(), frame.data()), Ok(None));
    }
}
