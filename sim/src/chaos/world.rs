//! The robot under test: the firmware's real tasks (and its update task) on the
//! virtual robot, booted again at every reset, panic, power cut and update, with the
//! PC's programs, the pads, the pins and the faults applied from the event list, and
//! everything it does fed to the [`Oracle`] as it happens.

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::rc::Rc;
use std::task::{Poll, Waker};

use base_core::controller::Input;
use base_core::gamepad::{Buttons, Dpad, GamepadState};
use base_core::remote::Pad;
use base_core::update::signature::Trust;
use base_core::update::trial::{self, ResetRecord};
use base_runtime::Hardware;
use base_runtime::channels::Channels;
use base_runtime::update::{ResetRequest, UpdateFlash};
use embassy_futures::select::{Either, Either4, select, select4};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_can::Frame as _;
use embedded_hal::digital::PinState;
use embedded_storage_async::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

use super::event::{
    DriveFault, Event, FlashFault, PadAction, PadHands, PadKind, ResetKind, Timed, wire,
};
use super::oracle::{Injected, Oracle, Us};
use super::programs;
use crate::app_flash::{self, Behaviour};
use crate::can::{CanPeer, SimFrame, VirtualCan};
use crate::drives::{DrivesConfig, FeedbackFault, Reversal};
use crate::flash::{FlashError, FlashTiming, RamFlash};
use crate::io::SimWatchdog;
use crate::robot::{FLASH_SIZE, VirtualRobot, WATCHDOG_TIMEOUT};
use crate::runtime::now;

/// The oracle and the drives, so that every observation first brings in the drives'
/// order changes up to its moment: the oracle sees everything in time order.
pub struct Observer {
    oracle: RefCell<Oracle>,
    drives: crate::drives::DrivesHandle,
}

impl Observer {
    pub fn with<T>(&self, observe: impl FnOnce(&mut Oracle, Us) -> T) -> T {
        let orders = self.drives.take_orders();
        let mut oracle = self.oracle.borrow_mut();
        oracle.orders(&orders);
        observe(&mut oracle, micros(now()))
    }
}

pub fn micros(at: Instant) -> Us {
    at.as_micros()
}

/// Why the controller restarts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reset {
    Injected(ResetKind),
    Watchdog,
    Update(ResetRequest),
}

/// Flash faults waiting for the next operation, shared by both flashes.
#[derive(Debug, Default)]
struct FlashFaults {
    fail_writes: u8,
    stall_next_erase: Option<Duration>,
}

/// What the flashes share with the world.
struct FlashProbe {
    observer: Rc<Observer>,
    faults: RefCell<FlashFaults>,
    /// The firmware's tasks run (the bootloader's and the arming writes come before).
    firmware_running: Cell<bool>,
    reset: Rc<Signal<NoopRawMutex, Reset>>,
}

/// A flash that tells the oracle what the firmware does with it and plays the
/// injected faults: stalls, failed writes, a power cut after some bytes.
#[derive(Clone)]
pub struct ProbedFlash {
    flash: RamFlash,
    probe: Rc<FlashProbe>,
    name: &'static str,
}

/// A probed flash's error: the chip's, or a write the tester made fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProbedFlashError {
    Flash(FlashError),
    InjectedWriteFailure,
}

impl NorFlashError for ProbedFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            ProbedFlashError::Flash(error) => error.kind(),
            ProbedFlashError::InjectedWriteFailure => NorFlashErrorKind::Other,
        }
    }
}

impl ProbedFlash {
    /// Tells the oracle about an operation that ran from `start` to now; a power cut
    /// resets the controller as a power-on.
    fn after(&self, start: Instant, what: &str, result: &Result<(), FlashError>) {
        let end = now();
        let observer = &self.probe.observer;
        observer.with(|oracle, _| oracle.stall(micros(start), micros(end)));
        if self.probe.firmware_running.get() {
            observer.with(|oracle, at| {
                oracle.flash_written(at, &format!("{what} of the {} flash", self.name))
            });
        }
        if result.is_err() && !self.flash.is_powered() {
            self.probe.firmware_running.set(false);
            self.probe.reset.signal(Reset::Injected(ResetKind::PowerOn));
        }
    }
}

impl ErrorType for ProbedFlash {
    type Error = ProbedFlashError;
}

