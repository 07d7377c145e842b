//! From a parsed Report Map to [`GamepadState`]: which usage is which stick, trigger,
//! D-pad or button, and how raw values become the normalised ranges.

use heapless::Vec;

use super::descriptor::{DescriptorError, Field, MAX_INPUT_REPORTS, ReportMap, Usage, Usages};
use crate::gamepad::{Buttons, Dpad, GamepadState};

#[cfg(test)]
mod tests;

/// Stick deflection, as a fraction of full travel, that still reads as centred. Sticks
/// rest a little off centre (the Xbox samples rest 0.8 % off), and a robot must not
/// creep; past it the output is rescaled, so it rises continuously from 0.
pub const STICK_DEAD_ZONE: f32 = 0.10;

/// USB vendor and product ID, as the Device Information service's PnP ID (0x2A50) gives
/// them. They pick a pad's button order where the generic one is wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VidPid {
    pub vendor_id: u16,
    pub product_id: u16,
}

impl VidPid {
    pub const fn new(vendor_id: u16, product_id: u16) -> VidPid {
        VidPid {
            vendor_id,
            product_id,
        }
    }
}

/// Why an input report was not decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReportError {
    /// The payload is shorter than the report the map declares.
    TooShort { expected: usize, received: usize },
}

/// Where a pad puts its right stick and triggers: the two conventions in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum AxisLayout {
    /// Right stick on Z/Rz, triggers on Simulation Brake/Accelerator: Android's
    /// mapping, which the Xbox BLE firmware, the Xbox One S 4.8 firmware and Stadia use.
    /// Also what a map without Rx/Ry gets: Z/Rz are then the right stick.
    Android,
    /// Right stick on Rx/Ry, triggers on Z/Rz: the Xbox One S "Windows" map and the
    /// third-party pads that copy it.
    Windows,
}

impl AxisLayout {
    fn of(map: &ReportMap) -> AxisLayout {
        let (mut has_rx_ry, mut has_sim_triggers) = (false, false);
        for usage in variable_usages(map) {
            has_rx_ry |= usage == usage::RX || usage == usage::RY;
            has_sim_triggers |= usage == usage::BRAKE || usage == usage::ACCELERATOR;
        }
        if has_rx_ry && !has_sim_triggers {
            AxisLayout::Windows
        } else {
            AxisLayout::Android
        }
    }
}

/// The usages of the variable input fields, element by element.
fn variable_usages(map: &ReportMap) -> impl Iterator<Item = Usage> + '_ {
    map.fields()
        .filter(|field| !field.flags.is_constant() && field.flags.is_variable())
        .flat_map(move |field| {
            let usages = map.usages(field);
            (0..field.count).filter_map(move |element| usages.of_element(element))
        })
}

/// Button-page usage IDs and their names.
type ButtonOrder = &'static [(u16, Buttons)];

/// Android's gamepad order (Linux BTN_A … BTN_THUMBR), which the Xbox BLE firmware
/// follows: buttons 3, 6, 9 and 10 (C, Z, L2, R2) are absent on these pads.
const ANDROID_BUTTONS: ButtonOrder = &[
    (1, Buttons::A),
    (2, Buttons::B),
    (4, Buttons::X),
    (5, Buttons::Y),
    (7, Buttons::LEFT_BUMPER),
    (8, Buttons::RIGHT_BUMPER),
    (11, Buttons::VIEW),
    (12, Buttons::MENU),
    (13, Buttons::HOME),
    (14, Buttons::LEFT_STICK),
    (15, Buttons::RIGHT_STICK),
];

/// The Xbox One S "Windows" map: ten buttons in Xbox order, Home in its own report.
const WINDOWS_XBOX_BUTTONS: ButtonOrder = &[
    (1, Buttons::A),
    (2, Buttons::B),
    (3, Buttons::X),
    (4, Buttons::Y),
    (5, Buttons::LEFT_BUMPER),
    (6, Buttons::RIGHT_BUMPER),
    (7, Buttons::VIEW),
    (8, Buttons::MENU),
    (9, Buttons::LEFT_STICK),
    (10, Buttons::RIGHT_STICK),
];

/// Stadia: the Android order, plus Capture as button 18 (0x12, the first bit of its
/// button bytes). Buttons 17 (Assistant), 19 and 20 (digital R2 and L2) have no name.
const STADIA_BUTTONS: ButtonOrder = &[
    (1, Buttons::A),
    (2, Buttons::B),
    (4, Buttons::X),
    (5, Buttons::Y),
    (7, Buttons::LEFT_BUMPER),
    (8, Buttons::RIGHT_BUMPER),
    (11, Buttons::VIEW),
    (12, Buttons::MENU),
    (13, Buttons::HOME),
    (14, Buttons::LEFT_STICK),
    (15, Buttons::RIGHT_STICK),
    (18, Buttons::SHARE),
];

