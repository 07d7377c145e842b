//! The firmware update's chip side: which app slot this image was started from (the
//! bootloader's choice, read from the partition table's booted partition), the chip id
//! images must carry, and the whole flash as the update task's NOR flash (it reaches
//! only the inactive slot and otadata through `base_runtime::update::UpdateFlash`).

use base_core::update::image::Chip;
use base_core::update::otadata::Slot;
use base_core::update::partitions;
use esp_bootloader_esp_idf::partitions::{PARTITION_TABLE_MAX_LEN, read_partition_table};
use esp_storage::FlashStorage;

/// The chip images for this build must be made for.
#[cfg(feature = "esp32")]
pub const CHIP: Chip = Chip::Esp32;
#[cfg(feature = "esp32c3")]
pub const CHIP: Chip = Chip::Esp32c3;
#[cfg(feature = "esp32c6")]
pub const CHIP: Chip = Chip::Esp32c6;

/// The slot the bootloader started, or `None` when the image runs from elsewhere (a
/// board still on the old partition table): then no update is offered.
pub fn running_slot(flash: &mut FlashStorage<'_>) -> Option<Slot> {
    let mut buffer = [0u8; PARTITION_TABLE_MAX_LEN];
    let table = read_partition_table(flash, &mut buffer).ok()?;
    let booted = table.booted_partition().ok()??;
    [Slot::Ota0, Slot::Ota1]
        .into_iter()
        .find(|&slot| partitions::slot(slot).offset == booted.offset())
}
