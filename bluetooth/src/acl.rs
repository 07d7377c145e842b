//! ACL data between the host and the controller: the packet header, reassembly of
//! L2CAP frames the controller hands over in pieces, and the way out, cut to the
//! controller's buffer size and sent only while it has free buffers (flow control:
//! Number Of Completed Packets gives them back).

use heapless::{Deque, Vec};

use crate::hci::{AclBuffers, Handle};

/// The longest L2CAP frame (header included) the host takes in: our channels' MTU
/// plus the 4-byte basic header. Longer frames are refused.
pub const MAX_RX_FRAME: usize = 4 + crate::RECEIVE_MTU as usize;
/// The longest L2CAP frame the host sends: an output report (79 bytes) with its header.
pub const MAX_TX_FRAME: usize = 96;
/// How many frames wait for controller buffers before new ones are refused.
pub const TX_QUEUE: usize = 8;

/// One ACL data packet as it goes to the controller (header and payload).
pub type AclPacket = Vec<u8, { MAX_TX_FRAME + 4 }>;

/// The packet boundary flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Boundary {
    /// The first piece of an L2CAP frame.
    First,
    /// A later piece.
    Continuing,
}

/// Why ACL data was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AclError {
    /// Shorter than its header, or than the length its header gives.
    Truncated,
    /// A continuing piece with no frame begun.
    OutOfSequence,
    /// The frame's length is beyond [`MAX_RX_FRAME`], or the pieces overrun it.
    TooLong,
    /// Broadcast flags, or the reserved boundary value.
    BadFlags,
}

/// Splits an ACL packet from the controller into handle, boundary and payload.
pub fn split(packet: &[u8]) -> Result<(Handle, Boundary, &[u8]), AclError> {
    let [h0, h1, l0, l1, payload @ ..] = packet else {
        return Err(AclError::Truncated);
    };
    if usize::from(u16::from_le_bytes([*l0, *l1])) != payload.len() {
        return Err(AclError::Truncated);
    }
    let header = u16::from_le_bytes([*h0, *h1]);
    let boundary = match (header >> 12) & 0b11 {
        0b10 | 0b00 => Boundary::First,
        0b01 => Boundary::Continuing,
        _ => return Err(AclError::BadFlags),
    };
    if header >> 14 != 0 {
        return Err(AclError::BadFlags);
    }
    Ok((Handle::from_bits(header), boundary, payload))
}

/// Puts the controller's pieces of one link back into whole L2CAP frames.
#[derive(Debug, Clone, Default)]
pub struct Reassembler {
    frame: Vec<u8, MAX_RX_FRAME>,
    /// The frame in the buffer was handed out whole: the next piece starts anew.
    handed_out: bool,
    /// Frames whose next piece never came before another frame began.
    abandoned: u32,
}

impl Reassembler {
    pub const fn new() -> Reassembler {
        Reassembler {
            frame: Vec::new(),
            handed_out: false,
            abandoned: 0,
        }
    }

    /// Frames dropped unfinished because another began.
    pub fn abandoned(&self) -> u32 {
        self.abandoned
    }

    /// Adds one piece; answers the whole frame once its last piece is in.
    pub fn push(&mut self, boundary: Boundary, piece: &[u8]) -> Result<Option<&[u8]>, AclError> {
        if self.handed_out {
            self.frame.clear();
            self.handed_out = false;
        }
        let in_progress = !self.frame.is_empty();
        match boundary {
            Boundary::First if in_progress => {
                // The unfinished frame is lost; the new one starts.
                self.abandoned = self.abandoned.saturating_add(1);
                self.frame.clear();
            }
            Boundary::Continuing if !in_progress => return Err(AclError::OutOfSequence),
            Boundary::First | Boundary::Continuing => {}
        }
        if self.frame.extend_from_slice(piece).is_err() {
            self.frame.clear();
            return Err(AclError::TooLong);
        }
        let Some(&[l0, l1]) = self.frame.get(..2) else {
            return Ok(None);
        };
        let expected = 4 + usize::from(u16::from_le_bytes([l0, l1]));
        if expected > MAX_RX_FRAME || self.frame.len() > expected {
            self.frame.clear();
            return Err(AclError::TooLong);
        }
        if self.frame.len() < expected {
            return Ok(None);
        }
        self.handed_out = true;
        Ok(Some(&self.frame))
    }
}

