//! Golden bytes: every full report and output report below was laid out by hand from
//! the byte tables in the module documentation, and its CRC computed with Python's
//! `zlib.crc32` (an implementation independent of the `crc` crate used here).

use proptest::prelude::*;

use super::*;
use crate::hid::test_data::hex;

/// DualShock 4 full report: left stick pushed forward, right stick full right, Cross,
/// R1 and Options held, PS held, L2 fully pulled, battery 8/10 on battery power.
const DUALSHOCK4_FULL: &str = "
A1 11 C0 00 80 00 FF 7F 28 26 55 FF 00 34 12 1A
01 00 FF FF 03 00 10 00 E0 1F 20 00 00 00 00 00
00 08 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 87 74 B4 33";

/// DualSense full report: left stick full left and pulled back, R2 at 0xC0, Square,
/// L1, Create and the touchpad held, D-pad right, battery 3/10 and charging.
const DUALSENSE_FULL: &str = "
A1 31 00 00 FF 80 80 00 C0 2A 12 11 02 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 13 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 C2 7A D2 B0";

/// The answer to GET_REPORT feature 0x05 (calibration bytes made up, CRC real).
const FEATURE_05: &str = "
A3 05 0E 15 1C 23 2A 31 38 3F 46 4D 54 5B 62 69
70 77 7E 85 8C 93 9A A1 A8 AF B6 BD C4 CB D2 D9
E0 E7 EE F5 FC 03 7D 26 BD 91";

/// DualShock 4 output: light bar red, strong motor 0x40, weak motor 0x20.
const DUALSHOCK4_OUTPUT_RED: &str = "
A2 11 C4 00 03 00 00 20 40 FF 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 8D F2 4B 39";

/// DualSense first output: green, strong 0x40, weak 0x20, start-up light ended.
const DUALSENSE_OUTPUT_FIRST_GREEN: &str = "
A2 31 00 10 03 04 20 40 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 02 00 00 02 00 00
00 FF 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 22 FD BA 5A";

/// DualSense second output: blue, motors off, sequence number 1.
const DUALSENSE_OUTPUT_SECOND_BLUE: &str = "
A2 31 10 10 03 04 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 FF 00 00 00 00 00 00 00 00 00 00 00 00 00
00 00 00 00 00 00 00 00 00 00 00 6F DB 9E 48";

fn full(kind: PadKind) -> Vec<u8> {
    hex(match kind {
        PadKind::DualShock4 => DUALSHOCK4_FULL,
        PadKind::DualSense => DUALSENSE_FULL,
    })
}

fn short(sticks: [u8; 4], buttons: [u8; 3], triggers: [u8; 2]) -> Vec<u8> {
    let mut report = vec![HEADER_INPUT, SHORT_REPORT_ID];
    report.extend(sticks);
    report.extend(buttons);
    report.extend(triggers);
    report
}

#[test]
fn the_crc_is_zlibs_crc32_over_the_seed_byte_and_the_report() {
    // The CRC-32 check value: "123456789" → 0xCBF43926; the seed is its first byte.
    assert_eq!(crc32(b'1', b"23456789"), 0xCBF4_3926);
    assert_eq!(crc32(HEADER_INPUT, &[]), 0x73D3_7CF3);
}

#[test]
fn a_dualshock4_full_report_decodes_sticks_buttons_l2_and_battery() {
    let report = decode_input(PadKind::DualShock4, &full(PadKind::DualShock4)).unwrap();
    assert_eq!(report.mode, ReportMode::Full);
    let state = report.state;
    assert_eq!((state.left_x, state.left_y), (0.0, 1.0));
    assert_eq!((state.right_x, state.right_y), (1.0, 0.0));
    assert_eq!((state.left_trigger, state.right_trigger), (1.0, 0.0));
    assert_eq!(
        state.buttons,
        Buttons::A
            .with(Buttons::RIGHT_BUMPER)
            .with(Buttons::MENU)
            .with(Buttons::HOME)
    );
    assert_eq!(state.dpad, Dpad::default());
    assert_eq!(
        report.battery,
        Some(Battery {
            percent: 85,
            state: BatteryState::Discharging
        })
    );
}

#[test]
fn a_dualsense_full_report_decodes_sticks_buttons_dpad_r2_and_battery() {
    let report = decode_input(PadKind::DualSense, &full(PadKind::DualSense)).unwrap();
    assert_eq!(report.mode, ReportMode::Full);
    let state = report.state;
    assert_eq!((state.left_x, state.left_y), (-1.0, -1.0));
    assert_eq!((state.right_x, state.right_y), (0.0, 0.0));
    assert_eq!(state.left_trigger, 0.0);
    assert_eq!(state.right_trigger, 192.0 / 255.0);
    // The touchpad click (0x02 in the third byte) has no name and is not reported.
    assert_eq!(
        state.buttons,
        Buttons::X.with(Buttons::LEFT_BUMPER).with(Buttons::VIEW)
    );
    assert_eq!(
        state.dpad,
        Dpad {
            right: true,
            ..Dpad::default()
        }
    );
    assert_eq!(
        report.battery,
        Some(Battery {
            percent: 35,
            state: BatteryState::Charging
        })
    );
}

