//! The CAN codec: every frame of the robot-PC protocol (`docs/protocol.md`) as a typed
//! value and back. The CAN task feeds it received frames and sends what the other
//! modules report; test tools, the simulator and the PC-side CLI use the same code.

mod command;
pub mod filter;
mod rejection;
mod report;
mod status;
pub mod update;

pub use command::{BULK_READ_MAX, Command};
pub use rejection::Rejection;
pub use report::{ReadEcho, Report};
pub use status::{ControlSource, Faults, Mode, Status, StatusFlags};

use core::fmt;

/// The 11-bit identifiers of the protocol. Values from the original manual except
/// where marked (ext).
pub mod id {
    /// PC → BC: enable (`40` refreshes, anything else withdraws).
    pub const ENABLE: u16 = 0x2E4;
    /// PC → BC: linear and rotational velocity.
    pub const VELOCITY: u16 = 0x0C8;
    /// PC → BC: register write.
    pub const REGISTER_WRITE: u16 = 0x003;
    /// Both ways: register read request (PC → BC) and its reply (BC → PC).
    pub const REGISTER_READ: u16 = 0x004;
    /// PC → BC: reset the pose to zero.
    pub const RESET_ODOMETRY: u16 = 0x005;
    /// PC → BC: the PC is alive.
    pub const HEARTBEAT: u16 = 0x006;
    /// PC → BC: a scale calibration step.
    pub const SCALE_CALIBRATION: u16 = 0x007;
    /// PC → BC: an odometry calibration step.
    pub const ODOMETRY_CALIBRATION: u16 = 0x008;
    /// BC → PC: weight on the load cell.
    pub const WEIGHT: u16 = 0x0EA;
    /// BC → PC: battery charge and voltage.
    pub const BATTERY: u16 = 0x0EB;
    /// BC → PC: position x, y.
    pub const POSITION: u16 = 0x0EC;
    /// BC → PC: heading.
    pub const HEADING: u16 = 0x0ED;
    /// BC → PC: status (ext).
    pub const STATUS: u16 = 0x0EE;
    /// BC → PC: the controller's time of the pose in the 0x0EC and 0x0ED that follow (ext).
    pub const POSE_TIME: u16 = 0x0EF;
    /// BC → PC: the measured speed of the base and its wheels (ext).
    pub const MEASURED_SPEED: u16 = 0x0F0;

    /// Every ID the base controller listens to, e.g. for the receive acceptance filter.
    pub const COMMANDS: [u16; 8] = [
        ENABLE,
        VELOCITY,
        REGISTER_WRITE,
        REGISTER_READ,
        RESET_ODOMETRY,
        HEARTBEAT,
        SCALE_CALIBRATION,
        ODOMETRY_CALIBRATION,
    ];

    /// PC → BC: firmware update command (ext).
    pub const UPDATE_COMMAND: u16 = 0x2E8;
    /// PC → BC: firmware image data, a sequence byte and 7 bytes (ext).
    pub const UPDATE_DATA: u16 = 0x2EC;
    /// BC → PC: firmware update reply (ext).
    pub const UPDATE_REPLY: u16 = 0x2EA;

    /// The update's IDs the base controller listens to; the update task takes them,
    /// never the controller.
    pub const UPDATE: [u16; 2] = [UPDATE_COMMAND, UPDATE_DATA];

    /// Every ID the base controller sends, e.g. for the PC-side receive filter.
    pub const REPORTS: [u16; 8] = [
        REGISTER_READ,
        WEIGHT,
        BATTERY,
        POSITION,
        HEADING,
        STATUS,
        POSE_TIME,
        MEASURED_SPEED,
    ];

    /// The periodic feedback frames: sent on their own schedule whatever else the bus
    /// carries. Everything else the base controller sends (register replies, update
    /// replies) answers a request.
    pub const FEEDBACK: [u16; 7] = [
        POSE_TIME,
        MEASURED_SPEED,
        POSITION,
        HEADING,
        BATTERY,
        WEIGHT,
        STATUS,
    ];

    /// Whether the base controller sends `frame_id` as periodic feedback rather than as
    /// a reply (see [`FEEDBACK`]).
    pub fn is_feedback(frame_id: u16) -> bool {
        FEEDBACK.contains(&frame_id)
    }
}

/// Highest identifier of classic CAN 2.0A (11 bits).
pub const MAX_STANDARD_ID: u16 = 0x7FF;

/// Most data bytes a classic CAN frame carries.
pub const MAX_DATA_LEN: usize = 8;

/// Why a frame with a known ID was refused. The codes go on the wire in the status
/// frame (byte 4), so they never change; 0x01..=0x0F belong to this module, other
/// modules number their rejections from 0x10.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum FrameError {
    /// Too few data bytes for this frame, more than 8, or (reports only) not the exact DLC.
    WrongLength = 0x01,
    /// A velocity frame whose byte 4 is not `03`.
    BadVelocityMarker = 0x02,
    /// A sub-command byte (or a status nibble) this protocol does not define.
    UnknownSubcommand = 0x03,
    /// (ext) A bulk register read asking for no register, more than
    /// [`BULK_READ_MAX`], or for addresses past 255.
    BadReadCount = 0x04,
}

