//! The Lawicel SLCAN ASCII line codec, for both ends of a USB-CAN adapter's serial
//! port: the simulator's adapter parses the PC's command lines and formats the frames it
//! heard; `basectl` formats the frames it sends and parses the frames it receives.
//! Pure: the serial port, the bus and the channel state belong to the caller.
//!
//! Lines end in CR; the adapter answers CR for OK and BEL for an error. A frame is
//! `tIIILDD…` (standard), `TIIIIIIIILDD…` (extended), `rIIIL` / `RIIIIIIIIL` (remote)
//! in both directions; the adapter may append a 4-digit millisecond timestamp.

use embedded_can::{ExtendedId, Id, StandardId};

pub use embedded_can::Frame as CanFrame;

/// The longest line any command has (`T`, 8 ID digits, DLC, 16 data digits, a
/// timestamp) is 30 characters; the assembler keeps at most this many, so a longer
/// line stays too long to parse and is refused as a whole.
pub const MAX_LINE: usize = 64;

/// The bit rates of `S0`…`S8`, in bit/s.
pub const BITRATES_BPS: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// The `S` command that selects `bitrate_bps`; `None` for a rate SLCAN cannot set.
pub fn bitrate_command(bitrate_bps: u32) -> Option<String> {
    let code = BITRATES_BPS.iter().position(|&bps| bps == bitrate_bps)?;
    Some(format!("S{code}\r"))
}

/// Most data bytes of a classic CAN frame.
const MAX_DLC: usize = 8;

/// The adapter's millisecond timestamp after a received frame's data (`Z1`).
const TIMESTAMP_DIGITS: usize = 4;

/// One line from the PC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command<F> {
    /// `O`: open the channel (join the bus).
    Open,
    /// `C`: close the channel.
    Close,
    /// `S0`…`S8`: the bit rate, in bit/s.
    SetBitrate(u32),
    /// `V`
    Version,
    /// `v`
    FirmwareVersion,
    /// `N`
    SerialNumber,
    /// `F`: read the status flags.
    StatusFlags,
    /// `Z0` / `Z1`: append a millisecond timestamp to received frames, or not.
    Timestamps(bool),
    /// `t`, `T`, `r`, `R`: send a frame on the bus.
    Transmit(F),
}

/// Why a line is not a command or not a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineError {
    /// The first character names no command this codec knows.
    UnknownCommand(u8),
    /// The command's argument is missing, out of range or followed by extra characters.
    BadArgument,
    /// A frame's identifier is not hex of the right width, or too large.
    BadIdentifier,
    /// A frame's length digit is not 0…8.
    BadLength,
    /// A frame's data is not exactly two hex digits per byte of its length (plus an
    /// optional timestamp, where one may follow).
    BadData,
}

impl core::fmt::Display for LineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LineError::UnknownCommand(byte) => {
                write!(f, "unknown command {:?}", char::from(*byte))
            }
            LineError::BadArgument => f.write_str("bad or missing argument"),
            LineError::BadIdentifier => f.write_str("bad frame identifier"),
            LineError::BadLength => f.write_str("frame length is not 0-8"),
            LineError::BadData => f.write_str("data does not match the frame length"),
        }
    }
}

impl std::error::Error for LineError {}

/// Parses one line from the PC, without its CR.
pub fn parse_line<F: CanFrame>(line: &[u8]) -> Result<Command<F>, LineError> {
    let Some((&letter, argument)) = line.split_first() else {
        return Err(LineError::UnknownCommand(b'\r'));
    };
    let no_argument = |command| {
        if argument.is_empty() {
            Ok(command)
        } else {
            Err(LineError::BadArgument)
        }
    };
    match letter {
        b'O' => no_argument(Command::Open),
        b'C' => no_argument(Command::Close),
        b'V' => no_argument(Command::Version),
        b'v' => no_argument(Command::FirmwareVersion),
        b'N' => no_argument(Command::SerialNumber),
        b'F' => no_argument(Command::StatusFlags),
        b'S' => match argument {
            [digit @ b'0'..=b'8'] => {
                Ok(Command::SetBitrate(BITRATES_BPS[usize::from(digit - b'0')]))
            }
            _ => Err(LineError::BadArgument),
        },
        b'Z' => match argument {
            b"0" => Ok(Command::Timestamps(false)),
            b"1" => Ok(Command::Timestamps(true)),
            _ => Err(LineError::BadArgument),
        },
        b't' | b'T' | b'r' | b'R' => parse_frame(line, false).map(Command::Transmit),
        other => Err(LineError::UnknownCommand(other)),
    }
}

/// Parses a frame line from the adapter (without its CR): a PC reads the bus with it.
/// Unlike a PC's transmit line, it may end in a 4-digit timestamp (`Z1`), which is
/// dropped.
pub fn parse_received_frame<F: CanFrame>(line: &[u8]) -> Result<F, LineError> {
    parse_frame(line, true)
}

