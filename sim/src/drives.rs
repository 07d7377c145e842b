//! The virtual pair of Oriental Motor BLV R drives on one RS-485 line. They speak the
//! bytes of the BLV R manual on the virtual clock (unicast FC 03h/10h/17h,
//! broadcast, ID share FC 03h/10h/17h) and turn their motors as commanded. The firmware's
//! drive link owns the [`DrivesPort`]; the test keeps the [`DrivesHandle`] to cut power,
//! silence a drive, raise alarms, garble replies and look inside.
//!
//! The slave side is written from the spec, not from `base_core::modbus` (only
//! the CRC routine is shared), so master and sim cannot agree on the same mistake.
//!
//! # The line
//! A byte takes one character time on the wire. A drive takes a request as complete
//! once the line has been idle for C3.5 after its last byte, and starts answering
//! C3.5 + the transmission waiting time after that last byte (Tb2, docs/drives.md). Reply bytes
//! become readable one by one as their stop bits arrive. The line is half duplex: bytes
//! that overlap another transmission are lost to the master, and a request that
//! overlaps a reply reaches the drives garbled.
//!
//! # Assumptions where the spec is silent (inferences, marked \[I\] in the spec)
//! - C3.5 is 3.5 character times at every baud rate (the drives' "auto" setting).
//! - ID share members answer back to back, without a gap, in local-ID order. A member
//!   starts when it has heard the previous member's block, so a silent member 1 also
//!   silences member 2 (which still executes the write part).
//! - The FC 10h share echo comes from local ID 1. A member that cannot execute its part
//!   of a share request stays quiet about it: it records communication error 8Ch (which
//!   the share read list can carry) and ends the reply if it was its turn to answer.
//!   Only local ID 1 answers with an exception, as `GID fc|80h code CRC`.
//! - Only DDO operation type 16 (continuous operation) moves the motor; a trigger with
//!   another type stops it. The acceleration and deceleration rates are in (r/min)/s
//!   (docs/drives.md, the configuration trigger). The trigger reads back as 0 once applied.
//! - An alarm de-excites the motor (the brake stops it) and cancels the running command;
//!   after the reset a new trigger is needed. Power-off clears alarms with the rest of RAM.
//! - Writes of 0 or less to the acceleration or deceleration rate are out of range
//!   (exception 03h), as are share list entries naming an item the sim does not know.
//!   Share list entries of 0 are unused: they read as 0 and ignore writes.
//! - The communication error codes follow Oriental's usual table: 84h for a frame with
//!   a bad CRC, 88h for an unknown function or register, 8Ch for a value out of range.

use core::cell::RefCell;
use core::convert::Infallible;
use core::future::poll_fn;
use core::task::{Poll, Waker};
use std::collections::VecDeque;
use std::rc::Rc;

use base_core::modbus::crc16;
use base_runtime::hw::Rs485;
use embassy_futures::select::select;
use embassy_time::{Duration, Instant, Timer};
use embedded_io_async::{ErrorType, Read, Write};

use crate::runtime::char_time;

/// The items the virtual drives know, by NET-ID (register address = 2 × NET-ID).
pub mod net_id {
    pub const DDO_OPERATION_TYPE: u16 = 45;
    pub const DDO_POSITION: u16 = 46;
    pub const DDO_SPEED: u16 = 47;
    pub const DDO_ACCELERATION: u16 = 48;
    pub const DDO_DECELERATION: u16 = 49;
    pub const DDO_TORQUE_LIMIT: u16 = 50;
    pub const DDO_TRIGGER: u16 = 51;
    pub const DRIVER_INPUT_COMMAND: u16 = 62;
    pub const PRESENT_ALARM: u16 = 64;
    pub const COMMUNICATION_ERROR: u16 = 86;
    pub const DETECTED_POSITION: u16 = 102;
    pub const DETECTED_SPEED: u16 = 103;
    pub const ALARM_RESET: u16 = 192;
    pub const SHARE_GLOBAL_ID: u16 = 1216;
    pub const SHARE_NUMBER: u16 = 1217;
    pub const SHARE_LOCAL_ID: u16 = 1218;
    /// Share read data 0; 1..11 follow.
    pub const SHARE_READ_DATA: u16 = 1224;
    /// Share write data 0; 1..11 follow.
    pub const SHARE_WRITE_DATA: u16 = 1236;
    /// Modbus communication timeout in ms, 0 = off (register 0x138A).
    pub const COMMUNICATION_TIMEOUT: u16 = 2501;
}

/// DDO operation type "continuous operation (speed control)".
pub const CONTINUOUS_OPERATION: u32 = 16;
/// Alarm raised when the communication timeout runs out.
pub const ALARM_COMMUNICATION_TIMEOUT: u8 = 0x85;
/// Detected position counts per motor revolution (0.01° steps).
pub const COUNTS_PER_REVOLUTION: f64 = 36_000.0;
/// Entries in each share list.
pub const SHARE_LIST_LEN: usize = 12;

const COMMUNICATION_ERROR_FRAME: u32 = 0x84;
const COMMUNICATION_ERROR_UNDEFINED: u32 = 0x88;
const COMMUNICATION_ERROR_RANGE: u32 = 0x8C;

const ILLEGAL_FUNCTION: u8 = 0x01;
const ILLEGAL_DATA_ADDRESS: u8 = 0x02;
const ILLEGAL_DATA_VALUE: u8 = 0x03;

const READ_HOLDING: u8 = 0x03;
const WRITE_MULTIPLE: u8 = 0x10;
const READ_WRITE_MULTIPLE: u8 = 0x17;

/// Registers one share member reads or writes at most (12 items of two registers).
const SHARE_REGISTERS_PER_MEMBER: usize = 24;
/// DDO rate and power-on default of the DDO rate fields, (r/min)/s.
const DEFAULT_DDO_RATE: u32 = 1000;
const DEFAULT_TORQUE_LIMIT: u32 = 1000;

/// How a motor is mounted, which decides what "forward" means for its shaft.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mounting {
    /// Positive shaft speed drives the robot forward.
    Forward,
    /// Mirrored (the right wheel): negative shaft speed drives the robot forward.
    Mirrored,
}

impl Mounting {
    /// +1 or −1: forward wheel motion = sign × shaft motion.
    pub fn sign(self) -> f64 {
        match self {
            Mounting::Forward => 1.0,
            Mounting::Mirrored => -1.0,
        }
    }
}

/// One drive on the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlaveConfig {
    /// Modbus slave address (the drive's rotary switch).
    pub address: u8,
    pub mounting: Mounting,
}

/// How the virtual pair is wired and set up.
#[derive(Debug, Clone, PartialEq)]
pub struct DrivesConfig {
    pub baud: u32,
    /// Bits per character: start, 8 data, parity, stop. 11 = 8E1.
    pub bits_per_char: u32,
    /// The drives' transmission waiting time (0x138E), added to C3.5 before a reply.
    pub transmission_wait: Duration,
    /// Time from power-on until a drive answers (the manual asks for ≥ 1 s).
    pub boot_time: Duration,
    /// Whether the last share member appends the 2-byte frame CRC after its check word
    /// (real drives are reported to differ).
    pub share_trailer: bool,
    /// How fast the holding brake stops a de-excited motor, (r/min)/s.
    pub brake_decel_rpm_per_s: f64,
    /// Left (local ID 1 in the spec's examples) and right drive.
    pub slaves: [SlaveConfig; 2],
    /// The share group and lists were saved to the drives' NV memory (with MEXE02):
    /// they survive a power cycle, so a drive that reboots answers the group again
    /// without a new setup. False (the default): they are RAM settings, lost.
    pub share_setup_saved: bool,
    /// Request and reply frames kept for [`DrivesHandle::requests`] and
    /// [`DrivesHandle::replies`]; older ones are dropped.
    pub log_capacity: usize,
}

impl Default for DrivesConfig {
    /// The drives as shipped: 115200 8E1, 3.0 ms transmission waiting time, 1 s boot,
    /// trailer sent, slave 1 left, slave 2 right and mirrored (docs/drives.md).
    fn default() -> Self {
        Self {
            baud: 115_200,
            bits_per_char: 11,
            transmission_wait: Duration::from_micros(3_000),
            boot_time: Duration::from_secs(1),
            share_trailer: true,
            share_setup_saved: false,
            brake_decel_rpm_per_s: 20_000.0,
            slaves: [
                SlaveConfig {
                    address: 1,
                    mounting: Mounting::Forward,
                },
                SlaveConfig {
                    address: 2,
                    mounting: Mounting::Mirrored,
                },
            ],
            log_capacity: 4096,
        }
    }
}

