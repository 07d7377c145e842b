//! A scripted Bluetooth controller in memory, for the random-stream test, the fuzz
//! target and the remote's scenarios on the virtual clock: it answers every HCI command
//! the host sends, connects when the host asks (and encrypts when it asks), and then
//! hands the host whatever packets the test gives it, good or malformed, as a
//! controller would pass on a peer's packets. On request its pad serves HID over GATT
//! as an Xbox Wireless Controller ([`FakeHandle::serve_gamepad`]) and sends input
//! reports ([`FakeHandle::notify`]); the test can also break the transport
//! ([`FakeHandle::fail_next_read`]) or send raw bytes ([`FakeHandle::send_raw`]).
//!
//! No thread, no socket: it runs on the caller's executor, so with the virtual clock
//! (`crate::runtime::block_on`) a whole reconnect back-off costs no wall time.
//!
//! ```text
//!   host ──H4──▶ FakeWriter ─▶ Fake::on_command ─▶ Command Complete / Status,
//!                                                   LE Connection Complete, Encryption Change
//!   host ◀─H4── FakeReader ◀─ to_host ◀──────────── and, once connected, the script's packets
//!                                  ▲
//!   host ──ACL─▶ Fake::on_acl ─────┴── the pad's GATT server: ATT answers, notifications
//! ```

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::poll_fn;
use std::rc::Rc;
use std::task::{Poll, Waker};

use bt_hci::controller::ExternalController;
use bt_hci_serial::SerialTransport;
use embassy_futures::select::{Either, select};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_time::{Duration, Instant, Timer};

use crate::ble::{HCI_SLOTS, HciError};

const CMD: u8 = 0x01;
const ACL: u8 = 0x02;
const EVENT: u8 = 0x04;

const EVENT_DISCONNECTION_COMPLETE: u8 = 0x05;
const EVENT_ENCRYPTION_CHANGE: u8 = 0x08;
const EVENT_COMMAND_COMPLETE: u8 = 0x0E;
const EVENT_COMMAND_STATUS: u8 = 0x0F;
const EVENT_LE_META: u8 = 0x3E;
const EVENT_NUMBER_OF_COMPLETED_PACKETS: u8 = 0x13;

const OP_DISCONNECT: u16 = 0x0406;
const OP_LE_CREATE_CONNECTION: u16 = 0x200D;
const OP_LE_CREATE_CONNECTION_CANCEL: u16 = 0x200E;
const OP_LE_ENABLE_ENCRYPTION: u16 = 0x2019;
const OP_LE_ADD_DEVICE_TO_FILTER_ACCEPT_LIST: u16 = 0x2011;
const OP_LE_SET_SCAN_ENABLE: u16 = 0x200C;
const OP_RESET: u16 = 0x0C03;

const STATUS_UNKNOWN_CONNECTION: u8 = 0x02;
const STATUS_COMMAND_DISALLOWED: u8 = 0x0C;

/// How long the link layer takes to end a link the host disconnects.
const TERMINATION: Duration = Duration::from_millis(20);

/// The pad the fake advertises while the host scans: random static address (least
/// significant byte first, as on the air), and advertising data with the flags and the
/// gamepad appearance.
pub const PAD_ADDRESS: [u8; 6] = [0x55, 0x44, 0x33, 0x22, 0x11, 0xC1];
const PAD_ADVERTISING: [u8; 7] = [0x02, 0x01, 0x06, 0x03, 0x19, 0xC4, 0x03];

/// What the fake has done, for the test to check it ran at all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeStats {
    /// HCI commands the host sent (zero: the host never touched the radio).
    pub commands: u32,
    pub connections: u32,
    pub packets_delivered: u32,
    pub disconnects_by_host: u32,
    /// HCI Resets: one per start of the host.
    pub resets: u32,
    /// Links on which the host subscribed to the pad's input reports.
    pub subscriptions: u32,
}

/// When the packets of a [`FakeHandle::attack_every_link`] go to the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AttackAt {
    /// Right after LE Connection Complete.
    Connect,
    /// When the host asks to encrypt, before the controller's answer.
    EncryptionRequested,
    /// Right after the encryption's outcome (encrypted, unless the pad is an impostor
    /// without the key: [`FakeHandle::impostor`]).
    Encrypted,
}

