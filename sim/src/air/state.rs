//! The air's state: every controller (the robot's and the pads'), the links between
//! them, and what is due when. Commands from a host are answered at once; whatever
//! crosses the air (advertising, a connection, data, encryption, a timeout) is put on
//! the schedule and happens when the virtual clock gets there ([`AirState::run_due`]).
//!
//! Only the robot's controller makes links, always to a pad: LE links as central to a
//! BLE pad, BR/EDR links to a PlayStation pad (paged by either side).

use std::collections::BTreeMap;
use std::task::Waker;

use embassy_time::{Duration, Instant};

use super::port::{FromHost, H4_ACL, H4_EVENT, HostPort};
use super::ps_pad::{PadOut, PsPad};
use super::{AirEvent, PadEvent};
use base_core::gamepad::GamepadState;

pub type DeviceId = usize;
pub type LinkId = u64;

/// The robot's controller is always the first device.
pub const ROBOT: DeviceId = 0;

// Event codes.
pub const EV_INQUIRY_COMPLETE: u8 = 0x01;
pub const EV_INQUIRY_RESULT: u8 = 0x02;
pub const EV_CONNECTION_COMPLETE: u8 = 0x03;
pub const EV_CONNECTION_REQUEST: u8 = 0x04;
pub const EV_DISCONNECTION_COMPLETE: u8 = 0x05;
pub const EV_AUTHENTICATION_COMPLETE: u8 = 0x06;
pub const EV_ENCRYPTION_CHANGE: u8 = 0x08;
pub const EV_COMMAND_COMPLETE: u8 = 0x0E;
pub const EV_COMMAND_STATUS: u8 = 0x0F;
pub const EV_ROLE_CHANGE: u8 = 0x12;
pub const EV_NUMBER_OF_COMPLETED_PACKETS: u8 = 0x13;
pub const EV_LINK_KEY_REQUEST: u8 = 0x17;
pub const EV_LINK_KEY_NOTIFICATION: u8 = 0x18;
pub const EV_ENCRYPTION_KEY_REFRESH_COMPLETE: u8 = 0x30;
pub const EV_IO_CAPABILITY_REQUEST: u8 = 0x31;
pub const EV_IO_CAPABILITY_RESPONSE: u8 = 0x32;
pub const EV_USER_CONFIRMATION_REQUEST: u8 = 0x33;
pub const EV_SIMPLE_PAIRING_COMPLETE: u8 = 0x36;
pub const EV_LE_META: u8 = 0x3E;
/// The ESP32 controller's vendor event, sent after an authentication by link key.
pub const EV_VENDOR: u8 = 0xFF;

// Status codes.
pub const SUCCESS: u8 = 0x00;
pub const UNKNOWN_CONNECTION: u8 = 0x02;
pub const PAGE_TIMEOUT: u8 = 0x04;
pub const AUTHENTICATION_FAILURE: u8 = 0x05;
pub const PIN_OR_KEY_MISSING: u8 = 0x06;
pub const CONNECTION_TIMEOUT: u8 = 0x08;
pub const COMMAND_DISALLOWED: u8 = 0x0C;
pub const CONNECTION_ACCEPT_TIMEOUT: u8 = 0x10;
pub const REMOTE_POWER_OFF: u8 = 0x15;
pub const LOCAL_HOST_TERMINATED: u8 = 0x16;
pub const PAIRING_NOT_ALLOWED: u8 = 0x18;
pub const INSUFFICIENT_SECURITY: u8 = 0x2F;
pub const MIC_FAILURE: u8 = 0x3D;

/// The event mask after a reset: every event of the first 45 bits.
const DEFAULT_EVENT_MASK: u64 = 0x0000_1FFF_FFFF_FFFF;
/// The LE event mask after a reset: subevents 1 to 5.
const DEFAULT_LE_EVENT_MASK: u64 = 0x1F;
/// The ACL length a host takes until it says otherwise (Host Buffer Size).
const DEFAULT_HOST_ACL_LEN: usize = 255;

/// SplitMix64: the air's only randomness, from the seed it is given.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A whole number in `low..=high`.
    pub fn between(&mut self, low: u64, high: u64) -> u64 {
        low + self.next() % (high - low + 1)
    }

    pub fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let mut bytes = [0u8; N];
        for chunk in bytes.chunks_mut(8) {
            let word = self.next().to_le_bytes();
            chunk.copy_from_slice(&word[..chunk.len()]);
        }
        bytes
    }
}

/// What a device is.
pub enum DeviceKind {
    /// The robot's dual-mode controller; its hosts are the firmware's.
    Robot,
    /// A BLE pad's LE controller; its host is a trouble-host stack in the air.
    BlePad(BlePadState),
    /// A PlayStation pad: controller and pad in one, no host port.
    PlayStation(Box<PsPad>),
}

