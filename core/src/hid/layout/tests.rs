use super::{GamepadLayout, ReportError, VidPid};
use crate::gamepad::{Buttons, Dpad, GamepadState};
use crate::hid::test_data::{EIGHTBITDO_WINDOWS, XBOX_BLE, XBOX_ONE_S_BREDR, hex};
use crate::hid::{DescriptorError, ReportMap};
use proptest::prelude::*;

const XBOX_ONE_S_FW3: VidPid = VidPid::new(0x045E, 0x02E0);
const XBOX_ONE_S_FW4: VidPid = VidPid::new(0x045E, 0x02FD);
const STADIA: VidPid = VidPid::new(0x18D1, 0x9400);

fn layout(file: &str, ids: Option<VidPid>) -> GamepadLayout {
    GamepadLayout::parse(&hex(file), ids).unwrap()
}

/// `items` inside a Generic Desktop / Game Pad application collection.
fn gamepad_map(items: &[u8]) -> Vec<u8> {
    [&[0x05, 0x01, 0x09, 0x05, 0xA1, 0x01], items, &[0xC0]].concat()
}

fn pressed(buttons: Buttons) -> GamepadState {
    GamepadState {
        buttons,
        ..GamepadState::default()
    }
}

#[track_caller]
fn assert_near(actual: f32, expected: f32) {
    assert!(
        (actual - expected).abs() < 1e-4,
        "{actual} is not {expected}"
    );
}

/// Report 1 of the Xbox maps (BLE and One S 4.8), as the files' layout comment has it.
#[derive(Clone, Copy)]
struct XboxReport {
    /// LX, LY, RX, RY: 0 … 65535, centre 0x8000.
    sticks: [u16; 4],
    /// LT, RT: 0 … 1023.
    triggers: [u16; 2],
    /// 1 … 8 clockwise from up, 0 centred.
    hat: u8,
    /// Button 1 in bit 0.
    buttons: u16,
    /// Byte 15 bit 0: Share (BLE) or View (One S 4.8).
    consumer: bool,
}

impl XboxReport {
    const NEUTRAL: XboxReport = XboxReport {
        sticks: [0x8000; 4],
        triggers: [0; 2],
        hat: 0,
        buttons: 0,
        consumer: false,
    };

    fn bytes(self) -> Vec<u8> {
        let mut bytes: Vec<u8> = self
            .sticks
            .iter()
            .chain(&self.triggers)
            .flat_map(|value| value.to_le_bytes())
            .collect();
        bytes.push(self.hat);
        bytes.extend(self.buttons.to_le_bytes());
        bytes.push(u8::from(self.consumer));
        bytes
    }
}

// ---- Xbox BLE samples (file comments) --------------------------------------------

#[test]
fn xbox_ble_neutral_report_centres_everything() {
    let mut pad = layout(XBOX_BLE, None);
    let neutral = hex("00 80 00 80 00 80 00 80 00 00 00 00 00 00 00 00");
    assert_eq!(pad.decode(1, &neutral), Ok(Some(GamepadState::default())));
}

#[test]
fn xbox_ble_btmon_samples_read_menu_view_and_share_with_sticks_at_rest() {
    let mut pad = layout(XBOX_BLE, Some(VidPid::new(0x045E, 0x0B13)));
    let samples = [
        (
            "eb 7e 5f 80 eb 7f 85 80 00 00 00 00 00 00 08 00",
            Buttons::MENU,
        ),
        (
            "eb 7e 5f 80 eb 7f 85 80 00 00 00 00 00 00 04 00",
            Buttons::VIEW,
        ),
        (
            "eb 7e 5f 80 eb 7f 85 80 00 00 00 00 00 00 00 01",
            Buttons::SHARE,
        ),
    ];
    for (sample, button) in samples {
        assert_eq!(
            pad.decode(1, &hex(sample)),
            Ok(Some(pressed(button))),
            "{sample}"
        );
    }
}

