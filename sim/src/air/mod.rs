//! A Bluetooth "air" on the virtual clock: the robot's dual-mode controller (LE and
//! BR/EDR) in memory, and virtual pads around it, so that the firmware's real
//! Bluetooth hosts (the BLE central on trouble-host behind the HCI guard, the
//! PlayStation pads' Classic host, both behind the HCI splitter) run in the
//! deterministic simulation, as they run on the chip.
//!
//! ```text
//!   firmware: classic::run_both ──H4── AirTransport ──┐
//!                                                      │  the robot's controller
//!   test / tester ──controls──▶ Air ── AirState ───────┤  links, schedule, pads
//!                                                      │
//!   BLE pad: trouble-host peripheral ──H4── AirTransport (its own LE controller)
//!   PlayStation pad: in the air itself (L2CAP, HID, reports)
//! ```
//!
//! - Commands are answered at once; what crosses the air (advertising events, a
//!   connection, data at the next connection event or slot pair, encryption, pages,
//!   inquiry answers, supervision timeouts, the pads' 4 ms reports) happens when the
//!   virtual clock gets there. No thread, no socket, no wall clock; the only
//!   randomness is the seed's (LE Rand, link keys, page and inquiry times, advertising
//!   jitter).
//! - Keys are compared, not used: encryption succeeds when both sides hold the same
//!   key, and a Classic authentication compares both sides' stored link keys instead
//!   of running LMP's challenge (as Bumble's virtual controllers do).
//! - [`Air::run`] must run beside the firmware (on the same executor);
//!   [`AirRobot`] boots the whole robot with the air.
//!
//! `docs/tests.md` ("The air") describes what it models and what it simplifies.

mod action;
mod ble_pad;
mod bredr;
mod le;
mod port;
mod ps_pad;
mod robot;
mod state;

use std::cell::RefCell;
use std::future::{Future, poll_fn};
use std::ops::Deref;
use std::pin::Pin;
use std::rc::Rc;
use std::task::{Poll, Waker};

use base_core::gamepad::{Buttons, Dpad, GamepadState};
use bt_hci_serial::SerialTransport;
use embassy_futures::join::join;
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Timer};

pub use action::{ActionRefused, AnyPad, PadAction};
pub use base_core::hid::playstation::{PadKind, Rgb};
pub use bredr::PAD_PAGE_ATTEMPTS;
pub use port::{AirController, AirReader, AirTransport, AirWriter};
pub use robot::AirRobot;
pub use state::AirCounters;

use port::{H4_ACL, HostPort};
use ps_pad::PsPad;
use state::{
    Action, AirState, BlePadState, Device, DeviceId, DeviceKind, LOCAL_HOST_TERMINATED,
    REMOTE_POWER_OFF, ROBOT,
};

/// The robot controller's public (BR/EDR) address, as a pad's bond names it.
pub const ROBOT_ADDRESS: &str = "00:B0:75:00:00:01";

/// What a pad saw, in the order it happened.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AirEvent {
    pub at: Instant,
    pub pad: String,
    pub event: PadEvent,
}

/// What happens to a pad.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PadEvent {
    /// A link to the robot is up.
    Connected,
    /// A new bond was made with the robot.
    Paired,
    /// The robot's pairing failed on the pad's side (BLE).
    PairingFailed,
    /// The link is encrypted.
    Encrypted,
    /// The robot's LE encryption failed: 0x06 the pad has no key, 0x3D the keys differ.
    EncryptionFailed(u8),
    /// A Classic authentication failed with this status (0x05 wrong key, 0x06 no key,
    /// 0x18 pairing refused).
    AuthenticationFailed(u8),
    /// The robot subscribed to the input report (BLE).
    Subscribed,
    /// Both HID channels are open (PlayStation).
    HidOpen,
    /// The robot asked for this feature report (PlayStation).
    FeatureRead(u8),
    /// The robot set the light bar (PlayStation).
    LightBar(Rgb),
    /// The link is gone, with the reason the pad heard.
    Disconnected(u8),
    /// The pad's page found no answer (0x04) or was refused (the robot's reason).
    PageFailed(u8),
    /// The robot refused to open or configure a channel the pad asked for.
    ChannelRefused(u16),
    /// The pad refused a frame of this length from the robot (malformed).
    Refused(usize),
}

/// Why a pad could not be made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AirError {
    /// Not `XX:XX:XX:XX:XX:XX` in hex.
    BadAddress(String),
    /// A pad of that name exists already.
    NameTaken(String),
}