/// What the air keeps of a BLE pad beside its controller.
#[derive(Default)]
pub struct BlePadState {
    /// What the pad's buttons, sticks and triggers are.
    pub inputs: GamepadState,
    /// The pad advertises whenever it is on and not connected.
    pub wants_advertising: bool,
    /// The pad's host should forget its bond.
    pub forget: bool,
    /// Something changed for the pad's host to look at.
    pub poked: bool,
    pub waker: Option<Waker>,
}

/// An LE advertiser, as its host set it up.
#[derive(Debug, Clone)]
pub struct Advertising {
    pub interval: Duration,
    /// 0x00 connectable undirected, others as HCI numbers them.
    pub kind: u8,
    /// 0 public, 1 random: which of the device's addresses it advertises with.
    pub own_address_kind: u8,
    pub data: Vec<u8>,
    pub scan_response: Vec<u8>,
    pub enabled: bool,
    /// Bumped at every enable: an advertising event of an earlier one is void.
    pub epoch: u64,
}

impl Default for Advertising {
    fn default() -> Self {
        Self {
            // 1.28 s, the specification's default.
            interval: Duration::from_micros(2048 * 625),
            kind: 0,
            own_address_kind: 0,
            data: Vec::new(),
            scan_response: Vec::new(),
            enabled: false,
            epoch: 0,
        }
    }
}

#[derive(Debug, Clone, Default)]
pub struct Scanning {
    pub active: bool,
    pub filter_duplicates: bool,
    pub seen: Vec<[u8; 6]>,
}

/// An LE Create Connection in progress.
#[derive(Debug, Clone)]
pub struct Initiating {
    /// The peer (address kind, address); `None`: anyone on the filter accept list.
    pub peer: Option<(u8, [u8; 6])>,
    pub interval: Duration,
    pub supervision: Duration,
}

#[derive(Debug, Clone, Default)]
pub struct LeState {
    pub advertising: Advertising,
    pub scan_active_parameter: bool,
    pub scanning: Option<Scanning>,
    pub initiating: Option<Initiating>,
    pub accept_list: Vec<(u8, [u8; 6])>,
}

#[derive(Debug, Clone)]
pub struct BrEdrState {
    /// Bit 0 inquiry scan, bit 1 page scan.
    pub scan_enable: u8,
    pub class_of_device: u32,
    pub page_timeout_slots: u16,
    /// The inquiry in progress (its number).
    pub inquiry: Option<u64>,
    /// Create Connection in progress: the address paged and the page's number.
    pub pages: Vec<([u8; 6], u64)>,
    /// Connection Request events waiting for Accept or Reject: the pad and its number.
    pub requests: Vec<(DeviceId, u64)>,
}

impl Default for BrEdrState {
    fn default() -> Self {
        Self {
            scan_enable: 0,
            class_of_device: 0,
            page_timeout_slots: 0x2000,
            inquiry: None,
            pages: Vec::new(),
            requests: Vec::new(),
        }
    }
}

/// One controller in the air.
pub struct Device {
    pub name: String,
    pub kind: DeviceKind,
    /// The H4 port to the device's host (none for a PlayStation pad, and for the robot
    /// before its first boot).
    pub port: Option<HostPort>,
    /// Bumped when the robot's controller powers up again: the old port is dead.
    pub generation: u32,
    pub powered: bool,
    pub in_range: bool,
    /// The public address as it travels on HCI (least significant byte first); all
    /// zero for a BLE pad (it has only its random static address).
    pub public_address: [u8; 6],
    pub random_address: Option<[u8; 6]>,
    pub event_mask: u64,
    pub le_event_mask: u64,
    pub host_acl_len: usize,
    pub next_handle: u16,
    pub le: LeState,
    pub bredr: BrEdrState,
    /// L2CAP frames the pad sends on every new link, at once (attack-on-connect).
    pub attacks: Vec<Vec<u8>>,
}

impl Device {
    pub fn new(name: &str, kind: DeviceKind, public_address: [u8; 6]) -> Self {
        Self {
            name: name.to_owned(),
            kind,
            port: None,
            generation: 0,
            powered: true,
            in_range: true,
            public_address,
            random_address: None,
            event_mask: DEFAULT_EVENT_MASK,
            le_event_mask: DEFAULT_LE_EVENT_MASK,
            host_acl_len: DEFAULT_HOST_ACL_LEN,
            next_handle: 0x0001,
            le: LeState::default(),
            bredr: BrEdrState::default(),
            attacks: Vec::new(),
        }
    }

    /// Back to the state after power-up: settings, masks and procedures forgotten.
    pub fn reset(&mut self) {
        self.random_address = None;
        self.event_mask = DEFAULT_EVENT_MASK;
        self.le_event_mask = DEFAULT_LE_EVENT_MASK;
        self.host_acl_len = DEFAULT_HOST_ACL_LEN;
        self.le = LeState::default();
        self.bredr = BrEdrState::default();
    }

