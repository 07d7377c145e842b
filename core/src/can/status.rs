//! The status frame 0x0EE (ext): why the base does or does not move, in 8 bytes. The
//! supervisor fills a [`Status`]; the CAN task sends it every `status_time`.

use super::FrameError;

/// What the base is doing, as one nibble on the wire. The supervisor's state machine
/// has more detail; this is what the PC needs to know.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Mode {
    /// Waiting for the drives after boot.
    #[default]
    Starting = 0,
    /// Drives ready, brakes applied, nothing requested.
    Standby = 1,
    /// Drives excited: driving or ramping down.
    Active = 2,
    /// E-stop pressed.
    Emergency = 3,
    /// E-stop released, waiting for the front-button confirm press.
    AwaitingConfirm = 4,
    /// Confirmed, setting the drives up again.
    Recovering = 5,
    /// Drive fault latched outside an e-stop, waiting for confirm.
    Fault = 6,
}

impl Mode {
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// `None` for a code this firmware does not define.
    pub const fn from_code(code: u8) -> Option<Mode> {
        Some(match code {
            0 => Mode::Starting,
            1 => Mode::Standby,
            2 => Mode::Active,
            3 => Mode::Emergency,
            4 => Mode::AwaitingConfirm,
            5 => Mode::Recovering,
            6 => Mode::Fault,
            _ => return None,
        })
    }
}

/// Which command source currently drives the base.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ControlSource {
    /// Nobody: no fresh CAN enable with a velocity, no dead-man held.
    #[default]
    None = 0,
    /// The robot PC over CAN.
    Can = 1,
    /// The Bluetooth gamepad, dead-man held.
    Remote = 2,
}

impl ControlSource {
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// `None` for a code this firmware does not define.
    pub const fn from_code(code: u8) -> Option<ControlSource> {
        Some(match code {
            0 => ControlSource::None,
            1 => ControlSource::Can,
            2 => ControlSource::Remote,
            _ => return None,
        })
    }
}

/// Live conditions, status byte 1 (bit 0 first).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StatusFlags {
    /// The last 0x2E4 refreshed the enable and is younger than `enable_timeout`.
    pub enable_fresh: bool,
    /// A heartbeat arrived within `heartbeat_time` (or the PC is still booting).
    pub pc_on: bool,
    /// Someone is in the safety zone: speeds are clamped.
    pub safety_zone: bool,
    pub remote_bonded: bool,
    pub remote_connected: bool,
    /// The gamepad's dead-man is held, so CAN velocity is ignored.
    pub remote_in_control: bool,
    pub estop_pressed: bool,
    pub brakes_applied: bool,
}

impl StatusFlags {
    pub fn to_byte(self) -> u8 {
        bits_to_byte([
            self.enable_fresh,
            self.pc_on,
            self.safety_zone,
            self.remote_bonded,
            self.remote_connected,
            self.remote_in_control,
            self.estop_pressed,
            self.brakes_applied,
        ])
    }

    pub fn from_byte(byte: u8) -> Self {
        let [
            enable_fresh,
            pc_on,
            safety_zone,
            remote_bonded,
            remote_connected,
            remote_in_control,
            estop_pressed,
            brakes_applied,
        ] = byte_to_bits(byte);
        Self {
            enable_fresh,
            pc_on,
            safety_zone,
            remote_bonded,
            remote_connected,
            remote_in_control,
            estop_pressed,
            brakes_applied,
        }
    }
}

/// Latched faults, status byte 2 (bit 0 first). A bit stays set until the condition is
/// cleared by the module that owns it (e.g. a confirm press for the drives), so a PC
/// that polls rarely still sees that something happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Faults {
    /// The left drive stopped answering on Modbus.
    pub left_drive_silent: bool,
    /// The left drive reported an alarm (code in `Status::drive_alarm`).
    pub left_drive_alarm: bool,
    pub right_drive_silent: bool,
    pub right_drive_alarm: bool,
    /// The store was corrupt or unreadable and defaults were loaded, or a write failed
    /// (a blank store is a first boot: no fault).
    pub flash: bool,
    /// The load cell does not answer.
    pub scale: bool,
    /// Bus-off or receive overflow happened: frames may have been lost.
    pub can_bus: bool,
    /// The last reset was by the watchdog.
    pub watchdog_reset: bool,
}

impl Faults {
    pub fn to_byte(self) -> u8 {
        bits_to_byte([
            self.left_drive_silent,
            self.left_drive_alarm,
            self.right_drive_silent,
            self.right_drive_alarm,
            self.flash,
            self.scale,
            self.can_bus,
            self.watchdog_reset,
        ])
    }

    pub fn from_byte(byte: u8) -> Self {
        let [
            left_drive_silent,
            left_drive_alarm,
            right_drive_silent,
            right_drive_alarm,
            flash,
            scale,
            can_bus,
            watchdog_reset,
        ] = byte_to_bits(byte);
        Self {
            left_drive_silent,
            left_drive_alarm,
            right_drive_silent,
            right_drive_alarm,
            flash,
            scale,
            can_bus,
            watchdog_reset,
        }
    }

    /// Any bit set.
    pub fn any(self) -> bool {
        self.to_byte() != 0
    }
}

