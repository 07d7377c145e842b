//! Request builders and reply parsers. Every 32-bit item is two registers, upper word
//! first, and both halves always travel in one frame (docs/drives.md).

use heapless::Vec;

use super::{
    EXCEPTION_REPLY_LEN, Frame, MAX_ITEMS, MAX_MEMBERS, MAX_WRITE_ITEMS, READ_HOLDING,
    READ_WRITE_MULTIPLE, ReplyError, RequestError, ShareReply, Target, WRITE_MULTIPLE, crc16,
};

/// Address, function code and byte count in front of every read reply's data.
const READ_HEADER: usize = 3;
/// Address, function code, start and count: the whole FC 10h echo without its CRC.
const WRITE_ECHO_LEN: usize = 8;
/// Bytes in one 32-bit item.
const ITEM_BYTES: usize = 4;
/// The check word after each member's block, and the CRC at the end of every frame.
const CRC_BYTES: usize = 2;

/// Appends to a frame and remembers an overflow instead of truncating, so a frame is
/// either complete or refused.
struct FrameBuilder {
    frame: Frame,
    overflow: bool,
}

impl FrameBuilder {
    fn new(address: u8, function: u8) -> Self {
        let mut builder = Self {
            frame: Frame::new(),
            overflow: false,
        };
        builder.bytes(&[address, function]);
        builder
    }

    fn bytes(&mut self, bytes: &[u8]) {
        if self.frame.extend_from_slice(bytes).is_err() {
            self.overflow = true;
        }
    }

    fn word(&mut self, word: u16) {
        self.bytes(&word.to_be_bytes());
    }

    fn items(&mut self, values: &[u32]) {
        for value in values {
            self.bytes(&value.to_be_bytes());
        }
    }

    fn finish(mut self) -> Result<Frame, RequestError> {
        let crc = crc16(&self.frame);
        self.bytes(&crc.to_le_bytes());
        if self.overflow {
            Err(RequestError::TooLarge)
        } else {
            Ok(self.frame)
        }
    }
}

fn check_items(items: usize, max: usize) -> Result<(), RequestError> {
    match items {
        0 => Err(RequestError::Empty),
        n if n > max => Err(RequestError::TooLarge),
        _ => Ok(()),
    }
}

fn check_members(members: usize) -> Result<(), RequestError> {
    match members {
        0 => Err(RequestError::Empty),
        n if n > MAX_MEMBERS => Err(RequestError::TooLarge),
        _ => Ok(()),
    }
}

/// Items per member of a share write, after checking that every member has as many.
fn share_write_items(per_member: &[&[u32]]) -> Result<usize, RequestError> {
    check_members(per_member.len())?;
    let items = per_member.first().map_or(0, |values| values.len());
    if per_member.iter().any(|values| values.len() != items) {
        return Err(RequestError::UnevenMembers);
    }
    check_items(items, MAX_ITEMS)?;
    Ok(items)
}

// The casts to u8/u16 below cannot truncate: the checks above bound every count far
// below 256 registers (at most 2 × 61 for a unicast write, 2 × 25 for a share read).

/// Registers a share read asks for: each member adds one for its check word (docs/drives.md).
fn share_read_count(members: usize, items: usize) -> u16 {
    (members * (2 * items + 1)) as u16
}

/// A unicast FC 03h request for `items` 32-bit items from register `start` on.
pub fn try_read_items(slave: u8, start: u16, items: u16) -> Result<Frame, RequestError> {
    check_items(usize::from(items), MAX_ITEMS)?;
    let mut frame = FrameBuilder::new(slave, READ_HOLDING);
    frame.word(start);
    frame.word(2 * items);
    frame.finish()
}

/// A unicast FC 10h request writing `values` from register `start` on.
pub fn try_write_items(slave: u8, start: u16, values: &[u32]) -> Result<Frame, RequestError> {
    check_items(values.len(), MAX_WRITE_ITEMS)?;
    let registers = (2 * values.len()) as u16;
    let mut frame = FrameBuilder::new(slave, WRITE_MULTIPLE);
    frame.word(start);
    frame.word(registers);
    frame.bytes(&[(2 * registers) as u8]);
    frame.items(values);
    frame.finish()
}

