//! The adapter's side of the Lawicel SLCAN protocol: the channel state (closed or
//! open, bit rate, timestamps) and the reply to every line the PC sends. The simulator's
//! serial endpoint feeds it lines; the line codec itself is the shared `slcan` crate.
//! Pure: the serial port and the bus belong to the caller.

use ::slcan::{Command, LineError, parse_line};
use embedded_can::Frame;

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
        let command = match parse_line::<SimFrame>(line) {
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