#[derive(Default)]
struct Fake {
    to_host: VecDeque<u8>,
    reader: Option<Waker>,
    from_host: Vec<u8>,
    /// H4 packets (type byte first) to deliver on the next link, in order.
    script: VecDeque<Vec<u8>>,
    /// The open link's handle.
    link: Option<u16>,
    /// The last address put on the filter accept list (type, address).
    accepted: Option<(u8, Vec<u8>)>,
    next_handle: u16,
    stats: FakeStats,
    /// The host's ACL fragments of the L2CAP PDU being put together.
    from_host_pdu: Vec<u8>,
    /// The pad's attributes, if it serves GATT.
    gatt: Option<GattTable>,
    /// The open link's state as the pad sees it.
    encrypted: bool,
    subscribed: bool,
    /// Packets sent on every link at a moment (the pad misbehaves each time).
    attacks: Vec<(AttackAt, Vec<u8>)>,
    /// The host's next read fails (a broken transport).
    read_error: bool,
    /// The pad has no key for the bond: every encryption fails (PIN or Key Missing).
    impostor: bool,
    /// The link the host disconnects, and when its Disconnection Complete comes.
    terminating: Option<(u16, Instant)>,
}

impl Fake {
    fn send(&mut self, packet: &[u8]) {
        self.to_host.extend(packet);
        if let Some(waker) = self.reader.take() {
            waker.wake();
        }
    }

    fn event(&mut self, code: u8, params: &[u8]) {
        let mut packet = vec![EVENT, code, params.len() as u8];
        packet.extend_from_slice(params);
        self.send(&packet);
    }

    fn complete(&mut self, opcode: u16, return_params: &[u8]) {
        let mut params = vec![1];
        params.extend_from_slice(&opcode.to_le_bytes());
        params.push(0);
        params.extend_from_slice(return_params);
        self.event(EVENT_COMMAND_COMPLETE, &params);
    }

    fn status(&mut self, opcode: u16, status: u8) {
        let [lo, hi] = opcode.to_le_bytes();
        self.event(EVENT_COMMAND_STATUS, &[status, 1, lo, hi]);
    }

    /// Takes the host's bytes and answers each complete H4 packet: commands, and ACL
    /// data (each packet's buffer is given back at once, as a controller does after
    /// sending it on air).
    fn on_bytes(&mut self, bytes: &[u8]) {
        self.from_host.extend_from_slice(bytes);
        loop {
            let length = match self.from_host.as_slice() {
                [CMD, _, _, len, ..] => 4 + usize::from(*len),
                [ACL, _, _, lo, hi, ..] => 5 + usize::from(u16::from_le_bytes([*lo, *hi])),
                [] => return,
                [_, ..] if self.from_host.len() < 5 => return,
                // Nothing else comes from a host; drop it.
                _ => {
                    self.from_host.clear();
                    return;
                }
            };
            if self.from_host.len() < length {
                return;
            }
            let packet: Vec<u8> = self.from_host.drain(..length).collect();
            if packet[0] == CMD {
                self.on_command(u16::from_le_bytes([packet[1], packet[2]]), &packet[4..]);
            } else {
                self.on_acl(&packet);
            }
        }
    }