/// An ID-share FC 03h request to group `gid`: `items` from share address `start` on,
/// from each of `members` members.
pub fn try_share_read(gid: u8, start: u16, items: u16, members: u8) -> Result<Frame, RequestError> {
    check_members(usize::from(members))?;
    check_items(usize::from(items), MAX_ITEMS)?;
    let mut frame = FrameBuilder::new(gid, READ_HOLDING);
    frame.word(start);
    frame.word(share_read_count(usize::from(members), usize::from(items)));
    frame.finish()
}

/// An ID-share FC 10h request to group `gid`; `per_member[k]` goes to local ID `k + 1`.
pub fn try_share_write(gid: u8, start: u16, per_member: &[&[u32]]) -> Result<Frame, RequestError> {
    let items = share_write_items(per_member)?;
    let registers = (per_member.len() * 2 * items) as u16;
    let mut frame = FrameBuilder::new(gid, WRITE_MULTIPLE);
    frame.word(start);
    frame.word(registers);
    frame.bytes(&[(2 * registers) as u8]);
    for values in per_member {
        frame.items(values);
    }
    frame.finish()
}

/// An ID-share FC 17h request to group `gid`: writes `per_member` from `write_start` on,
/// then reads `read_items` from `read_start` on, from every member.
pub fn try_share_read_write(
    gid: u8,
    read_start: u16,
    read_items: u16,
    write_start: u16,
    per_member: &[&[u32]],
) -> Result<Frame, RequestError> {
    let write_items = share_write_items(per_member)?;
    check_items(usize::from(read_items), MAX_ITEMS)?;
    let members = per_member.len();
    let write_registers = (members * 2 * write_items) as u16;
    let mut frame = FrameBuilder::new(gid, READ_WRITE_MULTIPLE);
    frame.word(read_start);
    frame.word(share_read_count(members, usize::from(read_items)));
    frame.word(write_start);
    frame.word(write_registers);
    frame.bytes(&[(2 * write_registers) as u8]);
    for values in per_member {
        frame.items(values);
    }
    frame.finish()
}

/// The frame of a request within the limits; see [`read_items`] for what happens outside.
fn within_limits(request: Result<Frame, RequestError>) -> Frame {
    request.unwrap_or_else(|error| {
        debug_assert!(false, "Modbus request outside the limits: {error:?}");
        Frame::new()
    })
}

/// A unicast FC 03h request for `items` 32-bit items (`2 × items` registers).
///
/// # Limits
/// `1 ..= MAX_ITEMS` items. The builders only see the firmware's own settings, so a
/// request outside the limits is a bug: a debug build panics, a release build returns
/// an empty frame, which gets no reply (the link sees a timeout, never a wrong
/// command). The `try_` variants return the [`RequestError`] instead.
pub fn read_items(slave: u8, start: u16, items: u16) -> Frame {
    within_limits(try_read_items(slave, start, items))
}

/// A unicast FC 10h request writing `values`, `1 ..= MAX_WRITE_ITEMS` of them. Limits as
/// for [`read_items`].
pub fn write_items(slave: u8, start: u16, values: &[u32]) -> Frame {
    within_limits(try_write_items(slave, start, values))
}

/// An ID-share FC 03h request: register count `members × (2 × items + 1)`.
/// `1 ..= MAX_ITEMS` items and `1 ..= MAX_MEMBERS` members; limits as for [`read_items`].
pub fn share_read(gid: u8, start: u16, items: u16, members: u8) -> Frame {
    within_limits(try_share_read(gid, start, items, members))
}

/// An ID-share FC 10h request: register count `members × 2 × items`. Every member gets
/// as many values, `1 ..= MAX_ITEMS`; limits as for [`read_items`].
pub fn share_write(gid: u8, start: u16, per_member: &[&[u32]]) -> Frame {
    within_limits(try_share_write(gid, start, per_member))
}

/// An ID-share FC 17h request (write first, then read), counts as in [`share_read`] and
/// [`share_write`]; limits as for [`read_items`].
pub fn share_read_write(
    gid: u8,
    read_start: u16,
    read_items: u16,
    write_start: u16,
    per_member: &[&[u32]],
) -> Frame {
    within_limits(try_share_read_write(
        gid,
        read_start,
        read_items,
        write_start,
        per_member,
    ))
}

