//! The firmware update's frames (ext): commands on 0x2E8 and image data on 0x2EC from
//! the PC, replies on 0x2EA from the base controller. None of the manual's IDs changes;
//! both PC → BC IDs pass the receive filter the velocity and enable IDs already need
//! (checked by a test in [`super::filter`]).
//!
//! Every command carries the PC's session id in byte 1, so that a second program on
//! the bus cannot step into a running transfer: it is answered with `Busy`.

use super::{FrameError, RawFrame, id};

/// Data bytes in one 0x2EC frame, after the sequence byte.
pub const DATA_BYTES: usize = 7;

const QUERY: u8 = 0x01;
const BEGIN: u8 = 0x02;
const DIGEST: u8 = 0x03;
const WINDOW: u8 = 0x04;
const FINISH: u8 = 0x05;
const ACTIVATE: u8 = 0x06;
const ABORT: u8 = 0x07;
const CONFIRM: u8 = 0x08;
const ROLLBACK: u8 = 0x09;

const REPLY_STATE: u8 = 0x81;
const REPLY_VERSION: u8 = 0x82;
const REPLY_READY: u8 = 0x83;
const REPLY_WRITTEN: u8 = 0x84;
const REPLY_DONE: u8 = 0x85;
const REPLY_REFUSED: u8 = 0xFF;

/// Bytes of the running version carried by one version reply.
pub const VERSION_CHUNK: usize = 6;
/// Version replies that carry the whole 32-byte version text.
pub const VERSION_CHUNKS: u8 = 6;

/// The running version from its version replies: a STATE starts them, each reply
/// carries one part, and the text is whole once every part came, NUL padding cut.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VersionAssembler {
    text: [u8; VERSION_CHUNK * VERSION_CHUNKS as usize],
    /// The parts seen since the last restart, one bit each.
    parts: u8,
}

impl Default for VersionAssembler {
    fn default() -> Self {
        Self {
            text: [0; VERSION_CHUNK * VERSION_CHUNKS as usize],
            parts: 0,
        }
    }
}

impl VersionAssembler {
    /// A STATE came: its version parts follow.
    pub fn restart(&mut self) {
        self.parts = 0;
    }

    /// Takes part `part`; the whole text once every part since the last restart came.
    pub fn add(&mut self, part: u8, chunk: &[u8; VERSION_CHUNK]) -> Option<&[u8]> {
        if part >= VERSION_CHUNKS {
            return None;
        }
        let at = usize::from(part) * VERSION_CHUNK;
        self.text[at..at + VERSION_CHUNK].copy_from_slice(chunk);
        self.parts |= 1 << part;
        if self.parts != (1 << VERSION_CHUNKS) - 1 {
            return None;
        }
        let end = self.text.iter().position(|&b| b == 0);
        Some(&self.text[..end.unwrap_or(self.text.len())])
    }
}

/// BEGIN flags (byte 5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BeginFlags {
    /// Write even an image whose version equals the running one.
    pub force: bool,
    /// Write even an older version.
    pub allow_downgrade: bool,
}

impl BeginFlags {
    const fn bits(self) -> u8 {
        (self.force as u8) | ((self.allow_downgrade as u8) << 1)
    }

    const fn from_bits(bits: u8) -> Self {
        Self {
            force: bits & 1 != 0,
            allow_downgrade: bits & 2 != 0,
        }
    }
}

/// One 0x2E8 command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateCommand {
    /// `01`: answered with the state and the running version; anyone may ask.
    Query,
    /// `02 sid size(3, LE) flags`: start a transfer of `size` bytes.
    Begin {
        session: u8,
        size: u32,
        flags: BeginFlags,
    },
    /// `03 sid part b0..b3`: bytes `4 * part ..` of the image's SHA-256 (parts 0..8).
    Digest {
        session: u8,
        part: u8,
        bytes: [u8; 4],
    },
    /// `04 sid index(2, LE) crc32(4, LE)`: the data frames of 4 KiB window `index`
    /// follow, and their bytes have this CRC-32.
    Window { session: u8, index: u16, crc: u32 },
    /// `05 sid`: every window is written; compare the SHA-256.
    Finish { session: u8 },
    /// `06 sid`: boot the new image on trial (the controller resets).
    Activate { session: u8 },
    /// `07 sid`: end the transfer; the slot is left unbootable as it was.
    Abort { session: u8 },
    /// `08 sid`: the image on trial is healthy; keep it. `sid` is the session that
    /// activated it; a frame without it (tools before the byte) names session 0.
    Confirm { session: u8 },
    /// `09 sid`: reject the image on trial and boot the previous one (the controller
    /// resets). `sid` as for CONFIRM.
    Rollback { session: u8 },
}

