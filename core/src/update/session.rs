//! The update session: what the base controller does with each update command and data
//! frame, as a pure state machine. The update task in the runtime owns the flash and
//! does what the [`Effects`] ask; it feeds back the result as [`Event::FlashDone`].
//!
//! ```text
//!            BEGIN (at rest, no control source)        WINDOW i, data..., CRC ok
//!   Idle ─────────────────────────────────────▶ Open ──────────────────────▶ (Writing i)
//!    ▲  ▲                                     │  │ ◀───── FlashDone ok ──────────┘
//!    │  └──── ABORT, 10 s silence, bad image, │  │
//!    │         bad digest, flash failure ─────┘  │ FINISH, SHA-256 ok, whole image ok
//!    │                                           ▼
//!    │ ◀──────────── FlashDone (reset) ───── Activating ◀── ACTIVATE ── Finished
//!
//!   OnTrial (from boot) ── CONFIRM ──▶ Confirming ── FlashDone ok ──▶ Idle
//!           ── ROLLBACK or deadline ──▶ Rejecting ── FlashDone ok ──▶ (reset)
//! ```
//!
//! Only the session that activated the image may CONFIRM or ROLLBACK it, when the boot
//! knows that session (the reset record carries it across the activation's reset); a
//! stranger's is refused with `NotTrialOwner`, and the deadline still rejects an image
//! nobody confirms.
//!
//! A transfer moves the image in 4 KiB windows. For each, the PC announces the index
//! and the CRC-32, then sends data frames (a sequence byte, 7 bytes). READY n says the
//! controller has every frame before n; the PC may send up to [`SUB_BLOCK`] frames
//! from n on and no further: the controller paces the sender, so its receive queue
//! never overflows. READY comes every [`READY_EVERY`] frames, half the credit, so the
//! next READY is on its way while the PC still has frames to send and the bus never
//! waits for the round trip. A complete
//! window whose CRC matches is erased, written and read back by the update task, then
//! acknowledged with WRITTEN; a mismatch is answered `BadCrc` and the PC sends the
//! window again. Window 0 holds the image header and app descriptor: they are checked
//! (chip, project, version) before the first byte is written. FINISH answers DONE only
//! when the whole image passes the bootloader's own checks (segments, checksum, appended
//! SHA-256), checked window by window as they arrive. Only the inactive slot is
//! written, at offsets below the announced size; [`Effects`] say where.

use heapless::Vec;
use sha2::{Digest, Sha256};

use super::image::{self, Chip, ImageInfo, WholeImageCheck};
use super::signature::{self, SignatureError, Trust};
use crate::can::update::{
    BeginFlags, DATA_BYTES, DataFrame, Phase, Step, UpdateCommand, UpdateError, UpdateReply,
    VERSION_CHUNK, VERSION_CHUNKS,
};
use crate::time::Timestamp;

/// Bytes of one window: one flash sector.
pub const WINDOW_LEN: usize = 4096;
/// Data frames the PC may send from the frame a READY names, before the next READY.
/// The chip's CAN receive queue holds 32 frames; the rest is margin for the PC's other
/// commands.
pub const SUB_BLOCK: u16 = 24;
/// The controller answers READY after every this many frames of a window.
pub const READY_EVERY: u16 = SUB_BLOCK / 2;
/// A session whose PC is silent this long ends, and the motion lock with it.
pub const SILENCE_MS: u64 = 10_000;
/// Parts of 4 bytes the SHA-256 is announced in.
pub const DIGEST_PARTS: u8 = 8;

const ALL_DIGEST_PARTS: u8 = 0xFF;
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// The CRC-32 (IEEE, as zlib's) of a window's bytes.
pub fn window_crc(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}

/// How many windows an image of `size` bytes takes.
pub const fn window_count(size: u32) -> u16 {
    size.div_ceil(WINDOW_LEN as u32) as u16
}

/// The bytes of window `index` of an image of `size` bytes.
pub const fn window_len(size: u32, index: u16) -> usize {
    let start = index as u32 * WINDOW_LEN as u32;
    let rest = size.saturating_sub(start);
    if rest > WINDOW_LEN as u32 {
        WINDOW_LEN
    } else {
        rest as usize
    }
}