impl DrivesConfig {
    /// The drives as docs/drives.md has them commissioned on the robot: the factory
    /// settings with the transmission waiting time (0x138E) lowered to 0.5 ms.
    pub fn commissioned() -> Self {
        Self {
            transmission_wait: Duration::from_micros(500),
            ..Self::default()
        }
    }

    /// Time one character takes on the line.
    pub fn char_time(&self) -> Duration {
        char_time(self.baud, self.bits_per_char)
    }

    /// C3.5: the idle time that ends a frame.
    pub fn silent_interval(&self) -> Duration {
        Duration::from_micros((self.char_time().as_micros() * 7).div_ceil(2))
    }

    /// From the end of a request's last byte to the start of the reply (Tb2).
    pub fn response_delay(&self) -> Duration {
        self.silent_interval() + self.transmission_wait
    }
}

/// The command a DDO trigger applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DdoCommand {
    pub operation_type: u32,
    /// Motor shaft speed, signed (the drive's own direction).
    pub speed_rpm: i32,
    pub accel_rpm_per_s: i32,
    pub decel_rpm_per_s: i32,
    /// 0.1 %.
    pub torque_limit: u32,
}

/// A drive's ID share settings (RAM, lost at power-off).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ShareSetup {
    pub global_id: u32,
    pub number: u32,
    pub local_id: u32,
    /// NET-IDs behind share read data 0..11.
    pub read_list: [u32; SHARE_LIST_LEN],
    /// NET-IDs behind share write data 0..11.
    pub write_list: [u32; SHARE_LIST_LEN],
}

impl ShareSetup {
    /// Whether the drive takes part in a share group.
    pub fn is_member(&self) -> bool {
        (1..=247).contains(&self.global_id)
            && self.number >= 1
            && (1..=self.number).contains(&self.local_id)
    }
}

/// One drive as a test sees it, at the moment of the snapshot.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveView {
    pub address: u8,
    pub mounting: Mounting,
    pub powered: bool,
    /// Powered, booted and not silenced: the drive hears the line.
    pub listening: bool,
    /// S-ON (driver input command bit 0).
    pub servo_on: bool,
    /// Present alarm, 0 = none.
    pub alarm: u32,
    pub communication_error: u32,
    /// The last command a trigger applied since power-on.
    pub command: Option<DdoCommand>,
    pub share: ShareSetup,
    /// Detected position as the drive reports it (restarts at 0 on power-on).
    pub position_counts: i32,
    /// Shaft speed as the drive sees its shaft, exact (the drive reports it rounded).
    pub speed_rpm: f64,
    /// Shaft revolutions since the simulation started; unaffected by power cycles.
    pub shaft_revolutions: f64,
    /// When a trigger last applied a command, and when one last changed the speed.
    pub last_command_at: Option<Instant>,
    pub last_new_speed_at: Option<Instant>,
    /// Requests this drive executed, and frames it heard that failed their CRC or shape.
    pub requests_handled: usize,
    pub malformed_requests: usize,
}

impl DriveView {
    /// Speed with the mounting applied: positive drives the robot forward.
    pub fn forward_rpm(&self) -> f64 {
        self.mounting.sign() * self.speed_rpm
    }

    /// Revolutions with the mounting applied.
    pub fn forward_revolutions(&self) -> f64 {
        self.mounting.sign() * self.shaft_revolutions
    }
}

/// A frame on the line: its bytes, the start of the first and the end of the last.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameRecord {
    pub started: Instant,
    pub at: Instant,
    pub bytes: Vec<u8>,
}

/// The master's end of the RS-485 line (implements [`Rs485`]).
pub struct DrivesPort {
    bus: Rc<RefCell<Bus>>,
}

/// The test's control over the drives, usable while the firmware owns the port.
#[derive(Clone)]
pub struct DrivesHandle {
    bus: Rc<RefCell<Bus>>,
}

impl DrivesPort {
    /// Both drives, powered on now (they answer after `config.boot_time`).
    pub fn new(config: DrivesConfig) -> (DrivesPort, DrivesHandle) {
        let bus = Rc::new(RefCell::new(Bus::new(config, Instant::now())));
        (DrivesPort { bus: bus.clone() }, DrivesHandle { bus })
    }

    /// Waits until the line state changes by the handle's hand.
    async fn changed(&self) {
        let seen = self.bus.borrow().generation;
        poll_fn(|cx| {
            let mut bus = self.bus.borrow_mut();
            if bus.generation != seen {
                Poll::Ready(())
            } else {
                bus.reader = Some(cx.waker().clone());
                Poll::Pending
            }
        })
        .await
    }
}

impl ErrorType for DrivesPort {
    type Error = Infallible;
}

impl Read for DrivesPort {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            let next_event = {
                let mut bus = self.bus.borrow_mut();
                let now = Instant::now();
                bus.advance(now);
                let received = bus.take_arrived(buf, now);
                if received > 0 {
                    return Ok(received);
                }
                bus.next_event()
            };
            match next_event {
                Some(at) => {
                    select(Timer::at(at), self.changed()).await;
                }
                None => self.changed().await,
            }
        }
    }
}

impl Write for DrivesPort {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        let mut bus = self.bus.borrow_mut();
        let now = Instant::now();
        bus.advance(now);
        bus.transmit(buf, now);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Infallible> {
        let sent = self.bus.borrow().master_tx_free;
        Timer::at(sent).await;
        Ok(())
    }
}

impl Rs485 for DrivesPort {}

impl DrivesHandle {
    /// Another master end of the same line: a rebooted controller's port.
    pub fn port(&self) -> DrivesPort {
        DrivesPort {
            bus: self.bus.clone(),
        }
    }

    /// Switches both drives' power. Off loses all RAM settings (share group and lists,
    /// DDO fields, S-ON, alarms), silences the drives and applies the brakes; on starts
    /// the position counters at 0 and answering after the boot time.
    pub fn power(&self, on: bool) {
        self.change(|bus, now| bus.power(on, now));
    }

    /// A brown-out of one drive: off and on again at once. It loses its RAM (see
    /// [`Self::power`]), its counter restarts at 0, and it answers after the boot time.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn power_cycle(&self, slave: u8) {
        self.change(|bus, now| {
            let index = bus.index_of(slave);
            let config = bus.config.clone();
            bus.drives[index].power_off(now, &config);
            bus.cut_replies(|from| from == index, now);
            bus.drives[index].power_on(now);
        });
    }

    /// Cuts one drive from the line (or reconnects it): a silent drive neither hears
    /// nor answers, and keeps running its last command.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn set_silent(&self, slave: u8, silent: bool) {
        self.change(|bus, now| {
            let index = bus.index_of(slave);
            bus.drives[index].silent = silent;
            if silent {
                bus.cut_replies(|from| from == index, now);
            }
        });
    }

    /// Raises an alarm (e.g. 0x30 overload) on a powered drive: the motor stops until
    /// the alarm reset (write 1 to 0x0180) and a new command.
    ///
    /// # Panics
    /// If no drive has the address `slave`, or it has no power.
    pub fn raise_alarm(&self, slave: u8, code: u8) {
        self.change(|bus, _| {
            let drive = &mut bus.drives[bus.index_of(slave)];
            assert!(drive.powered_since.is_some(), "drive {slave} has no power");
            drive.raise_alarm(u32::from(code));
        });
    }

    /// A marginal line: from now on every request frame longer than `max_len` bytes
    /// reaches the drives garbled (long frames fail first); `None` heals the line.
    pub fn fail_requests_longer_than(&self, max_len: Option<usize>) {
        self.change(|bus, _| bus.fail_longer_than = max_len);
    }

    /// Corrupts one byte of each of the next `replies` replies (as line noise would).
    pub fn garble_next_replies(&self, replies: usize) {
        self.change(|bus, _| bus.garble_replies = replies);
    }

    /// A snapshot of one drive now.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn drive(&self, slave: u8) -> DriveView {
        let mut bus = self.bus.borrow_mut();
        let now = Instant::now();
        bus.advance(now);
        let index = bus.index_of(slave);
        bus.drives[index].view(now, &bus.config)
    }

    /// The request frames seen on the line, oldest first (at most `log_capacity`).
    pub fn requests(&self) -> Vec<FrameRecord> {
        let mut bus = self.bus.borrow_mut();
        bus.advance(Instant::now());
        bus.log.iter().cloned().collect()
    }

    /// The replies the drives put on the line, oldest first (at most `log_capacity`),
    /// each logged whole when it starts: one that power-off or silencing cuts short, or
    /// that collides with a request, is logged as the drives meant to send it.
    pub fn replies(&self) -> Vec<FrameRecord> {
        let mut bus = self.bus.borrow_mut();
        bus.advance(Instant::now());
        bus.reply_log.iter().cloned().collect()
    }

    /// Request frames seen on the line since the start, including dropped log entries.
    pub fn request_count(&self) -> usize {
        let mut bus = self.bus.borrow_mut();
        bus.advance(Instant::now());
        bus.request_count
    }

    /// Request frames that overlapped a reply on the line.
    pub fn collisions(&self) -> usize {
        let mut bus = self.bus.borrow_mut();
        bus.advance(Instant::now());
        bus.collisions
    }

    /// Brings the line up to now, applies `change`, and wakes a waiting reader.
    fn change(&self, change: impl FnOnce(&mut Bus, Instant)) {
        let mut bus = self.bus.borrow_mut();
        let now = Instant::now();
        bus.advance(now);
        change(&mut bus, now);
        let config = bus.config.clone();
        for drive in &mut bus.drives {
            drive.note_order(now, &config);
        }
        bus.generation += 1;
        if let Some(reader) = bus.reader.take() {
            reader.wake();
        }
    }
}