/// One 0x2EC frame: the frame's index in its window (modulo 256) and 7 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DataFrame {
    pub seq: u8,
    pub bytes: [u8; DATA_BYTES],
}

/// Where the update stands, in the state reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Phase {
    Idle = 0,
    Receiving = 1,
    Writing = 2,
    Finished = 3,
    Activating = 4,
    /// A new image runs on trial: motion is refused until it is confirmed.
    OnTrial = 5,
}

impl Phase {
    const fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0 => Self::Idle,
            1 => Self::Receiving,
            2 => Self::Writing,
            3 => Self::Finished,
            4 => Self::Activating,
            5 => Self::OnTrial,
            _ => return None,
        })
    }
}

/// Why a command or data frame was refused. Stable codes on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum UpdateError {
    /// Another session runs (another PC, or a BEGIN while busy).
    Busy = 1,
    /// BEGIN while the base moves or the brakes are not confirmed.
    NotAtRest = 2,
    /// BEGIN while the CAN enable is fresh or the gamepad's dead-man is held.
    ControlActive = 3,
    /// BEGIN while an image is on trial: confirm or roll back first.
    OnTrial = 4,
    /// No session runs (never begun, aborted, or ended by silence).
    NoSession = 5,
    /// A data frame ahead of the expected one: resend from `next`.
    OutOfOrder = 6,
    /// A data frame already received: dropped.
    Duplicate = 7,
    /// The window's bytes do not match its CRC-32: resend the window.
    BadCrc = 8,
    /// A WINDOW other than the next one, or data before any WINDOW.
    WrongWindow = 9,
    /// The image fails a check (detail: the image error code).
    BadImage = 10,
    /// An older version than the running one, without allow-downgrade.
    Downgrade = 11,
    /// The running version again, without force.
    SameVersion = 12,
    /// Larger than the slot.
    TooLarge = 13,
    /// The SHA-256 over the written image differs from the announced one.
    DigestMismatch = 14,
    /// FINISH before every window or every digest part arrived.
    Incomplete = 15,
    /// Erase, write or read-back of the slot or otadata failed.
    FlashFailed = 16,
    /// CONFIRM or ROLLBACK while no image is on trial.
    NotOnTrial = 17,
    /// The session ended after 10 s without a frame from its PC.
    TimedOut = 18,
    /// A frame of the wrong length or an unknown opcode.
    Malformed = 19,
    /// ACTIVATE before a successful FINISH.
    NotFinished = 20,
    /// A command while a window is being written: wait for its reply.
    Writing = 21,
    /// FINISH: the image is not signed by a key this controller trusts (detail: 1 not
    /// signed, 2 another key, 3 the signature does not match).
    Untrusted = 22,
    /// FINISH: below the running image's security version, and the owner did not sign
    /// a downgrade (detail: the running security version, up to 255).
    SecurityDowngrade = 23,
    /// CONFIRM or ROLLBACK naming another session than the one that activated the
    /// image on trial.
    NotTrialOwner = 24,
}

impl UpdateError {
    pub const ALL: [UpdateError; 24] = [
        Self::Busy,
        Self::NotAtRest,
        Self::ControlActive,
        Self::OnTrial,
        Self::NoSession,
        Self::OutOfOrder,
        Self::Duplicate,
        Self::BadCrc,
        Self::WrongWindow,
        Self::BadImage,
        Self::Downgrade,
        Self::SameVersion,
        Self::TooLarge,
        Self::DigestMismatch,
        Self::Incomplete,
        Self::FlashFailed,
        Self::NotOnTrial,
        Self::TimedOut,
        Self::Malformed,
        Self::NotFinished,
        Self::Writing,
        Self::Untrusted,
        Self::SecurityDowngrade,
        Self::NotTrialOwner,
    ];

