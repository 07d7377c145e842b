//! PlayStation pads over Bluetooth Classic: the DualShock 4 and the DualSense.
//!
//! Their Bluetooth reports are not described by their HID descriptor (it declares
//! opaque vendor bytes), so they are decoded here at fixed offsets, beside the
//! descriptor-driven decoder the BLE pads use. Both pads start in a short mode: they
//! stream report 0x01 (sticks, buttons, triggers) until the host reads feature report
//! 0x05, and from then on the full report (0x11 on the DualShock 4, 0x31 on the
//! DualSense), which carries the battery and ends in a CRC-32.
//!
//! Every slice here is an L2CAP payload as it travels on the HID interrupt channel:
//! byte 0 is the HID transaction header (0xA1 input, 0xA2 output, 0xA3 a feature
//! answer on the control channel), byte 1 the report ID. The CRC-32 (zlib's) covers
//! that header byte and the report up to the CRC, which sits in the last four bytes,
//! little endian. A pad that sends anything else is refused with a [`PadReportError`]
//! and counted ([`PadReportCounters`]); no input reaches the remote from it.
//!
//! | report (with header) | sticks LX LY RX RY | buttons | L2 R2 | battery | CRC |
//! |---|---|---|---|---|---|
//! | 0x01, 11 bytes | 2-5 | 6-8 | 9, 10 | – | – |
//! | DualShock 4 0x11, 79 bytes | 4-7 | 8-10 | 11, 12 | 33 | 75-78 |
//! | DualSense 0x31, 79 bytes | 3-6 | 10-12 | 7, 8 | 55 | 75-78 |
//!
//! The layouts are those of Linux's `hid-playstation` driver, which names every byte.

use crc::{CRC_32_ISO_HDLC, Crc};

use super::VidPid;
use super::layout::{hat_position, with_dead_zone};
use crate::gamepad::{Buttons, Dpad, GamepadState};

#[cfg(test)]
mod tests;

/// Sony's USB vendor ID, which the pads also give in their Device ID record.
pub const SONY_VENDOR_ID: u16 = 0x054C;

/// HID transaction header of an input report on the interrupt channel (DATA | Input).
pub const HEADER_INPUT: u8 = 0xA1;
/// HID transaction header of an output report (DATA | Output): the CRC seed of outputs.
pub const HEADER_OUTPUT: u8 = 0xA2;
/// HID transaction header of a feature report answering GET_REPORT (DATA | Feature).
pub const HEADER_FEATURE: u8 = 0xA3;

/// The short report both pads send before feature report 0x05 was read.
pub const SHORT_REPORT_ID: u8 = 0x01;
/// The feature report whose reading switches the pads to their full report (the
/// calibration data; we only need its side effect).
pub const FULL_MODE_FEATURE_ID: u8 = 0x05;
/// The feature report 0x05 answer with its header: header, ID, 36 bytes, CRC.
pub const FULL_MODE_FEATURE_LEN: usize = 42;
/// GET_REPORT on the control channel for feature report 0x05: transaction GET_REPORT
/// (0x40) with report type Feature (0x03), then the report ID.
pub const FULL_MODE_FEATURE_REQUEST: [u8; 2] = [0x43, FULL_MODE_FEATURE_ID];

/// Length of the short report with its header.
pub const SHORT_REPORT_LEN: usize = 11;
/// Length of either pad's full input report with its header.
pub const FULL_REPORT_LEN: usize = 79;
/// Length of either pad's output report with its header.
pub const OUTPUT_REPORT_LEN: usize = 79;

/// The DualShock 4's input interval in full mode, asked for in every output report
/// (ms; the low six bits of its byte 2). Four is what USB and SDL use: 250 reports a
/// second, so a silent stream is noticed within a few milliseconds.
pub const DUALSHOCK4_POLL_INTERVAL_MS: u8 = 4;

const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
const CRC_LEN: usize = 4;

/// Which pad: they differ in report IDs and offsets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PadKind {
    DualShock4,
    DualSense,
}