fn parse_frame<F: CanFrame>(line: &[u8], timestamp_allowed: bool) -> Result<F, LineError> {
    let (extended, remote) = match line.first() {
        Some(b't') => (false, false),
        Some(b'T') => (true, false),
        Some(b'r') => (false, true),
        Some(b'R') => (true, true),
        Some(&other) => return Err(LineError::UnknownCommand(other)),
        None => return Err(LineError::UnknownCommand(b'\r')),
    };
    let text = &line[1..];
    let id_digits = if extended { 8 } else { 3 };
    let id_text = text.get(..id_digits).ok_or(LineError::BadIdentifier)?;
    let raw_id = parse_hex(id_text).ok_or(LineError::BadIdentifier)?;
    let id = if extended {
        Id::Extended(ExtendedId::new(raw_id).ok_or(LineError::BadIdentifier)?)
    } else {
        let raw_id = u16::try_from(raw_id).map_err(|_| LineError::BadIdentifier)?;
        Id::Standard(StandardId::new(raw_id).ok_or(LineError::BadIdentifier)?)
    };
    let (dlc, data_text) = match &text[id_digits..] {
        [digit @ b'0'..=b'8', rest @ ..] => (usize::from(digit - b'0'), rest),
        _ => return Err(LineError::BadLength),
    };
    let data_digits = if remote { 0 } else { 2 * dlc };
    let length_fits = data_text.len() == data_digits
        || (timestamp_allowed && data_text.len() == data_digits + TIMESTAMP_DIGITS);
    if !length_fits {
        return Err(LineError::BadData);
    }
    let frame = if remote {
        F::new_remote(id, dlc)
    } else {
        let mut data = [0; MAX_DLC];
        for (byte, pair) in data
            .iter_mut()
            .zip(data_text[..data_digits].as_chunks::<2>().0)
        {
            *byte = u8::try_from(parse_hex(pair).ok_or(LineError::BadData)?)
                .map_err(|_| LineError::BadData)?;
        }
        F::new(id, &data[..dlc])
    };
    frame.ok_or(LineError::BadLength)
}

/// Hex digits of either case; `None` for anything else (a sign, a space, nothing).
fn parse_hex(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || digits.len() > 8 {
        return None;
    }
    digits.iter().try_fold(0u32, |value, &digit| {
        Some(value << 4 | char::from(digit).to_digit(16)?)
    })
}

/// A frame as a line, CR included: what the PC sends to transmit it, and what the
/// adapter sends for a frame it received. `timestamp_ms` (the adapter's millisecond
/// counter, which wraps at 60 000) is appended when the PC turned timestamps on with
/// `Z1`.
pub fn format_frame<F: CanFrame>(frame: &F, timestamp_ms: Option<u16>) -> String {
    let letter = match (frame.is_extended(), frame.is_remote_frame()) {
        (false, false) => 't',
        (true, false) => 'T',
        (false, true) => 'r',
        (true, true) => 'R',
    };
    let mut line = String::with_capacity(MAX_LINE);
    line.push(letter);
    match frame.id() {
        Id::Standard(id) => line.push_str(&format!("{:03X}", id.as_raw())),
        Id::Extended(id) => line.push_str(&format!("{:08X}", id.as_raw())),
    }
    line.push_str(&frame.dlc().to_string());
    for byte in frame.data() {
        line.push_str(&format!("{byte:02X}"));
    }
    if let Some(timestamp_ms) = timestamp_ms {
        line.push_str(&format!("{:04X}", timestamp_ms % 60_000));
    }
    line.push('\r');
    line
}

/// Cuts a byte stream into lines. CR ends a line, as the protocol says; LF does too, so
/// a person can type commands in a terminal program. Empty lines are dropped: clients
/// send bare CRs to flush a half-sent command, and an adapter's OK is a bare CR.
#[derive(Debug, Default)]
pub struct LineAssembler {
    partial: Vec<u8>,
}

impl LineAssembler {
    /// The lines `bytes` completes, oldest first.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Vec<u8>> {
        let mut lines = Vec::new();
        for &byte in bytes {
            if byte == b'\r' || byte == b'\n' {
                if !self.partial.is_empty() {
                    lines.push(core::mem::take(&mut self.partial));
                }
            } else if self.partial.len() < MAX_LINE {
                self.partial.push(byte);
            }
        }
        lines
    }
}

/// One classic CAN frame (2.0A or 2.0B), data or remote: the frame type of basectl and
/// of the simulator's virtual bus (`embedded-can` defines only the trait). Data bytes past the length are always zero, so the
/// derived equality is equality of frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Frame {
    id: Id,
    remote: bool,
    dlc: u8,
    data: [u8; MAX_DLC],
}

