//! The register store's flash: the `registers` partition, found through the partition
//! table that espflash writes (`firmware/partitions.csv`), as an async NOR flash that
//! cannot reach past the partition.

use core::ops::Range;

use base_controller::store::PARTITION_PAGES;
use embassy_embedded_hal::adapter::BlockingAsync;
use embassy_embedded_hal::flash::partition::Partition;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use esp_bootloader_esp_idf::partitions::{self, PARTITION_TABLE_MAX_LEN};
use esp_storage::FlashStorage;

/// The label of the register store's partition in `partitions.csv`.
pub const REGISTERS_LABEL: &str = "registers";

/// The whole flash, shared by its partitions (the register store now, the Bluetooth
/// bond later). One executor thread uses it, hence the no-op mutex.
pub type SharedFlash = Mutex<NoopRawMutex, BlockingAsync<FlashStorage<'static>>>;

/// One partition of the shared flash; offsets are relative to its start.
pub type FlashPartition = Partition<'static, NoopRawMutex, BlockingAsync<FlashStorage<'static>>>;

const PAGE_SIZE: u32 = FlashStorage::SECTOR_SIZE;

/// Where the register store lives in `flash`: its byte range, or `None` if the
/// partition table has no usable `registers` partition (flashed with another table).
pub fn find_registers(flash: &mut FlashStorage<'_>) -> Option<Range<u32>> {
    let mut buffer = [0u8; PARTITION_TABLE_MAX_LEN];
    let table = partitions::read_partition_table(flash, &mut buffer).ok()?;
    let entry = table
        .iter()
        .find(|entry| entry.label_as_str() == REGISTERS_LABEL)?;
    let usable = entry.offset() % PAGE_SIZE == 0 && entry.len() >= PARTITION_PAGES * PAGE_SIZE;
    usable.then(|| entry.offset()..entry.offset() + PARTITION_PAGES * PAGE_SIZE)
}

/// The register store's partition and the range to give the store. Without a usable
/// partition the store gets a partition of size zero: every access fails, so the
/// controller runs on the defaults and reports the flash fault, and nothing writes to
/// flash it does not own.
pub fn registers_partition(
    flash: &'static SharedFlash,
    found: Option<Range<u32>>,
) -> (FlashPartition, Range<u32>) {
    let store_len = PARTITION_PAGES * PAGE_SIZE;
    let partition = match found {
        Some(range) => Partition::new(flash, range.start, range.end - range.start),
        None => Partition::new(flash, 0, 0),
    };
    (partition, 0..store_len)
}
