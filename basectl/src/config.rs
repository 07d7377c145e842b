//! `config save FILE` and `config load FILE`: every read-write register to a JSON file
//! with names, units and the firmware and register-map versions, and back.
//!
//! Loading checks everything before it writes anything: the register map the file
//! was saved from, every name, every value against its range, and the rules between
//! registers on the state the file would leave. It then shows the changes, writes
//! only those (in an order in which every step keeps the rules), and reads each back.
//!
//! ```json
//! { "basectl_config": 1, "firmware_version": "0.1", "regmap_version": 4,
//!   "registers": [ { "name": "rad_r", "address": 0, "value": 142, "unit": "mm" }, … ] }
//! ```

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use base_core::registers::saved_maps::{self, SavedMapError};
use base_core::registers::{ADDRESS_COUNT, Access, REGMAP_VERSION, Reg, RegisterInfo, TABLE};
use serde_json::{Value, json};

use crate::base::{Base, Error};
use crate::registers::{allowed, write_checked};
use crate::rules;

/// The file format's version.
pub const FORMAT: u64 = 1;

fn writable() -> impl Iterator<Item = &'static RegisterInfo> {
    TABLE
        .iter()
        .filter(|register| register.access == Access::ReadWrite)
}

/// `(major << 8) | minor` as text.
pub fn version_text(value: u16) -> String {
    format!("{}.{}", value >> 8, value & 0xFF)
}

/// The value of every read-write register, by address, in bulk reads.
fn read_writable(base: &mut Base) -> Result<BTreeMap<u8, u16>, Error> {
    let addresses: Vec<u8> = writable().map(|register| register.address).collect();
    base.read_many(&addresses)
}

/// Reads every read-write register and the versions, reads the registers once more
/// and compares, and writes the file only when both readings agree: a value another
/// program changed meanwhile is not saved.
pub fn save(base: &mut Base, path: &Path, out: &mut dyn Write) -> Result<(), Error> {
    let [firmware, regmap] = base.read_registers([Reg::FwVersion, Reg::RegmapVersion])?;
    let values = read_writable(base)?;
    let again = read_writable(base)?;
    if let Some(changed) = differences(&values, &again).first() {
        return Err(Error::Aborted(format!(
            "{changed} changed while it was being saved (another program wrote it); \
             nothing was saved, try again"
        )));
    }
    let mut registers = Vec::new();
    for register in writable() {
        let value = values[&register.address];
        registers.push(json!({
            "name": register.name,
            "address": register.address,
            "value": value,
            "unit": register.unit,
        }));
    }
    let count = registers.len();
    let document = json!({
        "basectl_config": FORMAT,
        "firmware_version": version_text(firmware),
        "regmap_version": regmap,
        "registers": registers,
    });
    let text = serde_json::to_string_pretty(&document).expect("a JSON value serializes");
    std::fs::write(path, text + "\n").map_err(|error| {
        Error::InvalidInput(format!("cannot write {}: {error}", path.display()))
    })?;
    writeln!(
        out,
        "saved {count} registers (firmware {}, register map {regmap}) to {}",
        version_text(firmware),
        path.display()
    )?;
    Ok(())
}

/// What a configuration file holds, checked against the register table.
#[derive(Debug, PartialEq, Eq)]
pub struct ConfigFile {
    pub firmware_version: Option<String>,
    pub regmap_version: u16,
    /// Address → value, for the registers the file names.
    pub values: BTreeMap<u8, u16>,
}

