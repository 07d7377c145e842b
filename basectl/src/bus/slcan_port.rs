//! An SLCAN adapter on a serial tty: a CANable, or the simulator's pseudo-terminal.
//! Opening takes the tty for basectl alone (an advisory lock, as pyserial's
//! `exclusive=True` takes it, and the tty's exclusive mode), puts it in raw mode and
//! runs the adapter's setup (`C`, `S`n, `O`); frames go through the shared `slcan`
//! codec. Closing (also on Ctrl-C, see [`super::exit`]) sends `C` and gives the tty
//! back as it was.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{ErrorKind, Read, Write};
use std::os::fd::{AsFd, AsRawFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::time::{Duration, Instant};

use base_core::can::RawFrame;
use nix::errno::Errno;
use nix::fcntl::{Flock, FlockArg, OFlag};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{SetArg, Termios, cfmakeraw, tcgetattr, tcsetattr};

use super::{Bus, BusError, exit};

nix::ioctl_none_bad!(tty_exclusive, nix::libc::TIOCEXCL);
nix::ioctl_none_bad!(tty_shared, nix::libc::TIOCNXCL);

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
    port: Flock<File>,
    path: String,
    partial: Vec<u8>,
    events: VecDeque<Event>,
    /// Closes the channel and restores the tty, once: on drop or on Ctrl-C.
    closer: exit::Registration,
}

/// Refuses a link the simulator left behind when it was killed: its lock file
/// (`PATH.lock`) is there but no simulator holds it, and `/dev/pts/N` may be someone's
/// terminal by now.
fn refuse_stale_link(path: &str) -> Result<(), BusError> {
    let mut lock_path = Path::new(path).as_os_str().to_owned();
    lock_path.push(".lock");
    let Ok(lock_file) = File::open(&lock_path) else {
        return Ok(());
    };
    match Flock::lock(lock_file, FlockArg::LockSharedNonblock) {
        // Nobody holds it: the simulator that made the link is gone.
        Ok(_) => Err(BusError::StaleLink {
            path: path.to_owned(),
        }),
        Err(_) => Ok(()),
    }
}

impl SlcanPort {
    pub fn open(path: &str, bitrate_bps: u32) -> Result<Self, BusError> {
        let bitrate_command =
            slcan::bitrate_command(bitrate_bps).ok_or(BusError::BadBitrate(bitrate_bps))?;
        let io_error = |source| BusError::Io {
            what: format!("cannot open the SLCAN device {path}"),
            source,
        };
        refuse_stale_link(path)?;
        // Not as the controlling terminal; never block in read or write (another
        // program might take the bytes poll announced).
        let file = File::options()
            .read(true)
            .write(true)
            .custom_flags((OFlag::O_NOCTTY | OFlag::O_NONBLOCK).bits())
            .open(path)
            .map_err(|error| match error.raw_os_error() {
                Some(code) if code == Errno::EBUSY as i32 => BusError::Busy {
                    path: path.to_owned(),
                },
                _ => io_error(error),
            })?;
        let port = match Flock::lock(file, FlockArg::LockExclusiveNonblock) {
            Ok(port) => port,
            Err((_, Errno::EWOULDBLOCK)) => {
                return Err(BusError::Busy {
                    path: path.to_owned(),
                });
            }
            Err((_, errno)) => return Err(io_error(errno.into())),
        };
        // SAFETY: TIOCEXCL takes no argument and acts on the open descriptor only.
        // Refused by a file that is no tty, which the termios call below reports.
        let _ = unsafe { tty_exclusive(port.as_raw_fd()) };
        // Raw mode: no echo, no CR→LF translation, bytes as they come.
        let original = tcgetattr(&*port).map_err(|errno| io_error(errno.into()))?;
        let mut termios = original.clone();
        cfmakeraw(&mut termios);
        tcsetattr(&*port, SetArg::TCSANOW, &termios).map_err(|errno| io_error(errno.into()))?;
        let closer = exit::register(close_action(&port, original).map_err(io_error)?);
        let mut adapter = Self {
            port,
            path: path.to_owned(),
            partial: Vec::new(),
            events: VecDeque::new(),
            closer,
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

    fn write(&mut self, mut bytes: &[u8]) -> Result<(), BusError> {
        let deadline = Instant::now() + SETUP_REPLY_TIMEOUT;
        let error = |path: &str, source| BusError::Io {
            what: format!("cannot write to {path}"),
            source,
        };
        while !bytes.is_empty() {
            match (&*self.port).write(bytes) {
                Ok(count) => bytes = &bytes[count..],
                Err(source) if source.kind() == ErrorKind::Interrupted => {}
                Err(source) if source.kind() == ErrorKind::WouldBlock => {
                    // The adapter takes nothing now: wait until it does, up to a second.
                    let remaining = deadline.saturating_duration_since(Instant::now());
                    if remaining.is_zero() {
                        return Err(error(&self.path, source));
                    }
                    let mut poll_fds = [PollFd::new(self.port.as_fd(), PollFlags::POLLOUT)];
                    let timeout_ms =
                        u16::try_from(remaining.as_millis().max(1)).unwrap_or(u16::MAX);
                    match poll(&mut poll_fds, PollTimeout::from(timeout_ms)) {
                        Ok(_) | Err(Errno::EINTR) => {}
                        Err(errno) => return Err(error(&self.path, errno.into())),
                    }
                }
                Err(source) => return Err(error(&self.path, source)),
            }
        }
        Ok(())
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
            let ready = match poll(&mut poll_fds, PollTimeout::from(timeout_ms)) {
                Ok(ready) => ready,
                Err(Errno::EINTR) => continue,
                Err(errno) => {
                    return Err(BusError::Io {
                        what: format!("cannot wait for {}", self.path),
                        source: errno.into(),
                    });
                }
            };
            if ready == 0 {
                continue;
            }
            let mut buffer = [0; 256];
            let count = match (&*self.port).read(&mut buffer) {
                Ok(count) => count,
                Err(error)
                    if matches!(error.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted) =>
                {
                    continue;
                }
                Err(source) => {
                    return Err(BusError::Io {
                        what: format!("cannot read from {}", self.path),
                        source,
                    });
                }
            };
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

/// What closing the port does, on a descriptor of its own so that it can run from the
/// signal thread: `C` (the adapter leaves the bus), the tty's exclusive mode off, the
/// tty settings as they were.
fn close_action(port: &File, original: Termios) -> std::io::Result<Box<dyn FnOnce() + Send>> {
    let port = port.try_clone()?;
    Ok(Box::new(move || {
        let _ = (&port).write_all(b"C\r");
        let _ = tcsetattr(&port, SetArg::TCSADRAIN, &original);
        // SAFETY: TIOCNXCL takes no argument and acts on the open descriptor only.
        let _ = unsafe { tty_shared(port.as_raw_fd()) };
    }))
}

impl Drop for SlcanPort {
    fn drop(&mut self) {
        self.closer.run();
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