    pub const fn code(self) -> u8 {
        self as u8
    }

    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|error| error.code() == code)
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Busy => "Busy",
            Self::NotAtRest => "NotAtRest",
            Self::ControlActive => "ControlActive",
            Self::OnTrial => "OnTrial",
            Self::NoSession => "NoSession",
            Self::OutOfOrder => "OutOfOrder",
            Self::Duplicate => "Duplicate",
            Self::BadCrc => "BadCrc",
            Self::WrongWindow => "WrongWindow",
            Self::BadImage => "BadImage",
            Self::Downgrade => "Downgrade",
            Self::SameVersion => "SameVersion",
            Self::TooLarge => "TooLarge",
            Self::DigestMismatch => "DigestMismatch",
            Self::Incomplete => "Incomplete",
            Self::FlashFailed => "FlashFailed",
            Self::NotOnTrial => "NotOnTrial",
            Self::TimedOut => "TimedOut",
            Self::Malformed => "Malformed",
            Self::NotFinished => "NotFinished",
            Self::Writing => "Writing",
            Self::Untrusted => "Untrusted",
            Self::SecurityDowngrade => "SecurityDowngrade",
            Self::NotTrialOwner => "NotTrialOwner",
        }
    }
}

/// Which step a DONE reply completes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Step {
    Begun = 1,
    Finished = 2,
    /// otadata names the new slot; the controller resets now.
    Activated = 3,
    Aborted = 4,
    Confirmed = 5,
    /// The trial image is rejected; the controller resets now.
    RolledBack = 6,
}

impl Step {
    const fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => Self::Begun,
            2 => Self::Finished,
            3 => Self::Activated,
            4 => Self::Aborted,
            5 => Self::Confirmed,
            6 => Self::RolledBack,
            _ => return None,
        })
    }
}

/// One 0x2EA reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateReply {
    /// `81 phase sid slot windows(2, LE) trust security`: the answer to QUERY; `slot`
    /// is the running slot (0, 1, or 0xFF when not started from an app slot); `trust`
    /// bit 0: only signed images activate; `security` the running image's security
    /// version (255 for any above). Controllers before signed images sent six bytes:
    /// decoded as unsigned accepted, security version 0, as they were.
    State {
        phase: Phase,
        session: u8,
        running_slot: u8,
        windows_written: u16,
        signatures_required: bool,
        security_version: u8,
    },
    /// `82 part text(6)`: bytes `6 * part ..` of the running version, NUL-padded.
    Version { part: u8, text: [u8; VERSION_CHUNK] },
    /// `83 sid window(2, LE) next(2, LE)`: send window `window` from frame `next` on,
    /// at most a sub-block of frames before the next READY.
    Ready { session: u8, window: u16, next: u16 },
    /// `84 sid window(2, LE)`: the window is erased, written and read back.
    Written { session: u8, window: u16 },
    /// `85 sid step`.
    Done { session: u8, step: Step },
    /// `FF opcode error detail sid`: `opcode` is the refused command's, or 0 for a data
    /// frame; `detail` is the image error code for `BadImage`, the expected frame
    /// index's low byte for `OutOfOrder`, 0 otherwise; `session` the session of the
    /// command refused (0 for one without a session), or the running session for a
    /// data frame and for what ends it. Controllers before the session byte sent four
    /// bytes: decoded as session 0.
    Refused {
        opcode: u8,
        error: UpdateError,
        detail: u8,
        session: u8,
    },
}

impl UpdateCommand {
    /// `Ok(None)` for any other ID.
    pub fn decode(frame_id: u16, data: &[u8]) -> Result<Option<Self>, FrameError> {
        if frame_id != id::UPDATE_COMMAND {
            return Ok(None);
        }
        let byte = |at: usize| data.get(at).copied().ok_or(FrameError::WrongLength);
        let session = || byte(1);
        let command = match byte(0)? {
            QUERY => Self::Query,
            BEGIN => Self::Begin {
                session: session()?,
                size: u32::from_le_bytes([byte(2)?, byte(3)?, byte(4)?, 0]),
                flags: BeginFlags::from_bits(byte(5)?),
            },
            DIGEST => Self::Digest {
                session: session()?,
                part: byte(2)?,
                bytes: [byte(3)?, byte(4)?, byte(5)?, byte(6)?],
            },
            WINDOW => Self::Window {
                session: session()?,
                index: u16::from_le_bytes([byte(2)?, byte(3)?]),
                crc: u32::from_le_bytes([byte(4)?, byte(5)?, byte(6)?, byte(7)?]),
            },
            FINISH => Self::Finish {
                session: session()?,
            },
            ACTIVATE => Self::Activate {
                session: session()?,
            },
            ABORT => Self::Abort {
                session: session()?,
            },
            // The session byte came with the binding of a trial to its session: a
            // one-byte frame from an older tool names none.
            CONFIRM => Self::Confirm {
                session: data.get(1).copied().unwrap_or(0),
            },
            ROLLBACK => Self::Rollback {
                session: data.get(1).copied().unwrap_or(0),
            },
            _ => return Err(FrameError::UnknownSubcommand),
        };
        Ok(Some(command))
    }

