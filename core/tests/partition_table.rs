//! The flash layout in `firmware/partitions.csv`, read with the parser espflash uses to
//! write it: the data a robot keeps (registers, bond) stays where it was before the
//! update slots came, the two slots hold an image several times today's size, and
//! `otadata` is the two sectors the core's codec writes. Also that every USB flash the
//! cargo aliases run erases `otadata`.

use base_core::update::otadata::SECTOR_LEN;
use esp_idf_part::{AppType, DataType, Partition, PartitionTable, SubType, Type};

const FLASH_SIZE: u32 = 4 * 1024 * 1024;
/// The bootloader and the partition table itself lie below this offset.
const FIRST_PARTITION: u32 = 0x9000;
/// ESP-IDF places app partitions on 64 KiB boundaries (the flash MMU's page).
const APP_ALIGNMENT: u32 = 0x1_0000;
/// The smallest update slot: about 3 times the ESP32-C3 image of today (~620 KiB).
const MIN_SLOT_SIZE: u32 = 1_900_000;

fn table() -> PartitionTable {
    let csv = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../firmware/partitions.csv"
    ))
    .expect("firmware/partitions.csv");
    let table = PartitionTable::try_from_str(csv).expect("espflash parses the table");
    table.validate().expect("espflash accepts the table");
    table
}

fn partition<'a>(table: &'a PartitionTable, name: &str) -> &'a Partition {
    table
        .find(name)
        .unwrap_or_else(|| panic!("no `{name}` partition"))
}

#[test]
fn the_stores_keep_their_offsets_and_sizes() {
    let table = table();
    for (name, offset, size) in [("registers", 0x9000, 0x4000), ("bonds", 0xD000, 0x3000)] {
        let found = partition(&table, name);
        assert_eq!(found.ty(), Type::Data, "{name}");
        assert_eq!(
            (found.offset(), found.size()),
            (offset, size),
            "{name} moved: its contents would not survive the migration"
        );
    }
}

#[test]
fn two_update_slots_and_no_factory_slot() {
    let table = table();
    let apps: Vec<_> = table
        .partitions()
        .iter()
        .filter(|p| p.ty() == Type::App)
        .collect();
    assert_eq!(apps.len(), 2, "exactly ota_0 and ota_1");
    for (name, subtype) in [("ota_0", AppType::Ota_0), ("ota_1", AppType::Ota_1)] {
        let slot = partition(&table, name);
        assert_eq!(slot.subtype(), SubType::App(subtype), "{name}");
        assert!(
            slot.size() >= MIN_SLOT_SIZE,
            "{name}: {} bytes",
            slot.size()
        );
        assert_eq!(slot.offset() % APP_ALIGNMENT, 0, "{name} offset");
        assert_eq!(slot.size() % APP_ALIGNMENT, 0, "{name} size");
    }
    assert_eq!(
        partition(&table, "ota_0").size(),
        partition(&table, "ota_1").size(),
        "an image that fits one slot fits the other"
    );
}

#[test]
fn otadata_is_the_two_sectors_the_codec_writes() {
    let table = table();
    let otadata = partition(&table, "otadata");
    assert_eq!(otadata.subtype(), SubType::Data(DataType::Ota));
    assert_eq!(otadata.size(), 2 * SECTOR_LEN);
    assert_eq!(otadata.offset() % SECTOR_LEN, 0);
}

#[test]
fn nothing_overlaps_and_everything_fits_the_flash() {
    let table = table();
    let mut ranges: Vec<_> = table
        .partitions()
        .iter()
        .map(|p| (p.offset(), p.offset() + p.size(), p.name()))
        .collect();
    ranges.sort();
    assert!(
        ranges[0].0 >= FIRST_PARTITION,
        "{:?} overlaps the partition table",
        ranges[0]
    );
    for pair in ranges.windows(2) {
        assert!(
            pair[0].1 <= pair[1].0,
            "{:?} overlaps {:?}",
            pair[0],
            pair[1]
        );
    }
    let end = ranges.last().unwrap().1;
    assert!(end <= FLASH_SIZE, "the table ends at {end:#x}, past 4 MB");
}

#[test]
fn every_usb_flash_erases_otadata() {
    let config = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../.cargo/config.toml"
    ))
    .expect(".cargo/config.toml");
    let flashes: Vec<_> = config
        .lines()
        .filter(|line| line.contains("espflash flash"))
        .collect();
    assert_eq!(flashes.len(), 3, "one runner per chip: {flashes:?}");
    for line in flashes {
        assert!(line.contains("--erase-parts otadata"), "{line}");
    }
}

/// The update task, the trial and the simulator take their offsets from the core's
/// table (`base_core::update::partitions`), the bootloader and espflash from the CSV:
/// the two must name the same partitions at the same places, or an update would write
/// where the bootloader does not look.
#[test]
fn the_csv_and_the_cores_table_agree() {
    use base_core::update::partitions;
    let table = table();
    let in_csv: Vec<_> = table
        .partitions()
        .iter()
        .map(|p| (p.name(), p.offset(), p.size()))
        .collect();
    let in_core: Vec<_> = partitions::TABLE
        .iter()
        .map(|p| (p.name.to_owned(), p.offset, p.len))
        .collect();
    assert_eq!(
        in_csv, in_core,
        "firmware/partitions.csv against the core's table"
    );
    assert_eq!(FLASH_SIZE, partitions::FLASH_SIZE);
}
