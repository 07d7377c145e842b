//! The rejection codes of the status frame (byte 4) and of register read errors, by
//! name and cause, from the core's one table.

use base_core::can::Rejection;

/// The name of rejection `code`, `None` for 00 (nothing rejected) and unknown codes.
pub fn name(code: u8) -> Option<&'static str> {
    Rejection::from_code(code).map(Rejection::name)
}

/// `Name (cause)`, or the bare code for one this basectl does not know (a newer
/// firmware's).
pub fn describe(code: u8) -> String {
    match Rejection::from_code(code) {
        Some(reason) => format!("{} ({})", reason.name(), reason.cause()),
        None => format!("rejection code 0x{code:02X}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_code_is_shown_with_its_name_and_cause() {
        assert_eq!(name(0x12), Some("OutOfRange"));
        assert_eq!(
            describe(0x22),
            "FactorOutOfRange (real / measured is outside 0.5 ... 1.5)"
        );
    }

    #[test]
    fn an_unknown_code_is_shown_as_a_number() {
        assert_eq!(name(0x00), None);
        assert_eq!(describe(0x7A), "rejection code 0x7A");
    }
}
