//! The rules between registers that the base controller enforces on every write
//! (a write that would break one is refused as `Inconsistent`), by name, so that
//! basectl can say which rule a value breaks before it writes, and which rule a
//! refused write broke. They mirror the library's own rules, which it keeps private;
//! `tests::the_rules_match_the_controllers` checks them against the library's
//! register store, so a change there fails here.

use base_core::registers::Reg;

/// Motor power is cut this long after the e-stop button.
const ESTOP_POWER_CUT_MS: u32 = 300;

/// One rule between two registers.
pub struct Rule {
    pub registers: [Reg; 2],
    /// The rule as a person reads it.
    pub text: &'static str,
    pub holds: fn(&dyn Fn(Reg) -> u16) -> bool,
}

pub const RULES: [Rule; 4] = [
    Rule {
        registers: [Reg::BattEmptyMv, Reg::BattFullMv],
        text: "batt_empty_mv < batt_full_mv",
        holds: |value| value(Reg::BattEmptyMv) < value(Reg::BattFullMv),
    },
    Rule {
        registers: [Reg::StartPc, Reg::ShutdownPc],
        text: "start_PC < shutdown_PC",
        holds: |value| value(Reg::StartPc) < value(Reg::ShutdownPc),
    },
    Rule {
        registers: [Reg::PsRelMaxVel, Reg::PsAbsMaxVel],
        text: "PS_rel_max_vel <= PS_abs_max_vel",
        holds: |value| value(Reg::PsRelMaxVel) <= value(Reg::PsAbsMaxVel),
    },
    Rule {
        registers: [Reg::EstopDecel, Reg::MaxMotorVel],
        text: "estop_decel x 0.3 s >= max_motor_vel (the e-stop ramp ends before the \
               power is cut)",
        holds: |value| {
            u32::from(value(Reg::EstopDecel)) * ESTOP_POWER_CUT_MS
                >= u32::from(value(Reg::MaxMotorVel)) * 1000
        },
    },
];

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
    use base_core::registers::{RegisterError, Registers, info};

    #[test]
    fn the_rules_match_the_controllers() {
        // For each rule, values around its edge: the library's store refuses exactly
        // the writes that these rules say break it.
        for rule in &RULES {
            let [first, second] = rule.registers;
            let info_first = info(first.address()).unwrap();
            for candidate in [
                info_first.min,
                info_first.max,
                info_first.default,
                info_first.default / 2,
                info_first.default.saturating_mul(2),
            ] {
                if !info_first.accepts(candidate) {
                    continue;
                }
                let mut registers = Registers::defaults();
                let result = registers.write(first.address(), candidate);
                let value = |reg: Reg| {
                    if reg == first {
                        candidate
                    } else {
                        Registers::defaults().get(reg)
                    }
                };
                let refused = result == Err(RegisterError::Inconsistent);
                assert_eq!(
                    refused,
                    !(rule.holds)(&value),
                    "{}: {first:?} = {candidate} with {second:?} at its default",
                    rule.text
                );
            }
        }
    }

    #[test]
    fn a_register_names_the_rules_it_is_part_of() {
        assert_eq!(
            involving(Reg::BattEmptyMv.address()),
            ["batt_empty_mv < batt_full_mv"]
        );
        assert!(involving(Reg::RadR.address()).is_empty());
    }
}