impl FrameError {
    /// The stable code reported in the status frame.
    pub const fn code(self) -> u8 {
        self as u8
    }
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::WrongLength => "wrong frame length",
            FrameError::BadVelocityMarker => "velocity frame byte 4 is not 0x03",
            FrameError::UnknownSubcommand => "unknown sub-command",
            FrameError::BadReadCount => "bulk register read of 0, more than 8, or past address 255",
        })
    }
}

impl core::error::Error for FrameError {}

/// One classic CAN 2.0A data frame, as the driver hands it over or takes it.
/// Bytes past `len` are always zero, so the derived equality is equality of frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RawFrame {
    id: u16,
    len: u8,
    data: [u8; MAX_DATA_LEN],
}

impl RawFrame {
    /// `None` if `id` does not fit 11 bits or `data` is longer than 8 bytes: such a
    /// frame cannot exist on a classic CAN bus.
    pub fn new(id: u16, data: &[u8]) -> Option<Self> {
        if id > MAX_STANDARD_ID {
            return None;
        }
        let len = u8::try_from(data.len()).ok()?;
        let mut bytes = [0; MAX_DATA_LEN];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Self {
            id,
            len,
            data: bytes,
        })
    }

    /// The encoders' constructor: their lengths are constants, so a frame too long to
    /// exist is a compile error instead of a run-time `None`. Their IDs are the
    /// constants of [`id`], all within 11 bits (checked by a test).
    pub(crate) const fn from_array<const N: usize>(id: u16, bytes: [u8; N]) -> Self {
        const { assert!(N <= MAX_DATA_LEN) };
        let mut data = [0; MAX_DATA_LEN];
        let mut i = 0;
        while i < N {
            data[i] = bytes[i];
            i += 1;
        }
        Self {
            id,
            len: N as u8,
            data,
        }
    }

    pub const fn id(&self) -> u16 {
        self.id
    }

    /// The `len` data bytes, nothing after them.
    pub fn data(&self) -> &[u8] {
        // `len` is at most 8 by construction, so this never slices out of bounds.
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

/// Conversions to and from the frame type of any CAN driver (the chip's TWAI, SocketCAN,
/// the virtual bus): the one place that decides which driver frames the protocol sees.
#[cfg(feature = "embedded-can")]
impl RawFrame {
    /// A standard data frame as the codec's frame; `None` for extended and remote
    /// frames, which are not part of the protocol.
    pub fn from_frame<F: embedded_can::Frame>(frame: &F) -> Option<Self> {
        match frame.id() {
            embedded_can::Id::Standard(id) if frame.is_data_frame() => {
                Self::new(id.as_raw(), frame.data())
            }
            _ => None,
        }
    }

    /// This frame as the driver's frame type.
    pub fn to_frame<F: embedded_can::Frame>(&self) -> Option<F> {
        F::new(embedded_can::StandardId::new(self.id)?, self.data())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_frame_keeps_exactly_the_given_bytes() {
        let frame = RawFrame::new(0x0C8, &[0xF4, 0x01, 0x00, 0x00, 0x03]).unwrap();
        assert_eq!(frame.id(), 0x0C8);
        assert_eq!(frame.data(), &[0xF4, 0x01, 0x00, 0x00, 0x03]);
    }

    #[test]
    fn raw_frame_accepts_empty_and_full_frames_at_the_highest_id() {
        assert_eq!(RawFrame::new(0x7FF, &[]).unwrap().data(), &[] as &[u8]);
        assert_eq!(RawFrame::new(0x7FF, &[9; 8]).unwrap().data(), &[9; 8]);
    }

    #[test]
    fn raw_frame_rejects_more_than_eight_bytes() {
        assert_eq!(RawFrame::new(0x0C8, &[0; 9]), None);
    }

    #[test]
    fn raw_frame_rejects_ids_wider_than_eleven_bits() {
        assert_eq!(RawFrame::new(0x800, &[0x01]), None);
        assert_eq!(RawFrame::new(u16::MAX, &[]), None);
    }

    #[test]
    fn raw_frame_from_array_equals_the_checked_constructor() {
        assert_eq!(
            RawFrame::from_array(0x006, [0x01]),
            RawFrame::new(0x006, &[0x01]).unwrap()
        );
    }

    #[test]
    fn every_protocol_id_fits_eleven_bits() {
        for id in id::COMMANDS
            .iter()
            .chain(id::REPORTS.iter())
            .chain(id::UPDATE.iter())
            .chain([id::UPDATE_REPLY].iter())
        {
            assert!(*id <= MAX_STANDARD_ID, "{id:#x}");
        }
    }

    #[test]
    fn the_periodic_frames_are_feedback_and_every_reply_is_not() {
        for feedback in [
            id::POSE_TIME,
            id::POSITION,
            id::HEADING,
            id::BATTERY,
            id::WEIGHT,
            id::STATUS,
        ] {
            assert!(id::is_feedback(feedback), "{feedback:#x}");
        }
        for reply in [id::REGISTER_READ, id::UPDATE_REPLY] {
            assert!(!id::is_feedback(reply), "{reply:#x}");
        }
        // Every frame the base controller sends is one or the other, and the feedback
        // frames are all reports.
        assert!(id::FEEDBACK.iter().all(|id| id::REPORTS.contains(id)));
    }

    #[test]
    fn frame_error_codes_are_stable() {
        assert_eq!(FrameError::WrongLength.code(), 0x01);
        assert_eq!(FrameError::BadVelocityMarker.code(), 0x02);
        assert_eq!(FrameError::UnknownSubcommand.code(), 0x03);
    }
}