impl PadKind {
    /// The kind from the Device ID record's vendor and product ID; `None` for any
    /// other pad (these decoders do not fit it).
    pub fn from_ids(ids: VidPid) -> Option<PadKind> {
        match (ids.vendor_id, ids.product_id) {
            // DualShock 4, first and second model.
            (SONY_VENDOR_ID, 0x05C4 | 0x09CC) => Some(PadKind::DualShock4),
            // DualSense and DualSense Edge.
            (SONY_VENDOR_ID, 0x0CE6 | 0x0DF2) => Some(PadKind::DualSense),
            _ => None,
        }
    }

    /// The kind whose full report this is (`payload` with its 0xA1 header): how the
    /// host tells the pads apart without asking for their Device ID, once they send
    /// full reports. `None` for anything else, the short report included.
    pub fn from_full_report(payload: &[u8]) -> Option<PadKind> {
        match payload {
            [HEADER_INPUT, 0x11, ..] => Some(PadKind::DualShock4),
            [HEADER_INPUT, 0x31, ..] => Some(PadKind::DualSense),
            _ => None,
        }
    }

    /// The ID of this pad's full input and output report.
    pub const fn full_report_id(self) -> u8 {
        match self {
            PadKind::DualShock4 => 0x11,
            PadKind::DualSense => 0x31,
        }
    }
}

/// Why a payload was not decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PadReportError {
    /// Shorter than a header and a report ID.
    Truncated { received: usize },
    /// The transaction header is not the one expected (0xA1 for input reports).
    WrongHeader { header: u8 },
    /// A report ID this pad kind does not send, or not the one asked for.
    UnknownReportId { report_id: u8 },
    /// A known report of the wrong length.
    WrongLength {
        report_id: u8,
        expected: usize,
        received: usize,
    },
    /// The CRC-32 in the report is not the one computed over it.
    BadCrc { computed: u32, received: u32 },
}

/// Whether the pad is still in its short mode (read feature report 0x05 to leave it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReportMode {
    Short,
    Full,
}

/// The pad's charge, as its full report gives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Battery {
    /// 5 … 100 % in steps of ten (the pads report tenths); 0 when `state` is `Fault`.
    pub percent: u8,
    pub state: BatteryState,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BatteryState {
    Discharging,
    Charging,
    Full,
    /// The pad reports a charging error (voltage or temperature) or a state unknown to us.
    Fault,
}

/// One decoded input report.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PadReport {
    pub state: GamepadState,
    pub mode: ReportMode,
    /// Only full reports carry it.
    pub battery: Option<Battery>,
}

/// How many payloads were decoded and how many refused, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PadReportCounters {
    pub full: u32,
    pub short: u32,
    pub truncated: u32,
    pub wrong_header: u32,
    pub unknown_report_id: u32,
    pub wrong_length: u32,
    pub bad_crc: u32,
}

impl PadReportCounters {
    /// Everything refused, whatever the reason.
    pub fn refused(&self) -> u32 {
        self.truncated
            .saturating_add(self.wrong_header)
            .saturating_add(self.unknown_report_id)
            .saturating_add(self.wrong_length)
            .saturating_add(self.bad_crc)
    }

    fn count(&mut self, result: &Result<PadReport, PadReportError>) {
        let counter = match result {
            Ok(PadReport {
                mode: ReportMode::Full,
                ..
            }) => &mut self.full,
            Ok(PadReport {
                mode: ReportMode::Short,
                ..
            }) => &mut self.short,
            Err(PadReportError::Truncated { .. }) => &mut self.truncated,
            Err(PadReportError::WrongHeader { .. }) => &mut self.wrong_header,
            Err(PadReportError::UnknownReportId { .. }) => &mut self.unknown_report_id,
            Err(PadReportError::WrongLength { .. }) => &mut self.wrong_length,
            Err(PadReportError::BadCrc { .. }) => &mut self.bad_crc,
        };
        *counter = counter.saturating_add(1);
    }
}