    fn on_command(&mut self, opcode: u16, params: &[u8]) {
        self.stats.commands += 1;
        match opcode {
            OP_LE_CREATE_CONNECTION => {
                self.status(opcode, 0);
                // The peer: from the filter accept list (policy 1), or as asked for.
                let (kind, address) = match (params.get(4), params.get(5..12)) {
                    (Some(1), _) => self.accepted.clone().unwrap_or((0, vec![0; 6])),
                    (_, Some([kind, address @ ..])) => (*kind, address.to_vec()),
                    _ => (0, vec![0; 6]),
                };
                self.next_handle = (self.next_handle + 1) % 0x0EFF;
                let handle = 0x0040 + self.next_handle;
                self.link = Some(handle);
                self.stats.connections += 1;
                let mut complete = vec![0x01, 0x00];
                complete.extend_from_slice(&handle.to_le_bytes());
                complete.extend_from_slice(&[0x00, kind]);
                complete.extend_from_slice(&address);
                // Interval 7.5 ms, latency 0, supervision 500 ms, accuracy.
                complete.extend_from_slice(&[0x06, 0x00, 0x00, 0x00, 0x32, 0x00, 0x00]);
                self.event(EVENT_LE_META, &complete);
                self.encrypted = false;
                self.subscribed = false;
                self.from_host_pdu.clear();
                self.deliver_script();
                self.deliver_attacks(AttackAt::Connect);
            }
            OP_LE_CREATE_CONNECTION_CANCEL => self.complete(opcode, &[]),
            OP_LE_SET_SCAN_ENABLE => {
                self.complete(opcode, &[]);
                if params.first() == Some(&1) {
                    // One connectable advertisement of a gamepad (LE Advertising Report).
                    let mut report = vec![0x02, 1, 0x00, 0x01];
                    report.extend_from_slice(&PAD_ADDRESS);
                    report.push(PAD_ADVERTISING.len() as u8);
                    report.extend_from_slice(&PAD_ADVERTISING);
                    report.push(0xC4);
                    self.event(EVENT_LE_META, &report);
                }
            }
            OP_LE_ADD_DEVICE_TO_FILTER_ACCEPT_LIST => {
                if let Some([kind, address @ ..]) = params.get(..7) {
                    self.accepted = Some((*kind, address.to_vec()));
                }
                self.complete(opcode, &[]);
            }
            OP_LE_ENABLE_ENCRYPTION => {
                self.status(opcode, 0);
                if let Some([lo, hi]) = params.get(..2).map(|p| [p[0], p[1]]) {
                    self.deliver_attacks(AttackAt::EncryptionRequested);
                    if self.link.is_none() {
                        return;
                    }
                    if self.impostor {
                        // PIN or Key Missing: the peer answered without a key.
                        self.event(EVENT_ENCRYPTION_CHANGE, &[0x06, lo, hi, 0]);
                    } else {
                        self.event(EVENT_ENCRYPTION_CHANGE, &[0, lo, hi, 1]);
                        self.encrypted = true;
                    }
                    self.deliver_attacks(AttackAt::Encrypted);
                }
            }
            OP_RESET => {
                // A reset controller keeps no link, and tells the host of none.
                self.link = None;
                self.terminating = None;
                self.stats.resets += 1;
                self.complete(opcode, &[]);
            }
            OP_DISCONNECT => {
                // As a link layer does: the termination takes a few connection events,
                // and a second Disconnect meanwhile is refused.
                let handle = params
                    .get(..2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]) & 0x0FFF);
                match (handle, self.terminating) {
                    (Some(handle), Some((ending, _))) if ending == handle => {
                        self.status(opcode, STATUS_COMMAND_DISALLOWED);
                    }
                    (Some(handle), _) if self.link == Some(handle) => {
                        self.status(opcode, 0);
                        self.stats.disconnects_by_host += 1;
                        self.terminating = Some((handle, Instant::now() + TERMINATION));
                    }
                    _ => self.status(opcode, STATUS_UNKNOWN_CONNECTION),
                }
            }
            _ => {
                let return_params = return_params(opcode);
                self.complete(opcode, &return_params);
            }
        }
    }

    /// The script's packets, on the new link's handle (an ACL packet's handle bytes are
    /// replaced; its flags are kept).
    fn deliver_script(&mut self) {
        let Some(handle) = self.link else { return };
        while let Some(mut packet) = self.script.pop_front() {
            if packet.first() == Some(&ACL) && packet.len() >= 3 {
                let flags = packet[2] & 0xF0;
                let [lo, hi] = handle.to_le_bytes();
                packet[1] = lo;
                packet[2] = hi | flags;
            }
            self.stats.packets_delivered += 1;
            self.send(&packet);
        }
    }

    /// The link the host disconnected is gone now: Disconnection Complete.
    fn end_termination(&mut self) {
        let Some((handle, _)) = self.terminating.take() else {
            return;
        };
        if self.link == Some(handle) {
            self.link = None;
            let [lo, hi] = handle.to_le_bytes();
            self.event(EVENT_DISCONNECTION_COMPLETE, &[0, lo, hi, 0x16]);
        }
    }

    fn deliver_attacks(&mut self, at: AttackAt) {
        let packets: Vec<Vec<u8>> = self
            .attacks
            .iter()
            .filter(|(when, _)| *when == at)
            .map(|(_, packet)| packet.clone())
            .collect();
        if packets.is_empty() {
            return;
        }
        self.script.extend(packets);
        self.deliver_script();
    }

    /// One ACL packet from the host: its buffer is free again at once; a whole L2CAP
    /// PDU on the ATT channel is answered by the pad's GATT server.
    fn on_acl(&mut self, packet: &[u8]) {
        let [_, lo, hi, _, _, data @ ..] = packet else {
            return;
        };
        let handle = u16::from_le_bytes([*lo, *hi]) & 0x0FFF;
        let [h_lo, h_hi] = handle.to_le_bytes();
        self.event(EVENT_NUMBER_OF_COMPLETED_PACKETS, &[1, h_lo, h_hi, 1, 0]);
        if self.link != Some(handle) {
            return;
        }
        let continuing = (hi >> 4) & 0b11 == 0b01;
        if !continuing {
            self.from_host_pdu.clear();
        }
        self.from_host_pdu.extend_from_slice(data);
        let [l0, l1, c0, c1, ..] = self.from_host_pdu[..] else {
            return;
        };
        let length = usize::from(u16::from_le_bytes([l0, l1]));
        if self.from_host_pdu.len() < 4 + length {
            return;
        }
        let channel = u16::from_le_bytes([c0, c1]);
        let pdu: Vec<u8> = self.from_host_pdu.drain(..).skip(4).take(length).collect();
        if channel == ATT_CHANNEL
            && let Some(answer) = self.att_answer(&pdu)
        {
            self.send_att(&answer);
        }
    }

    /// The pad's answer to an ATT request, if it serves GATT and the request wants one.
    fn att_answer(&mut self, request: &[u8]) -> Option<Vec<u8>> {
        let gatt = self.gatt.as_ref()?;
        let (answer, subscribed) = gatt.answer(request, self.encrypted);
        if subscribed && !self.subscribed {
            self.subscribed = true;
            self.stats.subscriptions += 1;
        }
        answer
    }

    fn send_att(&mut self, pdu: &[u8]) {
        let Some(handle) = self.link else { return };
        let [lo, hi] = handle.to_le_bytes();
        let mut packet = vec![ACL, lo, hi | 0x20];
        packet.extend_from_slice(&((pdu.len() + 4) as u16).to_le_bytes());
        packet.extend_from_slice(&(pdu.len() as u16).to_le_bytes());
        packet.extend_from_slice(&ATT_CHANNEL.to_le_bytes());
        packet.extend_from_slice(pdu);
        self.send(&packet);
    }
}

