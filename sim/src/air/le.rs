//! The LE half of the controllers: advertising, scanning, connecting as central,
//! connection updates and encryption, as the link layer would carry them. Keys are
//! compared, not used: encryption "succeeds" when both hosts hold the same key (a
//! wrong key is a MIC failure, as on the air).

use embassy_time::{Duration, Instant};

use super::PadEvent;
use super::state::{
    Action, AirState, Auth, COMMAND_DISALLOWED, DeviceId, EV_ENCRYPTION_CHANGE,
    EV_ENCRYPTION_KEY_REFRESH_COMPLETE, Initiating, Link, LinkId, LinkKind, MIC_FAILURE,
    PIN_OR_KEY_MISSING, ROBOT, SUCCESS, Scanning, UNKNOWN_CONNECTION, address_at, handle_at,
    to_units, units,
};

// LE subevents.
const LE_CONNECTION_COMPLETE: u8 = 0x01;
const LE_ADVERTISING_REPORT: u8 = 0x02;
const LE_CONNECTION_UPDATE_COMPLETE: u8 = 0x03;
const LE_READ_REMOTE_FEATURES_COMPLETE: u8 = 0x04;
const LE_LONG_TERM_KEY_REQUEST: u8 = 0x05;
const LE_ENHANCED_CONNECTION_COMPLETE: u8 = 0x0A;

/// An advertising event reaches a scanner with this much jitter at most (advDelay).
const ADV_DELAY_MAX_US: u64 = 10_000;
/// From the CONNECT_IND to the first connection event (the transmit window).
const TRANSMIT_WINDOW: Duration = Duration::from_micros(1_250);
/// A connection update takes effect this many connection events later (its instant).
const UPDATE_INSTANT_EVENTS: u32 = 6;
/// The RSSI an advertising report gives (−60 dBm).
const RSSI: u8 = 0xC4;

const INTERVAL_UNIT_US: u64 = 1_250;
const TIMEOUT_UNIT_US: u64 = 10_000;
const ADV_UNIT_US: u64 = 625;

