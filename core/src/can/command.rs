//! Frames from the robot PC to the base controller (docs/protocol.md): decoded on the robot,
//! encoded by the PC side, test tools and the simulator.

use super::{FrameError, MAX_DATA_LEN, RawFrame, id};
use crate::calibration::{OdometryCalibrationCommand, ScaleCalibrationCommand};

/// byte0 of an enable frame that refreshes the enable; any other value withdraws it.
const ENABLE_REFRESH: u8 = 0x40;
/// byte4 of every velocity frame.
const VELOCITY_MARKER: u8 = 0x03;
/// The one sub-command of 0x004 (read), 0x005 (reset) and 0x006 (heartbeat).
const REQUEST: u8 = 0x01;
/// byte0 of a register read reply; shares ID 0x004 with the request.
pub(super) const REGISTER_VALUE: u8 = 0x00;
/// byte0 of a register read error reply (ext); shares ID 0x004 with the request.
pub(super) const REGISTER_ERROR: u8 = 0xFF;
pub(super) const REGISTER_READ_REQUEST: u8 = REQUEST;
/// byte0 of a bulk register read request (ext).
pub(super) const REGISTER_BULK_READ_REQUEST: u8 = 0x02;

/// The most registers one bulk read asks for: their replies fit one controller output
/// and the transmit queue holds two such batches.
pub const BULK_READ_MAX: u8 = 8;

const SCALE_START: u8 = 0x01;
const SCALE_TARE: u8 = 0x02;
const SCALE_KNOWN_WEIGHT: u8 = 0x03;

const ODOMETRY_START_LINEAR: u8 = 0x01;
const ODOMETRY_END_LINEAR: u8 = 0x0C;
const ODOMETRY_START_CLOCKWISE: u8 = 0x02;
const ODOMETRY_END_CLOCKWISE: u8 = 0x16;
const ODOMETRY_START_COUNTER_CLOCKWISE: u8 = 0x03;
const ODOMETRY_END_COUNTER_CLOCKWISE: u8 = 0x20;
const ODOMETRY_STORE: u8 = 0x04;

/// One message from the robot PC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// 0x2E4: `refresh` keeps the base allowed to drive; `false` withdraws that at once.
    Enable { refresh: bool },
    /// 0x0C8: + forward, + clockwise.
    Velocity {
        linear_mm_s: i16,
        rotation_mrad_s: i16,
    },
    /// 0x003: `addr, MSB, LSB`.
    RegisterWrite { address: u8, value: u16 },
    /// 0x004: `01, addr` (the manual's request), or `01, addr, tag MSB, tag LSB` (ext):
    /// the reply echoes the address and the tag, so that a program can tell its own
    /// reply from another program's. `tag` 0 is the manual's two-byte request.
    RegisterRead { address: u8, tag: u16 },
    /// 0x004 (ext): `02, first, count, tag MSB, tag LSB`: reads the `count` addresses
    /// from `first` on (1 ..= [`BULK_READ_MAX`], not past 255) in one request. Each
    /// address gets its own reply, as for [`Command::RegisterRead`] with this tag, in
    /// address order, and the replies leave together.
    RegisterBulkRead { first: u8, count: u8, tag: u16 },
    /// 0x005: `01`.
    ResetOdometry,
    /// 0x006: `01`.
    Heartbeat,
    /// 0x007.
    ScaleCalibration(ScaleCalibrationCommand),
    /// 0x008.
    OdometryCalibration(OdometryCalibrationCommand),
}

