//! The boot-time trial of a new image, over the chip's flash: the decisions are the
//! core's (`base_core::update::trial`), this file reads and writes `otadata` and keeps
//! the record that lets the next boot tell why the chip was reset.
//!
//! 1. [`begin`], first thing after the watchdog is armed: finds `otadata` and the slot
//!    the bootloader started (the flash MMU's mapping, read by esp-bootloader-esp-idf),
//!    and if its entry is `New` rewrites it `Aborted` ("armed"): from then on any reset
//!    (a panic, the watchdog, a power cut) starts the previous slot. With a bootloader
//!    that has rollback the entry reads `PendingVerify` and that bootloader aborts it on
//!    the next reset by itself.
//! 2. [`watch`]: the health checks ([`base_core::update::trial::healthy`]: the drives
//!    answered, CAN is up, the register store was read) from the status frames the
//!    controller sends; when they pass, the entry becomes `Valid`. When they have not
//!    passed within [`TRIAL_DEADLINE_MS`], the entry becomes `Invalid` and the chip
//!    resets into the previous image.
//!
//! The register store is not migrated by an image on trial, nor by any other: records
//! of an older schema are converted in RAM as they are read and stay on the flash as
//! they are, so the previous image reads the store as it left it after a rollback.
//!
//! The reset cause: an image on trial leaves a record in RTC fast memory (which keeps
//! its contents across software and watchdog resets, not across power-on) and clears
//! it when it confirms. The next boot that finds the record of another image's trial
//! reports a failed trial; the first boot of an image on trial reports the activation.
//! Neither counts as a watchdog reset.

use core::sync::atomic::{AtomicBool, Ordering};

use base_core::can::{Status, id};
use base_core::registers::UpdateReset;
use base_core::time::Timestamp;
use base_core::update::otadata::{ENTRY_LEN, OtaData, SECTOR_LEN, SectorWrite, Slot};
use base_core::update::trial::{
    self, StartRole, TRIAL_DEADLINE_MS, TrialEffect, TrialEvent, TrialParams, TrialWatch,
};
use base_runtime::hw::CanFrame;
use defmt::{error, info, warn};
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use embedded_can::Id;
use esp_bootloader_esp_idf::partitions::{
    self, AppPartitionSubType, DataPartitionSubType, PARTITION_TABLE_MAX_LEN, PartitionType,
};
use esp_storage::FlashStorage;

use crate::flash::SharedFlash;

/// How often the watch looks at the deadline when no status frame comes.
const WATCH_TICK_MS: u64 = 1_000;

/// The status frames the controller sent while on trial, with the bus state after them
/// (latest wins: only the newest status matters).
pub static STATUS_SENT: Signal<CriticalSectionRawMutex, TrialEvent> = Signal::new();

/// A frame from another node arrived since boot: someone is on the bus.
static CAN_HEARD: AtomicBool = AtomicBool::new(false);

/// The trial record: `[RECORD_MAGIC, seq, !seq]` while the image of `seq` is on trial,
/// anything else otherwise. Persistent: not initialised at a software or watchdog
/// reset; zeroed after power-on by esp-hal.
#[esp_hal::ram(unstable(rtc_fast, persistent))]
static mut TRIAL_RECORD: [u32; 3] = [0; 3];
const RECORD_MAGIC: u32 = 0x7219_A1B0;

fn read_record() -> Option<u32> {
    // SAFETY: read once at start-up, before any task runs; a plain copy of three words.
    let [magic, seq, check] = unsafe { core::ptr::addr_of!(TRIAL_RECORD).read_volatile() };
    (magic == RECORD_MAGIC && check == !seq).then_some(seq)
}

fn write_record(seq: Option<u32>) {
    let record = match seq {
        Some(seq) => [RECORD_MAGIC, seq, !seq],
        None => [0; 3],
    };
    // SAFETY: only this module touches the record, from one executor thread.
    unsafe { core::ptr::addr_of_mut!(TRIAL_RECORD).write_volatile(record) }
}