impl ReadNorFlash for ProbedFlash {
    const READ_SIZE: usize = <RamFlash as ReadNorFlash>::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), ProbedFlashError> {
        self.flash
            .read(offset, bytes)
            .await
            .map_err(ProbedFlashError::Flash)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for ProbedFlash {
    const WRITE_SIZE: usize = <RamFlash as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <RamFlash as NorFlash>::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), ProbedFlashError> {
        let start = now();
        if let Some(stall) = self.probe.faults.borrow_mut().stall_next_erase.take() {
            crate::runtime::stall(stall);
        }
        let result = self.flash.erase(from, to).await;
        self.after(start, "an erase", &result);
        result.map_err(ProbedFlashError::Flash)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), ProbedFlashError> {
        let start = now();
        let fail = {
            let mut faults = self.probe.faults.borrow_mut();
            let fail = faults.fail_writes > 0;
            faults.fail_writes = faults.fail_writes.saturating_sub(1);
            fail
        };
        if fail {
            self.after(start, "a failed write", &Ok(()));
            return Err(ProbedFlashError::InjectedWriteFailure);
        }
        let result = self.flash.write(offset, bytes).await;
        self.after(start, "a write", &result);
        result.map_err(ProbedFlashError::Flash)
    }
}

/// Frames the controller sent, for the programs that wait for answers.
#[derive(Default)]
pub struct Inbox {
    frames: RefCell<VecDeque<(u64, Instant, SimFrame)>>,
    next: Cell<u64>,
    waiting: RefCell<Vec<Waker>>,
}

impl Inbox {
    fn push(&self, at: Instant, frame: SimFrame) {
        let mut frames = self.frames.borrow_mut();
        let seq = self.next.get();
        self.next.set(seq + 1);
        frames.push_back((seq, at, frame));
        while frames.front().is_some_and(|(_, sent, _)| {
            at.saturating_duration_since(*sent) > Duration::from_secs(5)
        }) {
            frames.pop_front();
        }
        for waker in self.waiting.borrow_mut().drain(..) {
            waker.wake();
        }
    }

    /// Where a reader starts: after everything sent so far.
    pub fn cursor(&self) -> u64 {
        self.next.get()
    }

    /// The next frame from `cursor` with this ID whose data `accept` takes, waiting
    /// until `deadline`.
    pub async fn wait_for(
        &self,
        cursor: &mut u64,
        id: u16,
        deadline: Instant,
        accept: impl Fn(&[u8]) -> bool,
    ) -> Option<Vec<u8>> {
        let found = core::future::poll_fn(|cx| {
            let frames = self.frames.borrow();
            for (seq, _, frame) in frames.iter() {
                if *seq < *cursor {
                    continue;
                }
                *cursor = seq + 1;
                if frame.standard_id() == Some(id) && accept(frame.data()) {
                    return Poll::Ready(frame.data().to_vec());
                }
            }
            self.waiting.borrow_mut().push(cx.waker().clone());
            Poll::Pending
        });
        match select(found, Timer::at(deadline)).await {
            Either::First(data) => Some(data),
            Either::Second(()) => None,
        }
    }
}

/// The pads' links as their tasks hold them, and the inputs on their way.
#[derive(Default)]
struct Pads {
    connected: [bool; 2],
    /// Inputs for the controller's queue, with what the oracle is told once it took them.
    queue: VecDeque<(Input, PadKind, PadNote)>,
    waker: Option<Waker>,
    /// The controller's switch-off requests seen so far, per pad.
    disconnects: [u16; 2],
    /// A pad whose packet the guard refused is not reached for before this.
    refused_until: [Option<Instant>; 2],
    /// When the BLE host stopped within the last minute.
    host_stops: VecDeque<Instant>,
    /// The BLE task gave its host up: no BLE pad connects until a turn-on.
    ble_host_off: bool,
    /// The controller's turn-ons of Bluetooth seen so far.
    turn_ons: u16,
}

/// The BLE task gives its host up after this many stops within [`HOST_STOPS_WINDOW`].
const HOST_STOPS_GIVEN_UP: usize = 3;
const HOST_STOPS_WINDOW: Duration = Duration::from_secs(60);
/// How long the remote task waits after the guard refused a pad's packet.
const REFUSED_BACKOFF: Duration = Duration::from_secs(1);

#[derive(Debug, Clone, Copy)]
enum PadNote {
    Link(bool),
    Report(PadHands),
    /// An input the oracle has no rule about (a refusal counted, the host given up).
    Nothing,
}