#[test]
fn xbox_ble_button_bits_have_their_xbox_names() {
    let mut pad = layout(XBOX_BLE, None);
    let bits = [
        (0, Buttons::A),
        (1, Buttons::B),
        (2, Buttons::NONE),
        (3, Buttons::X),
        (4, Buttons::Y),
        (5, Buttons::NONE),
        (6, Buttons::LEFT_BUMPER),
        (7, Buttons::RIGHT_BUMPER),
        (8, Buttons::NONE),
        (9, Buttons::NONE),
        (10, Buttons::VIEW),
        (11, Buttons::MENU),
        (12, Buttons::HOME),
        (13, Buttons::LEFT_STICK),
        (14, Buttons::RIGHT_STICK),
    ];
    for (bit, button) in bits {
        let report = XboxReport {
            buttons: 1 << bit,
            ..XboxReport::NEUTRAL
        };
        let state = pad.decode(1, &report.bytes()).unwrap().unwrap();
        assert_eq!(state.buttons, button, "bit {bit}");
    }
}

#[test]
fn xbox_ble_sticks_and_triggers_reach_full_scale_with_forward_positive() {
    let mut pad = layout(XBOX_BLE, None);
    let report = XboxReport {
        // Left stick full left and pushed forward (HID Y minimum), right stick full
        // right and pulled back.
        sticks: [0, 0, 0xFFFF, 0xFFFF],
        triggers: [1023, 0],
        ..XboxReport::NEUTRAL
    };
    let state = pad.decode(1, &report.bytes()).unwrap().unwrap();
    assert_eq!(
        (state.left_x, state.left_y, state.right_x, state.right_y),
        (-1.0, 1.0, 1.0, -1.0)
    );
    assert_eq!((state.left_trigger, state.right_trigger), (1.0, 0.0));

    let half_right_trigger = XboxReport {
        triggers: [0, 512],
        ..XboxReport::NEUTRAL
    };
    let state = pad.decode(1, &half_right_trigger.bytes()).unwrap().unwrap();
    assert_near(state.right_trigger, 512.0 / 1023.0);
}

#[test]
fn xbox_ble_hat_reads_eight_directions_and_its_null_state_as_centred() {
    let mut pad = layout(XBOX_BLE, None);
    let (up, right, down, left) = (true, true, true, true);
    let none = Dpad::default();
    let directions = [
        (0, none),
        (1, Dpad { up, ..none }),
        (2, Dpad { up, right, ..none }),
        (3, Dpad { right, ..none }),
        (
            4,
            Dpad {
                down,
                right,
                ..none
            },
        ),
        (5, Dpad { down, ..none }),
        (6, Dpad { down, left, ..none }),
        (7, Dpad { left, ..none }),
        (8, Dpad { up, left, ..none }),
        (15, none),
    ];
    for (hat, dpad) in directions {
        let report = XboxReport {
            hat,
            ..XboxReport::NEUTRAL
        };
        let state = pad.decode(1, &report.bytes()).unwrap().unwrap();
        assert_eq!(state.dpad, dpad, "hat {hat}");
    }
}

// ---- Xbox One S 4.8 (BR/EDR) --------------------------------------------------------

#[test]
fn xbox_one_s_bredr_reads_view_from_ac_back_and_home_from_report_2() {
    let mut pad = layout(XBOX_ONE_S_BREDR, Some(XBOX_ONE_S_FW4));
    let view = XboxReport {
        consumer: true,
        ..XboxReport::NEUTRAL
    };
    assert_eq!(
        pad.decode(1, &view.bytes()),
        Ok(Some(pressed(Buttons::VIEW)))
    );
    assert_eq!(
        pad.decode(2, &[0x01]),
        Ok(Some(pressed(Buttons::VIEW.with(Buttons::HOME))))
    );
}

