//! The Lawicel SLCAN ASCII protocol, as a USB-CAN adapter speaks it to the PC: the
//! simulator's serial endpoint parses the PC's command lines with it and formats the
//! frames it heard on the bus. Pure: the serial port and the bus belong to the caller.
//!
//! Lines end in CR; the adapter answers CR for OK and BEL for an error, and sends each
//! received frame as `tIIILDD…` (standard), `TIIIIIIIILDD…` (extended), `rIIIL` /
//! `RIIIIIIIIL` (remote), followed by CR.

use embedded_can::{ExtendedId, Frame, Id, StandardId};

use crate::can::SimFrame;

/// The reply to a command that succeeded.
pub const OK: &[u8] = b"\r";
/// The reply to a command that failed (BEL).
pub const ERROR: &[u8] = b"\x07";
/// `V`: hardware and software version, two digits each.
pub const VERSION_REPLY: &[u8] = b"V0101\r";
/// `v`: the firmware version alone, as CANable-style adapters answer it.
pub const FIRMWARE_VERSION_REPLY: &[u8] = b"v0101\r";
/// `N`: the adapter's serial number, four characters.
pub const SERIAL_NUMBER_REPLY: &[u8] = b"NVBC1\r";

/// The longest line any command has (`T`, 8 ID digits, DLC, 16 data digits) is 26
/// characters; the assembler keeps at most this many, so a longer line stays too long
/// to parse and is refused as a whole.
const MAX_LINE: usize = 64;

/// The bit rates of `S0`…`S8`, in bit/s.
const BITRATES_BPS: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// One command line from the PC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
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
    Transmit(SimFrame),
}

/// Why a line is not a command. Every one is answered with [`ERROR`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineError {
    /// The first character names no command this adapter knows.
    UnknownCommand(u8),
    /// The command's argument is missing, out of range or followed by extra characters.
    BadArgument,
    /// A frame's identifier is not hex of the right width, or too large.
    BadIdentifier,
    /// A frame's length digit is not 0…8.
    BadLength,
    /// A frame's data is not exactly two hex digits per byte of its length.
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

/// Parses one line, without its CR.
pub fn parse_line(line: &[u8]) -> Result<Command, LineError> {
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
        b't' => parse_frame(argument, false, false),
        b'T' => parse_frame(argument, true, false),
        b'r' => parse_frame(argument, false, true),
        b'R' => parse_frame(argument, true, true),
        other => Err(LineError::UnknownCommand(other)),
    }
}

fn parse_frame(text: &[u8], extended: bool, remote: bool) -> Result<Command, LineError> {
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
    let frame = if remote {
        if !data_text.is_empty() {
            return Err(LineError::BadData);
        }
        SimFrame::new_remote(id, dlc)
    } else {
        if data_text.len() != 2 * dlc {
            return Err(LineError::BadData);
        }
        let mut data = [0; 8];
        for (byte, pair) in data.iter_mut().zip(data_text.as_chunks::<2>().0) {
            *byte = u8::try_from(parse_hex(pair).ok_or(LineError::BadData)?)
                .map_err(|_| LineError::BadData)?;
        }
        SimFrame::new(id, &data[..dlc])
    };
    frame.map(Command::Transmit).ok_or(LineError::BadLength)
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

/// A frame as the adapter sends it to the PC, CR included. `timestamp_ms` (the
/// adapter's millisecond counter, which wraps at 60 000) is appended when the PC
/// turned timestamps on with `Z1`.
pub fn format_frame(frame: &SimFrame, timestamp_ms: Option<u16>) -> String {
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

/// Cuts a byte stream from the PC into command lines. CR ends a line, as the protocol
/// says; LF does too, so a person can type commands in a terminal program. Empty lines
/// are dropped: clients send bare CRs to flush a half-sent command.
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

/// What the adapter does with one line: the reply to send back, and a frame to put on
/// the bus if the line was a transmit command that was accepted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    pub reply: &'static [u8],
    pub transmit: Option<SimFrame>,
    /// Why the line was refused, for the simulator's log; `None` when it was accepted.
    pub refusal: Option<Refusal>,
}

/// Why the adapter answered [`ERROR`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    Malformed(LineError),
    /// Sending, or reading the status flags, needs an open channel.
    ChannelClosed,
    /// `O` while open, or `S`/`Z` while open (they only change a closed channel).
    ChannelOpen,
    /// `O` with a bit rate that is not the bus's: a real adapter would see only errors.
    WrongBitrate {
        requested_bps: u32,
        bus_bps: u32,
    },
}

impl core::fmt::Display for Refusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Refusal::Malformed(error) => error.fmt(f),
            Refusal::ChannelClosed => f.write_str("the channel is closed (send O first)"),
            Refusal::ChannelOpen => f.write_str("the channel is open (send C first)"),
            Refusal::WrongBitrate {
                requested_bps,
                bus_bps,
            } => write!(
                f,
                "bit rate {requested_bps} bit/s does not match the bus ({bus_bps} bit/s)"
            ),
        }
    }
}

