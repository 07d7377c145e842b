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

/// The subjects the status frame names when it refuses `command`: the low byte of its
/// CAN ID, and for a register write the register's address.
fn rejection_subjects(command: &Command) -> Vec<u8> {
    let mut subjects = vec![command.encode().id().to_le_bytes()[0]];
    if let Command::RegisterWrite { address, .. } = command {
        subjects.push(*address);
    }
    subjects
}

/// A pause of 10–80 ms, growing with the attempt and different for each program, so
/// that two programs that asked at the same moment do not ask at the same moment again.
fn backoff(attempt: u32) -> Duration {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |time| time.subsec_nanos());
    let spread = (nanos ^ std::process::id().wrapping_mul(2_654_435_761)) % 40;
    Duration::from_millis(10 + u64::from(attempt.min(4)) * 10 + u64::from(spread))
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

/// The base controller as basectl sees it over the bus: a command and its answer, and
/// the newest reports that passed by meanwhile.
pub struct Base<'bus> {
    bus: &'bus mut dyn Bus,
    reply_timeout: Duration,
    status: Option<Status>,
    pose: Option<Pose>,
    weight_g: Option<u16>,
    battery: Option<(u8, u16)>,
    /// Register reads other programs on the bus asked for that are not answered yet.
    foreign_reads_pending: u32,
    /// Register reads of other programs seen so far (never reset).
    foreign_reads_seen: u64,
    /// When another program last asked for a register.
    last_foreign_read: Option<Instant>,
    /// While our own read waits for its reply, replies are not counted as others'.
    awaiting_own_reply: bool,
}

/// How often a register read is tried again when another program read a register at
/// the same moment (replies carry no address, so whose is which is unknown).
const READ_ATTEMPTS: u32 = 20;

/// While other programs read registers (one did in this time), basectl listens for a
/// moment of its own choosing before it asks, as nodes on a shared medium do.
const FOREIGN_READS_RECENT: Duration = Duration::from_secs(2);

/// The first byte of a register read request on 0x004 (replies start with 00 or FF).
const READ_REQUEST: u8 = 0x01;

