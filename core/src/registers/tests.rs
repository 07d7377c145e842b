use super::record::encode_with_schema;
use super::*;
use proptest::prelude::*;

/// The manual's register table (§10), copied by hand: address, name, default.
const MANUAL: [(u8, &str, u16); 24] = [
    (0, "rad_r", 142),
    (1, "rad_l", 142),
    (2, "wheel_dist", 250),
    (3, "CAN_accel", 700),
    (4, "Contr_acc_norm", 350),
    (5, "Contr_acc_high", 500),
    (6, "max_motor_vel", 900),
    (7, "PS_abs_max_vel", 1200),
    (8, "PS_rel_max_vel", 250),
    (9, "sec_lin_vel", 200),
    (10, "sec_turn_vel", 100),
    (11, "disable_time", 300),
    (12, "volt_time", 5000),
    (13, "weight_time", 1000),
    (14, "PS_afk_time", 30000),
    (15, "loop_end_delay", 50),
    (16, "f_cw", 9938),
    (17, "f_ccw", 9894),
    (18, "f_lin", 10071),
    (19, "weight_offset", 20490),
    (20, "scale_value", 1900),
    (21, "heartbeat_time", 5000),
    (22, "start_PC", 3000),
    (23, "shutdown_PC", 8000),
];

/// The extensions as the lead fixed them: address, name, default, min, max, 0 = off.
const EXTENSIONS: [(u8, &str, u16, u16, u16, bool); 21] = [
    (24, "gear_ratio", 1000, 100, 10000, false),
    (25, "enable_timeout", 500, 50, 5000, false),
    (26, "estop_decel", 4500, 100, 30000, false),
    (27, "cmd_timeout", 0, 50, 10000, true),
    (28, "motor_dir", 2, 0, 3, false),
    (29, "batt_empty_mv", 21000, 5000, 60000, false),
    (30, "batt_full_mv", 25500, 5000, 60000, false),
    (31, "status_time", 1000, 100, 60000, true),
    (32, "pc_boot_grace", 120, 10, 600, false),
    (33, "pc_switch_pulse", 500, 50, 2000, false),
    (34, "remote_kind", 0, 0, 3, false),
    (35, "remote_battery", 0, 0, 0x0564, false),
    (36, "bluetooth_off", 0, 0, 2, false),
    (43, "can_tx_dropped", 0, 0, 65535, false),
    (44, "weight_offset_hi", 0, 0, 255, false),
    (45, "weight_offset_lo", 20490, 0, 65535, false),
    (46, "flash_erases_hi", 0, 0, 65535, false),
    (47, "flash_erases_lo", 0, 0, 65535, false),
    (48, "stop_decel", 2000, 2000, 30000, false),
    (49, "sec_motor_vel", 150, 0, 4000, false),
    (50, "boot_info", 0, 0, 31, false),
];

fn persistent() -> impl Iterator<Item = &'static RegisterInfo> {
    TABLE.iter().filter(|i| i.access == Access::ReadWrite)
}

fn assert_valid(registers: &Registers) {
    for info in persistent() {
        let value = registers.get(Reg::from_address(info.address).unwrap());
        assert!(info.accepts(value), "{} = {value}", info.name);
    }
    assert!(registers.is_consistent(), "{registers:?}");
    let offset = registers.weight_offset();
    assert!(WEIGHT_OFFSET_RANGE.contains(&offset));
    assert_eq!(
        i32::from(registers.get(Reg::WeightOffset)),
        offset.clamp(0, 65_535),
        "weight_offset reads the full offset clamped to 16 bits"
    );
}

#[test]
fn defaults_of_addresses_0_to_23_are_the_manuals() {
    let registers = Registers::defaults();
    for (address, name, default) in MANUAL {
        let info = info(address).unwrap();
        assert_eq!(info.name, name, "address {address}");
        assert_eq!(info.default, default, "{name}");
        assert_eq!(info.access, Access::ReadWrite, "{name}");
        assert!(!info.extension, "{name}");
        assert_eq!(registers.read(address), Ok(default), "{name}");
    }
}

