//! The register map: every address, its name, unit, default, valid range and access.
//! Addresses 0–23 are the manual's (§10) and never move; 24–36, 38–40 and 43–49 are
//! this firmware's extensions. `docs/registers.md` is this table in prose.

/// Every register by its manual name, in CamelCase; the discriminant is the CAN address.
///
/// 37 is deliberately absent: it is kept free for the Bluetooth remote, and
/// reading or writing it answers [`super::RegisterError::UnknownAddress`]; so do
/// 41–42, kept for the next extensions.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reg {
    /// `rad_r`, mm: right wheel radius.
    RadR = 0,
    /// `rad_l`, mm: left wheel radius.
    RadL = 1,
    /// `wheel_dist`, mm: distance between the wheels.
    WheelDist = 2,
    /// `CAN_accel`, (1/min)/s: acceleration under CAN control.
    CanAccel = 3,
    /// `Contr_acc_norm`, (1/min)/s: acceleration under remote control.
    ContrAccNorm = 4,
    /// `Contr_acc_high`, (1/min)/s: braking when the remote's dead-man is released.
    ContrAccHigh = 5,
    /// `max_motor_vel`, 1/min: motor speed limit.
    MaxMotorVel = 6,
    /// `PS_abs_max_vel`, mm/s: highest speed level the remote can select.
    PsAbsMaxVel = 7,
    /// `PS_rel_max_vel`, mm/s: the remote's speed level after boot.
    PsRelMaxVel = 8,
    /// `sec_lin_vel`, mm/s: linear limit while someone is in the safety zone.
    SecLinVel = 9,
    /// `sec_turn_vel`, mrad/s: rotation limit while someone is in the safety zone.
    SecTurnVel = 10,
    /// `disable_time`, ms: standstill time before the brakes close.
    DisableTime = 11,
    /// `volt_time`, ms: battery frame period.
    VoltTime = 12,
    /// `weight_time`, ms: weight frame period.
    WeightTime = 13,
    /// `PS_afk_time`, ms: the remote is switched off after this long without input.
    PsAfkTime = 14,
    /// `loop_end_delay`, ms: control and odometry period.
    LoopEndDelay = 15,
    /// `f_cw`, 1/10000: clockwise rotation correction.
    FCw = 16,
    /// `f_ccw`, 1/10000: counter-clockwise rotation correction.
    FCcw = 17,
    /// `f_lin`, 1/10000: linear correction.
    FLin = 18,
    /// `weight_offset`, raw: scale reading with nothing on it.
    WeightOffset = 19,
    /// `scale_value`, 1/100: raw counts per gram × 100.
    ScaleValue = 20,
    /// `heartbeat_time`, ms: the PC counts as off after this long without heartbeat.
    HeartbeatTime = 21,
    /// `start_PC`, ms: button hold time that switches the PC on.
    StartPc = 22,
    /// `shutdown_PC`, ms: button hold time that switches the PC off.
    ShutdownPc = 23,
    /// (ext) `gear_ratio`, 1/100: motor revolutions per wheel revolution × 100.
    GearRatio = 24,
    /// (ext) `enable_timeout`, ms: the CAN enable (0x2E4) lapses after this long.
    EnableTimeout = 25,
    /// (ext) `estop_decel`, (1/min)/s: deceleration of the emergency stop.
    EstopDecel = 26,
    /// (ext) `cmd_timeout`, ms: CAN velocity staleness timeout, 0 = off.
    CmdTimeout = 27,
    /// (ext) `motor_dir`, bit mask: [`MOTOR_DIR_INVERT_LEFT`], [`MOTOR_DIR_INVERT_RIGHT`].
    MotorDir = 28,
    /// (ext) `batt_empty_mv`, mV: battery voltage that reads 0 %.
    BattEmptyMv = 29,
    /// (ext) `batt_full_mv`, mV: battery voltage that reads 100 %.
    BattFullMv = 30,
    /// (ext) `status_time`, ms: status frame period, 0 = off.
    StatusTime = 31,
    /// (ext) `pc_boot_grace`, s: a PC just switched on counts as on this long.
    PcBootGrace = 32,
    /// (ext) `pc_switch_pulse`, ms: how long the PC power switch is closed.
    PcSwitchPulse = 33,
    /// (ext) `remote_kind`, read-only: the connected remote
    /// ([`super::RemoteKind`]: 0 none, 1 BLE pad, 2 DualShock 4, 3 DualSense).
    RemoteKind = 34,
    /// (ext) `remote_battery`, read-only: the remote's battery
    /// ([`super::RemoteBattery`]: level in bits 0–7, charge state in 8–15; 0 unknown).
    RemoteBattery = 35,
    /// (ext) `bluetooth_off`, read-only: [`BLUETOOTH_OFF_AFTER_PANICS`] while the
    /// Bluetooth remote is off after a panic loop ([`crate::panic_loop`]),
    /// [`BLE_OFF_AFTER_HOST_STOPS`] while the BLE host stays stopped;
    /// [`BLUETOOTH_ON_KEY`] to `command` or a confirm press turns it on.
    BluetoothOff = 36,
    /// (ext) `fw_version`, read-only: `(major << 8) | minor`.
    FwVersion = 38,
    /// (ext) `regmap_version`, read-only: version of this register map.
    RegmapVersion = 39,
    /// (ext) `command`, write-only, reads 0: [`RESTORE_DEFAULTS_KEY`] restores defaults,
    /// [`OPEN_PAIRING_WINDOW_KEY`] opens the Bluetooth remote's pairing window,
    /// [`BLUETOOTH_ON_KEY`] turns Bluetooth on after a panic loop.
    Command = 40,
    /// (ext) `weight_offset_hi`, raw: bits 16–23 of the full 24-bit scale offset.
    WeightOffsetHi = 44,
    /// (ext) `weight_offset_lo`, raw: bits 0–15 of the full 24-bit scale offset.
    WeightOffsetLo = 45,
    /// (ext) `flash_erases_hi`, read-only counter: register-store page erases, high word.
    FlashErasesHi = 46,
    /// (ext) `flash_erases_lo`, read-only counter: register-store page erases, low word.
    FlashErasesLo = 47,
    /// (ext) `can_tx_dropped`, read-only counter: CAN frames dropped with a full
    /// transmit queue since boot, saturating at 65535.
    CanTxDropped = 43,
    /// (ext) `stop_decel`, (1/min)/s: the gentlest any stop but the e-stop may brake.
    StopDecel = 48,
    /// (ext) `sec_motor_vel`, 1/min: motor speed limit while someone is in the safety zone.
    SecMotorVel = 49,
    /// (ext) `boot_info`, read-only bits: how this boot came about
    /// ([`super::BootInfo`]): a first boot, an update's activation, a failed trial.
    BootInfo = 50,
}