const ATT_CHANNEL: u16 = 0x0004;

// ATT opcodes the pad's server answers.
const ATT_ERROR_RSP: u8 = 0x01;
const ATT_EXCHANGE_MTU_REQ: u8 = 0x02;
const ATT_FIND_INFORMATION_REQ: u8 = 0x04;
const ATT_FIND_BY_TYPE_VALUE_REQ: u8 = 0x06;
const ATT_READ_BY_TYPE_REQ: u8 = 0x08;
const ATT_READ_REQ: u8 = 0x0A;
const ATT_READ_BLOB_REQ: u8 = 0x0C;
const ATT_READ_BY_GROUP_TYPE_REQ: u8 = 0x10;
const ATT_WRITE_REQ: u8 = 0x12;
const ATT_HANDLE_VALUE_NTF: u8 = 0x1B;
const ATT_ATTRIBUTE_NOT_FOUND: u8 = 0x0A;
const ATT_REQUEST_NOT_SUPPORTED: u8 = 0x06;
const ATT_INSUFFICIENT_ENCRYPTION: u8 = 0x0F;

/// The pad's ATT MTU: its answers and notifications fit one ACL packet.
const PAD_MTU: u16 = 185;

const PRIMARY_SERVICE: u16 = 0x2800;
const CHARACTERISTIC: u16 = 0x2803;
const CCCD: u16 = 0x2902;
const REPORT_REFERENCE: u16 = 0x2908;