// ---------------------------------------------------------------------------------------
// Line and reply faults: the controller's receive path dead, one drive's replies
// garbled, a drive that answers "busy" to everything
// ---------------------------------------------------------------------------------------

impl DrivesHandle {
    /// The master's receive path dies (or heals): every reply is lost on its way to
    /// the master, while the drives still hear and execute every request.
    pub fn lose_replies(&self, lost: bool) {
        self.change(|bus, _| bus.replies_lost = lost);
    }

    /// Every reply byte this drive sends reaches the master garbled (or, with `false`,
    /// clean again); its requests still arrive intact.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn garble_replies_of(&self, slave: u8, garbled: bool) {
        self.change(|bus, _| {
            let index = bus.index_of(slave);
            bus.garbled_from[index] = garbled;
        });
    }

    /// The drive answers every request addressed to it (alone or as a share member)
    /// with exception 06h (slave device busy) and executes nothing, broadcasts
    /// included; it still hears the line, so valid frames keep its communication
    /// timeout from tripping.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn set_busy(&self, slave: u8, busy: bool) {
        self.change(|bus, _| {
            let index = bus.index_of(slave);
            bus.drives[index].busy = busy;
        });
    }
}

/// Exception code of a drive that is busy.
const SLAVE_DEVICE_BUSY: u8 = 0x06;

/// A byte on the wire, with the end of its stop bit.
#[derive(Debug, Clone, Copy)]
struct WireByte {
    byte: u8,
    end: Instant,
    /// Another transmission overlapped it.
    collided: bool,
}

/// A reply byte on its way to the master, and the drive that sends it.
#[derive(Debug, Clone, Copy)]
struct ReplyByte {
    wire: WireByte,
    from: usize,
}

struct Bus {
    config: DrivesConfig,
    drives: [Drive; 2],
    /// The master's frame in progress (not yet ended by C3.5 of silence).
    incoming: Vec<WireByte>,
    master_tx_free: Instant,
    /// Reply bytes not yet read, by arrival.
    replies: VecDeque<ReplyByte>,
    garble_replies: usize,
    fail_longer_than: Option<usize>,
    /// Line and reply faults (see the section above).
    replies_lost: bool,
    garbled_from: [bool; 2],
    log: VecDeque<FrameRecord>,
    reply_log: VecDeque<FrameRecord>,
    request_count: usize,
    collisions: usize,
    /// Bumped by every handle change, so a waiting reader looks again.
    generation: u64,
    reader: Option<Waker>,
}

/// The bytes of a reply, in order, each part with the drive that sends it.
type Reply = Vec<(usize, Vec<u8>)>;

impl Bus {
    fn new(config: DrivesConfig, now: Instant) -> Self {
        let drives = config.slaves.map(|slave| Drive::new(slave, now));
        Self {
            config,
            drives,
            incoming: Vec::new(),
            master_tx_free: now,
            replies: VecDeque::new(),
            garble_replies: 0,
            fail_longer_than: None,
            replies_lost: false,
            garbled_from: [false; 2],
            log: VecDeque::new(),
            reply_log: VecDeque::new(),
            request_count: 0,
            collisions: 0,
            generation: 0,
            reader: None,
        }
    }

    fn index_of(&self, slave: u8) -> usize {
        self.drives
            .iter()
            .position(|drive| drive.config.address == slave)
            .unwrap_or_else(|| panic!("no virtual drive has address {slave}"))
    }

    /// Processes a request whose C3.5 has passed, then brings every motor up to `now`.
    fn advance(&mut self, now: Instant) {
        if let Some(last) = self.incoming.last() {
            let complete_at = last.end + self.config.silent_interval();
            if complete_at <= now {
                let frame = core::mem::take(&mut self.incoming);
                self.process(&frame, complete_at);
            }
        }
        for drive in &mut self.drives {
            drive.advance_to(now, &self.config);
        }
    }

    /// When something may next become readable.
    fn next_event(&self) -> Option<Instant> {
        let reply = self.replies.front().map(|reply| reply.wire.end);
        let request = self
            .incoming
            .last()
            .map(|last| last.end + self.config.silent_interval());
        reply.into_iter().chain(request).min()
    }

    fn take_arrived(&mut self, buf: &mut [u8], now: Instant) -> usize {
        let mut count = 0;
        while count < buf.len() {
            match self.replies.front() {
                Some(reply) if reply.wire.end <= now => {
                    let wire = reply.wire;
                    self.replies.pop_front();
                    buf[count] = if wire.collided { !wire.byte } else { wire.byte };
                    count += 1;
                }
                _ => break,
            }
        }
        count
    }

    fn transmit(&mut self, bytes: &[u8], now: Instant) {
        let char_time = self.config.char_time();
        let mut start = self.master_tx_free.max(now);
        for &byte in bytes {
            let end = start + char_time;
            // The master's receiver is off while it transmits: overlapping reply bytes
            // are lost to it, and the drives hear the request garbled.
            let before = self.replies.len();
            self.replies
                .retain(|reply| reply.wire.end <= start || reply.wire.end - char_time >= end);
            let collided = self.replies.len() != before;
            self.incoming.push(WireByte {
                byte,
                end,
                collided,
            });
            start = end;
        }
        self.master_tx_free = start;
    }

    fn power(&mut self, on: bool, now: Instant) {
        for drive in &mut self.drives {
            if on {
                drive.power_on(now);
            } else {
                drive.power_off(now, &self.config);
            }
        }
        if !on {
            self.cut_replies(|_| true, now);
        }
    }

    /// Removes the reply bytes of the chosen drives that have not arrived by `now`.
    fn cut_replies(&mut self, from: impl Fn(usize) -> bool, now: Instant) {
        self.replies
            .retain(|reply| reply.wire.end <= now || !from(reply.from));
    }

    /// Executes a complete request frame, then logs what it changed in the motors'
    /// orders.
    fn process(&mut self, frame: &[WireByte], at: Instant) {
        self.execute_frame(frame, at);
        for drive in &mut self.drives {
            drive.note_order(at, &self.config);
        }
    }