/// Parses and checks a file's text. The error lists every problem, each with the
/// register's name and allowed range.
pub fn parse(text: &str) -> Result<ConfigFile, Error> {
    let document: Value = serde_json::from_str(text).map_err(|error| {
        Error::InvalidInput(format!("not a basectl configuration (JSON): {error}"))
    })?;
    match document.get("basectl_config").and_then(Value::as_u64) {
        Some(FORMAT) => {}
        Some(other) => {
            return Err(Error::InvalidInput(format!(
                "configuration format {other}; this basectl reads format {FORMAT}"
            )));
        }
        None => {
            return Err(Error::InvalidInput(
                "not a basectl configuration (no \"basectl_config\": 1)".to_owned(),
            ));
        }
    }
    let regmap_version = document
        .get("regmap_version")
        .and_then(Value::as_u64)
        .and_then(|version| u16::try_from(version).ok())
        .ok_or_else(|| Error::InvalidInput("the file names no \"regmap_version\"".to_owned()))?;
    let firmware_version = document
        .get("firmware_version")
        .and_then(Value::as_str)
        .map(str::to_owned);
    let entries = document
        .get("registers")
        .and_then(Value::as_array)
        .ok_or_else(|| Error::InvalidInput("the file has no \"registers\" list".to_owned()))?;
    let mut problems = Vec::new();
    let mut values = BTreeMap::new();
    for (index, entry) in entries.iter().enumerate() {
        let Some(name) = entry.get("name").and_then(Value::as_str) else {
            problems.push(format!("entry {index}: no \"name\""));
            continue;
        };
        let Some(register) = TABLE.iter().find(|register| register.name == name) else {
            problems.push(format!("{name}: no such register"));
            continue;
        };
        if register.access != Access::ReadWrite {
            problems.push(format!("{name}: not writable ({})", allowed(register)));
            continue;
        }
        if let Some(address) = entry.get("address")
            && address.as_u64() != Some(u64::from(register.address))
        {
            problems.push(format!(
                "{name}: address {address} in the file, but {name} is register {}",
                register.address
            ));
            continue;
        }
        let value = entry.get("value").and_then(Value::as_u64);
        match value.and_then(|value| u16::try_from(value).ok()) {
            Some(value) if register.accepts(value) => {
                if values.insert(register.address, value).is_some() {
                    problems.push(format!("{name}: named twice"));
                }
            }
            _ => problems.push(format!(
                "{name}: value {} is outside the range (allowed: {} {})",
                entry
                    .get("value")
                    .map_or("missing".to_owned(), Value::to_string),
                allowed(register),
                register.unit
            )),
        }
    }
    if !problems.is_empty() {
        return Err(Error::InvalidInput(format!(
            "the configuration is refused, nothing was written:\n  {}",
            problems.join("\n  ")
        )));
    }
    Ok(ConfigFile {
        firmware_version,
        regmap_version,
        values,
    })
}

/// Brings a file saved under an older register map to `controller_map`, today's
/// (`saved_maps` in the core says what differs between maps), and says what it did.
/// Refused: a file from a newer map, and any other map than the controller's when the
/// controller's is not the one this basectl knows.
pub fn bring_to_map(
    file: &mut ConfigFile,
    controller_map: u16,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let saved_map = file.regmap_version;
    if saved_map == controller_map {
        return Ok(());
    }
    let refused = |why: &str| {
        Error::InvalidInput(format!(
            "the file was saved from register map {saved_map}, the controller has register \
             map {controller_map}: {why}; nothing was written"
        ))
    };
    if controller_map != REGMAP_VERSION {
        return Err(refused(&format!(
            "this basectl knows register map {REGMAP_VERSION} only"
        )));
    }
    let mut values = [None; ADDRESS_COUNT];
    for (&address, &value) in &file.values {
        values[usize::from(address)] = Some(value);
    }
    let upgrade = saved_maps::upgrade(saved_map, &mut values).map_err(|error| match error {
        SavedMapError::NoSuchMap => refused("there is no register map 0"),
        SavedMapError::Newer(_) => refused("a newer map's registers may mean what it cannot know"),
    })?;
    file.values = (0..)
        .zip(values)
        .filter_map(|(address, value)| Some((address, value?)))
        .collect();
    file.regmap_version = controller_map;
    writeln!(
        out,
        "the file was saved from register map {saved_map}; brought to map {controller_map}:"
    )?;
    if upgrade.offset_from_weight_offset {
        writeln!(
            out,
            "  weight_offset_hi, weight_offset_lo from weight_offset (the full scale offset \
             it names)"
        )?;
    }
    let newer: Vec<&str> = writable()
        .filter(|register| {
            Reg::from_address(register.address)
                .is_some_and(|reg| saved_maps::kept_since(reg) > saved_map)
                && !file.values.contains_key(&register.address)
        })
        .map(|register| register.name)
        .collect();
    if !newer.is_empty() {
        writeln!(
            out,
            "  not saved under map {saved_map}: {}",
            newer.join(", ")
        )?;
    }
    Ok(())
}