/// How many data frames carry `len` bytes.
pub const fn frame_count(len: usize) -> u16 {
    len.div_ceil(DATA_BYTES) as u16
}

/// What the controller reports about motion, for BEGIN.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionGate {
    /// Zero commanded and both wheels measured at rest.
    pub at_standstill: bool,
    /// The drives are de-excited and confirmed it: the brakes hold the base.
    pub brakes_applied: bool,
    /// A CAN enable is fresh or the gamepad's dead-man is held.
    pub control_active: bool,
}

/// What the running firmware is, and the limits of the slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Params<'a> {
    pub chip: Chip,
    pub project: &'a str,
    pub running_version: &'a str,
    /// The running slot, for the state reply (0, 1, or 0xFF for none).
    pub running_slot: u8,
    /// Bytes of the inactive slot.
    pub slot_len: u32,
    /// How long an image on trial waits for CONFIRM before it rejects itself.
    pub trial_deadline_ms: u64,
    /// Which images may be activated.
    pub trust: Trust<'a>,
    /// The running image's security version: no image below it activates unless its
    /// owner signed the downgrade.
    pub running_security_version: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// A command, with the controller's motion state at that moment.
    Command(UpdateCommand, MotionGate),
    Data(DataFrame),
    /// The flash operation the last effects asked for ended (`true`: done and read back).
    FlashDone(bool),
    /// Time passed: the silence and trial timeouts are checked.
    Tick,
}

/// A flash operation for the update task. Offsets are inside the inactive slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashOp {
    /// Erase the sector at `offset`, write [`Updater::window`] there, read it back.
    WriteWindow { offset: u32 },
    /// Write `{next seq, New}` for the inactive slot into otadata; reset afterwards,
    /// leaving `session` for the new image: only it may confirm or roll it back.
    Activate { session: u8 },
    /// Mark the running image `Valid`.
    Confirm,
    /// Mark the running image `Invalid`; reset afterwards.
    Reject,
}

#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Effects {
    /// Frames for 0x2EA, in order.
    pub replies: Vec<UpdateReply, 8>,
    pub flash: Option<FlashOp>,
    /// Reset the controller once the replies are sent (after activation or rejection).
    pub reset: bool,
    /// The session a refusal names: the one the event belongs to.
    answering: u8,
}

impl Effects {
    fn reply(&mut self, reply: UpdateReply) {
        // At most seven replies (a state and six version parts) per event.
        let _ = self.replies.push(reply);
    }

    fn refuse(&mut self, opcode: u8, error: UpdateError, detail: u8) {
        self.reply(UpdateReply::Refused {
            opcode,
            error,
            detail,
            session: self.answering,
        });
    }
}

/// Where a window stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum WindowRx {
    /// Waiting for the next WINDOW command.
    Waiting,
    Receiving {
        index: u16,
        crc: u32,
        next: u16,
        frames: u16,
        /// The complaint (out of order, duplicate) answered since the last good
        /// frame: more frames of the same kind are dropped without a reply each.
        complained: Option<UpdateError>,
    },
    /// The update task erases, writes and reads back this window.
    Writing { index: u16 },
}

#[derive(Debug, Clone)]
struct Transfer {
    session: u8,
    size: u32,
    flags: BeginFlags,
    digest: [u8; 32],
    digest_parts: u8,
    hasher: Sha256,
    /// The bootloader's checks, over the windows as they are written.
    image_check: WholeImageCheck,
    /// The image's security version, from window 0.
    security_version: u32,
    windows_written: u16,
    window: WindowRx,
    last_heard: Timestamp,
}

// One updater exists, beside its 4 KiB window, and there is no allocator to box into:
// the transfer's few hundred bytes cost nothing worth an indirection.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
enum State {
    Idle,
    Open(Transfer),
    Finished {
        session: u8,
        last_heard: Timestamp,
    },
    Activating {
        session: u8,
    },
    OnTrial(Trial),
    /// The confirm write runs, asked for by session `by`.
    Confirming {
        trial: Trial,
        by: u8,
    },
    /// The reject write runs, asked for by session `by` (0 for the deadline).
    Rejecting {
        by: u8,
    },
}