/// What [`begin`] found.
pub struct Trial {
    role: StartRole,
    running: Option<Slot>,
    /// Where `otadata` starts in flash, if the partition table has it.
    otadata: Option<u32>,
    /// An update's reset before this boot, for `boot_info`.
    pub update_reset: UpdateReset,
}

impl Trial {
    /// Whether this image runs on trial (not confirmed yet).
    pub fn on_trial(&self) -> bool {
        self.role.on_trial()
    }
}

/// Reads the partition table, `otadata` and the trial record; arms a new image. Call
/// it right after the watchdog is armed, before anything that could hang or panic.
pub fn begin(flash: &mut FlashStorage<'_>) -> Trial {
    let previous_trial = read_record();
    let (otadata, running) = locate(flash);
    let data = match (otadata, running) {
        (Some(offset), Some(_)) => {
            let data = read_otadata(flash, offset);
            if data.is_err() {
                error!("otadata unreadable: running without a trial");
            }
            data.ok()
        }
        // An old partition table (a factory slot, no otadata): no updates, no trial.
        _ => None,
    };
    let (role, running_seq) = match (data, running) {
        (Some(data), Some(slot)) => (
            trial::on_start(&data, slot),
            data.entry_of(slot).map(|sector| data.sectors[sector].seq),
        ),
        _ => (StartRole::Unrecorded, None),
    };
    if let (StartRole::Trial { arm }, Some(offset)) = (role, otadata) {
        match write_otadata(flash, offset, arm) {
            Ok(()) => info!("new image on trial: armed (seq {=u32})", arm.entry.seq),
            // The entry stays New: a reset before the confirm starts this image again,
            // and its trial with it.
            Err(()) => error!("new image on trial: arming failed"),
        }
    }
    let update_reset = if role.on_trial() {
        write_record(running_seq);
        UpdateReset::Activation
    } else {
        write_record(None);
        match previous_trial {
            Some(seq) if Some(seq) != running_seq => UpdateReset::FailedTrial,
            _ => UpdateReset::None,
        }
    };
    match role {
        StartRole::LastResort => {
            warn!("this image's trial failed, but no other slot boots: running it")
        }
        StartRole::Unrecorded => info!("no otadata entry names this slot (flashed over USB)"),
        _ => {}
    }
    if update_reset == UpdateReset::FailedTrial {
        warn!("the last reset ended a new image's trial: rolled back to this image");
    }
    Trial {
        role,
        running,
        otadata,
        update_reset,
    }
}

/// Watches the health of an image on trial and confirms or rejects it (see the module
/// doc). Returns at once for an image not on trial; otherwise after the confirm (a
/// rejection resets the chip).
pub async fn watch(trial: Trial, flash: &'static SharedFlash) {
    let (Some(offset), Some(running)) = (trial.otadata, trial.running) else {
        return;
    };
    if !trial.on_trial() {
        return;
    }
    let params = TrialParams::DEFAULT;
    let mut watch = TrialWatch::start(now());
    info!("trial: health checks within {=u64} ms", TRIAL_DEADLINE_MS);
    loop {
        let event = match select(STATUS_SENT.wait(), Timer::after_millis(WATCH_TICK_MS)).await {
            Either::First(event) => event,
            Either::Second(()) => TrialEvent::Tick,
        };
        match watch.step(now(), event, &params) {
            TrialEffect::Wait => {}
            TrialEffect::Confirm => {
                match rewrite_shared(flash, offset, |data| trial::confirm(data, running)).await {
                    Ok(()) => {
                        write_record(None);
                        info!("trial passed: this image is confirmed");
                    }
                    // The entry stays Aborted: the next reset starts the previous image.
                    Err(()) => error!("trial passed, but the confirm could not be written"),
                }
                return;
            }
            TrialEffect::Reject => {
                error!("trial failed: health checks not passed in time; rolling back");
                if rewrite_shared(flash, offset, |data| trial::reject(data, running))
                    .await
                    .is_err()
                {
                    // Armed (Aborted) already: the reset rolls back all the same.
                    error!("the rejection could not be written");
                }
                // The record stays: the next boot reports the failed trial.
                esp_hal::system::software_reset();
            }
        }
    }
}