    /// Whether this event reaches the host (Command Complete, Command Status,
    /// Number of Completed Packets and vendor events cannot be masked).
    fn event_enabled(&self, code: u8) -> bool {
        match code {
            EV_COMMAND_COMPLETE
            | EV_COMMAND_STATUS
            | EV_NUMBER_OF_COMPLETED_PACKETS
            | EV_VENDOR => true,
            1..=64 => self.event_mask & (1 << (code - 1)) != 0,
            _ => true,
        }
    }

    fn le_event_enabled(&self, subevent: u8) -> bool {
        self.event_enabled(EV_LE_META)
            && (1..=64).contains(&subevent)
            && self.le_event_mask & (1 << (subevent - 1)) != 0
    }

    pub fn ble_pad(&mut self) -> Option<&mut BlePadState> {
        match &mut self.kind {
            DeviceKind::BlePad(pad) => Some(pad),
            _ => None,
        }
    }

    pub fn ps_pad(&mut self) -> Option<&mut PsPad> {
        match &mut self.kind {
            DeviceKind::PlayStation(pad) => Some(pad),
            _ => None,
        }
    }

    /// On, in range, and (for the robot) with a host.
    pub fn on_air(&self) -> bool {
        self.powered && self.in_range
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkKind {
    Le,
    BrEdr,
}

/// Where a Classic authentication stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Auth {
    None,
    /// Link Key Request sent to the robot's host.
    KeyRequested,
    /// Secure Simple Pairing: IO Capability Request sent.
    IoCapability,
    /// Secure Simple Pairing: User Confirmation Request sent.
    Confirmation,
    Done,
}

/// A link between the robot's controller and a pad.
pub struct Link {
    pub kind: LinkKind,
    /// The robot controller's power-up this link belongs to.
    pub robot_generation: u32,
    pub robot_handle: u16,
    pub pad: DeviceId,
    /// The handle on the pad's controller (a BLE pad's host sees it).
    pub pad_handle: u16,
    pub robot_central: bool,
    /// LE: the connection interval; BR/EDR: a slot pair.
    pub interval: Duration,
    pub anchor: Instant,
    pub supervision: Duration,
    /// Out of range (or powered off) since: nothing passes; after the supervision
    /// timeout the link is gone.
    pub lost_since: Option<Instant>,
    /// Data that waited while the link was lost.
    pub held: Vec<(DeviceId, u8, Vec<u8>)>,
    /// LE: the central's key while the peripheral's host is asked for its own.
    pub le_key: Option<[u8; 16]>,
    pub encrypted: bool,
    pub auth: Auth,
    /// BR/EDR: the key both sides proved to hold.
    pub link_key: Option<[u8; 16]>,
    /// The robot's L2CAP frame from the pad's end, reassembled (PlayStation pads).
    pub to_pad: Vec<u8>,
}

impl Link {
    /// The handle of this link on `device`'s controller.
    pub fn handle_on(&self, device: DeviceId) -> u16 {
        if device == ROBOT {
            self.robot_handle
        } else {
            self.pad_handle
        }
    }

    /// The other end of the link from `device`.
    pub fn peer_of(&self, device: DeviceId) -> DeviceId {
        if device == ROBOT { self.pad } else { ROBOT }
    }

    /// The next moment data can cross: the next connection event.
    pub fn next_event(&self, now: Instant) -> Instant {
        if now <= self.anchor {
            return self.anchor;
        }
        let interval = self.interval.as_ticks().max(1);
        let since = (now - self.anchor).as_ticks();
        self.anchor + Duration::from_ticks(since.div_ceil(interval) * interval)
    }
}

/// Something due at a time.
#[derive(Debug, Clone)]
pub enum Action {
    /// An H4 packet for a device's host (dropped if that port is gone).
    ToHost {
        device: DeviceId,
        generation: u32,
        packet: Vec<u8>,
    },
    /// An ACL packet of `from`'s host (or pad) crossing the link.
    LinkData {
        link: LinkId,
        from: DeviceId,
        boundary: u8,
        data: Vec<u8>,
    },
    /// A pad's advertising event.
    Advertise {
        device: DeviceId,
        epoch: u64,
    },
    /// The link has been lost since `since`: if it still is, it is gone.
    Supervision {
        link: LinkId,
        since: Instant,
    },
    /// The robot's page of `page` ends: connected, or timed out.
    PageEnd {
        page: u64,
        target: [u8; 6],
    },
    /// A PlayStation pad's page reaches the robot (or times out).
    PadPage {
        pad: DeviceId,
        attempt: u64,
    },
    /// A PlayStation pad pages again after a failed page.
    PadPageStart {
        pad: DeviceId,
        attempt: u64,
    },
    /// Set Connection Encryption is carried out.
    ClassicEncryption {
        link: LinkId,
        enable: bool,
    },
    /// The robot's host did not answer a Connection Request in time.
    AcceptTimeout {
        pad: DeviceId,
        request: u64,
    },
    /// A discoverable pad answers the robot's inquiry.
    InquiryAnswer {
        inquiry: u64,
        pad: DeviceId,
    },
    InquiryEnd {
        inquiry: u64,
    },
    /// A PlayStation pad's report period.
    Report {
        pad: DeviceId,
        epoch: u64,
    },
    /// Authentication of a Classic link by link key: the answer of the pad's side.
    LinkKeyChecked {
        link: LinkId,
        key: [u8; 16],
    },
    /// The LE peripheral's host is asked for its key.
    LtkRequest {
        link: LinkId,
        rand: [u8; 8],
        ediv: u16,
    },
    /// The LE peripheral's host answered: compare the keys.
    LtkAnswer {
        link: LinkId,
        key: Option<[u8; 16]>,
    },
    /// An LE connection parameter update takes effect.
    ConnectionUpdate {
        link: LinkId,
        interval: Duration,
        latency: u16,
        supervision: Duration,
    },
    /// The link ends: each side hears its reason.
    LinkEnd {
        link: LinkId,
        robot_reason: u8,
        pad_reason: u8,
    },
}

/// What the air counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AirCounters {
    pub commands: u64,
    /// Bytes from a host that began no packet.
    pub garbage: u32,
    /// ACL packets for a handle that is no link.
    pub stray_acl: u32,
    pub acl_delivered: u64,
    pub reports_sent: u64,
}

