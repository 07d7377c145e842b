//! The parameter registers: their current values, validation of every write, and the
//! rebuild from flash at boot. The CAN task reads and writes them (0x003/0x004), the
//! calibrations write 16–20, the flash task persists what [`Registers::write`] reports.
//!
//! Every accepted state satisfies each register's range and these cross-register rules:
//!
//! - `batt_empty_mv < batt_full_mv` (the percentage divides by the difference);
//! - `start_PC < shutdown_PC` (one hold time must come first);
//! - `PS_rel_max_vel ≤ PS_abs_max_vel` (the boot speed level is one the remote may select);
//! - `estop_decel × 300 ms ≥ max_motor_vel`: the e-stop circuit cuts motor power about
//!   300 ms after the button, so the controlled stop must be able to finish before that.
//!
//! Changing a pair the "wrong" way round takes two writes in the right order (e.g.
//! raise `estop_decel` before `max_motor_vel`).

mod record;
mod remote_info;
pub mod saved_maps;
mod table;

pub use record::{
    RECORD_LEN, RecordError, SCHEMA_VERSION, STORE_SCHEMA, decode_record, encode_record,
    encode_store_record, migrate,
};
pub use remote_info::{Charge, RemoteBattery, RemoteInfo, RemoteKind};
pub use table::{
    ADDRESS_COUNT, Access, BLE_OFF_AFTER_HOST_STOPS, BLUETOOTH_OFF_AFTER_PANICS, BLUETOOTH_ON_KEY,
    FW_VERSION, LAST_MANUAL_ADDRESS, MOTOR_DIR_INVERT_LEFT, MOTOR_DIR_INVERT_RIGHT,
    OPEN_PAIRING_WINDOW_KEY, REGMAP_VERSION, RESTORE_DEFAULTS_KEY, Reg, RegisterInfo, TABLE, info,
};

/// Why a register read or write was refused. The code goes on CAN (register-read error
/// reply `004#FF addr code`, status frame); codes are stable and live in 0x10..=0x1F.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RegisterError {
    /// No register at this address (37, 41–42 and 51–255).
    UnknownAddress = 0x10,
    /// The register is read-only (`fw_version`, `regmap_version`, the counters and the
    /// remote's kind and battery).
    ReadOnly = 0x11,
    /// The value is outside the register's range, or not a known key for `command`.
    OutOfRange = 0x12,
    /// The value is in range but would break a cross-register rule.
    Inconsistent = 0x13,
    /// A motion or stop-shaping register ([`Reg::needs_standstill`]) or the
    /// restore-defaults key, written while the base is not standing: refused, nothing changed. The controller
    /// decides this; [`Registers::write`] itself never returns it.
    NotAtRest = 0x14,
}

impl RegisterError {
    /// The stable wire code.
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// What an accepted write means for the flash.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WriteOutcome {
    /// The register took a new value: persist this one record.
    Changed { address: u8, value: u16 },
    /// The register already held this value: nothing to write.
    Unchanged,
    /// Every writable register is back at its default: persist every record of
    /// [`Registers::iter`] (rewrite rather than erase, so the next boot finds a full
    /// store and does not report a blank one).
    DefaultsRestored,
    /// `command` got [`OPEN_PAIRING_WINDOW_KEY`]: no register changed, nothing to
    /// persist; the controller opens the pairing window.
    PairingWindowRequested,
    /// `command` got [`BLUETOOTH_ON_KEY`]: no register changed, nothing to persist; the
    /// controller turns Bluetooth on if a panic loop switched it off.
    BluetoothOnRequested,
    /// The full scale offset changed (a write of 19, 44 or 45, or a tare): persist
    /// [`Registers::weight_offset_records`], all three at once.
    OffsetChanged,
}

/// The full scale offset's range: any 24-bit two's complement HX711 reading.
pub const WEIGHT_OFFSET_RANGE: core::ops::RangeInclusive<i32> = -(1 << 23)..=(1 << 23) - 1;

