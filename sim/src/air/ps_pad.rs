//! A PlayStation pad (DualShock 4 or DualSense) as the robot meets it over Bluetooth
//! Classic: its L2CAP signalling, its HID control and interrupt channels, feature
//! report 0x05, and its input reports (short 0x01 until 0x05 was read, then full
//! 0x11 / 0x31 with their CRC-32). Sans IO: the air feeds it frames and asks it for
//! reports; it answers with frames and what it saw.
//!
//! The bytes are written from the pads' Bluetooth layout (Linux's `hid-playstation`
//! names them), not from the firmware's decoder: a decoder that read the wrong byte
//! would fail here.

use base_core::gamepad::{Buttons, Dpad, GamepadState};
use base_core::hid::playstation::{PadKind, Rgb, crc32};
use embassy_time::{Duration, Instant};

use super::PadEvent;
use super::state::{CONNECTION_TIMEOUT, LinkId};

/// The pad's own channel IDs (its end of the control and interrupt channels).
const CONTROL_CID: u16 = 0x0040;
const INTERRUPT_CID: u16 = 0x0041;
const SIGNALLING_CID: u16 = 0x0001;
const PSM_CONTROL: u16 = 0x0011;
const PSM_INTERRUPT: u16 = 0x0013;
/// The MTU the pad asks for on its channels.
const PAD_MTU: u16 = 672;

/// HID transaction headers.
const HEADER_INPUT: u8 = 0xA1;
const HEADER_OUTPUT: u8 = 0xA2;
const HEADER_FEATURE: u8 = 0xA3;
const HANDSHAKE_SUCCESSFUL: u8 = 0x00;
const HANDSHAKE_INVALID_REPORT_ID: u8 = 0x02;
const HANDSHAKE_UNSUPPORTED: u8 = 0x03;

/// What a pad asks the air to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PadOut {
    /// An L2CAP frame (header included) for the robot.
    Frame(Vec<u8>),
    Log(PadEvent),
    /// The interrupt channel is open: stream reports.
    StartStreaming,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Channel {
    Closed,
    /// The pad asked to open it.
    Requested {
        identifier: u8,
    },
    Configuring {
        remote: u16,
        ours_accepted: bool,
        theirs_accepted: bool,
    },
    Open {
        remote: u16,
    },
}

/// The pad's side of one link.
#[derive(Debug, Clone)]
pub struct PadLink {
    pub id: LinkId,
    /// The pad paged (a bonded pad switched on): it opens the HID channels.
    pub pad_opens: bool,
    pub encrypted: bool,
    control: Channel,
    interrupt: Channel,
    next_identifier: u8,
}

impl PadLink {
    fn channel(&mut self, cid: u16) -> Option<&mut Channel> {
        match cid {
            CONTROL_CID => Some(&mut self.control),
            INTERRUPT_CID => Some(&mut self.interrupt),
            _ => None,
        }
    }

    fn identifier(&mut self) -> u8 {
        let identifier = self.next_identifier;
        self.next_identifier = self.next_identifier.checked_add(1).unwrap_or(1);
        identifier
    }
}

pub struct PsPad {
    pub kind: PadKind,
    pub switched_on: bool,
    /// Share + PS held: discoverable, and willing to pair.
    pub pairing_mode: bool,
    /// The host it bonded with (its address as on HCI) and the link key.
    pub bond: Option<([u8; 6], [u8; 16])>,
    /// A host to page without a bond (a stranger or an impostor trying its luck).
    pub page_target: Option<[u8; 6]>,
    pub inputs: GamepadState,
    /// A clone that never leaves the short report.
    pub stuck_short: bool,
    /// The link stays, the reports stop.
    pub silent: bool,
    /// The full reports' CRC is wrong.
    pub garbled: bool,
    /// The battery byte of the full reports.
    pub battery: u8,
    pub report_period: Duration,
    /// The page in progress: its number and when it started.
    pub paging: Option<(u64, Instant)>,
    pub page_attempts: u32,
    /// The report stream's number (0: not streaming).
    pub stream_epoch: u64,
    pub link: Option<PadLink>,
    pub full_mode: bool,
    sequence: u8,
    /// The last light bar colour the robot set.
    pub light_bar: Option<Rgb>,
}