impl core::fmt::Display for AirError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            AirError::BadAddress(text) => {
                write!(
                    f,
                    "`{text}` is no Bluetooth address: give six hex bytes, AA:BB:CC:DD:EE:FF"
                )
            }
            AirError::NameTaken(name) => write!(f, "a pad named `{name}` is in the air already"),
        }
    }
}

impl std::error::Error for AirError {}

/// An address in the usual notation (most significant byte first) as it travels on
/// HCI (least significant byte first).
pub fn parse_address(text: &str) -> Result<[u8; 6], AirError> {
    let bytes: Vec<u8> = text
        .split(':')
        .map(|pair| match pair.len() {
            2 => u8::from_str_radix(pair, 16).ok(),
            _ => None,
        })
        .collect::<Option<_>>()
        .ok_or_else(|| AirError::BadAddress(text.to_owned()))?;
    let mut address: [u8; 6] = bytes
        .try_into()
        .map_err(|_| AirError::BadAddress(text.to_owned()))?;
    address.reverse();
    Ok(address)
}

type Task = Pin<Box<dyn Future<Output = ()>>>;

#[derive(Default)]
struct Tasks {
    futures: Vec<Task>,
    waker: Option<Waker>,
}

/// The air and everything in it; clones are the same air.
#[derive(Clone)]
pub struct Air {
    state: Rc<RefCell<AirState>>,
    tasks: Rc<RefCell<Tasks>>,
}

impl Air {
    /// An empty air whose randomness all comes from `seed`.
    pub fn new(seed: u64) -> Air {
        let robot = parse_address(ROBOT_ADDRESS).expect("a valid address");
        Air {
            state: Rc::new(RefCell::new(AirState::new(seed, robot))),
            tasks: Rc::new(RefCell::new(Tasks::default())),
        }
    }

    /// The robot's controller powers up (again): a fresh controller with no links, and
    /// the transport its hosts use. The previous controller's links are gone without
    /// a word: the pads see their supervision timeout.
    pub fn robot_transport(&self) -> AirTransport {
        self.robot_off();
        let mut state = self.state.borrow_mut();
        let robot = &mut state.devices[ROBOT];
        robot.powered = true;
        robot.port = Some(HostPort::default());
        let generation = robot.generation;
        drop(state);
        SerialTransport::new(
            AirReader {
                air: self.state.clone(),
                device: ROBOT,
                generation,
            },
            AirWriter {
                air: self.state.clone(),
                device: ROBOT,
                generation,
            },
        )
    }

    /// The robot's controller loses power.
    pub fn robot_off(&self) {
        let mut state = self.state.borrow_mut();
        for link in state.links_of(ROBOT) {
            state.abandon(link, ROBOT);
        }
        let robot = &mut state.devices[ROBOT];
        robot.reset();
        robot.powered = false;
        robot.port = None;
        robot.generation += 1;
    }

    /// `device`'s host transport (a BLE pad's).
    fn transport(&self, device: DeviceId) -> AirTransport {
        let mut state = self.state.borrow_mut();
        let pad = &mut state.devices[device];
        pad.port = Some(HostPort::default());
        let generation = pad.generation;
        SerialTransport::new(
            AirReader {
                air: self.state.clone(),
                device,
                generation,
            },
            AirWriter {
                air: self.state.clone(),
                device,
                generation,
            },
        )
    }

    fn add_device(&self, device: Device) -> Result<DeviceId, AirError> {
        let mut state = self.state.borrow_mut();
        if state.devices.iter().any(|known| known.name == device.name) {
            return Err(AirError::NameTaken(device.name));
        }
        state.devices.push(device);
        Ok(state.devices.len() - 1)
    }

    /// A BLE pad (Xbox Wireless Controller, BLE firmware 5), on, with no bond, at this
    /// random static address (`C1:11:22:33:44:55`). It advertises once asked to
    /// ([`BlePad::advertise`]).
    pub fn ble_pad(&self, name: &str, address: &str) -> Result<BlePad, AirError> {
        let random = parse_address(address)?;
        let mut device = Device::new(name, DeviceKind::BlePad(BlePadState::default()), [0; 6]);
        device.random_address = Some(random);
        let id = self.add_device(device)?;
        self.spawn(Box::pin(ble_pad::run(self.clone(), id, random)));
        Ok(BlePad(Pad {
            air: self.clone(),
            device: id,
        }))
    }

