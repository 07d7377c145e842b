//! Every open point of the drives' configuration as a named setting: the robot's
//! drives were configured with MEXE02 long ago, and these must match what is in them.
//! The defaults are the best guess from the drives' manual; docs/drives.md lists what
//! a commissioning engineer checks.

/// Parity of the RS-485 line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Parity {
    None,
    Even,
    Odd,
}

/// The serial line to the drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LineSettings {
    /// 9600 … 230400. BLV R ships with 230400; Panasonic's BLV R launch file and our
    /// latency goal use 115200.
    pub baud: u32,
    /// Even by default on Oriental drives (8N1 made a drive raise alarm 84h).
    pub parity: Parity,
    /// 1 by default.
    pub stop_bits: u8,
    /// The shortest silence the master keeps between two frames, µs. The frame gap is
    /// 3.5 characters and at least this. 0 (the default) trusts the drives' "C3.5
    /// silent interval" set to auto, 3.5 characters at any baud rate (0.34 ms at
    /// 115200); 1750 is the fixed gap Modbus recommends above 19200 baud, for slaves
    /// that need it (it adds 1.4 ms to every transaction at 115200, and to the
    /// latency of a command that waits for one).
    pub min_silent_interval_us: u32,
}

impl LineSettings {
    /// Start bit, 8 data bits, parity and stop bits.
    pub const fn bits_per_char(&self) -> u32 {
        let parity = match self.parity {
            Parity::None => 0,
            Parity::Even | Parity::Odd => 1,
        };
        1 + 8 + parity + self.stop_bits as u32
    }

    /// One character on the wire, µs (rounded up).
    pub const fn char_time_us(&self) -> u64 {
        (self.bits_per_char() as u64 * 1_000_000).div_ceil(self.baud as u64)
    }

    /// The Modbus-RTU frame gap: 3.5 characters, and at least `min_silent_interval_us`.
    pub const fn silent_interval_us(&self) -> u64 {
        let gap = (self.char_time_us() * 7).div_ceil(2);
        let floor = self.min_silent_interval_us as u64;
        if gap < floor { floor } else { gap }
    }
}

/// How the drives read the DDO acceleration and deceleration fields (NET-ID 48/49).
/// The unit is a drive parameter (docs/drives.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AccelUnit {
    /// (r/min)/s, as the original manual says the drives receive. The note's most
    /// plausible reading: the drives were set to this unit with MEXE02.
    RpmPerSecond,
    /// Oriental's factory unit: ms to change the speed by 1000 r/min.
    MsPer1000Rpm,
}

impl AccelUnit {
    /// The field value for an acceleration in (r/min)/s. Zero means "this wheel does
    /// not change speed"; it is sent as the gentlest representable rate so the drive
    /// never sees 0 (whose meaning is undocumented).
    pub fn field(self, rpm_per_s: u32) -> u32 {
        let rpm_per_s = rpm_per_s.max(1);
        match self {
            AccelUnit::RpmPerSecond => rpm_per_s,
            AccelUnit::MsPer1000Rpm => 1_000_000u32.div_ceil(rpm_per_s),
        }
    }
}

/// Everything the drive link needs to know about the drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveSettings {
    pub line: LineSettings,
    /// Slave address of the left drive (its DIP/rotary switch). Also local ID 1.
    pub left_slave: u8,
    /// Slave address of the right drive. Also local ID 2.
    pub right_slave: u8,
    /// The share group address (must not equal a slave address).
    pub share_group: u8,
    /// DDO operation type, written with every hold (so before every setup): 16 =
    /// continuous operation (speed control).
    pub operation_type: u32,
    pub accel_unit: AccelUnit,
    /// Wait after the drives get power before the first query (the BLH manual asks ≥ 1 s).
    pub power_up_wait_ms: u32,
    /// How often a silent drive is polled (the pause between two hold rounds), at most
    /// a third of `drive_comm_timeout_ms`.
    pub poll_interval_ms: u32,
    /// How long the master waits for the first byte of a reply, and for the next byte
    /// once a reply has started.
    pub reply_timeout_ms: u32,
    /// Consecutive failed cycles before the link declares a drive lost.
    pub failures_before_loss: u8,
    /// Time between S-ON and the first non-zero speed (Panasonic waits 50 ms).
    pub excite_settle_ms: u32,
    /// Drive-side communication watchdog (register 0x138A, alarm 85h), ms, written in
    /// every setup. When no valid frame (to any slave) crossed the line for this long,
    /// a drive raises alarm 85h and stops: the wheels stop when the controller hangs
    /// or the line breaks, without the controller. The recovery resets it like any
    /// alarm. It is what stops a drive the controller cannot reach (a line that fails
    /// the frames that carry a stop, a drive that executes nothing), so it is not
    /// optional: [`DriveSettings::check`] refuses 0 (off, the drives' factory value)
    /// and anything outside [`COMM_TIMEOUT_MS`].
    ///
    /// 150 ms by default, so that a controller that resets while the base drives at
    /// 500 mm/s lets it run on at most 75 mm before the drives stop on their own, plus
    /// their brake (about 4 mm), during a boot of 0.3 s: within the 100 mm goal. The
    /// control cycle reads the drives every `loop_end_delay` (50 ms: three reads
    /// inside the timeout) and never waits longer than a third of the timeout, whatever
    /// `loop_end_delay` says; the hold rounds outside the cycle are at most that far
    /// apart too. A flash erase at rest stalls the chip longer than this; the link
    /// resets the alarm 85h that its own stall caused (see `link`).
    pub drive_comm_timeout_ms: u16,
}

