//! The BR/EDR half of the robot's controller, and the PlayStation pads' side of it:
//! inquiry, paging both ways, accepting and rejecting, role switch, authentication by
//! link key (the two sides' stored keys are compared rather than challenged), Secure
//! Simple Pairing Just Works, encryption, the link supervision timeout, and the pads'
//! report stream.

use embassy_time::{Duration, Instant};

use super::PadEvent;
use super::state::{
    AUTHENTICATION_FAILURE, Action, AirState, Auth, COMMAND_DISALLOWED, CONNECTION_ACCEPT_TIMEOUT,
    DeviceId, EV_AUTHENTICATION_COMPLETE, EV_CONNECTION_COMPLETE, EV_CONNECTION_REQUEST,
    EV_ENCRYPTION_CHANGE, EV_INQUIRY_COMPLETE, EV_INQUIRY_RESULT, EV_IO_CAPABILITY_REQUEST,
    EV_IO_CAPABILITY_RESPONSE, EV_LINK_KEY_NOTIFICATION, EV_LINK_KEY_REQUEST, EV_ROLE_CHANGE,
    EV_SIMPLE_PAIRING_COMPLETE, EV_USER_CONFIRMATION_REQUEST, EV_VENDOR, INSUFFICIENT_SECURITY,
    Link, LinkId, LinkKind, PAGE_TIMEOUT, PAIRING_NOT_ALLOWED, PIN_OR_KEY_MISSING, ROBOT, SUCCESS,
    UNKNOWN_CONNECTION, address_at, handle_at,
};

/// One slot pair: how long data takes across a BR/EDR link.
const SLOT_PAIR: Duration = Duration::from_micros(1_250);
/// An LMP exchange (role switch, authentication, encryption) takes about this long.
const LMP_EXCHANGE: Duration = Duration::from_millis(5);
/// A page that finds a scanning device takes between these (R1 page scan).
const PAGE_TIME_MS: (u64, u64) = (10, 640);
/// How long a pad waits for the robot to answer its page before it gives up: the
/// specification's default page timeout, 5.12 s.
const PAD_PAGE_TIMEOUT: Duration = Duration::from_millis(5_120);
/// The robot's host must accept or reject a Connection Request within this (the
/// default Connection Accept Timeout, 5 s).
const CONNECTION_ACCEPT_TIMEOUT_AFTER: Duration = Duration::from_secs(5);
/// A pad that is switched on pages its host this many times at most, a second apart.
pub const PAD_PAGE_ATTEMPTS: u32 = 10;
const PAD_PAGE_RETRY: Duration = Duration::from_secs(1);
/// The default link supervision timeout (20 s) until the central sets one.
const DEFAULT_SUPERVISION: Duration = Duration::from_secs(20);
/// The ESP32 controller's vendor event subcode for an authentication by link key.
const VENDOR_LEGACY_AUTHENTICATION: u8 = 0x03;
/// The pads' class of device: peripheral, gamepad, limited discoverable.
pub const GAMEPAD_CLASS: u32 = 0x00_2508;
/// ACL link type in Connection Complete and Connection Request.
const ACL_LINK: u8 = 0x01;