    fn execute_frame(&mut self, frame: &[WireByte], at: Instant) {
        let bytes: Vec<u8> = frame.iter().map(|wire| wire.byte).collect();
        let char_time = self.config.char_time();
        let started = frame.first().map_or(at, |first| first.end - char_time);
        let ended = frame.last().map_or(at, |last| last.end);
        self.request_count += 1;
        let request = FrameRecord {
            started,
            at: ended,
            bytes: bytes.clone(),
        };
        push_bounded(&mut self.log, request, self.config.log_capacity);
        for drive in &mut self.drives {
            drive.advance_to(at, &self.config);
        }
        let listeners: Vec<usize> = (0..self.drives.len())
            .filter(|&index| self.drives[index].listening(at, &self.config))
            .collect();
        let collided = frame.iter().any(|wire| wire.collided);
        if collided {
            self.collisions += 1;
        }
        let too_long = self.fail_longer_than.is_some_and(|max| bytes.len() > max);
        let Some((address, pdu)) = valid_frame(&bytes).filter(|_| !collided && !too_long) else {
            // Nobody can trust the address of a broken frame: every listener counts it.
            for &index in &listeners {
                self.drives[index].malformed();
            }
            return;
        };
        // Valid frames to anyone count as traffic for the communication timeout.
        for &index in &listeners {
            self.drives[index].last_traffic = at;
        }
        let own = listeners
            .iter()
            .copied()
            .find(|&index| self.drives[index].config.address == address);
        let request = match parse_request(pdu) {
            Ok(request) => Ok(request),
            Err(Refusal::Exception(code)) => Err(code),
            Err(Refusal::Malformed) => {
                let addressees = match own {
                    Some(index) => vec![index],
                    None if address == 0 => listeners,
                    None => self.share_members(address, &listeners),
                };
                for index in addressees {
                    self.drives[index].malformed();
                }
                return;
            }
        };
        let reply = match (address, own) {
            (0, _) => {
                if let Ok(request) = &request {
                    self.broadcast(request, &listeners, at);
                }
                None
            }
            (_, Some(index)) => Some(self.unicast(index, address, pdu, request, at)),
            (_, None) => self.share(address, pdu[0], request, &listeners, at),
        };
        if let Some(reply) = reply {
            self.send(reply, at);
        }
    }

    fn broadcast(&mut self, request: &Request, listeners: &[usize], at: Instant) {
        // Only writes make sense to every slave at once; nobody answers.
        if let Request::Write { start, words, .. } = request {
            for &index in listeners {
                let drive = &mut self.drives[index];
                if drive.busy {
                    continue;
                }
                drive.requests_handled += 1;
                if let Err(code) = drive.write_registers(*start, words, unicast_item, at) {
                    drive.note_exception(code);
                }
            }
        }
    }

    fn unicast(
        &mut self,
        index: usize,
        address: u8,
        pdu: &[u8],
        request: Result<Request, u8>,
        at: Instant,
    ) -> Reply {
        let drive = &mut self.drives[index];
        drive.requests_handled += 1;
        let function = pdu[0];
        let result = if drive.busy {
            Err(SLAVE_DEVICE_BUSY)
        } else {
            request.and_then(|request| drive.execute(&request, unicast_item, unicast_item, at))
        };
        let bytes = match result {
            Ok(Some(words)) => read_reply(address, function, &words),
            Ok(None) => {
                // The write echo: address, function, start and count.
                let mut echo = vec![address];
                echo.extend_from_slice(&pdu[..5]);
                with_crc(echo)
            }
            Err(code) => {
                drive.note_exception(code);
                exception_reply(address, function, code)
            }
        };
        vec![(index, bytes)]
    }

    /// Listeners that are members of the share group at `address`, by local ID.
    fn share_members(&self, address: u8, listeners: &[usize]) -> Vec<usize> {
        let mut members: Vec<usize> = listeners
            .iter()
            .copied()
            .filter(|&index| {
                let share = &self.drives[index].share;
                share.is_member() && share.global_id == u32::from(address)
            })
            .collect();
        members.sort_unstable_by_key(|&index| self.drives[index].share.local_id);
        members
    }

    /// An ID-share request: every member executes its part, then they answer in turn.
    /// No member (or no set-up group at this address): no reply.
    fn share(
        &mut self,
        address: u8,
        function: u8,
        request: Result<Request, u8>,
        listeners: &[usize],
        at: Instant,
    ) -> Option<Reply> {
        let members = self.share_members(address, listeners);
        let mut answers = Vec::new();
        for index in members {
            let drive = &mut self.drives[index];
            drive.requests_handled += 1;
            let answer = match &request {
                _ if drive.busy => Err(SLAVE_DEVICE_BUSY),
                Ok(request) => drive.execute_share(request, at),
                Err(code) => Err(*code),
            };
            if let Err(code) = answer {
                drive.note_exception(code);
            }
            answers.push((drive.share.local_id, index, answer));
        }
        let answer_of = |local_id: u32| {
            answers
                .iter()
                .find(|(id, _, _)| *id == local_id)
                .map(|(_, index, answer)| (*index, answer))
        };

        let (first, first_answer) = answer_of(1)?;
        let request = match (&request, first_answer) {
            (Ok(request), Ok(_)) => request,
            (Err(code), _) | (_, Err(code)) => {
                return Some(vec![(first, exception_reply(address, function, *code))]);
            }
        };
        let mut line = match request {
            Request::Write { start, count, .. } => {
                let mut echo = vec![address, function];
                echo.extend_from_slice(&start.to_be_bytes());
                echo.extend_from_slice(&count.to_be_bytes());
                return Some(vec![(first, with_crc(echo))]);
            }
            Request::Read { count, .. }
            | Request::ReadWrite {
                read_count: count, ..
            } => {
                // The byte count covers the whole group: twice the query's count.
                vec![address, function, (2 * count) as u8]
            }
        };

        // Member 1 sends the header with its block; each later member starts once it has
        // heard the previous one, so the first gap ends the reply.
        let mut reply: Reply = Vec::new();
        let mut block_start = 0;
        for local_id in 1.. {
            let Some((index, Ok(Some(words)))) = answer_of(local_id) else {
                break;
            };
            for word in words {
                line.extend_from_slice(&word.to_be_bytes());
            }
            // The check word covers everything on the line since the group address.
            let check = crc16(&line);
            line.extend_from_slice(&check.to_le_bytes());
            let last = local_id >= self.drives[index].share.number;
            if last && self.config.share_trailer {
                let trailer = crc16(&line);
                line.extend_from_slice(&trailer.to_le_bytes());
            }
            reply.push((index, line[block_start..].to_vec()));
            block_start = line.len();
            if last {
                break;
            }
        }
        Some(reply)
    }

    /// Puts the reply on the line, starting one response delay after the request ended.
    fn send(&mut self, reply: Reply, processed_at: Instant) {
        let char_time = self.config.char_time();
        let mut bytes: Vec<(usize, u8)> = reply
            .into_iter()
            .flat_map(|(from, bytes)| bytes.into_iter().map(move |byte| (from, byte)))
            .collect();
        if bytes.is_empty() {
            return;
        }
        if self.garble_replies > 0 {
            self.garble_replies -= 1;
            let middle = bytes.len() / 2;
            bytes[middle].1 ^= 0xFF;
        }
        for (from, byte) in &mut bytes {
            if self.garbled_from[*from] {
                *byte ^= 0x5A;
            }
        }
        // `processed_at` is already C3.5 after the request; the waiting time follows.
        let start = processed_at + self.config.transmission_wait;
        // Two drives talking at once (only if the master asked during a reply): the
        // overlapping bytes of both reach the master garbled.
        let busy_until = self.replies.back().map(|pending| pending.wire.end);
        for pending in &mut self.replies {
            pending.wire.collided |= pending.wire.end > start;
        }
        let reply = FrameRecord {
            started: start,
            at: start + char_time * bytes.len() as u32,
            bytes: bytes.iter().map(|&(_, byte)| byte).collect(),
        };
        push_bounded(&mut self.reply_log, reply, self.config.log_capacity);
        if self.replies_lost {
            return;
        }
        let mut end = start;
        for (from, byte) in bytes {
            end += char_time;
            self.replies.push_back(ReplyByte {
                wire: WireByte {
                    byte,
                    end,
                    collided: busy_until.is_some_and(|busy| end - char_time < busy),
                },
                from,
            });
        }
        if busy_until.is_some_and(|busy| busy > start) {
            self.replies
                .make_contiguous()
                .sort_by_key(|reply| reply.wire.end);
        }
    }
}