/// The content of the status frame 0x0EE. Layout in `docs/protocol.md`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// byte 0, low nibble.
    pub mode: Mode,
    /// byte 0, bits 4–6.
    pub control: ControlSource,
    /// byte 0, bit 7: register values wait for the flash. They are in force, and are
    /// written at the next standstill (flash is never written while the base moves).
    pub persist_pending: bool,
    /// byte 1.
    pub flags: StatusFlags,
    /// byte 2.
    pub faults: Faults,
    /// byte 3: wrapping count of every rejected input (frames, register writes,
    /// calibration steps), so the PC sees a rejection even if a later one overwrote
    /// the reason.
    pub rejected_count: u8,
    /// byte 4: reason code of the latest rejection, 0 = none. 0x01..=0x0F are
    /// [`FrameError`] codes; other modules' codes start at 0x10.
    pub last_rejection: u8,
    /// byte 5: low byte of the CAN ID for a frame rejection, the register address for
    /// a register rejection.
    pub last_rejection_subject: u8,
    /// byte 6: last non-zero alarm code a drive reported (e.g. 0x84), 0 = none.
    pub drive_alarm: u8,
    /// byte 7: wrapping count of garbled or missing Modbus replies.
    pub modbus_errors: u8,
}

impl Status {
    pub fn to_bytes(&self) -> [u8; 8] {
        [
            (u8::from(self.persist_pending) << 7) | (self.control.code() << 4) | self.mode.code(),
            self.flags.to_byte(),
            self.faults.to_byte(),
            self.rejected_count,
            self.last_rejection,
            self.last_rejection_subject,
            self.drive_alarm,
            self.modbus_errors,
        ]
    }

    /// [`FrameError::UnknownSubcommand`] if byte 0 holds a mode or control source this
    /// firmware does not define (a newer firmware, or a garbled frame).
    pub fn from_bytes(bytes: [u8; 8]) -> Result<Status, FrameError> {
        let [
            mode_and_control,
            flags,
            faults,
            rejected_count,
            last_rejection,
            last_rejection_subject,
            drive_alarm,
            modbus_errors,
        ] = bytes;
        let mode = Mode::from_code(mode_and_control & 0x0F).ok_or(FrameError::UnknownSubcommand)?;
        let control = ControlSource::from_code((mode_and_control >> 4) & 0x07)
            .ok_or(FrameError::UnknownSubcommand)?;
        Ok(Status {
            mode,
            control,
            persist_pending: mode_and_control & 0x80 != 0,
            flags: StatusFlags::from_byte(flags),
            faults: Faults::from_byte(faults),
            rejected_count,
            last_rejection,
            last_rejection_subject,
            drive_alarm,
            modbus_errors,
        })
    }
}

fn bits_to_byte(bits: [bool; 8]) -> u8 {
    bits.iter()
        .enumerate()
        .fold(0, |byte, (bit, &set)| byte | (u8::from(set) << bit))
}

fn byte_to_bits(byte: u8) -> [bool; 8] {
    core::array::from_fn(|bit| byte & (1 << bit) != 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_flag_has_its_own_bit_in_documented_order() {
        let only = |byte| StatusFlags::from_byte(byte);
        assert!(only(0x01).enable_fresh);
        assert!(only(0x02).pc_on);
        assert!(only(0x04).safety_zone);
        assert!(only(0x08).remote_bonded);
        assert!(only(0x10).remote_connected);
        assert!(only(0x20).remote_in_control);
        assert!(only(0x40).estop_pressed);
        assert!(only(0x80).brakes_applied);
        assert_eq!(only(0x80).to_byte(), 0x80);
        assert_eq!(only(0x01).to_byte(), 0x01);
    }

    #[test]
    fn each_fault_has_its_own_bit_in_documented_order() {
        let only = |byte| Faults::from_byte(byte);
        assert!(only(0x01).left_drive_silent);
        assert!(only(0x02).left_drive_alarm);
        assert!(only(0x04).right_drive_silent);
        assert!(only(0x08).right_drive_alarm);
        assert!(only(0x10).flash);
        assert!(only(0x20).scale);
        assert!(only(0x40).can_bus);
        assert!(only(0x80).watchdog_reset);
        assert_eq!(only(0x40).to_byte(), 0x40);
        assert!(!Faults::default().any());
    }

    #[test]
    fn flag_and_fault_bytes_round_trip_for_every_value() {
        for byte in 0..=u8::MAX {
            assert_eq!(StatusFlags::from_byte(byte).to_byte(), byte);
            assert_eq!(Faults::from_byte(byte).to_byte(), byte);
        }
    }

    #[test]
    fn mode_and_control_codes_round_trip_and_stop_at_the_last_defined() {
        for code in 0..=6 {
            assert_eq!(Mode::from_code(code).map(Mode::code), Some(code));
        }
        assert_eq!(Mode::from_code(7), None);
        for code in 0..=2 {
            assert_eq!(
                ControlSource::from_code(code).map(ControlSource::code),
                Some(code)
            );
        }
        assert_eq!(ControlSource::from_code(3), None);
    }

    #[test]
    fn default_status_is_starting_with_nobody_in_control_and_all_zero() {
        let status = Status::default();
        assert_eq!(status.mode, Mode::Starting);
        assert_eq!(status.control, ControlSource::None);
        assert_eq!(status.to_bytes(), [0; 8]);
    }

    #[test]
    fn unknown_mode_or_control_nibble_is_refused() {
        assert_eq!(
            Status::from_bytes([0x07, 0, 0, 0, 0, 0, 0, 0]),
            Err(FrameError::UnknownSubcommand)
        );
        assert_eq!(
            Status::from_bytes([0x30, 0, 0, 0, 0, 0, 0, 0]),
            Err(FrameError::UnknownSubcommand)
        );
    }
}
