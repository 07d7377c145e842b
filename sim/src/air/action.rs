//! The pads' controls as data, for a seeded tester: it draws [`PadAction`]s, applies
//! them to pads it finds by name ([`Air::pad`]), logs them and replays them. Each
//! action is the same call a test makes on [`BlePad`] or [`PlayStationPad`]; one a
//! kind of pad cannot do is refused with the reason, and changes nothing.

use base_core::gamepad::{Buttons, Dpad, GamepadState};
use embassy_time::Duration;

use super::{Air, BlePad, Pad, PlayStationPad, state::DeviceKind};

/// Something a pad does.
#[derive(Debug, Clone, PartialEq)]
pub enum PadAction {
    /// BLE: on (it advertises again if it did before). PlayStation: PS pressed, a
    /// bonded pad pages its host.
    SwitchOn,
    /// The link ends with "power off"; the pad is silent until switched on.
    SwitchOff,
    /// BLE: advertises as a gamepad whenever not connected. PlayStation: Share + PS,
    /// discoverable and willing to pair.
    PairingMode,
    /// BLE only: stops advertising.
    StopAdvertising,
    /// PlayStation only: pages the robot without a bond (a stranger, or an impostor
    /// at a bonded pad's address).
    PageRobot,
    /// The pad forgets its bond.
    ForgetBond,
    /// All inputs at once.
    Inputs(GamepadState),
    Hold(Buttons),
    Release(Buttons),
    /// `x` right, `y` forward, each −1 … 1.
    LeftStick {
        x: f32,
        y: f32,
    },
    RightStick {
        x: f32,
        y: f32,
    },
    /// Each 0 … 1.
    Triggers {
        left: f32,
        right: f32,
    },
    Dpad(Dpad),
    /// Out of radio range: the links carry nothing and time out unless it is back
    /// before their supervision timeout.
    OutOfRange,
    BackInRange,
    /// PlayStation only: the link stays, the reports stop (or go on again).
    Silent(bool),
    /// PlayStation only: the full reports carry a wrong CRC (or a right one again).
    Garble(bool),
    /// PlayStation only: a clone that never leaves the short report 0x01 (or does).
    ShortReportsOnly(bool),
    /// PlayStation only: how often it reports (4 ms as the real pads).
    ReportPeriod(Duration),
    /// PlayStation only: the battery byte of the full reports.
    Battery(u8),
    /// The pad sends this L2CAP PDU on its link now.
    SendL2cap {
        cid: u16,
        payload: Vec<u8>,
    },
    /// The robot's controller hands its host this ACL data on the pad's link as it
    /// is, any length up to 1021 bytes, with this boundary flag.
    SendAcl {
        boundary: u8,
        data: Vec<u8>,
    },
    /// From now on the pad sends this L2CAP PDU on every new link, at once.
    AttackOnConnect {
        cid: u16,
        payload: Vec<u8>,
    },
    /// No more attacks on connect.
    Peace,
}

/// Why a pad did not do an action.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ActionRefused {
    /// A BLE pad cannot do this (reports, pages and CRCs are the PlayStation pads').
    NotForBlePads,
    /// A PlayStation pad cannot do this (it does not advertise).
    NotForPlayStationPads,
    /// The pad has no link to send on.
    NotConnected,
}

impl core::fmt::Display for ActionRefused {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ActionRefused::NotForBlePads => "a BLE pad cannot do that",
            ActionRefused::NotForPlayStationPads => "a PlayStation pad cannot do that",
            ActionRefused::NotConnected => "the pad has no link to send on",
        })
    }
}

impl std::error::Error for ActionRefused {}

/// A pad of either kind.
pub enum AnyPad {
    Ble(BlePad),
    PlayStation(PlayStationPad),
}

impl core::ops::Deref for AnyPad {
    type Target = Pad;

    fn deref(&self) -> &Pad {
        match self {
            AnyPad::Ble(pad) => pad,
            AnyPad::PlayStation(pad) => pad,
        }
    }
}