    /// The session the command names; 0 for QUERY, which has none.
    pub const fn session(&self) -> u8 {
        match *self {
            Self::Begin { session, .. }
            | Self::Digest { session, .. }
            | Self::Window { session, .. }
            | Self::Finish { session }
            | Self::Activate { session }
            | Self::Abort { session }
            | Self::Confirm { session }
            | Self::Rollback { session } => session,
            Self::Query => 0,
        }
    }

    pub const fn opcode(&self) -> u8 {
        match self {
            Self::Query => QUERY,
            Self::Begin { .. } => BEGIN,
            Self::Digest { .. } => DIGEST,
            Self::Window { .. } => WINDOW,
            Self::Finish { .. } => FINISH,
            Self::Activate { .. } => ACTIVATE,
            Self::Abort { .. } => ABORT,
            Self::Confirm { .. } => CONFIRM,
            Self::Rollback { .. } => ROLLBACK,
        }
    }

    pub fn encode(&self) -> RawFrame {
        let at = id::UPDATE_COMMAND;
        match *self {
            Self::Query => RawFrame::from_array(at, [QUERY]),
            Self::Begin {
                session,
                size,
                flags,
            } => {
                let [a, b, c, _] = size.to_le_bytes();
                RawFrame::from_array(at, [BEGIN, session, a, b, c, flags.bits()])
            }
            Self::Digest {
                session,
                part,
                bytes: [a, b, c, d],
            } => RawFrame::from_array(at, [DIGEST, session, part, a, b, c, d]),
            Self::Window {
                session,
                index,
                crc,
            } => {
                let [i0, i1] = index.to_le_bytes();
                let [c0, c1, c2, c3] = crc.to_le_bytes();
                RawFrame::from_array(at, [WINDOW, session, i0, i1, c0, c1, c2, c3])
            }
            Self::Finish { session } => RawFrame::from_array(at, [FINISH, session]),
            Self::Activate { session } => RawFrame::from_array(at, [ACTIVATE, session]),
            Self::Abort { session } => RawFrame::from_array(at, [ABORT, session]),
            Self::Confirm { session } => RawFrame::from_array(at, [CONFIRM, session]),
            Self::Rollback { session } => RawFrame::from_array(at, [ROLLBACK, session]),
        }
    }
}

impl DataFrame {
    /// `Ok(None)` for any other ID. A data frame always has 8 bytes; the last frame of
    /// a window is padded.
    pub fn decode(frame_id: u16, data: &[u8]) -> Result<Option<Self>, FrameError> {
        if frame_id != id::UPDATE_DATA {
            return Ok(None);
        }
        let &[seq, ref rest @ ..] = data else {
            return Err(FrameError::WrongLength);
        };
        let bytes: [u8; DATA_BYTES] = rest.try_into().map_err(|_| FrameError::WrongLength)?;
        Ok(Some(Self { seq, bytes }))
    }

    pub fn encode(&self) -> RawFrame {
        let [a, b, c, d, e, f, g] = self.bytes;
        RawFrame::from_array(id::UPDATE_DATA, [self.seq, a, b, c, d, e, f, g])
    }
}