/// How the world is set up for one run.
#[derive(Debug, Clone, Copy)]
pub struct WorldConfig {
    /// From power-on or reset until the firmware runs (a chip's bootloader and
    /// start-up).
    pub boot_time: Duration,
}

/// The robot and everything around it for one run.
pub struct World {
    pub robot: VirtualRobot,
    register_flash: ProbedFlash,
    app_flash: ProbedFlash,
    pub peer: CanPeer,
    pub observer: Rc<Observer>,
    pub inbox: Inbox,
    reset: Rc<Signal<NoopRawMutex, Reset>>,
    pads: RefCell<Pads>,
    config: WorldConfig,
    next_tag: Cell<u16>,
    /// Whether the firmware's tasks run now.
    up: Cell<bool>,
    /// The events applied so far, for the report.
    pub applied: RefCell<VecDeque<String>>,
    /// Events started and frames the PC sent.
    pub events_started: Cell<u64>,
}

/// The virtual load cell's offset and scale (`VirtualRobot::new`).
const LOAD_CELL_OFFSET: f64 = 8_000.0;
const LOAD_CELL_COUNTS_PER_GRAM: f64 = 100.0;

/// The factory image's filler: small, so each boot checks it quickly.
const FACTORY_PAYLOAD: usize = 8 * 1024;

impl World {
    pub fn new(config: WorldConfig) -> Self {
        let robot = VirtualRobot::with_drives(DrivesConfig {
            log_capacity: 16,
            ..DrivesConfig::commissioned()
        });
        robot.drives.log_orders();
        let observer = Rc::new(Observer {
            oracle: RefCell::new(Oracle::new()),
            drives: robot.drives.clone(),
        });
        let reset = Rc::new(Signal::new());
        let probe = Rc::new(FlashProbe {
            observer: observer.clone(),
            faults: RefCell::default(),
            firmware_running: Cell::new(false),
            reset: reset.clone(),
        });
        let app = RamFlash::new(base_core::update::partitions::FLASH_SIZE as usize);
        install_factory_image(&app);
        app.set_timing(FlashTiming::TYPICAL);
        robot.flash.set_timing(FlashTiming::TYPICAL);
        let (_, _, peer) = VirtualCan::new();
        Self {
            register_flash: ProbedFlash {
                flash: robot.flash.clone(),
                probe: probe.clone(),
                name: "register store's",
            },
            app_flash: ProbedFlash {
                flash: app,
                probe,
                name: "app",
            },
            robot,
            peer,
            observer,
            inbox: Inbox::default(),
            reset,
            pads: RefCell::default(),
            config,
            next_tag: Cell::new(0x5A00),
            up: Cell::new(false),
            applied: RefCell::default(),
            events_started: Cell::new(0),
        }
    }

    pub fn observe<T>(&self, observe: impl FnOnce(&mut Oracle, Us) -> T) -> T {
        self.observer.with(observe)
    }

    /// A tag for a register read, never 0.
    pub fn tag(&self) -> u16 {
        let tag = self.next_tag.get().wrapping_add(1).max(1);
        self.next_tag.set(tag);
        tag
    }

    /// Puts a PC frame on the bus (in turn with every other frame) and tells the
    /// oracle when it reached the controller.
    pub async fn send(&self, id: u16, data: &[u8]) {
        let Some(frame) = SimFrame::standard(id, data) else {
            return;
        };
        let at = self.peer.transmit(frame, now()).await;
        self.observe(|oracle, _| oracle.pc_frame(micros(at), id, data));
    }

    // -----------------------------------------------------------------------------
    // The controller, boot after boot
    // -----------------------------------------------------------------------------