#[test]
fn each_report_updates_only_the_controls_it_carries() {
    let mut pad = layout(XBOX_ONE_S_BREDR, None);
    let right = XboxReport {
        sticks: [0xFFFF, 0x8000, 0x8000, 0x8000],
        ..XboxReport::NEUTRAL
    };
    pad.decode(1, &right.bytes()).unwrap();

    // The Xbox button (report 2) keeps the stick of report 1 …
    let home = pad.decode(2, &[0x01]).unwrap().unwrap();
    assert_eq!((home.left_x, home.buttons), (1.0, Buttons::HOME));
    // … and report 1 does not release it.
    let centred = pad
        .decode(1, &XboxReport::NEUTRAL.bytes())
        .unwrap()
        .unwrap();
    assert_eq!((centred.left_x, centred.buttons), (0.0, Buttons::HOME));
    assert_eq!(pad.decode(2, &[0x00]), Ok(Some(GamepadState::default())));
}

#[test]
fn button_carried_by_two_reports_is_held_while_either_says_so() {
    let mut pad = layout(XBOX_ONE_S_BREDR, None);
    // Button 13 of report 1 and AC Home of report 2 are both the Xbox button.
    let button_13 = XboxReport {
        buttons: 1 << 12,
        ..XboxReport::NEUTRAL
    };
    pad.decode(1, &button_13.bytes()).unwrap();
    let state = pad.decode(2, &[0x00]).unwrap().unwrap();
    assert_eq!(state.buttons, Buttons::HOME);
    let state = pad
        .decode(1, &XboxReport::NEUTRAL.bytes())
        .unwrap()
        .unwrap();
    assert_eq!(state.buttons, Buttons::NONE);
}

#[test]
fn xbox_one_s_bredr_keeps_the_android_order_of_its_15_button_map() {
    // 02FD also sends the Windows map; the table's Windows order must not apply here.
    let mut pad = layout(XBOX_ONE_S_BREDR, Some(XBOX_ONE_S_FW4));
    let button_4 = XboxReport {
        buttons: 1 << 3,
        ..XboxReport::NEUTRAL
    };
    let state = pad.decode(1, &button_4.bytes()).unwrap().unwrap();
    assert_eq!(state.buttons, Buttons::X);
}

#[test]
fn battery_report_carries_no_gamepad_state() {
    let mut pad = layout(XBOX_ONE_S_BREDR, None);
    assert_eq!(pad.input_report_ids().collect::<Vec<_>>(), [1, 2, 4]);
    assert_eq!(pad.decode(4, &[0x64]), Ok(None));
}

// ---- 8BitDo / Xbox One S "Windows" map ----------------------------------------------

/// Report 1 of the Windows map: X, Y, Rx, Ry, Z, Rz as u16, hat, 10 buttons.
fn windows_report(axes: [u16; 6], hat: u8, buttons: u16) -> Vec<u8> {
    let mut bytes: Vec<u8> = axes.iter().flat_map(|axis| axis.to_le_bytes()).collect();
    bytes.push(hat);
    bytes.extend(buttons.to_le_bytes());
    bytes
}

const WINDOWS_NEUTRAL_AXES: [u16; 6] = [0x8000, 0x8000, 0x8000, 0x8000, 0, 0];

#[test]
fn windows_map_reads_rx_ry_as_right_stick_and_z_rz_as_triggers() {
    let mut pad = layout(EIGHTBITDO_WINDOWS, Some(XBOX_ONE_S_FW3));
    let report = windows_report([0x8000, 0x8000, 0xFFFF, 0, 1023, 0], 0, 0);
    let state = pad.decode(1, &report).unwrap().unwrap();
    assert_eq!(
        (
            state.right_x,
            state.right_y,
            state.left_trigger,
            state.right_trigger
        ),
        (1.0, 1.0, 1.0, 0.0)
    );
    assert_eq!((state.left_x, state.left_y), (0.0, 0.0));
}

