//! The firmware update task: it takes the update frames (0x2E8, 0x2EC) from the CAN
//! receive task, runs the core's [`Updater`] and does the flash work it asks for,
//! through an [`UpdateFlash`] that reaches only the inactive slot and otadata. It
//! answers on 0x2EA, tells the controller whether motion is locked, and returns when
//! the chip must reset (after activation or a rejected trial): the shell resets.
//!
//! Pacing: the core acknowledges a window only after it is erased, written and read
//! back, and the PC sends at most a sub-block of frames before each acknowledgement,
//! so the frames in flight never exceed [`UPDATE_QUEUE`]. While the flash works the
//! frames wait in the queue; one that finds it full is dropped and counted, and the PC
//! sends it again when its acknowledgement does not come.

use core::cell::Cell;

use embassy_futures::select::{Either, select};
use embassy_futures::yield_now;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::channel::Channel;
use embassy_time::{Duration, Instant, Ticker, Timer};

use base_core::can::update::{DataFrame, UpdateCommand, UpdateError, UpdateReply};
use base_core::can::{FrameError, RawFrame, id};
use base_core::time::Timestamp;
use base_core::update::image::Chip;
use base_core::update::otadata::{ENTRY_LEN, OtaData, PROGRAM_ORDER, SectorWrite, Slot};
use base_core::update::partitions::{self, Partition};
use base_core::update::session::{Event, FlashOp, MotionGate, Params, Updater};
use base_core::update::signature::Trust;
use base_core::update::trial::{self, ResetRecord, Start, StartRole};

use crate::can::FrameQueue;
use crate::hw::NorFlash;
use crate::sync::RawMutex;

pub use base_core::update::PROJECT;

/// Update frames the queue holds: a sub-block of 24 data frames and the PC's commands.
pub const UPDATE_QUEUE: usize = 32;

/// How often the session's timeouts are checked.
const TICK_MS: u64 = 100;

/// After the last reply before a reset, the transmit task gets this long to send it.
const REPLY_FLUSH_MS: u64 = 50;

/// How long an image on trial waits for CONFIRM before it rejects itself and resets.
pub const TRIAL_DEADLINE_MS: u64 = 120_000;

/// Between the CAN receive task, the controller task and the update task.
pub struct UpdateLink {
    frames: Channel<RawMutex, RawFrame, UPDATE_QUEUE>,
    dropped: Mutex<RawMutex, Cell<u32>>,
    locked: Mutex<RawMutex, Cell<bool>>,
    gate: Mutex<RawMutex, Cell<MotionGate>>,
}

impl UpdateLink {
    pub const fn new() -> Self {
        Self {
            frames: Channel::new(),
            dropped: Mutex::new(Cell::new(0)),
            // An image on trial is locked by [`Self::lock_at_start`], before the tasks
            // start.
            locked: Mutex::new(Cell::new(false)),
            gate: Mutex::new(Cell::new(MotionGate {
                at_standstill: false,
                brakes_applied: false,
                control_active: false,
            })),
        }
    }

    /// Whether the CAN receive task hands `frame_id` to the update task.
    pub fn takes(frame_id: u16) -> bool {
        id::UPDATE.contains(&frame_id)
    }

    /// Queues an update frame without waiting: the CAN receive task must never stall
    /// on it. A full queue drops the frame and counts it.
    pub fn offer(&self, frame: RawFrame) {
        if self.frames.try_send(frame).is_err() {
            self.dropped
                .lock(|dropped| dropped.set(dropped.get().wrapping_add(1)));
        }
    }

    /// Update frames dropped because the queue was full.
    pub fn dropped(&self) -> u32 {
        self.dropped.lock(Cell::get)
    }

    /// Before the tasks start: motion is refused from the controller's first input on
    /// when the image starts on trial or held.
    pub fn lock_at_start(&self, started: &Started) {
        self.set_locked(started.role().on_trial() || started.held());
    }

    /// Motion is refused: a session runs or an image is on trial.
    pub fn locked(&self) -> bool {
        self.locked.lock(Cell::get)
    }

    /// The controller's word on motion, after each input.
    pub fn set_gate(&self, gate: MotionGate) {
        self.gate.lock(|cell| cell.set(gate));
    }

    fn gate(&self) -> MotionGate {
        self.gate.lock(Cell::get)
    }

    fn set_locked(&self, locked: bool) {
        self.locked.lock(|cell| cell.set(locked));
    }
}

impl Default for UpdateLink {
    fn default() -> Self {
        Self::new()
    }
}