    /// Boots the controller again and again, as resets, panics, power cuts and
    /// updates ask.
    pub async fn controller(&self) -> ! {
        let mut reset_record = ResetRecord::Empty;
        let mut reset_by_watchdog = false;
        let mut app = self.app_flash.clone();
        loop {
            Timer::after(self.config.boot_time).await;
            let booted = app_flash::boot(&mut app).await;
            self.observe(|oracle, at| {
                oracle.booted(at, booted.as_ref().map(|b| b.version.as_str()))
            });
            let Some(booted) = booted else {
                // Dark until the run ends: the oracle has reported it.
                core::future::pending::<()>().await;
                continue;
            };
            let booted_at = now();
            let bluetooth = self.robot.rtc_ram.boot();
            let channels = Channels::new();
            let mut update_flash = UpdateFlash::new(app.clone(), booted.slot);
            let started = base_runtime::update::arm(&mut update_flash).await;
            channels.update.lock_at_start(&started);
            let boot =
                trial::boot_cause(reset_record, &started.start, started.written, booted.slot);
            reset_record = boot.keep;
            let behaviour = Behaviour::of(&booted.version);
            if behaviour == Behaviour::PanicsAtBoot {
                Timer::after_millis(200).await;
                self.robot
                    .rtc_ram
                    .record_panic(base_core::time::Timestamp::from_millis(
                        (now() - booted_at).as_millis(),
                    ));
                reset_by_watchdog = true;
                self.observe(|oracle, at| oracle.controller_down(at, true));
                continue;
            }
            // The CAN controller starts now: what came during the boot is lost.
            let (can_rx, can_tx) = self.peer.reset_controller();
            let watchdog = SimWatchdog::new(WATCHDOG_TIMEOUT);
            let hardware = Hardware {
                can_rx: app_flash::DeafToConfirm {
                    rx: can_rx,
                    deaf: behaviour == Behaviour::NeverConfirms,
                },
                can_tx,
                drives: self.robot.drives.port(),
                flash: self.register_flash.clone(),
                flash_range: 0..FLASH_SIZE,
                estop: self.robot.estop.clone(),
                safety_zone: self.robot.safety_zone.clone(),
                button: self.robot.button.clone(),
                pc_switch: self.robot.pc_switch.clone(),
                battery: self.robot.battery.clone(),
                load_cell: self.robot.load_cell.clone(),
                watchdog: watchdog.clone(),
                reset_by_watchdog: reset_by_watchdog
                    && boot.cause == base_core::registers::UpdateReset::None,
                bluetooth,
                update_reset: boot.cause,
            };
            {
                let mut pads = self.pads.borrow_mut();
                *pads = Pads::default();
            }
            let estop = self.robot.estop.level() == PinState::Low;
            let bluetooth_on = bluetooth == base_core::panic_loop::Bluetooth::On;
            let settings = behaviour.settings();
            self.observe(|oracle, at| {
                oracle.controller_up(at, bluetooth_on, estop, &settings.drives)
            });
            self.up.set(true);
            self.register_flash.probe.firmware_running.set(true);
            let version = booted.version.clone();
            let config = base_runtime::update::UpdateConfig {
                chip: app_flash::SIM_CHIP,
                project: base_runtime::update::PROJECT,
                version: &version,
                security_version: booted.security_version,
                trust: Trust::Keys(super::programs::trusted_keys()),
                trial_deadline_ms: base_runtime::update::TRIAL_DEADLINE_MS,
            };
            let firmware = embassy_futures::join::join(
                base_runtime::run(hardware, settings, &channels),
                self.pad_bridge(&channels),
            );
            let update = base_runtime::update::run(
                &mut update_flash,
                started,
                boot.trial_owner,
                &config,
                &channels.update,
                &channels.can_tx,
            );
            let bite = async {
                loop {
                    Timer::after_millis(100).await;
                    if watchdog.has_bitten() {
                        return;
                    }
                }
            };
            let reset = match select4(firmware, update, self.reset.wait(), bite).await {
                Either4::First((never, _)) => never,
                Either4::Second(request) => Reset::Update(request),
                Either4::Third(reset) => reset,
                Either4::Fourth(()) => {
                    self.observe(|oracle, at| oracle.watchdog_bit(at));
                    Reset::Watchdog
                }
            };
            self.up.set(false);
            self.register_flash.probe.firmware_running.set(false);
            self.reset.reset();
            let panic = matches!(reset, Reset::Injected(ResetKind::Panic) | Reset::Watchdog);
            self.observe(|oracle, at| oracle.controller_down(at, panic));
            match reset {
                Reset::Injected(ResetKind::Panic) => {
                    let uptime = (now() - booted_at).as_millis();
                    self.robot
                        .rtc_ram
                        .record_panic(base_core::time::Timestamp::from_millis(uptime));
                }
                Reset::Injected(ResetKind::PowerOn) => {
                    self.robot.rtc_ram.power_on();
                    self.register_flash.flash.restore_power();
                    self.app_flash.flash.restore_power();
                }
                _ => {}
            }
            reset_by_watchdog = panic;
            reset_record = match reset {
                Reset::Update(request) => request.record(),
                Reset::Injected(ResetKind::Button | ResetKind::PowerOn) => {
                    self.observe(|oracle, at| oracle.rtc_cleared(at));
                    ResetRecord::Empty
                }
                Reset::Injected(ResetKind::Panic) | Reset::Watchdog => reset_record,
            };
        }
    }