impl PsPad {
    pub fn new(kind: PadKind) -> Self {
        Self {
            kind,
            switched_on: false,
            pairing_mode: false,
            bond: None,
            page_target: None,
            inputs: GamepadState::default(),
            stuck_short: false,
            silent: false,
            garbled: false,
            // DualShock 4: 85 % on battery; DualSense: 85 %, discharging.
            battery: 0x08,
            report_period: Duration::from_millis(4),
            paging: None,
            page_attempts: 0,
            stream_epoch: 0,
            link: None,
            full_mode: false,
            sequence: 0,
            light_bar: None,
        }
    }

    /// Whether the pad's page is meant for `host`.
    pub fn pages(&self, host: [u8; 6]) -> bool {
        self.bond.is_some_and(|(bonded, _)| bonded == host) || self.page_target == Some(host)
    }

    pub fn on_connected(&mut self, id: LinkId, pad_opens: bool) {
        self.full_mode = false;
        self.link = Some(PadLink {
            id,
            pad_opens,
            encrypted: false,
            control: Channel::Closed,
            interrupt: Channel::Closed,
            next_identifier: 1,
        });
    }

    /// The link is gone, with the reason the pad heard (`None`: the pad dropped it).
    /// A pad that lost its host (a supervision timeout) pages it again; one its host
    /// dropped switches itself off, as a DualShock 4 does. Returns whether it pages.
    pub fn on_disconnected(&mut self, id: LinkId, reason: Option<u8>) -> bool {
        if self.link.as_ref().is_none_or(|link| link.id != id) {
            return false;
        }
        self.link = None;
        self.stream_epoch = 0;
        self.paging = None;
        if reason == Some(CONNECTION_TIMEOUT) && self.switched_on && self.bond.is_some() {
            self.page_attempts = 0;
            return true;
        }
        if reason.is_some() {
            self.switched_on = false;
            self.pairing_mode = false;
            self.page_target = None;
        }
        false
    }

    /// The link is encrypted: a pad that paged opens its control channel.
    pub fn on_encrypted(&mut self) -> Vec<PadOut> {
        let mut out = Vec::new();
        if let Some(link) = self.link.as_mut() {
            link.encrypted = true;
            if link.pad_opens && link.control == Channel::Closed {
                request(link, PSM_CONTROL, CONTROL_CID, &mut out);
            }
        }
        out
    }

    /// One whole L2CAP frame from the robot.
    pub fn on_frame(&mut self, frame: &[u8]) -> Vec<PadOut> {
        let mut out = Vec::new();
        let Some((cid, payload)) = split_frame(frame) else {
            out.push(PadOut::Log(PadEvent::Refused(frame.len())));
            return out;
        };
        match cid {
            SIGNALLING_CID => self.signalling(payload, &mut out),
            CONTROL_CID => self.control(payload, &mut out),
            INTERRUPT_CID => self.output_report(payload, &mut out),
            _ => out.push(PadOut::Log(PadEvent::Refused(frame.len()))),
        }
        out
    }

    fn signalling(&mut self, mut payload: &[u8], out: &mut Vec<PadOut>) {
        while let [code, identifier, lo, hi, rest @ ..] = payload {
            let length = usize::from(u16::from_le_bytes([*lo, *hi]));
            let Some(data) = rest.get(..length) else {
                return;
            };
            payload = &rest[length..];
            self.signal(*code, *identifier, data, out);
        }
    }