/// The drives' communication timeout the firmware accepts, ms. At most 180: a
/// controller that resets while the base drives at 500 mm/s is silent through its
/// boot (about 0.3 s), and only this timeout stops the wheels then; 180 ms keeps that
/// run-on within 100 mm (about 0.5 mm per ms, 79 mm at 150 ms). At least 100: the
/// longest quiet the control cycle leaves on the line (46 ms at 230400 baud; a failed
/// transaction is quiet for `reply_timeout_ms` and 5 ms, at most 35 ms) stays under
/// half of it, so normal operation never trips it.
pub const COMM_TIMEOUT_MS: core::ops::RangeInclusive<u16> = 100..=180;
/// Failed reads or writes in a row before the link stops blind: each one lets the
/// base run on about 50 ms (one cycle) before the drives are told to stop.
pub const FAILURES_BEFORE_LOSS: core::ops::RangeInclusive<u8> = 1..=3;
/// The reply timeout the firmware accepts, ms: long enough for the drives' longest
/// response delay (C3.5 and the factory's 3 ms transmission wait, 7 ms at 9600 baud);
/// short enough that three failed writes in a row end within a few cycles.
pub const REPLY_TIMEOUT_MS: core::ops::RangeInclusive<u32> = 10..=30;
/// The slowest line the firmware accepts, baud: below it a cycle's reads and a
/// command write no longer fit into a third of the drives' timeout, and a write that
/// fails is not tried again before the next read is due (at 9600 baud a PC's stop
/// through a line that failed long frames never got out; at 19200 the e-stop rolled
/// 360 mm).
pub const MIN_BAUD: u32 = 38_400;
/// The longest fixed frame gap the firmware accepts, µs: Modbus's own fixed value.
pub const MAX_MIN_SILENT_INTERVAL_US: u32 = 1_750;

/// A drive setting the firmware refuses, because with it a stop through a failing
/// line could come too late or never (docs/drives.md, "Settings the firmware
/// refuses").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingError {
    /// `drive_comm_timeout_ms` outside [`COMM_TIMEOUT_MS`] (0 is off).
    CommTimeout(u16),
    /// `failures_before_loss` outside [`FAILURES_BEFORE_LOSS`].
    FailuresBeforeLoss(u8),
    /// `reply_timeout_ms` outside [`REPLY_TIMEOUT_MS`].
    ReplyTimeout(u32),
    /// `line.baud` below [`MIN_BAUD`].
    Baud(u32),
    /// `line.min_silent_interval_us` above [`MAX_MIN_SILENT_INTERVAL_US`].
    MinSilentInterval(u32),
}

impl SettingError {
    /// What is wrong, for the log.
    pub const fn reason(self) -> &'static str {
        match self {
            SettingError::CommTimeout(_) => {
                "drive_comm_timeout_ms must be 100..=180: off, nothing stops a drive the line cannot reach; longer, a controller reset rolls over 100 mm"
            }
            SettingError::FailuresBeforeLoss(_) => {
                "failures_before_loss must be 1..=3: each more lets a failing line drive on another cycle"
            }
            SettingError::ReplyTimeout(_) => {
                "reply_timeout_ms must be 10..=30: shorter misses the drives' replies, longer delays the stop through a failing line"
            }
            SettingError::Baud(_) => {
                "line.baud must be at least 38400: slower, a stop through a failing line comes too late"
            }
            SettingError::MinSilentInterval(_) => {
                "line.min_silent_interval_us must be at most 1750 (Modbus's fixed gap)"
            }
        }
    }
}

impl DriveSettings {
    /// The note's assumptions: left = slave 1, right = slave 2, share group 15, 115200 8E1,
    /// acceleration in (r/min)/s.
    pub const DEFAULT: DriveSettings = DriveSettings {
        line: LineSettings {
            baud: 115_200,
            parity: Parity::Even,
            stop_bits: 1,
            min_silent_interval_us: 0,
        },
        left_slave: 1,
        right_slave: 2,
        share_group: 15,
        operation_type: 16,
        accel_unit: AccelUnit::RpmPerSecond,
        power_up_wait_ms: 1_000,
        poll_interval_ms: 200,
        reply_timeout_ms: 25,
        failures_before_loss: 3,
        excite_settle_ms: 50,
        drive_comm_timeout_ms: 150,
    };