impl Reg {
    /// Every register, in address order.
    pub const ALL: [Reg; 48] = [
        Reg::RadR,
        Reg::RadL,
        Reg::WheelDist,
        Reg::CanAccel,
        Reg::ContrAccNorm,
        Reg::ContrAccHigh,
        Reg::MaxMotorVel,
        Reg::PsAbsMaxVel,
        Reg::PsRelMaxVel,
        Reg::SecLinVel,
        Reg::SecTurnVel,
        Reg::DisableTime,
        Reg::VoltTime,
        Reg::WeightTime,
        Reg::PsAfkTime,
        Reg::LoopEndDelay,
        Reg::FCw,
        Reg::FCcw,
        Reg::FLin,
        Reg::WeightOffset,
        Reg::ScaleValue,
        Reg::HeartbeatTime,
        Reg::StartPc,
        Reg::ShutdownPc,
        Reg::GearRatio,
        Reg::EnableTimeout,
        Reg::EstopDecel,
        Reg::CmdTimeout,
        Reg::MotorDir,
        Reg::BattEmptyMv,
        Reg::BattFullMv,
        Reg::StatusTime,
        Reg::PcBootGrace,
        Reg::PcSwitchPulse,
        Reg::RemoteKind,
        Reg::RemoteBattery,
        Reg::BluetoothOff,
        Reg::FwVersion,
        Reg::RegmapVersion,
        Reg::Command,
        Reg::CanTxDropped,
        Reg::WeightOffsetHi,
        Reg::WeightOffsetLo,
        Reg::FlashErasesHi,
        Reg::FlashErasesLo,
        Reg::StopDecel,
        Reg::SecMotorVel,
        Reg::BootInfo,
    ];

    /// The read-only values the firmware sets ([`super::Registers::set_counter`]): the
    /// counters, Bluetooth's state and the boot's bits. Nothing persists them.
    pub const COUNTERS: [Reg; 5] = [
        Reg::FlashErasesHi,
        Reg::FlashErasesLo,
        Reg::CanTxDropped,
        Reg::BluetoothOff,
        Reg::BootInfo,
    ];