#[test]
fn extension_registers_have_the_fixed_addresses_defaults_and_ranges() {
    let registers = Registers::defaults();
    for (address, name, default, min, max, zero_is_off) in EXTENSIONS {
        let info = info(address).unwrap();
        assert_eq!(
            (
                info.name,
                info.default,
                info.min,
                info.max,
                info.zero_is_off
            ),
            (name, default, min, max, zero_is_off)
        );
        assert!(info.extension, "{name}");
        assert_eq!(registers.read(address), Ok(default), "{name}");
    }
}

#[test]
fn reg_enum_table_and_addresses_agree() {
    assert_eq!(TABLE.len(), Reg::ALL.len());
    for (info, reg) in TABLE.iter().zip(Reg::ALL) {
        assert_eq!(info.address, reg as u8);
        assert_eq!(reg.info().address, reg as u8);
        assert_eq!(Reg::from_address(reg as u8), Some(reg));
    }
    assert!(Reg::ALL.windows(2).all(|w| w[0] < w[1]));
    for address in (37..=37).chain(41..=42).chain(51..=u8::MAX) {
        assert_eq!(Reg::from_address(address), None);
        assert_eq!(info(address), None);
    }
}

#[test]
fn every_default_lies_in_its_range_and_defaults_keep_every_rule() {
    assert_valid(&Registers::defaults());
}

#[test]
fn version_registers_read_the_build_and_map_versions() {
    let mut parts = env!("CARGO_PKG_VERSION").split('.');
    let major: u16 = parts.next().unwrap().parse().unwrap();
    let minor: u16 = parts.next().unwrap().parse().unwrap();
    let registers = Registers::defaults();
    assert_eq!(registers.read(38), Ok((major << 8) | minor));
    // 4 since the remote's kind and battery (34, 35), `bluetooth_off` (36), the
    // Bluetooth-on key and `boot_info` (50) came.
    assert_eq!(registers.read(39), Ok(4));
}

#[test]
fn error_codes_are_stable() {
    assert_eq!(RegisterError::UnknownAddress.code(), 0x10);
    assert_eq!(RegisterError::ReadOnly.code(), 0x11);
    assert_eq!(RegisterError::OutOfRange.code(), 0x12);
    assert_eq!(RegisterError::Inconsistent.code(), 0x13);
    assert_eq!(RegisterError::NotAtRest.code(), 0x14);
}

#[test]
fn motion_registers_are_the_geometry_the_limits_and_the_zone_limits() {
    let motion: Vec<Reg> = Reg::ALL
        .into_iter()
        .filter(|r| r.changes_motion())
        .collect();
    assert_eq!(
        motion,
        [
            Reg::RadR,
            Reg::RadL,
            Reg::WheelDist,
            Reg::MaxMotorVel,
            Reg::SecLinVel,
            Reg::SecTurnVel,
            Reg::GearRatio,
            Reg::MotorDir,
            Reg::SecMotorVel,
        ]
    );
}

#[test]
fn stop_decel_stops_the_highest_max_motor_vel_within_2_s() {
    // The documented bound: 4000 1/min, the BLV R maximum and max_motor_vel's top, at
    // stop_decel's lowest value.
    let info = Reg::StopDecel.info();
    assert_eq!(
        u32::from(Reg::MaxMotorVel.info().max) * 1000 / u32::from(info.min),
        2000
    );
}

