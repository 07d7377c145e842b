//! `reg list/get/set/dump/restore`: the register table from the library, looked up by
//! name or address, values checked against the range before anything is sent.

use std::io::Write;

use base_core::registers::{
    Access, BLUETOOTH_ON_KEY, OPEN_PAIRING_WINDOW_KEY, RESTORE_DEFAULTS_KEY, Reg, RegisterInfo,
    TABLE, info,
};

use crate::base::{Base, Error};
use crate::{rejection, rules};

/// A register by its name (any case) or its address (decimal or `0x` hex).
pub fn lookup(name_or_address: &str) -> Result<&'static RegisterInfo, Error> {
    let by_name = TABLE
        .iter()
        .find(|register| register.name.eq_ignore_ascii_case(name_or_address));
    let found = by_name.or_else(|| {
        parse_number(name_or_address)
            .and_then(|n| u8::try_from(n).ok())
            .and_then(info)
    });
    found.ok_or_else(|| {
        Error::InvalidInput(format!(
            "no register {name_or_address:?} (see `basectl reg list` for names and addresses)"
        ))
    })
}

fn parse_number(text: &str) -> Option<u32> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

/// The allowed values of `register`, as a person reads them.
pub fn allowed(register: &RegisterInfo) -> String {
    match register.access {
        Access::ReadOnly => "none: the register is read-only".to_owned(),
        Access::WriteOnly => format!("only the keys 0x{RESTORE_DEFAULTS_KEY:04X} and 0xB1E0"),
        Access::ReadWrite if register.zero_is_off => {
            format!("0 (off) or {}..={}", register.min, register.max)
        }
        Access::ReadWrite => format!("{}..={}", register.min, register.max),
    }
}

/// A value for `register` from the command line, refused here with the allowed range
/// rather than by the base controller.
pub fn parse_value(register: &RegisterInfo, text: &str) -> Result<u16, Error> {
    let invalid = || {
        Error::InvalidInput(format!(
            "{text:?} is not a valid value for {} (allowed: {} {})",
            register.name,
            allowed(register),
            register.unit
        ))
    };
    let value = parse_number(text)
        .and_then(|n| u16::try_from(n).ok())
        .ok_or_else(invalid)?;
    if register.access == Access::ReadOnly || !register.accepts(value) {
        return Err(invalid());
    }
    Ok(value)
}

fn access_name(access: Access) -> &'static str {
    match access {
        Access::ReadWrite => "rw",
        Access::ReadOnly => "ro",
        Access::WriteOnly => "wo",
    }
}

pub fn list(out: &mut dyn Write) -> std::io::Result<()> {
    writeln!(
        out,
        "{:>4}  {:<16} {:<10} {:>7}  {:<20} {:<3} description",
        "addr", "name", "unit", "default", "range", "acc"
    )?;
    for register in &TABLE {
        let range = match register.access {
            Access::WriteOnly => "keys".to_owned(),
            _ if register.zero_is_off => format!("0|{}..{}", register.min, register.max),
            _ => format!("{}..{}", register.min, register.max),
        };
        writeln!(
            out,
            "{:>4}  {:<16} {:<10} {:>7}  {:<20} {:<3} {}",
            register.address,
            register.name,
            register.unit,
            register.default,
            range,
            access_name(register.access),
            register.description
        )?;
    }
    Ok(())
}

pub fn get(
    base: &mut Base,
    register: &RegisterInfo,
    json: bool,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let value = base.read_register(register.address)?;
    if json {
        writeln!(out, "{}", register_json(register, value))?;
    } else {
        writeln!(out, "{} = {value} {}", register.name, register.unit)?;
    }
    Ok(())
}

/// One register as a JSON object.
pub fn register_json(register: &RegisterInfo, value: u16) -> serde_json::Value {
    serde_json::json!({
        "name": register.name,
        "address": register.address,
        "value": value,
        "unit": register.unit,
    })
}

/// Writes `value` and reads it back. Before writing, the rules between registers are
/// checked against the controller's current values, so that a refusal names the rule
/// and the other register's value; a write the controller refuses anyway says which
/// rules the register is part of.
pub fn write_checked(base: &mut Base, register: &RegisterInfo, value: u16) -> Result<(), Error> {
    for rule in rules::RULES.iter().filter(|rule| {
        rule.registers
            .iter()
            .any(|reg| reg.address() == register.address)
    }) {
        let [first, second] = rule.registers;
        let values = base.read_registers([first, second])?;
        let value_of = |reg: Reg| {
            if reg.address() == register.address {
                value
            } else if reg == first {
                values[0]
            } else {
                values[1]
            }
        };
        if !(rule.holds)(&value_of) {
            let other = if first.address() == register.address {
                second
            } else {
                first
            };
            return Err(Error::InvalidInput(format!(
                "{value} is not a valid value for {}: it breaks the rule {} ({} is {} {})",
                register.name,
                rule.text,
                other.info().name,
                value_of(other),
                other.info().unit
            )));
        }
    }
    match base.write_and_read_back(register, value) {
        Err(Error::Refused { reason, .. }) if rejection::name(reason) == Some("Inconsistent") => {
            Err(Error::InvalidInput(format!(
                "the base controller refused writing {value} to {}: it breaks a rule between \
                 registers ({})",
                register.name,
                rules::involving(register.address).join("; ")
            )))
        }
        other => other,
    }
}

