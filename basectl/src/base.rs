//! The base controller on the far side of a [`Bus`]: commands that expect an answer
//! (register reads, steps whose refusal shows only in the status frame) and the latest
//! reports seen on the way.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::time::{Duration, Instant};

use base_core::can::{BULK_READ_MAX, Command, ReadEcho, Report, Status};
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

/// The first tag of this program: different for each program and each run, so that
/// two programs reading the same register at the same moment use different tags.
fn first_tag() -> u16 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |time| time.subsec_nanos());
    let mixed = nanos ^ std::process::id().wrapping_mul(2_654_435_761);
    // Either half: both change with the time and the process.
    (mixed as u16) ^ ((mixed >> 16) as u16)
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
    /// The tag of the previous register read; each read gets the next one.
    last_tag: u16,
    /// Whether the base controller answers bulk reads: `None` until one was tried.
    bulk_reads: Option<bool>,
}

/// How often a register read is asked, under a new tag each time, before basectl gives
/// up: a reply can be lost when the controller's transmit queue is full because other
/// programs read registers as fast as they can. Each attempt waits a fifth of the
/// reply timeout (a reply normally comes within milliseconds), so a silent controller
/// is reported after three reply timeouts.
const READ_ATTEMPTS: u32 = 15;
const ATTEMPT_SHARE: u32 = 5;

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
            last_tag: first_tag(),
            bulk_reads: None,
        }
    }

    /// The bus itself, for exchanges that are not register reads or reports (the
    /// update's QUERY).
    pub fn bus(&mut self) -> &mut (dyn Bus + 'bus) {
        &mut *self.bus
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
            Report::Battery {
                percent,
                voltage_mv,
            } => self.battery = Some((percent, voltage_mv)),
            Report::PoseTime { .. }
            | Report::MeasuredSpeed { .. }
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

    /// Reads one register. Requests and replies share 0x004 and other programs on the
    /// bus may read registers at the same moment, so each request carries a tag of its
    /// own and only the reply that echoes this address and this tag is taken; every
    /// other reply is someone else's.
    pub fn read_register(&mut self, address: u8) -> Result<u16, Error> {
        self.read_register_within(address, self.reply_timeout)
    }

    fn next_tag(&mut self) -> u16 {
        // 0 is the manual's untagged request: a reply to any untagged read echoes it.
        self.last_tag = match self.last_tag.wrapping_add(1) {
            0 => 1,
            tag => tag,
        };
        self.last_tag
    }

    /// [`Self::read_register`] with its own reply timeout.
    fn read_register_within(&mut self, address: u8, timeout: Duration) -> Result<u16, Error> {
        let mut unaddressed_replies = 0_u32;
        let attempt_timeout = timeout / ATTEMPT_SHARE;
        for _ in 0..READ_ATTEMPTS {
            let tag = self.next_tag();
            self.send(Command::RegisterRead { address, tag })?;
            let ours = ReadEcho { address, tag };
            let awaited = format!("reading register {address}");
            let reply = self.wait_for(&awaited, attempt_timeout, |report| match *report {
                Report::RegisterValue {
                    value,
                    echo: Some(echo),
                } if echo == ours => Some(Ok(value)),
                Report::RegisterReadError {
                    address: refused,
                    reason,
                    tag: Some(refused_tag),
                } if refused == address && refused_tag == tag => {
                    Some(Err(Error::ReadRefused { address, reason }))
                }
                Report::RegisterValue { echo: None, .. }
                | Report::RegisterReadError { tag: None, .. } => {
                    unaddressed_replies += 1;
                    None
                }
                _ => None,
            });
            match reply {
                Ok(answer) => return answer,
                Err(Error::NoReply { .. }) => {}
                Err(error) => return Err(error),
            }
        }
        if unaddressed_replies > 0 {
            return Err(Error::Aborted(format!(
                "register {address}: the base controller answers without saying which read \
                 a reply belongs to (firmware before addressed register replies); basectl \
                 cannot tell its reply from another program's, update the firmware"
            )));
        }
        Err(Error::NoReply {
            awaited: format!("reading register {address}, asked {READ_ATTEMPTS} times"),
            timeout_ms: (attempt_timeout * READ_ATTEMPTS).as_millis(),
        })
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

    /// Writes a register that cannot be read back (the write-only `command`): a
    /// refused write changes nothing and gets no reply, so the status frame names the
    /// reason.
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

    /// Writes a read-write register and reads it back. The controller handles frames
    /// in order, so the read's reply shows the write's effect, and the tagged reply is
    /// ours whatever other programs read meanwhile: the status frame (which a flooded
    /// bus may lose) is needed only to name why a write did not take.
    pub fn write_and_read_back(
        &mut self,
        register: &RegisterInfo,
        value: u16,
    ) -> Result<(), Error> {
        self.send(Command::RegisterWrite {
            address: register.address,
            value,
        })?;
        let now = self.read_register(register.address)?;
        if now == value {
            return Ok(());
        }
        let status = self.next_status()?;
        if status.last_rejection_subject == register.address && status.last_rejection != 0 {
            return Err(Error::Refused {
                step: format!("writing {value} to {}", register.name),
                reason: status.last_rejection,
                subject: status.last_rejection_subject,
            });
        }
        Err(Error::Aborted(format!(
            "{} reads back {now} after writing {value}: another client may have written it",
            register.name
        )))
    }

    /// The values of `addresses`, by address: in bulk reads of up to
    /// [`BULK_READ_MAX`] consecutive addresses (one request, the replies back to back),
    /// or one by one from a controller that does not answer bulk reads (firmware before
    /// them). A refused address is an error, as for [`Self::read_register`].
    pub fn read_many(&mut self, addresses: &[u8]) -> Result<BTreeMap<u8, u16>, Error> {
        let wanted: BTreeSet<u8> = addresses.iter().copied().collect();
        let mut values = BTreeMap::new();
        let mut rest = wanted.iter().copied().peekable();
        while let Some(first) = rest.next() {
            let last_in_reach = first.saturating_add(BULK_READ_MAX - 1);
            let mut last = first;
            while let Some(&address) = rest.peek() {
                if address > last_in_reach {
                    break;
                }
                last = address;
                rest.next();
            }
            for (address, reply) in (first..=last).zip(self.read_range(first, last - first + 1)?) {
                if !wanted.contains(&address) {
                    continue;
                }
                match reply {
                    Ok(value) => values.insert(address, value),
                    Err(reason) => return Err(Error::ReadRefused { address, reason }),
                };
            }
        }
        Ok(values)
    }

    /// Each address of `first .. first + count` read, or the reason the controller
    /// refused it.
    fn read_range(&mut self, first: u8, count: u8) -> Result<Vec<Result<u16, u8>>, Error> {
        if self.bulk_reads == Some(false) {
            return (first..=first + (count - 1))
                .map(|address| match self.read_register(address) {
                    Ok(value) => Ok(Ok(value)),
                    Err(Error::ReadRefused { reason, .. }) => Ok(Err(reason)),
                    Err(error) => Err(error),
                })
                .collect();
        }
        let attempt_timeout = self.reply_timeout / ATTEMPT_SHARE;
        let mut replies: Vec<Option<Result<u16, u8>>> = vec![None; usize::from(count)];
        for _ in 0..READ_ATTEMPTS {
            let tag = self.next_tag();
            self.send(Command::RegisterBulkRead { first, count, tag })?;
            let deadline = Instant::now() + attempt_timeout;
            while replies.iter().any(Option::is_none) {
                let remaining = deadline.saturating_duration_since(Instant::now());
                let Some(report) = self.next_report(remaining)? else {
                    break;
                };
                let (address, reply) = match report {
                    Report::RegisterValue {
                        value,
                        echo: Some(echo),
                    } if echo.tag == tag => (echo.address, Ok(value)),
                    Report::RegisterReadError {
                        address,
                        reason,
                        tag: Some(refused_tag),
                    } if refused_tag == tag => (address, Err(reason)),
                    _ => continue,
                };
                if let Some(slot) = address
                    .checked_sub(first)
                    .and_then(|offset| replies.get_mut(usize::from(offset)))
                {
                    *slot = Some(reply);
                    self.bulk_reads = Some(true);
                }
            }
            if replies.iter().all(Option::is_some) {
                return Ok(replies.into_iter().flatten().collect());
            }
            if self.bulk_reads.is_none() {
                // Not one reply: a controller that predates bulk reads counts the
                // request as an unknown sub-command. If it answers a single read, read
                // one by one from now on.
                match self.read_register(first) {
                    Ok(_) | Err(Error::ReadRefused { .. }) => {}
                    Err(error) => return Err(error),
                }
                self.bulk_reads = Some(false);
                return self.read_range(first, count);
            }
        }
        Err(Error::NoReply {
            awaited: format!(
                "reading registers {first} to {}, asked {READ_ATTEMPTS} times",
                first + (count - 1)
            ),
            timeout_ms: (attempt_timeout * READ_ATTEMPTS).as_millis(),
        })
    }

    /// The values of `registers`, in their order, read as [`Self::read_many`] does.
    pub fn read_registers<const N: usize>(
        &mut self,
        registers: [Reg; N],
    ) -> Result<[u16; N], Error> {
        let values = self.read_many(&registers.map(Reg::address))?;
        Ok(registers.map(|register| values[&register.address()]))
    }
}