    /// A PlayStation pad of `kind` at this public address (`A4:AE:12:00:00:01`),
    /// switched off, with no bond.
    pub fn playstation_pad(
        &self,
        name: &str,
        kind: PadKind,
        address: &str,
    ) -> Result<PlayStationPad, AirError> {
        let public = parse_address(address)?;
        let device = Device::new(
            name,
            DeviceKind::PlayStation(Box::new(PsPad::new(kind))),
            public,
        );
        let id = self.add_device(device)?;
        Ok(PlayStationPad(Pad {
            air: self.clone(),
            device: id,
        }))
    }

    fn spawn(&self, task: Task) {
        let mut tasks = self.tasks.borrow_mut();
        tasks.futures.push(task);
        if let Some(waker) = tasks.waker.take() {
            waker.wake();
        }
    }

    /// The air at work, for ever: the pads' hosts and everything due. Run it beside
    /// the firmware on the same executor.
    pub async fn run(&self) -> ! {
        let pads = poll_fn(|cx| {
            let mut running = std::mem::take(&mut self.tasks.borrow_mut().futures);
            running.retain_mut(|task| task.as_mut().poll(cx).is_pending());
            let mut tasks = self.tasks.borrow_mut();
            if !tasks.futures.is_empty() {
                // Made while the others ran: poll them next time round.
                cx.waker().wake_by_ref();
            }
            running.append(&mut tasks.futures);
            tasks.futures = running;
            tasks.waker = Some(cx.waker().clone());
            Poll::<()>::Pending
        });
        let schedule = async {
            loop {
                let next = self.state.borrow_mut().run_due();
                let kicked = poll_fn(|cx| {
                    if self.state.borrow_mut().take_kick(cx.waker()) {
                        Poll::Ready(())
                    } else {
                        Poll::Pending
                    }
                });
                match next {
                    Some(at) => {
                        select(Timer::at(at), kicked).await;
                    }
                    None => kicked.await,
                }
            }
        };
        join(pads, schedule).await;
        unreachable!("the air runs for ever")
    }

    /// Everything the pads saw so far.
    pub fn events(&self) -> Vec<AirEvent> {
        self.state.borrow().log.clone()
    }

    /// A mark in the events: [`Self::events_since`] and [`Self::wait_for`] look after it.
    pub fn mark(&self) -> usize {
        self.state.borrow().log.len()
    }

    pub fn events_since(&self, mark: usize) -> Vec<AirEvent> {
        self.state.borrow().log[mark.min(self.mark())..].to_vec()
    }

    /// Waits (virtual time) until `pad` saw an event `what` accepts after `mark`;
    /// `None` after `timeout`.
    pub async fn wait_for(
        &self,
        mark: usize,
        pad: &str,
        what: impl Fn(&PadEvent) -> bool,
        timeout: Duration,
    ) -> Option<AirEvent> {
        let found = poll_fn(|cx| {
            let mut state = self.state.borrow_mut();
            let start = mark.min(state.log.len());
            match state.log[start..]
                .iter()
                .find(|event| event.pad == pad && what(&event.event))
            {
                Some(event) => Poll::Ready(event.clone()),
                None => {
                    // The executor polls with one waker again and again: keep it once.
                    let waker = cx.waker();
                    if !state
                        .log_watchers
                        .iter()
                        .any(|known| known.will_wake(waker))
                    {
                        state.log_watchers.push(waker.clone());
                    }
                    Poll::Pending
                }
            }
        });
        match select(found, Timer::after(timeout)).await {
            Either::First(event) => Some(event),
            Either::Second(()) => None,
        }
    }

    fn record(&self, device: DeviceId, event: PadEvent) {
        self.state.borrow_mut().record(device, event);
    }

    pub fn counters(&self) -> AirCounters {
        self.state.borrow().counters
    }

    /// Hands the robot's hosts this H4 packet (type byte first) now, as its
    /// controller would: any event or ACL packet, malformed or oversized.
    pub fn inject_to_robot(&self, packet: &[u8]) {
        let mut state = self.state.borrow_mut();
        let generation = state.devices[ROBOT].generation;
        if let Some(port) = state.port(ROBOT, generation) {
            port.send(packet);
        }
    }
}

/// What both kinds of pad do.
pub struct Pad {
    air: Air,
    device: DeviceId,
}

impl Pad {
    pub fn name(&self) -> String {
        self.air.state.borrow().devices[self.device].name.clone()
    }