/// The order to write `changes` in so that every state on the way keeps the rules
/// (`current` is the controller's state); `Err` names the rules the end state breaks.
pub fn plan(
    current: &BTreeMap<u8, u16>,
    changes: &BTreeMap<u8, u16>,
) -> Result<Vec<(u8, u16)>, Error> {
    let value_in = |state: &BTreeMap<u8, u16>| {
        let state = state.clone();
        move |reg: Reg| state.get(&reg.address()).copied().unwrap_or(0)
    };
    let mut end = current.clone();
    end.extend(changes);
    let broken = rules::broken(&value_in(&end));
    if !broken.is_empty() {
        let texts: Vec<String> = broken
            .iter()
            .map(|rule| {
                let [a, b] = rule
                    .registers
                    .map(|reg| format!("{} = {}", reg.info().name, end[&reg.address()]));
                format!("rule {} is broken ({a}, {b})", rule.text)
            })
            .collect();
        return Err(Error::InvalidInput(format!(
            "the configuration is refused, nothing was written:\n  {}",
            texts.join("\n  ")
        )));
    }
    let mut state = current.clone();
    let mut pending: Vec<(u8, u16)> = changes.iter().map(|(&a, &v)| (a, v)).collect();
    let mut order = Vec::new();
    while !pending.is_empty() {
        let next = pending.iter().position(|&(address, value)| {
            let mut candidate = state.clone();
            candidate.insert(address, value);
            rules::broken(&value_in(&candidate)).is_empty()
        });
        let Some(next) = next else {
            return Err(Error::InvalidInput(
                "no order of writes keeps the rules between registers on the way".to_owned(),
            ));
        };
        let (address, value) = pending.remove(next);
        state.insert(address, value);
        order.push((address, value));
    }
    Ok(order)
}

/// Checks the file, shows the changes, writes them and reads them back.
pub fn load(base: &mut Base, path: &Path, dry_run: bool, out: &mut dyn Write) -> Result<(), Error> {
    let text = std::fs::read_to_string(path)
        .map_err(|error| Error::InvalidInput(format!("cannot read {}: {error}", path.display())))?;
    let mut file = parse(&text)?;
    let [firmware, regmap] = base.read_registers([Reg::FwVersion, Reg::RegmapVersion])?;
    bring_to_map(&mut file, regmap, out)?;
    if let Some(saved) = &file.firmware_version
        && *saved != version_text(firmware)
    {
        writeln!(
            out,
            "note: saved from firmware {saved}, the controller runs {}",
            version_text(firmware)
        )?;
    }
    let current = read_writable(base)?;
    let changes: BTreeMap<u8, u16> = file
        .values
        .iter()
        .filter(|(address, value)| current.get(address) != Some(value))
        .map(|(&address, &value)| (address, value))
        .collect();
    let order = plan(&current, &changes)?;
    let missing: Vec<&str> = writable()
        .filter(|register| !file.values.contains_key(&register.address))
        .map(|register| register.name)
        .collect();
    if !missing.is_empty() {
        writeln!(
            out,
            "not in the file, left as they are: {}",
            missing.join(", ")
        )?;
    }
    if order.is_empty() {
        writeln!(
            out,
            "every register already holds the file's value; nothing to write"
        )?;
        return Ok(());
    }
    writeln!(out, "changes:")?;
    for &(address, value) in &order {
        let register = base_core::registers::info(address).expect("checked above");
        writeln!(
            out,
            "  {:<16} {:>6} -> {:<6} {}",
            register.name, current[&address], value, register.unit
        )?;
    }
    if dry_run {
        writeln!(out, "--dry-run: nothing was written")?;
        return Ok(());
    }
    for &(address, value) in &order {
        let register = base_core::registers::info(address).expect("checked above");
        write_checked(base, register, value)?;
    }
    // Each write was read back at once; a last reading of all proves that no later
    // write (ours or another program's) undid an earlier one.
    let mut expected = current;
    expected.extend(&file.values);
    let differing = differences(&expected, &read_writable(base)?);
    if !differing.is_empty() {
        return Err(Error::Aborted(format!(
            "after loading, these registers do not hold the file's values: {} (another \
             program may have written them)",
            differing.join(", ")
        )));
    }
    writeln!(
        out,
        "wrote {} registers, read each back and then all of them once more",
        order.len()
    )?;
    Ok(())
}