/// What [`Registers::load`] made of the stored records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LoadReport {
    /// Registers that now hold a stored value (the rest hold their defaults).
    pub applied: u16,
    /// Records skipped as damaged, unknown, out of range or inconsistent.
    pub rejected: u16,
    /// Records of a newer firmware's extension registers, skipped on purpose.
    pub dropped: u16,
    /// The store held no record at all.
    pub blank: bool,
    /// The store was blank because it was erased throughout (a robot fresh from
    /// flashing), and the defaults were written to it: a first boot, not a fault.
    pub first_boot: bool,
}

impl LoadReport {
    /// Whether the status frame's flash fault bit should be set: the registers are not
    /// (all) what was stored, because a record was rejected, or the store held nothing
    /// and that was not a first boot (it could not be read, was corrupt beyond repair,
    /// or the defaults could not be written to it).
    pub fn flash_fault(&self) -> bool {
        (self.blank && !self.first_boot) || self.rejected > 0
    }
}

/// How this boot came about, for the read-only register [`Reg::BootInfo`]: set once at
/// boot, so PC tools can tell a robot fresh from flashing, or one an update just reset,
/// from one with a fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BootInfo {
    /// The register store was blank (erased throughout, fresh from flashing) and the
    /// defaults were written to it ([`LoadReport::first_boot`]).
    pub first_boot: bool,
    /// The reset before this boot was one an update caused on purpose.
    pub update_reset: UpdateReset,
}

/// A reset the firmware caused on purpose for an update, recorded before it resets so
/// that the next boot reports it as such rather than as a watchdog reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateReset {
    /// No update reset the chip (power-on, the reset pin, the watchdog, a panic).
    #[default]
    None,
    /// An update was activated: this boot starts the new image on its trial.
    Activation,
    /// A new image's trial ended without its confirm (marked invalid): this boot starts
    /// the previous image again, a rollback.
    FailedTrial,
    /// An update activated an image that the bootloader refused to load (another chip
    /// or eFuse revision, a header it rejects): the previous image runs, nothing is on
    /// trial. Read from otadata, so it is also reported after a power cycle, until the
    /// running image has set the refused entry aside.
    Refused,
    /// An image nobody confirmed runs and nothing would roll it back: its trial failed
    /// yet no other slot boots, or its arming write failed. Motion stays locked, with
    /// no deadline, until a person keeps it (CONFIRM) or tries the other slot
    /// (ROLLBACK).
    Held,
}

impl BootInfo {
    const FIRST_BOOT: u16 = 1 << 0;
    const ACTIVATION: u16 = 1 << 1;
    const FAILED_TRIAL: u16 = 1 << 2;
    const REFUSED: u16 = 1 << 3;
    const HELD: u16 = 1 << 4;
    const UPDATE_RESETS: u16 = Self::ACTIVATION | Self::FAILED_TRIAL | Self::REFUSED | Self::HELD;
    /// Every bit the register may hold: its range.
    pub const ALL_BITS: u16 = Self::FIRST_BOOT | Self::UPDATE_RESETS;

    /// The register's value.
    pub const fn to_bits(self) -> u16 {
        let first_boot = if self.first_boot { Self::FIRST_BOOT } else { 0 };
        let reset = match self.update_reset {
            UpdateReset::None => 0,
            UpdateReset::Activation => Self::ACTIVATION,
            UpdateReset::FailedTrial => Self::FAILED_TRIAL,
            UpdateReset::Refused => Self::REFUSED,
            UpdateReset::Held => Self::HELD,
        };
        first_boot | reset
    }

    /// Reads the register; `None` for bits no firmware sets (undefined bits, or both
    /// reset causes at once).
    pub const fn from_bits(bits: u16) -> Option<Self> {
        let update_reset = match bits & Self::UPDATE_RESETS {
            0 => UpdateReset::None,
            Self::ACTIVATION => UpdateReset::Activation,
            Self::FAILED_TRIAL => UpdateReset::FailedTrial,
            Self::REFUSED => UpdateReset::Refused,
            Self::HELD => UpdateReset::Held,
            _ => return None,
        };
        if bits & !Self::ALL_BITS != 0 {
            return None;
        }
        Some(Self {
            first_boot: bits & Self::FIRST_BOOT != 0,
            update_reset,
        })
    }
}

/// Motor power is cut this long after the e-stop button; see the module doc.
pub const ESTOP_POWER_CUT_MS: u32 = 300;