pub struct AirState {
    pub rng: Rng,
    pub devices: Vec<Device>,
    pub links: BTreeMap<LinkId, Link>,
    next_link: LinkId,
    schedule: BTreeMap<(u64, u64), Action>,
    sequence: u64,
    pub log: Vec<AirEvent>,
    /// Whoever waits for the next event ([`super::Air::wait_for`]).
    pub log_watchers: Vec<Waker>,
    /// The schedule's runner, woken when something new is due.
    runner: Option<Waker>,
    kicked: bool,
    pub counters: AirCounters,
    /// Numbers for pages, inquiries, requests and epochs.
    pub serial: u64,
}

impl AirState {
    pub fn new(seed: u64, robot_address: [u8; 6]) -> Self {
        let mut robot = Device::new("robot", DeviceKind::Robot, robot_address);
        robot.powered = false;
        Self {
            rng: Rng::new(seed),
            devices: vec![robot],
            links: BTreeMap::new(),
            next_link: 1,
            schedule: BTreeMap::new(),
            sequence: 0,
            log: Vec::new(),
            log_watchers: Vec::new(),
            runner: None,
            kicked: false,
            counters: AirCounters::default(),
            serial: 0,
        }
    }

    pub fn now() -> Instant {
        Instant::now()
    }

    pub fn fresh(&mut self) -> u64 {
        self.serial += 1;
        self.serial
    }

    // ---------------------------------------------------------------- the schedule

    pub fn at(&mut self, when: Instant, action: Action) {
        self.sequence += 1;
        self.schedule
            .insert((when.as_ticks(), self.sequence), action);
        self.kick();
    }

    pub fn after(&mut self, delay: Duration, action: Action) {
        self.at(Self::now() + delay, action);
    }

    fn kick(&mut self) {
        self.kicked = true;
        if let Some(waker) = self.runner.take() {
            waker.wake();
        }
    }

    /// Whether something new was scheduled since the runner last looked; else
    /// remembers the runner's waker.
    pub fn take_kick(&mut self, waker: &Waker) -> bool {
        if std::mem::take(&mut self.kicked) {
            return true;
        }
        self.runner = Some(waker.clone());
        false
    }

    /// Does everything due by now; returns when the next thing is due.
    pub fn run_due(&mut self) -> Option<Instant> {
        let now = Self::now().as_ticks();
        loop {
            let (&key, _) = self.schedule.first_key_value()?;
            if key.0 > now {
                return Some(Instant::from_ticks(key.0));
            }
            let action = self.schedule.remove(&key).expect("first key");
            self.perform(action);
        }
    }

    fn perform(&mut self, action: Action) {
        match action {
            Action::ToHost {
                device,
                generation,
                packet,
            } => {
                if let Some(port) = self.port(device, generation) {
                    port.send(&packet);
                }
            }
            Action::LinkData {
                link,
                from,
                boundary,
                data,
            } => self.deliver(link, from, boundary, data),
            Action::Advertise { device, epoch } => self.advertising_event(device, epoch),
            Action::Supervision { link, since } => {
                if self
                    .links
                    .get(&link)
                    .is_some_and(|l| l.lost_since == Some(since))
                {
                    self.end_link(link, CONNECTION_TIMEOUT, CONNECTION_TIMEOUT);
                }
            }
            Action::PageEnd { page, target } => self.page_end(page, target),
            Action::PadPage { pad, attempt } => self.pad_page_arrives(pad, attempt),
            Action::PadPageStart { pad, attempt } => self.pad_page_start(pad, attempt),
            Action::ClassicEncryption { link, enable } => self.classic_encryption(link, enable),
            Action::AcceptTimeout { pad, request } => self.accept_timeout(pad, request),
            Action::InquiryAnswer { inquiry, pad } => self.inquiry_answer(inquiry, pad),
            Action::InquiryEnd { inquiry } => self.inquiry_end(inquiry),
            Action::Report { pad, epoch } => self.report_due(pad, epoch),
            Action::LinkKeyChecked { link, key } => self.link_key_checked(link, key),
            Action::LtkRequest { link, rand, ediv } => self.ltk_request(link, rand, ediv),
            Action::LtkAnswer { link, key } => self.ltk_answer(link, key),
            Action::ConnectionUpdate {
                link,
                interval,
                latency,
                supervision,
            } => self.connection_updated(link, interval, latency, supervision),
            Action::LinkEnd {
                link,
                robot_reason,
                pad_reason,
            } => self.close_link(link, robot_reason, pad_reason),
        }
    }