/// The way out: frames queued for the controller, cut to its ACL packet length, sent
/// while it has free buffers.
#[derive(Debug, Clone)]
pub struct AclSender {
    buffers: AclBuffers,
    /// Controller buffers not yet used.
    free: u16,
    queue: Deque<(Handle, Vec<u8, MAX_TX_FRAME>), TX_QUEUE>,
    /// How much of the front frame has been sent.
    sent: usize,
}

/// Why a frame was not queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SendError {
    /// Longer than [`MAX_TX_FRAME`].
    TooLong,
    /// [`TX_QUEUE`] frames are already waiting: the controller does not keep up.
    QueueFull,
}

impl AclSender {
    /// Before Read Buffer Size has answered: one buffer of the smallest size the
    /// specification allows a BR/EDR controller (27 bytes).
    pub const fn new() -> AclSender {
        AclSender {
            buffers: AclBuffers {
                packet_len: 27,
                packets: 1,
            },
            free: 1,
            queue: Deque::new(),
            sent: 0,
        }
    }

    /// The controller's buffers, as Read Buffer Size reported them: all free.
    pub fn set_buffers(&mut self, buffers: AclBuffers) {
        let buffers = AclBuffers {
            packet_len: buffers.packet_len.max(1),
            packets: buffers.packets.max(1),
        };
        self.buffers = buffers;
        self.free = buffers.packets;
    }

    /// Queues one whole L2CAP frame (header included) for `handle`.
    pub fn queue(&mut self, handle: Handle, frame: &[u8]) -> Result<(), SendError> {
        let frame = Vec::from_slice(frame).map_err(|_| SendError::TooLong)?;
        self.queue
            .push_back((handle, frame))
            .map_err(|_| SendError::QueueFull)
    }

    /// The controller finished `packets` of ours: their buffers are free again.
    pub fn completed(&mut self, packets: u16) {
        self.free = self.free.saturating_add(packets).min(self.buffers.packets);
    }

    /// A link closed: its queued frames are dropped and, as the specification says,
    /// the controller's buffers it held count as free.
    pub fn link_closed(&mut self, handle: Handle) {
        if self.queue.front().is_some_and(|(h, _)| *h == handle) {
            self.sent = 0;
        }
        for _ in 0..self.queue.len() {
            if let Some(entry) = self.queue.pop_front()
                && entry.0 != handle
            {
                let _ = self.queue.push_back(entry);
            }
        }
        self.free = self.buffers.packets;
    }

    /// The next ACL packet to hand to the controller, if one waits and a buffer is free.
    pub fn next_packet(&mut self) -> Option<AclPacket> {
        if self.free == 0 {
            return None;
        }
        let (handle, frame) = self.queue.front()?;
        let piece_len = (frame.len() - self.sent).min(usize::from(self.buffers.packet_len));
        let boundary: u16 = if self.sent == 0 { 0b00 } else { 0b01 };
        let header = handle.0 | (boundary << 12);
        let mut packet = AclPacket::new();
        let _ = packet.extend_from_slice(&header.to_le_bytes());
        let _ = packet.extend_from_slice(&(piece_len as u16).to_le_bytes());
        let _ = packet.extend_from_slice(&frame[self.sent..self.sent + piece_len]);
        self.sent += piece_len;
        if self.sent == frame.len() {
            self.queue.pop_front();
            self.sent = 0;
        }
        self.free -= 1;
        Some(packet)
    }

    /// Frames waiting, the one partly sent included.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }
}

impl Default for AclSender {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests;