    /// Hands the pads' inputs to this boot's controller as the remote tasks do, and
    /// acts on its switch-off requests.
    async fn pad_bridge(&self, channels: &Channels) -> ! {
        let ends = channels.remote_ends();
        loop {
            let next = core::future::poll_fn(|cx| {
                let mut pads = self.pads.borrow_mut();
                match pads.queue.pop_front() {
                    Some(item) => Poll::Ready(item),
                    None => {
                        pads.waker = Some(cx.waker().clone());
                        Poll::Pending
                    }
                }
            });
            match select(next, ends.remote_requests.wait()).await {
                Either::First((input, pad, note)) => {
                    ends.inputs.send(input).await;
                    self.observe(|oracle, at| match note {
                        PadNote::Link(up) => oracle.pad_link(at, pad, up),
                        PadNote::Report(hands) => oracle.pad_report(at, pad, hands),
                        PadNote::Nothing => {}
                    });
                }
                Either::Second(request) => {
                    {
                        let mut pads = self.pads.borrow_mut();
                        if request.turn_ons != pads.turn_ons {
                            pads.turn_ons = request.turn_ons;
                            pads.ble_host_off = false;
                            pads.host_stops.clear();
                        }
                    }
                    for pad in PadKind::ALL {
                        let asked = request.disconnects_of(pad_of(pad));
                        let mut pads = self.pads.borrow_mut();
                        if asked != pads.disconnects[pad.index()] {
                            pads.disconnects[pad.index()] = asked;
                            if pads.connected[pad.index()] {
                                pads.connected[pad.index()] = false;
                                pads.queue.push_back((
                                    link_input(pad, false),
                                    pad,
                                    PadNote::Link(false),
                                ));
                            }
                        }
                    }
                }
            }
        }
    }

    fn queue_pad(&self, pad: PadKind, action: &PadAction) {
        if !self.up.get() {
            return;
        }
        let mut pads = self.pads.borrow_mut();
        let index = pad.index();
        let now = now();
        let link_down = |pads: &mut Pads, pad: PadKind| {
            if pads.connected[pad.index()] {
                pads.connected[pad.index()] = false;
                pads.queue
                    .push_back((link_input(pad, false), pad, PadNote::Link(false)));
            }
        };
        match action {
            PadAction::Connect
                if !pads.connected[index]
                    && !(pad == PadKind::Ble && pads.ble_host_off)
                    && pads.refused_until[index].is_none_or(|until| now >= until) =>
            {
                pads.connected[index] = true;
                pads.queue
                    .push_back((link_input(pad, true), pad, PadNote::Link(true)));
            }
            PadAction::Drop => link_down(&mut pads, pad),
            PadAction::Report(hands) if pads.connected[index] => pads.queue.push_back((
                Input::Gamepad {
                    pad: pad_of(pad),
                    state: gamepad_state(*hands),
                },
                pad,
                PadNote::Report(*hands),
            )),
            PadAction::PacketRefused if pads.connected[index] => {
                link_down(&mut pads, pad);
                pads.refused_until[index] = Some(now + REFUSED_BACKOFF);
                pads.queue.push_back((
                    Input::RadioPacketRefused { pad: pad_of(pad) },
                    pad,
                    PadNote::Nothing,
                ));
            }
            PadAction::HostStops if !pads.ble_host_off => {
                for pad in PadKind::ALL {
                    link_down(&mut pads, pad);
                }
                pads.host_stops
                    .retain(|&stop| now < stop + HOST_STOPS_WINDOW);
                pads.host_stops.push_back(now);
                if pads.host_stops.len() >= HOST_STOPS_GIVEN_UP {
                    pads.ble_host_off = true;
                    pads.queue
                        .push_back((Input::BleHostOff, PadKind::Ble, PadNote::Nothing));
                }
            }
            _ => return,
        }
        if let Some(waker) = pads.waker.take() {
            waker.wake();
        }
    }

    // -----------------------------------------------------------------------------
    // Events
    // -----------------------------------------------------------------------------