impl AirState {
    /// A BR/EDR command of the robot's controller, if `opcode` is one.
    pub(super) fn bredr_command(&mut self, device: DeviceId, opcode: u16, params: &[u8]) -> bool {
        if device != ROBOT {
            return false;
        }
        match opcode {
            // Read Buffer Size: 1021-byte ACL packets (3-DH5), eight of them, no SCO.
            0x1005 => self.command_complete(device, opcode, SUCCESS, &[0xFD, 0x03, 0, 8, 0, 0, 0]),
            // Write Class of Device.
            0x0C24 => {
                if let Some(class) = params.get(..3) {
                    self.devices[device].bredr.class_of_device =
                        u32::from_le_bytes([class[0], class[1], class[2], 0]);
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Write Page Timeout.
            0x0C18 => {
                if let [lo, hi, ..] = *params {
                    self.devices[device].bredr.page_timeout_slots = u16::from_le_bytes([lo, hi]);
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Write Scan Enable.
            0x0C1A => {
                self.devices[device].bredr.scan_enable = params.first().copied().unwrap_or(0);
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Write Link Supervision Timeout.
            0x0C37 => {
                let handle = handle_at(params, 0).unwrap_or(0);
                let link = self.link_by_handle(device, handle);
                let status = match (link, handle_at(params, 2)) {
                    (Some(link), Some(slots)) => {
                        let link = self.links.get_mut(&link).expect("found");
                        if link.robot_central {
                            link.supervision = Duration::from_micros(u64::from(slots) * 625);
                            SUCCESS
                        } else {
                            COMMAND_DISALLOWED
                        }
                    }
                    _ => UNKNOWN_CONNECTION,
                };
                self.command_complete(device, opcode, status, &handle.to_le_bytes());
            }
            // Inquiry.
            0x0401 => self.inquiry(opcode, params),
            // Inquiry Cancel.
            0x0402 => {
                self.devices[ROBOT].bredr.inquiry = None;
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // Create Connection.
            0x0405 => self.page(opcode, params),
            // Create Connection Cancel.
            0x0408 => {
                let address = address_at(params, 0).unwrap_or_default();
                let pages = &mut self.devices[ROBOT].bredr.pages;
                let pending = pages.iter().position(|(paged, _)| *paged == address);
                let status = if pending.is_some() {
                    SUCCESS
                } else {
                    UNKNOWN_CONNECTION
                };
                if let Some(index) = pending {
                    pages.remove(index);
                }
                self.command_complete(device, opcode, status, &address);
                if pending.is_some() {
                    self.connection_complete(UNKNOWN_CONNECTION, 0, address, Self::now());
                }
            }
            // Accept / Reject Connection Request.
            0x0409 => self.accept(opcode, params),
            0x040A => self.reject(opcode, params),
            // Link Key Request Reply / Negative Reply.
            0x040B => self.link_key_reply(opcode, params),
            0x040C => {
                let address = address_at(params, 0).unwrap_or_default();
                self.command_complete(device, opcode, SUCCESS, &address);
                if let Some(link) = self.classic_link_to(address, Auth::KeyRequested) {
                    // No key: Secure Simple Pairing.
                    self.links.get_mut(&link).expect("found").auth = Auth::IoCapability;
                    self.event_after(SLOT_PAIR, ROBOT, EV_IO_CAPABILITY_REQUEST, &address);
                }
            }
            // PIN Code Request Negative Reply.
            0x040E => {
                let address = address_at(params, 0).unwrap_or_default();
                self.command_complete(device, opcode, SUCCESS, &address);
            }
            // Authentication Requested.
            0x0411 => match handle_at(params, 0).and_then(|h| self.link_by_handle(device, h)) {
                Some(link) if self.links[&link].kind == LinkKind::BrEdr => {
                    self.command_status(device, opcode, SUCCESS);
                    self.links.get_mut(&link).expect("found").auth = Auth::KeyRequested;
                    let address = self.pad_address(self.links[&link].pad);
                    self.event_after(SLOT_PAIR, ROBOT, EV_LINK_KEY_REQUEST, &address);
                }
                _ => self.command_status(device, opcode, UNKNOWN_CONNECTION),
            },
            // Set Connection Encryption.
            0x0413 => match handle_at(params, 0).and_then(|h| self.link_by_handle(device, h)) {
                Some(link) if self.links[&link].kind == LinkKind::BrEdr => {
                    self.command_status(device, opcode, SUCCESS);
                    let enable = params.get(2) == Some(&1);
                    self.after(LMP_EXCHANGE, Action::ClassicEncryption { link, enable });
                }
                _ => self.command_status(device, opcode, UNKNOWN_CONNECTION),
            },
            // IO Capability Request Reply / Negative Reply.
            0x042B => self.io_capability_reply(opcode, params),
            0x0434 => {
                let address = address_at(params, 0).unwrap_or_default();
                let reason = params.get(6).copied().unwrap_or(PAIRING_NOT_ALLOWED);
                self.command_complete(device, opcode, SUCCESS, &address);
                if let Some(link) = self.classic_link_to(address, Auth::IoCapability) {
                    self.pairing_failed(link, reason);
                }
            }
            // User Confirmation Request Reply / Negative Reply.
            0x042C => self.user_confirmation(opcode, params),
            0x042D => {
                let address = address_at(params, 0).unwrap_or_default();
                self.command_complete(device, opcode, SUCCESS, &address);
                if let Some(link) = self.classic_link_to(address, Auth::Confirmation) {
                    self.pairing_failed(link, AUTHENTICATION_FAILURE);
                }
            }
            // Switch Role.
            0x080B => {
                let address = address_at(params, 0).unwrap_or_default();
                let role = params.get(6).copied().unwrap_or(0);
                match self.classic_link_by_address(address) {
                    Some(link) => {
                        self.command_status(device, opcode, SUCCESS);
                        self.links.get_mut(&link).expect("found").robot_central = role == 0;
                        let mut event = vec![SUCCESS];
                        event.extend_from_slice(&address);
                        event.push(role);
                        self.event_after(LMP_EXCHANGE, ROBOT, EV_ROLE_CHANGE, &event);
                    }
                    None => self.command_status(device, opcode, UNKNOWN_CONNECTION),
                }
            }
            _ => return false,
        }
        true
    }

    /// A PlayStation pad's address (on HCI, least significant byte first).
    pub(super) fn pad_address(&self, pad: DeviceId) -> [u8; 6] {
        self.devices[pad].public_address
    }

    fn classic_link_by_address(&self, address: [u8; 6]) -> Option<LinkId> {
        self.links_of(ROBOT).into_iter().find(|id| {
            let link = &self.links[id];
            link.kind == LinkKind::BrEdr && self.devices[link.pad].public_address == address
        })
    }

    /// The robot's Classic link to `address`, if its authentication is at `step`.
    fn classic_link_to(&self, address: [u8; 6], step: Auth) -> Option<LinkId> {
        self.classic_link_by_address(address)
            .filter(|id| self.links[id].auth == step)
    }

    /// The pad at `address` whose page scan would answer: on, in range, not connected.
    fn scanning_pad(&mut self, address: [u8; 6]) -> Option<DeviceId> {
        let pad = (1..self.devices.len()).find(|&id| {
            let device = &self.devices[id];
            device.public_address == address && device.on_air()
        })?;
        let on = self.devices[pad]
            .ps_pad()
            .is_some_and(|ps| ps.switched_on && ps.link.is_none());
        on.then_some(pad)
    }

    fn connection_complete(&mut self, status: u8, handle: u16, address: [u8; 6], when: Instant) {
        let mut event = vec![status];
        event.extend_from_slice(&handle.to_le_bytes());
        event.extend_from_slice(&address);
        event.extend_from_slice(&[ACL_LINK, 0]);
        self.event_at(when, ROBOT, EV_CONNECTION_COMPLETE, &event);
    }

    // ------------------------------------------------------------------ inquiry

    fn inquiry(&mut self, opcode: u16, params: &[u8]) {
        if self.devices[ROBOT].bredr.inquiry.is_some() {
            self.command_status(ROBOT, opcode, COMMAND_DISALLOWED);
            return;
        }
        self.command_status(ROBOT, opcode, SUCCESS);
        let id = self.fresh();
        self.devices[ROBOT].bredr.inquiry = Some(id);
        let length = Duration::from_millis(u64::from(params.get(3).copied().unwrap_or(1)) * 1_280);
        for pad in 1..self.devices.len() {
            if self.discoverable(pad) {
                let delay = self
                    .rng
                    .between(20, length.as_millis().clamp(21, 1_500) - 1);
                self.after(
                    Duration::from_millis(delay),
                    Action::InquiryAnswer { inquiry: id, pad },
                );
            }
        }
        self.after(length, Action::InquiryEnd { inquiry: id });
    }

    /// A pad in pairing mode answers inquiries.
    pub(super) fn discoverable(&mut self, pad: DeviceId) -> bool {
        self.devices[pad].on_air()
            && self.devices[pad]
                .ps_pad()
                .is_some_and(|ps| ps.switched_on && ps.pairing_mode && ps.link.is_none())
    }

    /// A pad just became discoverable: a running inquiry finds it too.
    pub(super) fn discoverable_now(&mut self, pad: DeviceId) {
        if let Some(inquiry) = self.devices[ROBOT].bredr.inquiry {
            let delay = self.rng.between(20, 500);
            self.after(
                Duration::from_millis(delay),
                Action::InquiryAnswer { inquiry, pad },
            );
        }
    }

    pub(super) fn inquiry_answer(&mut self, inquiry: u64, pad: DeviceId) {
        if self.devices[ROBOT].bredr.inquiry != Some(inquiry) || !self.discoverable(pad) {
            return;
        }
        let mut event = vec![1];
        event.extend_from_slice(&self.pad_address(pad));
        // Page scan repetition mode R1, two reserved bytes, class, clock offset.
        event.extend_from_slice(&[1, 0, 0]);
        event.extend_from_slice(&GAMEPAD_CLASS.to_le_bytes()[..3]);
        event.extend_from_slice(&[0, 0]);
        self.event_now(ROBOT, EV_INQUIRY_RESULT, &event);
    }

    pub(super) fn inquiry_end(&mut self, inquiry: u64) {
        if self.devices[ROBOT].bredr.inquiry == Some(inquiry) {
            self.devices[ROBOT].bredr.inquiry = None;
            self.event_now(ROBOT, EV_INQUIRY_COMPLETE, &[SUCCESS]);
        }
    }

    // ------------------------------------------------------------------ the robot pages

    fn page(&mut self, opcode: u16, params: &[u8]) {
        let Some(address) = address_at(params, 0) else {
            self.command_status(ROBOT, opcode, 0x12);
            return;
        };
        self.command_status(ROBOT, opcode, SUCCESS);
        let page = self.fresh();
        self.devices[ROBOT].bredr.pages.push((address, page));
        let delay = if self.scanning_pad(address).is_some() {
            Duration::from_millis(self.rng.between(PAGE_TIME_MS.0, PAGE_TIME_MS.1))
        } else {
            let slots = u64::from(self.devices[ROBOT].bredr.page_timeout_slots);
            Duration::from_micros(slots * 625)
        };
        self.after(
            delay,
            Action::PageEnd {
                page,
                target: address,
            },
        );
    }

    pub(super) fn page_end(&mut self, page: u64, address: [u8; 6]) {
        let pages = &mut self.devices[ROBOT].bredr.pages;
        let Some(index) = pages.iter().position(|(_, id)| *id == page) else {
            return;
        };
        pages.remove(index);
        match self.scanning_pad(address) {
            Some(pad) => {
                let link = self.new_classic_link(pad, true, Self::now());
                let handle = self.links[&link].robot_handle;
                self.connection_complete(SUCCESS, handle, address, Self::now());
                if let Some(ps) = self.devices[pad].ps_pad() {
                    ps.on_connected(link, false);
                }
                self.record(pad, PadEvent::Connected);
                self.attack_on_connect(pad, link);
            }
            None => self.connection_complete(PAGE_TIMEOUT, 0, address, Self::now()),
        }
    }

    fn new_classic_link(&mut self, pad: DeviceId, robot_central: bool, anchor: Instant) -> LinkId {
        let robot_handle = self.new_handle(ROBOT);
        let pad_handle = self.new_handle(pad);
        let id = self.new_link_id();
        self.links.insert(
            id,
            Link {
                kind: LinkKind::BrEdr,
                robot_generation: self.devices[ROBOT].generation,
                robot_handle,
                pad,
                pad_handle,
                robot_central,
                interval: SLOT_PAIR,
                anchor,
                supervision: DEFAULT_SUPERVISION,
                lost_since: None,
                held: Vec::new(),
                le_key: None,
                encrypted: false,
                auth: Auth::None,
                link_key: None,
                to_pad: Vec::new(),
            },
        );
        id
    }

    // ------------------------------------------------------------------ a pad pages

    /// The robot answers pages: its controller is up, with page scan on.
    fn robot_connectable(&self) -> bool {
        let robot = &self.devices[ROBOT];
        robot.on_air() && robot.port.is_some() && robot.bredr.scan_enable & 0x02 != 0
    }

    /// A switched-on pad with a bond pages the robot it bonded with.
    pub(super) fn start_paging(&mut self, pad: DeviceId) {
        let attempt = self.fresh();
        let robot_address = self.devices[ROBOT].public_address;
        let reachable = self.robot_connectable();
        let Some(ps) = self.devices[pad].ps_pad() else {
            return;
        };
        ps.paging = Some((attempt, Self::now()));
        let delay = if reachable && ps.pages(robot_address) {
            Duration::from_millis(self.rng.between(PAGE_TIME_MS.0, PAGE_TIME_MS.1))
        } else {
            PAD_PAGE_TIMEOUT
        };
        self.after(delay, Action::PadPage { pad, attempt });
    }

    pub(super) fn pad_page_arrives(&mut self, pad: DeviceId, attempt: u64) {
        let robot_address = self.devices[ROBOT].public_address;
        let reachable = self.robot_connectable() && self.devices[pad].on_air();
        let Some(ps) = self.devices[pad].ps_pad() else {
            return;
        };
        if ps.paging.map(|(id, _)| id) != Some(attempt) || !ps.switched_on || ps.link.is_some() {
            return;
        }
        if !(reachable && ps.pages(robot_address)) {
            ps.paging = None;
            self.record(pad, PadEvent::PageFailed(PAGE_TIMEOUT));
            self.page_again(pad);
            return;
        }
        let request = self.fresh();
        self.devices[ROBOT].bredr.requests.push((pad, request));
        let mut event = self.pad_address(pad).to_vec();
        event.extend_from_slice(&GAMEPAD_CLASS.to_le_bytes()[..3]);
        event.push(ACL_LINK);
        self.event_now(ROBOT, EV_CONNECTION_REQUEST, &event);
        self.after(
            CONNECTION_ACCEPT_TIMEOUT_AFTER,
            Action::AcceptTimeout { pad, request },
        );
    }

    /// After a failed page the pad tries again a second later, a few times.
    fn page_again(&mut self, pad: DeviceId) {
        let Some(ps) = self.devices[pad].ps_pad() else {
            return;
        };
        ps.page_attempts += 1;
        if ps.switched_on && ps.page_attempts < PAD_PAGE_ATTEMPTS {
            let attempt = self.fresh();
            let ps = self.devices[pad].ps_pad().expect("a pad");
            // The next page starts after the pause.
            ps.paging = Some((attempt, Self::now() + PAD_PAGE_RETRY));
            self.after(PAD_PAGE_RETRY, Action::PadPageStart { pad, attempt });
        }
    }

    pub(super) fn pad_page_start(&mut self, pad: DeviceId, attempt: u64) {
        let current = self.devices[pad].ps_pad().and_then(|ps| ps.paging);
        if current.map(|(id, _)| id) == Some(attempt) {
            self.start_paging(pad);
        }
    }

    fn take_request(&mut self, address: [u8; 6]) -> Option<DeviceId> {
        let requests = &self.devices[ROBOT].bredr.requests;
        let index = requests
            .iter()
            .position(|(pad, _)| self.devices[*pad].public_address == address)?;
        Some(self.devices[ROBOT].bredr.requests.remove(index).0)
    }

    fn accept(&mut self, opcode: u16, params: &[u8]) {
        let address = address_at(params, 0).unwrap_or_default();
        let Some(pad) = self.take_request(address) else {
            self.command_status(ROBOT, opcode, UNKNOWN_CONNECTION);
            return;
        };
        self.command_status(ROBOT, opcode, SUCCESS);
        let become_central = params.get(6) == Some(&0);
        let when = Self::now() + LMP_EXCHANGE;
        let link = self.new_classic_link(pad, become_central, when);
        let handle = self.links[&link].robot_handle;
        if become_central {
            let mut event = vec![SUCCESS];
            event.extend_from_slice(&address);
            event.push(0x00);
            self.event_at(when, ROBOT, EV_ROLE_CHANGE, &event);
        }
        self.connection_complete(SUCCESS, handle, address, when);
        if let Some(ps) = self.devices[pad].ps_pad() {
            ps.paging = None;
            ps.on_connected(link, true);
        }
        self.record(pad, PadEvent::Connected);
        self.attack_on_connect(pad, link);
    }

    fn reject(&mut self, opcode: u16, params: &[u8]) {
        let address = address_at(params, 0).unwrap_or_default();
        let reason = params.get(6).copied().unwrap_or(0x0F);
        let Some(pad) = self.take_request(address) else {
            self.command_status(ROBOT, opcode, UNKNOWN_CONNECTION);
            return;
        };
        self.command_status(ROBOT, opcode, SUCCESS);
        self.connection_complete(reason, 0, address, Self::now() + SLOT_PAIR);
        if let Some(ps) = self.devices[pad].ps_pad() {
            ps.paging = None;
        }
        self.record(pad, PadEvent::PageFailed(reason));
        self.page_again(pad);
    }

    pub(super) fn accept_timeout(&mut self, pad: DeviceId, request: u64) {
        let requests = &mut self.devices[ROBOT].bredr.requests;
        let Some(index) = requests.iter().position(|(_, id)| *id == request) else {
            return;
        };
        requests.remove(index);
        let address = self.pad_address(pad);
        self.connection_complete(CONNECTION_ACCEPT_TIMEOUT, 0, address, Self::now());
        if let Some(ps) = self.devices[pad].ps_pad() {
            ps.paging = None;
        }
        self.record(pad, PadEvent::PageFailed(CONNECTION_ACCEPT_TIMEOUT));
        self.page_again(pad);
    }

    // ------------------------------------------------------------------ security

    fn link_key_reply(&mut self, opcode: u16, params: &[u8]) {
        let address = address_at(params, 0).unwrap_or_default();
        self.command_complete(ROBOT, opcode, SUCCESS, &address);
        let key = params
            .get(6..22)
            .and_then(|key| <[u8; 16]>::try_from(key).ok());
        if let (Some(link), Some(key)) = (self.classic_link_to(address, Auth::KeyRequested), key) {
            self.after(LMP_EXCHANGE, Action::LinkKeyChecked { link, key });
        }
    }

    /// LMP's challenge and response, simplified: the pad's key for the robot is
    /// compared with the one the robot's host gave.
    pub(super) fn link_key_checked(&mut self, link_id: LinkId, key: [u8; 16]) {
        let Some(link) = self.links.get(&link_id) else {
            return;
        };
        if link.lost_since.is_some() || link.auth != Auth::KeyRequested {
            return;
        }
        let (pad, handle) = (link.pad, link.robot_handle);
        let robot_address = self.devices[ROBOT].public_address;
        let pad_key = self.devices[pad]
            .ps_pad()
            .and_then(|ps| ps.bond)
            .filter(|(host, _)| *host == robot_address)
            .map(|(_, key)| key);
        let status = match pad_key {
            Some(theirs) if theirs == key => SUCCESS,
            Some(_) => AUTHENTICATION_FAILURE,
            None => PIN_OR_KEY_MISSING,
        };
        let link = self.links.get_mut(&link_id).expect("found");
        let [lo, hi] = handle.to_le_bytes();
        if status == SUCCESS {
            link.auth = Auth::Done;
            link.link_key = Some(key);
            self.event_now(ROBOT, EV_AUTHENTICATION_COMPLETE, &[SUCCESS, lo, hi]);
            // The dual-mode ESP32's controller reports an authentication by link key
            // with its vendor event; the robot's hosts must take it in their stride.
            self.event_now(ROBOT, EV_VENDOR, &[VENDOR_LEGACY_AUTHENTICATION, lo, hi]);
        } else {
            link.auth = Auth::None;
            self.event_now(ROBOT, EV_AUTHENTICATION_COMPLETE, &[status, lo, hi]);
            self.record(pad, PadEvent::AuthenticationFailed(status));
        }
    }

    fn io_capability_reply(&mut self, opcode: u16, params: &[u8]) {
        let address = address_at(params, 0).unwrap_or_default();
        self.command_complete(ROBOT, opcode, SUCCESS, &address);
        let Some(link) = self.classic_link_to(address, Auth::IoCapability) else {
            return;
        };
        let pad = self.links[&link].pad;
        let pairing = self.devices[pad].ps_pad().is_some_and(|ps| ps.pairing_mode);
        if !pairing {
            // Outside its pairing mode the pad's own host refuses to pair.
            self.pairing_failed(link, PAIRING_NOT_ALLOWED);
            return;
        }
        self.links.get_mut(&link).expect("found").auth = Auth::Confirmation;
        // The pad has no input and no output: Just Works, general bonding.
        let mut response = address.to_vec();
        response.extend_from_slice(&[0x03, 0x00, 0x04]);
        self.event_after(LMP_EXCHANGE, ROBOT, EV_IO_CAPABILITY_RESPONSE, &response);
        let mut confirmation = address.to_vec();
        let number = (self.rng.next() % 1_000_000) as u32;
        confirmation.extend_from_slice(&number.to_le_bytes());
        self.event_after(
            LMP_EXCHANGE,
            ROBOT,
            EV_USER_CONFIRMATION_REQUEST,
            &confirmation,
        );
    }

    fn user_confirmation(&mut self, opcode: u16, params: &[u8]) {
        let address = address_at(params, 0).unwrap_or_default();
        self.command_complete(ROBOT, opcode, SUCCESS, &address);
        let Some(link_id) = self.classic_link_to(address, Auth::Confirmation) else {
            return;
        };
        let key: [u8; 16] = self.rng.bytes();
        let robot_address = self.devices[ROBOT].public_address;
        let link = self.links.get_mut(&link_id).expect("found");
        link.auth = Auth::Done;
        link.link_key = Some(key);
        let (pad, handle) = (link.pad, link.robot_handle);
        if let Some(ps) = self.devices[pad].ps_pad() {
            ps.bond = Some((robot_address, key));
            ps.pairing_mode = false;
        }
        let when = Self::now() + LMP_EXCHANGE;
        let mut complete = vec![SUCCESS];
        complete.extend_from_slice(&address);
        self.event_at(when, ROBOT, EV_SIMPLE_PAIRING_COMPLETE, &complete);
        let mut notification = address.to_vec();
        notification.extend_from_slice(&key);
        // Unauthenticated combination key (P-192).
        notification.push(0x04);
        self.event_at(when, ROBOT, EV_LINK_KEY_NOTIFICATION, &notification);
        let [lo, hi] = handle.to_le_bytes();
        self.event_at(when, ROBOT, EV_AUTHENTICATION_COMPLETE, &[SUCCESS, lo, hi]);
        self.record(pad, PadEvent::Paired);
    }

    fn pairing_failed(&mut self, link_id: LinkId, status: u8) {
        let link = self.links.get_mut(&link_id).expect("found");
        link.auth = Auth::None;
        let (pad, handle) = (link.pad, link.robot_handle);
        let address = self.pad_address(pad);
        let mut complete = vec![status];
        complete.extend_from_slice(&address);
        self.event_after(SLOT_PAIR, ROBOT, EV_SIMPLE_PAIRING_COMPLETE, &complete);
        let [lo, hi] = handle.to_le_bytes();
        self.event_after(
            SLOT_PAIR,
            ROBOT,
            EV_AUTHENTICATION_COMPLETE,
            &[status, lo, hi],
        );
        self.record(pad, PadEvent::AuthenticationFailed(status));
    }

    pub(super) fn classic_encryption(&mut self, link_id: LinkId, enable: bool) {
        let Some(link) = self.links.get_mut(&link_id) else {
            return;
        };
        let [lo, hi] = link.robot_handle.to_le_bytes();
        let pad = link.pad;
        if link.auth != Auth::Done {
            self.event_now(
                ROBOT,
                EV_ENCRYPTION_CHANGE,
                &[INSUFFICIENT_SECURITY, lo, hi, 0],
            );
            return;
        }
        link.encrypted = enable;
        self.event_now(
            ROBOT,
            EV_ENCRYPTION_CHANGE,
            &[SUCCESS, lo, hi, u8::from(enable)],
        );
        if enable {
            self.record(pad, PadEvent::Encrypted);
            let out = self.devices[pad]
                .ps_pad()
                .map(|ps| ps.on_encrypted())
                .unwrap_or_default();
            self.pad_outputs(pad, link_id, out);
        }
    }

    // ------------------------------------------------------------------ the stream

    pub(super) fn start_streaming(&mut self, pad: DeviceId) {
        let epoch = self.fresh();
        let Some(ps) = self.devices[pad].ps_pad() else {
            return;
        };
        if ps.stream_epoch != 0 {
            return;
        }
        ps.stream_epoch = epoch;
        let period = ps.report_period;
        self.after(period, Action::Report { pad, epoch });
    }

    pub(super) fn report_due(&mut self, pad: DeviceId, epoch: u64) {
        let Some(ps) = self.devices[pad].ps_pad() else {
            return;
        };
        if ps.stream_epoch != epoch {
            return;
        }
        let period = ps.report_period;
        let link = ps.link.as_ref().map(|link| link.id);
        let frame = ps.next_report();
        self.after(period, Action::Report { pad, epoch });
        if let (Some(link), Some(frame)) = (link, frame) {
            self.counters.reports_sent += 1;
            self.send_frame_to_robot(link, pad, &frame);
        }
    }
}