#[test]
fn bad_writes_are_rejected_and_change_nothing() {
    use RegisterError::*;
    let cases: &[(u8, u16, RegisterError)] = &[
        (0, 0, OutOfRange),      // rad_r
        (1, 0, OutOfRange),      // rad_l
        (2, 0, OutOfRange),      // wheel_dist
        (15, 0, OutOfRange),     // loop_end_delay
        (20, 0, OutOfRange),     // scale_value
        (18, 4999, OutOfRange),  // f_lin
        (18, 15001, OutOfRange), // f_lin
        (6, 0, OutOfRange),      // max_motor_vel
        (6, 4001, OutOfRange),   // max_motor_vel
        (27, 20, OutOfRange),    // cmd_timeout: neither off nor 50..=10000
        (21, 1999, OutOfRange),  // heartbeat_time below the PC's 0.5 Hz period
        (8, 49, OutOfRange),     // PS_rel_max_vel below the lowest speed level
        (28, 4, OutOfRange),     // motor_dir has two bits
        (40, 1, OutOfRange),     // command: not the restore key
        (36, 0, ReadOnly),       // bluetooth_off: only the panic loop and the BLE task set it
        (37, 1, UnknownAddress),
        (41, 1, UnknownAddress),
        (255, 1, UnknownAddress),
        (38, 0x0100, ReadOnly),
        (39, 1, ReadOnly),
        (34, 1, ReadOnly),
        (35, 0, ReadOnly),
        (29, 25500, Inconsistent), // batt_empty_mv = batt_full_mv
        (29, 30000, Inconsistent), // batt_empty_mv > batt_full_mv
        (30, 21000, Inconsistent), // batt_full_mv = batt_empty_mv
        (22, 8000, Inconsistent),  // start_PC = shutdown_PC
        (23, 2999, Inconsistent),  // shutdown_PC < start_PC
        (8, 1201, Inconsistent),   // PS_rel_max_vel > PS_abs_max_vel
        (7, 249, Inconsistent),    // PS_abs_max_vel < PS_rel_max_vel
        (6, 1351, Inconsistent),   // 4500 (1/min)/s cannot stop 1351 1/min in 300 ms
        (26, 2999, Inconsistent),  // nor can 2999 (1/min)/s stop 900 1/min
    ];
    for &(address, value, error) in cases {
        let mut registers = Registers::defaults();
        assert_eq!(
            registers.write(address, value),
            Err(error),
            "{address} <- {value}"
        );
        assert_eq!(registers, Registers::defaults(), "{address} <- {value}");
    }
}

#[test]
fn range_and_rule_boundaries_are_accepted() {
    let cases: &[(u8, u16)] = &[
        (0, 10),
        (0, 1000),
        (2, 50),
        (2, 2000),
        (15, 10),
        (18, 5000),
        (18, 15000),
        (6, 1),
        (6, 1350), // 4500 (1/min)/s stops 1350 1/min in exactly 300 ms
        (26, 3000),
        (27, 50),
        (27, 10000),
        (31, 0),
        (9, 0),
        (10, 0),
        (11, 0),
        (21, 2000),
        (20, 1),
        (29, 25499),
        (22, 7999),
        (8, 1200),
        (7, 250),
    ];
    for &(address, value) in cases {
        let mut registers = Registers::defaults();
        assert_eq!(
            registers.write(address, value),
            Ok(WriteOutcome::Changed { address, value }),
            "{address} <- {value}"
        );
        assert_eq!(registers.read(address), Ok(value));
    }
    // cmd_timeout defaults to off; switching it on and off again.
    let mut registers = Registers::defaults();
    registers.write(27, 50).unwrap();
    assert_eq!(
        registers.write(27, 0),
        Ok(WriteOutcome::Changed {
            address: 27,
            value: 0
        })
    );
}

#[test]
fn pair_rules_can_be_moved_in_the_right_order() {
    let mut registers = Registers::defaults();
    assert_eq!(registers.write(6, 4000), Err(RegisterError::Inconsistent));
    assert!(registers.write(26, 13334).is_ok());
    assert!(registers.write(6, 4000).is_ok());
    assert!(registers.write(30, 28000).is_ok());
    assert!(registers.write(29, 26000).is_ok());
    assert_valid(&registers);
}

#[test]
fn same_value_is_unchanged_and_new_value_is_changed() {
    let mut registers = Registers::defaults();
    assert_eq!(registers.write(15, 50), Ok(WriteOutcome::Unchanged));
    assert_eq!(
        registers.write(15, 20),
        Ok(WriteOutcome::Changed {
            address: 15,
            value: 20
        })
    );
    assert_eq!(registers.get(Reg::LoopEndDelay), 20);
    assert_eq!(registers.write(15, 20), Ok(WriteOutcome::Unchanged));
}

#[test]
fn restore_key_brings_back_every_default() {
    let mut registers = Registers::defaults();
    registers.write(0, 150).unwrap();
    registers.write(18, 10000).unwrap();
    registers.write(28, 1).unwrap();
    registers.write(27, 200).unwrap();
    assert_ne!(registers, Registers::defaults());
    assert_eq!(
        registers.write(40, RESTORE_DEFAULTS_KEY),
        Ok(WriteOutcome::DefaultsRestored)
    );
    assert_eq!(registers, Registers::defaults());
}