    fn signal(&mut self, code: u8, identifier: u8, data: &[u8], out: &mut Vec<PadOut>) {
        let Some(link) = self.link.as_mut() else {
            return;
        };
        let word = |at: usize| {
            data.get(at..at + 2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
        };
        match code {
            // Connection Request: the robot opens a channel.
            0x02 => {
                let (Some(psm), Some(source)) = (word(0), word(2)) else {
                    return reject(identifier, out);
                };
                let local = match psm {
                    PSM_CONTROL => CONTROL_CID,
                    PSM_INTERRUPT => INTERRUPT_CID,
                    _ => {
                        return send_signal(out, 0x03, identifier, &[&0u16, &source, &2, &0]);
                    }
                };
                let channel = link.channel(local).expect("one of ours");
                if *channel != Channel::Closed {
                    return send_signal(out, 0x03, identifier, &[&0u16, &source, &4, &0]);
                }
                *channel = Channel::Configuring {
                    remote: source,
                    ours_accepted: false,
                    theirs_accepted: false,
                };
                send_signal(out, 0x03, identifier, &[&local, &source, &0, &0]);
                configure(link, source, out);
            }
            // Connection Response to the pad's request.
            0x03 => {
                let (Some(destination), Some(source), Some(result)) = (word(0), word(2), word(4))
                else {
                    return;
                };
                let Some(channel) = link.channel(source) else {
                    return;
                };
                if *channel != (Channel::Requested { identifier }) {
                    return;
                }
                match result {
                    0 => {
                        *channel = Channel::Configuring {
                            remote: destination,
                            ours_accepted: false,
                            theirs_accepted: false,
                        };
                        configure(link, destination, out);
                    }
                    // Pending: the answer comes later.
                    1 => {}
                    _ => {
                        *channel = Channel::Closed;
                        out.push(PadOut::Log(PadEvent::ChannelRefused(result)));
                    }
                }
            }
            // Configuration Request: the robot's options for our channel.
            0x04 => {
                let Some(local) = word(0) else {
                    return reject(identifier, out);
                };
                match link.channel(local) {
                    Some(Channel::Configuring {
                        remote,
                        theirs_accepted,
                        ..
                    }) => {
                        *theirs_accepted = true;
                        let remote = *remote;
                        send_signal(out, 0x05, identifier, &[&remote, &0, &0]);
                    }
                    _ => {
                        // Invalid CID in request.
                        send_signal(out, 0x01, identifier, &[&2u16, &local, &0]);
                        return;
                    }
                }
                self.opened(local, out);
            }
            // Configuration Response to our options.
            0x05 => {
                let (Some(local), Some(result)) = (word(0), word(4)) else {
                    return;
                };
                match link.channel(local) {
                    Some(Channel::Configuring { ours_accepted, .. }) if result == 0 => {
                        *ours_accepted = true;
                    }
                    Some(channel @ Channel::Configuring { .. }) => {
                        *channel = Channel::Closed;
                        out.push(PadOut::Log(PadEvent::ChannelRefused(result)));
                        return;
                    }
                    _ => return,
                }
                self.opened(local, out);
            }
            // Disconnection Request.
            0x06 => {
                let (Some(local), Some(remote)) = (word(0), word(2)) else {
                    return reject(identifier, out);
                };
                if let Some(channel) = link.channel(local) {
                    *channel = Channel::Closed;
                }
                send_signal(out, 0x07, identifier, &[&local, &remote]);
            }
            // Echo Request.
            0x08 => send_signal(out, 0x09, identifier, &[]),
            // Information Request: nothing extended.
            0x0A => {
                let kind = word(0).unwrap_or(0);
                send_signal(out, 0x0B, identifier, &[&kind, &1]);
            }
            // Responses the pad has no use for.
            0x01 | 0x07 | 0x09 | 0x0B => {}
            _ => reject(identifier, out),
        }
    }

    /// A channel finished its configuration both ways: the pad opens the next one, and
    /// streams once the interrupt channel is open.
    fn opened(&mut self, local: u16, out: &mut Vec<PadOut>) {
        let Some(link) = self.link.as_mut() else {
            return;
        };
        let channel = link.channel(local).expect("one of ours");
        if let Channel::Configuring {
            remote,
            ours_accepted: true,
            theirs_accepted: true,
        } = *channel
        {
            *channel = Channel::Open { remote };
            if local == CONTROL_CID && link.pad_opens && link.interrupt == Channel::Closed {
                request(link, PSM_INTERRUPT, INTERRUPT_CID, out);
            }
            if local == INTERRUPT_CID {
                out.push(PadOut::Log(PadEvent::HidOpen));
                out.push(PadOut::StartStreaming);
            }
        }
    }

    /// A request on the control channel: GET_REPORT for feature 0x05 switches the pad
    /// to its full reports.
    fn control(&mut self, payload: &[u8], out: &mut Vec<PadOut>) {
        let Some(Channel::Open { remote }) = self.link.as_ref().map(|link| link.control) else {
            return;
        };
        let answer = match payload {
            // GET_REPORT, feature (with or without the size flag).
            [request, report_id, ..] if request & 0xF7 == 0x43 => {
                out.push(PadOut::Log(PadEvent::FeatureRead(*report_id)));
                match *report_id {
                    0x05 => {
                        if !self.stuck_short {
                            self.full_mode = true;
                        }
                        feature_report(0x05, 36)
                    }
                    0x02 if self.kind == PadKind::DualShock4 => feature_report(0x02, 35),
                    _ => vec![HANDSHAKE_INVALID_REPORT_ID],
                }
            }
            // SET_REPORT, SET_PROTOCOL: done.
            [request, ..] if request >> 4 == 0x5 || request >> 4 == 0x7 => {
                vec![HANDSHAKE_SUCCESSFUL]
            }
            _ => vec![HANDSHAKE_UNSUPPORTED],
        };
        out.push(PadOut::Frame(frame(remote, &answer)));
    }

    /// An output report on the interrupt channel: the light bar's colour.
    fn output_report(&mut self, payload: &[u8], out: &mut Vec<PadOut>) {
        let valid = payload.len() == 79
            && payload[0] == HEADER_OUTPUT
            && crc32(HEADER_OUTPUT, &payload[1..75]).to_le_bytes() == payload[75..79];
        if !valid {
            out.push(PadOut::Log(PadEvent::Refused(payload.len())));
            return;
        }
        let at = match self.kind {
            PadKind::DualShock4 => 9,
            PadKind::DualSense => 48,
        };
        let colour = Rgb::new(payload[at], payload[at + 1], payload[at + 2]);
        self.light_bar = Some(colour);
        out.push(PadOut::Log(PadEvent::LightBar(colour)));
    }

    /// The next input report as an L2CAP frame on the interrupt channel, if the pad
    /// streams now.
    pub fn next_report(&mut self) -> Option<Vec<u8>> {
        let link = self.link.as_ref()?;
        let Channel::Open { remote } = link.interrupt else {
            return None;
        };
        if !link.encrypted || self.silent {
            return None;
        }
        let report = if self.full_mode {
            self.full_report()
        } else {
            short_report(&self.inputs)
        };
        Some(frame(remote, &report))
    }

    fn full_report(&mut self) -> Vec<u8> {
        self.sequence = self.sequence.wrapping_add(1);
        let mut report = [0u8; 74];
        let sticks = sticks(&self.inputs);
        let buttons = buttons(&self.inputs);
        let triggers = triggers(&self.inputs);
        match self.kind {
            PadKind::DualShock4 => {
                report[..3].copy_from_slice(&[0x11, 0xC0, 0x00]);
                report[3..7].copy_from_slice(&sticks);
                report[7..10].copy_from_slice(&buttons);
                report[10..12].copy_from_slice(&triggers);
                report[32] = self.battery;
            }
            PadKind::DualSense => {
                report[..2].copy_from_slice(&[0x31, self.sequence]);
                report[2..6].copy_from_slice(&sticks);
                report[6..8].copy_from_slice(&triggers);
                report[9..12].copy_from_slice(&buttons);
                report[54] = self.battery;
            }
        }
        let mut crc = crc32(HEADER_INPUT, &report);
        if self.garbled {
            crc = !crc;
        }
        let mut payload = vec![HEADER_INPUT];
        payload.extend_from_slice(&report);
        payload.extend_from_slice(&crc.to_le_bytes());
        payload
    }
}

fn short_report(inputs: &GamepadState) -> Vec<u8> {
    let mut payload = vec![HEADER_INPUT, 0x01];
    payload.extend_from_slice(&sticks(inputs));
    payload.extend_from_slice(&buttons(inputs));
    payload.extend_from_slice(&triggers(inputs));
    payload
}

/// LX, LY, RX, RY: 0 … 255, 128 centred, Y = 0 pushed forward.
fn sticks(inputs: &GamepadState) -> [u8; 4] {
    let axis = |value: f32, forward_is_low: bool| {
        let value = value.clamp(-1.0, 1.0);
        let value = if forward_is_low { -value } else { value };
        (128.0 + value * 127.0).round().clamp(0.0, 255.0) as u8
    };
    [
        axis(inputs.left_x, false),
        axis(inputs.left_y, true),
        axis(inputs.right_x, false),
        axis(inputs.right_y, true),
    ]
}

fn triggers(inputs: &GamepadState) -> [u8; 2] {
    let pull = |value: f32| (value.clamp(0.0, 1.0) * 255.0).round() as u8;
    [pull(inputs.left_trigger), pull(inputs.right_trigger)]
}

/// Byte 0: the hat (low nibble, 8 released) and the face buttons; byte 1 the
/// shoulders, triggers, Share, Options, L3, R3; byte 2 PS.
fn buttons(inputs: &GamepadState) -> [u8; 3] {
    const BITS: [(Buttons, usize, u8); 11] = [
        (Buttons::X, 0, 0x10),            // Square
        (Buttons::A, 0, 0x20),            // Cross
        (Buttons::B, 0, 0x40),            // Circle
        (Buttons::Y, 0, 0x80),            // Triangle
        (Buttons::LEFT_BUMPER, 1, 0x01),  // L1
        (Buttons::RIGHT_BUMPER, 1, 0x02), // R1
        (Buttons::VIEW, 1, 0x10),         // Share (Create)
        (Buttons::MENU, 1, 0x20),         // Options
        (Buttons::LEFT_STICK, 1, 0x40),   // L3
        (Buttons::RIGHT_STICK, 1, 0x80),  // R3
        (Buttons::HOME, 2, 0x01),         // PS
    ];
    let mut bytes = [hat(inputs.dpad), 0, 0];
    for (button, byte, bit) in BITS {
        if inputs.buttons.contains(button) {
            bytes[byte] |= bit;
        }
    }
    // L2 and R2 also have digital bits, set as soon as the trigger moves.
    if inputs.left_trigger > 0.0 {
        bytes[1] |= 0x04;
    }
    if inputs.right_trigger > 0.0 {
        bytes[1] |= 0x08;
    }
    bytes
}

/// The hat: 0 up, clockwise to 7 up-left, 8 released.
fn hat(dpad: Dpad) -> u8 {
    match (dpad.up, dpad.right, dpad.down, dpad.left) {
        (true, false, false, false) => 0,
        (true, true, false, false) => 1,
        (false, true, false, false) => 2,
        (false, true, true, false) => 3,
        (false, false, true, false) => 4,
        (false, false, true, true) => 5,
        (false, false, false, true) => 6,
        (true, false, false, true) => 7,
        _ => 8,
    }
}

/// A feature report answer: header, ID, `len` bytes, CRC-32 over them seeded with
/// the header.
fn feature_report(report_id: u8, len: usize) -> Vec<u8> {
    let mut body = vec![report_id];
    body.extend(std::iter::repeat_n(0, len));
    let crc = crc32(HEADER_FEATURE, &body);
    let mut answer = vec![HEADER_FEATURE];
    answer.extend_from_slice(&body);
    answer.extend_from_slice(&crc.to_le_bytes());
    answer
}

/// An L2CAP basic frame on `cid`.
pub fn frame(cid: u16, payload: &[u8]) -> Vec<u8> {
    let mut frame = (payload.len() as u16).to_le_bytes().to_vec();
    frame.extend_from_slice(&cid.to_le_bytes());
    frame.extend_from_slice(payload);
    frame
}

fn split_frame(frame: &[u8]) -> Option<(u16, &[u8])> {
    let [l0, l1, c0, c1, payload @ ..] = frame else {
        return None;
    };
    (usize::from(u16::from_le_bytes([*l0, *l1])) == payload.len())
        .then(|| (u16::from_le_bytes([*c0, *c1]), payload))
}

/// A signalling command from the pad: code, identifier, its 16-bit fields.
fn send_signal(out: &mut Vec<PadOut>, code: u8, identifier: u8, fields: &[&u16]) {
    let mut data = Vec::new();
    for field in fields {
        data.extend_from_slice(&field.to_le_bytes());
    }
    signal_bytes(out, code, identifier, &data);
}

fn signal_bytes(out: &mut Vec<PadOut>, code: u8, identifier: u8, data: &[u8]) {
    let mut command = vec![code, identifier];
    command.extend_from_slice(&(data.len() as u16).to_le_bytes());
    command.extend_from_slice(data);
    out.push(PadOut::Frame(frame(SIGNALLING_CID, &command)));
}

/// Command Reject, command not understood.
fn reject(identifier: u8, out: &mut Vec<PadOut>) {
    send_signal(out, 0x01, identifier, &[&0]);
}

/// The pad opens a channel.
fn request(link: &mut PadLink, psm: u16, local: u16, out: &mut Vec<PadOut>) {
    let identifier = link.identifier();
    *link.channel(local).expect("one of ours") = Channel::Requested { identifier };
    send_signal(out, 0x02, identifier, &[&psm, &local]);
}

/// The pad's Configuration Request for a channel: its MTU.
fn configure(link: &mut PadLink, remote: u16, out: &mut Vec<PadOut>) {
    let identifier = link.identifier();
    let mut data = remote.to_le_bytes().to_vec();
    data.extend_from_slice(&[0, 0]);
    // Option MTU: type 1, length 2.
    data.extend_from_slice(&[0x01, 2]);
    data.extend_from_slice(&PAD_MTU.to_le_bytes());
    signal_bytes(out, 0x04, identifier, &data);
}

#[cfg(test)]
mod tests {
    use super::*;
    use base_core::hid::playstation::{ReportMode, decode_input};