#[test]
fn windows_map_names_buttons_in_xbox_order_for_the_pads_of_the_table() {
    let expected = [
        Buttons::A,
        Buttons::B,
        Buttons::X,
        Buttons::Y,
        Buttons::LEFT_BUMPER,
        Buttons::RIGHT_BUMPER,
        Buttons::VIEW,
        Buttons::MENU,
        Buttons::LEFT_STICK,
        Buttons::RIGHT_STICK,
    ];
    for ids in [XBOX_ONE_S_FW3, XBOX_ONE_S_FW4] {
        let mut pad = layout(EIGHTBITDO_WINDOWS, Some(ids));
        for (bit, button) in expected.into_iter().enumerate() {
            let report = windows_report(WINDOWS_NEUTRAL_AXES, 0, 1 << bit);
            let state = pad.decode(1, &report).unwrap().unwrap();
            assert_eq!(state, pressed(button), "{ids:?} bit {bit}");
        }
    }
}

#[test]
fn windows_map_of_an_unknown_pad_falls_back_to_the_android_order() {
    let mut pad = layout(EIGHTBITDO_WINDOWS, Some(VidPid::new(0x2DC8, 0x6001)));
    let button_4 = windows_report(WINDOWS_NEUTRAL_AXES, 0, 1 << 3);
    assert_eq!(pad.decode(1, &button_4), Ok(Some(pressed(Buttons::X))));
}

#[test]
fn windows_map_reads_home_from_system_main_menu_in_report_2() {
    let mut pad = layout(EIGHTBITDO_WINDOWS, Some(XBOX_ONE_S_FW3));
    assert_eq!(pad.decode(2, &[0x01]), Ok(Some(pressed(Buttons::HOME))));
    assert_eq!(pad.decode(4, &[0xFF]), Ok(None));
}

// ---- Stadia ----------------------------------------------------------------------

/// The input report of Stadia's map (report 3, 10 bytes) as SDL's and BlueRetro's
/// Stadia drivers read it: hat 0 … 7 with 8 centred, 15 buttons listed one usage each, sticks
/// as u8 from 1 with centre 0x80, triggers as u8, a consumer byte (left constant here).
/// The button usages are listed in bit order: bit 0 is Capture (18), bit 14 A (1).
const STADIA_MAP: &[u8] = &[
    0x05, 0x01, 0x09, 0x05, 0xA1, 0x01, // Generic Desktop, Game Pad, Application
    0x85, 0x03, // Report ID 3
    0x75, 0x04, 0x95, 0x01, 0x25, 0x07, // 1 × 4 bits, logical 0 … 7
    0x09, 0x39, 0x81, 0x42, // Hat switch: Input (Data, Var, Null state)
    0x75, 0x01, 0x95, 0x04, 0x81, 0x01, // 4 bits padding
    0x05, 0x09, 0x25, 0x01, 0x95, 0x0F, // Buttons: 15 × 1 bit, logical 0 … 1
    0x09, 0x12, 0x09, 0x11, 0x09, 0x14, 0x09, 0x13, 0x09, 0x0D, 0x09, 0x0C, 0x09, 0x0B, 0x09, 0x0F,
    0x09, 0x0E, 0x09, 0x08, 0x09, 0x07, 0x09, 0x05, 0x09, 0x04, 0x09, 0x02, 0x09, 0x01, 0x81,
    0x02, //
    0x95, 0x01, 0x81, 0x01, // 1 bit padding
    0x05, 0x01, 0x15, 0x01, 0x26, 0xFF, 0x00, // Generic Desktop, logical 1 … 255
    0x75, 0x08, 0x95, 0x04, 0x09, 0x30, 0x09, 0x31, 0x09, 0x32, 0x09, 0x35, // X Y Z Rz
    0x81, 0x02, //
    0x05, 0x02, 0x15, 0x00, 0x95, 0x02, 0x09, 0xC5, 0x09, 0xC4, // Brake, Accelerator
    0x81, 0x02, //
    0x95, 0x01, 0x81, 0x01, // the consumer byte
    0xC0,
];

const STADIA_NEUTRAL: [u8; 10] = [0x08, 0x00, 0x00, 0x80, 0x80, 0x80, 0x80, 0x00, 0x00, 0x00];

#[test]
fn stadia_report_is_10_bytes_and_rests_centred() {
    let mut pad = GamepadLayout::parse(STADIA_MAP, Some(STADIA)).unwrap();
    assert_eq!(pad.report_map().input_report_len(3), Some(10));
    assert_eq!(
        pad.decode(3, &STADIA_NEUTRAL),
        Ok(Some(GamepadState::default()))
    );
}