/// Appends `record`, dropping the oldest once the log holds `capacity`.
fn push_bounded(log: &mut VecDeque<FrameRecord>, record: FrameRecord, capacity: usize) {
    if capacity == 0 {
        return;
    }
    if log.len() >= capacity {
        log.pop_front();
    }
    log.push_back(record);
}

/// The address and PDU (function code and data) of a frame whose CRC is right.
fn valid_frame(bytes: &[u8]) -> Option<(u8, &[u8])> {
    let (body, crc) = bytes.split_last_chunk::<2>()?;
    let (&address, pdu) = body.split_first()?;
    (!pdu.is_empty() && crc16(body) == u16::from_le_bytes(*crc)).then_some((address, pdu))
}

fn with_crc(mut frame: Vec<u8>) -> Vec<u8> {
    let crc = crc16(&frame);
    frame.extend_from_slice(&crc.to_le_bytes());
    frame
}

fn read_reply(address: u8, function: u8, words: &[u16]) -> Vec<u8> {
    let mut frame = vec![address, function, (2 * words.len()) as u8];
    for word in words {
        frame.extend_from_slice(&word.to_be_bytes());
    }
    with_crc(frame)
}

fn exception_reply(address: u8, function: u8, code: u8) -> Vec<u8> {
    with_crc(vec![address, function | 0x80, code])
}

/// What a request asks, with the written data as register words.
enum Request {
    Read {
        start: u16,
        count: u16,
    },
    Write {
        start: u16,
        count: u16,
        words: Vec<u16>,
    },
    ReadWrite {
        read_start: u16,
        read_count: u16,
        write_start: u16,
        words: Vec<u16>,
    },
}

enum Refusal {
    /// The frame's length does not fit its function: a real slave stays quiet.
    Malformed,
    /// A well-formed request the slave refuses with this exception code.
    Exception(u8),
}

fn word_at(pdu: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([pdu[at], pdu[at + 1]])
}

fn words_of(data: &[u8]) -> Vec<u16> {
    data.as_chunks::<2>()
        .0
        .iter()
        .map(|pair| u16::from_be_bytes(*pair))
        .collect()
}

/// Parses a request PDU (function code and data, CRC already checked).
fn parse_request(pdu: &[u8]) -> Result<Request, Refusal> {
    let in_range = |count: u16, max: u16| (1..=max).contains(&count);
    match pdu[0] {
        READ_HOLDING => {
            if pdu.len() != 5 {
                return Err(Refusal::Malformed);
            }
            let (start, count) = (word_at(pdu, 1), word_at(pdu, 3));
            if !in_range(count, 125) {
                return Err(Refusal::Exception(ILLEGAL_DATA_VALUE));
            }
            Ok(Request::Read { start, count })
        }
        WRITE_MULTIPLE => {
            let Some(&byte_count) = pdu.get(5) else {
                return Err(Refusal::Malformed);
            };
            if pdu.len() != 6 + usize::from(byte_count) {
                return Err(Refusal::Malformed);
            }
            let (start, count) = (word_at(pdu, 1), word_at(pdu, 3));
            if !in_range(count, 123) || usize::from(byte_count) != 2 * usize::from(count) {
                return Err(Refusal::Exception(ILLEGAL_DATA_VALUE));
            }
            Ok(Request::Write {
                start,
                count,
                words: words_of(&pdu[6..]),
            })
        }
        READ_WRITE_MULTIPLE => {
            let Some(&byte_count) = pdu.get(9) else {
                return Err(Refusal::Malformed);
            };
            if pdu.len() != 10 + usize::from(byte_count) {
                return Err(Refusal::Malformed);
            }
            let (read_start, read_count) = (word_at(pdu, 1), word_at(pdu, 3));
            let (write_start, write_count) = (word_at(pdu, 5), word_at(pdu, 7));
            if !in_range(read_count, 125)
                || !in_range(write_count, 121)
                || usize::from(byte_count) != 2 * usize::from(write_count)
            {
                return Err(Refusal::Exception(ILLEGAL_DATA_VALUE));
            }
            Ok(Request::ReadWrite {
                read_start,
                read_count,
                write_start,
                words: words_of(&pdu[10..]),
            })
        }
        _ => Err(Refusal::Exception(ILLEGAL_FUNCTION)),
    }
}

/// Unicast register pairs map straight to NET-IDs.
fn unicast_item(pair: u32) -> Option<u16> {
    u16::try_from(pair).ok()
}

/// The part of the drive that RAM holds; all of it is lost at power-off.
#[derive(Debug, Clone)]
struct Ram {
    operation_type: u32,
    position: u32,
    speed: u32,
    acceleration: u32,
    deceleration: u32,
    torque_limit: u32,
    input_command: u32,
    alarm_reset: u32,
    communication_timeout_ms: u32,
}

impl Default for Ram {
    fn default() -> Self {
        Self {
            operation_type: 0,
            position: 0,
            speed: 0,
            acceleration: DEFAULT_DDO_RATE,
            deceleration: DEFAULT_DDO_RATE,
            torque_limit: DEFAULT_TORQUE_LIMIT,
            input_command: 0,
            alarm_reset: 0,
            communication_timeout_ms: 0,
        }
    }
}

/// Where the motor is heading and how fast it may change speed, (r/min)/s.
struct Regime {
    target_rpm: f64,
    accel: f64,
    decel: f64,
}

/// The motor shaft, integrated exactly between events: between two events the
/// acceleration is piecewise constant.
#[derive(Debug, Clone)]
struct Motor {
    speed_rpm: f64,
    /// Shaft position since the simulation started, in counts.
    position_counts: f64,
    at: Instant,
}

/// Counts per second at 1 r/min.
const COUNTS_PER_RPM_SECOND: f64 = COUNTS_PER_REVOLUTION / 60.0;

impl Motor {
    fn advance(&mut self, to: Instant, regime: &Regime) {
        let mut remaining = to.saturating_duration_since(self.at).as_micros() as f64 / 1e6;
        self.at = self.at.max(to);
        while remaining > 0.0 {
            let speed = self.speed_rpm;
            let target = regime.target_rpm;
            let same_direction = speed * target > 0.0;
            // Slowing down (towards zero, or through it) uses the deceleration rate.
            let slowing = speed != 0.0 && !(same_direction && target.abs() >= speed.abs());
            let (goal, rate) = match (slowing, same_direction) {
                (true, true) => (target, regime.decel),
                (true, false) => (0.0, regime.decel),
                (false, _) => (target, regime.accel),
            };
            if speed == goal || rate <= 0.0 {
                self.position_counts += COUNTS_PER_RPM_SECOND * speed * remaining;
                return;
            }
            let acceleration = rate.copysign(goal - speed);
            let to_goal = (goal - speed) / acceleration;
            let step = to_goal.min(remaining);
            self.position_counts +=
                COUNTS_PER_RPM_SECOND * (speed * step + 0.5 * acceleration * step * step);
            self.speed_rpm = if step == to_goal {
                goal
            } else {
                speed + acceleration * step
            };
            remaining -= step;
        }
    }
}

#[derive(Debug, Clone)]
struct Drive {
    config: SlaveConfig,
    ram: Ram,
    share: ShareSetup,
    motor: Motor,
    alarm: u32,
    communication_error: u32,
    /// The command running now (cleared by alarms and power-off).
    running: Option<DdoCommand>,
    last_command: Option<DdoCommand>,
    last_command_at: Option<Instant>,
    last_new_speed_at: Option<Instant>,
    powered_since: Option<Instant>,
    /// Where the position counter started (power-on).
    counter_origin: f64,
    silent: bool,
    /// Answers exception 06h to everything and executes nothing (a line fault).
    busy: bool,
    last_traffic: Instant,
    requests_handled: usize,
    malformed_requests: usize,
    /// What its feedback lies about, if anything (see "Encoder faults" below).
    feedback_lie: Option<FeedbackLie>,
    /// Its direction parameter differs from the others' (see "A reversed drive" below).
    reversal: Option<Reversed>,
    /// What the motor was last told, as the event log saw it; `None` until the log is on.
    observed: Option<MotorOrder>,
    /// Its direction parameter changed since the last order was logged: the next one
    /// logged is the same command turned round, not a new command.
    turned_round: bool,
    /// Changes of [`Self::observed`] not yet taken (see "Motor orders" below).
    orders: Vec<MotorOrderChange>,
    power_ons: u32,
}