/// The handle of the pad's input report value and of its CCCD.
const INPUT_REPORT_HANDLE: u16 = 7;
const INPUT_REPORT_CCCD: u16 = 8;

/// One attribute of the pad's server: handle, type, value, and whether reading it
/// needs an encrypted link (the HID service's do, as on the real pad).
struct Attribute {
    handle: u16,
    kind: u16,
    value: Vec<u8>,
    encrypted: bool,
}

/// An Xbox Wireless Controller's GATT server: the HID service (HID Information, the
/// Report Map, one input report with its CCCD and Report Reference) and the Device
/// Information service's PnP ID.
struct GattTable {
    attributes: Vec<Attribute>,
    /// The end handle of each primary service, by its start handle.
    service_ends: Vec<(u16, u16)>,
}

impl GattTable {
    fn xbox_pad(report_map: Vec<u8>) -> GattTable {
        let declaration = |props: u8, value_handle: u16, uuid: u16| {
            let mut value = vec![props];
            value.extend_from_slice(&value_handle.to_le_bytes());
            value.extend_from_slice(&uuid.to_le_bytes());
            value
        };
        let attribute = |handle, kind, value: Vec<u8>, encrypted| Attribute {
            handle,
            kind,
            value,
            encrypted,
        };
        const READ: u8 = 0x02;
        const NOTIFY: u8 = 0x10;
        GattTable {
            attributes: vec![
                attribute(1, PRIMARY_SERVICE, 0x1812u16.to_le_bytes().to_vec(), false),
                attribute(2, CHARACTERISTIC, declaration(READ, 3, 0x2A4A), false),
                attribute(3, 0x2A4A, vec![0x11, 0x01, 0x00, 0x02], true),
                attribute(4, CHARACTERISTIC, declaration(READ, 5, 0x2A4B), false),
                attribute(5, 0x2A4B, report_map, true),
                attribute(
                    6,
                    CHARACTERISTIC,
                    declaration(READ | NOTIFY, 7, 0x2A4D),
                    false,
                ),
                attribute(INPUT_REPORT_HANDLE, 0x2A4D, idle_xbox_report(), true),
                attribute(INPUT_REPORT_CCCD, CCCD, vec![0, 0], false),
                attribute(9, REPORT_REFERENCE, vec![1, 1], false),
                attribute(10, PRIMARY_SERVICE, 0x180Au16.to_le_bytes().to_vec(), false),
                attribute(11, CHARACTERISTIC, declaration(READ, 12, 0x2A50), false),
                attribute(
                    12,
                    0x2A50,
                    vec![0x02, 0x5E, 0x04, 0x13, 0x0B, 0x01, 0x05],
                    false,
                ),
            ],
            service_ends: vec![(1, 9), (10, 12)],
        }
    }

    fn range(&self, start: u16, end: u16) -> impl Iterator<Item = &Attribute> {
        self.attributes
            .iter()
            .filter(move |a| (start..=end).contains(&a.handle))
    }

