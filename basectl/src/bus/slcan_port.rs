//! An SLCAN adapter on a serial tty: a CANable, or the simulator's pseudo-terminal.
//! Opening puts the tty in raw mode and runs the adapter's setup (`C`, `S`n, `O`);
//! frames go through the shared `slcan` codec.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::time::{Duration, Instant};

use base_core::can::RawFrame;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

use super::{Bus, BusError};

/// How long the adapter may take to answer a setup command.
const SETUP_REPLY_TIMEOUT: Duration = Duration::from_millis(1000);
const BEL: u8 = 0x07;

/// What one piece of the adapter's output means to the PC.
#[derive(Debug, PartialEq, Eq)]
enum Event {
    /// A bare CR: the last command succeeded.
    Ok,
    /// BEL: the last command failed.
    Error,
    /// A non-empty line: a received frame, or a transmit acknowledgement (`z`, `Z`).
    Line(Vec<u8>),
}

pub struct SlcanPort {
    port: File,
    path: String,
    partial: Vec<u8>,
    events: VecDeque<Event>,
}

impl SlcanPort {
    pub fn open(path: &str, bitrate_bps: u32) -> Result<Self, BusError> {
        let bitrate_command =
            slcan::bitrate_command(bitrate_bps).ok_or(BusError::BadBitrate(bitrate_bps))?;
        let io_error = |source| BusError::Io {
            what: format!("cannot open the SLCAN device {path}"),
            source,
        };
        let port = File::options()
            .read(true)
            .write(true)
            .open(path)
            .map_err(io_error)?;
        // Raw mode: no echo, no CR→LF translation, bytes as they come.
        let mut termios = tcgetattr(&port).map_err(|errno| io_error(errno.into()))?;
        cfmakeraw(&mut termios);
        tcsetattr(&port, SetArg::TCSANOW, &termios).map_err(|errno| io_error(errno.into()))?;
        let mut adapter = Self {
            port,
            path: path.to_owned(),
            partial: Vec::new(),
            events: VecDeque::new(),
        };
        // Close first: the channel may still be open from an earlier session, and the
        // bit rate can only change while it is closed.
        adapter.setup("C\r", "")?;
        adapter.setup(&bitrate_command, "")?;
        adapter.setup(
            "O\r",
            &format!("does the bus run at {bitrate_bps} bit/s? see --bitrate"),
        )?;
        Ok(adapter)
    }

    /// Sends one setup command and waits for its OK, skipping frames still arriving
    /// from an open channel.
    fn setup(&mut self, command: &str, refusal_hint: &str) -> Result<(), BusError> {
        self.write(command.as_bytes())?;
        let deadline = Instant::now() + SETUP_REPLY_TIMEOUT;
        loop {
            match self.next_event(deadline)? {
                Some(Event::Ok) => return Ok(()),
                Some(Event::Error) => {
                    return Err(BusError::AdapterRefused {
                        command: command.trim_end().to_owned(),
                        hint: refusal_hint.to_owned(),
                    });
                }
                Some(Event::Line(_)) => {}
                None => {
                    return Err(BusError::AdapterSilent {
                        command: command.trim_end().to_owned(),
                    });
                }
            }
        }
    }

    fn write(&mut self, bytes: &[u8]) -> Result<(), BusError> {
        self.port.write_all(bytes).map_err(|source| BusError::Io {
            what: format!("cannot write to {}", self.path),
            source,
        })
    }

    /// The next event, reading the tty until `deadline`; `None` if none came by then.
    fn next_event(&mut self, deadline: Instant) -> Result<Option<Event>, BusError> {
        loop {
            if let Some(event) = self.events.pop_front() {
                return Ok(Some(event));
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            let timeout_ms = u16::try_from(remaining.as_millis().max(1)).unwrap_or(u16::MAX);
            let mut poll_fds = [PollFd::new(self.port.as_fd(), PollFlags::POLLIN)];
            let ready = poll(&mut poll_fds, PollTimeout::from(timeout_ms)).map_err(|errno| {
                BusError::Io {
                    what: format!("cannot wait for {}", self.path),
                    source: errno.into(),
                }
            })?;
            if ready == 0 {
                continue;
            }
            let mut buffer = [0; 256];
            let count = self.port.read(&mut buffer).map_err(|source| BusError::Io {
                what: format!("cannot read from {}", self.path),
                source,
            })?;
            if count == 0 {
                return Err(BusError::Io {
                    what: format!("{} was closed", self.path),
                    source: std::io::ErrorKind::UnexpectedEof.into(),
                });
            }
            self.split_events(&buffer[..count]);
        }
    }

    fn split_events(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            match byte {
                BEL => self.events.push_back(Event::Error),
                b'\r' | b'\n' if self.partial.is_empty() => self.events.push_back(Event::Ok),
                b'\r' | b'\n' => {
                    let line = std::mem::take(&mut self.partial);
                    self.events.push_back(Event::Line(line));
                }
                other if self.partial.len() < slcan::MAX_LINE => self.partial.push(other),
                // Longer than any valid line: keep it too long to parse.
                _ => {}
            }
        }
    }
}

impl Bus for SlcanPort {
    fn send(&mut self, frame: &RawFrame) -> Result<(), BusError> {
        let line = slcan::format_frame(
            &frame
                .to_frame::<slcan::Frame>()
                .expect("a RawFrame has an 11-bit ID and at most 8 bytes"),
            None,
        );
        self.write(line.as_bytes())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<RawFrame>, BusError> {
        let deadline = Instant::now() + timeout;
        while let Some(event) = self.next_event(deadline)? {
            // Acknowledgements and lines that are no frame say nothing about the bus.
            if let Event::Line(line) = event
                && let Ok(frame) = slcan::parse_received_frame::<slcan::Frame>(&line)
                && let Some(frame) = RawFrame::from_frame(&frame)
            {
                return Ok(Some(frame));
            }
        }
        Ok(None)
    }
}