    /// Starts `event`: inputs and faults act at once, programs run as their future.
    pub fn start<'a>(&'a self, event: &'a Event) -> Option<Pin<Box<dyn Future<Output = ()> + 'a>>> {
        self.events_started.set(self.events_started.get() + 1);
        {
            let mut applied = self.applied.borrow_mut();
            if applied.len() == 32 {
                applied.pop_front();
            }
            applied.push_back(
                Timed {
                    at_ms: now().as_millis(),
                    event: event.clone(),
                }
                .to_string(),
            );
        }
        let robot = &self.robot;
        let drives = &robot.drives;
        match event {
            Event::Stream { .. }
            | Event::Frame { .. }
            | Event::WriteRegister { .. }
            | Event::ReadFlood { .. }
            | Event::QueryFlood { .. }
            | Event::Update { .. } => return Some(Box::pin(programs::run(self, event))),
            Event::Pad { pad, action } => self.queue_pad(*pad, action),
            Event::Estop { pressed } => {
                robot.estop.set_level(level(!*pressed));
                self.observe(|oracle, at| oracle.estop(at, *pressed));
            }
            Event::EstopChatter {
                period_us,
                on_us,
                ms,
            } => {
                let (period, on, ms) = (*period_us, *on_us, *ms);
                return Some(Box::pin(async move {
                    robot.estop.chatter(
                        PinState::Low,
                        Duration::from_micros(u64::from(period.max(1))),
                        Duration::from_micros(u64::from(on)),
                    );
                    let started = micros(now());
                    self.observe(|oracle, at| oracle.estop(at, true));
                    Timer::after_millis(u64::from(ms)).await;
                    robot.estop.set_level(PinState::High);
                    let last = last_pulse(started, period, on, micros(now()));
                    self.observe(|oracle, at| oracle.estop_until(at, false, last));
                }));
            }
            Event::Zone { occupied } => {
                robot.set_safety_zone(*occupied);
                self.observe(|oracle, at| oracle.zone(at, *occupied));
            }
            Event::ZoneChatter {
                period_us,
                on_us,
                ms,
            } => {
                let (period, on, ms) = (*period_us, *on_us, *ms);
                return Some(Box::pin(async move {
                    robot.safety_zone.chatter(
                        PinState::Low,
                        Duration::from_micros(u64::from(period.max(1))),
                        Duration::from_micros(u64::from(on)),
                    );
                    let started = micros(now());
                    self.observe(|oracle, at| oracle.zone(at, true));
                    Timer::after_millis(u64::from(ms)).await;
                    robot.safety_zone.set_level(PinState::High);
                    let last = last_pulse(started, period, on, micros(now()));
                    self.observe(|oracle, at| oracle.zone_until(at, false, last));
                }));
            }
            Event::Button { ms } => {
                let ms = *ms;
                return Some(Box::pin(async move {
                    robot.button.set_level(PinState::Low);
                    self.observe(|oracle, at| oracle.button(at, true));
                    Timer::after_millis(u64::from(ms)).await;
                    robot.button.set_level(PinState::High);
                    self.observe(|oracle, at| oracle.button(at, false));
                }));
            }
            Event::Battery { millivolts } => robot.battery.set_millivolts(*millivolts),
            Event::Weight { grams } => {
                robot.load_cell.set_load_grams(f64::from(*grams));
                // Beyond the HX711's 24-bit range the reading is refused: the scale
                // fault it reports is one that happened.
                let overloaded = LOAD_CELL_OFFSET + f64::from(*grams) * LOAD_CELL_COUNTS_PER_GRAM
                    >= f64::from(0x7F_FFFF);
                if overloaded {
                    self.observe(|oracle, at| {
                        oracle.injected(at, Injected::LoadCell { missing: true })
                    });
                }
            }
            Event::LoadCellMissing { missing } => {
                robot.load_cell.set_missing(*missing);
                self.observe(|oracle, at| {
                    oracle.injected(at, Injected::LoadCell { missing: *missing })
                });
            }
            Event::Drive(fault) => {
                let injected = match *fault {
                    DriveFault::Silent { slave, on } => {
                        drives.set_silent(slave, on);
                        Injected::DriveLine { slave, active: on }
                    }
                    DriveFault::Alarm { slave, code } => {
                        if drives.drive(slave).powered {
                            drives.raise_alarm(slave, code);
                        }
                        Injected::DriveLine {
                            slave,
                            active: false,
                        }
                    }
                    DriveFault::Power { on } => {
                        drives.power(on);
                        Injected::DriveLine {
                            slave: 0,
                            active: !on,
                        }
                    }
                    DriveFault::PowerCycle { slave } => {
                        drives.power_cycle(slave);
                        Injected::DriveLine {
                            slave,
                            active: false,
                        }
                    }
                    DriveFault::LoseReplies { on } => {
                        drives.lose_replies(on);
                        Injected::DriveLine {
                            slave: 0,
                            active: on,
                        }
                    }
                    DriveFault::GarbleNext { replies } => {
                        drives.garble_next_replies(usize::from(replies));
                        Injected::DriveLine {
                            slave: 0,
                            active: false,
                        }
                    }
                    DriveFault::GarbleOf { slave, on } => {
                        drives.garble_replies_of(slave, on);
                        Injected::DriveLine { slave, active: on }
                    }
                    DriveFault::Busy { slave, on } => {
                        drives.set_busy(slave, on);
                        Injected::DriveLine { slave, active: on }
                    }
                    DriveFault::FailLongerThan { bytes } => {
                        drives.fail_requests_longer_than(bytes.map(usize::from));
                        Injected::DriveLine {
                            slave: 0,
                            active: bytes.is_some(),
                        }
                    }
                    DriveFault::StuckEncoder { slave, on } => {
                        drives
                            .set_feedback_fault(slave, on.then_some(FeedbackFault::StuckPosition));
                        Injected::Feedback { slave, active: on }
                    }
                    DriveFault::SpeedReads { slave, rpm } => {
                        drives.set_feedback_fault(
                            slave,
                            rpm.map(|rpm| FeedbackFault::SpeedReads(i32::from(rpm))),
                        );
                        Injected::Feedback {
                            slave,
                            active: rpm.is_some(),
                        }
                    }
                    DriveFault::Reversed { slave, motion, on } => {
                        let reversal = if motion {
                            Reversal::Motion
                        } else {
                            Reversal::Feedback
                        };
                        drives.set_reversed(slave, on.then_some(reversal));
                        if motion {
                            Injected::ReversedMotion { slave, active: on }
                        } else {
                            Injected::Feedback { slave, active: on }
                        }
                    }
                };
                self.observe(|oracle, at| oracle.injected(at, injected));
            }
            Event::Flash(fault) => {
                let probe = &self.register_flash.probe;
                match *fault {
                    FlashFault::StallNextErase { ms } => {
                        probe.faults.borrow_mut().stall_next_erase =
                            Some(Duration::from_millis(u64::from(ms)));
                    }
                    FlashFault::FailWrites { count } => {
                        probe.faults.borrow_mut().fail_writes = count;
                        self.observe(|oracle, at| oracle.injected(at, Injected::Flash));
                    }
                    FlashFault::PowerCut { after_bytes } => {
                        self.register_flash
                            .flash
                            .cut_power_after(u64::from(after_bytes));
                        self.app_flash.flash.cut_power_after(u64::from(after_bytes));
                        self.observe(|oracle, at| oracle.injected(at, Injected::Flash));
                    }
                }
            }
            Event::BusOff => {
                if self.up.get() {
                    self.peer.force_bus_off();
                    self.observe(|oracle, at| oracle.injected(at, Injected::CanBus));
                }
            }
            Event::RxOverrun => {
                if self.up.get() {
                    self.peer
                        .inject_rx_error(base_runtime::hw::CanError::Overrun);
                    self.observe(|oracle, at| oracle.injected(at, Injected::CanBus));
                }
            }
            Event::Reset(kind) => {
                if self.up.get() {
                    self.reset.signal(Reset::Injected(*kind));
                }
            }
        }
        None
    }