impl AirState {
    /// An LE command, if `opcode` is one; false otherwise.
    pub(super) fn le_command(&mut self, device: DeviceId, opcode: u16, params: &[u8]) -> bool {
        match opcode {
            // LE Set Event Mask.
            0x2001 => {
                if let Some(mask) = params.get(..8) {
                    self.devices[device].le_event_mask =
                        u64::from_le_bytes(mask.try_into().expect("eight bytes"));
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Read Buffer Size (v1, v2): 27-byte packets (no data length
            // extension), eight of them.
            0x2002 => self.command_complete(device, opcode, SUCCESS, &[27, 0, 8]),
            0x2060 => self.command_complete(device, opcode, SUCCESS, &[27, 0, 8, 0, 0, 0]),
            // LE Read Local Supported Features: none of the optional ones.
            0x2003 => self.command_complete(device, opcode, SUCCESS, &[0; 8]),
            // LE Set Random Address.
            0x2005 => {
                self.devices[device].random_address = address_at(params, 0);
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Set Advertising Parameters.
            0x2006 => {
                let advertising = &mut self.devices[device].le.advertising;
                if let Some(interval) = units(params, 0, ADV_UNIT_US) {
                    advertising.interval = interval.max(Duration::from_millis(20));
                }
                if let Some(&kind) = params.get(4) {
                    advertising.kind = kind;
                }
                if let Some(&own) = params.get(5) {
                    advertising.own_address_kind = own;
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Set Advertising Data, LE Set Scan Response Data.
            0x2008 | 0x2009 => {
                let length = usize::from(params.first().copied().unwrap_or(0)).min(31);
                let data = params.get(1..1 + length).unwrap_or(&[]).to_vec();
                let advertising = &mut self.devices[device].le.advertising;
                if opcode == 0x2008 {
                    advertising.data = data;
                } else {
                    advertising.scan_response = data;
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Set Advertising Enable.
            0x200A => {
                let enable = params.first() == Some(&1);
                let epoch = self.fresh();
                let advertising = &mut self.devices[device].le.advertising;
                let was = advertising.enabled;
                advertising.enabled = enable;
                if enable && !was {
                    advertising.epoch = epoch;
                    let first = Duration::from_micros(self.rng.between(0, ADV_DELAY_MAX_US));
                    self.after(first, Action::Advertise { device, epoch });
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Set Scan Parameters.
            0x200B => {
                self.devices[device].le.scan_active_parameter = params.first() == Some(&1);
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Set Scan Enable.
            0x200C => {
                let le = &mut self.devices[device].le;
                le.scanning = (params.first() == Some(&1)).then(|| Scanning {
                    active: le.scan_active_parameter,
                    filter_duplicates: params.get(1) == Some(&1),
                    seen: Vec::new(),
                });
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Create Connection.
            0x200D => self.create_connection(device, opcode, params),
            // LE Create Connection Cancel.
            0x200E => match self.devices[device].le.initiating.take() {
                Some(initiating) => {
                    self.command_complete(device, opcode, SUCCESS, &[]);
                    let (kind, address) = initiating.peer.unwrap_or((0, [0; 6]));
                    // After the Command Complete, as a controller does.
                    let mut params = vec![UNKNOWN_CONNECTION, 0, 0, 0, kind];
                    params.extend_from_slice(&address);
                    params.extend_from_slice(&[0; 7]);
                    self.connection_complete_event(device, Self::now(), &params);
                }
                None => self.command_complete(device, opcode, COMMAND_DISALLOWED, &[]),
            },
            // LE Read Filter Accept List Size.
            0x200F => self.command_complete(device, opcode, SUCCESS, &[8]),
            // LE Clear / Add to / Remove from the Filter Accept List.
            0x2010 => {
                self.devices[device].le.accept_list.clear();
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            0x2011 | 0x2012 => {
                if let (Some(&kind), Some(address)) = (params.first(), address_at(params, 1)) {
                    let list = &mut self.devices[device].le.accept_list;
                    list.retain(|entry| *entry != (kind, address));
                    if opcode == 0x2011 {
                        list.push((kind, address));
                    }
                }
                self.command_complete(device, opcode, SUCCESS, &[]);
            }
            // LE Connection Update.
            0x2013 => self.connection_update(device, opcode, params),
            // LE Read Remote Features.
            0x2016 => match handle_at(params, 0).and_then(|h| self.link_by_handle(device, h)) {
                Some(link) => {
                    self.command_status(device, opcode, SUCCESS);
                    let handle = self.links[&link].handle_on(device);
                    let mut event = vec![SUCCESS];
                    event.extend_from_slice(&handle.to_le_bytes());
                    event.extend_from_slice(&[0; 8]);
                    let when = self.link_moment(link);
                    self.le_event_at(when, device, LE_READ_REMOTE_FEATURES_COMPLETE, &event);
                }
                None => self.command_status(device, opcode, UNKNOWN_CONNECTION),
            },
            // LE Rand.
            0x2018 => {
                let random: [u8; 8] = self.rng.bytes();
                self.command_complete(device, opcode, SUCCESS, &random);
            }
            // LE Enable Encryption.
            0x2019 => self.enable_encryption(device, opcode, params),
            // LE Long Term Key Request Reply / Negative Reply.
            0x201A | 0x201B => {
                let handle = handle_at(params, 0).unwrap_or(0);
                let link = self.link_by_handle(device, handle);
                let status = if link.is_some() {
                    SUCCESS
                } else {
                    UNKNOWN_CONNECTION
                };
                self.command_complete(device, opcode, status, &handle.to_le_bytes());
                if let Some(link) = link {
                    let key = (opcode == 0x201A)
                        .then(|| params.get(2..18).and_then(|k| k.try_into().ok()))
                        .flatten();
                    let when = self.link_moment(link);
                    self.at(when, Action::LtkAnswer { link, key });
                }
            }
            // LE Remote Connection Parameter Request (Negative) Reply, LE Set Data
            // Length: the handle back.
            0x2020..=0x2022 => {
                let handle = handle_at(params, 0).unwrap_or(0);
                self.command_complete(device, opcode, SUCCESS, &handle.to_le_bytes());
            }
            _ => return false,
        }
        true
    }

    fn create_connection(&mut self, device: DeviceId, opcode: u16, params: &[u8]) {
        let parsed = (|| {
            let policy = *params.get(4)?;
            let peer_kind = *params.get(5)?;
            let peer = address_at(params, 6)?;
            let interval = units(params, 13, INTERVAL_UNIT_US)?;
            let supervision = units(params, 19, TIMEOUT_UNIT_US)?;
            Some((policy, peer_kind, peer, interval, supervision))
        })();
        let le = &mut self.devices[device].le;
        let Some((policy, peer_kind, peer, interval, supervision)) = parsed else {
            self.command_status(device, opcode, 0x12);
            return;
        };
        if le.initiating.is_some() {
            self.command_status(device, opcode, COMMAND_DISALLOWED);
            return;
        }
        le.initiating = Some(Initiating {
            peer: (policy == 0).then_some((peer_kind, peer)),
            interval: interval.max(Duration::from_micros(7_500)),
            supervision: supervision.max(Duration::from_millis(100)),
        });
        self.command_status(device, opcode, SUCCESS);
    }

    fn connection_update(&mut self, device: DeviceId, opcode: u16, params: &[u8]) {
        let Some(link) = handle_at(params, 0).and_then(|h| self.link_by_handle(device, h)) else {
            self.command_status(device, opcode, UNKNOWN_CONNECTION);
            return;
        };
        if device != ROBOT {
            // The peripheral's own update (the Connection Parameters Request
            // procedure) is not offered: the robot's controller does not list it.
            self.command_status(device, opcode, COMMAND_DISALLOWED);
            return;
        }
        let (Some(interval), Some(latency), Some(supervision)) = (
            units(params, 2, INTERVAL_UNIT_US),
            handle_at(params, 6),
            units(params, 8, TIMEOUT_UNIT_US),
        ) else {
            self.command_status(device, opcode, 0x12);
            return;
        };
        self.command_status(device, opcode, SUCCESS);
        let current = &self.links[&link];
        let instant = current.next_event(Self::now()) + current.interval * UPDATE_INSTANT_EVENTS;
        self.at(
            instant,
            Action::ConnectionUpdate {
                link,
                interval: interval.max(Duration::from_micros(7_500)),
                latency,
                supervision: supervision.max(Duration::from_millis(100)),
            },
        );
    }

    pub(super) fn connection_updated(
        &mut self,
        link_id: LinkId,
        interval: Duration,
        latency: u16,
        supervision: Duration,
    ) {
        let Some(link) = self.links.get_mut(&link_id) else {
            return;
        };
        link.interval = interval;
        link.anchor = Self::now();
        link.supervision = supervision;
        let (robot_handle, pad, pad_handle) = (link.robot_handle, link.pad, link.pad_handle);
        for (device, handle) in [(ROBOT, robot_handle), (pad, pad_handle)] {
            let mut event = vec![SUCCESS];
            event.extend_from_slice(&handle.to_le_bytes());
            event.extend_from_slice(&to_units(interval, INTERVAL_UNIT_US));
            event.extend_from_slice(&latency.to_le_bytes());
            event.extend_from_slice(&to_units(supervision, TIMEOUT_UNIT_US));
            self.le_event_at(Self::now(), device, LE_CONNECTION_UPDATE_COMPLETE, &event);
        }
    }

    fn enable_encryption(&mut self, device: DeviceId, opcode: u16, params: &[u8]) {
        let link = handle_at(params, 0).and_then(|h| self.link_by_handle(device, h));
        let (Some(link), Some(rand), Some(ediv), Some(key)) = (
            link,
            params.get(2..10).and_then(|r| <[u8; 8]>::try_from(r).ok()),
            params.get(10..12).map(|e| u16::from_le_bytes([e[0], e[1]])),
            params
                .get(12..28)
                .and_then(|k| <[u8; 16]>::try_from(k).ok()),
        ) else {
            self.command_status(device, opcode, UNKNOWN_CONNECTION);
            return;
        };
        if device != ROBOT || self.links[&link].kind != LinkKind::Le {
            self.command_status(device, opcode, COMMAND_DISALLOWED);
            return;
        }
        self.command_status(device, opcode, SUCCESS);
        self.links.get_mut(&link).expect("found").le_key = Some(key);
        let when = self.link_moment(link);
        self.at(when, Action::LtkRequest { link, rand, ediv });
    }

    /// The central's LL_ENC_REQ reaches the peripheral: its host is asked for the key.
    pub(super) fn ltk_request(&mut self, link: LinkId, rand: [u8; 8], ediv: u16) {
        let Some(found) = self.links.get(&link) else {
            return;
        };
        if found.lost_since.is_some() {
            return;
        }
        let (pad, handle) = (found.pad, found.pad_handle);
        let mut event = handle.to_le_bytes().to_vec();
        event.extend_from_slice(&rand);
        event.extend_from_slice(&ediv.to_le_bytes());
        self.le_event_at(Self::now(), pad, LE_LONG_TERM_KEY_REQUEST, &event);
    }

    /// The peripheral's host answered with its key (or none): the keys meet.
    pub(super) fn ltk_answer(&mut self, link_id: LinkId, key: Option<[u8; 16]>) {
        let Some(link) = self.links.get_mut(&link_id) else {
            return;
        };
        let central_key = link.le_key.take();
        let (robot_handle, pad, pad_handle, was_encrypted) =
            (link.robot_handle, link.pad, link.pad_handle, link.encrypted);
        match (key, central_key) {
            (Some(ours), Some(theirs)) if ours == theirs => {
                link.encrypted = true;
                link.auth = Auth::Done;
                for (device, handle) in [(ROBOT, robot_handle), (pad, pad_handle)] {
                    let [lo, hi] = handle.to_le_bytes();
                    if was_encrypted {
                        self.event_now(
                            device,
                            EV_ENCRYPTION_KEY_REFRESH_COMPLETE,
                            &[SUCCESS, lo, hi],
                        );
                    } else {
                        self.event_now(device, EV_ENCRYPTION_CHANGE, &[SUCCESS, lo, hi, 1]);
                    }
                }
                self.record(pad, PadEvent::Encrypted);
            }
            (None, _) => {
                // LL_REJECT_EXT_IND, PIN or Key Missing: the link stays unencrypted.
                let [lo, hi] = robot_handle.to_le_bytes();
                self.event_now(
                    ROBOT,
                    EV_ENCRYPTION_CHANGE,
                    &[PIN_OR_KEY_MISSING, lo, hi, 0],
                );
                self.record(pad, PadEvent::EncryptionFailed(PIN_OR_KEY_MISSING));
            }
            (Some(_), _) => {
                // Different keys: the first encrypted packet fails its MIC check and
                // the link is dropped.
                self.record(pad, PadEvent::EncryptionFailed(MIC_FAILURE));
                self.end_link(link_id, MIC_FAILURE, MIC_FAILURE);
            }
        }
    }

    /// One advertising event of `device`: a scanning robot hears it, an initiating
    /// robot connects.
    pub(super) fn advertising_event(&mut self, device: DeviceId, epoch: u64) {
        let advertising = self.devices[device].le.advertising.clone();
        if !advertising.enabled || advertising.epoch != epoch {
            return;
        }
        let delay = Duration::from_micros(self.rng.between(0, ADV_DELAY_MAX_US));
        self.after(
            advertising.interval + delay,
            Action::Advertise { device, epoch },
        );
        let robot = &self.devices[ROBOT];
        if !self.devices[device].on_air() || !robot.on_air() || robot.port.is_none() {
            return;
        }
        let own_kind = advertising.own_address_kind;
        let address = if own_kind == 0 {
            self.devices[device].public_address
        } else {
            self.devices[device].random_address.unwrap_or_default()
        };
        let event_type = match advertising.kind {
            0x00 => 0x00,
            0x01 | 0x04 => 0x01,
            0x02 => 0x02,
            _ => 0x03,
        };
        if let Some(scanning) = self.devices[ROBOT].le.scanning.as_mut() {
            let fresh = !scanning.filter_duplicates || !scanning.seen.contains(&address);
            if fresh {
                scanning.seen.push(address);
                let active = scanning.active;
                let now = Self::now();
                let report = advertising_report(event_type, own_kind, address, &advertising.data);
                self.le_event_at(now, ROBOT, LE_ADVERTISING_REPORT, &report);
                if active && event_type != 0x03 && !advertising.scan_response.is_empty() {
                    let report =
                        advertising_report(0x04, own_kind, address, &advertising.scan_response);
                    self.le_event_at(now, ROBOT, LE_ADVERTISING_REPORT, &report);
                }
            }
        }
        let connectable = matches!(event_type, 0x00 | 0x01);
        let wanted = self.devices[ROBOT]
            .le
            .initiating
            .as_ref()
            .is_some_and(|initiating| match initiating.peer {
                Some(peer) => peer == (own_kind, address),
                None => self.devices[ROBOT]
                    .le
                    .accept_list
                    .contains(&(own_kind, address)),
            });
        if connectable && wanted {
            self.le_connect(device, own_kind, address);
        }
    }

    /// The robot's CONNECT_IND: a link to `pad`, which stops advertising.
    fn le_connect(&mut self, pad: DeviceId, pad_kind: u8, pad_address: [u8; 6]) {
        let initiating = self.devices[ROBOT]
            .le
            .initiating
            .take()
            .expect("initiating");
        self.devices[pad].le.advertising.enabled = false;
        let anchor = Self::now() + TRANSMIT_WINDOW;
        let robot_handle = self.new_handle(ROBOT);
        let pad_handle = self.new_handle(pad);
        let id = self.new_link_id();
        self.links.insert(
            id,
            Link {
                kind: LinkKind::Le,
                robot_generation: self.devices[ROBOT].generation,
                robot_handle,
                pad,
                pad_handle,
                robot_central: true,
                interval: initiating.interval,
                anchor,
                supervision: initiating.supervision,
                lost_since: None,
                held: Vec::new(),
                le_key: None,
                encrypted: false,
                auth: Auth::None,
                link_key: None,
                to_pad: Vec::new(),
            },
        );
        let robot_address = self.devices[ROBOT].random_address.unwrap_or_default();
        let timing = {
            let mut timing = to_units(initiating.interval, INTERVAL_UNIT_US).to_vec();
            timing.extend_from_slice(&[0, 0]);
            timing.extend_from_slice(&to_units(initiating.supervision, TIMEOUT_UNIT_US));
            timing.push(0);
            timing
        };
        let complete = |handle: u16, role: u8, kind: u8, address: [u8; 6]| {
            let mut params = vec![SUCCESS];
            params.extend_from_slice(&handle.to_le_bytes());
            params.extend_from_slice(&[role, kind]);
            params.extend_from_slice(&address);
            params.extend_from_slice(&timing);
            params
        };
        self.connection_complete_event(
            ROBOT,
            anchor,
            &complete(robot_handle, 0, pad_kind, pad_address),
        );
        self.connection_complete_event(pad, anchor, &complete(pad_handle, 1, 1, robot_address));
        self.record(pad, PadEvent::Connected);
        self.attack_on_connect(pad, id);
    }

    /// An LE connection complete in the form the host asked for: the enhanced event if
    /// it unmasked it, the first one otherwise. `legacy` holds the first's parameters.
    fn connection_complete_event(&mut self, device: DeviceId, when: Instant, legacy: &[u8]) {
        let enhanced_on =
            self.devices[device].le_event_mask & (1 << (LE_ENHANCED_CONNECTION_COMPLETE - 1)) != 0;
        if enhanced_on {
            // The same, with the local and peer resolvable private addresses (none).
            let mut params = legacy[..11].to_vec();
            params.extend_from_slice(&[0; 12]);
            params.extend_from_slice(&legacy[11..]);
            self.le_event_at(when, device, LE_ENHANCED_CONNECTION_COMPLETE, &params);
        } else {
            self.le_event_at(when, device, LE_CONNECTION_COMPLETE, legacy);
        }
    }
}

fn advertising_report(event_type: u8, kind: u8, address: [u8; 6], data: &[u8]) -> Vec<u8> {
    let mut report = vec![1, event_type, kind];
    report.extend_from_slice(&address);
    report.push(data.len() as u8);
    report.extend_from_slice(data);
    report.push(RSSI);
    report
}