#[test]
fn both_pads_short_report_decodes_without_battery() {
    // R1 held, L2 pulled, PS pressed: the switch-off combination, in short mode.
    let payload = short([0x80, 0x80, 0x80, 0x80], [0x08, 0x02, 0x01], [0xFF, 0x00]);
    for kind in [PadKind::DualShock4, PadKind::DualSense] {
        let report = decode_input(kind, &payload).unwrap();
        assert_eq!(report.mode, ReportMode::Short);
        assert_eq!(report.battery, None);
        assert_eq!(
            report.state,
            GamepadState {
                left_trigger: 1.0,
                buttons: Buttons::RIGHT_BUMPER.with(Buttons::HOME),
                ..GamepadState::default()
            }
        );
    }
}

#[test]
fn the_rest_position_of_the_sticks_is_inside_the_dead_zone() {
    // 0x80 is 1/255 right of centre, 0x7F 1/255 left; pads rest a few counts off, and
    // the dead zone (10 %) spans 0x73 … 0x8C.
    for raw in [0x73, 0x7F, 0x80, 0x8C] {
        let payload = short([raw; 4], [0x08, 0, 0], [0, 0]);
        let state = decode_input(PadKind::DualShock4, &payload).unwrap().state;
        assert_eq!(
            [state.left_x, state.left_y, state.right_x, state.right_y],
            [0.0; 4],
            "raw {raw:#04x}"
        );
    }
    let just_outside = short([0x8D; 4], [0x08, 0, 0], [0, 0]);
    let state = decode_input(PadKind::DualShock4, &just_outside)
        .unwrap()
        .state;
    assert!(state.left_x > 0.0 && state.left_y < 0.0);
}

#[test]
fn every_button_bit_maps_to_its_name() {
    let table: [([u8; 3], Buttons); 11] = [
        ([0x18, 0, 0], Buttons::X),
        ([0x28, 0, 0], Buttons::A),
        ([0x48, 0, 0], Buttons::B),
        ([0x88, 0, 0], Buttons::Y),
        ([0x08, 0x01, 0], Buttons::LEFT_BUMPER),
        ([0x08, 0x02, 0], Buttons::RIGHT_BUMPER),
        ([0x08, 0x10, 0], Buttons::VIEW),
        ([0x08, 0x20, 0], Buttons::MENU),
        ([0x08, 0x40, 0], Buttons::LEFT_STICK),
        ([0x08, 0x80, 0], Buttons::RIGHT_STICK),
        ([0x08, 0, 0x01], Buttons::HOME),
    ];
    for (bytes, button) in table {
        let state = decode_input(PadKind::DualSense, &short([0x80; 4], bytes, [0, 0]))
            .unwrap()
            .state;
        assert_eq!(state.buttons, button, "bytes {bytes:02x?}");
    }
    // Digital L2/R2, the touchpad, the mic button and the DualShock 4's report counter
    // in the upper bits of the third byte name nothing.
    let unnamed = short([0x80; 4], [0x08, 0x0C, 0xFE], [0, 0]);
    let state = decode_input(PadKind::DualShock4, &unnamed).unwrap().state;
    assert_eq!(state.buttons, Buttons::NONE);
}

#[test]
fn the_hat_nibble_gives_eight_directions_and_anything_else_is_released() {
    let (up, right, down, left) = (true, true, true, true);
    let none = Dpad::default();
    let table = [
        (0, Dpad { up, ..none }),
        (1, Dpad { up, right, ..none }),
        (2, Dpad { right, ..none }),
        (
            3,
            Dpad {
                down,
                right,
                ..none
            },
        ),
        (4, Dpad { down, ..none }),
        (5, Dpad { down, left, ..none }),
        (6, Dpad { left, ..none }),
        (7, Dpad { up, left, ..none }),
        (8, none),
        (15, none),
    ];
    for (nibble, dpad) in table {
        let payload = short([0x80; 4], [0xF0 | nibble, 0, 0], [0, 0]);
        let state = decode_input(PadKind::DualShock4, &payload).unwrap().state;
        assert_eq!(state.dpad, dpad, "hat {nibble}");
    }
}