impl Frame {
    /// A standard data frame; `None` if `id` is wider than 11 bits or `data` longer
    /// than 8 bytes.
    pub fn standard(id: u16, data: &[u8]) -> Option<Self> {
        Self::new(StandardId::new(id)?, data)
    }

    /// The 11-bit identifier, if this is a standard frame.
    pub fn standard_id(&self) -> Option<u16> {
        match self.id {
            Id::Standard(id) => Some(id.as_raw()),
            Id::Extended(_) => None,
        }
    }

    /// Bits this frame occupies on the wire, an upper bound.
    ///
    /// Without stuffing a standard frame has 47 bits plus 8 per data byte (SOF, 11-bit
    /// ID, RTR, IDE, r0, DLC, CRC 15, CRC delimiter, ACK slot and delimiter, 7 EOF,
    /// 3 intermission): 111 bits with 8 bytes. An extended frame adds SRR, the
    /// 18-bit ID extension and r1: 67 + 8n. Stuffing inserts a bit after five equal
    /// bits from SOF to the end of the CRC; at worst that is the first five bits and
    /// then every fourth, `(L - 1) / 4` for `L` bits. Counting the worst case instead
    /// of stuffing the real bits (which needs the CRC) keeps the model simple and
    /// errs towards a slower bus: 135 bits for 8 standard bytes, 270 µs at 500 kbit/s.
    /// A remote frame sends no data field, whatever its DLC.
    pub fn wire_bits(&self) -> u32 {
        let data_bits = if self.remote {
            0
        } else {
            8 * u32::from(self.dlc)
        };
        // SOF to the end of the CRC: the part that is stuffed.
        let stuffed = if self.is_extended() { 54 } else { 34 } + data_bits;
        // CRC delimiter, ACK slot and delimiter, end of frame, intermission.
        let trailer = 1 + 2 + 7 + 3;
        stuffed + (stuffed - 1) / 4 + trailer
    }
}