/// A relation between registers that every accepted state satisfies: a write that
/// would break one is refused as [`RegisterError::Inconsistent`]. Public so that PC
/// tools can say which rule a value breaks before they write it.
pub struct CrossRule {
    /// The registers the rule reads; restoring them to their defaults satisfies it.
    pub registers: [Reg; 2],
    /// The rule as a person reads it.
    pub text: &'static str,
    /// Whether the rule holds for the register values `value` gives.
    pub holds: fn(&dyn Fn(Reg) -> u16) -> bool,
}

impl CrossRule {
    fn holds_for(&self, registers: &Registers) -> bool {
        (self.holds)(&|reg| registers.get(reg))
    }
}

/// Every cross-register rule.
pub const RULES: [CrossRule; 4] = [
    CrossRule {
        registers: [Reg::BattEmptyMv, Reg::BattFullMv],
        text: "batt_empty_mv < batt_full_mv",
        holds: |value| value(Reg::BattEmptyMv) < value(Reg::BattFullMv),
    },
    CrossRule {
        registers: [Reg::StartPc, Reg::ShutdownPc],
        text: "start_PC < shutdown_PC",
        holds: |value| value(Reg::StartPc) < value(Reg::ShutdownPc),
    },
    CrossRule {
        registers: [Reg::PsRelMaxVel, Reg::PsAbsMaxVel],
        text: "PS_rel_max_vel <= PS_abs_max_vel",
        holds: |value| value(Reg::PsRelMaxVel) <= value(Reg::PsAbsMaxVel),
    },
    CrossRule {
        registers: [Reg::EstopDecel, Reg::MaxMotorVel],
        text: "estop_decel x 0.3 s >= max_motor_vel (the e-stop ramp ends before the \
               power is cut)",
        holds: |value| {
            u32::from(value(Reg::EstopDecel)) * ESTOP_POWER_CUT_MS
                >= u32::from(value(Reg::MaxMotorVel)) * 1000
        },
    },
];

/// Registers that depend on each other: the cross-register rules' pairs. The store
/// writes the members of one group that change in one batch all at once, so a power cut
/// leaves the group entirely old or entirely new (never a mix that breaks its rule).
/// The scale offset's three registers form one group too: `weight_offset` (19) is the
/// offset clamped to 16 bits, 44 and 45 hold it in full.
pub const DEPENDENT_GROUPS: [&[Reg]; RULES.len() + 1] = [
    &RULES[0].registers,
    &RULES[1].registers,
    &RULES[2].registers,
    &RULES[3].registers,
    &[Reg::WeightOffset, Reg::WeightOffsetHi, Reg::WeightOffsetLo],
];

/// The current value of every register, always inside its range and consistent.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Registers {
    /// Indexed by address; unassigned addresses and `command` stay 0.
    values: [u16; ADDRESS_COUNT],
}

impl Default for Registers {
    fn default() -> Self {
        Self::defaults()
    }
}

impl Registers {
    /// The manual's defaults, and ours for the extensions.
    pub fn defaults() -> Self {
        let mut values = [0; ADDRESS_COUNT];
        for info in &TABLE {
            values[usize::from(info.address)] = info.default;
        }
        Self { values }
    }

    pub fn get(&self, reg: Reg) -> u16 {
        self.values[usize::from(reg.address())]
    }

    /// The full scale offset: registers 44 (bits 16–23) and 45 (bits 0–15) as a 24-bit
    /// two's complement number.
    pub fn weight_offset(&self) -> i32 {
        let raw = (u32::from(self.get(Reg::WeightOffsetHi)) << 16)
            | u32::from(self.get(Reg::WeightOffsetLo));
        // Sign-extend bit 23.
        ((raw << 8) as i32) >> 8
    }