/// Pads whose button order is not the Android one. An entry applies only to the axis
/// layout it was seen with: the Xbox One S (02FD) sends the Windows map to some hosts
/// and an Android-order map with 15 buttons to others, under the same product ID.
const BUTTON_ORDERS: &[(VidPid, AxisLayout, ButtonOrder)] = &[
    // Xbox One S, firmware 3.x, and the 8BitDo, GameSir and GuliKit pads that copy it.
    (
        VidPid::new(0x045E, 0x02E0),
        AxisLayout::Windows,
        WINDOWS_XBOX_BUTTONS,
    ),
    // Xbox One S, firmware 4.8, in Windows mode.
    (
        VidPid::new(0x045E, 0x02FD),
        AxisLayout::Windows,
        WINDOWS_XBOX_BUTTONS,
    ),
    (
        VidPid::new(0x18D1, 0x9400),
        AxisLayout::Android,
        STADIA_BUTTONS,
    ),
];

/// Buttons outside the Button page, named the same on every pad.
const OTHER_BUTTONS: &[(Usage, Buttons)] = &[
    // The Xbox button of the Windows map, in its own report.
    (usage::SYSTEM_MAIN_MENU, Buttons::HOME),
    // The Xbox button of the Xbox One S 4.8 map, in its own report.
    (usage::AC_HOME, Buttons::HOME),
    // View on the Xbox One S 4.8 map.
    (usage::AC_BACK, Buttons::VIEW),
    // Share on the Xbox BLE map.
    (usage::RECORD, Buttons::SHARE),
];

mod usage {
    use super::Usage;

    const GENERIC_DESKTOP: u16 = 0x01;
    const SIMULATION: u16 = 0x02;
    pub const BUTTON_PAGE: u16 = 0x09;
    const CONSUMER: u16 = 0x0C;

    pub const X: Usage = Usage::new(GENERIC_DESKTOP, 0x30);
    pub const Y: Usage = Usage::new(GENERIC_DESKTOP, 0x31);
    pub const Z: Usage = Usage::new(GENERIC_DESKTOP, 0x32);
    pub const RX: Usage = Usage::new(GENERIC_DESKTOP, 0x33);
    pub const RY: Usage = Usage::new(GENERIC_DESKTOP, 0x34);
    pub const RZ: Usage = Usage::new(GENERIC_DESKTOP, 0x35);
    pub const HAT_SWITCH: Usage = Usage::new(GENERIC_DESKTOP, 0x39);
    pub const SYSTEM_MAIN_MENU: Usage = Usage::new(GENERIC_DESKTOP, 0x85);
    pub const ACCELERATOR: Usage = Usage::new(SIMULATION, 0xC4);
    pub const BRAKE: Usage = Usage::new(SIMULATION, 0xC5);
    pub const RECORD: Usage = Usage::new(CONSUMER, 0xB2);
    pub const AC_HOME: Usage = Usage::new(CONSUMER, 0x223);
    pub const AC_BACK: Usage = Usage::new(CONSUMER, 0x224);
}

/// What a usage controls in [`GamepadState`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Control {
    Axis(Axis),
    Hat,
    Button(Buttons),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Axis {
    LeftX,
    LeftY,
    RightX,
    RightY,
    LeftTrigger,
    RightTrigger,
}

/// One pad's Report Map read as a gamepad, and the state its reports last described.
///
/// Parse it once per connection from the Report Map (0x2A4B), then hand every input
/// notification to [`decode`](Self::decode). Some maps spread the pad over several
/// reports (the Xbox One S sends its Xbox button in report 2), so each report updates
/// only the controls it carries and the rest keep the values of earlier reports. A
/// button that two reports carry is held while either says so: the One S 4.8 map
/// declares the Xbox button as button 13 of report 1 and as AC Home in report 2.
#[derive(Debug, Clone)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GamepadLayout {
    map: ReportMap,
    axes: AxisLayout,
    buttons: ButtonOrder,
    gamepad_reports: Vec<GamepadReport, MAX_INPUT_REPORTS>,
    state: GamepadState,
}

/// An input report with gamepad controls, and the buttons it last said were pressed.
#[derive(Debug, Clone, Copy)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct GamepadReport {
    id: u8,
    pressed: Buttons,
}