    /// The pad's inputs from now on (buttons by their Xbox names, sticks −1 … 1 with
    /// +Y forward, triggers 0 … 1, the D-pad). A BLE pad notifies the change; a
    /// PlayStation pad's next report carries it.
    pub fn set_inputs(&self, inputs: GamepadState) {
        let mut state = self.air.state.borrow_mut();
        let device = &mut state.devices[self.device];
        if let Some(pad) = device.ble_pad() {
            pad.inputs = inputs;
            pad.poke();
        } else if let Some(pad) = device.ps_pad() {
            pad.inputs = inputs;
        }
    }

    pub fn inputs(&self) -> GamepadState {
        let mut state = self.air.state.borrow_mut();
        let device = &mut state.devices[self.device];
        if let Some(pad) = device.ble_pad() {
            pad.inputs
        } else {
            device.ps_pad().map(|pad| pad.inputs).unwrap_or_default()
        }
    }

    fn change(&self, change: impl FnOnce(&mut GamepadState)) {
        let mut inputs = self.inputs();
        change(&mut inputs);
        self.set_inputs(inputs);
    }

    /// Holds these buttons (besides those held already).
    pub fn hold(&self, buttons: Buttons) {
        self.change(|inputs| inputs.buttons = inputs.buttons.with(buttons));
    }

    /// Lets go of these buttons.
    pub fn release(&self, buttons: Buttons) {
        self.change(|inputs| inputs.buttons = Buttons(inputs.buttons.0 & !buttons.0));
    }

    /// The left stick: `x` right, `y` forward, each −1 … 1.
    pub fn left_stick(&self, x: f32, y: f32) {
        self.change(|inputs| {
            inputs.left_x = x;
            inputs.left_y = y;
        });
    }

    pub fn right_stick(&self, x: f32, y: f32) {
        self.change(|inputs| {
            inputs.right_x = x;
            inputs.right_y = y;
        });
    }

    pub fn triggers(&self, left: f32, right: f32) {
        self.change(|inputs| {
            inputs.left_trigger = left;
            inputs.right_trigger = right;
        });
    }

    pub fn dpad(&self, dpad: Dpad) {
        self.change(|inputs| inputs.dpad = dpad);
    }

    /// The pad leaves radio range: its links carry nothing, and time out after their
    /// supervision timeout unless it is back before.
    pub fn out_of_range(&self) {
        let mut state = self.air.state.borrow_mut();
        state.devices[self.device].in_range = false;
        state.leave(self.device);
    }

    pub fn back_in_range(&self) {
        let mut state = self.air.state.borrow_mut();
        state.devices[self.device].in_range = true;
        state.come_back(self.device);
        if let Some(pad) = state.devices[self.device].ble_pad() {
            pad.poke();
        }
    }

    /// A link to the robot is up.
    pub fn connected(&self) -> bool {
        self.robot_handle().is_some()
    }

    /// The robot controller's handle of the pad's link (to build raw packets).
    pub fn robot_handle(&self) -> Option<u16> {
        let state = self.air.state.borrow();
        let link = state.links_of(self.device).into_iter().next()?;
        let link = &state.links[&link];
        (link.robot_generation == state.devices[ROBOT].generation).then_some(link.robot_handle)
    }

    /// The pad sends this L2CAP PDU (`payload` on channel `cid`) on its link now: the
    /// controllers frame it and cut it to the robot host's ACL length. False without a
    /// link.
    pub fn inject_l2cap(&self, cid: u16, payload: &[u8]) -> bool {
        let frame = ps_pad::frame(cid, payload);
        let mut state = self.air.state.borrow_mut();
        let Some(link) = state.links_of(self.device).into_iter().next() else {
            return false;
        };
        state.send_frame_to_robot(link, self.device, &frame);
        true
    }

    /// The robot's controller hands its host this ACL data on the pad's link,
    /// unchanged, whatever its length (up to 1021 bytes, an EDR packet) or
    /// boundary flag (0b10 a frame's start, 0b01 a continuation). False without a link.
    pub fn inject_acl(&self, boundary: u8, data: &[u8]) -> bool {
        let mut state = self.air.state.borrow_mut();
        let Some(link) = state.links_of(self.device).into_iter().next() else {
            return false;
        };
        let when = state.link_moment(link);
        let Some(handle) = state.links.get(&link).map(|link| link.robot_handle) else {
            return false;
        };
        let generation = state.devices[ROBOT].generation;
        let mut packet = vec![H4_ACL];
        packet.extend_from_slice(&(handle | u16::from(boundary & 0b11) << 12).to_le_bytes());
        packet.extend_from_slice(&(data.len() as u16).to_le_bytes());
        packet.extend_from_slice(data);
        state.at(
            when,
            Action::ToHost {
                device: ROBOT,
                generation,
                packet,
            },
        );
        true
    }