    /// The register at a CAN address, or `None` for an unassigned one.
    pub const fn from_address(address: u8) -> Option<Reg> {
        let mut i = 0;
        while i < Reg::ALL.len() {
            if Reg::ALL[i] as u8 == address {
                return Some(Reg::ALL[i]);
            }
            i += 1;
        }
        None
    }

    pub const fn address(self) -> u8 {
        self as u8
    }

    pub fn info(self) -> &'static RegisterInfo {
        &TABLE[self.table_index()]
    }

    /// Position in [`TABLE`] (and in [`Reg::ALL`]), which skip the unassigned addresses.
    pub(super) const fn table_index(self) -> usize {
        let mut i = 0;
        while i < Reg::ALL.len() {
            if Reg::ALL[i] as u8 == self as u8 {
                return i;
            }
            i += 1;
        }
        unreachable!()
    }

    /// Whether the register changes how the wheels move for a given command: the
    /// geometry, the gear ratio, the motor directions, the speed limits and the
    /// safety-zone limits. The controller accepts a new value only while the base
    /// stands (`RegisterError::NotAtRest` otherwise), and so restores the defaults.
    pub const fn changes_motion(self) -> bool {
        matches!(
            self,
            Reg::RadR
                | Reg::RadL
                | Reg::WheelDist
                | Reg::MaxMotorVel
                | Reg::SecLinVel
                | Reg::SecTurnVel
                | Reg::GearRatio
                | Reg::MotorDir
                | Reg::SecMotorVel
        )
    }

    /// Whether the register shapes how a stop happens: when the base must stop
    /// (`enable_timeout`, `cmd_timeout`) and how hard it brakes (`estop_decel`,
    /// `stop_decel`, `Contr_acc_high`). Like the motion registers, a new value is
    /// accepted only while the base stands: a stop that is already under way, or due,
    /// keeps the rules it started with, so no write can stretch it (an `estop_decel`
    /// of 100 written at 500 mm/s would make the next e-stop roll 3.4 s).
    pub const fn shapes_stop(self) -> bool {
        matches!(
            self,
            Reg::EnableTimeout
                | Reg::CmdTimeout
                | Reg::EstopDecel
                | Reg::StopDecel
                | Reg::ContrAccHigh
        )
    }

    /// Whether a new value is accepted only while the base stands
    /// ([`Self::changes_motion`] or [`Self::shapes_stop`]).
    pub const fn needs_standstill(self) -> bool {
        self.changes_motion() || self.shapes_stop()
    }
}

/// The highest address whose name, default and meaning the manual fixes. Records of
/// these survive any schema change; everything above is ours and may be redefined.
pub const LAST_MANUAL_ADDRESS: u8 = 23;
/// One past the highest address; the size of an array indexed by address.
pub const ADDRESS_COUNT: usize = 51;

/// Writing this to [`Reg::Command`] restores every writable register to its default.
/// A key rather than 1 so that a stray or mistyped write cannot wipe a calibration.
pub const RESTORE_DEFAULTS_KEY: u16 = 0xDEF0;

/// Writing this to [`Reg::Command`] opens the Bluetooth remote's pairing window
/// ([`crate::remote::PairingWindow`]): the deliberate act on the robot without which no
/// new gamepad is bonded. A key, like [`RESTORE_DEFAULTS_KEY`], so that no stray write
/// lets a stranger's pad in.
pub const OPEN_PAIRING_WINDOW_KEY: u16 = 0xB1E0;

/// Writing this to [`Reg::Command`] turns the Bluetooth remote on again after a panic
/// loop or the BLE host's stops switched it off ([`Reg::BluetoothOff`]); with
/// Bluetooth on it changes nothing.
pub const BLUETOOTH_ON_KEY: u16 = 0xB1E1;

/// [`Reg::BluetoothOff`]: three panics in a row, each soon after its boot, left the
/// whole Bluetooth remote off (no task touches the radio).
pub const BLUETOOTH_OFF_AFTER_PANICS: u16 = 1;
/// [`Reg::BluetoothOff`]: the BLE host stopped three times within a minute and is not
/// started again; BLE pads cannot connect, a PlayStation pad still can.
pub const BLE_OFF_AFTER_HOST_STOPS: u16 = 2;