impl Drive {
    fn new(config: SlaveConfig, now: Instant) -> Self {
        Self {
            config,
            ram: Ram::default(),
            share: ShareSetup::default(),
            motor: Motor {
                speed_rpm: 0.0,
                position_counts: 0.0,
                at: now,
            },
            alarm: 0,
            communication_error: 0,
            running: None,
            last_command: None,
            last_command_at: None,
            last_new_speed_at: None,
            powered_since: Some(now),
            counter_origin: 0.0,
            silent: false,
            busy: false,
            last_traffic: now,
            requests_handled: 0,
            malformed_requests: 0,
            feedback_lie: None,
            reversal: None,
            observed: None,
            turned_round: false,
            orders: Vec::new(),
            power_ons: 0,
        }
    }

    fn booted(&self, at: Instant, config: &DrivesConfig) -> bool {
        self.powered_since
            .is_some_and(|since| at >= since + config.boot_time)
    }

    fn listening(&self, at: Instant, config: &DrivesConfig) -> bool {
        self.booted(at, config) && !self.silent
    }

    fn servo_on(&self) -> bool {
        self.ram.input_command & 1 != 0
    }

    fn regime(&self, config: &DrivesConfig) -> Regime {
        let excited = self.powered_since.is_some() && self.servo_on() && self.alarm == 0;
        if !excited {
            return Regime {
                target_rpm: 0.0,
                accel: config.brake_decel_rpm_per_s,
                decel: config.brake_decel_rpm_per_s,
            };
        }
        match self.running {
            Some(command) => Regime {
                target_rpm: if command.operation_type == CONTINUOUS_OPERATION {
                    self.shaft_sign() * f64::from(command.speed_rpm)
                } else {
                    0.0
                },
                accel: f64::from(command.accel_rpm_per_s),
                decel: f64::from(command.decel_rpm_per_s),
            },
            None => Regime {
                target_rpm: 0.0,
                accel: f64::from(self.ram.acceleration as i32),
                decel: f64::from(self.ram.deceleration as i32),
            },
        }
    }

    /// Brings motor and communication timeout up to `to`.
    fn advance_to(&mut self, to: Instant, config: &DrivesConfig) {
        if let Some(deadline) = self.communication_deadline(config)
            && deadline < to
        {
            self.motor.advance(deadline, &self.regime(config));
            self.raise_alarm(u32::from(ALARM_COMMUNICATION_TIMEOUT));
            self.note_order(deadline, config);
        }
        self.motor.advance(to, &self.regime(config));
    }

    fn communication_deadline(&self, config: &DrivesConfig) -> Option<Instant> {
        let timeout = self.ram.communication_timeout_ms;
        let monitoring = timeout > 0 && self.alarm == 0 && self.booted(self.motor.at, config);
        monitoring.then(|| self.last_traffic + Duration::from_millis(u64::from(timeout)))
    }

    fn raise_alarm(&mut self, code: u32) {
        self.alarm = code;
        self.running = None;
    }

    fn power_on(&mut self, now: Instant) {
        if self.powered_since.is_none() {
            self.power_ons += 1;
            self.powered_since = Some(now);
            self.counter_origin = self.motor.position_counts;
            self.last_traffic = now;
            if let Some(Reversed::Feedback { mirror_counts }) = &mut self.reversal {
                // The counter restarts at 0 and runs negated from there.
                *mirror_counts = self.motor.position_counts;
            }
        }
    }

    fn power_off(&mut self, now: Instant, config: &DrivesConfig) {
        self.advance_to(now, config);
        self.powered_since = None;
        self.ram = Ram::default();
        if !config.share_setup_saved {
            self.share = ShareSetup::default();
        }
        self.alarm = 0;
        self.communication_error = 0;
        self.running = None;
        self.last_command = None;
    }

    fn malformed(&mut self) {
        self.malformed_requests += 1;
        self.communication_error = COMMUNICATION_ERROR_FRAME;
    }

    fn note_exception(&mut self, code: u8) {
        self.communication_error = if code == ILLEGAL_DATA_VALUE {
            COMMUNICATION_ERROR_RANGE
        } else {
            COMMUNICATION_ERROR_UNDEFINED
        };
    }

    fn position_counts(&self) -> i32 {
        // Wrapping like the drive's 32-bit counter.
        (self.motor.position_counts - self.counter_origin).floor() as i64 as i32
    }

    fn view(&self, now: Instant, config: &DrivesConfig) -> DriveView {
        DriveView {
            address: self.config.address,
            mounting: self.config.mounting,
            powered: self.powered_since.is_some(),
            listening: self.listening(now, config),
            servo_on: self.servo_on(),
            alarm: self.alarm,
            communication_error: self.communication_error,
            command: self.last_command,
            share: self.share,
            position_counts: self.position_counts(),
            speed_rpm: self.motor.speed_rpm,
            shaft_revolutions: self.motor.position_counts / COUNTS_PER_REVOLUTION,
            last_command_at: self.last_command_at,
            last_new_speed_at: self.last_new_speed_at,
            requests_handled: self.requests_handled,
            malformed_requests: self.malformed_requests,
        }
    }

    fn known(net_id: u16) -> bool {
        Self::writable(net_id)
            || matches!(
                net_id,
                net_id::PRESENT_ALARM
                    | net_id::COMMUNICATION_ERROR
                    | net_id::DETECTED_POSITION
                    | net_id::DETECTED_SPEED
            )
    }

    fn writable(net_id: u16) -> bool {
        let share_lists = net_id::SHARE_READ_DATA..net_id::SHARE_WRITE_DATA + SHARE_LIST_LEN as u16;
        matches!(
            net_id,
            net_id::DDO_OPERATION_TYPE..=net_id::DDO_TRIGGER
                | net_id::DRIVER_INPUT_COMMAND
                | net_id::ALARM_RESET
                | net_id::SHARE_GLOBAL_ID..=net_id::SHARE_LOCAL_ID
                | net_id::COMMUNICATION_TIMEOUT
        ) || share_lists.contains(&net_id)
    }

    /// The item's value now; `None` for an item the drive does not have. NET-ID 0 is
    /// an unused share list slot and reads as 0.
    fn read_item(&self, id: u16) -> Option<u32> {
        let list_entry = |list: &[u32; SHARE_LIST_LEN], first: u16| {
            list.get(usize::from(id.checked_sub(first)?)).copied()
        };
        Some(match id {
            0 => 0,
            net_id::DDO_OPERATION_TYPE => self.ram.operation_type,
            net_id::DDO_POSITION => self.ram.position,
            net_id::DDO_SPEED => self.ram.speed,
            net_id::DDO_ACCELERATION => self.ram.acceleration,
            net_id::DDO_DECELERATION => self.ram.deceleration,
            net_id::DDO_TORQUE_LIMIT => self.ram.torque_limit,
            net_id::DDO_TRIGGER => 0,
            net_id::DRIVER_INPUT_COMMAND => self.ram.input_command,
            net_id::PRESENT_ALARM => self.alarm,
            net_id::COMMUNICATION_ERROR => self.communication_error,
            net_id::DETECTED_POSITION => self.reported_position_counts() as u32,
            net_id::DETECTED_SPEED => self.reported_speed_rpm() as u32,
            net_id::ALARM_RESET => self.ram.alarm_reset,
            net_id::SHARE_GLOBAL_ID => self.share.global_id,
            net_id::SHARE_NUMBER => self.share.number,
            net_id::SHARE_LOCAL_ID => self.share.local_id,
            net_id::COMMUNICATION_TIMEOUT => self.ram.communication_timeout_ms,
            _ => list_entry(&self.share.read_list, net_id::SHARE_READ_DATA)
                .or_else(|| list_entry(&self.share.write_list, net_id::SHARE_WRITE_DATA))?,
        })
    }