/// The adapter's channel state: closed or open, its bit rate and timestamp setting.
#[derive(Debug, Clone)]
pub struct Channel {
    bus_bps: u32,
    bitrate_bps: u32,
    open: bool,
    timestamps: bool,
}

impl Channel {
    /// A closed channel on a bus of `bus_bps`; its bit rate is the bus's until the PC
    /// sets one, so `O` alone (as `slcand` without `-s` sends) joins the bus.
    pub fn new(bus_bps: u32) -> Self {
        Self {
            bus_bps,
            bitrate_bps: bus_bps,
            open: false,
            timestamps: false,
        }
    }

    /// Whether frames from the bus go to the PC now.
    pub fn is_open(&self) -> bool {
        self.open
    }

    pub fn timestamps(&self) -> bool {
        self.timestamps
    }

    /// Acts on one line from the PC (without its CR).
    pub fn handle_line(&mut self, line: &[u8]) -> Response {
        let command = match parse_line(line) {
            Ok(command) => command,
            Err(error) => return refuse(Refusal::Malformed(error)),
        };
        let reply = match command {
            Command::Open if self.open => return refuse(Refusal::ChannelOpen),
            Command::Open if self.bitrate_bps != self.bus_bps => {
                return refuse(Refusal::WrongBitrate {
                    requested_bps: self.bitrate_bps,
                    bus_bps: self.bus_bps,
                });
            }
            Command::Open => {
                self.open = true;
                OK
            }
            // Closing a closed channel is fine: clients send `C` first to start from
            // a known state.
            Command::Close => {
                self.open = false;
                OK
            }
            Command::SetBitrate(_) | Command::Timestamps(_) if self.open => {
                return refuse(Refusal::ChannelOpen);
            }
            Command::SetBitrate(bitrate_bps) => {
                self.bitrate_bps = bitrate_bps;
                OK
            }
            Command::Timestamps(on) => {
                self.timestamps = on;
                OK
            }
            Command::Version => VERSION_REPLY,
            Command::FirmwareVersion => FIRMWARE_VERSION_REPLY,
            Command::SerialNumber => SERIAL_NUMBER_REPLY,
            Command::StatusFlags if !self.open => return refuse(Refusal::ChannelClosed),
            // No FIFO ever overflows and the virtual bus has no errors to flag.
            Command::StatusFlags => b"F00\r",
            Command::Transmit(_) if !self.open => return refuse(Refusal::ChannelClosed),
            Command::Transmit(frame) => {
                return Response {
                    reply: if frame.is_extended() { b"Z\r" } else { b"z\r" },
                    transmit: Some(frame),
                    refusal: None,
                };
            }
        };
        Response {
            reply,
            transmit: None,
            refusal: None,
        }
    }
}