    /// The answer to one request, and whether it subscribed to the input report.
    fn answer(&self, request: &[u8], encrypted: bool) -> (Option<Vec<u8>>, bool) {
        let Some(&opcode) = request.first() else {
            return (None, false);
        };
        let u16_at = |at: usize| {
            request
                .get(at..at + 2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
        };
        let error = |handle: u16, code: u8| {
            let [lo, hi] = handle.to_le_bytes();
            Some(vec![ATT_ERROR_RSP, opcode, lo, hi, code])
        };
        let room = usize::from(PAD_MTU);
        let answer = match opcode {
            ATT_EXCHANGE_MTU_REQ => {
                let mut answer = vec![opcode + 1];
                answer.extend_from_slice(&PAD_MTU.to_le_bytes());
                Some(answer)
            }
            ATT_FIND_INFORMATION_REQ => {
                let (start, end) = (u16_at(1).unwrap_or(1), u16_at(3).unwrap_or(0));
                let mut answer = vec![opcode + 1, 0x01];
                for attribute in self.range(start, end).take((room - 2) / 4) {
                    answer.extend_from_slice(&attribute.handle.to_le_bytes());
                    answer.extend_from_slice(&attribute.kind.to_le_bytes());
                }
                if answer.len() > 2 {
                    Some(answer)
                } else {
                    error(start, ATT_ATTRIBUTE_NOT_FOUND)
                }
            }
            ATT_FIND_BY_TYPE_VALUE_REQ => {
                let (start, end) = (u16_at(1).unwrap_or(1), u16_at(3).unwrap_or(0));
                let value = request.get(7..).unwrap_or(&[]);
                let mut answer = vec![opcode + 1];
                for attribute in self
                    .range(start, end)
                    .filter(|a| a.kind == PRIMARY_SERVICE && a.value == value)
                {
                    let group_end = self
                        .service_ends
                        .iter()
                        .find(|(first, _)| *first == attribute.handle)
                        .map_or(attribute.handle, |(_, last)| *last);
                    answer.extend_from_slice(&attribute.handle.to_le_bytes());
                    answer.extend_from_slice(&group_end.to_le_bytes());
                }
                if answer.len() > 1 {
                    Some(answer)
                } else {
                    error(start, ATT_ATTRIBUTE_NOT_FOUND)
                }
            }
            ATT_READ_BY_TYPE_REQ => {
                let (start, end) = (u16_at(1).unwrap_or(1), u16_at(3).unwrap_or(0));
                let kind = u16_at(5).unwrap_or(0);
                let found: Vec<&Attribute> = self
                    .range(start, end)
                    .filter(|a| a.kind == kind && request.len() == 7)
                    .collect();
                match found.first() {
                    // Every item of one answer has the first one's length.
                    Some(first) => {
                        let item = 2 + first.value.len().min(room - 4);
                        let mut answer = vec![opcode + 1, item as u8];
                        for attribute in found
                            .iter()
                            .filter(|a| 2 + a.value.len() == item)
                            .take((room - 2) / item)
                        {
                            answer.extend_from_slice(&attribute.handle.to_le_bytes());
                            answer.extend_from_slice(&attribute.value[..item - 2]);
                        }
                        Some(answer)
                    }
                    None => error(start, ATT_ATTRIBUTE_NOT_FOUND),
                }
            }
            ATT_READ_REQ | ATT_READ_BLOB_REQ => {
                let handle = u16_at(1).unwrap_or(0);
                let offset = if opcode == ATT_READ_BLOB_REQ {
                    usize::from(u16_at(3).unwrap_or(0))
                } else {
                    0
                };
                match self.attributes.iter().find(|a| a.handle == handle) {
                    Some(attribute) if attribute.encrypted && !encrypted => {
                        error(handle, ATT_INSUFFICIENT_ENCRYPTION)
                    }
                    Some(attribute) => {
                        let value = attribute.value.get(offset..).unwrap_or(&[]);
                        let mut answer = vec![opcode + 1];
                        answer.extend_from_slice(&value[..value.len().min(room - 1)]);
                        Some(answer)
                    }
                    None => error(handle, 0x01),
                }
            }
            ATT_READ_BY_GROUP_TYPE_REQ => error(u16_at(1).unwrap_or(0), ATT_ATTRIBUTE_NOT_FOUND),
            ATT_WRITE_REQ => {
                let handle = u16_at(1).unwrap_or(0);
                let subscribed =
                    handle == INPUT_REPORT_CCCD && request.get(3..5) == Some(&[0x01, 0x00]);
                return (Some(vec![opcode + 1]), subscribed);
            }
            // Commands, notifications and confirmations want no answer.
            0x52 | 0xD2 | 0x1B | 0x1E => None,
            _ => error(0, ATT_REQUEST_NOT_SUPPORTED),
        };
        (answer, false)
    }
}

/// An Xbox pad's 16-byte input report: sticks centred, triggers and buttons released.
fn idle_xbox_report() -> Vec<u8> {
    XboxReport::default().bytes()
}

/// The state of the fake Xbox pad, as its 16-byte input report (report ID 1) carries
/// it: four stick axes (0x8000 centred, small LY forward), two triggers, the hat and
/// 15 buttons (RB is bit 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct XboxReport {
    pub left_y: u16,
    pub buttons: u16,
}