    /// From now on the pad sends this L2CAP PDU on every new link, at once.
    pub fn attack_on_connect(&self, cid: u16, payload: &[u8]) {
        let frame = ps_pad::frame(cid, payload);
        self.air.state.borrow_mut().devices[self.device]
            .attacks
            .push(frame);
    }

    /// No more attacks on connect.
    pub fn peace(&self) {
        self.air.state.borrow_mut().devices[self.device]
            .attacks
            .clear();
    }

    /// What this pad saw so far.
    pub fn events(&self) -> Vec<PadEvent> {
        let name = self.name();
        self.air
            .events()
            .into_iter()
            .filter(|event| event.pad == name)
            .map(|event| event.event)
            .collect()
    }

    /// Ends the pad's links as a switched-off pad does: the robot hears `reason` at
    /// the next moment the link allows.
    fn end_links(&self, state: &mut AirState, reason: u8) {
        for link in state.links_of(self.device) {
            let when = state.link_moment(link);
            state.at(
                when,
                Action::LinkEnd {
                    link,
                    robot_reason: reason,
                    pad_reason: LOCAL_HOST_TERMINATED,
                },
            );
        }
    }
}

/// A BLE pad in the air.
pub struct BlePad(Pad);

impl Deref for BlePad {
    type Target = Pad;

    fn deref(&self) -> &Pad {
        &self.0
    }
}

impl BlePad {
    /// Advertises as a gamepad whenever it is on and not connected (again after every
    /// disconnection), or stops.
    pub fn advertise(&self, on: bool) {
        let mut state = self.air.state.borrow_mut();
        if let Some(pad) = state.devices[self.device].ble_pad() {
            pad.wants_advertising = on;
            pad.poke();
        }
    }

    /// Switched off (the Xbox button held): the link ends with "power off" and the pad
    /// is silent until [`Self::switch_on`].
    pub fn switch_off(&self) {
        let mut state = self.air.state.borrow_mut();
        self.end_links(&mut state, REMOTE_POWER_OFF);
        state.devices[self.device].powered = false;
        if let Some(pad) = state.devices[self.device].ble_pad() {
            pad.poke();
        }
    }

    pub fn switch_on(&self) {
        let mut state = self.air.state.borrow_mut();
        state.devices[self.device].powered = true;
        if let Some(pad) = state.devices[self.device].ble_pad() {
            pad.poke();
        }
    }

    /// The pad forgets its bond (a reset of the pad).
    pub fn forget_bond(&self) {
        let mut state = self.air.state.borrow_mut();
        if let Some(pad) = state.devices[self.device].ble_pad() {
            pad.forget = true;
            pad.poke();
        }
    }
}

/// A PlayStation pad in the air.
pub struct PlayStationPad(Pad);

impl Deref for PlayStationPad {
    type Target = Pad;

    fn deref(&self) -> &Pad {
        &self.0
    }
}

impl PlayStationPad {
    fn with<T>(&self, change: impl FnOnce(&mut PsPad) -> T) -> T {
        let mut state = self.air.state.borrow_mut();
        change(
            state.devices[self.device]
                .ps_pad()
                .expect("a PlayStation pad"),
        )
    }

    /// Share + PS: on, discoverable and willing to pair until it paired.
    pub fn pairing_mode(&self) {
        self.with(|pad| {
            pad.switched_on = true;
            pad.pairing_mode = true;
        });
        let mut state = self.air.state.borrow_mut();
        if state.discoverable(self.device) {
            state.discoverable_now(self.device);
        }
    }

    /// PS pressed: on, and a bonded pad pages its host (up to
    /// [`PAD_PAGE_ATTEMPTS`] times, a second apart) and opens its HID channels.
    pub fn switch_on(&self) {
        let pages = self.with(|pad| {
            pad.switched_on = true;
            pad.page_attempts = 0;
            pad.bond.is_some() && pad.link.is_none()
        });
        if pages {
            self.air.state.borrow_mut().start_paging(self.device);
        }
    }