impl Command {
    /// `Ok(None)`: the frame is not for the base controller (unknown ID, or a register
    /// reply from another controller on the bus). Extra bytes after the ones a frame
    /// needs are ignored, as long as the frame has at most 8.
    pub fn decode(id: u16, data: &[u8]) -> Result<Option<Command>, FrameError> {
        if !id::COMMANDS.contains(&id) {
            return Ok(None);
        }
        if data.len() > MAX_DATA_LEN {
            return Err(FrameError::WrongLength);
        }
        // Every frame for us carries at least one byte.
        let &[first, ref rest @ ..] = data else {
            return Err(FrameError::WrongLength);
        };
        let command = match id {
            id::ENABLE => Command::Enable {
                refresh: first == ENABLE_REFRESH,
            },
            id::VELOCITY => {
                let &[linear_msb, rotation_lsb, rotation_msb, marker, ..] = rest else {
                    return Err(FrameError::WrongLength);
                };
                if marker != VELOCITY_MARKER {
                    return Err(FrameError::BadVelocityMarker);
                }
                Command::Velocity {
                    linear_mm_s: i16::from_le_bytes([first, linear_msb]),
                    rotation_mrad_s: i16::from_le_bytes([rotation_lsb, rotation_msb]),
                }
            }
            id::REGISTER_WRITE => Command::RegisterWrite {
                address: first,
                value: be_u16(rest)?,
            },
            id::REGISTER_READ => match (first, rest) {
                (REGISTER_VALUE | REGISTER_ERROR, _) => return Ok(None),
                (REGISTER_READ_REQUEST, &[address, ref tag @ ..]) => Command::RegisterRead {
                    address,
                    // A tag needs both bytes; a lone third byte is extra, as before.
                    tag: be_u16(tag).unwrap_or(0),
                },
                (REGISTER_READ_REQUEST, []) => return Err(FrameError::WrongLength),
                (REGISTER_BULK_READ_REQUEST, &[first, count, tag_msb, tag_lsb, ..]) => {
                    if count == 0
                        || count > BULK_READ_MAX
                        || usize::from(first) + usize::from(count) > 256
                    {
                        return Err(FrameError::BadReadCount);
                    }
                    Command::RegisterBulkRead {
                        first,
                        count,
                        tag: u16::from_be_bytes([tag_msb, tag_lsb]),
                    }
                }
                (REGISTER_BULK_READ_REQUEST, _) => return Err(FrameError::WrongLength),
                _ => return Err(FrameError::UnknownSubcommand),
            },
            id::RESET_ODOMETRY => only_request(first, Command::ResetOdometry)?,
            id::HEARTBEAT => only_request(first, Command::Heartbeat)?,
            id::SCALE_CALIBRATION => Command::ScaleCalibration(decode_scale(first, rest)?),
            id::ODOMETRY_CALIBRATION => Command::OdometryCalibration(decode_odometry(first, rest)?),
            _ => return Ok(None),
        };
        Ok(Some(command))
    }

    /// The frame the robot PC sends for this command, with the manual's DLC.
    pub fn encode(&self) -> RawFrame {
        match *self {
            Command::Enable { refresh } => {
                let first = if refresh { ENABLE_REFRESH } else { 0x00 };
                RawFrame::from_array(id::ENABLE, [first, 0, 0, 0, 0, 0, 0, 0])
            }
            Command::Velocity {
                linear_mm_s,
                rotation_mrad_s,
            } => {
                let [l0, l1] = linear_mm_s.to_le_bytes();
                let [r0, r1] = rotation_mrad_s.to_le_bytes();
                RawFrame::from_array(id::VELOCITY, [l0, l1, r0, r1, VELOCITY_MARKER])
            }
            Command::RegisterWrite { address, value } => {
                let [msb, lsb] = value.to_be_bytes();
                RawFrame::from_array(id::REGISTER_WRITE, [address, msb, lsb])
            }
            Command::RegisterRead { address, tag: 0 } => {
                RawFrame::from_array(id::REGISTER_READ, [REGISTER_READ_REQUEST, address])
            }
            Command::RegisterRead { address, tag } => {
                let [tag_msb, tag_lsb] = tag.to_be_bytes();
                RawFrame::from_array(
                    id::REGISTER_READ,
                    [REGISTER_READ_REQUEST, address, tag_msb, tag_lsb],
                )
            }
            Command::RegisterBulkRead { first, count, tag } => {
                let [tag_msb, tag_lsb] = tag.to_be_bytes();
                RawFrame::from_array(
                    id::REGISTER_READ,
                    [REGISTER_BULK_READ_REQUEST, first, count, tag_msb, tag_lsb],
                )
            }
            Command::ResetOdometry => RawFrame::from_array(id::RESET_ODOMETRY, [REQUEST]),
            Command::Heartbeat => RawFrame::from_array(id::HEARTBEAT, [REQUEST]),
            Command::ScaleCalibration(step) => encode_scale(step),
            Command::OdometryCalibration(step) => encode_odometry(step),
        }
    }
}