/// The registers whose value differs between two readings, as `name: first -> second`.
fn differences(first: &BTreeMap<u8, u16>, second: &BTreeMap<u8, u16>) -> Vec<String> {
    first
        .iter()
        .filter(|&(address, value)| second.get(address) != Some(value))
        .map(|(address, value)| {
            let name = base_core::registers::info(*address).map_or("?", |info| info.name);
            match second.get(address) {
                Some(now) => format!("{name}: {value} -> {now}"),
                None => format!("{name}: {value} -> not read"),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defaults() -> BTreeMap<u8, u16> {
        writable()
            .map(|register| (register.address, register.default))
            .collect()
    }

    #[test]
    fn a_file_with_bad_names_and_values_is_refused_naming_each_with_its_range() {
        let text = r#"{"basectl_config": 1, "regmap_version": 2, "registers": [
            {"name": "loop_end_delay", "value": 0},
            {"name": "no_such", "value": 1},
            {"name": "fw_version", "value": 1},
            {"name": "rad_r", "address": 5, "value": 142}
        ]}"#;
        let error = parse(text).unwrap_err().to_string();
        for part in [
            "loop_end_delay: value 0 is outside the range (allowed: ",
            "no_such: no such register",
            "fw_version: not writable",
            "rad_r: address 5 in the file, but rad_r is register 0",
            "nothing was written",
        ] {
            assert!(error.contains(part), "{part:?} in {error}");
        }
    }

    fn file(map: u16, registers: &str) -> ConfigFile {
        parse(&format!(
            r#"{{"basectl_config": 1, "regmap_version": {map}, "registers": [{registers}]}}"#
        ))
        .unwrap()
    }

    #[test]
    fn a_file_from_an_older_map_is_brought_to_todays_and_says_what_changed() {
        let mut old = file(2, r#"{"name": "weight_offset", "value": 31000}"#);
        let mut out = Vec::new();
        bring_to_map(&mut old, REGMAP_VERSION, &mut out).unwrap();
        let said = String::from_utf8(out).unwrap();
        assert_eq!(old.regmap_version, REGMAP_VERSION);
        assert_eq!(
            old.values,
            BTreeMap::from([(19, 31_000), (44, 0), (45, 31_000)])
        );
        assert!(
            said.contains("weight_offset_hi, weight_offset_lo from weight_offset"),
            "{said}"
        );
        assert!(
            said.contains("not saved under map 2: stop_decel, sec_motor_vel"),
            "{said}"
        );
    }

    #[test]
    fn a_file_from_a_newer_map_or_for_a_map_basectl_does_not_know_is_refused() {
        let mut out = Vec::new();
        let mut newer = file(REGMAP_VERSION + 1, r#"{"name": "rad_r", "value": 150}"#);
        let error = bring_to_map(&mut newer, REGMAP_VERSION, &mut out).unwrap_err();
        assert!(
            error.to_string().contains("a newer map's registers"),
            "{error}"
        );
        let mut older = file(2, r#"{"name": "rad_r", "value": 150}"#);
        let error = bring_to_map(&mut older, REGMAP_VERSION - 1, &mut out).unwrap_err();
        assert!(
            error.to_string().contains(&format!(
                "this basectl knows register map {REGMAP_VERSION} only"
            )),
            "{error}"
        );
        assert!(out.is_empty(), "nothing said before a refusal");
    }

    #[test]
    fn writes_are_ordered_so_that_every_step_keeps_the_rules() {
        let current = defaults();
        // Both battery limits up, the new empty above the old full: full must go first.
        let empty = Reg::BattEmptyMv.address();
        let full = Reg::BattFullMv.address();
        let changes = BTreeMap::from([(empty, 30_000), (full, 32_000)]);
        let order = plan(&current, &changes).unwrap();
        assert_eq!(order, [(full, 32_000), (empty, 30_000)]);
    }

    #[test]
    fn an_end_state_that_breaks_a_rule_is_refused_naming_it() {
        let changes = BTreeMap::from([(Reg::BattEmptyMv.address(), 30_000)]);
        let error = plan(&defaults(), &changes).unwrap_err().to_string();
        assert!(
            error.contains("rule batt_empty_mv < batt_full_mv is broken (batt_empty_mv = 30000, batt_full_mv = 25500)"),
            "{error}"
        );
    }
}