impl<'bus> Base<'bus> {
    /// `reply_timeout`: how long a register read may take to be answered.
    pub fn new(bus: &'bus mut dyn Bus, reply_timeout: Duration) -> Self {
        Self {
            bus,
            reply_timeout,
            status: None,
            pose: None,
            weight_g: None,
            battery: None,
            foreign_reads_pending: 0,
            foreign_reads_seen: 0,
            last_foreign_read: None,
            awaiting_own_reply: false,
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
            // Another program on the bus (socketcand, SocketCAN) reads a register: its
            // reply will come on the same ID as ours.
            if frame.id() == base_core::can::id::REGISTER_READ
                && frame.data().first() == Some(&READ_REQUEST)
            {
                self.foreign_reads_pending += 1;
                self.foreign_reads_seen += 1;
                self.last_foreign_read = Some(Instant::now());
                continue;
            }
            if let Ok(Some(report)) = Report::decode(frame.id(), frame.data()) {
                if !self.awaiting_own_reply
                    && matches!(
                        report,
                        Report::RegisterValue { .. } | Report::RegisterReadError { .. }
                    )
                {
                    self.foreign_reads_pending = self.foreign_reads_pending.saturating_sub(1);
                }
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
            Report::Battery {
                percent,
                voltage_mv,
            } => self.battery = Some((percent, voltage_mv)),
            Report::RegisterValue { .. } | Report::RegisterReadError { .. } => {}
        }
    }

    pub fn pose(&self) -> Option<Pose> {
        self.pose
    }

    pub fn status(&self) -> Option<Status> {
        self.status
    }

    /// The latest battery report: percent and mV.
    pub fn battery(&self) -> Option<(u8, u16)> {
        self.battery
    }

    pub fn weight_g(&self) -> Option<u16> {
        self.weight_g
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

    /// Reads one register. Requests and replies share 0x004 and a value reply carries
    /// no address, so the first reply after the request is the answer, provided no
    /// other program on the bus asked at the same moment. basectl sees the others'
    /// requests: it waits until they are answered before it asks, and when another
    /// request crossed its own it cannot tell whose reply came first, so it lets the
    /// replies pass and asks again after a pause of its own.
    pub fn read_register(&mut self, address: u8) -> Result<u16, Error> {
        self.read_register_within(address, self.reply_timeout)
    }

    /// [`Self::read_register`] with its own reply timeout.
    fn read_register_within(&mut self, address: u8, timeout: Duration) -> Result<u16, Error> {
        for attempt in 0..READ_ATTEMPTS {
            self.wait_until_foreign_reads_answered()?;
            let seen_before = self.foreign_reads_seen;
            self.send(Command::RegisterRead { address })?;
            self.awaiting_own_reply = true;
            let reply = self.wait_for(&format!("reading register {address}"), timeout, |report| {
                match *report {
                    Report::RegisterValue { value } => Some(Ok(value)),
                    Report::RegisterReadError {
                        address: refused, ..
                    } if refused != address => None,
                    Report::RegisterReadError { address, reason } => {
                        Some(Err(Error::ReadRefused { address, reason }))
                    }
                    _ => None,
                }
            });
            self.awaiting_own_reply = false;
            let crossed = self.foreign_reads_seen - seen_before;
            if crossed == 0 {
                return reply?;
            }
            // Our reply and theirs are both still to come, or one of them came: as
            // many replies as crossing requests are left either way.
            self.foreign_reads_pending = u32::try_from(crossed).unwrap_or(u32::MAX);
            std::thread::sleep(backoff(attempt));
        }
        Err(Error::Aborted(format!(
            "register {address}: another program on the bus kept reading registers at the \
             same moment {READ_ATTEMPTS} times; try again"
        )))
    }

    /// Lets the replies to other programs' register reads pass (up to one reply
    /// timeout each: a request nobody answers does not block basectl), and while other
    /// programs read registers, also a pause of random length in which none asks.
    fn wait_until_foreign_reads_answered(&mut self) -> Result<(), Error> {
        for _ in 0..READ_ATTEMPTS {
            let deadline = Instant::now() + self.reply_timeout;
            while self.foreign_reads_pending > 0 {
                let remaining = deadline.saturating_duration_since(Instant::now());
                if remaining.is_zero() || self.next_report(remaining)?.is_none() {
                    self.foreign_reads_pending = 0;
                }
            }
            let busy = self
                .last_foreign_read
                .is_some_and(|at| at.elapsed() < FOREIGN_READS_RECENT);
            if !busy {
                return Ok(());
            }
            let quiet_until = Instant::now() + backoff(0) / 3;
            while self.foreign_reads_pending == 0 {
                let remaining = quiet_until.saturating_duration_since(Instant::now());
                if remaining.is_zero() {
                    return Ok(());
                }
                self.next_report(remaining)?;
            }
        }
        Ok(())
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
        let subjects = rejection_subjects(&command);
        self.send(command)?;
        // A command may keep the controller busy (restoring every register writes
        // them all to flash): its barrier may take as long as a status period.
        self.read_register_within(
            Reg::RegmapVersion.address(),
            self.reply_timeout.max(STATUS_TIMEOUT),
        )?;
        let after = self.next_status()?;
        let rejected = after.rejected_count.wrapping_sub(before.rejected_count);
        let ours = subjects.contains(&after.last_rejection_subject);
        match (rejected, ours) {
            (0, _) => Ok(()),
            (_, true) => Err(Error::Refused {
                step: step.to_owned(),
                reason: after.last_rejection,
                subject: after.last_rejection_subject,
            }),
            // Another program's frame was refused, not ours.
            (1, false) => Ok(()),
            (_, false) => Err(Error::Aborted(format!(
                "{step}: frames of another program on the bus were refused at the same \
                 moment ({}), so whether this one was cannot be told; check and try again",
                rejection::describe(after.last_rejection)
            ))),
        }
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