impl AnyPad {
    /// Does `action` now, or says why this pad cannot.
    pub fn apply(&self, action: &PadAction) -> Result<(), ActionRefused> {
        use ActionRefused::{NotConnected, NotForBlePads, NotForPlayStationPads};
        let connected = |sent: bool| if sent { Ok(()) } else { Err(NotConnected) };
        match (self, action) {
            (AnyPad::Ble(pad), PadAction::SwitchOn) => pad.switch_on(),
            (AnyPad::PlayStation(pad), PadAction::SwitchOn) => pad.switch_on(),
            (AnyPad::Ble(pad), PadAction::SwitchOff) => pad.switch_off(),
            (AnyPad::PlayStation(pad), PadAction::SwitchOff) => pad.switch_off(),
            (AnyPad::Ble(pad), PadAction::PairingMode) => pad.advertise(true),
            (AnyPad::PlayStation(pad), PadAction::PairingMode) => pad.pairing_mode(),
            (AnyPad::Ble(pad), PadAction::StopAdvertising) => pad.advertise(false),
            (AnyPad::PlayStation(_), PadAction::StopAdvertising) => {
                return Err(NotForPlayStationPads);
            }
            (AnyPad::PlayStation(pad), PadAction::PageRobot) => pad.page_robot(),
            (AnyPad::Ble(pad), PadAction::ForgetBond) => pad.forget_bond(),
            (AnyPad::PlayStation(pad), PadAction::ForgetBond) => pad.forget_bond(),
            (_, PadAction::Inputs(inputs)) => self.set_inputs(*inputs),
            (_, PadAction::Hold(buttons)) => self.hold(*buttons),
            (_, PadAction::Release(buttons)) => self.release(*buttons),
            (_, PadAction::LeftStick { x, y }) => self.left_stick(*x, *y),
            (_, PadAction::RightStick { x, y }) => self.right_stick(*x, *y),
            (_, PadAction::Triggers { left, right }) => self.triggers(*left, *right),
            (_, PadAction::Dpad(dpad)) => self.dpad(*dpad),
            (_, PadAction::OutOfRange) => self.out_of_range(),
            (_, PadAction::BackInRange) => self.back_in_range(),
            (AnyPad::PlayStation(pad), PadAction::Silent(on)) => pad.silent(*on),
            (AnyPad::PlayStation(pad), PadAction::Garble(on)) => pad.garble(*on),
            (AnyPad::PlayStation(pad), PadAction::ShortReportsOnly(on)) => {
                pad.short_reports_only(*on)
            }
            (AnyPad::PlayStation(pad), PadAction::ReportPeriod(period)) => {
                pad.report_period(*period)
            }
            (AnyPad::PlayStation(pad), PadAction::Battery(status)) => pad.battery(*status),
            (
                AnyPad::Ble(_),
                PadAction::PageRobot
                | PadAction::Silent(_)
                | PadAction::Garble(_)
                | PadAction::ShortReportsOnly(_)
                | PadAction::ReportPeriod(_)
                | PadAction::Battery(_),
            ) => return Err(NotForBlePads),
            (_, PadAction::SendL2cap { cid, payload }) => {
                return connected(self.inject_l2cap(*cid, payload));
            }
            (_, PadAction::SendAcl { boundary, data }) => {
                return connected(self.inject_acl(*boundary, data));
            }
            (_, PadAction::AttackOnConnect { cid, payload }) => {
                self.attack_on_connect(*cid, payload)
            }
            (_, PadAction::Peace) => self.peace(),
        }
        Ok(())
    }
}

impl Air {
    /// The pad of this name, of whichever kind.
    pub fn pad(&self, name: &str) -> Option<AnyPad> {
        let state = self.state.borrow();
        let device = state.devices.iter().position(|d| d.name == name)?;
        let pad = Pad {
            air: self.clone(),
            device,
        };
        match state.devices[device].kind {
            DeviceKind::Robot => None,
            DeviceKind::BlePad(_) => Some(AnyPad::Ble(BlePad(pad))),
            DeviceKind::PlayStation(_) => Some(AnyPad::PlayStation(PlayStationPad(pad))),
        }
    }

    /// The names of the pads in the air, in the order they were made.
    pub fn pad_names(&self) -> Vec<String> {
        self.state
            .borrow()
            .devices
            .iter()
            .filter(|device| !matches!(device.kind, DeviceKind::Robot))
            .map(|device| device.name.clone())
            .collect()
    }

    /// Applies `action` to the pad of this name; `None` if there is no such pad.
    pub fn apply(&self, name: &str, action: &PadAction) -> Option<Result<(), ActionRefused>> {
        Some(self.pad(name)?.apply(action))
    }
}