    /// On, paging the robot although it has no bond with it (a stranger, or an
    /// impostor at a bonded pad's address).
    pub fn page_robot(&self) {
        let robot = self.air.state.borrow().devices[ROBOT].public_address;
        let pages = self.with(|pad| {
            pad.switched_on = true;
            pad.page_attempts = 0;
            pad.page_target = Some(robot);
            pad.link.is_none()
        });
        if pages {
            self.air.state.borrow_mut().start_paging(self.device);
        }
    }

    /// Switched off: the link ends with "power off", no more pages or reports.
    pub fn switch_off(&self) {
        let mut state = self.air.state.borrow_mut();
        self.end_links(&mut state, REMOTE_POWER_OFF);
        let pad = state.devices[self.device]
            .ps_pad()
            .expect("a PlayStation pad");
        pad.switched_on = false;
        pad.pairing_mode = false;
        pad.paging = None;
        pad.page_target = None;
    }

    /// The link stays, the reports stop (`true`), or go on (`false`).
    pub fn silent(&self, silent: bool) {
        self.with(|pad| pad.silent = silent);
    }

    /// From now on the full reports carry a wrong CRC.
    pub fn garble(&self, garbled: bool) {
        self.with(|pad| pad.garbled = garbled);
    }

    /// A clone that never leaves the short report 0x01.
    pub fn short_reports_only(&self, stuck: bool) {
        self.with(|pad| pad.stuck_short = stuck);
    }

    /// The battery byte of the full reports (DualShock 4: low nibble tenths, 0x10
    /// on the cable; DualSense: high nibble the state).
    pub fn battery(&self, status: u8) {
        self.with(|pad| pad.battery = status);
    }

    /// How often the pad reports (4 ms, as the real pads, by default).
    pub fn report_period(&self, period: Duration) {
        self.with(|pad| pad.report_period = period.max(Duration::from_millis(1)));
    }

    /// The pad forgets its link key.
    pub fn forget_bond(&self) {
        self.with(|pad| pad.bond = None);
    }

    pub fn bonded(&self) -> bool {
        self.with(|pad| pad.bond.is_some())
    }

    /// Whether it sends its full reports (feature report 0x05 was read).
    pub fn full_mode(&self) -> bool {
        self.with(|pad| pad.full_mode)
    }

    /// The colour the robot last set.
    pub fn light_bar(&self) -> Option<Rgb> {
        self.with(|pad| pad.light_bar)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_are_read_most_significant_byte_first_and_bad_ones_are_refused() {
        assert_eq!(
            parse_address("C1:11:22:33:44:55"),
            Ok([0x55, 0x44, 0x33, 0x22, 0x11, 0xC1])
        );
        for bad in [
            "C1:11:22:33:44",
            "C1:11:22:33:44:55:66",
            "C1-11-22-33-44-55",
            "G1:11:22:33:44:55",
            "",
        ] {
            assert_eq!(
                parse_address(bad),
                Err(AirError::BadAddress(bad.to_owned()))
            );
        }
    }

    #[test]
    fn a_wait_for_an_event_ends_when_it_happens_or_at_its_timeout() {
        let air = Air::new(1);
        let pad = air
            .playstation_pad("pad", PadKind::DualShock4, "A4:AE:12:00:00:01")
            .expect("a pad");
        crate::runtime::block_on(async {
            let start = Instant::now();
            let (_, seen) = join(
                async {
                    Timer::after_micros(1_500).await;
                    air.record(pad.device, PadEvent::Paired);
                    Timer::after_micros(700).await;
                    air.record(pad.device, PadEvent::Connected);
                },
                air.wait_for(
                    0,
                    "pad",
                    |event| *event == PadEvent::Connected,
                    Duration::from_millis(10),
                ),
            )
            .await;
            let seen = seen.expect("the event came");
            assert_eq!((seen.at - start).as_micros(), 2_200);
            assert_eq!(Instant::now(), seen.at, "the wait ended when it happened");
            let missing = air
                .wait_for(
                    0,
                    "pad",
                    |event| *event == PadEvent::Encrypted,
                    Duration::from_millis(10),
                )
                .await;
            assert_eq!(missing, None);
            assert_eq!((Instant::now() - seen.at).as_millis(), 10);
        });
    }

    #[test]
    fn two_pads_of_one_name_are_refused() {
        let air = Air::new(1);
        air.playstation_pad("pad", PadKind::DualShock4, "A4:AE:12:00:00:01")
            .expect("the first");
        let second = air.playstation_pad("pad", PadKind::DualSense, "A4:AE:12:00:00:02");
        assert_eq!(second.err(), Some(AirError::NameTaken("pad".into())));
    }
}