/// One connected pad's input decoder: [`decode_input`] with the counters kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PadDecoder {
    kind: PadKind,
    counters: PadReportCounters,
}

impl PadDecoder {
    pub const fn new(kind: PadKind) -> PadDecoder {
        PadDecoder {
            kind,
            counters: PadReportCounters {
                full: 0,
                short: 0,
                truncated: 0,
                wrong_header: 0,
                unknown_report_id: 0,
                wrong_length: 0,
                bad_crc: 0,
            },
        }
    }

    pub fn kind(&self) -> PadKind {
        self.kind
    }

    pub fn counters(&self) -> PadReportCounters {
        self.counters
    }

    /// Decodes one interrupt-channel payload and counts the outcome.
    pub fn decode(&mut self, payload: &[u8]) -> Result<PadReport, PadReportError> {
        let result = decode_input(self.kind, payload);
        if let Err(error) = result {
            warn!("PlayStation report refused: {}", error);
        }
        self.counters.count(&result);
        result
    }
}

/// The CRC-32 the pads put in their reports: zlib's CRC-32 over the transaction
/// header byte (`seed`) and then `bytes`.
pub fn crc32(seed: u8, bytes: &[u8]) -> u32 {
    let mut digest = CRC32.digest();
    digest.update(&[seed]);
    digest.update(bytes);
    digest.finalize()
}

/// Decodes an input report (`payload` starts with the 0xA1 header) of a `kind` pad.
pub fn decode_input(kind: PadKind, payload: &[u8]) -> Result<PadReport, PadReportError> {
    let report_id = report_id(HEADER_INPUT, payload)?;
    if report_id == SHORT_REPORT_ID {
        expect_len(report_id, SHORT_REPORT_LEN, payload)?;
        return Ok(PadReport {
            state: state_at(payload, &SHORT_OFFSETS),
            mode: ReportMode::Short,
            battery: None,
        });
    }
    if report_id != kind.full_report_id() {
        return Err(PadReportError::UnknownReportId { report_id });
    }
    expect_len(report_id, FULL_REPORT_LEN, payload)?;
    check_crc(payload)?;
    let (offsets, battery) = match kind {
        PadKind::DualShock4 => (&DUALSHOCK4_OFFSETS, dualshock4_battery(payload[33])),
        PadKind::DualSense => (&DUALSENSE_OFFSETS, dualsense_battery(payload[55])),
    };
    Ok(PadReport {
        state: state_at(payload, offsets),
        mode: ReportMode::Full,
        battery: Some(battery),
    })
}

/// Checks the answer to [`FULL_MODE_FEATURE_REQUEST`] (header 0xA3, report 0x05,
/// length, CRC). The pads answer it in either mode; the calibration data in it is not
/// needed to drive.
pub fn check_full_mode_feature(payload: &[u8]) -> Result<(), PadReportError> {
    let report_id = report_id(HEADER_FEATURE, payload)?;
    if report_id != FULL_MODE_FEATURE_ID {
        return Err(PadReportError::UnknownReportId { report_id });
    }
    expect_len(report_id, FULL_MODE_FEATURE_LEN, payload)?;
    check_crc(payload)
}

fn report_id(header: u8, payload: &[u8]) -> Result<u8, PadReportError> {
    match *payload {
        [received_header, report_id, ..] if received_header == header => Ok(report_id),
        [received_header, _, ..] => Err(PadReportError::WrongHeader {
            header: received_header,
        }),
        _ => Err(PadReportError::Truncated {
            received: payload.len(),
        }),
    }
}

fn expect_len(report_id: u8, expected: usize, payload: &[u8]) -> Result<(), PadReportError> {
    if payload.len() == expected {
        Ok(())
    } else {
        Err(PadReportError::WrongLength {
            report_id,
            expected,
            received: payload.len(),
        })
    }
}