impl UpdateReply {
    /// `Ok(None)` for any other ID.
    pub fn decode(frame_id: u16, data: &[u8]) -> Result<Option<Self>, FrameError> {
        if frame_id != id::UPDATE_REPLY {
            return Ok(None);
        }
        let byte = |at: usize| data.get(at).copied().ok_or(FrameError::WrongLength);
        let word = |at: usize| Ok(u16::from_le_bytes([byte(at)?, byte(at + 1)?]));
        let reply = match byte(0)? {
            REPLY_STATE => Self::State {
                phase: Phase::from_code(byte(1)?).ok_or(FrameError::UnknownSubcommand)?,
                session: byte(2)?,
                running_slot: byte(3)?,
                windows_written: word(4)?,
                signatures_required: data.get(6).is_some_and(|trust| trust & 1 != 0),
                security_version: data.get(7).copied().unwrap_or(0),
            },
            REPLY_VERSION => {
                let mut text = [0; VERSION_CHUNK];
                for (i, byte_out) in text.iter_mut().enumerate() {
                    *byte_out = byte(2 + i)?;
                }
                Self::Version {
                    part: byte(1)?,
                    text,
                }
            }
            REPLY_READY => Self::Ready {
                session: byte(1)?,
                window: word(2)?,
                next: word(4)?,
            },
            REPLY_WRITTEN => Self::Written {
                session: byte(1)?,
                window: word(2)?,
            },
            REPLY_DONE => Self::Done {
                session: byte(1)?,
                step: Step::from_code(byte(2)?).ok_or(FrameError::UnknownSubcommand)?,
            },
            REPLY_REFUSED => Self::Refused {
                opcode: byte(1)?,
                error: UpdateError::from_code(byte(2)?).ok_or(FrameError::UnknownSubcommand)?,
                detail: byte(3)?,
                session: data.get(4).copied().unwrap_or(0),
            },
            _ => return Err(FrameError::UnknownSubcommand),
        };
        Ok(Some(reply))
    }

