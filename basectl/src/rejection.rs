//! The rejection codes of the status frame (byte 4) and of register read errors, by
//! name and cause, as `docs/protocol.md` ("Rejection codes") lists them.

/// (code, name, cause) of every rejection the firmware reports.
const REJECTIONS: [(u8, &str, &str); 17] = [
    (
        0x01,
        "WrongLength",
        "a frame too short for its content, or longer than 8 bytes",
    ),
    (
        0x02,
        "BadVelocityMarker",
        "a velocity frame whose byte 4 is not 03",
    ),
    (
        0x03,
        "UnknownSubcommand",
        "the frame's first byte is not a defined sub-command",
    ),
    (0x10, "UnknownAddress", "no register at this address"),
    (0x11, "ReadOnly", "the register is read-only"),
    (
        0x12,
        "OutOfRange",
        "the value is outside the register's range",
    ),
    (
        0x13,
        "Inconsistent",
        "the value would break a cross-register rule (docs/registers.md)",
    ),
    (
        0x20,
        "EndWithoutStart",
        "an end step without its own start step running",
    ),
    (
        0x21,
        "ZeroRawValue",
        "nothing measured in the step's direction (not moved, or the wrong way)",
    ),
    (
        0x22,
        "FactorOutOfRange",
        "real / measured is outside 0.5 ... 1.5",
    ),
    (
        0x23,
        "NothingPending",
        "store (04) with no computed factor waiting",
    ),
    (0x30, "NotStarted", "scale step without start (01)"),
    (
        0x31,
        "NotTared",
        "known weight (03) before the empty reading (02)",
    ),
    (0x32, "NoReading", "the load cell gave no reading"),
    (
        0x33,
        "OffsetOutOfRange",
        "the empty reading does not fit weight_offset (0..65535)",
    ),
    (0x34, "ZeroWeight", "known weight of 0 g"),
    (
        0x35,
        "ScaleValueOutOfRange",
        "the computed scale_value does not fit 1..65535 (too steep, or the load cell reads backwards)",
    ),
];

/// The name of rejection `code`, `None` for 00 (nothing rejected) and unknown codes.
pub fn name(code: u8) -> Option<&'static str> {
    REJECTIONS
        .iter()
        .find(|(known, ..)| *known == code)
        .map(|(_, name, _)| *name)
}

/// `Name (cause)`, or the bare code for one this basectl does not know (a newer
/// firmware's).
pub fn describe(code: u8) -> String {
    match REJECTIONS.iter().find(|(known, ..)| *known == code) {
        Some((_, name, cause)) => format!("{name} ({cause})"),
        None => format!("rejection code 0x{code:02X}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use base_core::calibration::odometry::OdometryCalibrationError;
    use base_core::calibration::scale::ScaleCalibrationError;
    use base_core::can::FrameError;
    use base_core::registers::RegisterError;

    #[test]
    fn names_match_the_firmwares_codes() {
        assert_eq!(name(FrameError::WrongLength.code()), Some("WrongLength"));
        assert_eq!(
            name(FrameError::UnknownSubcommand.code()),
            Some("UnknownSubcommand")
        );
        assert_eq!(name(RegisterError::OutOfRange.code()), Some("OutOfRange"));
        assert_eq!(
            name(RegisterError::Inconsistent.code()),
            Some("Inconsistent")
        );
        assert_eq!(
            name(OdometryCalibrationError::FactorOutOfRange.code()),
            Some("FactorOutOfRange")
        );
        assert_eq!(
            name(OdometryCalibrationError::NothingPending.code()),
            Some("NothingPending")
        );
        assert_eq!(
            name(ScaleCalibrationError::NotTared.code()),
            Some("NotTared")
        );
        assert_eq!(
            name(ScaleCalibrationError::ScaleValueOutOfRange.code()),
            Some("ScaleValueOutOfRange")
        );
    }

    #[test]
    fn an_unknown_code_is_shown_as_a_number() {
        assert_eq!(name(0x00), None);
        assert_eq!(describe(0x7A), "rejection code 0x7A");
        assert!(describe(0x22).starts_with("FactorOutOfRange ("));
    }
}