    /// Writes one item and applies its effect (in the order the frame carries them).
    fn write_item(&mut self, id: u16, value: u32, at: Instant) -> Result<(), u8> {
        let positive_rate = |value: u32| {
            if (value as i32) > 0 {
                Ok(value)
            } else {
                Err(ILLEGAL_DATA_VALUE)
            }
        };
        let in_range = |value: u32, max: u32| {
            if value <= max {
                Ok(value)
            } else {
                Err(ILLEGAL_DATA_VALUE)
            }
        };
        match id {
            0 => {}
            net_id::DDO_OPERATION_TYPE => self.ram.operation_type = value,
            net_id::DDO_POSITION => self.ram.position = value,
            net_id::DDO_SPEED => self.ram.speed = value,
            net_id::DDO_ACCELERATION => self.ram.acceleration = positive_rate(value)?,
            net_id::DDO_DECELERATION => self.ram.deceleration = positive_rate(value)?,
            net_id::DDO_TORQUE_LIMIT => self.ram.torque_limit = value,
            net_id::DDO_TRIGGER => {
                if value == 1 {
                    self.trigger(at);
                }
            }
            net_id::DRIVER_INPUT_COMMAND => self.ram.input_command = value,
            net_id::ALARM_RESET => {
                // The reset runs on the 0 → 1 edge.
                if self.ram.alarm_reset == 0 && value == 1 {
                    self.alarm = 0;
                }
                self.ram.alarm_reset = value;
            }
            net_id::SHARE_GLOBAL_ID => self.share.global_id = in_range(value, 247)?,
            net_id::SHARE_NUMBER => self.share.number = in_range(value, 31)?,
            net_id::SHARE_LOCAL_ID => self.share.local_id = in_range(value, 31)?,
            net_id::COMMUNICATION_TIMEOUT => self.ram.communication_timeout_ms = value,
            _ => self.write_share_list(id, value)?,
        }
        Ok(())
    }

    fn write_share_list(&mut self, id: u16, value: u32) -> Result<(), u8> {
        let named = u16::try_from(value).ok();
        let slot = usize::from(id.wrapping_sub(net_id::SHARE_READ_DATA));
        if slot < SHARE_LIST_LEN {
            if value != 0 && !named.is_some_and(Self::known) {
                return Err(ILLEGAL_DATA_VALUE);
            }
            self.share.read_list[slot] = value;
            return Ok(());
        }
        let slot = usize::from(id.wrapping_sub(net_id::SHARE_WRITE_DATA));
        if slot < SHARE_LIST_LEN {
            if value != 0 && !named.is_some_and(Self::writable) {
                return Err(ILLEGAL_DATA_VALUE);
            }
            self.share.write_list[slot] = value;
            return Ok(());
        }
        Err(ILLEGAL_DATA_ADDRESS)
    }

    fn trigger(&mut self, at: Instant) {
        let command = DdoCommand {
            operation_type: self.ram.operation_type,
            speed_rpm: self.ram.speed as i32,
            accel_rpm_per_s: self.ram.acceleration as i32,
            decel_rpm_per_s: self.ram.deceleration as i32,
            torque_limit: self.ram.torque_limit,
        };
        let new_speed = self
            .last_command
            .is_none_or(|last| last.speed_rpm != command.speed_rpm);
        if new_speed {
            self.last_new_speed_at = Some(at);
        }
        self.last_command = Some(command);
        self.last_command_at = Some(at);
        if self.alarm == 0 {
            self.running = Some(command);
        }
    }

    /// Reads `count` registers from `start`; `item_at` maps a register pair to a NET-ID.
    fn read_registers(
        &self,
        start: u16,
        count: u16,
        item_at: impl Fn(u32) -> Option<u16>,
    ) -> Result<Vec<u16>, u8> {
        let first = u32::from(start);
        (first..first + u32::from(count))
            .map(|register| {
                let value = item_at(register / 2)
                    .and_then(|id| self.read_item(id))
                    .ok_or(ILLEGAL_DATA_ADDRESS)?;
                Ok(if register % 2 == 0 {
                    (value >> 16) as u16
                } else {
                    value as u16
                })
            })
            .collect()
    }

    /// Writes `words` from register `start` on. Every register must exist and be
    /// writable before anything is written; then the items are written in order, and a
    /// value out of range stops the write there (earlier items stay written).
    fn write_registers(
        &mut self,
        start: u16,
        words: &[u16],
        item_at: impl Fn(u32) -> Option<u16>,
        at: Instant,
    ) -> Result<(), u8> {
        let first = u32::from(start);
        let registers = first..first + words.len() as u32;
        let mut items: Vec<(u16, u32)> = Vec::new();
        for (register, &word) in registers.zip(words) {
            let id = item_at(register / 2)
                .filter(|&id| id == 0 || Self::writable(id))
                .ok_or(ILLEGAL_DATA_ADDRESS)?;
            // Both halves of an item in one frame make one write.
            let continues_item =
                register % 2 == 1 && items.last().is_some_and(|&(last, _)| last == id);
            if !continues_item {
                let current = self.read_item(id).ok_or(ILLEGAL_DATA_ADDRESS)?;
                items.push((id, current));
            }
            let Some((_, value)) = items.last_mut() else {
                return Err(ILLEGAL_DATA_ADDRESS);
            };
            *value = if register % 2 == 0 {
                (u32::from(word) << 16) | (*value & 0xFFFF)
            } else {
                (*value & 0xFFFF_0000) | u32::from(word)
            };
        }
        for (id, value) in items {
            self.write_item(id, value, at)?;
        }
        Ok(())
    }

    /// Executes a unicast-shaped request: the write part first, then the read part.
    /// Returns the words read, if the request reads.
    fn execute(
        &mut self,
        request: &Request,
        read_item_at: impl Fn(u32) -> Option<u16>,
        write_item_at: impl Fn(u32) -> Option<u16>,
        at: Instant,
    ) -> Result<Option<Vec<u16>>, u8> {
        match request {
            Request::Read { start, count } => {
                self.read_registers(*start, *count, read_item_at).map(Some)
            }
            Request::Write { start, words, .. } => {
                self.write_registers(*start, words, write_item_at, at)?;
                Ok(None)
            }
            Request::ReadWrite {
                read_start,
                read_count,
                write_start,
                words,
            } => {
                self.write_registers(*write_start, words, write_item_at, at)?;
                self.read_registers(*read_start, *read_count, read_item_at)
                    .map(Some)
            }
        }
    }

    /// This member's part of an ID-share request: its slice of the written data, and
    /// the read count less its check word, both split by the share control number.
    fn execute_share(&mut self, request: &Request, at: Instant) -> Result<Option<Vec<u16>>, u8> {
        let members = self.share.number as usize;
        let member = self.share.local_id as usize - 1;
        let per_member = |count: usize, extra: usize| {
            let each = count.is_multiple_of(members).then(|| count / members)?;
            let registers = each.checked_sub(extra)?;
            (1..=SHARE_REGISTERS_PER_MEMBER)
                .contains(&registers)
                .then_some(registers)
        };
        let my_words = |words: &[u16]| -> Result<Vec<u16>, u8> {
            let each = per_member(words.len(), 0).ok_or(ILLEGAL_DATA_VALUE)?;
            Ok(words[member * each..(member + 1) * each].to_vec())
        };
        let my_read_count = |count: u16| -> Result<u16, u8> {
            // Each member adds one register for its check word.
            let each = per_member(usize::from(count), 1).ok_or(ILLEGAL_DATA_VALUE)?;
            Ok(each as u16)
        };
        let mine = match request {
            Request::Read { start, count } => Request::Read {
                start: *start,
                count: my_read_count(*count)?,
            },
            Request::Write { start, words, .. } => {
                let words = my_words(words)?;
                Request::Write {
                    start: *start,
                    count: words.len() as u16,
                    words,
                }
            }
            Request::ReadWrite {
                read_start,
                read_count,
                write_start,
                words,
            } => Request::ReadWrite {
                read_start: *read_start,
                read_count: my_read_count(*read_count)?,
                write_start: *write_start,
                words: my_words(words)?,
            },
        };
        let read_list = self.share.read_list;
        let write_list = self.share.write_list;
        let list_item = |list: [u32; SHARE_LIST_LEN]| {
            move |pair: u32| {
                let entry = *list.get(usize::try_from(pair).ok()?)?;
                u16::try_from(entry).ok()
            }
        };
        self.execute(&mine, list_item(read_list), list_item(write_list), at)
    }
}

// ---------------------------------------------------------------------------------
// Encoder faults: feedback that lies while the motor does what it is told.
// ---------------------------------------------------------------------------------