/// The running image's trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Trial {
    /// When it rejects itself; `None`: it runs held (see [`Updater::held`]).
    deadline: Option<Timestamp>,
    /// The session that activated it: only that session's CONFIRM or ROLLBACK counts.
    /// `None`: not known, any program may decide.
    owner: Option<u8>,
}

impl Trial {
    /// Whether a CONFIRM or ROLLBACK naming `session` may decide about this trial.
    fn heeds(&self, session: u8) -> bool {
        self.owner.is_none_or(|owner| owner == session)
    }
}

/// The session and the window it is receiving.
pub struct Updater {
    state: State,
    window: [u8; WINDOW_LEN],
    window_len: usize,
}

impl Updater {
    /// No session: the running image is confirmed.
    pub fn idle() -> Self {
        Self::in_state(State::Idle)
    }

    /// The running image started on trial: it refuses motion until CONFIRM, and rejects
    /// itself after the deadline. `owner` is the session that activated it
    /// ([`trial::BootCause::trial_owner`](super::trial::BootCause::trial_owner)).
    pub fn on_trial(now: Timestamp, owner: Option<u8>, params: &Params<'_>) -> Self {
        Self::in_state(State::OnTrial(Trial {
            deadline: Some(now.plus_millis(params.trial_deadline_ms)),
            owner,
        }))
    }

    /// An image that runs held (`trial::Start::held`): nobody confirmed it and nothing
    /// would roll it back. Motion stays locked with no deadline: rejecting itself would
    /// only start it again. CONFIRM keeps it; ROLLBACK marks it invalid and resets, so
    /// the bootloader tries the other slot. `owner` as for [`Updater::on_trial`].
    pub fn held(owner: Option<u8>) -> Self {
        Self::in_state(State::OnTrial(Trial {
            deadline: None,
            owner,
        }))
    }

    fn in_state(state: State) -> Self {
        Self {
            state,
            window: [0xFF; WINDOW_LEN],
            window_len: 0,
        }
    }

    /// The window to write for [`FlashOp::WriteWindow`].
    pub fn window(&self) -> &[u8] {
        &self.window[..self.window_len]
    }

    /// Motion (velocity, enable, the gamepad) is refused: a session runs or an image
    /// is on trial.
    pub fn locks_motion(&self) -> bool {
        !matches!(self.state, State::Idle)
    }

    pub fn phase(&self) -> Phase {
        match &self.state {
            State::Idle => Phase::Idle,
            State::Open(transfer) => match transfer.window {
                WindowRx::Writing { .. } => Phase::Writing,
                _ => Phase::Receiving,
            },
            State::Finished { .. } => Phase::Finished,
            State::Activating { .. } => Phase::Activating,
            State::OnTrial(_) | State::Confirming { .. } | State::Rejecting { .. } => {
                Phase::OnTrial
            }
        }
    }

    pub fn step(&mut self, now: Timestamp, event: Event, params: &Params<'_>) -> Effects {
        let answering = match event {
            Event::Command(command, _) => command.session(),
            // A data frame, a flash result and time belong to the running session, or
            // to the one whose decision about a trial is being written.
            Event::Data(_) | Event::FlashDone(_) | Event::Tick => match self.state {
                State::Confirming { by, .. } | State::Rejecting { by } => by,
                _ => self.session().unwrap_or(0),
            },
        };
        let mut effects = Effects {
            answering,
            ..Effects::default()
        };
        match event {
            Event::Command(command, gate) => self.command(now, command, gate, params, &mut effects),
            Event::Data(frame) => self.data(now, frame, params, &mut effects),
            Event::FlashDone(ok) => self.flash_done(ok, &mut effects),
            Event::Tick => self.tick(now, &mut effects),
        }
        effects
    }

