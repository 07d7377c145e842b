//! Frames from the base controller to the robot PC (docs/protocol.md): encoded on the robot,
//! decoded by test tools and the PC-side CLI.

use super::command::{
    REGISTER_BULK_READ_REQUEST, REGISTER_ERROR, REGISTER_READ_REQUEST, REGISTER_VALUE,
};
use super::{FrameError, MAX_DATA_LEN, RawFrame, Status, id};

/// Which read a register reply answers (ext, after the manual's bytes): the address
/// asked for and the tag the request carried (0 for the manual's two-byte request).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReadEcho {
    pub address: u8,
    pub tag: u16,
}

/// One message to the robot PC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Report {
    /// 0x0EC: x forward, y to the right, since the last odometry reset.
    Position { x_mm: i32, y_mm: i32 },
    /// 0x0ED: positive clockwise, cumulative (not wrapped).
    Heading { heading_mrad: i32 },
    /// 0x0EF (ext): the moment, on the controller's clock (milliseconds since boot,
    /// wrapping after 49.7 days), at which the pose in the 0x0EC and 0x0ED that follow
    /// this frame holds. Sent just before them in every cycle.
    PoseTime { controller_ms: u32 },
    /// 0x0F0 (ext): the speeds the drives measured at the reading the next pose is
    /// carried on from, sent between 0x0EF and 0x0EC. Linear + forward, rotation +
    /// clockwise (like 0x0C8 and 0x0ED), each wheel + when it drives the base forward,
    /// in hundredths of a radian per second. Each saturates at the i16 range.
    MeasuredSpeed {
        linear_mm_s: i16,
        rotation_mrad_s: i16,
        left_wheel_crad_s: i16,
        right_wheel_crad_s: i16,
    },
    /// 0x0EB.
    Battery { percent: u8, voltage_mv: u16 },
    /// 0x0EA: the producer clamps negative weights to 0.
    Weight { grams: u16 },
    /// 0x004 `00 MSB LSB addr tagMSB tagLSB`: reply to a register read. Bytes 0–2 are
    /// the manual's; bytes 3–5 (ext) say which read it answers. `echo` is `None` for a
    /// three-byte reply (firmware before the extension), which cannot be matched.
    RegisterValue { value: u16, echo: Option<ReadEcho> },
    /// 0x004 `FF addr reason tagMSB tagLSB` (ext): the read was refused; `reason` is the
    /// register module's rejection code, `tag` the request's (`None` for a three-byte
    /// refusal from firmware before the tag).
    RegisterReadError {
        address: u8,
        reason: u8,
        tag: Option<u16>,
    },
    /// 0x0EE (ext).
    Status(Status),
}

impl Report {
    /// The exact DLC of each report is required: the base controller always sends it,
    /// so anything else is a different device or a corrupt capture. `Ok(None)`: not a
    /// report (unknown ID, or a register read request on 0x004).
    pub fn decode(id: u16, data: &[u8]) -> Result<Option<Report>, FrameError> {
        if !id::REPORTS.contains(&id) {
            return Ok(None);
        }
        if data.len() > MAX_DATA_LEN {
            return Err(FrameError::WrongLength);
        }
        let report = match id {
            id::POSITION => {
                let &[x0, x1, x2, x3, y0, y1, y2, y3] = data else {
                    return Err(FrameError::WrongLength);
                };
                Report::Position {
                    x_mm: i32::from_le_bytes([x0, x1, x2, x3]),
                    y_mm: i32::from_le_bytes([y0, y1, y2, y3]),
                }
            }
            id::HEADING => {
                let &[h0, h1, h2, h3] = data else {
                    return Err(FrameError::WrongLength);
                };
                Report::Heading {
                    heading_mrad: i32::from_le_bytes([h0, h1, h2, h3]),
                }
            }
            id::POSE_TIME => {
                let &[t0, t1, t2, t3] = data else {
                    return Err(FrameError::WrongLength);
                };
                Report::PoseTime {
                    controller_ms: u32::from_le_bytes([t0, t1, t2, t3]),
                }
            }
            id::MEASURED_SPEED => {
                let &[l0, l1, r0, r1, a0, a1, b0, b1] = data else {
                    return Err(FrameError::WrongLength);
                };
                Report::MeasuredSpeed {
                    linear_mm_s: i16::from_le_bytes([l0, l1]),
                    rotation_mrad_s: i16::from_le_bytes([r0, r1]),
                    left_wheel_crad_s: i16::from_le_bytes([a0, a1]),
                    right_wheel_crad_s: i16::from_le_bytes([b0, b1]),
                }
            }
            id::BATTERY => {
                let &[percent, v0, v1] = data else {
                    return Err(FrameError::WrongLength);
                };
                Report::Battery {
                    percent,
                    voltage_mv: u16::from_le_bytes([v0, v1]),
                }
            }
            id::WEIGHT => {
                let &[g0, g1] = data else {
                    return Err(FrameError::WrongLength);
                };
                Report::Weight {
                    grams: u16::from_le_bytes([g0, g1]),
                }
            }
            id::REGISTER_READ => match *data {
                [REGISTER_READ_REQUEST | REGISTER_BULK_READ_REQUEST, ..] => return Ok(None),
                [REGISTER_VALUE, msb, lsb] => Report::RegisterValue {
                    value: u16::from_be_bytes([msb, lsb]),
                    echo: None,
                },
                [REGISTER_VALUE, msb, lsb, address, tag_msb, tag_lsb] => Report::RegisterValue {
                    value: u16::from_be_bytes([msb, lsb]),
                    echo: Some(ReadEcho {
                        address,
                        tag: u16::from_be_bytes([tag_msb, tag_lsb]),
                    }),
                },
                [REGISTER_ERROR, address, reason] => Report::RegisterReadError {
                    address,
                    reason,
                    tag: None,
                },
                [REGISTER_ERROR, address, reason, tag_msb, tag_lsb] => Report::RegisterReadError {
                    address,
                    reason,
                    tag: Some(u16::from_be_bytes([tag_msb, tag_lsb])),
                },
                [] | [REGISTER_VALUE | REGISTER_ERROR, ..] => {
                    return Err(FrameError::WrongLength);
                }
                _ => return Err(FrameError::UnknownSubcommand),
            },
            id::STATUS => {
                let Ok(bytes) = <[u8; 8]>::try_from(data) else {
                    return Err(FrameError::WrongLength);
                };
                Report::Status(Status::from_bytes(bytes)?)
            }
            _ => return Ok(None),
        };
        Ok(Some(report))
    }