#[test]
fn pairing_and_bluetooth_keys_change_no_register_and_command_takes_no_other_value() {
    let mut registers = Registers::defaults();
    registers.write(0, 150).unwrap();
    let before = registers.clone();
    assert_eq!(
        registers.write(40, OPEN_PAIRING_WINDOW_KEY),
        Ok(WriteOutcome::PairingWindowRequested)
    );
    assert_eq!(
        registers.write(40, BLUETOOTH_ON_KEY),
        Ok(WriteOutcome::BluetoothOnRequested)
    );
    assert_eq!(registers, before);
    for value in [0, 1, 0xB1DF, 0xB1E2, 0xC000, 0xDEEF, 0xDEF1, u16::MAX] {
        assert_eq!(
            registers.write(40, value),
            Err(RegisterError::OutOfRange),
            "{value:#06X}"
        );
    }
    assert_eq!(registers, before);
}

#[test]
fn command_register_reads_zero() {
    let mut registers = Registers::defaults();
    assert_eq!(registers.read(40), Ok(0));
    registers.write(40, 0xDEF0).unwrap();
    assert_eq!(registers.read(40), Ok(0));
}

#[test]
fn iter_lists_exactly_the_persistent_registers_with_current_values() {
    let mut registers = Registers::defaults();
    registers.write(19, 12345).unwrap();
    let listed: Vec<(u8, u16)> = registers.iter().collect();
    let addresses: Vec<u8> = listed.iter().map(|&(a, _)| a).collect();
    assert_eq!(
        addresses,
        (0..=33).chain([44, 45, 48, 49]).collect::<Vec<u8>>()
    );
    assert!(listed.contains(&(19, 12345)));
    assert!(listed.contains(&(0, 142)));
}

fn store_of(registers: &Registers) -> Vec<[u8; RECORD_LEN]> {
    registers
        .iter()
        .map(|(address, value)| encode_record(address, value))
        .collect()
}

fn load_from(store: &[[u8; RECORD_LEN]]) -> (Registers, LoadReport) {
    Registers::load(store.iter().map(|r| r.as_slice()))
}

#[test]
fn blank_store_loads_defaults_and_raises_the_fault() {
    let (registers, report) = Registers::load(core::iter::empty());
    assert_eq!(registers, Registers::defaults());
    assert_eq!(
        report,
        LoadReport {
            applied: 0,
            rejected: 0,
            dropped: 0,
            blank: true,
            first_boot: false
        }
    );
    assert!(report.flash_fault());
}

#[test]
fn full_store_round_trips_without_fault() {
    let mut written = Registers::defaults();
    written.write(0, 150).unwrap();
    written.write(16, 9950).unwrap();
    written.write(28, 1).unwrap();
    let (loaded, report) = load_from(&store_of(&written));
    assert_eq!(loaded, written);
    assert_eq!(report.applied, 38);
    assert_eq!(report.rejected, 0);
    assert!(!report.flash_fault());
}

#[test]
fn corrupt_record_is_skipped_and_flagged() {
    let mut written = Registers::defaults();
    written.write(2, 300).unwrap();
    written.write(3, 800).unwrap();
    let mut store = store_of(&written);
    store[2][3] ^= 0x01; // wheel_dist's value LSB
    let (loaded, report) = load_from(&store);
    assert_eq!(loaded.get(Reg::WheelDist), 250);
    assert_eq!(loaded.get(Reg::CanAccel), 800);
    assert_eq!(report.rejected, 1);
    assert_eq!(report.applied, 37);
    assert!(report.flash_fault());
}

#[test]
fn zero_radius_with_valid_crc_is_skipped() {
    let store = [encode_record(0, 0), encode_record(1, 150)];
    let (loaded, report) = load_from(&store);
    assert_eq!(loaded.get(Reg::RadR), 142);
    assert_eq!(loaded.get(Reg::RadL), 150);
    assert_eq!((report.applied, report.rejected), (1, 1));
    assert!(report.flash_fault());
}

#[test]
fn records_for_unassigned_or_read_only_addresses_are_rejected() {
    let store = [
        encode_record(34, 1),
        encode_record(38, 0x0700),
        encode_record(39, 9),
        encode_record(40, RESTORE_DEFAULTS_KEY),
        encode_record(200, 1),
    ];
    let (loaded, report) = load_from(&store);
    assert_eq!(loaded, Registers::defaults());
    assert_eq!(report.rejected, 5);
}