/// The CRC in the last four bytes against the one over the header and the report
/// before it. `payload` is at least a header, an ID and the CRC long.
fn check_crc(payload: &[u8]) -> Result<(), PadReportError> {
    let (covered, tail) = payload.split_at(payload.len() - CRC_LEN);
    let received = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
    let computed = crc32(covered[0], &covered[1..]);
    if computed == received {
        Ok(())
    } else {
        Err(PadReportError::BadCrc { computed, received })
    }
}

/// Where a report keeps its controls (offsets with the header byte).
struct Offsets {
    sticks: usize,
    buttons: usize,
    triggers: usize,
}

const SHORT_OFFSETS: Offsets = Offsets {
    sticks: 2,
    buttons: 6,
    triggers: 9,
};
const DUALSHOCK4_OFFSETS: Offsets = Offsets {
    sticks: 4,
    buttons: 8,
    triggers: 11,
};
const DUALSENSE_OFFSETS: Offsets = Offsets {
    sticks: 3,
    buttons: 10,
    triggers: 7,
};

/// Buttons by (byte after the hat byte's start, mask). Byte 0's low nibble is the
/// hat; L2 and R2 also have digital bits, unused: the remote reads the analog travel.
const BUTTON_BITS: [(usize, u8, Buttons); 11] = [
    (0, 0x10, Buttons::X),            // Square
    (0, 0x20, Buttons::A),            // Cross
    (0, 0x40, Buttons::B),            // Circle
    (0, 0x80, Buttons::Y),            // Triangle
    (1, 0x01, Buttons::LEFT_BUMPER),  // L1
    (1, 0x02, Buttons::RIGHT_BUMPER), // R1
    (1, 0x10, Buttons::VIEW),         // Share (DualSense: Create)
    (1, 0x20, Buttons::MENU),         // Options
    (1, 0x40, Buttons::LEFT_STICK),   // L3
    (1, 0x80, Buttons::RIGHT_STICK),  // R3
    (2, 0x01, Buttons::HOME),         // PS
];

/// The controls of a report whose length was checked against `offsets`.
fn state_at(payload: &[u8], offsets: &Offsets) -> GamepadState {
    let stick = |index: usize| centred(payload[offsets.sticks + index]);
    let buttons = &payload[offsets.buttons..offsets.buttons + 3];
    let pressed = BUTTON_BITS
        .iter()
        .filter(|(byte, mask, _)| buttons[*byte] & mask != 0)
        .fold(Buttons::NONE, |held, (_, _, button)| held.with(*button));
    GamepadState {
        left_x: with_dead_zone(stick(0)),
        // Y grows towards the player on the pads; forward is +1 here.
        left_y: with_dead_zone(-stick(1)),
        right_x: with_dead_zone(stick(2)),
        right_y: with_dead_zone(-stick(3)),
        left_trigger: f32::from(payload[offsets.triggers]) / 255.0,
        right_trigger: f32::from(payload[offsets.triggers + 1]) / 255.0,
        buttons: pressed,
        dpad: hat(buttons[0] & 0x0F),
    }
}

/// 0 … 255 on −1 … 1; the pads' centre, 128, is 1/255 off zero, well inside the dead zone.
fn centred(raw: u8) -> f32 {
    (2.0 * f32::from(raw) - 255.0) / 255.0
}

/// The hat nibble: 0 … 7 clockwise from up, 8 released.
fn hat(nibble: u8) -> Dpad {
    hat_position(i64::from(nibble))
}

/// DualShock 4 status byte: charge in tenths in the low nibble, bit 4 set on a cable;
/// on a cable 10 is "charging, nearly full", 11 "full", above that an error.
fn dualshock4_battery(status: u8) -> Battery {
    let tenths = status & 0x0F;
    let on_cable = status & 0x10 != 0;
    let (percent, state) = match (on_cable, tenths) {
        (false, 0..=9) => (tenths * 10 + 5, BatteryState::Discharging),
        (false, _) => (100, BatteryState::Discharging),
        (true, 0..=9) => (tenths * 10 + 5, BatteryState::Charging),
        (true, 10) => (100, BatteryState::Charging),
        (true, 11) => (100, BatteryState::Full),
        (true, _) => (0, BatteryState::Fault),
    };
    Battery { percent, state }
}