#[test]
fn stadia_hat_counts_from_zero() {
    let mut pad = GamepadLayout::parse(STADIA_MAP, Some(STADIA)).unwrap();
    let mut report = STADIA_NEUTRAL;
    report[0] = 0;
    let state = pad.decode(3, &report).unwrap().unwrap();
    let up = Dpad {
        up: true,
        ..Dpad::default()
    };
    assert_eq!(state.dpad, up);
}

#[test]
fn stadia_sticks_start_at_one_and_triggers_use_brake_and_accelerator() {
    let mut pad = GamepadLayout::parse(STADIA_MAP, Some(STADIA)).unwrap();
    let report = [0x08, 0x00, 0x00, 0x01, 0x01, 0xFF, 0xFF, 0xFF, 0x00, 0x00];
    let state = pad.decode(3, &report).unwrap().unwrap();
    assert_eq!(
        (state.left_x, state.left_y, state.right_x, state.right_y),
        (-1.0, 1.0, 1.0, -1.0)
    );
    assert_eq!((state.left_trigger, state.right_trigger), (1.0, 0.0));
}

#[test]
fn stadia_capture_is_share_only_with_stadia_ids() {
    // Capture (bit 0) and A (bit 14).
    let mut report = STADIA_NEUTRAL;
    report[1] = 0x01;
    report[2] = 0x40;
    let mut stadia = GamepadLayout::parse(STADIA_MAP, Some(STADIA)).unwrap();
    assert_eq!(
        stadia.decode(3, &report),
        Ok(Some(pressed(Buttons::SHARE.with(Buttons::A))))
    );
    let mut generic = GamepadLayout::parse(STADIA_MAP, None).unwrap();
    assert_eq!(generic.decode(3, &report), Ok(Some(pressed(Buttons::A))));
}

// ---- Layout choice and normalisation ------------------------------------------------

/// X and Y as signed 16-bit, −32767 … 32767: values are `fraction × 32767`.
const SIGNED_STICK: &[u8] = &[
    0x09, 0x30, 0x09, 0x31, 0x16, 0x01, 0x80, 0x26, 0xFF, 0x7F, 0x75, 0x10, 0x95, 0x02, 0x81, 0x02,
];

fn left_stick(pad: &mut GamepadLayout, x: f32, y: f32) -> (f32, f32) {
    let raw = |fraction: f32| ((fraction * 32767.0).round() as i16).to_le_bytes();
    let report = [raw(x), raw(y)].concat();
    let state = pad.decode(0, &report).unwrap().unwrap();
    (state.left_x, state.left_y)
}

#[test]
fn stick_within_the_dead_zone_reads_zero() {
    let mut pad = GamepadLayout::parse(&gamepad_map(SIGNED_STICK), None).unwrap();
    for x in [0.0, 0.05, -0.05, 0.099, -0.099] {
        assert_eq!(left_stick(&mut pad, x, 0.0).0, 0.0, "{x}");
    }
}

#[test]
fn dead_zone_rescales_so_the_stick_rises_continuously_to_full_scale() {
    let mut pad = GamepadLayout::parse(&gamepad_map(SIGNED_STICK), None).unwrap();
    let (just_outside, _) = left_stick(&mut pad, 0.101, 0.0);
    assert!(just_outside > 0.0 && just_outside < 0.002, "{just_outside}");
    assert_near(left_stick(&mut pad, 0.55, 0.0).0, 0.5);
    assert_near(left_stick(&mut pad, -0.55, 0.0).0, -0.5);
    assert_eq!(left_stick(&mut pad, 1.0, 0.0).0, 1.0);
    assert_eq!(left_stick(&mut pad, -1.0, 0.0).0, -1.0);
}

