//! The rules between registers that the base controller enforces on every write
//! (a write that would break one is refused as `Inconsistent`), by name, so that
//! basectl can say which rule a value breaks before it writes, and which rule a
//! refused write broke. They are the controller's own (`base_core::registers::RULES`).

use base_core::registers::Reg;
pub use base_core::registers::{CrossRule as Rule, RULES};

/// The rules `value` breaks.
pub fn broken(value: &dyn Fn(Reg) -> u16) -> Vec<&'static Rule> {
    RULES.iter().filter(|rule| !(rule.holds)(value)).collect()
}

/// The rules that involve the register at `address`, as text: what a refused write to
/// it may have broken.
pub fn involving(address: u8) -> Vec<&'static str> {
    RULES
        .iter()
        .filter(|rule| rule.registers.iter().any(|reg| reg.address() == address))
        .map(|rule| rule.text)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_register_names_the_rules_it_is_part_of() {
        assert_eq!(
            involving(Reg::BattEmptyMv.address()),
            ["batt_empty_mv < batt_full_mv"]
        );
        assert!(involving(Reg::RadR.address()).is_empty());
    }
}