pub fn set(
    base: &mut Base,
    register: &RegisterInfo,
    value: u16,
    json: bool,
    out: &mut dyn Write,
) -> Result<(), Error> {
    if register.access == Access::WriteOnly {
        // `command` reads 0 whatever was written: there is nothing to read back.
        base.write_register(register, value)?;
        let done = match value {
            RESTORE_DEFAULTS_KEY => "every writable register is back at its default",
            OPEN_PAIRING_WINDOW_KEY => "the remote's pairing window is open",
            BLUETOOTH_ON_KEY => {
                "Bluetooth is on (the remote starts if a panic loop had switched it off)"
            }
            _ => "done",
        };
        if json {
            writeln!(
                out,
                "{}",
                serde_json::json!({"name": register.name, "key": value, "done": done})
            )?;
        } else {
            writeln!(out, "{} 0x{value:04X}: {done}", register.name)?;
        }
        return Ok(());
    }
    let old = base.read_register(register.address)?;
    write_checked(base, register, value)?;
    if json {
        let mut object = register_json(register, value);
        object["old"] = old.into();
        writeln!(out, "{object}")?;
    } else {
        writeln!(out, "{}: {old} -> {value} {}", register.name, register.unit)?;
    }
    Ok(())
}

pub fn dump(base: &mut Base, json: bool, out: &mut dyn Write) -> Result<(), Error> {
    let mut all = Vec::new();
    for register in TABLE.iter().filter(|r| r.access != Access::WriteOnly) {
        let value = base.read_register(register.address)?;
        if json {
            all.push(register_json(register, value));
        } else {
            writeln!(out, "{} = {value} {}", register.name, register.unit)?;
        }
    }
    if json {
        writeln!(out, "{}", serde_json::Value::Array(all))?;
    }
    Ok(())
}

pub fn restore(base: &mut Base, confirmed: bool, out: &mut dyn Write) -> Result<(), Error> {
    if !confirmed {
        return Err(Error::InvalidInput(
            "restoring every register to its default needs --yes".to_owned(),
        ));
    }
    base.write_register(Reg::Command.info(), RESTORE_DEFAULTS_KEY)?;
    writeln!(out, "every writable register is back at its default")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registers_are_found_by_name_in_any_case_or_by_address() {
        assert_eq!(lookup("loop_end_delay").unwrap().address, 15);
        assert_eq!(lookup("CAN_ACCEL").unwrap().address, 3);
        assert_eq!(lookup("16").unwrap().name, "f_cw");
        assert_eq!(lookup("0x13").unwrap().name, "weight_offset");
    }

    #[test]
    fn unknown_registers_and_holes_are_refused() {
        assert!(lookup("no_such_register").is_err());
        assert!(lookup("37").is_err(), "37 is kept free");
        assert_eq!(lookup("remote_battery").unwrap().address, 35);
        assert!(lookup("300").is_err());
    }

    #[test]
    fn values_outside_the_range_are_refused_with_the_range() {
        let loop_end_delay = lookup("loop_end_delay").unwrap();
        let error = parse_value(loop_end_delay, "0").unwrap_err().to_string();
        assert!(
            error.contains(&format!("{}..={}", loop_end_delay.min, loop_end_delay.max)),
            "{error}"
        );
        assert!(parse_value(loop_end_delay, "70000").is_err());
        assert!(parse_value(loop_end_delay, "-1").is_err());
        assert!(parse_value(loop_end_delay, "fast").is_err());
        assert_eq!(parse_value(loop_end_delay, "50").unwrap(), 50);
        assert_eq!(parse_value(loop_end_delay, "0x32").unwrap(), 50);
    }

    #[test]
    fn read_only_registers_take_no_value() {
        assert!(parse_value(lookup("fw_version").unwrap(), "1").is_err());
    }

    #[test]
    fn zero_means_off_where_the_register_allows_it() {
        let status_time = lookup("status_time").unwrap();
        assert_eq!(parse_value(status_time, "0").unwrap(), 0);
    }

    #[test]
    fn the_list_has_a_line_per_register() {
        let mut text = Vec::new();
        list(&mut text).unwrap();
        assert_eq!(
            String::from_utf8(text).unwrap().lines().count(),
            TABLE.len() + 1
        );
    }
}