fn refuse(refusal: Refusal) -> Response {
    Response {
        reply: ERROR,
        transmit: None,
        refusal: Some(refusal),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn standard(id: u16, data: &[u8]) -> SimFrame {
        SimFrame::standard(id, data).unwrap()
    }

    #[test]
    fn standard_data_frames_parse_in_either_case() {
        assert_eq!(
            parse_line(b"t2E48400000000000000"),
            Err(LineError::BadData),
            "eight bytes need sixteen digits"
        );
        assert_eq!(
            parse_line(b"t2E484000000000000000"),
            Ok(Command::Transmit(standard(
                0x2E4,
                &[0x40, 0, 0, 0, 0, 0, 0, 0]
            )))
        );
        assert_eq!(
            parse_line(b"t0c852c01000003"),
            Ok(Command::Transmit(standard(0x0C8, &[0x2C, 0x01, 0, 0, 3])))
        );
        assert_eq!(
            parse_line(b"t0050"),
            Ok(Command::Transmit(standard(5, &[])))
        );
    }

    #[test]
    fn extended_and_remote_frames_parse() {
        let extended = Id::Extended(ExtendedId::new(0x1234_5678).unwrap());
        assert_eq!(
            parse_line(b"T123456782ABCD"),
            Ok(Command::Transmit(
                SimFrame::new(extended, &[0xAB, 0xCD]).unwrap()
            ))
        );
        let standard_id = Id::Standard(StandardId::new(0x0EC).unwrap());
        assert_eq!(
            parse_line(b"r0EC8"),
            Ok(Command::Transmit(
                SimFrame::new_remote(standard_id, 8).unwrap()
            ))
        );
        assert_eq!(
            parse_line(b"R123456780"),
            Ok(Command::Transmit(
                SimFrame::new_remote(extended, 0).unwrap()
            ))
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
            assert_eq!(parse_line(line), Err(error), "{}", line.escape_ascii());
        }
    }

    #[test]
    fn control_commands_parse_and_their_arguments_are_checked() {
        assert_eq!(parse_line(b"O"), Ok(Command::Open));
        assert_eq!(parse_line(b"C"), Ok(Command::Close));
        assert_eq!(parse_line(b"S0"), Ok(Command::SetBitrate(10_000)));
        assert_eq!(parse_line(b"S6"), Ok(Command::SetBitrate(500_000)));
        assert_eq!(parse_line(b"S8"), Ok(Command::SetBitrate(1_000_000)));
        assert_eq!(parse_line(b"S9"), Err(LineError::BadArgument));
        assert_eq!(parse_line(b"S"), Err(LineError::BadArgument));
        assert_eq!(parse_line(b"Z1"), Ok(Command::Timestamps(true)));
        assert_eq!(parse_line(b"Z2"), Err(LineError::BadArgument));
        assert_eq!(parse_line(b"Ox"), Err(LineError::BadArgument));
        assert_eq!(parse_line(b"x"), Err(LineError::UnknownCommand(b'x')));
        assert_eq!(parse_line(b"s4F00"), Err(LineError::UnknownCommand(b's')));
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
        let remote = SimFrame::new_remote(extended, 2).unwrap();
        assert_eq!(format_frame(&remote, None), "R0ABCDEF02\r");
    }

    #[test]
    fn formatted_frames_parse_back_to_themselves() {
        let frame = standard(0x004, &[0, 0x12, 0x34]);
        let line = format_frame(&frame, None);
        let without_cr = line.trim_end_matches('\r').as_bytes();
        assert_eq!(parse_line(without_cr), Ok(Command::Transmit(frame)));
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
        assert_eq!(parse_line(&lines[0]), Err(LineError::BadData));
    }

    #[test]
    fn a_client_session_opens_sends_and_closes() {
        let mut channel = Channel::new(500_000);
        // python-can: close, bit rate, open, and open again.
        assert_eq!(channel.handle_line(b"C").reply, OK);
        assert_eq!(channel.handle_line(b"S6").reply, OK);
        assert_eq!(channel.handle_line(b"O").reply, OK);
        assert!(channel.is_open());
        let again = channel.handle_line(b"O");
        assert_eq!(again.reply, ERROR);
        assert_eq!(again.refusal, Some(Refusal::ChannelOpen));
        let malformed = channel.handle_line(b"t0061");
        assert_eq!(malformed.reply, ERROR);
        assert_eq!(
            malformed.refusal,
            Some(Refusal::Malformed(LineError::BadData))
        );
        let sent = channel.handle_line(b"t006101");
        assert_eq!(sent.reply, b"z\r");
        assert_eq!(sent.transmit, Some(standard(0x006, &[1])));
        assert_eq!(channel.handle_line(b"T000000060").reply, b"Z\r");
        assert_eq!(channel.handle_line(b"F").reply, b"F00\r");
        assert_eq!(channel.handle_line(b"C").reply, OK);
        assert!(!channel.is_open());
    }

    #[test]
    fn a_closed_channel_refuses_to_send() {
        let mut channel = Channel::new(500_000);
        let response = channel.handle_line(b"t006101");
        assert_eq!(response.reply, ERROR);
        assert_eq!(response.transmit, None);
        assert_eq!(response.refusal, Some(Refusal::ChannelClosed));
        assert_eq!(channel.handle_line(b"F").reply, ERROR);
    }

    #[test]
    fn opening_at_another_bit_rate_than_the_bus_is_refused() {
        let mut channel = Channel::new(500_000);
        assert_eq!(channel.handle_line(b"S5").reply, OK);
        let response = channel.handle_line(b"O");
        assert_eq!(
            response.refusal,
            Some(Refusal::WrongBitrate {
                requested_bps: 250_000,
                bus_bps: 500_000
            })
        );
        assert!(!channel.is_open());
    }

    #[test]
    fn bit_rate_and_timestamps_change_only_while_closed() {
        let mut channel = Channel::new(500_000);
        assert_eq!(channel.handle_line(b"Z1").reply, OK);
        assert!(channel.timestamps());
        channel.handle_line(b"O");
        assert_eq!(channel.handle_line(b"S6").reply, ERROR);
        assert_eq!(channel.handle_line(b"Z0").reply, ERROR);
        assert!(channel.timestamps());
    }

    #[test]
    fn identity_queries_answer_in_the_protocols_format() {
        let mut channel = Channel::new(500_000);
        assert_eq!(channel.handle_line(b"V").reply, VERSION_REPLY);
        assert_eq!(channel.handle_line(b"v").reply, FIRMWARE_VERSION_REPLY);
        assert_eq!(channel.handle_line(b"N").reply, SERIAL_NUMBER_REPLY);
    }
}