#[test]
fn y_axis_reads_forward_as_positive() {
    let mut pad = GamepadLayout::parse(&gamepad_map(SIGNED_STICK), None).unwrap();
    // HID Y is negative when pushed away from the player.
    assert_eq!(left_stick(&mut pad, 0.0, -1.0).1, 1.0);
    assert_near(left_stick(&mut pad, 0.0, 0.55).1, -0.5);
}

#[test]
fn signed_fields_are_sign_extended() {
    let items = [
        0x09, 0x30, 0x15, 0x81, 0x25, 0x7F, 0x75, 0x08, 0x95, 0x01, 0x81, 0x02,
    ];
    let mut pad = GamepadLayout::parse(&gamepad_map(&items), None).unwrap();
    assert_eq!(pad.decode(0, &[0x81]).unwrap().unwrap().left_x, -1.0);
    assert_eq!(pad.decode(0, &[0x7F]).unwrap().unwrap().left_x, 1.0);
    assert_eq!(pad.decode(0, &[0x00]).unwrap().unwrap().left_x, 0.0);
}

#[test]
fn trigger_beyond_its_logical_maximum_is_clamped() {
    // Simulation Accelerator, 0 … 1000 in 16 bits.
    let items = [
        0x05, 0x02, 0x09, 0xC4, 0x15, 0x00, 0x26, 0xE8, 0x03, 0x75, 0x10, 0x95, 0x01, 0x81, 0x02,
    ];
    let mut pad = GamepadLayout::parse(&gamepad_map(&items), None).unwrap();
    let trigger = |pad: &mut GamepadLayout, raw: u16| {
        pad.decode(0, &raw.to_le_bytes())
            .unwrap()
            .unwrap()
            .right_trigger
    };
    assert_eq!(trigger(&mut pad, 500), 0.5);
    assert_eq!(trigger(&mut pad, 1000), 1.0);
    assert_eq!(trigger(&mut pad, 0xFFFF), 1.0);
}

#[test]
fn z_rz_are_the_right_stick_on_a_map_without_rx_ry() {
    // X, Y, Z, Rz as u8 and nothing else: the common generic pad.
    let items = [
        0x09, 0x30, 0x09, 0x31, 0x09, 0x32, 0x09, 0x35, 0x15, 0x00, 0x26, 0xFF, 0x00, 0x75, 0x08,
        0x95, 0x04, 0x81, 0x02,
    ];
    let mut pad = GamepadLayout::parse(&gamepad_map(&items), None).unwrap();
    let state = pad.decode(0, &[0x80, 0x80, 0xFF, 0x00]).unwrap().unwrap();
    assert_near(state.right_x, 1.0);
    assert_eq!(state.right_y, 1.0);
    assert_eq!((state.left_trigger, state.right_trigger), (0.0, 0.0));
}

#[test]
fn array_fields_name_the_pressed_buttons_by_index() {
    // Two slots, each naming one of buttons 1 … 15 (logical 1 … 15), 0 for none.
    let items = [
        0x05, 0x09, 0x19, 0x01, 0x29, 0x0F, 0x15, 0x01, 0x25, 0x0F, 0x75, 0x08, 0x95, 0x02, 0x81,
        0x00,
    ];
    let mut pad = GamepadLayout::parse(&gamepad_map(&items), None).unwrap();
    assert_eq!(
        pad.decode(0, &[1, 8]),
        Ok(Some(pressed(Buttons::A.with(Buttons::RIGHT_BUMPER))))
    );
    assert_eq!(pad.decode(0, &[0, 12]), Ok(Some(pressed(Buttons::MENU))));
    assert_eq!(pad.decode(0, &[0, 0]), Ok(Some(GamepadState::default())));
}

// ---- Reports that do not fit ------------------------------------------------------

#[test]
fn short_report_is_rejected_and_a_longer_one_accepted() {
    let mut pad = layout(XBOX_BLE, None);
    let neutral = XboxReport::NEUTRAL.bytes();
    assert_eq!(
        pad.decode(1, &neutral[..15]),
        Err(ReportError::TooShort {
            expected: 16,
            received: 15
        })
    );
    assert_eq!(
        pad.decode(1, &[]),
        Err(ReportError::TooShort {
            expected: 16,
            received: 0
        })
    );
    let longer = [neutral.as_slice(), &[0xAA, 0xBB]].concat();
    assert_eq!(pad.decode(1, &longer), Ok(Some(GamepadState::default())));
}

