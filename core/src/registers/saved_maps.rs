//! Values saved under an older register map (a `basectl config save` file, or the
//! register store an older image wrote), brought to today's map.
//!
//! Maps only ever add: from map 1 to today's no register changed its address, unit or
//! range, so a value saved under any map means today what it meant then. Two things
//! differ between maps, and this module says both:
//! - a register that became read-write in a later map is in no older save:
//!   [`kept_since`] (it keeps the value it has);
//! - the full scale offset (44 and 45, read-write since map 4) follows from
//!   `weight_offset` (19) when a save holds only that: [`offset_words_from`].

use super::{ADDRESS_COUNT, REGMAP_VERSION, Reg};

/// The register map from which on `reg` is read-write, and so saved and restored.
pub const fn kept_since(reg: Reg) -> u16 {
    match reg {
        Reg::StopDecel | Reg::SecMotorVel => 3,
        Reg::WeightOffsetHi | Reg::WeightOffsetLo => 4,
        _ => 1,
    }
}

/// Registers 44 and 45 for a save that holds only `weight_offset` (19), from before the
/// full 24-bit offset: that offset is 19's value.
pub const fn offset_words_from(weight_offset: u16) -> [u16; 2] {
    [0, weight_offset]
}

/// Why values saved under a register map cannot be brought to this one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SavedMapError {
    /// Map 0 has never existed.
    NoSuchMap,
    /// A map newer than this firmware's: its registers may mean what this one cannot
    /// know.
    Newer(u16),
}

/// What [`upgrade`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Upgrade {
    /// 44 and 45 were set from `weight_offset` ([`offset_words_from`]).
    pub offset_from_weight_offset: bool,
}

/// Brings `values` (by address; `None` where the save holds nothing) saved under
/// register map `map` to [`REGMAP_VERSION`]. A save from the same map is left as it is.
pub fn upgrade(
    map: u16,
    values: &mut [Option<u16>; ADDRESS_COUNT],
) -> Result<Upgrade, SavedMapError> {
    match map {
        0 => return Err(SavedMapError::NoSuchMap),
        newer if newer > REGMAP_VERSION => return Err(SavedMapError::Newer(newer)),
        _ => {}
    }
    let mut upgrade = Upgrade::default();
    let [hi, lo] = [Reg::WeightOffsetHi, Reg::WeightOffsetLo].map(|reg| usize::from(reg.address()));
    if map < kept_since(Reg::WeightOffsetHi)
        && values[hi].is_none()
        && values[lo].is_none()
        && let Some(weight_offset) = values[usize::from(Reg::WeightOffset.address())]
    {
        let [high, low] = offset_words_from(weight_offset);
        values[hi] = Some(high);
        values[lo] = Some(low);
        upgrade.offset_from_weight_offset = true;
    }
    Ok(upgrade)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registers::{Access, Registers, TABLE};

    fn saved(pairs: &[(Reg, u16)]) -> [Option<u16>; ADDRESS_COUNT] {
        let mut values = [None; ADDRESS_COUNT];
        for &(reg, value) in pairs {
            values[usize::from(reg.address())] = Some(value);
        }
        values
    }

    #[test]
    fn a_save_from_before_the_full_offset_gets_it_from_weight_offset() {
        for map in 1..kept_since(Reg::WeightOffsetHi) {
            let mut values = saved(&[(Reg::WeightOffset, 31_000), (Reg::RadR, 150)]);
            let upgrade = upgrade(map, &mut values).unwrap();
            assert!(upgrade.offset_from_weight_offset, "map {map}");
            assert_eq!(values[44], Some(0));
            assert_eq!(values[45], Some(31_000));
            assert_eq!(values[0], Some(150), "everything else as saved");
        }
    }

    /// The controller's own migration of an old store agrees: the offset it loads from
    /// a store holding only 19 is the one a file holding only 19 is given.
    #[test]
    fn the_offset_words_make_the_offset_weight_offset_names() {
        let mut registers = Registers::defaults();
        let [high, low] = offset_words_from(31_000);
        registers
            .write(Reg::WeightOffsetHi.address(), high)
            .unwrap();
        registers.write(Reg::WeightOffsetLo.address(), low).unwrap();
        assert_eq!(registers.weight_offset(), 31_000);
        assert_eq!(registers.get(Reg::WeightOffset), 31_000);
    }

    #[test]
    fn a_save_with_the_full_offset_or_from_todays_map_is_left_as_it_is() {
        let with_words = saved(&[
            (Reg::WeightOffset, 0),
            (Reg::WeightOffsetHi, 0xFF),
            (Reg::WeightOffsetLo, 0xFF00),
        ]);
        for map in 1..=REGMAP_VERSION {
            let mut values = with_words;
            assert_eq!(upgrade(map, &mut values), Ok(Upgrade::default()));
            assert_eq!(values, with_words);
        }
        let mut today = saved(&[(Reg::WeightOffset, 31_000)]);
        assert_eq!(upgrade(REGMAP_VERSION, &mut today), Ok(Upgrade::default()));
        assert_eq!(today[44], None);
    }

    #[test]
    fn map_zero_and_newer_maps_are_refused() {
        let mut values = saved(&[(Reg::RadR, 150)]);
        assert_eq!(upgrade(0, &mut values), Err(SavedMapError::NoSuchMap));
        assert_eq!(
            upgrade(REGMAP_VERSION + 1, &mut values),
            Err(SavedMapError::Newer(REGMAP_VERSION + 1))
        );
    }

    #[test]
    fn every_register_kept_since_a_map_is_read_write_in_todays() {
        for register in &TABLE {
            let Some(reg) = Reg::from_address(register.address) else {
                continue;
            };
            let since = kept_since(reg);
            assert!((1..=REGMAP_VERSION).contains(&since), "{}", register.name);
            if since > 1 {
                assert_eq!(register.access, Access::ReadWrite, "{}", register.name);
            }
        }
    }
}