/// Called by the CAN transmit half after each frame the controller took: the status
/// frames feed the trial watch.
pub fn frame_sent(frame: &impl CanFrame, bus_active: bool) {
    let Id::Standard(standard) = frame.id() else {
        return;
    };
    if standard.as_raw() != id::STATUS {
        return;
    }
    let Ok(bytes) = <[u8; 8]>::try_from(frame.data()) else {
        return;
    };
    if let Ok(status) = Status::from_bytes(bytes) {
        STATUS_SENT.signal(TrialEvent::StatusSent {
            status,
            bus_active: bus_active && CAN_HEARD.load(Ordering::Relaxed),
        });
    }
}

/// Called by the CAN receive half for each frame received.
pub fn frame_received() {
    CAN_HEARD.store(true, Ordering::Relaxed);
}

fn now() -> Timestamp {
    Timestamp::from_millis(Instant::now().as_millis())
}

/// `otadata`'s offset and the slot the bootloader started.
fn locate(flash: &mut FlashStorage<'_>) -> (Option<u32>, Option<Slot>) {
    let mut buffer = [0u8; PARTITION_TABLE_MAX_LEN];
    let Ok(table) = partitions::read_partition_table(flash, &mut buffer) else {
        error!("partition table unreadable");
        return (None, None);
    };
    let otadata = table
        .iter()
        .find(|entry| {
            entry.partition_type() == PartitionType::Data(DataPartitionSubType::Ota)
                && entry.len() >= 2 * SECTOR_LEN
        })
        .map(|entry| entry.offset());
    let running = match table.booted_partition() {
        Ok(Some(entry)) => match entry.partition_type() {
            PartitionType::App(AppPartitionSubType::Ota0) => Some(Slot::Ota0),
            PartitionType::App(AppPartitionSubType::Ota1) => Some(Slot::Ota1),
            _ => None,
        },
        _ => None,
    };
    (otadata, running)
}

fn read_otadata(flash: &mut FlashStorage<'_>, offset: u32) -> Result<OtaData, ()> {
    let mut sectors = [[0u8; ENTRY_LEN]; 2];
    for (index, sector) in sectors.iter_mut().enumerate() {
        flash
            .read_nor(offset + index as u32 * SECTOR_LEN, sector)
            .map_err(|_| ())?;
    }
    Ok(OtaData::decode(&sectors[0], &sectors[1]))
}

/// One sector rewritten: erase, then program the entry (see `otadata`'s module doc for
/// why every such write is safe on its own).
fn write_otadata(flash: &mut FlashStorage<'_>, offset: u32, write: SectorWrite) -> Result<(), ()> {
    let start = offset + write.sector as u32 * SECTOR_LEN;
    flash.erase(start, start + SECTOR_LEN).map_err(|_| ())?;
    flash
        .write_nor(start, &write.entry.encode())
        .map_err(|_| ())
}

/// Reads `otadata` through the shared flash and writes what `change` makes of it.
async fn rewrite_shared(
    flash: &'static SharedFlash,
    offset: u32,
    change: impl FnOnce(&OtaData) -> Result<SectorWrite, base_core::update::otadata::OtaDataError>,
) -> Result<(), ()> {
    use embedded_storage_async::nor_flash::{NorFlash, ReadNorFlash};
    let mut flash = flash.lock().await;
    let mut sectors = [[0u8; ENTRY_LEN]; 2];
    for (index, sector) in sectors.iter_mut().enumerate() {
        flash
            .read(offset + index as u32 * SECTOR_LEN, sector)
            .await
            .map_err(|_| ())?;
    }
    let write = change(&OtaData::decode(&sectors[0], &sectors[1])).map_err(|_| ())?;
    let start = offset + write.sector as u32 * SECTOR_LEN;
    flash
        .erase(start, start + SECTOR_LEN)
        .await
        .map_err(|_| ())?;
    flash
        .write(start, &write.entry.encode())
        .await
        .map_err(|_| ())
}
