//! Which remote is connected and its battery, for the PC: the read-only registers
//! `remote_kind` (34) and `remote_battery` (35). The Bluetooth tasks report it with
//! `Input::RemoteInfo`; nothing persists it. A register read is the only way out, so
//! the encoding is fixed here, and `basectl info` decodes it with the same functions.

use crate::hid::playstation::{self, BatteryState, PadKind};

/// The connected remote, `remote_kind` (34).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RemoteKind {
    /// No remote connected.
    #[default]
    None = 0,
    /// A BLE gamepad (HID over GATT).
    BlePad = 1,
    /// A DualShock 4 over Bluetooth Classic.
    DualShock4 = 2,
    /// A DualSense (or DualSense Edge) over Bluetooth Classic.
    DualSense = 3,
}

impl RemoteKind {
    /// The highest code: the register's range.
    pub const MAX_CODE: u16 = RemoteKind::DualSense as u16;

    pub const fn code(self) -> u16 {
        self as u16
    }

    /// `None` for a code this firmware does not define.
    pub const fn from_code(code: u16) -> Option<RemoteKind> {
        Some(match code {
            0 => RemoteKind::None,
            1 => RemoteKind::BlePad,
            2 => RemoteKind::DualShock4,
            3 => RemoteKind::DualSense,
            _ => return None,
        })
    }
}

impl From<PadKind> for RemoteKind {
    fn from(kind: PadKind) -> RemoteKind {
        match kind {
            PadKind::DualShock4 => RemoteKind::DualShock4,
            PadKind::DualSense => RemoteKind::DualSense,
        }
    }
}

/// Whether the remote is charging, as far as it says.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Charge {
    /// Only the level is known (a BLE pad's Battery Service has no charge state).
    LevelOnly = 1,
    Discharging = 2,
    Charging = 3,
    Full = 4,
    /// The pad reports a charging error.
    Fault = 5,
}

/// The remote's battery, `remote_battery` (35): bits 0–7 the level in percent
/// (0–100), bits 8–15 the [`Charge`] code; 0 when no reading is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RemoteBattery {
    /// 0 … 100.
    pub percent: u8,
    pub charge: Charge,
}

impl RemoteBattery {
    /// The register's largest value: 100 % with the highest charge code.
    pub const MAX_REGISTER: u16 = ((Charge::Fault as u16) << 8) | 100;

    /// The register value; a level above 100 reads as 100.
    pub const fn register(self) -> u16 {
        let percent = if self.percent > 100 {
            100
        } else {
            self.percent
        };
        ((self.charge as u16) << 8) | percent as u16
    }

    /// The reading in a register value; `None` for "no reading" (0) and for a value
    /// this firmware does not produce.
    pub const fn from_register(value: u16) -> Option<RemoteBattery> {
        let percent = (value & 0xFF) as u8;
        let charge = match value >> 8 {
            1 => Charge::LevelOnly,
            2 => Charge::Discharging,
            3 => Charge::Charging,
            4 => Charge::Full,
            5 => Charge::Fault,
            _ => return None,
        };
        if percent > 100 {
            return None;
        }
        Some(RemoteBattery { percent, charge })
    }
}

impl From<playstation::Battery> for RemoteBattery {
    fn from(battery: playstation::Battery) -> RemoteBattery {
        RemoteBattery {
            percent: battery.percent,
            charge: match battery.state {
                BatteryState::Discharging => Charge::Discharging,
                BatteryState::Charging => Charge::Charging,
                BatteryState::Full => Charge::Full,
                BatteryState::Fault => Charge::Fault,
            },
        }
    }
}

/// What the PC learns about the remote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RemoteInfo {
    pub kind: RemoteKind,
    pub battery: Option<RemoteBattery>,
}

impl RemoteInfo {
    /// No remote connected.
    pub const NONE: RemoteInfo = RemoteInfo {
        kind: RemoteKind::None,
        battery: None,
    };

    /// A PlayStation pad, with the battery of its latest full report (short reports
    /// carry none).
    pub fn playstation(kind: PadKind, battery: Option<playstation::Battery>) -> RemoteInfo {
        RemoteInfo {
            kind: kind.into(),
            battery: battery.map(RemoteBattery::from),
        }
    }

    /// `(remote_kind, remote_battery)` register values.
    pub const fn registers(self) -> (u16, u16) {
        let battery = match self.battery {
            Some(battery) => battery.register(),
            None => 0,
        };
        (self.kind.code(), battery)
    }

    /// The info in register values; `None` for a kind code this firmware does not
    /// define. A battery value it does not produce reads as no reading.
    pub const fn from_registers(kind: u16, battery: u16) -> Option<RemoteInfo> {
        match RemoteKind::from_code(kind) {
            Some(kind) => Some(RemoteInfo {
                kind,
                battery: RemoteBattery::from_register(battery),
            }),
            None => None,
        }
    }
}
