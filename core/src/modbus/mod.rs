//! Modbus-RTU frames for the Oriental Motor BLV R drives in ID share mode: building
//! requests and checking replies, byte for byte as the BLV R manual has them (docs/drives.md).
//! No I/O and no time: the drive link sends what this builds and hands back what it read.
//!
//! Hand-written rather than taken from a crate: the maintained `no_std` Modbus crates
//! (rmodbus, modbus-core) cannot parse the ID-share reply (a check word after every
//! member's block, a byte count covering the whole group, an optional trailing CRC), and
//! the standard part we need is three function codes. The CRC is `crc::CRC_16_MODBUS`.

mod frame;
#[cfg(test)]
mod tests;

pub use frame::{
    expected_reply_len, parse_read, parse_share_reply, parse_write_echo, read_items, share_read,
    share_read_write, share_write, try_read_items, try_share_read, try_share_read_write,
    try_share_write, try_write_items, write_items,
};

use crc::{CRC_16_MODBUS, Crc};
use heapless::Vec;

/// Longest RTU frame (Modbus over serial line, and what `om_modbus_master` checks).
pub const MAX_FRAME: usize = 256;

/// One request or reply as it goes on the wire, CRC included.
pub type Frame = Vec<u8, MAX_FRAME>;

/// Read holding registers.
pub const READ_HOLDING: u8 = 0x03;
/// Write multiple registers.
pub const WRITE_MULTIPLE: u8 = 0x10;
/// Read/write multiple registers: the write runs first, then the read.
pub const READ_WRITE_MULTIPLE: u8 = 0x17;

/// Most 32-bit items a share member reads or writes (12 per Oriental's lists). Unicast
/// reads share the limit, so one [`parse_read`] result type fits every read.
pub const MAX_ITEMS: usize = 12;

/// Members in a share group we support.
pub const MAX_MEMBERS: usize = 2;

/// Most 32-bit items in one unicast write: Modbus allows 123 registers per FC 10h.
/// The largest write we send is the 24-item share list setup (the setup's step 3, docs/drives.md).
pub const MAX_WRITE_ITEMS: usize = 61;

/// Length of an exception reply (`addr fc|0x80 code CRC`). A reader that sees bit 7 set
/// in the second byte has the whole reply after this many bytes.
pub const EXCEPTION_REPLY_LEN: usize = 5;

/// The exception codes of the Modbus application protocol that a slave may answer with.
pub mod exception {
    /// The function code is not supported.
    pub const ILLEGAL_FUNCTION: u8 = 0x01;
    /// A register in the request does not exist.
    pub const ILLEGAL_DATA_ADDRESS: u8 = 0x02;
    /// A count or value in the request is out of range.
    pub const ILLEGAL_DATA_VALUE: u8 = 0x03;
    /// The slave failed while executing the request.
    pub const SLAVE_DEVICE_FAILURE: u8 = 0x04;
}

const MODBUS_CRC: Crc<u16> = Crc::<u16>::new(&CRC_16_MODBUS);

/// The Modbus CRC-16 of `bytes`. On the wire it goes low byte first.
pub fn crc16(bytes: &[u8]) -> u16 {
    MODBUS_CRC.checksum(bytes)
}

/// How a request is addressed, which decides the layout of its reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Target {
    /// One slave (or broadcast, address 0, which gets no reply).
    Unicast,
    /// A share group address: every member answers in turn.
    Share,
}

/// Why a request could not be built. The builders only ever see the firmware's own
/// settings, so this marks a programming error; see [`read_items`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RequestError {
    /// No items or no members: Modbus has no empty request.
    Empty,
    /// More items than [`MAX_ITEMS`] ([`MAX_WRITE_ITEMS`] for a unicast write), or more
    /// members than [`MAX_MEMBERS`].
    TooLarge,
    /// Share members with different numbers of values: the drives split the data
    /// evenly, so the request would mean something else than intended.
    UnevenMembers,
}

/// Why a transaction brought no reply to parse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TransferError {
    /// Not a single byte came back in time.
    NoReply,
    /// The port failed to send or receive.
    Port,
}

/// Why a reply was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReplyError {
    /// Fewer bytes than the reply needs: the slave stopped or the reader timed out.
    TooShort,
    /// The frame CRC does not match (line noise, a collision, a wrong baud rate).
    BadCrc,
    /// A valid frame from another address than the one asked.
    WrongAddress,
    /// A valid frame with another function code than the request's.
    WrongFunction,
    /// The slave refused the request with this exception code (see [`exception`]).
    Exception(u8),
    /// A valid frame whose byte count or length does not fit the request.
    BadLength,
    /// A write echo whose start address or register count differs from the request.
    BadEcho,
    /// The check word after this member's block (1-based local ID) does not match.
    BadCheck { member: u8 },
    /// An ID-share reply that stopped after `answered` complete, checked member blocks:
    /// member `answered + 1` went silent (or was cut off), and the ones after it with it.
    PartialShare { answered: u8 },
}

/// The values an ID-share read returned, per member in local-ID order.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ShareReply {
    values: Vec<u32, { MAX_ITEMS * MAX_MEMBERS }>,
    items: usize,
}

impl ShareReply {
    /// Number of members that answered (all of them: partial replies are errors).
    pub fn members(&self) -> usize {
        self.values.len().checked_div(self.items).unwrap_or(0)
    }

    /// Items per member.
    pub fn items(&self) -> usize {
        self.items
    }

    /// The values of member `k` (0-based, so local ID `k + 1`), in share-list order.
    /// Empty for a member that is not in the reply.
    pub fn member(&self, k: usize) -> &[u32] {
        let start = k.saturating_mul(self.items);
        self.values
            .get(start..start.saturating_add(self.items))
            .unwrap_or(&[])
    }
}
