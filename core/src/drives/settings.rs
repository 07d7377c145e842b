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
/// The unit is a drive parameter (§5 of the note).
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
    /// every setup; `None` leaves the drives' own value (0 = off from the factory).
    /// When no valid frame (to any slave) crossed the line for this long, a drive
    /// raises alarm 85h and stops: the wheels stop when the controller hangs or the
    /// line breaks, without the controller. The recovery resets it like any alarm.
    ///
    /// 150 ms by default, so that a controller that resets while the base drives at
    /// 500 mm/s lets it run on at most 75 mm before the drives stop on their own, plus
    /// their brake (about 4 mm), during a boot of 0.3 s: within the 100 mm goal. The
    /// control cycle reads the drives every `loop_end_delay` (50 ms: three reads
    /// inside the timeout) and never waits longer than a third of the timeout, whatever
    /// `loop_end_delay` says; the hold rounds outside the cycle are at most that far
    /// apart too. A flash erase at rest stalls the chip longer than this; the link
    /// resets the alarm 85h that its own stall caused (see `link`).
    pub drive_comm_timeout_ms: Option<u16>,
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
        drive_comm_timeout_ms: Some(150),
    };
}

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

    #[test]
    fn acceleration_fields_follow_the_configured_unit() {
        assert_eq!(AccelUnit::RpmPerSecond.field(700), 700);
        assert_eq!(AccelUnit::MsPer1000Rpm.field(700), 1_429);
        assert_eq!(AccelUnit::RpmPerSecond.field(0), 1);
        assert_eq!(AccelUnit::MsPer1000Rpm.field(0), 1_000_000);
    }
}
