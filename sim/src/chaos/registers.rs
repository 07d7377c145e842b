//! What the tester knows of the controller's registers, from the frames it saw: for
//! each register the values that may be in force now and the ones a reboot may bring
//! back. The defaults and the registers a calibration touches are docs/registers.md's.

use std::collections::BTreeSet;

/// Register defaults as docs/registers.md lists them (address, default), for the
/// registers the tester follows: every plain read-write register but those the
/// calibrations change (16–20, 44, 45).
pub const FOLLOWED: [(u8, u16); 32] = [
    (0, 142),
    (1, 142),
    (2, 250),
    (3, 700),
    (4, 350),
    (5, 500),
    (6, 900),
    (7, 1200),
    (8, 250),
    (9, 200),
    (10, 100),
    (11, 300),
    (12, 5000),
    (13, 1000),
    (14, 30000),
    (15, 50),
    (21, 5000),
    (22, 3000),
    (23, 8000),
    (24, 1000),
    (25, 500),
    (26, 4500),
    (27, 0),
    (28, 2),
    (29, 21000),
    (30, 25500),
    (31, 1000),
    (32, 120),
    (33, 500),
    (48, 2000),
    (49, 150),
    // `command` (40) is write-only: followed only for its keys.
    (40, 0),
];

pub mod address {
    pub const RAD_R: u8 = 0;
    pub const RAD_L: u8 = 1;
    pub const WHEEL_DIST: u8 = 2;
    pub const MAX_MOTOR_VEL: u8 = 6;
    pub const DISABLE_TIME: u8 = 11;
    pub const VOLT_TIME: u8 = 12;
    pub const WEIGHT_TIME: u8 = 13;
    pub const LOOP_END_DELAY: u8 = 15;
    pub const START_PC: u8 = 22;
    pub const GEAR_RATIO: u8 = 24;
    pub const ENABLE_TIMEOUT: u8 = 25;
    pub const ESTOP_DECEL: u8 = 26;
    pub const CMD_TIMEOUT: u8 = 27;
    pub const MOTOR_DIR: u8 = 28;
    pub const STATUS_TIME: u8 = 31;
    pub const COMMAND: u8 = 40;
    pub const STOP_DECEL: u8 = 48;
    pub const SEC_MOTOR_VEL: u8 = 49;
}

/// `command` keys (docs/registers.md).
pub const RESTORE_DEFAULTS: u16 = 0xDEF0;
pub const BLUETOOTH_ON: u16 = 0xB1E1;

fn default_of(address: u8) -> Option<u16> {
    FOLLOWED
        .iter()
        .find(|(followed, _)| *followed == address)
        .map(|(_, value)| *value)
}

/// One register as far as the frames tell.
#[derive(Debug, Clone)]
struct Known {
    /// The values that may be in force in RAM now.
    in_force: BTreeSet<u16>,
    /// The values a reboot may load from flash.
    after_reboot: BTreeSet<u16>,
    /// The last read's answer and when its request reached the controller; writes
    /// after it are in `in_force` too.
    read_at_us: Option<u64>,
}

impl Known {
    fn new(default: u16) -> Self {
        Self {
            in_force: BTreeSet::from([default]),
            after_reboot: BTreeSet::from([default]),
            read_at_us: None,
        }
    }
}

/// A read after a reboot that brought back a value nobody wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LostValue {
    pub address: u8,
    pub read: u16,
    pub expected: Vec<u16>,
}

/// The tester's knowledge of the registers.
#[derive(Debug, Clone)]
pub struct Registers {
    known: Vec<(u8, Known)>,
    /// Writes since the last status frame that said nothing waits for the flash, so
    /// the frame that says so next is taken as their persistence only if it was built
    /// after them.
    last_write_us: u64,
    /// Reads of this boot not yet checked against the reboot's expectations: the first
    /// status frame says whether a flash fault excuses a loss.
    unchecked_after_boot: Vec<LostValue>,
    /// Registers read since this boot started (their first read is checked).
    read_this_boot: BTreeSet<u8>,
}

impl Default for Registers {
    fn default() -> Self {
        Self {
            known: FOLLOWED
                .iter()
                .map(|&(address, default)| (address, Known::new(default)))
                .collect(),
            last_write_us: 0,
            unchecked_after_boot: Vec::new(),
            read_this_boot: BTreeSet::new(),
        }
    }
}

