//! A CAN bus served by socketcand over TCP: the simulator (127.0.0.1:29536 by
//! default) or `socketcand -i can0` on the robot, for a laptop on the network. Any
//! number of programs share the bus this way. `--channel HOST:PORT`, or
//! `HOST:PORT/BUS` for a bus not named can0.

use std::io::{ErrorKind, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use base_core::can::RawFrame;
use embedded_can::{Frame as _, Id};

use super::{Bus, BusError};

/// How long the server may take to answer the handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(3);
/// The bus name when the channel names none.
pub const DEFAULT_BUS: &str = "can0";
/// A message longer than this is no socketcand message.
const MAX_MESSAGE: usize = 256;

pub struct SocketcandBus {
    stream: TcpStream,
    server: String,
    received: Vec<u8>,
}

impl SocketcandBus {
    /// Connects to `HOST:PORT[/BUS]`, opens the bus and switches to raw mode.
    pub fn open(channel: &str) -> Result<Self, BusError> {
        let (server, bus) = match channel.rsplit_once('/') {
            Some((server, bus)) => (server, bus),
            None => (channel, DEFAULT_BUS),
        };
        let io_error = |what: String| {
            move |source| BusError::Io {
                what: what.clone(),
                source,
            }
        };
        let addresses: Vec<_> = server
            .to_socket_addrs()
            .map_err(io_error(format!(
                "{server:?} is not HOST:PORT of a socketcand server"
            )))?
            .collect();
        let mut last_error = std::io::Error::from(ErrorKind::AddrNotAvailable);
        let mut stream = None;
        for address in addresses {
            match TcpStream::connect_timeout(&address, HANDSHAKE_TIMEOUT) {
                Ok(connected) => {
                    stream = Some(connected);
                    break;
                }
                Err(error) => last_error = error,
            }
        }
        let stream = stream.ok_or_else(|| BusError::Io {
            what: format!(
                "cannot connect to socketcand at {server} (is the simulator or socketcand \
                 running?)"
            ),
            source: last_error,
        })?;
        let _ = stream.set_nodelay(true);
        let mut connection = Self {
            stream,
            server: server.to_owned(),
            received: Vec::new(),
        };
        connection.expect("< hi >", "the greeting")?;
        connection.write(&format!("< open {bus} >"))?;
        connection.expect("< ok >", &format!("opening bus {bus}"))?;
        connection.write("< rawmode >")?;
        connection.expect("< ok >", "raw mode")?;
        Ok(connection)
    }

    fn write(&mut self, message: &str) -> Result<(), BusError> {
        self.stream
            .write_all(message.as_bytes())
            .map_err(|source| BusError::Io {
                what: format!("cannot send to socketcand at {}", self.server),
                source,
            })
    }

    fn expect(&mut self, wanted: &str, step: &str) -> Result<(), BusError> {
        let deadline = Instant::now() + HANDSHAKE_TIMEOUT;
        match self.next_message(deadline)? {
            Some(message) if message.split_whitespace().eq(wanted.split_whitespace()) => Ok(()),
            Some(message) => Err(BusError::AdapterRefused {
                command: step.to_owned(),
                hint: format!("socketcand at {} answered {message}", self.server),
            }),
            None => Err(BusError::AdapterSilent {
                command: format!("{step} (socketcand at {})", self.server),
            }),
        }
    }

    /// The next whole `< … >` message, or `None` if none came by `deadline`.
    fn next_message(&mut self, deadline: Instant) -> Result<Option<String>, BusError> {
        loop {
            if let Some(end) = self.received.iter().position(|&byte| byte == b'>') {
                let message: Vec<u8> = self.received.drain(..=end).collect();
                let text = String::from_utf8_lossy(&message);
                let Some(start) = text.find('<') else {
                    continue;
                };
                return Ok(Some(text[start..].to_owned()));
            }
            if self.received.len() > MAX_MESSAGE {
                self.received.clear();
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            self.stream
                .set_read_timeout(Some(remaining))
                .map_err(|source| self.read_error(source))?;
            let mut buffer = [0; 4096];
            match self.stream.read(&mut buffer) {
                Ok(0) => {
                    return Err(BusError::Io {
                        what: format!("socketcand at {} closed the connection", self.server),
                        source: ErrorKind::UnexpectedEof.into(),
                    });
                }
                Ok(count) => self.received.extend_from_slice(&buffer[..count]),
                Err(error)
                    if matches!(
                        error.kind(),
                        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                    ) => {}
                Err(error) => return Err(self.read_error(error)),
            }
        }
    }

    fn read_error(&self, source: std::io::Error) -> BusError {
        BusError::Io {
            what: format!("cannot read from socketcand at {}", self.server),
            source,
        }
    }
}

/// `< frame ID SECS.USECS DATA >` as a frame; `None` for anything else.
pub fn parse_frame(message: &str) -> Option<slcan::Frame> {
    let body = message.strip_prefix('<')?.strip_suffix('>')?;
    let mut words = body.split_whitespace();
    if words.next()? != "frame" {
        return None;
    }
    let id_text = words.next()?;
    let _time = words.next()?;
    let data_text = words.next().unwrap_or("");
    if words.next().is_some() || data_text.len() % 2 != 0 || data_text.len() > 16 {
        return None;
    }
    let number = u32::from_str_radix(id_text, 16).ok()?;
    let id: Id = if id_text.len() == 8 {
        embedded_can::ExtendedId::new(number)?.into()
    } else {
        embedded_can::StandardId::new(u16::try_from(number).ok()?)?.into()
    };
    let data: Option<Vec<u8>> = (0..data_text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&data_text[i..i + 2], 16).ok())
        .collect();
    slcan::Frame::new(id, &data?)
}

/// A frame as a `< send … >` message.
pub fn format_send(frame: &slcan::Frame) -> String {
    let id = match frame.id() {
        Id::Standard(id) => format!("{:03X}", id.as_raw()),
        Id::Extended(id) => format!("{:08X}", id.as_raw()),
    };
    let mut message = format!("< send {id} {:X}", frame.data().len());
    for byte in frame.data() {
        message.push_str(&format!(" {byte:02X}"));
    }
    message.push_str(" >");
    message
}

impl Bus for SocketcandBus {
    fn send(&mut self, frame: &RawFrame) -> Result<(), BusError> {
        let frame = frame
            .to_frame::<slcan::Frame>()
            .expect("a RawFrame has an 11-bit ID and at most 8 bytes");
        self.write(&format_send(&frame))
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<RawFrame>, BusError> {
        let deadline = Instant::now() + timeout;
        while let Some(message) = self.next_message(deadline)? {
            if let Some(frame) = parse_frame(&message)
                && let Some(frame) = RawFrame::from_frame(&frame)
            {
                return Ok(Some(frame));
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_parse_as_socketcand_sends_them() {
        let frame = parse_frame("< frame 0EE 1700000000.000042 248D >").unwrap();
        assert_eq!(frame.standard_id(), Some(0x0EE));
        assert_eq!(frame.data(), [0x24, 0x8D]);
        let empty = parse_frame("< frame 006 3.000000  >").unwrap();
        assert!(empty.data().is_empty());
        assert!(
            parse_frame("< frame 00001234 0.0 01 >")
                .unwrap()
                .is_extended()
        );
        for bad in [
            "< ok >",
            "< frame 800 0.0 01 >",
            "< frame 0EE 0.0 0 >",
            "< frame 0EE 0.0 001122334455667788 >",
            "< frame xyz 0.0 >",
            "< error 0EE 0.0 >",
        ] {
            assert_eq!(parse_frame(bad), None, "{bad}");
        }
    }

    #[test]
    fn sends_are_formatted_as_socketcand_reads_them() {
        let frame = slcan::Frame::standard(0x0C8, &[0x2C, 0x01, 0, 0, 3]).unwrap();
        assert_eq!(format_send(&frame), "< send 0C8 5 2C 01 00 00 03 >");
        let empty = slcan::Frame::standard(0x006, &[]).unwrap();
        assert_eq!(format_send(&empty), "< send 006 0 >");
    }
}
