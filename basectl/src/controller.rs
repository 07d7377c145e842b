//! The base controller on the far side of a [`Bus`]: commands that expect an answer
//! (register reads, steps whose refusal shows only in the status frame) and the latest
//! reports seen on the way.

use std::fmt;
use std::time::{Duration, Instant};

use base_core::can::{Command, Report, Status};
use base_core::registers::{Reg, RegisterInfo};

use crate::bus::{Bus, BusError};
use crate::rejection;

/// The status frame comes every `status_time` (1 s by default); allow for one lost.
pub const STATUS_TIMEOUT: Duration = Duration::from_millis(2500);

/// Why a command to the base controller failed.
#[derive(Debug)]
pub enum Error {
    Bus(BusError),
    /// Nothing (or not the expected frame) came back in time.
    NoReply {
        awaited: String,
        timeout_ms: u128,
    },
    /// The base controller counted the frame as rejected (status frame bytes 3–5).
    Refused {
        step: String,
        reason: u8,
        subject: u8,
    },
    /// A register read answered `004#FF addr reason`.
    ReadRefused {
        address: u8,
        reason: u8,
    },
    /// A bad command-line argument or answer, with what is allowed.
    InvalidInput(String),
    /// The person or the terminal could not be talked to.
    Terminal(std::io::Error),
    /// Something went wrong on the robot that stops the step (e.g. it did not move).
    Aborted(String),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Bus(error) => error.fmt(f),
            Error::NoReply {
                awaited,
                timeout_ms,
            } => write!(
                f,
                "no reply from the base controller within {timeout_ms} ms ({awaited}; is it \
                 connected? bit rate?)"
            ),
            Error::Refused {
                step,
                reason,
                subject,
            } => write!(
                f,
                "the base controller refused {step}: {} (subject 0x{subject:02X})",
                rejection::describe(*reason)
            ),
            Error::ReadRefused { address, reason } => write!(
                f,
                "the base controller refused to read register {address}: {}",
                rejection::describe(*reason)
            ),
            Error::InvalidInput(why) => f.write_str(why),
            Error::Terminal(error) => write!(f, "terminal: {error}"),
            Error::Aborted(why) => f.write_str(why),
        }
    }
}

impl std::error::Error for Error {}

impl From<BusError> for Error {
    fn from(error: BusError) -> Self {
        Error::Bus(error)
    }
}

impl From<std::io::Error> for Error {
    fn from(error: std::io::Error) -> Self {
        Error::Terminal(error)
    }
}

/// The latest pose the base reported.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Pose {
    pub x_mm: i32,
    pub y_mm: i32,
    pub heading_mrad: i32,
}

pub struct Controller<'bus> {
    bus: &'bus mut dyn Bus,
    reply_timeout: Duration,
    status: Option<Status>,
    pose: Option<Pose>,
    weight_g: Option<u16>,
}

impl<'bus> Controller<'bus> {
    /// `reply_timeout`: how long a register read may take to be answered.
    pub fn new(bus: &'bus mut dyn Bus, reply_timeout: Duration) -> Self {
        Self {
            bus,
            reply_timeout,
            status: None,
            pose: None,
            weight_g: None,
        }
    }

    pub fn send(&mut self, command: Command) -> Result<(), Error> {
        Ok(self.bus.send(&command.encode())?)
    }