/// [`Reg::MotorDir`] bit: invert the left motor's direction.
pub const MOTOR_DIR_INVERT_LEFT: u16 = 0b01;
/// [`Reg::MotorDir`] bit: invert the right motor's direction.
pub const MOTOR_DIR_INVERT_RIGHT: u16 = 0b10;

/// Version of the register map ([`Reg::RegmapVersion`]). Bump it when an extension
/// register is added, removed or changes meaning, so PC software can tell.
/// 1: the first map. 2: `command` also takes [`OPEN_PAIRING_WINDOW_KEY`]. 3: the CAN
/// transmit drops (43), the full 24-bit scale offset (44, 45), the store's erase count
/// (46, 47), `stop_decel` (48) and `sec_motor_vel` (49); motion registers only at
/// standstill. 4: the remote's kind (34) and battery (35), `bluetooth_off` (36),
/// [`BLUETOOTH_ON_KEY`] and `boot_info` (50).
pub const REGMAP_VERSION: u16 = 4;

/// [`Reg::FwVersion`]: `(major << 8) | minor` of the crate version, fixed at compile time.
pub const FW_VERSION: u16 = ((parse_version_part(env!("CARGO_PKG_VERSION_MAJOR")) as u16) << 8)
    | parse_version_part(env!("CARGO_PKG_VERSION_MINOR")) as u16;

/// Parses one decimal version component; a component that does not fit a byte stops
/// the build (this runs only in const evaluation).
const fn parse_version_part(digits: &str) -> u8 {
    let bytes = digits.as_bytes();
    assert!(!bytes.is_empty(), "empty version component");
    let mut value: u16 = 0;
    let mut i = 0;
    while i < bytes.len() {
        assert!(
            bytes[i].is_ascii_digit(),
            "version component is not a number"
        );
        value = value * 10 + (bytes[i] - b'0') as u16;
        assert!(
            value <= 255,
            "version component does not fit the fw_version byte"
        );
        i += 1;
    }
    value as u8
}

/// Who may read and write a register over CAN.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// Readable, writable, persisted in flash.
    ReadWrite,
    /// A value built into the firmware; writes are rejected, nothing is persisted.
    ReadOnly,
    /// A command: reads 0, a write triggers an action, nothing is persisted.
    WriteOnly,
}

/// What one register is and which values it accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RegisterInfo {
    pub address: u8,
    /// The manual's name (`rad_r`, `CAN_accel`), or ours for an extension.
    pub name: &'static str,
    pub unit: &'static str,
    /// The value after a blank boot or a restore; for a read-only register its fixed
    /// value; `command` reads 0.
    pub default: u16,
    /// Smallest accepted value (apart from 0 when `zero_is_off`). For `command`, its
    /// smallest key: it accepts only its keys, nothing between them.
    pub min: u16,
    /// Largest accepted value; for `command`, its largest key.
    pub max: u16,
    /// 0 is accepted too and switches the function off ("0 = off or min..=max").
    pub zero_is_off: bool,
    pub access: Access,
    pub description: &'static str,
    /// An extension of this firmware, not in the manual.
    pub extension: bool,
}

impl RegisterInfo {
    /// Whether a write of `value` passes this register's own range (cross-register
    /// rules are checked separately).
    pub const fn accepts(&self, value: u16) -> bool {
        match self.access {
            Access::WriteOnly => matches!(
                value,
                RESTORE_DEFAULTS_KEY | OPEN_PAIRING_WINDOW_KEY | BLUETOOTH_ON_KEY
            ),
            Access::ReadWrite | Access::ReadOnly => {
                (self.zero_is_off && value == 0) || (value >= self.min && value <= self.max)
            }
        }
    }
}

/// Builds a table row; `extension` follows from the address.
const fn row(
    reg: Reg,
    name: &'static str,
    unit: &'static str,
    default: u16,
    (min, max): (u16, u16),
    access: Access,
    description: &'static str,
) -> RegisterInfo {
    RegisterInfo {
        address: reg as u8,
        name,
        unit,
        default,
        min,
        max,
        zero_is_off: false,
        access,
        description,
        extension: reg as u8 > LAST_MANUAL_ADDRESS,
    }
}

/// The same row, with 0 accepted as "off".
const fn or_off(mut info: RegisterInfo) -> RegisterInfo {
    info.zero_is_off = true;
    info
}

use super::BootInfo;
use super::remote_info::{RemoteBattery, RemoteKind};
use Access::{ReadOnly, ReadWrite, WriteOnly};