impl Registers {
    fn get_mut(&mut self, address: u8) -> Option<&mut Known> {
        self.known
            .iter_mut()
            .find(|(followed, _)| *followed == address)
            .map(|(_, known)| known)
    }

    fn get(&self, address: u8) -> Option<&Known> {
        self.known
            .iter()
            .find(|(followed, _)| *followed == address)
            .map(|(_, known)| known)
    }

    /// The largest value that may be in force.
    pub fn max(&self, address: u8) -> u16 {
        self.get(address)
            .and_then(|known| known.in_force.last().copied())
            .unwrap_or(u16::MAX)
    }

    /// The smallest value that may be in force.
    pub fn min(&self, address: u8) -> u16 {
        self.get(address)
            .and_then(|known| known.in_force.first().copied())
            .unwrap_or(0)
    }

    /// Whether the register surely holds its default.
    pub fn surely_default(&self, address: u8) -> bool {
        let default = default_of(address);
        self.get(address).is_some_and(|known| {
            known.in_force.len() == 1 && known.in_force.first().copied() == default
        })
    }

    /// A write reached the controller (accepted or not: a read tells).
    pub fn written(&mut self, at_us: u64, address: u8, value: u16) {
        self.last_write_us = at_us;
        if address == address::COMMAND {
            if value == RESTORE_DEFAULTS {
                for (address, known) in &mut self.known {
                    if let Some(default) = default_of(*address) {
                        known.in_force.insert(default);
                        known.after_reboot.insert(default);
                    }
                }
            }
            return;
        }
        if let Some(known) = self.get_mut(address) {
            known.in_force.insert(value);
            known.after_reboot.insert(value);
        }
    }

    /// A read's reply: `value` was in force when the request (which reached the
    /// controller at `asked_us`) was handled. Writes that reached it later may be in
    /// force too, so they stay possible.
    pub fn read(&mut self, asked_us: u64, address: u8, value: u16, writes_after: &[u16]) {
        let first_this_boot = self.read_this_boot.insert(address);
        let Some(known) = self.get_mut(address) else {
            return;
        };
        if first_this_boot && !known.after_reboot.contains(&value) {
            let expected = known.after_reboot.iter().copied().collect();
            self.unchecked_after_boot.push(LostValue {
                address,
                read: value,
                expected,
            });
        }
        let Some(known) = self.get_mut(address) else {
            return;
        };
        known.in_force = writes_after.iter().copied().collect();
        known.in_force.insert(value);
        known.read_at_us = Some(asked_us);
    }

    /// A status frame built at `built_us` says nothing waits for the flash: the
    /// values in force then are what a reboot brings back.
    pub fn persisted(&mut self, built_us: u64) {
        if built_us <= self.last_write_us {
            return;
        }
        for (_, known) in &mut self.known {
            known.after_reboot = known.in_force.clone();
        }
    }

    /// The controller rebooted: RAM holds what the flash gave.
    pub fn rebooted(&mut self) {
        for (_, known) in &mut self.known {
            known.in_force = known.after_reboot.clone();
            known.read_at_us = None;
        }
        self.unchecked_after_boot.clear();
        self.read_this_boot.clear();
    }

    /// The boot's first status frame came: the reads that brought back a value
    /// nobody wrote, unless the boot reported a flash fault (then the loss is not
    /// silent, and anything may hold).
    pub fn check_after_boot(&mut self, flash_fault: bool) -> Vec<LostValue> {
        let lost = std::mem::take(&mut self.unchecked_after_boot);
        if flash_fault {
            for (address, known) in &mut self.known {
                if let Some(default) = default_of(*address) {
                    known.after_reboot.insert(default);
                }
            }
            return Vec::new();
        }
        lost
    }

    /// A flash fault was reported: what the flash gives back is anyone's guess until
    /// read (a failed write may leave the old value, a damaged store the defaults).
    pub fn flash_unreliable(&mut self) {
        for (address, known) in &mut self.known {
            if let Some(default) = default_of(*address) {
                known.after_reboot.insert(default);
            }
        }
    }

    /// Whether a first read after the boot is still to be checked.
    pub fn awaiting_boot_check(&self) -> bool {
        !self.unchecked_after_boot.is_empty()
    }
}