    /// Takes the controller's frames off the bus as they come: to the oracle and to
    /// the programs that wait for answers.
    pub async fn monitor(&self) -> ! {
        loop {
            let frame = self.peer.receive().await;
            let at = now();
            if let Some(id) = frame.standard_id() {
                let wheels = if id == wire::POSITION {
                    Some([1, 2].map(|slave| self.robot.drives.drive(slave).forward_revolutions()))
                } else {
                    None
                };
                self.observe(|oracle, _| {
                    if let Some(wheels) = wheels {
                        oracle.wheels(wheels);
                    }
                    oracle.bc_frame(micros(at), id, frame.data())
                });
            }
            self.inbox.push(at, frame);
        }
    }

    /// Every control cycle: the shafts' speeds to the oracle. Ends at `end` or at the
    /// first violation.
    pub async fn ticks(&self, end: Instant) {
        let drives = &self.robot.drives;
        while now() < end {
            Timer::after_millis(10).await;
            // The bus keeps what it carried; the monitor has it already.
            let _ = self.peer.take_sent();
            self.peer.forget_sent_by_pc();
            let speeds = [1, 2].map(|slave| drives.drive(slave).speed_rpm);
            let violated = self.observe(|oracle, at| {
                oracle.tick(at, speeds);
                oracle.violation().is_some()
            });
            if violated {
                return;
            }
        }
    }
}