/// Every register in address order (37 and 41–42 are not assigned). Why each range is what it
/// is: `docs/registers.md`.
#[rustfmt::skip]
pub static TABLE: [RegisterInfo; 48] = [
    row(Reg::RadR, "rad_r", "mm", 142, (10, 1000), ReadWrite, "right wheel radius"),
    row(Reg::RadL, "rad_l", "mm", 142, (10, 1000), ReadWrite, "left wheel radius"),
    row(Reg::WheelDist, "wheel_dist", "mm", 250, (50, 2000), ReadWrite, "distance between the wheels"),
    row(Reg::CanAccel, "CAN_accel", "(1/min)/s", 700, (1, 30000), ReadWrite, "acceleration under CAN control"),
    row(Reg::ContrAccNorm, "Contr_acc_norm", "(1/min)/s", 350, (1, 30000), ReadWrite, "acceleration under remote control"),
    row(Reg::ContrAccHigh, "Contr_acc_high", "(1/min)/s", 500, (1, 30000), ReadWrite, "braking when the remote's enable (dead-man) is released"),
    row(Reg::MaxMotorVel, "max_motor_vel", "1/min", 900, (1, 4000), ReadWrite, "motor speed limit"),
    row(Reg::PsAbsMaxVel, "PS_abs_max_vel", "mm/s", 1200, (50, 5000), ReadWrite, "highest speed level the remote can select"),
    row(Reg::PsRelMaxVel, "PS_rel_max_vel", "mm/s", 250, (50, 5000), ReadWrite, "remote's full-stick speed level after boot"),
    row(Reg::SecLinVel, "sec_lin_vel", "mm/s", 200, (0, 1000), ReadWrite, "linear limit while someone is in the safety zone (0 = stand still)"),
    row(Reg::SecTurnVel, "sec_turn_vel", "mrad/s", 100, (0, 1000), ReadWrite, "rotation limit while someone is in the safety zone (0 = stand still)"),
    row(Reg::DisableTime, "disable_time", "ms", 300, (0, 10000), ReadWrite, "standstill time before the brakes close (0 = at once)"),
    row(Reg::VoltTime, "volt_time", "ms", 5000, (100, 60000), ReadWrite, "battery frame period"),
    row(Reg::WeightTime, "weight_time", "ms", 1000, (100, 60000), ReadWrite, "weight frame period"),
    row(Reg::PsAfkTime, "PS_afk_time", "ms", 30000, (5000, 65535), ReadWrite, "remote switched off after this long without input"),
    row(Reg::LoopEndDelay, "loop_end_delay", "ms", 50, (10, 1000), ReadWrite, "control/odometry period"),
    row(Reg::FCw, "f_cw", "1/10000", 9938, (5000, 15000), ReadWrite, "clockwise rotation correction"),
    row(Reg::FCcw, "f_ccw", "1/10000", 9894, (5000, 15000), ReadWrite, "counter-clockwise rotation correction"),
    row(Reg::FLin, "f_lin", "1/10000", 10071, (5000, 15000), ReadWrite, "linear correction"),
    row(Reg::WeightOffset, "weight_offset", "raw", 20490, (0, 65535), ReadWrite, "scale reading with nothing on it"),
    row(Reg::ScaleValue, "scale_value", "1/100", 1900, (1, 65535), ReadWrite, "raw counts per gram × 100"),
    row(Reg::HeartbeatTime, "heartbeat_time", "ms", 5000, (2000, 60000), ReadWrite, "PC counted off after this long without heartbeat"),
    row(Reg::StartPc, "start_PC", "ms", 3000, (1000, 30000), ReadWrite, "button hold time to switch the PC on"),
    row(Reg::ShutdownPc, "shutdown_PC", "ms", 8000, (1000, 30000), ReadWrite, "button hold time to switch the PC off"),
    row(Reg::GearRatio, "gear_ratio", "1/100", 1000, (100, 10000), ReadWrite, "motor revolutions per wheel revolution × 100"),
    row(Reg::EnableTimeout, "enable_timeout", "ms", 500, (50, 5000), ReadWrite, "CAN enable (0x2E4) lapses after this long"),
    row(Reg::EstopDecel, "estop_decel", "(1/min)/s", 4500, (100, 30000), ReadWrite, "deceleration of the emergency stop"),
    or_off(row(Reg::CmdTimeout, "cmd_timeout", "ms", 0, (50, 10000), ReadWrite, "CAN velocity counts as stale after this long (0 = off)")),
    row(Reg::MotorDir, "motor_dir", "bit mask", 2, (0, 3), ReadWrite, "bit0 inverts the left motor, bit1 the right motor"),
    row(Reg::BattEmptyMv, "batt_empty_mv", "mV", 21000, (5000, 60000), ReadWrite, "battery voltage shown as 0 %"),
    row(Reg::BattFullMv, "batt_full_mv", "mV", 25500, (5000, 60000), ReadWrite, "battery voltage shown as 100 %"),
    or_off(row(Reg::StatusTime, "status_time", "ms", 1000, (100, 60000), ReadWrite, "status frame period (0 = off)")),
    row(Reg::PcBootGrace, "pc_boot_grace", "s", 120, (10, 600), ReadWrite, "a PC switched on counts as on this long before its first heartbeat"),
    row(Reg::PcSwitchPulse, "pc_switch_pulse", "ms", 500, (50, 2000), ReadWrite, "how long the PC power switch is closed"),
    row(Reg::RemoteKind, "remote_kind", "kind", 0, (0, RemoteKind::MAX_CODE), ReadOnly, "the connected remote: 0 none, 1 BLE pad, 2 DualShock 4, 3 DualSense"),
    row(Reg::RemoteBattery, "remote_battery", "state<<8 | %", 0, (0, RemoteBattery::MAX_REGISTER), ReadOnly, "the remote's battery: bits 0-7 percent, bits 8-15 1 level only, 2 discharging, 3 charging, 4 full, 5 fault; 0 unknown"),
    row(Reg::BluetoothOff, "bluetooth_off", "state", 0, (0, BLE_OFF_AFTER_HOST_STOPS), ReadOnly, "1: Bluetooth is off after 3 panics each within 30 s of boot; 2: the BLE host stopped 3 times within a minute (BLE pads off); 0xB1E1 to command or a confirm press turns it on"),
    row(Reg::FwVersion, "fw_version", "major.minor", FW_VERSION, (FW_VERSION, FW_VERSION), ReadOnly, "firmware version"),
    row(Reg::RegmapVersion, "regmap_version", "", REGMAP_VERSION, (REGMAP_VERSION, REGMAP_VERSION), ReadOnly, "register map version"),
    row(Reg::Command, "command", "key", 0, (OPEN_PAIRING_WINDOW_KEY, RESTORE_DEFAULTS_KEY), WriteOnly, "0xDEF0 restores every writable register to its default; 0xB1E0 opens the remote's pairing window; 0xB1E1 turns Bluetooth on after a panic loop"),
    row(Reg::CanTxDropped, "can_tx_dropped", "frames", 0, (0, 65535), ReadOnly, "CAN frames dropped with a full transmit queue since boot (saturates)"),
    row(Reg::WeightOffsetHi, "weight_offset_hi", "raw", 0, (0, 255), ReadWrite, "bits 16-23 of the full scale offset (24-bit two's complement)"),
    row(Reg::WeightOffsetLo, "weight_offset_lo", "raw", 20490, (0, 65535), ReadWrite, "bits 0-15 of the full scale offset"),
    row(Reg::FlashErasesHi, "flash_erases_hi", "erases", 0, (0, 65535), ReadOnly, "register-store page erases so far, high word"),
    row(Reg::FlashErasesLo, "flash_erases_lo", "erases", 0, (0, 65535), ReadOnly, "register-store page erases so far, low word"),
    row(Reg::StopDecel, "stop_decel", "(1/min)/s", 2000, (2000, 30000), ReadWrite, "the gentlest braking of any stop but the e-stop (lapse, cmd_timeout, dead-man release, link loss)"),
    row(Reg::SecMotorVel, "sec_motor_vel", "1/min", 150, (0, 4000), ReadWrite, "motor speed limit while someone is in the safety zone (0 = stand still)"),
    row(Reg::BootInfo, "boot_info", "bits", 0, (0, BootInfo::ALL_BITS), ReadOnly, "bit0 first boot (blank store, defaults written), bit1 started by an update's activation, bit2 the last reset ended a failed trial (rolled back), bit3 the bootloader refused the activated image and the previous one runs, bit4 held: an image nobody confirmed runs with no rollback possible, motion locked until CONFIRM or ROLLBACK"),
];

/// The description of the register at `address`, or `None` if it is not assigned.
pub fn info(address: u8) -> Option<&'static RegisterInfo> {
    Reg::from_address(address).map(Reg::info)
}