#[test]
fn newer_schema_keeps_wheel_dist_and_drops_enable_timeout() {
    let newer = SCHEMA_VERSION + 1;
    let store = [
        encode_with_schema(newer, 2, 300),
        encode_with_schema(newer, 25, 1000),
    ];
    let (loaded, report) = load_from(&store);
    assert_eq!(loaded.get(Reg::WheelDist), 300);
    assert_eq!(loaded.get(Reg::EnableTimeout), 500);
    assert_eq!(
        report,
        LoadReport {
            applied: 1,
            rejected: 0,
            dropped: 1,
            blank: false,
            first_boot: false
        }
    );
    assert!(!report.flash_fault());
}

#[test]
fn newer_schema_values_are_still_range_checked() {
    let (loaded, report) = load_from(&[encode_with_schema(SCHEMA_VERSION + 1, 0, 0)]);
    assert_eq!(loaded.get(Reg::RadR), 142);
    assert_eq!(report.rejected, 1);
}

#[test]
fn stored_pairs_load_in_any_order() {
    // Each pair is consistent, but no single write from the defaults reaches it.
    let pairs = [
        [encode_record(7, 200), encode_record(8, 150)],
        [encode_record(29, 26000), encode_record(30, 28000)],
        [encode_record(22, 9000), encode_record(23, 12000)],
        [encode_record(6, 3000), encode_record(26, 10000)],
    ];
    for pair in pairs {
        for store in [pair, [pair[1], pair[0]]] {
            let (loaded, report) = load_from(&store);
            assert_eq!((report.applied, report.rejected), (2, 0), "{store:?}");
            for record in store {
                let (address, value) = decode_record(&record).unwrap();
                assert_eq!(loaded.read(address), Ok(value));
            }
        }
    }
}

#[test]
fn inconsistent_stored_pair_falls_back_to_defaults() {
    // batt_full_mv below the default batt_empty_mv, and PS_rel above PS_abs.
    let store = [
        encode_record(30, 20000),
        encode_record(7, 300),
        encode_record(8, 400),
        encode_record(0, 150),
    ];
    let (loaded, report) = load_from(&store);
    let defaults = Registers::defaults();
    for reg in [
        Reg::BattEmptyMv,
        Reg::BattFullMv,
        Reg::PsAbsMaxVel,
        Reg::PsRelMaxVel,
    ] {
        assert_eq!(loaded.get(reg), defaults.get(reg), "{reg:?}");
    }
    assert_eq!(loaded.get(Reg::RadR), 150);
    assert_eq!((report.applied, report.rejected), (1, 3));
    assert!(report.flash_fault());
}

#[test]
fn later_record_for_an_address_wins() {
    let store = [encode_record(15, 20), encode_record(15, 40)];
    let (loaded, report) = load_from(&store);
    assert_eq!(loaded.get(Reg::LoopEndDelay), 40);
    assert_eq!(report.applied, 1);
}

/// Addresses around and beyond the map, with values near the interesting edges.
fn write_op() -> impl Strategy<Value = (u8, u16)> {
    let address = prop_oneof![8 => 0u8..=49, 1 => any::<u8>()];
    let value = prop_oneof![
        any::<u16>(),
        0u16..=100,
        (0usize..TABLE.len()).prop_flat_map(|i| {
            let info = &TABLE[i];
            prop_oneof![
                Just(info.min),
                Just(info.max),
                info.min..=info.max,
                Just(info.min.saturating_sub(1)),
                Just(info.max.saturating_add(1)),
            ]
        }),
    ];
    (address, value)
}