    /// The next report within `timeout`, remembered as the latest of its kind.
    /// Frames that are not reports (other devices, our own requests) are skipped.
    pub fn next_report(&mut self, timeout: Duration) -> Result<Option<Report>, Error> {
        let deadline = Instant::now() + timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let Some(frame) = self.bus.receive(remaining)? else {
                return Ok(None);
            };
            if let Ok(Some(report)) = Report::decode(frame.id(), frame.data()) {
                self.remember(report);
                return Ok(Some(report));
            }
        }
    }

    fn remember(&mut self, report: Report) {
        let pose = self.pose.get_or_insert_default();
        match report {
            Report::Position { x_mm, y_mm } => {
                pose.x_mm = x_mm;
                pose.y_mm = y_mm;
            }
            Report::Heading { heading_mrad } => pose.heading_mrad = heading_mrad,
            Report::Status(status) => self.status = Some(status),
            Report::Weight { grams } => self.weight_g = Some(grams),
            Report::Battery { .. }
            | Report::RegisterValue { .. }
            | Report::RegisterReadError { .. } => {}
        }
    }

    pub fn pose(&self) -> Option<Pose> {
        self.pose
    }

    pub fn status(&self) -> Option<Status> {
        self.status
    }

    /// Waits for the first report `wanted` picks something from.
    pub fn wait_for<T>(
        &mut self,
        awaited: &str,
        timeout: Duration,
        mut wanted: impl FnMut(&Report) -> Option<T>,
    ) -> Result<T, Error> {
        let deadline = Instant::now() + timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            match self.next_report(remaining)? {
                Some(report) => {
                    if let Some(value) = wanted(&report) {
                        return Ok(value);
                    }
                }
                None => {
                    return Err(Error::NoReply {
                        awaited: awaited.to_owned(),
                        timeout_ms: timeout.as_millis(),
                    });
                }
            }
        }
    }

    pub fn next_status(&mut self) -> Result<Status, Error> {
        self.wait_for(
            "a status frame 0x0EE",
            STATUS_TIMEOUT,
            |report| match report {
                Report::Status(status) => Some(*status),
                _ => None,
            },
        )
    }

    pub fn next_weight(&mut self) -> Result<u16, Error> {
        // The weight frame comes every `weight_time` (1 s by default, up to 60 s).
        self.wait_for(
            "a weight frame 0x0EA",
            Duration::from_secs(65),
            |report| match report {
                Report::Weight { grams } => Some(*grams),
                _ => None,
            },
        )
    }

    /// Reads one register. Requests and replies share 0x004 and carry no address, so
    /// the first reply after the request is the answer.
    pub fn read_register(&mut self, address: u8) -> Result<u16, Error> {
        self.send(Command::RegisterRead { address })?;
        let timeout = self.reply_timeout;
        self.wait_for(
            &format!("reading register {address}"),
            timeout,
            |report| match *report {
                Report::RegisterValue { value } => Some(Ok(value)),
                Report::RegisterReadError { address, reason } => {
                    Some(Err(Error::ReadRefused { address, reason }))
                }
                _ => None,
            },
        )?
    }

    /// Sends `command` and proves it was accepted: a register read after it is
    /// answered only once the base controller has handled the command, and the status
    /// frame after that answer counts a rejection of it. `step` names the command in
    /// the error.
    pub fn send_checked(&mut self, command: Command, step: &str) -> Result<(), Error> {
        let before = match self.status {
            Some(status) => status,
            None => self.next_status()?,
        };
        self.send(command)?;
        self.read_register(Reg::RegmapVersion.address())?;
        let after = self.next_status()?;
        if after.rejected_count != before.rejected_count {
            return Err(Error::Refused {
                step: step.to_owned(),
                reason: after.last_rejection,
                subject: after.last_rejection_subject,
            });
        }
        Ok(())
    }

    /// Writes a register and reads it back: a refused write changes nothing and gets
    /// no reply, so the status frame names the reason.
    pub fn write_register(&mut self, register: &RegisterInfo, value: u16) -> Result<(), Error> {
        let step = format!("writing {value} to {}", register.name);
        self.send_checked(
            Command::RegisterWrite {
                address: register.address,
                value,
            },
            &step,
        )
    }

    /// The values of `registers`, in order.
    pub fn read_registers<const N: usize>(
        &mut self,
        registers: [Reg; N],
    ) -> Result<[u16; N], Error> {
        let mut values = [0; N];
        for (value, register) in values.iter_mut().zip(registers) {
            *value = self.read_register(register.address())?;
        }
        Ok(values)
    }
}