    fn held() -> GamepadState {
        GamepadState {
            left_y: 1.0,
            right_x: -0.5,
            right_trigger: 1.0,
            buttons: Buttons::RIGHT_BUMPER.with(Buttons::HOME),
            dpad: Dpad {
                up: true,
                ..Dpad::default()
            },
            ..GamepadState::default()
        }
    }

    #[test]
    fn the_reports_decode_to_what_the_pad_holds_in_both_modes_and_kinds() {
        for kind in [PadKind::DualShock4, PadKind::DualSense] {
            let mut pad = PsPad::new(kind);
            pad.inputs = held();
            let short = short_report(&pad.inputs);
            let decoded = decode_input(kind, &short).expect("short report");
            assert_eq!(decoded.mode, ReportMode::Short);
            pad.full_mode = true;
            let full = pad.full_report();
            let decoded = decode_input(kind, &full).expect("full report");
            assert_eq!(decoded.mode, ReportMode::Full, "{kind:?}");
            let state = decoded.state;
            assert!(
                state
                    .buttons
                    .contains(Buttons::RIGHT_BUMPER.with(Buttons::HOME))
            );
            assert!(state.left_y > 0.95, "{kind:?}: forward is forward");
            assert!(state.right_x < -0.4, "{kind:?}");
            assert!(state.right_trigger > 0.99, "{kind:?}");
            assert!(state.dpad.up && !state.dpad.down, "{kind:?}");
            assert_eq!(decoded.battery.map(|b| b.percent), Some(85), "{kind:?}");
        }
    }

    #[test]
    fn a_garbled_pad_sends_full_reports_whose_crc_fails() {
        let mut pad = PsPad::new(PadKind::DualShock4);
        pad.full_mode = true;
        pad.garbled = true;
        let full = pad.full_report();
        assert!(decode_input(PadKind::DualShock4, &full).is_err());
    }

    #[test]
    fn feature_report_0x05_is_what_the_host_checks() {
        let answer = feature_report(0x05, 36);
        assert_eq!(
            base_core::hid::playstation::check_full_mode_feature(&answer),
            Ok(())
        );
    }
}