/// A lie in a drive's feedback: the motor still follows its commands, but what the
/// drive reports about its shaft is wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeedbackFault {
    /// The position counter (NET-ID 102) stops where it is now: a stuck encoder
    /// channel or a frozen register. The reported speed stays true.
    StuckPosition,
    /// The reported speed (NET-ID 103) reads this many r/min, whatever the shaft
    /// does: a stale register, e.g. 0 while the wheel still turns. The position stays
    /// true.
    SpeedReads(i32),
}

/// A [`FeedbackFault`] with the value it froze.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FeedbackLie {
    PositionAt(i32),
    SpeedAt(i32),
}

impl Drive {
    /// The counter as the drive reports it.
    fn reported_position_counts(&self) -> i32 {
        match (self.feedback_lie, self.reversal) {
            (Some(FeedbackLie::PositionAt(counts)), _) => counts,
            (_, Some(Reversed::Feedback { mirror_counts })) => {
                // Mirrored at the moment the reversal began, so the counter runs on
                // from where it was, backwards.
                (2.0 * mirror_counts - self.motor.position_counts - self.counter_origin).floor()
                    as i64 as i32
            }
            _ => self.position_counts(),
        }
    }

    /// The speed as the drive reports it, whole r/min.
    fn reported_speed_rpm(&self) -> i32 {
        match (self.feedback_lie, self.reversal) {
            (Some(FeedbackLie::SpeedAt(rpm)), _) => rpm,
            (_, Some(Reversed::Feedback { .. })) => -(self.motor.speed_rpm.round() as i32),
            _ => self.motor.speed_rpm.round() as i32,
        }
    }
}

impl DrivesHandle {
    /// Makes a drive's feedback lie from now on (`None` heals it); the lie survives
    /// power cycles, as a broken encoder would.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn set_feedback_fault(&self, slave: u8, fault: Option<FeedbackFault>) {
        self.change(|bus, _| {
            let drive = &mut bus.drives[bus.index_of(slave)];
            drive.feedback_lie = fault.map(|fault| match fault {
                FeedbackFault::StuckPosition => FeedbackLie::PositionAt(drive.position_counts()),
                FeedbackFault::SpeedReads(rpm) => FeedbackLie::SpeedAt(rpm),
            });
        });
    }
}

// ---------------------------------------------------------------------------------
// A reversed drive: its direction parameter at the other value (a replaced drive, a
// parameter reset), so its position and speed run against the sign of its command
// while agreeing with each other.
// ---------------------------------------------------------------------------------

/// How a reversed drive's direction differs; the controller sees the same either way
/// (position and speed against the command, agreeing with each other).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reversal {
    /// The shaft turns against the sign of the command, and the drive reports it as it
    /// turns: the wheel drives the wrong way.
    Motion,
    /// The shaft turns as commanded, but the drive reports position and speed negated:
    /// the wheel drives the right way, the odometry sees it backwards.
    Feedback,
}

/// A [`Reversal`] with where the negated counter was mirrored.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Reversed {
    Motion,
    /// The shaft position (in the motor's counts since the start) at which the
    /// reported counter turned round.
    Feedback {
        mirror_counts: f64,
    },
}

impl Drive {
    /// −1 when the shaft turns against its command, else +1.
    fn shaft_sign(&self) -> f64 {
        match self.reversal {
            Some(Reversed::Motion) => -1.0,
            _ => 1.0,
        }
    }
}

impl DrivesHandle {
    /// Reverses a drive's direction from now on (`None` restores it). A running motor
    /// reversed by [`Reversal::Motion`] ramps through zero towards the other sign at its
    /// command's rates. The reversal survives power cycles, as a parameter would.
    ///
    /// # Panics
    /// If no drive has the address `slave`.
    pub fn set_reversed(&self, slave: u8, reversal: Option<Reversal>) {
        self.change(|bus, _| {
            let drive = &mut bus.drives[bus.index_of(slave)];
            drive.turned_round = drive.reversal.is_some() != reversal.is_some();
            drive.reversal = reversal.map(|reversal| match reversal {
                Reversal::Motion => Reversed::Motion,
                Reversal::Feedback => Reversed::Feedback {
                    mirror_counts: drive.motor.position_counts,
                },
            });
        });
    }
}

impl DrivesConfig {
    /// The drives' address switches swapped: address 1 sits on the right wheel
    /// (mirrored), address 2 on the left. The controller, which takes address 1 for
    /// the left wheel, drives the base backwards when told forwards.
    pub fn with_swapped_addresses(mut self) -> Self {
        self.slaves = [
            SlaveConfig {
                address: 2,
                mounting: Mounting::Forward,
            },
            SlaveConfig {
                address: 1,
                mounting: Mounting::Mirrored,
            },
        ];
        self
    }
}

// ---------------------------------------------------------------------------------
// Motor orders: what each motor is told to do, as a log for a whole-robot oracle.
// ---------------------------------------------------------------------------------

/// What a motor is told to do at a moment. Excited (powered, S-ON, no alarm) it runs
/// towards its target; de-excited, its brake holds it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorOrder {
    pub powered: bool,
    /// Counts the drive's power-ons: a change tells a brown-out from a S-OFF.
    pub power_ons: u32,
    /// S-ON (driver input command bit 0).
    pub servo_on: bool,
    /// Present alarm, 0 = none.
    pub alarm: u32,
    /// Shaft r/min in the drive's own direction; 0 while de-excited.
    pub target_rpm: f64,
    /// The rate it slows down with, (r/min)/s (the brake's while de-excited).
    pub decel_rpm_per_s: f64,
}

impl MotorOrder {
    /// The motor is driven (its brake is released).
    pub fn excited(&self) -> bool {
        self.powered && self.servo_on && self.alarm == 0
    }
}

/// A change of one drive's [`MotorOrder`], when it took effect, and the shaft's speed
/// at that moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorOrderChange {
    pub at: Instant,
    /// The drive's address.
    pub slave: u8,
    pub order: MotorOrder,
    /// The shaft's speed when the order changed, r/min in the drive's own direction.
    pub speed_rpm: f64,
    /// Logged because the drive's direction parameter changed: the command is the one
    /// before, turned round.
    pub turned_round: bool,
}

impl Drive {
    fn order(&self, config: &DrivesConfig) -> MotorOrder {
        let regime = self.regime(config);
        MotorOrder {
            powered: self.powered_since.is_some(),
            power_ons: self.power_ons,
            servo_on: self.servo_on(),
            alarm: self.alarm,
            target_rpm: regime.target_rpm,
            decel_rpm_per_s: regime.decel,
        }
    }

    /// Logs the order if it changed since the last one logged (only while the log is on).
    fn note_order(&mut self, at: Instant, config: &DrivesConfig) {
        let Some(last) = self.observed else {
            return;
        };
        let order = self.order(config);
        let turned_round = core::mem::take(&mut self.turned_round);
        if order != last {
            self.observed = Some(order);
            self.orders.push(MotorOrderChange {
                at,
                slave: self.config.address,
                order,
                speed_rpm: self.motor.speed_rpm,
                turned_round,
            });
        }
    }
}

impl DrivesHandle {
    /// Starts logging every change of what the motors are told (see
    /// [`Self::take_orders`]); the first entries are the orders in force now.
    pub fn log_orders(&self) {
        let mut bus = self.bus.borrow_mut();
        let now = Instant::now();
        bus.advance(now);
        let config = bus.config.clone();
        for drive in &mut bus.drives {
            let order = drive.order(&config);
            drive.observed = Some(order);
            drive.orders.push(MotorOrderChange {
                at: now,
                slave: drive.config.address,
                order,
                speed_rpm: drive.motor.speed_rpm,
                turned_round: false,
            });
        }
    }

    /// The order changes logged since the last call, both drives, oldest first.
    pub fn take_orders(&self) -> Vec<MotorOrderChange> {
        let mut bus = self.bus.borrow_mut();
        bus.advance(Instant::now());
        let mut orders: Vec<MotorOrderChange> = bus
            .drives
            .iter_mut()
            .flat_map(|drive| core::mem::take(&mut drive.orders))
            .collect();
        orders.sort_by_key(|change| change.at);
        orders
    }
}