    pub fn encode(&self) -> RawFrame {
        match *self {
            Report::Position { x_mm, y_mm } => {
                let [x0, x1, x2, x3] = x_mm.to_le_bytes();
                let [y0, y1, y2, y3] = y_mm.to_le_bytes();
                RawFrame::from_array(id::POSITION, [x0, x1, x2, x3, y0, y1, y2, y3])
            }
            Report::Heading { heading_mrad } => {
                RawFrame::from_array(id::HEADING, heading_mrad.to_le_bytes())
            }
            Report::PoseTime { controller_ms } => {
                RawFrame::from_array(id::POSE_TIME, controller_ms.to_le_bytes())
            }
            Report::MeasuredSpeed {
                linear_mm_s,
                rotation_mrad_s,
                left_wheel_crad_s,
                right_wheel_crad_s,
            } => {
                let [l0, l1] = linear_mm_s.to_le_bytes();
                let [r0, r1] = rotation_mrad_s.to_le_bytes();
                let [a0, a1] = left_wheel_crad_s.to_le_bytes();
                let [b0, b1] = right_wheel_crad_s.to_le_bytes();
                RawFrame::from_array(id::MEASURED_SPEED, [l0, l1, r0, r1, a0, a1, b0, b1])
            }
            Report::Battery {
                percent,
                voltage_mv,
            } => {
                let [v0, v1] = voltage_mv.to_le_bytes();
                RawFrame::from_array(id::BATTERY, [percent, v0, v1])
            }
            Report::Weight { grams } => RawFrame::from_array(id::WEIGHT, grams.to_le_bytes()),
            Report::RegisterValue { value, echo: None } => {
                let [msb, lsb] = value.to_be_bytes();
                RawFrame::from_array(id::REGISTER_READ, [REGISTER_VALUE, msb, lsb])
            }
            Report::RegisterValue {
                value,
                echo: Some(ReadEcho { address, tag }),
            } => {
                let [msb, lsb] = value.to_be_bytes();
                let [tag_msb, tag_lsb] = tag.to_be_bytes();
                RawFrame::from_array(
                    id::REGISTER_READ,
                    [REGISTER_VALUE, msb, lsb, address, tag_msb, tag_lsb],
                )
            }
            Report::RegisterReadError {
                address,
                reason,
                tag: None,
            } => RawFrame::from_array(id::REGISTER_READ, [REGISTER_ERROR, address, reason]),
            Report::RegisterReadError {
                address,
                reason,
                tag: Some(tag),
            } => {
                let [tag_msb, tag_lsb] = tag.to_be_bytes();
                RawFrame::from_array(
                    id::REGISTER_READ,
                    [REGISTER_ERROR, address, reason, tag_msb, tag_lsb],
                )
            }
            Report::Status(status) => RawFrame::from_array(id::STATUS, status.to_bytes()),
        }
    }
}