impl Default for XboxReport {
    fn default() -> Self {
        Self {
            left_y: 0x8000,
            buttons: 0,
        }
    }
}

impl XboxReport {
    /// RB, the dead-man.
    pub const RB: u16 = 1 << 7;
    /// The left stick pushed fully forward.
    pub const FULL_FORWARD: u16 = 0x0001;

    pub fn bytes(self) -> Vec<u8> {
        let mut report = Vec::with_capacity(16);
        for axis in [0x8000, self.left_y, 0x8000, 0x8000u16] {
            report.extend_from_slice(&axis.to_le_bytes());
        }
        report.extend_from_slice(&[0, 0, 0, 0, 0]);
        report.extend_from_slice(&(self.buttons & 0x7FFF).to_le_bytes());
        report.push(0);
        report
    }
}

/// The return parameters (after the status) of the commands whose answer carries
/// more than a status; every other command succeeds with its status alone.
fn return_params(opcode: u16) -> Vec<u8> {
    match opcode {
        // LE Read Buffer Size: 27-byte ACL packets, 8 of them.
        0x2002 => vec![27, 0, 8],
        // LE Read Buffer Size v2: the same, no ISO buffers.
        0x2060 => vec![27, 0, 8, 0, 0, 0],
        // LE Rand.
        0x2018 => vec![0x5A, 0x3C, 0x96, 0x0F, 0xE1, 0x2D, 0x78, 0xB4],
        // LE Read Filter Accept List Size.
        0x200F => vec![4],
        // Read BD_ADDR.
        0x1009 => vec![1, 2, 3, 4, 5, 6],
        // Read Local Version Information.
        0x1001 => vec![0x0C, 0, 0, 0x0C, 0xFF, 0xFF, 0, 0],
        // Read Local Supported Commands: everything.
        0x1002 => vec![0xFF; 64],
        // Read Local Supported Features, LE Read Local Supported Features.
        0x1003 | 0x2003 => vec![0; 8],
        // Read RSSI: handle, RSSI.
        0x1405 => vec![0x40, 0, 0xC4],
        // LE Set Data Length, LE Remote Connection Parameter Request (Negative) Reply.
        0x2020..=0x2022 => vec![0x40, 0],
        _ => Vec::new(),
    }
}

/// The host's end of the fake: reads what the controller sends.
pub struct FakeReader(Rc<RefCell<Fake>>);
/// The host's end of the fake: writes commands and data to the controller.
pub struct FakeWriter(Rc<RefCell<Fake>>);
/// The test's handle: scripts packets and reads the statistics.
#[derive(Clone)]
pub struct FakeHandle(Rc<RefCell<Fake>>);

/// The controller trouble-host drives, over the fake.
pub type FakeController =
    ExternalController<SerialTransport<NoopRawMutex, FakeReader, FakeWriter>, HCI_SLOTS>;

/// A fresh fake controller, and the handle to script it.
pub fn fake_controller() -> (FakeController, FakeHandle) {
    let fake = Rc::new(RefCell::new(Fake::default()));
    let controller = ExternalController::new(SerialTransport::new(
        FakeReader(fake.clone()),
        FakeWriter(fake.clone()),
    ));
    (controller, FakeHandle(fake))
}

impl FakeHandle {
    /// Packets (H4, type byte first) the next link delivers as soon as it is made; at
    /// once if a link is open.
    pub fn script(&self, packets: impl IntoIterator<Item = Vec<u8>>) {
        let mut fake = self.0.borrow_mut();
        fake.script.extend(packets);
        if fake.link.is_some() {
            fake.deliver_script();
        }
    }

    /// The peer drops the link (if one is open).
    pub fn peer_disconnects(&self) {
        let mut fake = self.0.borrow_mut();
        fake.terminating = None;
        if let Some(handle) = fake.link.take() {
            let [lo, hi] = handle.to_le_bytes();
            fake.event(EVENT_DISCONNECTION_COMPLETE, &[0, lo, hi, 0x13]);
        }
    }