/// Why an [`UpdateFlash`] operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateFlashError {
    /// Outside the inactive slot, or not sector-aligned: refused, nothing touched.
    OutOfBounds,
    /// The flash reported an error.
    Flash,
    /// What was read back differs from what was written.
    ReadBack,
}

/// The flash as the update task may see it: the slot that is not running and the two
/// otadata sectors. Offsets are relative to the slot; nothing else can be addressed.
pub struct UpdateFlash<F> {
    flash: F,
    running: Slot,
    target: Partition,
}

/// Bytes compared per read during read-back.
const CHUNK: usize = 256;
/// Bytes programmed per write: one flash page. The chip runs nothing while its flash
/// erases or programs, so the task yields after the erase and after each page: a
/// control cycle that fell due during one runs before the next, and is late by one
/// erase (45 ms typical) or one page (0.5 ms), not by the whole window's flash work.
const PAGE: usize = 256;

impl<F: NorFlash> UpdateFlash<F> {
    /// `flash` is the whole chip, laid out as [`partitions`] says.
    pub fn new(flash: F, running: Slot) -> Self {
        Self {
            flash,
            running,
            target: partitions::slot(running.other()),
        }
    }

    pub fn running(&self) -> Slot {
        self.running
    }

    /// Erases the sector at `offset` in the inactive slot, writes `data` there (the
    /// tail padded with 0xFF to the write size) and reads it back.
    pub async fn write_window(&mut self, offset: u32, data: &[u8]) -> Result<(), UpdateFlashError> {
        let sector = F::ERASE_SIZE as u32;
        if !offset.is_multiple_of(sector)
            || data.len() > F::ERASE_SIZE
            || offset
                .checked_add(sector)
                .is_none_or(|end| end > self.target.len)
        {
            return Err(UpdateFlashError::OutOfBounds);
        }
        let at = self.target.offset + offset;
        self.program(at, data).await
    }

    /// Reads both otadata entries.
    pub async fn read_otadata(&mut self) -> Result<OtaData, UpdateFlashError> {
        let mut first = [0u8; ENTRY_LEN];
        let mut second = [0u8; ENTRY_LEN];
        let base = partitions::OTADATA.offset;
        let sector = partitions::OTADATA.len / 2;
        self.flash
            .read(base, &mut first)
            .await
            .map_err(|_| UpdateFlashError::Flash)?;
        self.flash
            .read(base + sector, &mut second)
            .await
            .map_err(|_| UpdateFlashError::Flash)?;
        Ok(OtaData::decode(&first, &second))
    }

    /// Rewrites one otadata sector: erase, then the entry's program operations in
    /// [`PROGRAM_ORDER`], each read back before the next, so that the CRC, which makes
    /// the entry valid, is programmed last.
    pub async fn write_otadata(&mut self, write: SectorWrite) -> Result<(), UpdateFlashError> {
        if write.sector > 1 {
            return Err(UpdateFlashError::OutOfBounds);
        }
        let at = partitions::OTADATA.offset + write.sector as u32 * (partitions::OTADATA.len / 2);
        self.erase(at).await?;
        let bytes = write.entry.encode();
        for range in PROGRAM_ORDER {
            self.program_erased(at + range.start as u32, &bytes[range])
                .await?;
        }
        Ok(())
    }

    async fn program(&mut self, at: u32, data: &[u8]) -> Result<(), UpdateFlashError> {
        self.erase(at).await?;
        self.program_erased(at, data).await
    }

    async fn erase(&mut self, at: u32) -> Result<(), UpdateFlashError> {
        let sector = F::ERASE_SIZE as u32;
        self.flash
            .erase(at, at + sector)
            .await
            .map_err(|_| UpdateFlashError::Flash)?;
        yield_now().await;
        Ok(())
    }

    /// Programs `data` at `at`, in erased flash, and reads it back.
    async fn program_erased(&mut self, at: u32, data: &[u8]) -> Result<(), UpdateFlashError> {
        let aligned = data.len() - data.len() % F::WRITE_SIZE;
        for (index, page) in data[..aligned].chunks(PAGE).enumerate() {
            self.flash
                .write(at + (index * PAGE) as u32, page)
                .await
                .map_err(|_| UpdateFlashError::Flash)?;
            yield_now().await;
        }
        if aligned < data.len() {
            let mut tail = [0xFFu8; 64];
            let tail = &mut tail[..F::WRITE_SIZE];
            tail[..data.len() - aligned].copy_from_slice(&data[aligned..]);
            self.flash
                .write(at + aligned as u32, tail)
                .await
                .map_err(|_| UpdateFlashError::Flash)?;
        }
        let mut back = [0u8; CHUNK];
        for (index, expected) in data.chunks(CHUNK).enumerate() {
            let read_len = expected.len().next_multiple_of(F::READ_SIZE);
            let back = &mut back[..read_len];
            self.flash
                .read(at + (index * CHUNK) as u32, back)
                .await
                .map_err(|_| UpdateFlashError::Flash)?;
            if &back[..expected.len()] != expected {
                return Err(UpdateFlashError::ReadBack);
            }
        }
        Ok(())
    }
}