#[test]
fn battery_status_bytes_of_both_pads() {
    use BatteryState::*;
    let dualshock4 = [
        (0x00, 5, Discharging),
        (0x09, 95, Discharging),
        (0x0A, 100, Discharging),
        (0x0F, 100, Discharging),
        (0x13, 35, Charging),
        (0x1A, 100, Charging),
        (0x1B, 100, Full),
        (0x1E, 0, Fault),
    ];
    for (status, percent, state) in dualshock4 {
        assert_eq!(
            dualshock4_battery(status),
            Battery { percent, state },
            "{status:#04x}"
        );
    }
    let dualsense = [
        (0x00, 5, Discharging),
        (0x0A, 100, Discharging),
        (0x0F, 100, Discharging),
        (0x17, 75, Charging),
        (0x25, 100, Full),
        (0xA5, 0, Fault),
        (0xB5, 0, Fault),
        (0xF0, 0, Fault),
    ];
    for (status, percent, state) in dualsense {
        assert_eq!(
            dualsense_battery(status),
            Battery { percent, state },
            "{status:#04x}"
        );
    }
}

#[test]
fn a_corrupted_byte_or_crc_is_refused_as_bad_crc() {
    for kind in [PadKind::DualShock4, PadKind::DualSense] {
        for index in [1, 10, 74, 75, 78] {
            let mut payload = full(kind);
            payload[index] ^= 0x01;
            let result = decode_input(kind, &payload);
            // Flipping the report ID makes it another report; anything else is a CRC error.
            if index == 1 {
                assert!(matches!(
                    result,
                    Err(PadReportError::UnknownReportId { .. })
                ));
            } else {
                assert!(
                    matches!(result, Err(PadReportError::BadCrc { .. })),
                    "{kind:?} byte {index}: {result:?}"
                );
            }
        }
    }
}

#[test]
fn wrong_lengths_unknown_ids_and_wrong_headers_are_refused() {
    let dualshock4 = full(PadKind::DualShock4);
    let mut longer = dualshock4.clone();
    longer.push(0);
    let mut dualshock4_extended = dualshock4.clone();
    dualshock4_extended[1] = 0x12;
    let mut as_output = dualshock4.clone();
    as_output[0] = HEADER_OUTPUT;
    let short_report = short([0x80; 4], [0x08, 0, 0], [0, 0]);
    let table: [(&[u8], PadReportError); 8] = [
        (&[], PadReportError::Truncated { received: 0 }),
        (&[HEADER_INPUT], PadReportError::Truncated { received: 1 }),
        (
            &dualshock4[..78],
            PadReportError::WrongLength {
                report_id: 0x11,
                expected: 79,
                received: 78,
            },
        ),
        (
            &longer,
            PadReportError::WrongLength {
                report_id: 0x11,
                expected: 79,
                received: 80,
            },
        ),
        (
            &short_report[..10],
            PadReportError::WrongLength {
                report_id: 0x01,
                expected: 11,
                received: 10,
            },
        ),
        (
            &dualshock4_extended,
            PadReportError::UnknownReportId { report_id: 0x12 },
        ),
        // A DualSense report reaching a DualShock 4 decoder.
        (
            &full(PadKind::DualSense),
            PadReportError::UnknownReportId { report_id: 0x31 },
        ),
        (&as_output, PadReportError::WrongHeader { header: 0xA2 }),
    ];
    for (payload, error) in table {
        assert_eq!(
            decode_input(PadKind::DualShock4, payload),
            Err(error),
            "{payload:02x?}"
        );
    }
}

#[test]
fn the_decoder_counts_every_outcome() {
    let mut decoder = PadDecoder::new(PadKind::DualSense);
    let good = full(PadKind::DualSense);
    let mut corrupted = good.clone();
    corrupted[20] ^= 0x80;
    let payloads: [&[u8]; 7] = [
        &short([0x80; 4], [0x08, 0, 0], [0, 0]),
        &good,
        &good,
        &corrupted,
        &good[..40],
        &full(PadKind::DualShock4),
        &[0xA2, 0x31],
    ];
    for payload in payloads {
        let _ = decoder.decode(payload);
    }
    assert_eq!(
        decoder.counters(),
        PadReportCounters {
            full: 2,
            short: 1,
            truncated: 0,
            wrong_header: 1,
            unknown_report_id: 1,
            wrong_length: 1,
            bad_crc: 1,
        }
    );
    assert_eq!(decoder.counters().refused(), 4);
}

#[test]
fn the_feature_answer_is_checked_for_id_length_and_crc() {
    let good = hex(FEATURE_05);
    assert_eq!(check_full_mode_feature(&good), Ok(()));
    let mut corrupted = good.clone();
    corrupted[5] ^= 0x10;
    assert!(matches!(
        check_full_mode_feature(&corrupted),
        Err(PadReportError::BadCrc { .. })
    ));
    let mut other_id = good.clone();
    other_id[1] = 0x02;
    assert_eq!(
        check_full_mode_feature(&other_id),
        Err(PadReportError::UnknownReportId { report_id: 0x02 })
    );
    assert_eq!(
        check_full_mode_feature(&good[..41]),
        Err(PadReportError::WrongLength {
            report_id: 0x05,
            expected: 42,
            received: 41
        })
    );
    // An input report is not a feature answer.
    assert_eq!(
        check_full_mode_feature(&full(PadKind::DualShock4)),
        Err(PadReportError::WrongHeader { header: 0xA1 })
    );
}