    // ---------------------------------------------------------------- ports and events

    pub fn port(&mut self, device: DeviceId, generation: u32) -> Option<&mut HostPort> {
        let device = self.devices.get_mut(device)?;
        if device.generation != generation {
            return None;
        }
        device.port.as_mut()
    }

    /// An event packet (H4) for `device`'s host, or `None` if its mask keeps it.
    pub fn event_packet(&self, device: DeviceId, code: u8, params: &[u8]) -> Option<Vec<u8>> {
        if !self.devices[device].event_enabled(code) {
            return None;
        }
        let mut packet = vec![H4_EVENT, code, params.len() as u8];
        packet.extend_from_slice(params);
        Some(packet)
    }

    /// Sends an event to `device`'s host now.
    pub fn event_now(&mut self, device: DeviceId, code: u8, params: &[u8]) {
        if let Some(packet) = self.event_packet(device, code, params) {
            let generation = self.devices[device].generation;
            if let Some(port) = self.port(device, generation) {
                port.send(&packet);
            }
        }
    }

    /// Sends an event to `device`'s host after `delay`.
    pub fn event_after(&mut self, delay: Duration, device: DeviceId, code: u8, params: &[u8]) {
        self.event_at(Self::now() + delay, device, code, params);
    }

    pub fn event_at(&mut self, when: Instant, device: DeviceId, code: u8, params: &[u8]) {
        if let Some(packet) = self.event_packet(device, code, params) {
            let generation = self.devices[device].generation;
            self.at(
                when,
                Action::ToHost {
                    device,
                    generation,
                    packet,
                },
            );
        }
    }

    /// An LE meta event after `delay` (or now), if both masks let it through.
    pub fn le_event_at(&mut self, when: Instant, device: DeviceId, subevent: u8, params: &[u8]) {
        if !self.devices[device].le_event_enabled(subevent) {
            return;
        }
        let mut meta = vec![subevent];
        meta.extend_from_slice(params);
        self.event_at(when, device, EV_LE_META, &meta);
    }

    pub fn command_complete(&mut self, device: DeviceId, opcode: u16, status: u8, rest: &[u8]) {
        let mut params = vec![1];
        params.extend_from_slice(&opcode.to_le_bytes());
        params.push(status);
        params.extend_from_slice(rest);
        self.event_now(device, EV_COMMAND_COMPLETE, &params);
    }

    pub fn command_status(&mut self, device: DeviceId, opcode: u16, status: u8) {
        let [lo, hi] = opcode.to_le_bytes();
        self.event_now(device, EV_COMMAND_STATUS, &[status, 1, lo, hi]);
    }

    pub fn record(&mut self, device: DeviceId, event: PadEvent) {
        let pad = self.devices[device].name.clone();
        self.log.push(AirEvent {
            at: Self::now(),
            pad,
            event,
        });
        for watcher in self.log_watchers.drain(..) {
            watcher.wake();
        }
    }

    // ---------------------------------------------------------------- hosts

    /// Bytes from `device`'s host.
    pub fn host_bytes(&mut self, device: DeviceId, generation: u32, bytes: &[u8]) {
        let mut garbage = 0;
        let Some(port) = self.port(device, generation) else {
            return;
        };
        let packets = port.take_bytes(bytes, &mut garbage);
        self.counters.garbage += garbage;
        for packet in packets {
            match packet {
                FromHost::Command(opcode, params) => {
                    self.counters.commands += 1;
                    self.on_command(device, opcode, &params);
                }
                FromHost::Acl(handle, boundary, data) => {
                    self.on_host_acl(device, handle, boundary, data)
                }
            }
        }
    }

    fn on_command(&mut self, device: DeviceId, opcode: u16, params: &[u8]) {
        if self.le_command(device, opcode, params) || self.bredr_command(device, opcode, params) {
            return;
        }
        self.general_command(device, opcode, params);
    }