/// What the running image is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UpdateConfig<'a> {
    pub chip: Chip,
    pub project: &'a str,
    pub version: &'a str,
    /// The app descriptor's `secure_version` of the running image.
    pub security_version: u32,
    /// Which images an update may activate (the keys the build carries).
    pub trust: Trust<'a>,
    pub trial_deadline_ms: u64,
}

/// How the image started: what it found in otadata ([`trial::on_start`]) and whether
/// its first write is done.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Started {
    pub start: Start,
    /// `start.write` is done and read back (or there was none).
    pub written: bool,
}

impl Started {
    pub const fn role(&self) -> StartRole {
        self.start.role
    }

    /// Runs held ([`Start::held`]): motion locked until a person decides.
    pub const fn held(&self) -> bool {
        self.start.held(self.written)
    }
}

/// First thing at start, before anything else can fail: the image's role from
/// otadata and its first write (a new image's arming, so that any reset from here on
/// boots the previous slot). A flash that cannot be read counts as a confirmed image
/// (nothing to arm; updates still work).
pub async fn arm<F: NorFlash>(flash: &mut UpdateFlash<F>) -> Started {
    let Ok(otadata) = flash.read_otadata().await else {
        warn!("otadata unreadable: running as a confirmed image");
        return Started {
            start: Start {
                role: StartRole::Confirmed,
                write: None,
                refused_activation: false,
            },
            written: true,
        };
    };
    let start = trial::on_start(&otadata, flash.running);
    let written = match start.write {
        Some(write) => flash.write_otadata(write).await.is_ok(),
        None => true,
    };
    Started { start, written }
}

/// Says at start what [`arm`] found, once the log works.
pub fn report_start(started: &Started) {
    let role = started.role();
    if role.on_trial() {
        info!("new image on trial");
    }
    if started.start.refused_activation {
        warn!("the bootloader refused the image activated last: its entry is set aside");
    }
    if role == StartRole::LastResort {
        warn!("started an image whose trial failed: no other slot boots");
    }
    if !started.written {
        error!("the first otadata write at start failed");
    }
    if started.held() {
        warn!("held: motion locked until CONFIRM keeps this image or ROLLBACK tries the other");
    }
}

/// Why the update task asks for a reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetRequest {
    /// The new image is activated by `session`: boot it on trial.
    Activated { session: u8 },
    /// The image on trial was rejected (asked for, or its deadline passed).
    RolledBack,
}

impl ResetRequest {
    /// What the shell leaves for the next boot just before it resets, so that the boot
    /// reports the update's reset rather than a watchdog reset.
    pub const fn record(self) -> ResetRecord {
        match self {
            Self::Activated { session } => ResetRecord::Activation { session },
            Self::RolledBack => ResetRecord::Rejection,
        }
    }
}

fn core_now() -> Timestamp {
    Timestamp::from_millis(Instant::now().as_millis())
}

