//! Every reason the controller gives for refusing an input, as one table: the code on
//! the wire (status byte 4, and a refused register read's `004#FF addr code`), a name
//! and a cause. The PC tools show these; `docs/protocol.md` (Rejection codes) lists
//! the same table, and a test holds the two together.

use crate::calibration::odometry::OdometryCalibrationError;
use crate::calibration::scale::ScaleCalibrationError;
use crate::plausibility::Finding;
use crate::registers::RegisterError;

use super::FrameError;

/// One rejection reason, whichever module gave it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rejection {
    Frame(FrameError),
    Register(RegisterError),
    OdometryCalibration(OdometryCalibrationError),
    ScaleCalibration(ScaleCalibrationError),
    /// Not a refused command: a drive's position counter stepped further than the
    /// motor can turn in the time since the previous sample, and the odometry took
    /// that sample as a new baseline. Counted and shown the same way.
    OdometryDiscontinuity,
    /// Not a refused command: a drive's position counter and reported speed disagreed,
    /// or its counter ran against its command, for two windows in a row, and the base
    /// stopped with a latched drive fault.
    Feedback(Finding),
    /// Velocity, enable or the gamepad's dead-man while a firmware update runs or a
    /// new image is on trial: refused, the base stays braked.
    UpdateInProgress,
    /// Not a refused command: the radio guard refused a pad's packet and closed its
    /// link; the remote task waits before it reaches for the pad again.
    RadioPacketRefused,
}

impl Rejection {
    /// Every reason this firmware reports, in code order.
    pub const ALL: [Rejection; 25] = [
        Rejection::Frame(FrameError::WrongLength),
        Rejection::Frame(FrameError::BadVelocityMarker),
        Rejection::Frame(FrameError::UnknownSubcommand),
        Rejection::Frame(FrameError::BadReadCount),
        Rejection::Register(RegisterError::UnknownAddress),
        Rejection::Register(RegisterError::ReadOnly),
        Rejection::Register(RegisterError::OutOfRange),
        Rejection::Register(RegisterError::Inconsistent),
        Rejection::Register(RegisterError::NotAtRest),
        Rejection::OdometryCalibration(OdometryCalibrationError::EndWithoutStart),
        Rejection::OdometryCalibration(OdometryCalibrationError::ZeroRawValue),
        Rejection::OdometryCalibration(OdometryCalibrationError::FactorOutOfRange),
        Rejection::OdometryCalibration(OdometryCalibrationError::NothingPending),
        Rejection::ScaleCalibration(ScaleCalibrationError::NotStarted),
        Rejection::ScaleCalibration(ScaleCalibrationError::NotTared),
        Rejection::ScaleCalibration(ScaleCalibrationError::NoReading),
        Rejection::ScaleCalibration(ScaleCalibrationError::OffsetOutOfRange),
        Rejection::ScaleCalibration(ScaleCalibrationError::ZeroWeight),
        Rejection::ScaleCalibration(ScaleCalibrationError::ScaleValueOutOfRange),
        Rejection::OdometryDiscontinuity,
        Rejection::Feedback(Finding::PositionStuck),
        Rejection::Feedback(Finding::SpeedStale),
        Rejection::Feedback(Finding::WrongDirection),
        Rejection::UpdateInProgress,
        Rejection::RadioPacketRefused,
    ];

    /// `None` for 0 (nothing rejected) and for codes this firmware does not define (a
    /// newer firmware's).
    pub fn from_code(code: u8) -> Option<Rejection> {
        Self::ALL.into_iter().find(|reason| reason.code() == code)
    }

    /// The stable code on the wire.
    pub fn code(self) -> u8 {
        match self {
            Rejection::Frame(error) => error.code(),
            Rejection::Register(error) => error.code(),
            Rejection::OdometryCalibration(error) => error.code(),
            Rejection::ScaleCalibration(error) => error.code(),
            Rejection::OdometryDiscontinuity => 0x40,
            Rejection::Feedback(Finding::PositionStuck) => 0x41,
            Rejection::Feedback(Finding::SpeedStale) => 0x42,
            Rejection::Feedback(Finding::WrongDirection) => 0x43,
            Rejection::UpdateInProgress => 0x50,
            Rejection::RadioPacketRefused => 0x60,
        }
    }