    fn command(
        &mut self,
        now: Timestamp,
        command: UpdateCommand,
        gate: MotionGate,
        params: &Params<'_>,
        effects: &mut Effects,
    ) {
        let opcode = command.opcode();
        match command {
            UpdateCommand::Query => self.query(params, effects),
            UpdateCommand::Begin {
                session,
                size,
                flags,
            } => self.begin(now, session, size, flags, gate, params, effects),
            UpdateCommand::Confirm { session } => match self.state {
                State::OnTrial(trial) if trial.heeds(session) => {
                    self.state = State::Confirming { trial, by: session };
                    effects.flash = Some(FlashOp::Confirm);
                }
                State::OnTrial(_) => effects.refuse(opcode, UpdateError::NotTrialOwner, 0),
                _ => effects.refuse(opcode, UpdateError::NotOnTrial, 0),
            },
            UpdateCommand::Rollback { session } => match self.state {
                State::OnTrial(trial) if trial.heeds(session) => {
                    self.state = State::Rejecting { by: session };
                    effects.flash = Some(FlashOp::Reject);
                }
                State::OnTrial(_) => effects.refuse(opcode, UpdateError::NotTrialOwner, 0),
                _ => effects.refuse(opcode, UpdateError::NotOnTrial, 0),
            },
            UpdateCommand::Digest { session, .. }
            | UpdateCommand::Window { session, .. }
            | UpdateCommand::Finish { session }
            | UpdateCommand::Activate { session }
            | UpdateCommand::Abort { session } => match self.session() {
                None => effects.refuse(opcode, UpdateError::NoSession, 0),
                Some(owner) if owner != session => effects.refuse(opcode, UpdateError::Busy, 0),
                Some(_) => self.session_command(now, command, params, effects),
            },
        }
    }

    /// The running session's id, if one runs.
    fn session(&self) -> Option<u8> {
        match &self.state {
            State::Open(transfer) => Some(transfer.session),
            State::Finished { session, .. } | State::Activating { session } => Some(*session),
            _ => None,
        }
    }