fn only_request(first: u8, command: Command) -> Result<Command, FrameError> {
    if first == REQUEST {
        Ok(command)
    } else {
        Err(FrameError::UnknownSubcommand)
    }
}

/// The big-endian value at the start of `bytes` (register and calibration frames).
fn be_u16(bytes: &[u8]) -> Result<u16, FrameError> {
    match *bytes {
        [msb, lsb, ..] => Ok(u16::from_be_bytes([msb, lsb])),
        _ => Err(FrameError::WrongLength),
    }
}

fn decode_scale(first: u8, rest: &[u8]) -> Result<ScaleCalibrationCommand, FrameError> {
    Ok(match first {
        SCALE_START => ScaleCalibrationCommand::Start,
        SCALE_TARE => ScaleCalibrationCommand::Tare,
        SCALE_KNOWN_WEIGHT => ScaleCalibrationCommand::KnownWeight {
            grams: be_u16(rest)?,
        },
        _ => return Err(FrameError::UnknownSubcommand),
    })
}

fn encode_scale(step: ScaleCalibrationCommand) -> RawFrame {
    let id = id::SCALE_CALIBRATION;
    match step {
        ScaleCalibrationCommand::Start => RawFrame::from_array(id, [SCALE_START]),
        ScaleCalibrationCommand::Tare => RawFrame::from_array(id, [SCALE_TARE]),
        ScaleCalibrationCommand::KnownWeight { grams } => {
            let [msb, lsb] = grams.to_be_bytes();
            RawFrame::from_array(id, [SCALE_KNOWN_WEIGHT, msb, lsb])
        }
    }
}

fn decode_odometry(first: u8, rest: &[u8]) -> Result<OdometryCalibrationCommand, FrameError> {
    use OdometryCalibrationCommand as Step;
    Ok(match first {
        ODOMETRY_START_LINEAR => Step::StartLinear,
        ODOMETRY_END_LINEAR => Step::EndLinear {
            real_mm: be_u16(rest)?,
        },
        ODOMETRY_START_CLOCKWISE => Step::StartClockwise,
        ODOMETRY_END_CLOCKWISE => Step::EndClockwise {
            real_mrad: be_u16(rest)?,
        },
        ODOMETRY_START_COUNTER_CLOCKWISE => Step::StartCounterClockwise,
        ODOMETRY_END_COUNTER_CLOCKWISE => Step::EndCounterClockwise {
            real_mrad: be_u16(rest)?,
        },
        ODOMETRY_STORE => Step::Store,
        _ => return Err(FrameError::UnknownSubcommand),
    })
}

fn encode_odometry(step: OdometryCalibrationCommand) -> RawFrame {
    use OdometryCalibrationCommand as Step;
    let id = id::ODOMETRY_CALIBRATION;
    let with_value = |sub_command: u8, value: u16| {
        let [msb, lsb] = value.to_be_bytes();
        RawFrame::from_array(id, [sub_command, msb, lsb])
    };
    match step {
        Step::StartLinear => RawFrame::from_array(id, [ODOMETRY_START_LINEAR]),
        Step::EndLinear { real_mm } => with_value(ODOMETRY_END_LINEAR, real_mm),
        Step::StartClockwise => RawFrame::from_array(id, [ODOMETRY_START_CLOCKWISE]),
        Step::EndClockwise { real_mrad } => with_value(ODOMETRY_END_CLOCKWISE, real_mrad),
        Step::StartCounterClockwise => RawFrame::from_array(id, [ODOMETRY_START_COUNTER_CLOCKWISE]),
        Step::EndCounterClockwise { real_mrad } => {
            with_value(ODOMETRY_END_COUNTER_CLOCKWISE, real_mrad)
        }
        Step::Store => RawFrame::from_array(id, [ODOMETRY_STORE]),
    }
}