    /// The name the PC tools and the docs use.
    pub const fn name(self) -> &'static str {
        use OdometryCalibrationError as Odometry;
        use ScaleCalibrationError as Scale;
        match self {
            Rejection::Frame(FrameError::WrongLength) => "WrongLength",
            Rejection::Frame(FrameError::BadVelocityMarker) => "BadVelocityMarker",
            Rejection::Frame(FrameError::UnknownSubcommand) => "UnknownSubcommand",
            Rejection::Frame(FrameError::BadReadCount) => "BadReadCount",
            Rejection::Register(RegisterError::UnknownAddress) => "UnknownAddress",
            Rejection::Register(RegisterError::ReadOnly) => "ReadOnly",
            Rejection::Register(RegisterError::OutOfRange) => "OutOfRange",
            Rejection::Register(RegisterError::Inconsistent) => "Inconsistent",
            Rejection::Register(RegisterError::NotAtRest) => "NotAtRest",
            Rejection::OdometryCalibration(Odometry::EndWithoutStart) => "EndWithoutStart",
            Rejection::OdometryCalibration(Odometry::ZeroRawValue) => "ZeroRawValue",
            Rejection::OdometryCalibration(Odometry::FactorOutOfRange) => "FactorOutOfRange",
            Rejection::OdometryCalibration(Odometry::NothingPending) => "NothingPending",
            Rejection::ScaleCalibration(Scale::NotStarted) => "NotStarted",
            Rejection::ScaleCalibration(Scale::NotTared) => "NotTared",
            Rejection::ScaleCalibration(Scale::NoReading) => "NoReading",
            Rejection::ScaleCalibration(Scale::OffsetOutOfRange) => "OffsetOutOfRange",
            Rejection::ScaleCalibration(Scale::ZeroWeight) => "ZeroWeight",
            Rejection::ScaleCalibration(Scale::ScaleValueOutOfRange) => "ScaleValueOutOfRange",
            Rejection::OdometryDiscontinuity => "OdometryDiscontinuity",
            Rejection::Feedback(Finding::PositionStuck) => "PositionStuck",
            Rejection::Feedback(Finding::SpeedStale) => "SpeedStale",
            Rejection::Feedback(Finding::WrongDirection) => "WrongDirection",
            Rejection::UpdateInProgress => "UpdateInProgress",
            Rejection::RadioPacketRefused => "RadioPacketRefused",
        }
    }

    /// What the sender did wrong, in a few words.
    pub const fn cause(self) -> &'static str {
        use OdometryCalibrationError as Odometry;
        use ScaleCalibrationError as Scale;
        match self {
            Rejection::Frame(FrameError::WrongLength) => {
                "a frame too short for its content, or longer than 8 bytes"
            }
            Rejection::Frame(FrameError::BadVelocityMarker) => {
                "a velocity frame whose byte 4 is not 03"
            }
            Rejection::Frame(FrameError::UnknownSubcommand) => {
                "the frame's first byte is not a defined sub-command"
            }
            Rejection::Frame(FrameError::BadReadCount) => {
                "a bulk register read of 0 or more than 8 registers, or past address 255"
            }
            Rejection::Register(RegisterError::UnknownAddress) => "no register at this address",
            Rejection::Register(RegisterError::ReadOnly) => "the register is read-only",
            Rejection::Register(RegisterError::OutOfRange) => {
                "the value is outside the register's range"
            }
            Rejection::Register(RegisterError::Inconsistent) => {
                "the value would break a cross-register rule (docs/registers.md)"
            }
            Rejection::Register(RegisterError::NotAtRest) => {
                "a motion or stop-shaping register, or restore-defaults, while the base moves: stop first"
            }
            Rejection::OdometryCalibration(Odometry::EndWithoutStart) => {
                "an end step without its own start step running"
            }
            Rejection::OdometryCalibration(Odometry::ZeroRawValue) => {
                "nothing measured in the step's direction (not moved, or the wrong way)"
            }
            Rejection::OdometryCalibration(Odometry::FactorOutOfRange) => {
                "real / measured is outside 0.5 ... 1.5"
            }
            Rejection::OdometryCalibration(Odometry::NothingPending) => {
                "store (04) with no computed factor waiting"
            }
            Rejection::ScaleCalibration(Scale::NotStarted) => "scale step without start (01)",
            Rejection::ScaleCalibration(Scale::NotTared) => {
                "known weight (03) before the empty reading (02)"
            }
            Rejection::ScaleCalibration(Scale::NoReading) => "the load cell gave no reading",
            Rejection::ScaleCalibration(Scale::OffsetOutOfRange) => {
                "the empty reading lies outside the HX711's 24-bit range (no working load cell gives it)"
            }
            Rejection::ScaleCalibration(Scale::ZeroWeight) => "known weight of 0 g",
            Rejection::ScaleCalibration(Scale::ScaleValueOutOfRange) => {
                "the computed scale_value does not fit 1..65535 (too steep, or the load cell reads backwards)"
            }
            Rejection::OdometryDiscontinuity => {
                "a drive's position counter jumped further than the motor can turn; the odometry took it as a new baseline"
            }
            Rejection::Feedback(Finding::PositionStuck) => {
                "a drive's position counter stood or lagged while its speed said the shaft turned (stuck encoder): drive fault"
            }
            Rejection::Feedback(Finding::SpeedStale) => {
                "a drive's position counter ran while its reported speed stood or lagged (stale speed): drive fault"
            }
            Rejection::Feedback(Finding::WrongDirection) => {
                "a drive's position counter ran against the sign of its command (its direction parameter differs): drive fault"
            }
            Rejection::UpdateInProgress => {
                "velocity, enable or the gamepad while a firmware update runs or a new image is on trial"
            }
            Rejection::RadioPacketRefused => {
                "a pad sent a packet the radio guard refuses; its link was closed and the next attempt waits 1 s"
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;

    #[test]
    fn every_reason_has_its_own_code_and_name() {
        for (i, a) in Rejection::ALL.iter().enumerate() {
            assert_eq!(Rejection::from_code(a.code()), Some(*a));
            for b in &Rejection::ALL[i + 1..] {
                assert_ne!(a.code(), b.code(), "{a:?} and {b:?}");
                assert_ne!(a.name(), b.name(), "{a:?} and {b:?}");
            }
        }
        assert_eq!(Rejection::from_code(0), None);
    }

    #[test]
    fn the_table_is_the_one_in_docs_protocol() {
        let docs = include_str!("../../../docs/protocol.md");
        let section = docs
            .split("## Rejection codes")
            .nth(1)
            .expect("docs/protocol.md has a Rejection codes section");
        let documented: Vec<(u8, &str)> = section
            .lines()
            .filter_map(|line| {
                let mut cells = line.split('|').map(str::trim).skip(1);
                let code = cells.next()?.strip_prefix("0x")?;
                let name = cells.next()?;
                let code = u8::from_str_radix(code, 16).ok()?;
                (code != 0).then_some((code, name))
            })
            .collect();
        let ours: Vec<(u8, &str)> = Rejection::ALL
            .iter()
            .map(|reason| (reason.code(), reason.name()))
            .collect();
        assert_eq!(documented, ours);
    }
}