#[test]
fn dualshock4_output_sets_light_bar_rumble_and_poll_interval() {
    let mut builder = OutputBuilder::new(PadKind::DualShock4);
    let output = PadOutput {
        light_bar: Rgb::new(0xFF, 0, 0),
        rumble: Rumble {
            strong: 0x40,
            weak: 0x20,
        },
    };
    assert_eq!(builder.build(&output).to_vec(), hex(DUALSHOCK4_OUTPUT_RED));
    // The DualShock 4's report has no sequence: the same output gives the same bytes.
    assert_eq!(builder.build(&output).to_vec(), hex(DUALSHOCK4_OUTPUT_RED));
}

#[test]
fn dualsense_output_ends_the_start_up_light_once_and_numbers_its_reports() {
    let mut builder = OutputBuilder::new(PadKind::DualSense);
    let green = PadOutput {
        light_bar: Rgb::new(0, 0xFF, 0),
        rumble: Rumble {
            strong: 0x40,
            weak: 0x20,
        },
    };
    let blue = PadOutput {
        light_bar: Rgb::new(0, 0, 0xFF),
        rumble: Rumble::default(),
    };
    assert_eq!(
        builder.build(&green).to_vec(),
        hex(DUALSENSE_OUTPUT_FIRST_GREEN)
    );
    assert_eq!(
        builder.build(&blue).to_vec(),
        hex(DUALSENSE_OUTPUT_SECOND_BLUE)
    );
    // The sequence number runs 0 … 15 in the high nibble of byte 2, then starts over.
    let sequences: Vec<u8> = (2..18).map(|_| builder.build(&blue)[2]).collect();
    let expected: Vec<u8> = (2..16).chain(0..2).map(|number| number << 4).collect();
    assert_eq!(sequences, expected);
    let again = builder.build(&blue);
    assert_eq!((again[42], again[45]), (0, 0));
}

#[test]
fn every_output_report_carries_a_valid_crc() {
    for kind in [PadKind::DualShock4, PadKind::DualSense] {
        let report = OutputBuilder::new(kind).build(&PadOutput::default());
        let (covered, crc) = report.split_at(OUTPUT_REPORT_LEN - 4);
        assert_eq!(
            crc32(covered[0], &covered[1..]).to_le_bytes(),
            [crc[0], crc[1], crc[2], crc[3]]
        );
    }
}

#[test]
fn the_pad_kind_comes_from_the_device_ids() {
    let table = [
        (0x054C, 0x05C4, Some(PadKind::DualShock4)),
        (0x054C, 0x09CC, Some(PadKind::DualShock4)),
        (0x054C, 0x0CE6, Some(PadKind::DualSense)),
        (0x054C, 0x0DF2, Some(PadKind::DualSense)),
        // Sony's PS3 pad and another vendor's pad with a DualShock 4 product ID.
        (0x054C, 0x0268, None),
        (0x045E, 0x05C4, None),
    ];
    for (vendor, product, kind) in table {
        assert_eq!(PadKind::from_ids(VidPid::new(vendor, product)), kind);
    }
}

#[test]
fn the_pad_kind_comes_from_the_full_report_id() {
    assert_eq!(
        PadKind::from_full_report(&full(PadKind::DualShock4)),
        Some(PadKind::DualShock4)
    );
    assert_eq!(
        PadKind::from_full_report(&full(PadKind::DualSense)),
        Some(PadKind::DualSense)
    );
    let short_report = short([0x80; 4], [0x08, 0, 0], [0, 0]);
    assert_eq!(PadKind::from_full_report(&short_report), None);
    assert_eq!(PadKind::from_full_report(&[0xA2, 0x11]), None);
    assert_eq!(PadKind::from_full_report(&[]), None);
}

proptest! {
    #[test]
    fn any_bytes_decode_in_range_or_are_refused(
        payload in proptest::collection::vec(any::<u8>(), 0..100),
        dualsense in any::<bool>(),
    ) {
        let kind = if dualsense { PadKind::DualSense } else { PadKind::DualShock4 };
        if let Ok(report) = decode_input(kind, &payload) {
            let state = report.state;
            for stick in [state.left_x, state.left_y, state.right_x, state.right_y] {
                prop_assert!((-1.0..=1.0).contains(&stick));
            }
            for trigger in [state.left_trigger, state.right_trigger] {
                prop_assert!((0.0..=1.0).contains(&trigger));
            }
        }
    }
}