    fn query(&self, params: &Params<'_>, effects: &mut Effects) {
        let (session, windows_written) = match &self.state {
            State::Open(transfer) => (transfer.session, transfer.windows_written),
            State::Finished { session, .. } | State::Activating { session } => (*session, 0),
            _ => (0, 0),
        };
        effects.reply(UpdateReply::State {
            phase: self.phase(),
            session,
            running_slot: params.running_slot,
            windows_written,
            signatures_required: !params.trust.accepts_unsigned(),
            security_version: params.running_security_version.min(255) as u8,
        });
        let version = params.running_version.as_bytes();
        for part in 0..VERSION_CHUNKS {
            let mut text = [0; VERSION_CHUNK];
            let start = usize::from(part) * VERSION_CHUNK;
            for (i, byte) in text.iter_mut().enumerate() {
                *byte = version.get(start + i).copied().unwrap_or(0);
            }
            effects.reply(UpdateReply::Version { part, text });
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn begin(
        &mut self,
        now: Timestamp,
        session: u8,
        size: u32,
        flags: BeginFlags,
        gate: MotionGate,
        params: &Params<'_>,
        effects: &mut Effects,
    ) {
        const OPCODE: u8 = 0x02;
        match &self.state {
            State::Idle => {}
            // Also with the running session's own id: another program may have drawn
            // the same id, and a PC that wants to start over ends its session first.
            State::OnTrial(_) => return effects.refuse(OPCODE, UpdateError::OnTrial, 0),
            _ => return effects.refuse(OPCODE, UpdateError::Busy, 0),
        }
        let refusal = if !gate.at_standstill || !gate.brakes_applied {
            Some((UpdateError::NotAtRest, 0))
        } else if gate.control_active {
            Some((UpdateError::ControlActive, 0))
        } else if size > params.slot_len {
            Some((UpdateError::TooLarge, 0))
        } else if (size as usize) < image::PREFIX_LEN {
            Some((UpdateError::BadImage, image::ImageError::TooShort.code()))
        } else {
            None
        };
        if let Some((error, detail)) = refusal {
            return effects.refuse(OPCODE, error, detail);
        }
        self.state = State::Open(Transfer {
            session,
            size,
            flags,
            digest: [0; 32],
            digest_parts: 0,
            hasher: Sha256::new(),
            image_check: WholeImageCheck::new(),
            security_version: 0,
            windows_written: 0,
            window: WindowRx::Waiting,
            last_heard: now,
        });
        effects.reply(UpdateReply::Done {
            session,
            step: Step::Begun,
        });
    }

    /// A command from the session's own PC.
    fn session_command(
        &mut self,
        now: Timestamp,
        command: UpdateCommand,
        params: &Params<'_>,
        effects: &mut Effects,
    ) {
        let opcode = command.opcode();
        if let UpdateCommand::Abort { session } = command {
            if matches!(self.state, State::Activating { .. }) {
                // otadata is being rewritten: the activated image starts either way.
                return effects.refuse(opcode, UpdateError::Writing, 0);
            }
            // Also while a window is written: its result is ignored.
            self.state = State::Idle;
            return effects.reply(UpdateReply::Done {
                session,
                step: Step::Aborted,
            });
        }
        match &mut self.state {
            State::Open(transfer) => {
                transfer.last_heard = now;
                if matches!(transfer.window, WindowRx::Writing { .. }) {
                    return effects.refuse(opcode, UpdateError::Writing, 0);
                }
                match command {
                    UpdateCommand::Digest { part, bytes, .. } => {
                        if part >= DIGEST_PARTS {
                            return effects.refuse(opcode, UpdateError::Malformed, part);
                        }
                        let at = usize::from(part) * 4;
                        transfer.digest[at..at + 4].copy_from_slice(&bytes);
                        transfer.digest_parts |= 1 << part;
                    }
                    UpdateCommand::Window {
                        session,
                        index,
                        crc,
                    } => {
                        // Compared without `index + 1`, which overflows for 0xFFFF.
                        if transfer.windows_written.checked_sub(1) == Some(index) {
                            // Its WRITTEN reply was lost: say it again.
                            return effects.reply(UpdateReply::Written {
                                session,
                                window: index,
                            });
                        }
                        if index != transfer.windows_written || index >= window_count(transfer.size)
                        {
                            return effects.refuse(opcode, UpdateError::WrongWindow, 0);
                        }
                        let len = window_len(transfer.size, index);
                        transfer.window = WindowRx::Receiving {
                            index,
                            crc,
                            next: 0,
                            frames: frame_count(len),
                            complained: None,
                        };
                        self.window_len = len;
                        effects.reply(UpdateReply::Ready {
                            session,
                            window: index,
                            next: 0,
                        });
                    }
                    UpdateCommand::Finish { session } => {
                        if transfer.windows_written != window_count(transfer.size)
                            || transfer.digest_parts != ALL_DIGEST_PARTS
                        {
                            return effects.refuse(opcode, UpdateError::Incomplete, 0);
                        }
                        let digest = transfer.hasher.clone().finalize();
                        if digest.as_slice() != transfer.digest {
                            self.state = State::Idle;
                            return effects.refuse(opcode, UpdateError::DigestMismatch, 0);
                        }
                        // An image the bootloader would refuse is never activated: the
                        // old one would come back after the reset, and no client learns why.
                        if let Err(error) = transfer.image_check.finish() {
                            self.state = State::Idle;
                            return effects.refuse(opcode, UpdateError::BadImage, error.code());
                        }
                        if let Err(error) = check_signature(transfer, params) {
                            self.state = State::Idle;
                            let (error, detail) = match error {
                                SignatureError::SecurityDowngrade => (
                                    UpdateError::SecurityDowngrade,
                                    params.running_security_version.min(255) as u8,
                                ),
                                _ => (UpdateError::Untrusted, error.code()),
                            };
                            return effects.refuse(opcode, error, detail);
                        }
                        self.state = State::Finished {
                            session,
                            last_heard: now,
                        };
                        effects.reply(UpdateReply::Done {
                            session,
                            step: Step::Finished,
                        });
                    }
                    UpdateCommand::Activate { .. } => {
                        effects.refuse(opcode, UpdateError::NotFinished, 0)
                    }
                    _ => {}
                }
            }
            State::Finished { session, .. } => match command {
                UpdateCommand::Activate { .. } => {
                    let session = *session;
                    self.state = State::Activating { session };
                    effects.flash = Some(FlashOp::Activate { session });
                }
                UpdateCommand::Finish { session } => effects.reply(UpdateReply::Done {
                    session,
                    step: Step::Finished,
                }),
                _ => effects.refuse(opcode, UpdateError::WrongWindow, 0),
            },
            State::Activating { .. } => effects.refuse(opcode, UpdateError::Writing, 0),
            _ => effects.refuse(opcode, UpdateError::NoSession, 0),
        }
    }

    fn data(
        &mut self,
        now: Timestamp,
        frame: DataFrame,
        params: &Params<'_>,
        effects: &mut Effects,
    ) {
        let State::Open(transfer) = &mut self.state else {
            return effects.refuse(0, UpdateError::NoSession, frame.seq);
        };
        transfer.last_heard = now;
        let WindowRx::Receiving {
            index,
            crc,
            next,
            frames,
            complained,
        } = &mut transfer.window
        else {
            return effects.refuse(0, UpdateError::WrongWindow, frame.seq);
        };
        let expected = *next as u8;
        if frame.seq != expected {
            let behind = expected.wrapping_sub(frame.seq);
            let complaint = if *next > 0 && u16::from(behind) <= SUB_BLOCK.min(*next) {
                UpdateError::Duplicate
            } else {
                UpdateError::OutOfOrder
            };
            if *complained != Some(complaint) {
                *complained = Some(complaint);
                if complaint == UpdateError::Duplicate {
                    effects.refuse(0, complaint, frame.seq);
                } else {
                    effects.refuse(0, complaint, expected);
                    effects.reply(UpdateReply::Ready {
                        session: transfer.session,
                        window: *index,
                        next: *next,
                    });
                }
            }
            return;
        }
        *complained = None;
        let at = usize::from(*next) * DATA_BYTES;
        let end = (at + DATA_BYTES).min(self.window_len);
        if at < end {
            self.window[at..end].copy_from_slice(&frame.bytes[..end - at]);
        }
        *next += 1;
        if *next < *frames {
            if *next % READY_EVERY == 0 {
                effects.reply(UpdateReply::Ready {
                    session: transfer.session,
                    window: *index,
                    next: *next,
                });
            }
            return;
        }
        // The window is complete.
        let index = *index;
        let window = &self.window[..self.window_len];
        if window_crc(window) != *crc {
            transfer.window = WindowRx::Waiting;
            return effects.refuse(0x04, UpdateError::BadCrc, 0);
        }
        if index == 0 {
            match check_image(window, transfer.flags, params) {
                Ok(info) => transfer.security_version = info.security_version,
                Err((error, detail)) => {
                    // Refused before anything is written.
                    self.state = State::Idle;
                    return effects.refuse(0x04, error, detail);
                }
            }
        }
        transfer.hasher.update(window);
        transfer.image_check.feed(window);
        transfer.window = WindowRx::Writing { index };
        effects.flash = Some(FlashOp::WriteWindow {
            offset: u32::from(index) * WINDOW_LEN as u32,
        });
    }

    fn flash_done(&mut self, ok: bool, effects: &mut Effects) {
        match &mut self.state {
            State::Open(transfer) => {
                let WindowRx::Writing { index } = transfer.window else {
                    return;
                };
                if ok {
                    transfer.windows_written += 1;
                    transfer.window = WindowRx::Waiting;
                    effects.reply(UpdateReply::Written {
                        session: transfer.session,
                        window: index,
                    });
                } else {
                    self.state = State::Idle;
                    effects.refuse(0x04, UpdateError::FlashFailed, 0);
                }
            }
            State::Activating { session } => {
                let session = *session;
                self.state = State::Idle;
                if ok {
                    effects.reply(UpdateReply::Done {
                        session,
                        step: Step::Activated,
                    });
                    effects.reset = true;
                } else {
                    effects.refuse(0x06, UpdateError::FlashFailed, 0);
                }
            }
            State::Confirming { trial, by } => {
                if ok {
                    let session = *by;
                    self.state = State::Idle;
                    effects.reply(UpdateReply::Done {
                        session,
                        step: Step::Confirmed,
                    });
                } else {
                    self.state = State::OnTrial(*trial);
                    effects.refuse(0x08, UpdateError::FlashFailed, 0);
                }
            }
            State::Rejecting { by } => {
                // Even when the write failed, the reset boots the previous slot: the
                // image armed itself (`Aborted`) at start.
                effects.reply(UpdateReply::Done {
                    session: *by,
                    step: Step::RolledBack,
                });
                if !ok {
                    effects.refuse(0x09, UpdateError::FlashFailed, 0);
                }
                effects.reset = true;
            }
            // An aborted session's write ended: nothing waits for it.
            State::Idle | State::Finished { .. } | State::OnTrial(_) => {}
        }
    }

    fn tick(&mut self, now: Timestamp, effects: &mut Effects) {
        match self.state {
            State::Open(Transfer { last_heard, .. }) | State::Finished { last_heard, .. }
                if now.millis_since(last_heard) >= SILENCE_MS =>
            {
                warn!("update session: the PC went silent; session ended");
                self.state = State::Idle;
                effects.refuse(0, UpdateError::TimedOut, 0);
            }
            State::OnTrial(Trial {
                deadline: Some(deadline),
                ..
            }) if now >= deadline => {
                warn!("image on trial not confirmed in time: rejecting it");
                self.state = State::Rejecting { by: 0 };
                effects.flash = Some(FlashOp::Reject);
            }
            _ => {}
        }
    }
}

/// The checks on window 0, before anything is written: this project's image for this
/// chip, and a version the flags allow.
fn check_image(
    window: &[u8],
    flags: BeginFlags,
    params: &Params<'_>,
) -> Result<ImageInfo, (UpdateError, u8)> {
    let info = ImageInfo::parse(window, params.chip, params.project)
        .map_err(|error| (UpdateError::BadImage, error.code()))?;
    let new = info.version.as_str();
    if new == params.running_version && !flags.force {
        return Err((UpdateError::SameVersion, 0));
    }
    if is_older(new, params.running_version) && !flags.allow_downgrade {
        return Err((UpdateError::Downgrade, 0));
    }
    Ok(info)
}

/// Whether the trust lets the finished image activate: its signature block (the
/// bytes after its appended SHA-256) and its security version.
fn check_signature(transfer: &Transfer, params: &Params<'_>) -> Result<(), SignatureError> {
    let digest = transfer
        .image_check
        .digest()
        .ok_or(SignatureError::NotSigned)?;
    signature::check(
        params.trust,
        signature::block_after(&transfer.image_check).as_ref(),
        digest,
        transfer.security_version,
        params.running_security_version,
    )
    .map(|_| ())
}

/// `major.minor.patch` of a version like `0.3.1` or `0.3.1-rc1`; `None` when it has
/// no such numbers (then no downgrade check is possible, and none is made).
pub fn release(version: &str) -> Option<(u32, u32, u32)> {
    let core = version.split(['-', '+']).next()?;
    let mut numbers = core.split('.').map(|part| part.parse::<u32>().ok());
    let release = (numbers.next()??, numbers.next()??, numbers.next()??);
    numbers.next().is_none().then_some(release)
}

/// The build number a stamped build carries after its release: 412 in
/// `0.1.0+412.g7efef4d` (firmware/build.rs); `None` without one.
pub fn build_number(version: &str) -> Option<u32> {
    let (_, build) = version.split_once('+')?;
    build.split('.').next()?.parse().ok()
}

/// Whether `new` is older than `running` (docs/protocol.md, "Versions"): the
/// releases compare as numbers; between two builds of one release the build numbers
/// decide, when both carry one. Anything else is not older.
pub fn is_older(new: &str, running: &str) -> bool {
    match (release(new), release(running)) {
        (Some(new_release), Some(running_release)) if new_release != running_release => {
            new_release < running_release
        }
        (Some(_), Some(_)) => matches!(
            (build_number(new), build_number(running)),
            (Some(new_build), Some(running_build)) if new_build < running_build
        ),
        _ => false,
    }
}

#[cfg(test)]
mod tests;