impl CanFrame for Frame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        let mut bytes = [0; MAX_DLC];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Self {
            id: id.into(),
            remote: false,
            dlc: u8::try_from(data.len()).ok()?,
            data: bytes,
        })
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        if dlc > MAX_DLC {
            return None;
        }
        Some(Self {
            id: id.into(),
            remote: true,
            dlc: u8::try_from(dlc).ok()?,
            data: [0; MAX_DLC],
        })
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        self.remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.dlc)
    }

    fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..usize::from(self.dlc)]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn standard(id: u16, data: &[u8]) -> Frame {
        Frame::new(StandardId::new(id).unwrap(), data).unwrap()
    }

    fn parse(line: &[u8]) -> Result<Command<Frame>, LineError> {
        parse_line(line)
    }

    #[test]
    fn standard_data_frames_parse_in_either_case() {
        assert_eq!(
            parse(b"t2E48400000000000000"),
            Err(LineError::BadData),
            "eight bytes need sixteen digits"
        );
        assert_eq!(
            parse(b"t2E484000000000000000"),
            Ok(Command::Transmit(standard(
                0x2E4,
                &[0x40, 0, 0, 0, 0, 0, 0, 0]
            )))
        );
        assert_eq!(
            parse(b"t0c852c01000003"),
            Ok(Command::Transmit(standard(0x0C8, &[0x2C, 0x01, 0, 0, 3])))
        );
        assert_eq!(parse(b"t0050"), Ok(Command::Transmit(standard(5, &[]))));
    }

    #[test]
    fn extended_and_remote_frames_parse() {
        let extended = Id::Extended(ExtendedId::new(0x1234_5678).unwrap());
        assert_eq!(
            parse(b"T123456782ABCD"),
            Ok(Command::Transmit(
                Frame::new(extended, &[0xAB, 0xCD]).unwrap()
            ))
        );
        let standard_id = Id::Standard(StandardId::new(0x0EC).unwrap());
        assert_eq!(
            parse(b"r0EC8"),
            Ok(Command::Transmit(
                Frame::new_remote(standard_id, 8).unwrap()
            ))
        );
        assert_eq!(
            parse(b"R123456780"),
            Ok(Command::Transmit(Frame::new_remote(extended, 0).unwrap()))
        );
    }

    #[test]
    fn malformed_frames_name_what_is_wrong() {
        for (line, error) in [
            (&b"t8000"[..], LineError::BadIdentifier), // wider than 11 bits
            (b"t0G00", LineError::BadIdentifier),
            (b"t0E", LineError::BadIdentifier),
            (b"T200000000", LineError::BadIdentifier), // wider than 29 bits
            (b"t0EC9", LineError::BadLength),
            (b"t0EC", LineError::BadLength),
            (b"t0EC2AB", LineError::BadData),
            (b"t0EC2ABCDEF", LineError::BadData),
            (b"t0EC1X1", LineError::BadData),
            (b"t0EC1+1", LineError::BadData),
            (b"r0EC100", LineError::BadData),
        ] {
            assert_eq!(parse(line), Err(error), "{}", line.escape_ascii());
        }
    }

    #[test]
    fn a_pc_transmit_line_may_not_carry_a_timestamp() {
        assert_eq!(parse(b"t006101ABCD"), Err(LineError::BadData));
    }

    #[test]
    fn control_commands_parse_and_their_arguments_are_checked() {
        assert_eq!(parse(b"O"), Ok(Command::Open));
        assert_eq!(parse(b"C"), Ok(Command::Close));
        assert_eq!(parse(b"S0"), Ok(Command::SetBitrate(10_000)));
        assert_eq!(parse(b"S6"), Ok(Command::SetBitrate(500_000)));
        assert_eq!(parse(b"S8"), Ok(Command::SetBitrate(1_000_000)));
        assert_eq!(parse(b"S9"), Err(LineError::BadArgument));
        assert_eq!(parse(b"S"), Err(LineError::BadArgument));
        assert_eq!(parse(b"Z1"), Ok(Command::Timestamps(true)));
        assert_eq!(parse(b"Z2"), Err(LineError::BadArgument));
        assert_eq!(parse(b"Ox"), Err(LineError::BadArgument));
        assert_eq!(parse(b"x"), Err(LineError::UnknownCommand(b'x')));
        assert_eq!(parse(b"s4F00"), Err(LineError::UnknownCommand(b's')));
    }

    #[test]
    fn bit_rate_commands_exist_only_for_slcan_rates() {
        assert_eq!(bitrate_command(500_000).as_deref(), Some("S6\r"));
        assert_eq!(bitrate_command(10_000).as_deref(), Some("S0\r"));
        assert_eq!(bitrate_command(1_000_000).as_deref(), Some("S8\r"));
        assert_eq!(bitrate_command(300_000), None);
    }

    #[test]
    fn frames_format_as_the_protocol_writes_them() {
        let position = standard(0x0EC, &[0x2C, 0x01, 0, 0, 0xF6, 0xFF, 0xFF, 0xFF]);
        assert_eq!(format_frame(&position, None), "t0EC82C010000F6FFFFFF\r");
        assert_eq!(format_frame(&standard(0x7FF, &[]), None), "t7FF0\r");
        assert_eq!(
            format_frame(&standard(0x0EB, &[80, 0xB4, 0x5F]), Some(61_234)),
            "t0EB350B45F04D2\r",
            "the timestamp wraps at 60 000 ms"
        );
        let extended = Id::Extended(ExtendedId::new(0x0ABC_DEF0).unwrap());
        let remote = Frame::new_remote(extended, 2).unwrap();
        assert_eq!(format_frame(&remote, None), "R0ABCDEF02\r");
    }

    #[test]
    fn formatted_frames_parse_back_to_themselves() {
        let frame = standard(0x004, &[0, 0x12, 0x34]);
        let line = format_frame(&frame, None);
        let without_cr = line.trim_end_matches('\r').as_bytes();
        assert_eq!(parse(without_cr), Ok(Command::Transmit(frame)));
        assert_eq!(parse_received_frame::<Frame>(without_cr), Ok(frame));
    }

    #[test]
    fn received_frames_parse_with_or_without_a_timestamp() {
        let weight = standard(0x0EA, &[0xD2, 0x04]);
        assert_eq!(parse_received_frame::<Frame>(b"t0EA2D204"), Ok(weight));
        assert_eq!(parse_received_frame::<Frame>(b"t0EA2D20404D2"), Ok(weight));
        assert_eq!(
            parse_received_frame::<Frame>(b"t0EA2D20404"),
            Err(LineError::BadData),
            "a timestamp has four digits"
        );
        assert_eq!(
            parse_received_frame::<Frame>(b"z"),
            Err(LineError::UnknownCommand(b'z'))
        );
    }

    #[test]
    fn lines_end_at_cr_or_lf_and_empty_ones_vanish() {
        let mut assembler = LineAssembler::default();
        assert_eq!(assembler.push(b"\r\r\rS6\rO"), vec![b"S6".to_vec()]);
        assert_eq!(
            assembler.push(b"\r\nt0050\r"),
            vec![b"O".to_vec(), b"t0050".to_vec()]
        );
    }

    #[test]
    fn an_overlong_line_is_refused_as_a_whole() {
        let mut assembler = LineAssembler::default();
        let mut long = b"t0EC8".to_vec();
        long.extend(std::iter::repeat_n(b'0', 200));
        long.push(b'\r');
        let lines = assembler.push(&long);
        assert_eq!(lines.len(), 1);
        assert_eq!(parse(&lines[0]), Err(LineError::BadData));
    }
}
