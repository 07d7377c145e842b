//! The firmware update's chip side: which app slot this image was started from (the
//! bootloader's choice, read from the partition table's booted partition), the chip id
//! images must carry, and the whole flash as the update task's NOR flash (it reaches
//! only the inactive slot and otadata through `base_runtime::update::UpdateFlash`),
//! and the reset-cause record the next boot reads to tell an update's reset from a
//! fault.

use base_core::update::image::Chip;
use base_core::update::otadata::Slot;
use base_core::update::partitions;
use base_core::update::signature::Trust;
use base_core::update::trial::{self, ResetRecord};
use base_runtime::update::{ResetRequest, Started, UpdateFlash};
use embassy_embedded_hal::adapter::BlockingAsync;
use esp_bootloader_esp_idf::partitions::{PARTITION_TABLE_MAX_LEN, read_partition_table};
use esp_hal::peripherals::FLASH;
use esp_storage::FlashStorage;

use crate::board;

/// The chip images for this build must be made for.
#[cfg(feature = "esp32")]
pub const CHIP: Chip = Chip::Esp32;
#[cfg(feature = "esp32c3")]
pub const CHIP: Chip = Chip::Esp32c3;
#[cfg(feature = "esp32c6")]
pub const CHIP: Chip = Chip::Esp32c6;

// `UPDATE_KEYS` and `SECURITY_VERSION`, from `BASE_UPDATE_KEY` and
// `BASE_SECURITY_VERSION` at build time (firmware/build.rs).
include!(concat!(env!("OUT_DIR"), "/update_trust.rs"));

/// Which images an update may activate: only those signed by a key the build was
/// given, or any image in a development build (no key given).
pub const TRUST: Trust<'static> = Trust::of_keys(UPDATE_KEYS);

/// The slot the bootloader started, or `None` when the image runs from elsewhere (a
/// board still on the old partition table): then no update is offered.
fn running_slot(flash: &mut FlashStorage<'_>) -> Option<Slot> {
    let mut buffer = [0u8; PARTITION_TABLE_MAX_LEN];
    let table = read_partition_table(flash, &mut buffer).ok()?;
    let booted = table.booted_partition().ok()??;
    [Slot::Ota0, Slot::Ota1]
        .into_iter()
        .find(|&slot| partitions::slot(slot).offset == booted.offset())
}

/// The image's first flash write, straight after `esp_hal::init` and the watchdog and
/// before anything else that can fail (the board's setup, the heap, the scheduler, the
/// partition lookups): a new image arms its trial here, so that a panic or a hang
/// anywhere later boots the previous image (docs/flashing.md says what still cannot
/// be rolled back). The flash is borrowed for this alone, blocking, with nothing else
/// running. `None` on a board without app slots: no updates there.
pub async fn arm_first(flash: FLASH<'_>) -> Option<(Slot, Started)> {
    let mut storage = board::flash_storage(flash);
    let slot = running_slot(&mut storage)?;
    let mut whole = UpdateFlash::new(BlockingAsync::new(&mut storage), slot);
    Some((slot, base_runtime::update::arm(&mut whole).await))
}

/// The reset-cause record ([`ResetRecord`]) in RTC fast RAM: kept across software and
/// watchdog resets, zeroed by esp-hal after a power-on (which reads as empty).
#[esp_hal::ram(unstable(rtc_fast, persistent))]
static mut RESET_RECORD: [u32; 3] = [0; 3];

fn load() -> ResetRecord {
    // SAFETY: a plain three-word read of our own static; whole records are written
    // below, and a torn one fails the record's check word.
    ResetRecord::decode(unsafe { (&raw const RESET_RECORD).read_volatile() })
}

fn store(record: ResetRecord) {
    // SAFETY: as in `load`; one executor thread, no interrupt touches the record.
    unsafe { (&raw mut RESET_RECORD).write_volatile(record.encode()) }
}

/// At boot, once the image's start is known (after its arming): whether an update's
/// reset started this boot and who activated an image on trial; the record this run
/// keeps for the next boot is stored.
pub fn boot_cause(started: &Started, running: Slot) -> trial::BootCause {
    let boot = trial::boot_cause(load(), &started.start, started.written, running);
    store(boot.keep);
    boot
}

/// Just before the reset the update task asked for.
pub fn record_reset(request: ResetRequest) {
    store(request.record());
}