    pub fn encode(&self) -> RawFrame {
        let at = id::UPDATE_REPLY;
        match *self {
            Self::State {
                phase,
                session,
                running_slot,
                windows_written,
                signatures_required,
                security_version,
            } => {
                let [w0, w1] = windows_written.to_le_bytes();
                RawFrame::from_array(
                    at,
                    [
                        REPLY_STATE,
                        phase as u8,
                        session,
                        running_slot,
                        w0,
                        w1,
                        u8::from(signatures_required),
                        security_version,
                    ],
                )
            }
            Self::Version { part, text } => {
                let [a, b, c, d, e, f] = text;
                RawFrame::from_array(at, [REPLY_VERSION, part, a, b, c, d, e, f])
            }
            Self::Ready {
                session,
                window,
                next,
            } => {
                let [w0, w1] = window.to_le_bytes();
                let [n0, n1] = next.to_le_bytes();
                RawFrame::from_array(at, [REPLY_READY, session, w0, w1, n0, n1])
            }
            Self::Written { session, window } => {
                let [w0, w1] = window.to_le_bytes();
                RawFrame::from_array(at, [REPLY_WRITTEN, session, w0, w1])
            }
            Self::Done { session, step } => {
                RawFrame::from_array(at, [REPLY_DONE, session, step as u8])
            }
            Self::Refused {
                opcode,
                error,
                detail,
                session,
            } => RawFrame::from_array(at, [REPLY_REFUSED, opcode, error.code(), detail, session]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_version_is_whole_only_once_every_part_since_the_last_state_came() {
        let version = b"0.1.0+412.g7efef4d";
        let part = |index: u8| {
            let mut text = [0u8; VERSION_CHUNK];
            let at = usize::from(index) * VERSION_CHUNK;
            for (byte, source) in text.iter_mut().zip(version.iter().skip(at)) {
                *byte = *source;
            }
            text
        };
        let mut assembler = VersionAssembler::default();
        for index in 0..VERSION_CHUNKS - 1 {
            assert_eq!(assembler.add(index, &part(index)), None);
        }
        assert_eq!(
            assembler.add(VERSION_CHUNKS, &part(0)),
            None,
            "no such part"
        );
        assembler.restart();
        assert_eq!(
            assembler.add(VERSION_CHUNKS - 1, &part(VERSION_CHUNKS - 1)),
            None
        );
        for index in 0..VERSION_CHUNKS - 1 {
            assembler.add(index, &part(index));
        }
        assert_eq!(
            assembler.add(0, &part(0)),
            Some(&version[..]),
            "whole, the NUL padding cut"
        );
    }

    #[test]
    fn every_command_survives_encode_and_decode() {
        let commands = [
            UpdateCommand::Query,
            UpdateCommand::Begin {
                session: 7,
                size: 0x1F_0000,
                flags: BeginFlags {
                    force: true,
                    allow_downgrade: false,
                },
            },
            UpdateCommand::Digest {
                session: 7,
                part: 3,
                bytes: [1, 2, 3, 4],
            },
            UpdateCommand::Window {
                session: 7,
                index: 300,
                crc: 0xDEAD_BEEF,
            },
            UpdateCommand::Finish { session: 7 },
            UpdateCommand::Activate { session: 7 },
            UpdateCommand::Abort { session: 7 },
            UpdateCommand::Confirm { session: 7 },
            UpdateCommand::Rollback { session: 7 },
        ];
        for command in commands {
            let frame = command.encode();
            assert_eq!(frame.id(), id::UPDATE_COMMAND);
            assert_eq!(
                UpdateCommand::decode(frame.id(), frame.data()),
                Ok(Some(command))
            );
            assert_eq!(frame.data()[0], command.opcode());
        }
    }

    #[test]
    fn every_reply_survives_encode_and_decode() {
        let replies = [
            UpdateReply::State {
                phase: Phase::OnTrial,
                session: 9,
                running_slot: 1,
                windows_written: 150,
                signatures_required: true,
                security_version: 3,
            },
            UpdateReply::Version {
                part: 2,
                text: *b"0.3.0\0",
            },
            UpdateReply::Ready {
                session: 9,
                window: 4,
                next: 48,
            },
            UpdateReply::Written {
                session: 9,
                window: 4,
            },
            UpdateReply::Done {
                session: 9,
                step: Step::Activated,
            },
            UpdateReply::Refused {
                opcode: 0x04,
                error: UpdateError::BadCrc,
                detail: 0,
                session: 0x5A,
            },
        ];
        for reply in replies {
            let frame = reply.encode();
            assert_eq!(frame.id(), id::UPDATE_REPLY);
            assert_eq!(
                UpdateReply::decode(frame.id(), frame.data()),
                Ok(Some(reply))
            );
        }
    }

    #[test]
    fn a_state_from_a_controller_before_signed_images_reads_as_accepting_any_image() {
        assert_eq!(
            UpdateReply::decode(id::UPDATE_REPLY, &[0x81, 0, 0, 1, 0, 0]),
            Ok(Some(UpdateReply::State {
                phase: Phase::Idle,
                session: 0,
                running_slot: 1,
                windows_written: 0,
                signatures_required: false,
                security_version: 0,
            }))
        );
    }

    #[test]
    fn a_confirm_or_rollback_from_a_tool_before_the_session_byte_names_session_0() {
        assert_eq!(
            UpdateCommand::decode(id::UPDATE_COMMAND, &[0x08]),
            Ok(Some(UpdateCommand::Confirm { session: 0 }))
        );
        assert_eq!(
            UpdateCommand::decode(id::UPDATE_COMMAND, &[0x09]),
            Ok(Some(UpdateCommand::Rollback { session: 0 }))
        );
    }

    #[test]
    fn short_frames_and_unknown_opcodes_are_refused_not_guessed() {
        assert_eq!(
            UpdateCommand::decode(id::UPDATE_COMMAND, &[]),
            Err(FrameError::WrongLength)
        );
        assert_eq!(
            UpdateCommand::decode(id::UPDATE_COMMAND, &[0x04, 1, 0, 0, 1, 2, 3]),
            Err(FrameError::WrongLength)
        );
        assert_eq!(
            UpdateCommand::decode(id::UPDATE_COMMAND, &[0x42, 1]),
            Err(FrameError::UnknownSubcommand)
        );
        assert_eq!(
            DataFrame::decode(id::UPDATE_DATA, &[0, 1, 2, 3]),
            Err(FrameError::WrongLength)
        );
        assert_eq!(UpdateCommand::decode(id::VELOCITY, &[0x01]), Ok(None));
        assert_eq!(DataFrame::decode(id::UPDATE_COMMAND, &[0; 8]), Ok(None));
    }

    #[test]
    fn error_codes_are_stable_and_distinct() {
        for (i, error) in UpdateError::ALL.iter().enumerate() {
            assert_eq!(error.code() as usize, i + 1);
            assert_eq!(UpdateError::from_code(error.code()), Some(*error));
        }
        assert_eq!(UpdateError::from_code(0), None);
    }
}