/// Length of the complete normal reply to `request`, so a reader knows when it is done.
///
/// - For an ID-share read ([`Target::Share`], FC 03h or 17h) this excludes the optional
///   2-byte trailer: a reader may stop here, or wait for a C3.5 idle gap to collect it.
/// - An exception reply is shorter: [`EXCEPTION_REPLY_LEN`] bytes, recognisable by
///   bit 7 in its second byte.
/// - `None` when no reply comes (broadcast, address 0) or `request` is not a request
///   these builders make.
pub fn expected_reply_len(request: &[u8], target: Target) -> Option<usize> {
    let [address, function, _, _, count_high, count_low, ..] = *request else {
        return None;
    };
    if address == 0 {
        return None;
    }
    // For FC 17h this is the read count, which sits where FC 03h has its count.
    let registers = usize::from(u16::from_be_bytes([count_high, count_low]));
    match (function, target) {
        (WRITE_MULTIPLE, _) => Some(WRITE_ECHO_LEN),
        (READ_HOLDING | READ_WRITE_MULTIPLE, Target::Unicast) => {
            Some(READ_HEADER + 2 * registers + CRC_BYTES)
        }
        // The last member's check word already closes the frame.
        (READ_HOLDING | READ_WRITE_MULTIPLE, Target::Share) => Some(READ_HEADER + 2 * registers),
        _ => None,
    }
}

/// Whether the frame ends in the CRC of everything before it.
fn crc_matches(frame: &[u8]) -> bool {
    frame
        .split_last_chunk::<CRC_BYTES>()
        .is_some_and(|(body, crc)| crc16(body) == u16::from_le_bytes(*crc))
}

/// The verdict on `reply` if it has the shape of an exception (`addr fc|0x80 code CRC`).
fn exception(reply: &[u8], address: u8, function: u8) -> Option<ReplyError> {
    let [from, replied_function, code, _, _] = *reply else {
        return None;
    };
    if replied_function & 0x80 == 0 {
        return None;
    }
    Some(if !crc_matches(reply) {
        ReplyError::BadCrc
    } else if from != address {
        ReplyError::WrongAddress
    } else if replied_function != function | 0x80 {
        ReplyError::WrongFunction
    } else {
        ReplyError::Exception(code)
    })
}

/// Checks what every fixed-length reply shares. The CRC comes before address and
/// function, so that those errors mean a real frame from someone else, not noise.
fn check_frame(reply: &[u8], address: u8, function: u8, len: usize) -> Result<(), ReplyError> {
    debug_assert!(len >= EXCEPTION_REPLY_LEN);
    if let Some(error) = exception(reply, address, function) {
        return Err(error);
    }
    if reply.len() < len {
        return Err(ReplyError::TooShort);
    }
    if reply.len() > len {
        return Err(ReplyError::BadLength);
    }
    if !crc_matches(reply) {
        return Err(ReplyError::BadCrc);
    }
    let [from, replied_function, ..] = *reply else {
        return Err(ReplyError::TooShort);
    };
    if from != address {
        return Err(ReplyError::WrongAddress);
    }
    if replied_function != function {
        return Err(ReplyError::WrongFunction);
    }
    Ok(())
}

/// Appends the big-endian 32-bit items in `data` (a multiple of 4 bytes long).
fn push_items<const N: usize>(data: &[u8], values: &mut Vec<u32, N>) -> Result<(), ReplyError> {
    let (items, _) = data.as_chunks::<ITEM_BYTES>();
    for item in items {
        values
            .push(u32::from_be_bytes(*item))
            .map_err(|_| ReplyError::BadLength)?;
    }
    Ok(())
}

/// Checks the echo of an FC 10h write (unicast, or ID share to a group address): the
/// same `start` and register `count` as the request.
pub fn parse_write_echo(
    reply: &[u8],
    address: u8,
    start: u16,
    count: u16,
) -> Result<(), ReplyError> {
    check_frame(reply, address, WRITE_MULTIPLE, WRITE_ECHO_LEN)?;
    let [_, _, start_high, start_low, count_high, count_low, ..] = *reply else {
        return Err(ReplyError::TooShort);
    };
    let echoed_start = u16::from_be_bytes([start_high, start_low]);
    let echoed_count = u16::from_be_bytes([count_high, count_low]);
    if (echoed_start, echoed_count) != (start, count) {
        return Err(ReplyError::BadEcho);
    }
    Ok(())
}