#[test]
fn rejected_report_leaves_the_state_unchanged() {
    let mut pad = layout(XBOX_ONE_S_BREDR, None);
    pad.decode(2, &[0x01]).unwrap();
    assert!(pad.decode(2, &[]).is_err());
    let state = pad
        .decode(1, &XboxReport::NEUTRAL.bytes())
        .unwrap()
        .unwrap();
    assert_eq!(state.buttons, Buttons::HOME);
}

#[test]
fn report_id_not_in_the_map_decodes_to_none() {
    let mut pad = layout(XBOX_BLE, None);
    assert_eq!(pad.decode(3, &[0; 8]), Ok(None));
    assert_eq!(pad.decode(0, &[0; 16]), Ok(None));
}

#[test]
fn map_without_gamepad_controls_is_not_a_gamepad() {
    // Report 4: battery strength only.
    let battery = [
        0x05, 0x06, 0x09, 0x20, 0x85, 0x04, 0x15, 0x00, 0x26, 0xFF, 0x00, 0x75, 0x08, 0x95, 0x01,
        0x81, 0x02,
    ];
    assert!(ReportMap::parse(&battery).is_ok());
    assert_eq!(
        GamepadLayout::parse(&battery, None).err(),
        Some(DescriptorError::NotAGamepad)
    );
    assert_eq!(
        GamepadLayout::parse(&[], None).err(),
        Some(DescriptorError::NotAGamepad)
    );
}

// ---- Properties -------------------------------------------------------------------

#[track_caller]
fn assert_in_range(state: &GamepadState) {
    for stick in [state.left_x, state.left_y, state.right_x, state.right_y] {
        assert!((-1.0..=1.0).contains(&stick), "stick {stick}");
    }
    for trigger in [state.left_trigger, state.right_trigger] {
        assert!((0.0..=1.0).contains(&trigger), "trigger {trigger}");
    }
}

/// Parses `map` and decodes `payload` as each of its input reports.
fn parse_and_decode_all(map: &[u8], ids: Option<VidPid>, payload: &[u8]) {
    if let Ok(mut pad) = GamepadLayout::parse(map, ids) {
        let report_ids: Vec<u8> = pad.input_report_ids().collect();
        for id in report_ids {
            if let Ok(Some(state)) = pad.decode(id, payload) {
                assert_in_range(&state);
            }
        }
    }
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic_the_decoder(
        map in proptest::collection::vec(any::<u8>(), 0..400),
        payload in proptest::collection::vec(any::<u8>(), 0..80),
        ids in proptest::option::of((any::<u16>(), any::<u16>())),
    ) {
        parse_and_decode_all(&map, ids.map(|(vid, pid)| VidPid::new(vid, pid)), &payload);
    }

    #[test]
    fn damaged_real_maps_never_panic_the_decoder(
        file in prop::sample::select(vec![XBOX_BLE, XBOX_ONE_S_BREDR, EIGHTBITDO_WINDOWS]),
        damage in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        ids in prop::sample::select(vec![None, Some(XBOX_ONE_S_FW3), Some(XBOX_ONE_S_FW4)]),
        payload in proptest::collection::vec(any::<u8>(), 0..24),
    ) {
        let mut map = hex(file);
        for (at, byte) in damage {
            let at = at.index(map.len());
            map[at] = byte;
        }
        map.truncate(cut.index(map.len() + 1));
        parse_and_decode_all(&map, ids, &payload);
    }

    #[test]
    fn any_xbox_report_decodes_within_range(
        payload in proptest::collection::vec(any::<u8>(), 16..20),
    ) {
        let mut pad = layout(XBOX_BLE, None);
        let state = pad.decode(1, &payload).unwrap().unwrap();
        assert_in_range(&state);
    }
}