/// Runs the update session until a reset is needed. `started` comes from [`arm`];
/// `trial_owner` from [`trial::boot_cause`]: the session that activated the image on
/// trial, which alone may confirm or roll it back.
pub async fn run<F: NorFlash>(
    flash: &mut UpdateFlash<F>,
    started: Started,
    trial_owner: Option<u8>,
    config: &UpdateConfig<'_>,
    link: &UpdateLink,
    can_tx: &FrameQueue,
) -> ResetRequest {
    let params = Params {
        chip: config.chip,
        project: config.project,
        running_version: config.version,
        running_slot: flash.running.index() as u8,
        slot_len: partitions::SLOT_LEN,
        trial_deadline_ms: config.trial_deadline_ms,
        trust: config.trust,
        running_security_version: config.security_version,
    };
    let mut updater = if started.held() {
        Updater::held(trial_owner)
    } else if started.role().on_trial() {
        Updater::on_trial(core_now(), trial_owner, &params)
    } else {
        Updater::idle()
    };
    link.set_locked(updater.locks_motion());
    // The tick comes every TICK_MS however many frames arrive, and is asked first: a
    // flood of frames (QUERY from any program, every millisecond) must not hold off
    // the silence and trial deadlines, and with them the motion lock's end.
    let mut ticker = Ticker::every(Duration::from_millis(TICK_MS));
    loop {
        let event = match select(ticker.next(), link.frames.receive()).await {
            Either::First(()) => Event::Tick,
            Either::Second(frame) => match decode(&frame) {
                Ok(Some(Decoded::Command(command))) => Event::Command(command, link.gate()),
                Ok(Some(Decoded::Data(data))) => Event::Data(data),
                Ok(None) => continue,
                Err(_) => {
                    let opcode = frame.data().first().copied().unwrap_or(0);
                    let opcode = if frame.id() == id::UPDATE_DATA {
                        0
                    } else {
                        opcode
                    };
                    can_tx.send(
                        UpdateReply::Refused {
                            opcode,
                            error: UpdateError::Malformed,
                            detail: 0,
                            // The session byte of a command that carries one (BEGIN to
                            // ABORT, opcodes 2 to 7); a data frame names none.
                            session: match opcode {
                                2..=7 => frame.data().get(1).copied().unwrap_or(0),
                                _ => 0,
                            },
                        }
                        .encode(),
                    );
                    continue;
                }
            },
        };
        let mut effects = updater.step(core_now(), event, &params);
        loop {
            for reply in &effects.replies {
                can_tx.send(reply.encode());
            }
            // Locked or released before the controller's next input.
            link.set_locked(updater.locks_motion());
            let Some(op) = effects.flash else {
                break;
            };
            let ok = match op {
                FlashOp::WriteWindow { offset } => {
                    let started = Instant::now();
                    let written = flash.write_window(offset, updater.window()).await.is_ok();
                    // The flash's real erase and write times, for the bench checklist.
                    info!(
                        "update: window at {=u32:#x} erased, written and read back in {=u64} ms",
                        offset,
                        started.elapsed().as_millis()
                    );
                    written
                }
                FlashOp::Activate { .. } => activate(flash).await,
                FlashOp::Confirm => set_running_state(flash, trial::confirm).await,
                FlashOp::Reject => set_running_state(flash, trial::reject).await,
            };
            if !ok {
                warn!("update flash operation failed");
            }
            let reset_after = matches!(op, FlashOp::Activate { .. } | FlashOp::Reject);
            effects = updater.step(core_now(), Event::FlashDone(ok), &params);
            if effects.reset && reset_after {
                for reply in &effects.replies {
                    can_tx.send(reply.encode());
                }
                Timer::after_millis(REPLY_FLUSH_MS).await;
                return match op {
                    FlashOp::Activate { session } => ResetRequest::Activated { session },
                    _ => ResetRequest::RolledBack,
                };
            }
        }
    }
}

enum Decoded {
    Command(UpdateCommand),
    Data(DataFrame),
}

fn decode(frame: &RawFrame) -> Result<Option<Decoded>, FrameError> {
    if let Some(command) = UpdateCommand::decode(frame.id(), frame.data())? {
        return Ok(Some(Decoded::Command(command)));
    }
    Ok(DataFrame::decode(frame.id(), frame.data())?.map(Decoded::Data))
}

async fn activate<F: NorFlash>(flash: &mut UpdateFlash<F>) -> bool {
    let Ok(otadata) = flash.read_otadata().await else {
        return false;
    };
    match otadata.activate(flash.running.other()) {
        Ok(write) => flash.write_otadata(write).await.is_ok(),
        Err(_) => false,
    }
}

async fn set_running_state<F: NorFlash>(
    flash: &mut UpdateFlash<F>,
    change: fn(&OtaData, Slot) -> Result<SectorWrite, base_core::update::otadata::OtaDataError>,
) -> bool {
    let Ok(otadata) = flash.read_otadata().await else {
        return false;
    };
    match change(&otadata, flash.running) {
        Ok(write) => flash.write_otadata(write).await.is_ok(),
        Err(_) => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn started(role: StartRole, written: bool) -> Started {
        Started {
            start: Start {
                role,
                write: None,
                refused_activation: false,
            },
            written,
        }
    }

    #[test]
    fn an_image_nobody_confirmed_without_a_fallback_starts_with_motion_locked() {
        // (role, first write done) → motion locked from the first input
        let cases = [
            (StartRole::Confirmed, true, false),
            (StartRole::Trial, true, true),
            (StartRole::PendingVerify, true, true),
            // Its trial failed and no other slot boots.
            (StartRole::LastResort, true, true),
            // Its arming failed: nothing would roll it back.
            (StartRole::Trial, false, true),
        ];
        for (role, written, locked) in cases {
            let link = UpdateLink::new();
            link.lock_at_start(&started(role, written));
            assert_eq!(link.locked(), locked, "{role:?}, written {written}");
        }
    }
}