proptest! {
    #[test]
    fn any_write_sequence_keeps_every_range_and_rule(ops in prop::collection::vec(write_op(), 0..200)) {
        let mut registers = Registers::defaults();
        for (address, value) in ops {
            let before = registers.clone();
            match registers.write(address, value) {
                Ok(WriteOutcome::Changed { address: a, value: v }) => {
                    prop_assert_eq!((a, v), (address, value));
                    prop_assert_eq!(registers.read(address), Ok(value));
                }
                Ok(WriteOutcome::OffsetChanged) => {
                    prop_assert!([19, 44, 45].contains(&address));
                    prop_assert_ne!(registers.weight_offset(), before.weight_offset());
                }
                Ok(WriteOutcome::Unchanged) => prop_assert_eq!(&registers, &before),
                Ok(WriteOutcome::DefaultsRestored) => prop_assert_eq!(&registers, &Registers::defaults()),
                Ok(WriteOutcome::PairingWindowRequested) => {
                    prop_assert_eq!((address, value), (40, OPEN_PAIRING_WINDOW_KEY));
                    prop_assert_eq!(&registers, &before);
                }
                Ok(WriteOutcome::BluetoothOnRequested) => {
                    prop_assert_eq!((address, value), (40, BLUETOOTH_ON_KEY));
                    prop_assert_eq!(&registers, &before);
                }
                Err(_) => prop_assert_eq!(&registers, &before),
            }
            assert_valid(&registers);
        }
    }

    #[test]
    fn load_never_panics_on_arbitrary_bytes(store in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..10), 0..50)) {
        let (registers, report) = Registers::load(store.iter().map(|r| r.as_slice()));
        assert_valid(&registers);
        prop_assert_eq!(report.blank, store.is_empty());
    }

    #[test]
    fn load_of_well_formed_records_with_any_content_stays_valid(
        store in prop::collection::vec((0u8..=3, write_op()), 0..80)
    ) {
        let records: Vec<[u8; RECORD_LEN]> = store
            .iter()
            .map(|&(schema, (address, value))| encode_with_schema(schema, address, value))
            .collect();
        let (registers, report) = load_from(&records);
        assert_valid(&registers);
        prop_assert!(usize::from(report.applied) <= records.len());
        prop_assert!(usize::from(report.rejected + report.dropped) <= records.len());
    }
}

/// The start of a register's table row as `docs/registers.md` prints it:
/// address, name, unit, default and valid range.
fn documented_row(info: &RegisterInfo) -> String {
    let name = if info.extension {
        format!("{} (ext)", info.name)
    } else {
        info.name.to_string()
    };
    let valid = if info.zero_is_off {
        format!("off or {}..={}", info.min, info.max)
    } else {
        format!("{}..={}", info.min, info.max)
    };
    format!(
        "\n| {} | {} | {} | {} | {} | ",
        info.address, name, info.unit, info.default, valid
    )
}

#[test]
fn docs_table_matches_the_register_table() {
    let docs = include_str!("../../../docs/registers.md");
    for info in persistent() {
        let row = format!("{}rw | ", documented_row(info));
        assert!(
            docs.contains(&row),
            "docs/registers.md lacks the row {row:?}"
        );
    }
    let golden = encode_record(15, 50).map(|b| format!("{b:02X}")).join(" ");
    assert!(docs.contains(&format!("record: {golden}")), "{golden}");
}

#[test]
fn a_tare_beyond_16_bits_keeps_the_full_offset_and_19_reads_it_clamped() {
    let mut registers = Registers::defaults();
    assert_eq!(registers.weight_offset(), 20_490);
    assert_eq!(
        registers.set_weight_offset(80_000),
        Ok(WriteOutcome::OffsetChanged)
    );
    assert_eq!(registers.weight_offset(), 80_000);
    assert_eq!(registers.read(19), Ok(65_535));
    assert_eq!(
        (registers.read(44), registers.read(45)),
        (Ok(0x01), Ok(0x3880))
    );
    registers.set_weight_offset(-15_000).unwrap();
    assert_eq!(registers.weight_offset(), -15_000);
    assert_eq!(registers.read(19), Ok(0));
    assert_eq!(
        (registers.read(44), registers.read(45)),
        (Ok(0xFF), Ok(0xC568))
    );
    assert_eq!(
        registers.set_weight_offset(1 << 23),
        Err(RegisterError::OutOfRange)
    );
}

#[test]
fn writing_19_back_as_read_keeps_the_full_offset_and_another_value_replaces_it() {
    let mut registers = Registers::defaults();
    registers.set_weight_offset(-15_000).unwrap();
    // A PC tool that saves and restores register 19 writes back what it read.
    assert_eq!(registers.write(19, 0), Ok(WriteOutcome::Unchanged));
    assert_eq!(registers.weight_offset(), -15_000);
    // Any other value is the new offset, as register 19 always meant.
    assert_eq!(registers.write(19, 20_000), Ok(WriteOutcome::OffsetChanged));
    assert_eq!(registers.weight_offset(), 20_000);
    assert_eq!(
        (registers.read(44), registers.read(45)),
        (Ok(0), Ok(20_000))
    );
}