    pub fn stats(&self) -> FakeStats {
        self.0.borrow().stats
    }

    /// Whether every scripted packet went to the host.
    pub fn script_done(&self) -> bool {
        let fake = self.0.borrow();
        fake.script.is_empty() && fake.to_host.is_empty()
    }

    pub fn connected(&self) -> bool {
        self.0.borrow().link.is_some()
    }

    /// From now on the pad serves HID over GATT as an Xbox Wireless Controller with
    /// this Report Map (its HID characteristics need an encrypted link).
    pub fn serve_gamepad(&self, report_map: Vec<u8>) {
        self.0.borrow_mut().gatt = Some(GattTable::xbox_pad(report_map));
    }

    /// Whether the host subscribed to the input report on the open link.
    pub fn subscribed(&self) -> bool {
        let fake = self.0.borrow();
        fake.link.is_some() && fake.subscribed
    }

    /// The pad notifies this input report, if the host subscribed to it.
    pub fn notify(&self, report: XboxReport) {
        let mut fake = self.0.borrow_mut();
        if fake.link.is_none() || !fake.subscribed {
            return;
        }
        let mut pdu = vec![ATT_HANDLE_VALUE_NTF];
        pdu.extend_from_slice(&INPUT_REPORT_HANDLE.to_le_bytes());
        pdu.extend_from_slice(&report.bytes());
        fake.send_att(&pdu);
    }

    /// On every link from now on, these packets (H4, as for [`Self::script`]) reach
    /// the host at `at`: a pad that misbehaves every time.
    pub fn attack_every_link(&self, at: AttackAt, packets: impl IntoIterator<Item = Vec<u8>>) {
        let mut fake = self.0.borrow_mut();
        fake.attacks
            .extend(packets.into_iter().map(|packet| (at, packet)));
    }

    /// No more attacks.
    pub fn peace(&self) {
        self.0.borrow_mut().attacks.clear();
    }

    /// From now on the pad at the bonded address has no key (`true`: an impostor, whose
    /// every encryption fails with PIN or Key Missing), or is the owner's pad again.
    pub fn impostor(&self, impostor: bool) {
        self.0.borrow_mut().impostor = impostor;
    }

    /// The host's next read fails, as a broken UART or a dead radio driver would.
    pub fn fail_next_read(&self) {
        let mut fake = self.0.borrow_mut();
        fake.read_error = true;
        if let Some(waker) = fake.reader.take() {
            waker.wake();
        }
    }

    /// Raw bytes to the host (H4, type byte first): a packet no controller should
    /// send, say.
    pub fn send_raw(&self, bytes: &[u8]) {
        self.0.borrow_mut().send(bytes);
    }
}

impl embedded_io::ErrorType for FakeReader {
    type Error = HciError;
}

impl embedded_io::ErrorType for FakeWriter {
    type Error = HciError;
}

impl embedded_io_async::Read for FakeReader {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, HciError> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            let termination = self.0.borrow().terminating.map(|(_, due)| due);
            let data = poll_fn(|cx| {
                let mut fake = self.0.borrow_mut();
                // Between packets only: the next read starts a packet again.
                if fake.read_error && fake.to_host.is_empty() {
                    fake.read_error = false;
                    return Poll::Ready(Err(HciError(std::io::ErrorKind::BrokenPipe)));
                }
                if fake.to_host.is_empty() {
                    fake.reader = Some(cx.waker().clone());
                    return Poll::Pending;
                }
                let n = buf.len().min(fake.to_host.len());
                for (to, from) in buf.iter_mut().zip(fake.to_host.drain(..n)) {
                    *to = from;
                }
                Poll::Ready(Ok(n))
            });
            let Some(due) = termination else {
                return data.await;
            };
            match select(data, Timer::at(due)).await {
                Either::First(read) => return read,
                Either::Second(()) => self.0.borrow_mut().end_termination(),
            }
        }
    }
}

impl embedded_io_async::Write for FakeWriter {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, HciError> {
        self.0.borrow_mut().on_bytes(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), HciError> {
        Ok(())
    }
}