    /// Sets the full scale offset (a tare): 44 and 45 take it, `weight_offset` (19) the
    /// offset clamped to 0..=65535. [`RegisterError::OutOfRange`] outside
    /// [`WEIGHT_OFFSET_RANGE`].
    pub fn set_weight_offset(&mut self, offset: i32) -> Result<WriteOutcome, RegisterError> {
        if !WEIGHT_OFFSET_RANGE.contains(&offset) {
            return Err(RegisterError::OutOfRange);
        }
        if offset == self.weight_offset() {
            return Ok(WriteOutcome::Unchanged);
        }
        let bits = offset as u32 & 0x00FF_FFFF;
        self.values[usize::from(Reg::WeightOffsetHi.address())] = (bits >> 16) as u16;
        self.values[usize::from(Reg::WeightOffsetLo.address())] = bits as u16;
        self.values[usize::from(Reg::WeightOffset.address())] = offset.clamp(0, 0xFFFF) as u16;
        Ok(WriteOutcome::OffsetChanged)
    }

    /// The three records of the scale offset, `(address, value)`.
    pub fn weight_offset_records(&self) -> [(u8, u16); 3] {
        [Reg::WeightOffset, Reg::WeightOffsetHi, Reg::WeightOffsetLo]
            .map(|reg| (reg.address(), self.get(reg)))
    }

    /// Sets a read-only counter ([`Reg::COUNTERS`]); any other register is left alone.
    pub fn set_counter(&mut self, reg: Reg, value: u16) {
        if Reg::COUNTERS.contains(&reg) {
            self.values[usize::from(reg.address())] = value;
        }
    }

    /// Sets `remote_kind` and `remote_battery` (34, 35), the remote the Bluetooth
    /// tasks report.
    pub fn set_remote_info(&mut self, remote: RemoteInfo) {
        let (kind, battery) = remote.registers();
        self.values[usize::from(Reg::RemoteKind.address())] = kind;
        self.values[usize::from(Reg::RemoteBattery.address())] = battery;
    }

    /// What `remote_kind` and `remote_battery` hold.
    pub fn remote_info(&self) -> RemoteInfo {
        RemoteInfo::from_registers(self.get(Reg::RemoteKind), self.get(Reg::RemoteBattery))
            .unwrap_or_default()
    }

    /// A CAN register read. `command` reads 0.
    pub fn read(&self, address: u8) -> Result<u16, RegisterError> {
        let reg = Reg::from_address(address).ok_or(RegisterError::UnknownAddress)?;
        Ok(self.get(reg))
    }

    /// A CAN register write, validated against the register's range and every
    /// cross-register rule. A rejected write changes nothing.
    pub fn write(&mut self, address: u8, value: u16) -> Result<WriteOutcome, RegisterError> {
        let info = info(address).ok_or(RegisterError::UnknownAddress)?;
        if info.access == Access::ReadOnly {
            return Err(RegisterError::ReadOnly);
        }
        if !info.accepts(value) {
            return Err(RegisterError::OutOfRange);
        }
        if info.access == Access::WriteOnly {
            // `command`: `accepts` let only its keys through.
            return match value {
                RESTORE_DEFAULTS_KEY => {
                    // The remote is still connected: what the tasks reported stays;
                    // so do the firmware's own values (counters, boot_info), facts
                    // about this run rather than settings.
                    let remote = self.remote_info();
                    let kept = Reg::COUNTERS.map(|reg| (reg, self.get(reg)));
                    *self = Self::defaults();
                    self.set_remote_info(remote);
                    for (reg, value) in kept {
                        self.set_counter(reg, value);
                    }
                    Ok(WriteOutcome::DefaultsRestored)
                }
                OPEN_PAIRING_WINDOW_KEY => Ok(WriteOutcome::PairingWindowRequested),
                BLUETOOTH_ON_KEY => Ok(WriteOutcome::BluetoothOnRequested),
                _ => Err(RegisterError::OutOfRange),
            };
        }
        let index = usize::from(address);
        if self.values[index] == value {
            return Ok(WriteOutcome::Unchanged);
        }
        match Reg::from_address(address) {
            // A value other than what 19 reads sets the whole offset to it.
            Some(Reg::WeightOffset) => return self.set_weight_offset(i32::from(value)),
            Some(reg @ (Reg::WeightOffsetHi | Reg::WeightOffsetLo)) => {
                let mut words = [self.get(Reg::WeightOffsetHi), self.get(Reg::WeightOffsetLo)];
                words[usize::from(reg == Reg::WeightOffsetLo)] = value;
                let bits = (u32::from(words[0]) << 16) | u32::from(words[1]);
                return self.set_weight_offset(((bits << 8) as i32) >> 8);
            }
            _ => {}
        }
        let mut candidate = self.clone();
        candidate.values[index] = value;
        if !candidate.is_consistent() {
            return Err(RegisterError::Inconsistent);
        }
        *self = candidate;
        Ok(WriteOutcome::Changed { address, value })
    }