#[test]
fn the_offset_words_set_the_offset_and_19_follows() {
    let mut registers = Registers::defaults();
    assert_eq!(registers.write(44, 0x01), Ok(WriteOutcome::OffsetChanged));
    assert_eq!(registers.weight_offset(), 0x01_0000 + 20_490);
    assert_eq!(registers.read(19), Ok(65_535));
    assert_eq!(registers.write(45, 0x3880), Ok(WriteOutcome::OffsetChanged));
    assert_eq!(registers.weight_offset(), 80_000);
    assert_eq!(registers.write(44, 256), Err(RegisterError::OutOfRange));
}

#[test]
fn an_old_store_with_only_19_loads_it_as_the_full_offset() {
    let (registers, report) = load_from(&[encode_record(19, 12_345)]);
    assert_eq!(registers.weight_offset(), 12_345);
    assert_eq!(registers.get(Reg::WeightOffsetLo), 12_345);
    assert_eq!(report.applied, 1);
    assert!(!report.flash_fault());
}

#[test]
fn stored_offset_words_win_over_19_and_one_word_alone_is_rejected() {
    let mut full = Registers::defaults();
    full.set_weight_offset(-15_000).unwrap();
    let records = full
        .weight_offset_records()
        .map(|(a, v)| encode_record(a, v));
    let (registers, report) = load_from(&records);
    assert_eq!(registers.weight_offset(), -15_000);
    assert_eq!(registers.get(Reg::WeightOffset), 0);
    assert!(!report.flash_fault());

    let (registers, report) = load_from(&[encode_record(19, 300), encode_record(44, 1)]);
    assert_eq!(registers.weight_offset(), 300);
    assert_eq!(report.rejected, 1);
}

#[test]
fn counters_are_read_only_and_set_by_the_firmware() {
    let mut registers = Registers::defaults();
    registers.set_counter(Reg::CanTxDropped, 7);
    registers.set_counter(Reg::RadR, 7);
    assert_eq!(registers.read(43), Ok(7));
    assert_eq!(registers.get(Reg::RadR), 142);
    assert_eq!(registers.write(43, 0), Err(RegisterError::ReadOnly));
}

#[test]
fn the_remote_registers_read_what_the_bluetooth_tasks_report_and_refuse_writes() {
    use crate::hid::playstation::{Battery, BatteryState, PadKind};
    let mut registers = Registers::defaults();
    assert_eq!((registers.read(34), registers.read(35)), (Ok(0), Ok(0)));
    assert_eq!(registers.remote_info(), RemoteInfo::NONE);

    // (what the task reports) → (remote_kind, remote_battery)
    let table = [
        (RemoteInfo::NONE, (0, 0)),
        (
            RemoteInfo {
                kind: RemoteKind::BlePad,
                battery: None,
            },
            (1, 0),
        ),
        (
            RemoteInfo {
                kind: RemoteKind::BlePad,
                battery: Some(RemoteBattery {
                    percent: 55,
                    charge: Charge::LevelOnly,
                }),
            },
            (1, 0x0137),
        ),
        (RemoteInfo::playstation(PadKind::DualShock4, None), (2, 0)),
        (
            RemoteInfo::playstation(
                PadKind::DualShock4,
                Some(Battery {
                    percent: 80,
                    state: BatteryState::Discharging,
                }),
            ),
            (2, 0x0250),
        ),
        (
            RemoteInfo::playstation(
                PadKind::DualSense,
                Some(Battery {
                    percent: 35,
                    state: BatteryState::Charging,
                }),
            ),
            (3, 0x0323),
        ),
        (
            RemoteInfo::playstation(
                PadKind::DualSense,
                Some(Battery {
                    percent: 100,
                    state: BatteryState::Full,
                }),
            ),
            (3, 0x0464),
        ),
        (
            RemoteInfo::playstation(
                PadKind::DualSense,
                Some(Battery {
                    percent: 0,
                    state: BatteryState::Fault,
                }),
            ),
            (3, 0x0500),
        ),
    ];
    for (remote, (kind, battery)) in table {
        registers.set_remote_info(remote);
        assert_eq!(
            (registers.read(34), registers.read(35)),
            (Ok(kind), Ok(battery)),
            "{remote:?}"
        );
        assert_eq!(registers.remote_info(), remote, "decodes back");
        for (address, value) in [(34, kind), (35, battery)] {
            let info = info(address).unwrap();
            assert!(
                info.accepts(value),
                "{} = {value:#06X} in its range",
                info.name
            );
        }
    }

    let before = registers.clone();
    assert_eq!(registers.write(34, 1), Err(RegisterError::ReadOnly));
    assert_eq!(registers.write(35, 0), Err(RegisterError::ReadOnly));
    assert_eq!(registers, before);
    // Not persisted, and a stored record of them is refused at boot.
    assert!(
        registers
            .iter()
            .all(|(address, _)| address != 34 && address != 35)
    );
    let stored = [encode_record(34, 2), encode_record(35, 0x0250)];
    let (loaded, report) = Registers::load(stored.iter().map(|record| &record[..]));
    assert_eq!(report.rejected, 2);
    assert_eq!(loaded.remote_info(), RemoteInfo::NONE);
}