/// DualSense status byte: charge in tenths in the low nibble, the charging state in
/// the high one (0 discharging, 1 charging, 2 full, others errors).
fn dualsense_battery(status: u8) -> Battery {
    let percent = ((status & 0x0F) * 10 + 5).min(100);
    match status >> 4 {
        0x0 => Battery {
            percent,
            state: BatteryState::Discharging,
        },
        0x1 => Battery {
            percent,
            state: BatteryState::Charging,
        },
        0x2 => Battery {
            percent: 100,
            state: BatteryState::Full,
        },
        _ => Battery {
            percent: 0,
            state: BatteryState::Fault,
        },
    }
}

/// A light bar colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rgb {
    pub red: u8,
    pub green: u8,
    pub blue: u8,
}

impl Rgb {
    pub const fn new(red: u8, green: u8, blue: u8) -> Rgb {
        Rgb { red, green, blue }
    }
}

/// Rumble motor speeds, 0 (off) … 255.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rumble {
    /// The heavy motor in the left grip.
    pub strong: u8,
    /// The light motor in the right grip.
    pub weak: u8,
}

/// What an output report sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PadOutput {
    pub light_bar: Rgb,
    pub rumble: Rumble,
}

/// Builds one pad's output reports (light bar and rumble), for the interrupt channel.
///
/// It keeps what the pads need across reports: the DualSense numbers its output
/// reports (four bits) and, in the first one, is told to end its start-up light
/// animation, which would otherwise keep the light bar blue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OutputBuilder {
    kind: PadKind,
    /// The DualSense's number for the next report, 0 … 15.
    sequence: u8,
    /// Whether a report was built: only the first ends the start-up light.
    started: bool,
}

impl OutputBuilder {
    pub const fn new(kind: PadKind) -> OutputBuilder {
        OutputBuilder {
            kind,
            sequence: 0,
            started: false,
        }
    }

    /// The next output report, header and CRC included.
    pub fn build(&mut self, output: &PadOutput) -> [u8; OUTPUT_REPORT_LEN] {
        let mut report = [0u8; OUTPUT_REPORT_LEN];
        report[0] = HEADER_OUTPUT;
        report[1] = self.kind.full_report_id();
        match self.kind {
            PadKind::DualShock4 => {
                // Bits 7 and 6: HID report with CRC; low six bits: the input interval.
                report[2] = 0xC0 | DUALSHOCK4_POLL_INTERVAL_MS;
                // Valid flags: motors, light bar.
                report[4] = 0x01 | 0x02;
                report[7] = output.rumble.weak;
                report[8] = output.rumble.strong;
                report[9] = output.light_bar.red;
                report[10] = output.light_bar.green;
                report[11] = output.light_bar.blue;
            }
            PadKind::DualSense => {
                report[2] = self.sequence << 4;
                self.sequence = (self.sequence + 1) % 16;
                // The tag the pad expects in byte 3 of its Bluetooth output reports.
                report[3] = 0x10;
                // Valid flags: compatible vibration and haptics select (rumble), light bar.
                report[4] = 0x01 | 0x02;
                report[5] = 0x04;
                report[6] = output.rumble.weak;
                report[7] = output.rumble.strong;
                if !self.started {
                    // Light bar setup valid, setup: fade the start-up light out.
                    report[42] = 0x02;
                    report[45] = 0x02;
                }
                report[48] = output.light_bar.red;
                report[49] = output.light_bar.green;
                report[50] = output.light_bar.blue;
            }
        }
        let crc = crc32(HEADER_OUTPUT, &report[1..OUTPUT_REPORT_LEN - CRC_LEN]);
        report[OUTPUT_REPORT_LEN - CRC_LEN..].copy_from_slice(&crc.to_le_bytes());
        self.started = true;
        report
    }
}