    /// Whether the firmware accepts these settings: `Err` names the first one with
    /// which the base could not be stopped within 300 mm from 500 mm/s whatever the
    /// line does (measured in `sim/tests/drive_link_safety.rs` at the edges of every
    /// range at once). The drive link refuses to set up drives with such settings: it
    /// holds them, stopped and de-excited, and the base stays in Starting.
    pub const fn check(&self) -> Result<(), SettingError> {
        let timeout = self.drive_comm_timeout_ms;
        if timeout < *COMM_TIMEOUT_MS.start() || timeout > *COMM_TIMEOUT_MS.end() {
            return Err(SettingError::CommTimeout(timeout));
        }
        let failures = self.failures_before_loss;
        if failures < *FAILURES_BEFORE_LOSS.start() || failures > *FAILURES_BEFORE_LOSS.end() {
            return Err(SettingError::FailuresBeforeLoss(failures));
        }
        let reply = self.reply_timeout_ms;
        if reply < *REPLY_TIMEOUT_MS.start() || reply > *REPLY_TIMEOUT_MS.end() {
            return Err(SettingError::ReplyTimeout(reply));
        }
        if self.line.baud < MIN_BAUD {
            return Err(SettingError::Baud(self.line.baud));
        }
        if self.line.min_silent_interval_us > MAX_MIN_SILENT_INTERVAL_US {
            return Err(SettingError::MinSilentInterval(
                self.line.min_silent_interval_us,
            ));
        }
        Ok(())
    }
}

// The firmware's own settings pass their check, or it does not build.
const _: () = assert!(DriveSettings::DEFAULT.check().is_ok());

impl Default for DriveSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_8e1_character_at_115200_takes_96_us_and_the_gap_three_and_a_half() {
        let line = DriveSettings::DEFAULT.line;
        assert_eq!(line.bits_per_char(), 11);
        assert_eq!(line.char_time_us(), 96);
        assert_eq!(line.silent_interval_us(), 336);
        let fixed = LineSettings {
            min_silent_interval_us: 1_750,
            ..line
        };
        assert_eq!(fixed.silent_interval_us(), 1_750);
    }

    #[test]
    fn slow_lines_use_three_and_a_half_characters() {
        let line = LineSettings {
            baud: 9_600,
            parity: Parity::None,
            stop_bits: 2,
            min_silent_interval_us: 1_750,
        };
        assert_eq!(line.char_time_us(), 1_146);
        assert_eq!(line.silent_interval_us(), 4_011);
    }

    /// Every setting at the edges of its range passes; one step beyond, and off, is
    /// refused with the setting named.
    #[test]
    fn settings_that_could_keep_the_base_from_stopping_are_refused() {
        let default = DriveSettings::DEFAULT;
        type Change = fn(&mut DriveSettings);
        let with = |change: Change| {
            let mut settings = default;
            change(&mut settings);
            settings.check()
        };
        assert_eq!(default.check(), Ok(()));
        let edges: [Change; 8] = [
            |s| s.drive_comm_timeout_ms = 100,
            |s| s.drive_comm_timeout_ms = 180,
            |s| s.failures_before_loss = 1,
            |s| s.reply_timeout_ms = 10,
            |s| s.reply_timeout_ms = 30,
            |s| s.line.baud = 38_400,
            |s| s.line.baud = 230_400,
            |s| s.line.min_silent_interval_us = 1_750,
        ];
        for edge in edges {
            assert_eq!(with(edge), Ok(()));
        }
        let refused: [(Change, SettingError); 9] = [
            (
                |s| s.drive_comm_timeout_ms = 0,
                SettingError::CommTimeout(0),
            ),
            (
                |s| s.drive_comm_timeout_ms = 99,
                SettingError::CommTimeout(99),
            ),
            (
                |s| s.drive_comm_timeout_ms = 181,
                SettingError::CommTimeout(181),
            ),
            (
                |s| s.failures_before_loss = 0,
                SettingError::FailuresBeforeLoss(0),
            ),
            (
                |s| s.failures_before_loss = 4,
                SettingError::FailuresBeforeLoss(4),
            ),
            (|s| s.reply_timeout_ms = 9, SettingError::ReplyTimeout(9)),
            (|s| s.reply_timeout_ms = 31, SettingError::ReplyTimeout(31)),
            (|s| s.line.baud = 19_200, SettingError::Baud(19_200)),
            (
                |s| s.line.min_silent_interval_us = 1_751,
                SettingError::MinSilentInterval(1_751),
            ),
        ];
        for (change, error) in refused {
            assert_eq!(with(change), Err(error));
            assert!(!error.reason().is_empty());
        }
    }

    #[test]
    fn acceleration_fields_follow_the_configured_unit() {
        assert_eq!(AccelUnit::RpmPerSecond.field(700), 700);
        assert_eq!(AccelUnit::MsPer1000Rpm.field(700), 1_429);
        assert_eq!(AccelUnit::RpmPerSecond.field(0), 1);
        assert_eq!(AccelUnit::MsPer1000Rpm.field(0), 1_000_000);
    }
}