#[test]
fn remote_register_values_the_firmware_never_writes_decode_as_unknown() {
    assert_eq!(RemoteKind::from_code(4), None);
    assert_eq!(RemoteInfo::from_registers(4, 0), None);
    // Charge code 0 and 6.., and a level above 100.
    for battery in [0x0000, 0x0050, 0x0650, 0xFF64, 0x0265] {
        assert_eq!(
            RemoteBattery::from_register(battery),
            None,
            "{battery:#06X}"
        );
    }
    // A level above 100 is never written.
    let battery = RemoteBattery {
        percent: 150,
        charge: Charge::Discharging,
    };
    assert_eq!(battery.register(), 0x0264);
}

#[test]
fn restoring_the_defaults_keeps_the_connected_remote() {
    use crate::hid::playstation::PadKind;
    let mut registers = Registers::defaults();
    let remote = RemoteInfo::playstation(PadKind::DualSense, None);
    registers.set_remote_info(remote);
    assert_eq!(
        registers.write(40, RESTORE_DEFAULTS_KEY),
        Ok(WriteOutcome::DefaultsRestored)
    );
    assert_eq!(registers.remote_info(), remote);
}

#[test]
fn boot_info_bits_round_trip_and_undefined_bits_are_refused() {
    for first_boot in [false, true] {
        for update_reset in [
            UpdateReset::None,
            UpdateReset::Activation,
            UpdateReset::FailedTrial,
            UpdateReset::Refused,
            UpdateReset::Held,
        ] {
            let info = BootInfo {
                first_boot,
                update_reset,
            };
            assert!(info.to_bits() <= BootInfo::ALL_BITS);
            assert_eq!(BootInfo::from_bits(info.to_bits()), Some(info));
        }
    }
    assert_eq!(
        BootInfo {
            first_boot: true,
            update_reset: UpdateReset::None
        }
        .to_bits(),
        1
    );
    // Both reset causes at once, or a bit above bit 2: no firmware sends it.
    assert_eq!(BootInfo::from_bits(0b110), None);
    assert_eq!(BootInfo::from_bits(0b1010), None);
    assert_eq!(BootInfo::from_bits(0b1_1000), None);
    assert_eq!(BootInfo::from_bits(0b10_0000), None);
}

#[test]
fn a_restore_keeps_the_values_the_firmware_sets() {
    let mut registers = Registers::defaults();
    for (reg, value) in [
        (Reg::BootInfo, 1),
        (Reg::FlashErasesLo, 70),
        (Reg::CanTxDropped, 3),
    ] {
        registers.set_counter(reg, value);
    }
    registers.write(Reg::RadR.address(), 150).unwrap();
    registers
        .write(Reg::Command.address(), RESTORE_DEFAULTS_KEY)
        .unwrap();
    assert_eq!(registers.get(Reg::RadR), Reg::RadR.info().default);
    assert_eq!(registers.get(Reg::BootInfo), 1);
    assert_eq!(registers.get(Reg::FlashErasesLo), 70);
    assert_eq!(registers.get(Reg::CanTxDropped), 3);
}