impl GamepadLayout {
    /// Parses `report_map` and maps its usages. `ids` (from the PnP ID) refine the
    /// button order for the pads of the built-in table; `None` uses the generic order.
    pub fn parse(report_map: &[u8], ids: Option<VidPid>) -> Result<GamepadLayout, DescriptorError> {
        let map = ReportMap::parse(report_map)?;
        let axes = AxisLayout::of(&map);
        let buttons = BUTTON_ORDERS
            .iter()
            .find(|(pad, layout, _)| Some(*pad) == ids && *layout == axes)
            .map_or(ANDROID_BUTTONS, |(_, _, order)| order);
        let mut layout = GamepadLayout {
            map,
            axes,
            buttons,
            gamepad_reports: Vec::new(),
            state: GamepadState::default(),
        };
        for report_id in layout.map.input_report_ids() {
            if layout.carries_controls(report_id) {
                let report = GamepadReport {
                    id: report_id,
                    pressed: Buttons::NONE,
                };
                layout
                    .gamepad_reports
                    .push(report)
                    .map_err(|_| DescriptorError::TooManyReports)?;
            }
        }
        if layout.gamepad_reports.is_empty() {
            return Err(DescriptorError::NotAGamepad);
        }
        Ok(layout)
    }

    /// Every input report of the map, gamepad or not (a battery report, say): the ones
    /// to subscribe to.
    pub fn input_report_ids(&self) -> impl Iterator<Item = u8> + '_ {
        self.map.input_report_ids()
    }

    pub fn report_map(&self) -> &ReportMap {
        &self.map
    }

    /// Decodes one input report: `payload` is the HOGP notification value, which has
    /// no report ID byte (the ID comes from the Report Reference descriptor). Returns
    /// the whole pad's state after this report, or `None` for a report without gamepad
    /// controls. Bytes past the report's length are ignored.
    pub fn decode(
        &mut self,
        report_id: u8,
        payload: &[u8],
    ) -> Result<Option<GamepadState>, ReportError> {
        let Some(index) = self
            .gamepad_reports
            .iter()
            .position(|report| report.id == report_id)
        else {
            return Ok(None);
        };
        let expected = self.map.input_report_len(report_id).unwrap_or(0);
        let too_short = ReportError::TooShort {
            expected,
            received: payload.len(),
        };
        if payload.len() < expected {
            return Err(too_short);
        }
        let mut state = self.state;
        let mut pressed = Buttons::NONE;
        for field in self.map.fields_of(report_id) {
            if field.flags.is_constant() {
                continue;
            }
            let usages = self.map.usages(field);
            let decoded = if field.flags.is_variable() {
                self.decode_variable(field, usages, payload, &mut state, &mut pressed)
            } else {
                self.decode_array(field, usages, payload, &mut pressed)
            };
            decoded.ok_or(too_short)?;
        }
        if let Some(report) = self.gamepad_reports.get_mut(index) {
            report.pressed = pressed;
        }
        state.buttons = self
            .gamepad_reports
            .iter()
            .fold(Buttons::NONE, |held, report| held.with(report.pressed));
        self.state = state;
        Ok(Some(state))
    }

    /// Each element is the value of its own usage. `None` if the payload is too short.
    fn decode_variable(
        &self,
        field: &Field,
        usages: Usages<'_>,
        payload: &[u8],
        state: &mut GamepadState,
        pressed: &mut Buttons,
    ) -> Option<()> {
        for element in 0..field.count {
            let Some(control) = usages.of_element(element).and_then(|u| self.control(u)) else {
                continue;
            };
            let value = field.read(payload, element)?;
            match control {
                Control::Axis(axis) => set_axis(state, axis, field, value),
                Control::Hat => state.dpad = hat_direction(field, value),
                Control::Button(button) if value != 0 => *pressed = pressed.with(button),
                Control::Button(_) => {}
            }
        }
        Some(())
    }

    /// Each element names one pressed usage by its index. `None` if the payload is too
    /// short.
    fn decode_array(
        &self,
        field: &Field,
        usages: Usages<'_>,
        payload: &[u8],
        pressed: &mut Buttons,
    ) -> Option<()> {
        for element in 0..field.count {
            let value = field.read(payload, element)?;
            if !(field.logical_min..=field.logical_max).contains(&value) {
                continue;
            }
            let index = u32::try_from(value - field.logical_min).ok();
            if let Some(Control::Button(button)) = index
                .and_then(|index| usages.get(index))
                .and_then(|usage| self.control(usage))
            {
                *pressed = pressed.with(button);
            }
        }
        Some(())
    }

    /// Whether any input field of `report_id` carries a control we name.
    fn carries_controls(&self, report_id: u8) -> bool {
        self.map
            .fields_of(report_id)
            .filter(|field| !field.flags.is_constant())
            .any(|field| {
                let usages = self.map.usages(field);
                if field.flags.is_variable() {
                    (0..field.count).any(|element| {
                        usages
                            .of_element(element)
                            .and_then(|usage| self.control(usage))
                            .is_some()
                    })
                } else {
                    let on_button_page = self
                        .buttons
                        .iter()
                        .map(|&(number, _)| Usage::new(usage::BUTTON_PAGE, number));
                    on_button_page
                        .chain(OTHER_BUTTONS.iter().map(|&(usage, _)| usage))
                        .any(|usage| usages.contains(usage))
                }
            })
    }

    fn control(&self, usage: Usage) -> Option<Control> {
        use AxisLayout::{Android, Windows};
        let axis = match (usage, self.axes) {
            (usage::X, _) => Axis::LeftX,
            (usage::Y, _) => Axis::LeftY,
            (usage::Z, Android) | (usage::RX, Windows) => Axis::RightX,
            (usage::RZ, Android) | (usage::RY, Windows) => Axis::RightY,
            (usage::BRAKE, Android) | (usage::Z, Windows) => Axis::LeftTrigger,
            (usage::ACCELERATOR, Android) | (usage::RZ, Windows) => Axis::RightTrigger,
            (usage::HAT_SWITCH, _) => return Some(Control::Hat),
            _ => return self.button(usage).map(Control::Button),
        };
        Some(Control::Axis(axis))
    }

    fn button(&self, usage: Usage) -> Option<Buttons> {
        if usage.page() == usage::BUTTON_PAGE {
            self.buttons
                .iter()
                .find(|(number, _)| *number == usage.id())
                .map(|&(_, button)| button)
        } else {
            OTHER_BUTTONS
                .iter()
                .find(|(named, _)| *named == usage)
                .map(|&(_, button)| button)
        }
    }
}