    /// `(address, value)` of every persistent (read-write) register, in address order:
    /// what the flash task stores.
    pub fn iter(&self) -> impl Iterator<Item = (u8, u16)> + '_ {
        TABLE
            .iter()
            .filter(|info| info.access == Access::ReadWrite)
            .map(|info| (info.address, self.values[usize::from(info.address)]))
    }

    /// Rebuilds the registers from stored records, in any order: starts from the
    /// defaults and applies each record that decodes, migrates and passes its register's
    /// range. The cross-register rules are checked once all records are in (a valid
    /// store may hold a pair that no single write order from the defaults reaches);
    /// a rule that still fails puts its registers back to their defaults.
    pub fn load<'a>(records: impl IntoIterator<Item = &'a [u8]>) -> (Registers, LoadReport) {
        let mut registers = Self::defaults();
        let mut report = LoadReport {
            blank: true,
            ..LoadReport::default()
        };
        // Bit n set: register n holds a value from the store.
        let mut from_store: u64 = 0;

        for bytes in records {
            report.blank = false;
            match decode_record(bytes) {
                Ok((address, value)) => match info(address) {
                    Some(register)
                        if register.access == Access::ReadWrite && register.accepts(value) =>
                    {
                        registers.values[usize::from(address)] = value;
                        from_store |= 1 << address;
                    }
                    _ => report.rejected = report.rejected.saturating_add(1),
                },
                Err(RecordError::NewerSchema { .. }) => {
                    report.dropped = report.dropped.saturating_add(1);
                }
                Err(_) => report.rejected = report.rejected.saturating_add(1),
            }
        }

        // The scale offset: 44 and 45 stored together hold it in full, and 19 follows
        // from them. A store from before they existed has only 19: the offset is 19's
        // value (the migration of old stores). One of 44/45 without the other is no
        // offset at all (rejected).
        let bit = |reg: Reg| 1u64 << reg.address();
        let words = bit(Reg::WeightOffsetHi) | bit(Reg::WeightOffsetLo);
        let stored_words = from_store & words;
        if stored_words == words {
            let offset = registers.weight_offset();
            registers.values[usize::from(Reg::WeightOffset.address())] =
                offset.clamp(0, 0xFFFF) as u16;
        } else {
            if stored_words != 0 {
                report.rejected = report.rejected.saturating_add(1);
                from_store &= !words;
            }
            let [high, low] = saved_maps::offset_words_from(registers.get(Reg::WeightOffset));
            registers.values[usize::from(Reg::WeightOffsetHi.address())] = high;
            registers.values[usize::from(Reg::WeightOffsetLo.address())] = low;
        }

        // Restoring a rule's registers can only break a rule sharing one of them, so
        // this settles within one pass per rule; defaults satisfy every rule.
        for _ in 0..RULES.len() {
            let mut settled = true;
            for rule in &RULES {
                if rule.holds_for(&registers) {
                    continue;
                }
                settled = false;
                for reg in rule.registers {
                    registers.values[usize::from(reg.address())] = reg.info().default;
                    let bit = 1u64 << reg.address();
                    if from_store & bit != 0 {
                        from_store &= !bit;
                        report.rejected = report.rejected.saturating_add(1);
                    }
                }
            }
            if settled {
                break;
            }
        }
        if !registers.is_consistent() {
            // Unreachable while the rules are pairs over registers that restore to
            // consistent defaults; kept so that a future rule can never let a broken
            // state through.
            report.rejected = report
                .rejected
                .saturating_add(from_store.count_ones() as u16);
            from_store = 0;
            registers = Self::defaults();
        }

        report.applied = from_store.count_ones() as u16;
        (registers, report)
    }

    fn is_consistent(&self) -> bool {
        RULES.iter().all(|rule| rule.holds_for(self))
    }
}

#[cfg(test)]
mod tests;