/// The end of the last active pulse of a chatter (`on_us` of every `period_us` from
/// `start`) before `end` that the firmware surely sampled.
fn last_pulse(start: Us, period_us: u32, on_us: u32, end: Us) -> Us {
    // A last pulse cut shorter than one sample period may fall between two samples:
    // the firmware never saw it, and its release time runs from the pulse before.
    const SAMPLED_US: u64 = base_runtime::InputSettings::DEFAULT.sample_period_us as u64;
    let period = u64::from(period_us.max(1));
    let on = u64::from(on_us);
    let elapsed = end.saturating_sub(start);
    let into = elapsed % period;
    let begun = start + elapsed - into;
    if into.min(on) >= SAMPLED_US {
        begun + into.min(on)
    } else {
        begun.saturating_sub(period) + on
    }
}

fn level(high: bool) -> PinState {
    if high { PinState::High } else { PinState::Low }
}

fn pad_of(pad: PadKind) -> Pad {
    match pad {
        PadKind::Ble => Pad::Ble,
        PadKind::Classic => Pad::Classic,
    }
}

fn link_input(pad: PadKind, connected: bool) -> Input {
    Input::RemoteLink {
        pad: pad_of(pad),
        bonded: true,
        connected,
    }
}

/// A report as the pads' decoders hand it on: the dead-man is RB (R1), L2 the left
/// trigger (docs/remote.md).
fn gamepad_state(hands: PadHands) -> GamepadState {
    let mut buttons = Buttons(hands.buttons & 0x0FFF);
    if hands.dead_man {
        buttons = Buttons(buttons.0 | Buttons::RIGHT_BUMPER.0);
    } else {
        buttons = Buttons(buttons.0 & !Buttons::RIGHT_BUMPER.0);
    }
    let dpad_bits = hands.buttons >> 12;
    GamepadState {
        left_y: f32::from(hands.left_y) / 100.0,
        right_x: f32::from(hands.right_x) / 100.0,
        left_trigger: if hands.l2 { 1.0 } else { 0.0 },
        buttons,
        dpad: Dpad {
            up: dpad_bits & 1 != 0,
            down: dpad_bits & 2 != 0,
            left: dpad_bits & 4 != 0,
            right: dpad_bits & 8 != 0,
        },
        ..GamepadState::default()
    }
}

/// The factory image in `ota_0` and an erased otadata, as a USB flash leaves a board.
fn install_factory_image(app: &RamFlash) {
    let image = app_flash::sim_image(app_flash::FACTORY_VERSION, FACTORY_PAYLOAD);
    let at = base_core::update::partitions::OTA_0.offset;
    let mut padded = image;
    padded.resize(
        padded.len().next_multiple_of(crate::flash::ERASE_SIZE),
        0xFF,
    );
    app.corrupt(at, &padded);
}

/// The drives' frames: what a register read of `address` with `tag` returns.
pub fn register_read_frame(address: u8, tag: u16) -> Vec<u8> {
    wire::register_read(address, tag)
}

#[cfg(test)]
mod tests {
    use super::last_pulse;

    #[test]
    fn a_last_pulse_cut_too_short_to_be_sampled_does_not_count() {
        // 4 ms on in every 10 ms from 0.
        assert_eq!(last_pulse(0, 10_000, 4_000, 43_000), 43_000, "cut while on");
        assert_eq!(
            last_pulse(0, 10_000, 4_000, 47_000),
            44_000,
            "cut while off"
        );
        assert_eq!(
            last_pulse(0, 10_000, 4_000, 40_000),
            34_000,
            "cut as one begins"
        );
        // 100 µs of a pulse may fall between two samples: the pulse before counts.
        assert_eq!(
            last_pulse(0, 10_000, 4_000, 40_100),
            34_000,
            "cut 100 µs in"
        );
    }
}
