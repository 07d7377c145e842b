//! The data partitions: `registers` (the register store) and `bonds` (the Bluetooth
//! remote's bond), found through the partition table that espflash writes
//! (`firmware/partitions.csv`), each as an async NOR flash that cannot reach past its
//! partition.

use core::ops::Range;

use base_runtime::store::PARTITION_PAGES;
use embassy_embedded_hal::adapter::BlockingAsync;
use embassy_embedded_hal::flash::partition::Partition;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use esp_bootloader_esp_idf::partitions::{self, PARTITION_TABLE_MAX_LEN};
use esp_storage::FlashStorage;

/// The register store's partition in `partitions.csv`, and the pages the store uses.
pub const REGISTERS: PartitionSpec = PartitionSpec {
    label: "registers",
    pages: PARTITION_PAGES,
};
/// The Bluetooth bond's partition.
pub const BONDS: PartitionSpec = PartitionSpec {
    label: "bonds",
    pages: 3,
};

/// A data partition the firmware needs: its label, and how many 4 KiB pages of it it
/// uses (the partition may be larger).
#[derive(Clone, Copy)]
pub struct PartitionSpec {
    pub label: &'static str,
    pub pages: u32,
}

/// The whole flash, shared by its partitions (the register store and the Bluetooth
/// bond). One executor thread uses it, hence the no-op mutex.
pub type SharedFlash = Mutex<NoopRawMutex, BlockingAsync<FlashStorage<'static>>>;

/// One partition of the shared flash; offsets are relative to its start.
pub type FlashPartition = Partition<'static, NoopRawMutex, BlockingAsync<FlashStorage<'static>>>;

const PAGE_SIZE: u32 = FlashStorage::SECTOR_SIZE;

/// Where `spec`'s partition lies in `flash`: the byte range the firmware uses, or `None`
/// if the partition table has no usable partition of that label (a board flashed with
/// another table).
pub fn find(flash: &mut FlashStorage<'_>, spec: PartitionSpec) -> Option<Range<u32>> {
    let mut buffer = [0u8; PARTITION_TABLE_MAX_LEN];
    let table = partitions::read_partition_table(flash, &mut buffer).ok()?;
    let entry = table
        .iter()
        .find(|entry| entry.label_as_str() == spec.label)?;
    let len = spec.pages * PAGE_SIZE;
    let usable = entry.offset() % PAGE_SIZE == 0 && entry.len() >= len;
    usable.then(|| entry.offset()..entry.offset() + len)
}

/// A view of `spec`'s partition and the range to give its user (relative to the
/// view). Without a usable partition the view has size zero: every access fails, so
/// the register store runs on the defaults and reports the flash fault, the remote
/// keeps no bond, and nothing writes to flash it does not own.
pub fn partition(
    flash: &'static SharedFlash,
    spec: PartitionSpec,
    found: Option<Range<u32>>,
) -> (FlashPartition, Range<u32>) {
    let view = match found {
        Some(range) => Partition::new(flash, range.start, range.end - range.start),
        None => Partition::new(flash, 0, 0),
    };
    (view, 0..spec.pages * PAGE_SIZE)
}