fn set_axis(state: &mut GamepadState, axis: Axis, field: &Field, value: i64) {
    let Some(centred) = centred(field, value) else {
        return;
    };
    // HID Y axes grow downwards (towards the player); forward is +1 here.
    match axis {
        Axis::LeftX => state.left_x = with_dead_zone(centred),
        Axis::LeftY => state.left_y = with_dead_zone(-centred),
        Axis::RightX => state.right_x = with_dead_zone(centred),
        Axis::RightY => state.right_y = with_dead_zone(-centred),
        Axis::LeftTrigger => state.left_trigger = (centred + 1.0) / 2.0,
        Axis::RightTrigger => state.right_trigger = (centred + 1.0) / 2.0,
    }
}

/// `value` on −1 (logical minimum) … 1 (logical maximum), the midpoint at 0, clamped;
/// `None` for a field without a range to scale by.
fn centred(field: &Field, value: i64) -> Option<f32> {
    let span = field.logical_max - field.logical_min;
    if span <= 0 {
        return None;
    }
    // (2v − min − max) / (max − min), exact in i64: the values have at most 32 bits.
    let offset = 2 * value - field.logical_min - field.logical_max;
    Some((offset as f32 / span as f32).clamp(-1.0, 1.0))
}

/// Zero within [`STICK_DEAD_ZONE`] of centre, then rescaled to reach ±1 at full travel.
pub(super) fn with_dead_zone(x: f32) -> f32 {
    let scale = 1.0 - STICK_DEAD_ZONE;
    if x > STICK_DEAD_ZONE {
        (x - STICK_DEAD_ZONE) / scale
    } else if x < -STICK_DEAD_ZONE {
        (x + STICK_DEAD_ZONE) / scale
    } else {
        0.0
    }
}

/// A hat's eight positions clockwise from up, counted from its logical minimum (0 on
/// Stadia, 1 on Xbox). Anything outside the range is the null state: centred. Hats
/// with other than eight positions are not supported and read as centred.
fn hat_direction(field: &Field, value: i64) -> Dpad {
    if field.logical_max - field.logical_min != 7 {
        return Dpad::default();
    }
    hat_position(value - field.logical_min)
}

/// A hat's position 0 … 7 clockwise from up; anything else is centred (PlayStation
/// pads send 8 for a released D-pad).
pub(super) fn hat_position(position: i64) -> Dpad {
    let centred = Dpad::default();
    let (up, right, down, left) = (true, true, true, true);
    match position {
        0 => Dpad { up, ..centred },
        1 => Dpad {
            up,
            right,
            ..centred
        },
        2 => Dpad { right, ..centred },
        3 => Dpad {
            down,
            right,
            ..centred
        },
        4 => Dpad { down, ..centred },
        5 => Dpad {
            down,
            left,
            ..centred
        },
        6 => Dpad { left, ..centred },
        7 => Dpad {
            up,
            left,
            ..centred
        },
        _ => centred,
    }
}