/// The `items` 32-bit values of a unicast FC 03h reply from `slave`.
/// `items` outside `1 ..= MAX_ITEMS` matches no reply: `BadLength`.
pub fn parse_read(
    reply: &[u8],
    slave: u8,
    items: usize,
) -> Result<Vec<u32, MAX_ITEMS>, ReplyError> {
    if items == 0 || items > MAX_ITEMS {
        return Err(ReplyError::BadLength);
    }
    let data_len = ITEM_BYTES * items;
    check_frame(
        reply,
        slave,
        READ_HOLDING,
        READ_HEADER + data_len + CRC_BYTES,
    )?;
    let data = reply
        .get(READ_HEADER..READ_HEADER + data_len)
        .ok_or(ReplyError::TooShort)?;
    if reply.get(2).map(|&count| usize::from(count)) != Some(data_len) {
        return Err(ReplyError::BadLength);
    }
    let mut values = Vec::new();
    push_items(data, &mut values)?;
    Ok(values)
}

/// The values of an ID-share reply to FC 03h or 17h (`function`) from group `gid`:
/// `GID fc BC | data1 CHK1 | data2 CHK2 | [CRC]`, accepted with or without the 2
/// trailing bytes (drives are reported to differ; when present they must be the CRC).
///
/// Members answer in turn, so a silent member ends the frame early: a reply that stops
/// after `k` complete member blocks with valid check words is
/// `PartialShare { answered: k }`, telling the link which member went silent. A block
/// that is complete but fails its check word is `BadCheck`; the header is judged only
/// once member 1's check word has vouched for it.
///
/// `members` outside `1 ..= MAX_MEMBERS` or `items` outside `1 ..= MAX_ITEMS` match no
/// reply (`BadLength`), nor does a `function` other than 03h or 17h (`WrongFunction`).
pub fn parse_share_reply(
    reply: &[u8],
    gid: u8,
    function: u8,
    members: u8,
    items: usize,
) -> Result<ShareReply, ReplyError> {
    if !matches!(function, READ_HOLDING | READ_WRITE_MULTIPLE) {
        return Err(ReplyError::WrongFunction);
    }
    if members == 0 || usize::from(members) > MAX_MEMBERS || items == 0 || items > MAX_ITEMS {
        return Err(ReplyError::BadLength);
    }
    if let Some(error) = exception(reply, gid, function) {
        return Err(error);
    }
    let block = ITEM_BYTES * items + CRC_BYTES;
    let mut values = Vec::new();
    for member in 0..members {
        let block_end = READ_HEADER + (usize::from(member) + 1) * block;
        // Each check word covers everything from the group address up to itself.
        let Some(through_check) = reply.get(..block_end) else {
            return Err(ReplyError::PartialShare { answered: member });
        };
        if !crc_matches(through_check) {
            return Err(ReplyError::BadCheck { member: member + 1 });
        }
        if member == 0 {
            check_share_header(through_check, gid, function, usize::from(members) * block)?;
        }
        let data = through_check
            .get(block_end - block..block_end - CRC_BYTES)
            .ok_or(ReplyError::TooShort)?;
        push_items(data, &mut values)?;
    }
    let blocks_end = READ_HEADER + usize::from(members) * block;
    match reply.len() - blocks_end {
        0 => {}
        CRC_BYTES if crc_matches(reply) => {}
        CRC_BYTES => return Err(ReplyError::BadCrc),
        _ => return Err(ReplyError::BadLength),
    }
    Ok(ShareReply { values, items })
}

fn check_share_header(
    reply: &[u8],
    gid: u8,
    function: u8,
    byte_count: usize,
) -> Result<(), ReplyError> {
    let [from, replied_function, replied_count, ..] = *reply else {
        return Err(ReplyError::TooShort);
    };
    if from != gid {
        return Err(ReplyError::WrongAddress);
    }
    if replied_function != function {
        return Err(ReplyError::WrongFunction);
    }
    if usize::from(replied_count) != byte_count {
        return Err(ReplyError::BadLength);
    }
    Ok(())
}