    /// The commands both kinds of controller take the same way.
    fn general_command(&mut self, device: DeviceId, opcode: u16, params: &[u8]) {
        match opcode {
            // Reset.
            0x0C03 => {
                self.reset(device);
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Set Event Mask.
            0x0C01 => {
                if let Some(mask) = params.get(..8) {
                    self.devices[device].event_mask =
                        u64::from_le_bytes(mask.try_into().expect("eight bytes"));
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Host Buffer Size: the host's ACL length.
            0x0C33 => {
                if let [lo, hi, ..] = *params {
                    self.devices[device].host_acl_len =
                        usize::from(u16::from_le_bytes([lo, hi])).max(27);
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Disconnect.
            0x0406 => {
                let (Some(handle), Some(&reason)) = (handle_at(params, 0), params.get(2)) else {
                    self.command_status(device, opcode, UNKNOWN_CONNECTION);
                    return;
                };
                match self.link_by_handle(device, handle) {
                    Some(link) => {
                        self.command_status(device, opcode, SUCCESS);
                        let when = self.link_moment(link);
                        let (robot_reason, pad_reason) = if device == ROBOT {
                            (LOCAL_HOST_TERMINATED, reason)
                        } else {
                            (reason, LOCAL_HOST_TERMINATED)
                        };
                        self.at(
                            when,
                            Action::LinkEnd {
                                link,
                                robot_reason,
                                pad_reason,
                            },
                        );
                    }
                    None => self.command_status(device, opcode, UNKNOWN_CONNECTION),
                }
            }
            // Read BD_ADDR.
            0x1009 => {
                let address = self.devices[device].public_address;
                self.command_complete(device, opcode, SUCCESS, &address);
            }
            // Read Local Version Information: Bluetooth 5.3.
            0x1001 => self.command_complete(
                device,
                opcode,
                SUCCESS,
                &[0x0C, 0, 0, 0x0C, 0xFF, 0xFF, 0, 0],
            ),
            // Read Local Supported Commands: all of them.
            0x1002 => self.command_complete(device, opcode, SUCCESS, &[0xFF; 64]),
            // Read Local Supported Features.
            0x1003 => self.command_complete(device, opcode, SUCCESS, &[0; 8]),
            // Read RSSI.
            0x1405 => {
                let handle = handle_at(params, 0).unwrap_or(0);
                let [lo, hi] = handle.to_le_bytes();
                self.command_complete(device, opcode, SUCCESS, &[lo, hi, 0xC4]);
            }
            // Everything else a host sets up (event mask page 2, timeouts, policies,
            // resolving lists...) simply succeeds.
            _ => self.command_complete(device, opcode, SUCCESS, &[]),
        }
    }

    /// HCI Reset: every link of the device is gone without a word to the peer, who
    /// sees its supervision timeout; every setting is back to its default.
    fn reset(&mut self, device: DeviceId) {
        let links: Vec<LinkId> = self.links_of(device);
        for link in links {
            self.abandon(link, device);
        }
        self.devices[device].reset();
    }

    /// `device` forgets `link` at once (a reset, a power cut): the peer hears nothing
    /// and times out.
    pub fn abandon(&mut self, link: LinkId, device: DeviceId) {
        let Some(gone) = self.links.remove(&link) else {
            return;
        };
        // Lost already (out of range): the peer's timer runs since then.
        let lost = gone.lost_since.unwrap_or_else(Self::now);
        let supervision = gone.supervision;
        // The peer's side of the link lives on until its timeout: keep a shell of it
        // that only times out.
        let id = link;
        let mut shell = gone;
        shell.lost_since = Some(lost);
        shell.held.clear();
        if device == ROBOT {
            // The robot's side forgot it: only the pad hears the timeout.
            shell.robot_generation = u32::MAX;
        } else {
            shell.pad = usize::MAX;
        }
        self.links.insert(id, shell);
        self.at(
            lost + supervision,
            Action::Supervision {
                link: id,
                since: lost,
            },
        );
        if device != ROBOT {
            self.pad_link_gone(device, link, None);
        }
    }

    pub fn new_link_id(&mut self) -> LinkId {
        let id = self.next_link;
        self.next_link += 1;
        id
    }

    pub fn links_of(&self, device: DeviceId) -> Vec<LinkId> {
        self.links
            .iter()
            .filter(|(_, link)| {
                if device == ROBOT {
                    link.robot_generation == self.devices[ROBOT].generation
                } else {
                    link.pad == device
                }
            })
            .map(|(id, _)| *id)
            .collect()
    }

    pub fn link_by_handle(&self, device: DeviceId, handle: u16) -> Option<LinkId> {
        self.links_of(device)
            .into_iter()
            .find(|id| self.links[id].handle_on(device) == handle)
    }

    /// A handle free on `device`'s controller.
    pub fn new_handle(&mut self, device: DeviceId) -> u16 {
        loop {
            let handle = self.devices[device].next_handle;
            self.devices[device].next_handle = if handle >= 0x0EFF { 0x0001 } else { handle + 1 };
            if self.link_by_handle(device, handle).is_none() {
                return handle;
            }
        }
    }

    /// When something sent on `link` now arrives: the next connection event (LE), the
    /// next slot pair (BR/EDR).
    pub fn link_moment(&self, link: LinkId) -> Instant {
        let now = Self::now();
        self.links
            .get(&link)
            .map_or(now, |link| link.next_event(now))
    }

    fn on_host_acl(&mut self, device: DeviceId, handle: u16, boundary: u8, data: Vec<u8>) {
        let Some(link) = self.link_by_handle(device, handle) else {
            self.counters.stray_acl += 1;
            return;
        };
        self.send_on_link(link, device, boundary, data);
    }

    /// Data of `from` onto `link`: it crosses at the next moment the link allows.
    pub fn send_on_link(&mut self, link: LinkId, from: DeviceId, boundary: u8, data: Vec<u8>) {
        let when = self.link_moment(link);
        self.at(
            when,
            Action::LinkData {
                link,
                from,
                boundary,
                data,
            },
        );
    }

    /// An L2CAP frame from a pad (its own, or one a test injects): cut to the robot
    /// host's ACL length, as a controller hands data up.
    pub fn send_frame_to_robot(&mut self, link: LinkId, pad: DeviceId, frame: &[u8]) {
        let piece = self.devices[ROBOT].host_acl_len.max(1);
        for (index, chunk) in frame.chunks(piece).enumerate() {
            let boundary = if index == 0 { 0b10 } else { 0b01 };
            self.send_on_link(link, pad, boundary, chunk.to_vec());
        }
    }

    fn deliver(&mut self, link_id: LinkId, from: DeviceId, boundary: u8, data: Vec<u8>) {
        let Some(link) = self.links.get_mut(&link_id) else {
            return;
        };
        if link.lost_since.is_some() {
            link.held.push((from, boundary, data));
            return;
        }
        let to = link.peer_of(from);
        let to_handle = link.handle_on(to);
        let from_handle = link.handle_on(from);
        let robot_generation = link.robot_generation;
        self.counters.acl_delivered += 1;
        // A host's first fragment (non-flushable or not) reaches the other host as the
        // start of a frame; a continuation stays one.
        let boundary_up = if boundary == 0b01 { 0b01 } else { 0b10 };
        if matches!(self.devices[to].kind, DeviceKind::PlayStation(_)) {
            self.deliver_to_playstation(link_id, to, boundary_up, &data);
        } else {
            {
                let generation = if to == ROBOT {
                    robot_generation
                } else {
                    self.devices[to].generation
                };
                let mut packet = vec![H4_ACL];
                let header = to_handle | (u16::from(boundary_up) << 12);
                packet.extend_from_slice(&header.to_le_bytes());
                packet.extend_from_slice(&(data.len() as u16).to_le_bytes());
                packet.extend_from_slice(&data);
                if let Some(port) = self.port(to, generation) {
                    port.send(&packet);
                }
            }
        }
        // The sender's buffer is free again.
        if !matches!(self.devices[from].kind, DeviceKind::PlayStation(_)) {
            let [lo, hi] = from_handle.to_le_bytes();
            let generation = if from == ROBOT {
                robot_generation
            } else {
                self.devices[from].generation
            };
            if self.devices[from].generation == generation {
                self.event_now(from, EV_NUMBER_OF_COMPLETED_PACKETS, &[1, lo, hi, 1, 0]);
            }
        }
    }

    /// Robot data for a PlayStation pad: reassembled into L2CAP frames for the pad.
    fn deliver_to_playstation(
        &mut self,
        link_id: LinkId,
        pad: DeviceId,
        boundary: u8,
        data: &[u8],
    ) {
        let Some(link) = self.links.get_mut(&link_id) else {
            return;
        };
        if boundary != 0b01 {
            link.to_pad.clear();
        }
        link.to_pad.extend_from_slice(data);
        let expected = match link.to_pad.as_slice() {
            [lo, hi, ..] => 4 + usize::from(u16::from_le_bytes([*lo, *hi])),
            _ => return,
        };
        if link.to_pad.len() < expected {
            return;
        }
        let frame = std::mem::take(&mut link.to_pad);
        let out = match self.devices[pad].ps_pad() {
            Some(ps) => ps.on_frame(&frame),
            None => return,
        };
        self.pad_outputs(pad, link_id, out);
    }

    /// Carries out what a PlayStation pad asked for.
    pub fn pad_outputs(&mut self, pad: DeviceId, link: LinkId, outputs: Vec<PadOut>) {
        for output in outputs {
            match output {
                PadOut::Frame(frame) => self.send_frame_to_robot(link, pad, &frame),
                PadOut::Log(event) => self.record(pad, event),
                PadOut::StartStreaming => self.start_streaming(pad),
            }
        }
    }

    /// The pad's attack-on-connect frames go out on its new link at once.
    pub fn attack_on_connect(&mut self, pad: DeviceId, link: LinkId) {
        let frames = self.devices[pad].attacks.clone();
        for frame in frames {
            self.send_frame_to_robot(link, pad, &frame);
        }
    }

    // ---------------------------------------------------------------- links ending

    /// One side closes the link (its reason to itself is "terminated by local host").
    /// Over a lost link the other side hears nothing: it times out.
    fn close_link(&mut self, link_id: LinkId, robot_reason: u8, pad_reason: u8) {
        let Some(link) = self.links.get(&link_id) else {
            return;
        };
        if link.lost_since.is_none() {
            self.end_link(link_id, robot_reason, pad_reason);
            return;
        }
        let (robot_handle, pad, pad_handle) = (link.robot_handle, link.pad, link.pad_handle);
        if robot_reason == LOCAL_HOST_TERMINATED {
            let [lo, hi] = robot_handle.to_le_bytes();
            self.event_now(
                ROBOT,
                EV_DISCONNECTION_COMPLETE,
                &[SUCCESS, lo, hi, robot_reason],
            );
            self.abandon(link_id, ROBOT);
        } else {
            let [lo, hi] = pad_handle.to_le_bytes();
            self.event_now(
                pad,
                EV_DISCONNECTION_COMPLETE,
                &[SUCCESS, lo, hi, pad_reason],
            );
            self.abandon(link_id, pad);
        }
    }

    /// The link is gone: each side's host (or pad) hears its reason.
    pub fn end_link(&mut self, link_id: LinkId, robot_reason: u8, pad_reason: u8) {
        let Some(link) = self.links.remove(&link_id) else {
            return;
        };
        if link.robot_generation == self.devices[ROBOT].generation {
            let [lo, hi] = link.robot_handle.to_le_bytes();
            self.event_now(
                ROBOT,
                EV_DISCONNECTION_COMPLETE,
                &[SUCCESS, lo, hi, robot_reason],
            );
        }
        if link.pad != usize::MAX {
            let [lo, hi] = link.pad_handle.to_le_bytes();
            self.event_now(
                link.pad,
                EV_DISCONNECTION_COMPLETE,
                &[SUCCESS, lo, hi, pad_reason],
            );
            self.pad_link_gone(link.pad, link_id, Some(pad_reason));
        }
    }

    /// A pad's end of a link is gone (`reason` as the pad heard it; `None`: the pad
    /// itself dropped it).
    fn pad_link_gone(&mut self, pad: DeviceId, link: LinkId, reason: Option<u8>) {
        self.record(
            pad,
            PadEvent::Disconnected(reason.unwrap_or(LOCAL_HOST_TERMINATED)),
        );
        let page_again = self.devices[pad]
            .ps_pad()
            .is_some_and(|ps| ps.on_disconnected(link, reason));
        if page_again {
            self.start_paging(pad);
        }
        if let Some(ble) = self.devices[pad].ble_pad() {
            ble.poke();
        }
    }

    /// `device` goes out of range (or loses power): its links stop carrying anything,
    /// and time out unless it is back in time.
    pub fn leave(&mut self, device: DeviceId) {
        let now = Self::now();
        for link in self.links_of(device) {
            let link_ref = self.links.get_mut(&link).expect("listed");
            if link_ref.lost_since.is_none() {
                link_ref.lost_since = Some(now);
                let supervision = link_ref.supervision;
                self.at(now + supervision, Action::Supervision { link, since: now });
            }
        }
    }

    /// `device` is back in range: links not yet timed out carry on, with what waited.
    pub fn come_back(&mut self, device: DeviceId) {
        for link in self.links_of(device) {
            let held = {
                let link_ref = self.links.get_mut(&link).expect("listed");
                link_ref.lost_since = None;
                std::mem::take(&mut link_ref.held)
            };
            for (from, boundary, data) in held {
                self.send_on_link(link, from, boundary, data);
            }
        }
    }
}

impl BlePadState {
    pub fn poke(&mut self) {
        self.poked = true;
        if let Some(waker) = self.waker.take() {
            waker.wake();
        }
    }
}

/// A connection handle at `offset` of command parameters.
pub fn handle_at(params: &[u8], offset: usize) -> Option<u16> {
    let bytes = params.get(offset..offset + 2)?;
    Some(u16::from_le_bytes([bytes[0], bytes[1]]) & 0x0FFF)
}

/// A device address at `offset`.
pub fn address_at(params: &[u8], offset: usize) -> Option<[u8; 6]> {
    params.get(offset..offset + 6)?.try_into().ok()
}

/// A duration in units of `unit_us` µs (1.25 ms intervals, 10 ms timeouts, 0.625 ms
/// slots).
pub fn units(params: &[u8], offset: usize, unit_us: u64) -> Option<Duration> {
    let bytes = params.get(offset..offset + 2)?;
    Some(Duration::from_micros(
        u64::from(u16::from_le_bytes([bytes[0], bytes[1]])) * unit_us,
    ))
}

/// A duration in units of `unit_us` µs as two bytes.
pub fn to_units(duration: Duration, unit_us: u64) -> [u8; 2] {
    ((duration.as_micros() / unit_us) as u16).to_le_bytes()
}
