//! The guard between the Bluetooth controller (HCI) and the BLE host: every event and
//! every ACL packet from the radio passes [`Guard`] before the host (trouble-host) sees
//! it. The host is written for well-behaved peers; a peer is anyone in radio range, so
//! a packet the host would choke on (an index out of bounds, an unwrap on `None`) or
//! that would make it pair outside the pairing window is dropped here, counted, and the
//! link to that peer is closed.
//!
//! ```text
//!   radio ──HCI──▶ Guard::on_event ──Pass──────────────────────────────▶ host
//!            │       (tracks which handle is which link)
//!            └───▶ Guard::on_acl ──Deliver(route)──────────────────────▶ host of that route
//!                                ├─Drop(rule)─────────▶ counted
//!                                └─Close(rule)────────▶ counted; Guard::next_link_to_close
//!                                                        → the caller sends HCI Disconnect
//! ```
//!
//! Every link is born at its Connection Complete event with a [`Route`]: today every
//! link is LE and goes to the LE host. The same decision, per handle, is where a Classic
//! (BR/EDR) link would be routed to a Classic host.
//!
//! # The rules, for a peer on an LE link (we are the central)
//!
//! - **Framing**: no broadcast flag, a known boundary flag; a first fragment holds the
//!   whole L2CAP basic header, is not longer than the PDU it announces, and no earlier
//!   PDU of the link is still incomplete; a continuation continues one and does not
//!   overrun it. ([`Rule::Framing`])
//! - **Channels**: only ATT (4), LE signalling (5) and the Security Manager (6); channel
//!   0 and every other channel are refused (we open no dynamic channels). ([`Rule::Channel`])
//! - **Signalling**: one command per PDU (as LE requires) whose length field matches,
//!   with the exact length its code needs; disconnection requests and responses name a
//!   dynamic channel (0x0040 and up), never 0. ([`Rule::Signalling`])
//! - **ATT**: not empty, and at least as long as its opcode needs ([`att_min_len`]); a
//!   Read By Group Type Request only with a 16-bit type. ([`Rule::AttLength`])
//! - **SMP**: a Security Request is dropped but the link stays (a bonded pad may ask
//!   for encryption; we encrypt with the bond ourselves, and inside the window we start
//!   pairing ourselves). A Pairing Request from a peripheral, any other SMP outside the
//!   pairing window, and any SMP of the wrong length close the link. ([`Rule::Smp`],
//!   [`Rule::SecurityRequest`])
//! - **Links**: ACL for a handle that is not an open link is dropped; once a link is
//!   being closed, everything from it is dropped, and the host's own commands for it
//!   are kept from the controller ([`Guard::is_closing`]). ([`Rule::UnknownHandle`],
//!   [`Rule::Closing`])
//! - **Events**: an event that does not parse as its code says is dropped (the host
//!   unwraps the parse of most events); the parse is the HCI crate's, so the caller
//!   does it and counts it here ([`Guard::count_malformed_event`]).

use crate::hci::Handle;

/// L2CAP fixed channels of an LE link.
pub const CID_ATT: u16 = 0x0004;
pub const CID_LE_SIGNALLING: u16 = 0x0005;
pub const CID_SMP: u16 = 0x0006;
/// The first dynamic channel (LE credit-based channels).
pub const CID_DYNAMIC_FIRST: u16 = 0x0040;

/// Where the packets of a link go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Route {
    /// The BLE host (trouble-host).
    LeHost,
}

/// Which rule a packet broke.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rule {
    UnknownHandle,
    Closing,
    Framing,
    Channel,
    Signalling,
    AttLength,
    Smp,
    SecurityRequest,
}

/// What to do with an ACL packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AclVerdict {
    /// Hand it to the host of this route.
    Deliver(Route),
    /// Drop it; the link stays.
    Drop(Rule),
    /// Drop it and close the link ([`Guard::next_link_to_close`] says which).
    Close(Rule),
}

/// How many packets each rule dropped, and how many links the guard closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    pub unknown_handle: u32,
    pub closing: u32,
    pub framing: u32,
    pub channel: u32,
    pub signalling: u32,
    pub att_length: u32,
    pub smp: u32,
    pub security_request: u32,
    /// Events from the controller that do not parse (the wrapper parses them).
    pub malformed_events: u32,
    pub links_closed: u32,
}

impl Counters {
    fn count(&mut self, rule: Rule) {
        let counter = match rule {
            Rule::UnknownHandle => &mut self.unknown_handle,
            Rule::Closing => &mut self.closing,
            Rule::Framing => &mut self.framing,
            Rule::Channel => &mut self.channel,
            Rule::Signalling => &mut self.signalling,
            Rule::AttLength => &mut self.att_length,
            Rule::Smp => &mut self.smp,
            Rule::SecurityRequest => &mut self.security_request,
        };
        *counter = counter.saturating_add(1);
    }

    /// Packets dropped, whatever the rule.
    pub fn dropped(&self) -> u32 {
        [
            self.unknown_handle,
            self.closing,
            self.framing,
            self.channel,
            self.signalling,
            self.att_length,
            self.smp,
            self.security_request,
            self.malformed_events,
        ]
        .iter()
        .fold(0u32, |sum, n| sum.saturating_add(*n))
    }
}

/// ACL packet boundary flag (HCI), as the controller sends it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Boundary {
    /// The first fragment of an L2CAP PDU (0b00 or 0b10).
    First,
    /// A continuation fragment (0b01).
    Continuing,
    /// Anything else (0b11: a complete automatically flushable PDU, not for LE).
    Other,
}

impl Boundary {
    /// From the two boundary bits of the ACL header.
    pub fn from_bits(bits: u8) -> Boundary {
        match bits & 0b11 {
            0b00 | 0b10 => Boundary::First,
            0b01 => Boundary::Continuing,
            _ => Boundary::Other,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reassembly {
    Idle,
    /// The host is collecting a PDU; this many bytes are still to come.
    Passing {
        remaining: u16,
    },
    /// A dropped PDU's remaining bytes are dropped too.
    Skipping {
        remaining: u16,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LinkState {
    Open(Reassembly),
    /// The guard asked to close it; `requested` once the caller took it.
    Closing {
        requested: bool,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Link {
    handle: u16,
    route: Route,
    state: LinkState,
}

/// The guard: the links the controller reported, the pairing window, the counters.
/// `LINKS` is the most links it tracks at once (a link beyond that is refused).
#[derive(Debug, Clone)]
pub struct Guard<const LINKS: usize> {
    links: [Option<Link>; LINKS],
    pairing_open: bool,
    counters: Counters,
}

impl<const LINKS: usize> Default for Guard<LINKS> {
    fn default() -> Self {
        Self::new()
    }
}

// HCI event codes and LE subevents the guard follows.
const EVENT_DISCONNECTION_COMPLETE: u8 = 0x05;
const EVENT_ENCRYPTION_CHANGE: u8 = 0x08;
const EVENT_KEY_REFRESH_COMPLETE: u8 = 0x30;
const EVENT_ENCRYPTION_CHANGE_V2: u8 = 0x59;
const EVENT_LE_META: u8 = 0x3E;
const LE_CONNECTION_COMPLETE: u8 = 0x01;
const LE_ENHANCED_CONNECTION_COMPLETE: u8 = 0x0A;
const LE_ENHANCED_CONNECTION_COMPLETE_V2: u8 = 0x29;

impl<const LINKS: usize> Guard<LINKS> {
    pub const fn new() -> Self {
        Self {
            links: [None; LINKS],
            pairing_open: false,
            counters: Counters {
                unknown_handle: 0,
                closing: 0,
                framing: 0,
                channel: 0,
                signalling: 0,
                att_length: 0,
                smp: 0,
                security_request: 0,
                malformed_events: 0,
                links_closed: 0,
            },
        }
    }

    /// Opens or closes the pairing window: SMP (other than a Security Request) passes
    /// only while it is open.
    pub fn set_pairing_window(&mut self, open: bool) {
        self.pairing_open = open;
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// The caller dropped an event from the controller that does not parse.
    pub fn count_malformed_event(&mut self) {
        self.counters.malformed_events = self.counters.malformed_events.saturating_add(1);
    }

    /// Follows an HCI event (code and parameters): connection complete events open a
    /// link, disconnection complete closes it. Returns whether the host may see it:
    /// an encryption event for a handle that is no open link is dropped (the host
    /// stops altogether on one).
    pub fn on_event(&mut self, code: u8, params: &[u8]) -> bool {
        if let (
            EVENT_ENCRYPTION_CHANGE | EVENT_ENCRYPTION_CHANGE_V2 | EVENT_KEY_REFRESH_COMPLETE,
            [_, lo, hi, ..],
        ) = (code, params)
        {
            let handle = handle_of(*lo, *hi);
            let known = self
                .links
                .iter()
                .flatten()
                .any(|link| link.handle == handle);
            if !known {
                self.counters.unknown_handle = self.counters.unknown_handle.saturating_add(1);
            }
            return known;
        }
        match (code, params) {
            (EVENT_DISCONNECTION_COMPLETE, [0x00, lo, hi, ..]) => {
                let handle = handle_of(*lo, *hi);
                for slot in self.links.iter_mut() {
                    if slot.is_some_and(|link| link.handle == handle) {
                        *slot = None;
                    }
                }
            }
            (
                EVENT_LE_META,
                [
                    LE_CONNECTION_COMPLETE
                    | LE_ENHANCED_CONNECTION_COMPLETE
                    | LE_ENHANCED_CONNECTION_COMPLETE_V2,
                    0x00,
                    lo,
                    hi,
                    ..,
                ],
            ) => self.open_link(handle_of(*lo, *hi), Route::LeHost),
            _ => {}
        }
        true
    }

    fn open_link(&mut self, handle: u16, route: Route) {
        let link = Link {
            handle,
            route,
            state: LinkState::Open(Reassembly::Idle),
        };
        if let Some(slot) = self
            .links
            .iter_mut()
            .find(|slot| slot.is_some_and(|link| link.handle == handle))
        {
            // A handle the controller reuses without a disconnection: a new link.
            *slot = Some(link);
        } else if let Some(slot) = self.links.iter_mut().find(|slot| slot.is_none()) {
            *slot = Some(link);
        }
        // With every slot taken (more links than the host can hold) the link is not
        // followed, and everything it sends is dropped as from an unknown handle.
    }

    /// Decides about one ACL packet from the controller: `handle` and the two boundary
    /// bits and two broadcast bits of its header, and its data.
    pub fn on_acl(&mut self, handle: u16, boundary: u8, broadcast: u8, data: &[u8]) -> AclVerdict {
        let pairing_open = self.pairing_open;
        let Some(link) = self
            .links
            .iter_mut()
            .flatten()
            .find(|link| link.handle == handle)
        else {
            self.counters.count(Rule::UnknownHandle);
            return AclVerdict::Drop(Rule::UnknownHandle);
        };
        let verdict = match link.state {
            LinkState::Closing { .. } => AclVerdict::Drop(Rule::Closing),
            LinkState::Open(reassembly) => {
                let (verdict, next) =
                    check_fragment(reassembly, boundary, broadcast, data, pairing_open);
                link.state = match verdict {
                    AclVerdict::Close(_) => LinkState::Closing { requested: false },
                    _ => LinkState::Open(next),
                };
                match verdict {
                    AclVerdict::Deliver(_) => AclVerdict::Deliver(link.route),
                    other => other,
                }
            }
        };
        match verdict {
            AclVerdict::Deliver(_) => {}
            AclVerdict::Drop(rule) => self.counters.count(rule),
            AclVerdict::Close(rule) => {
                self.counters.count(rule);
                self.counters.links_closed = self.counters.links_closed.saturating_add(1);
            }
        }
        verdict
    }

    /// Whether the guard is closing the link `handle` (from the packet that broke a rule
    /// until its Disconnection Complete). The host's own commands for that link are
    /// kept from the controller: a second Disconnect of a link already ending is
    /// refused by a controller with Command Disallowed, and trouble-host 0.8 stops
    /// altogether on that answer.
    pub fn is_closing(&self, handle: u16) -> bool {
        self.links
            .iter()
            .flatten()
            .any(|link| link.handle == handle && matches!(link.state, LinkState::Closing { .. }))
    }

    /// The next link the caller must close with HCI Disconnect (each is given once).
    pub fn next_link_to_close(&mut self) -> Option<u16> {
        self.links.iter_mut().flatten().find_map(|link| {
            (link.state == LinkState::Closing { requested: false }).then(|| {
                link.state = LinkState::Closing { requested: true };
                link.handle
            })
        })
    }
}

/// The link a host's HCI command is about (`opcode` and the first bytes of its
/// parameters), for the commands the BLE host sends on a link: Disconnect, LE
/// Connection Update, LE Read Remote Features, LE Enable Encryption, the LE Long Term
/// Key and Remote Connection Parameter Request replies, LE Set Data Length, Read RSSI.
pub fn command_link(opcode: u16, params: &[u8]) -> Option<u16> {
    const ON_A_LINK: [u16; 10] = [
        0x0406, // Disconnect
        0x1405, // Read RSSI
        0x2013, // LE Connection Update
        0x2016, // LE Read Remote Features
        0x2019, // LE Enable Encryption
        0x201A, // LE Long Term Key Request Reply
        0x201B, // LE Long Term Key Request Negative Reply
        0x2020, // LE Remote Connection Parameter Request Reply
        0x2021, // LE Remote Connection Parameter Request Negative Reply
        0x2022, // LE Set Data Length
    ];
    match params {
        [lo, hi, ..] if ON_A_LINK.contains(&opcode) => Some(handle_of(*lo, *hi)),
        _ => None,
    }
}

fn handle_of(lo: u8, hi: u8) -> u16 {
    Handle::from_field(lo, hi).0
}

/// One fragment against the link's reassembly: the verdict and the next state.
fn check_fragment(
    reassembly: Reassembly,
    boundary: u8,
    broadcast: u8,
    data: &[u8],
    pairing_open: bool,
) -> (AclVerdict, Reassembly) {
    let close = |rule| (AclVerdict::Close(rule), Reassembly::Idle);
    if broadcast != 0 {
        return close(Rule::Framing);
    }
    match (Boundary::from_bits(boundary), reassembly) {
        (Boundary::Other, _) | (Boundary::First, Reassembly::Passing { .. }) => {
            close(Rule::Framing)
        }
        (Boundary::Continuing, Reassembly::Idle) => close(Rule::Framing),
        (Boundary::Continuing, Reassembly::Passing { remaining })
        | (Boundary::Continuing, Reassembly::Skipping { remaining }) => {
            let Some(left) = usize::from(remaining).checked_sub(data.len()) else {
                return close(Rule::Framing);
            };
            let left = left as u16;
            let next = |remaining| match left {
                0 => Reassembly::Idle,
                _ => remaining,
            };
            match reassembly {
                Reassembly::Passing { .. } => (
                    AclVerdict::Deliver(Route::LeHost),
                    next(Reassembly::Passing { remaining: left }),
                ),
                _ => (
                    AclVerdict::Drop(Rule::SecurityRequest),
                    next(Reassembly::Skipping { remaining: left }),
                ),
            }
        }
        // A dropped PDU's first fragment arrived and a new one starts: fine.
        (Boundary::First, Reassembly::Idle | Reassembly::Skipping { .. }) => {
            let [l0, l1, c0, c1, payload @ ..] = data else {
                return close(Rule::Framing);
            };
            let length = u16::from_le_bytes([*l0, *l1]);
            let channel = u16::from_le_bytes([*c0, *c1]);
            let Some(remaining) = usize::from(length).checked_sub(payload.len()) else {
                return close(Rule::Framing);
            };
            let remaining = remaining as u16;
            let verdict = check_pdu(channel, usize::from(length), payload, pairing_open);
            let next = match (verdict, remaining) {
                (_, 0) => Reassembly::Idle,
                (AclVerdict::Deliver(_), _) => Reassembly::Passing { remaining },
                _ => Reassembly::Skipping { remaining },
            };
            match verdict {
                AclVerdict::Close(_) => (verdict, Reassembly::Idle),
                _ => (verdict, next),
            }
        }
    }
}

/// One L2CAP PDU of `length` bytes, of which `start` arrived in the first fragment.
fn check_pdu(channel: u16, length: usize, start: &[u8], pairing_open: bool) -> AclVerdict {
    match channel {
        CID_ATT => check_att(length, start),
        CID_LE_SIGNALLING => check_signalling(length, start),
        CID_SMP => check_smp(length, start, pairing_open),
        _ => AclVerdict::Close(Rule::Channel),
    }
}

fn check_att(length: usize, start: &[u8]) -> AclVerdict {
    let Some(&opcode) = start.first() else {
        return AclVerdict::Close(Rule::AttLength);
    };
    let long_enough = length >= att_min_len(opcode);
    // trouble-host 0.8 slices a 128-bit group type one byte past the PDU.
    let group_type_ok = opcode != ATT_READ_BY_GROUP_TYPE_REQ || length == 7;
    if long_enough && group_type_ok {
        AclVerdict::Deliver(Route::LeHost)
    } else {
        AclVerdict::Close(Rule::AttLength)
    }
}

const ATT_READ_BY_GROUP_TYPE_REQ: u8 = 0x10;

/// The shortest ATT PDU (opcode included) the Attribute Protocol allows for `opcode`;
/// 1 for opcodes it does not define (the host answers those with an error).
pub const fn att_min_len(opcode: u8) -> usize {
    match opcode {
        0x01 => 5,        // Error Response: request opcode, handle, error code
        0x02 | 0x03 => 3, // Exchange MTU Request / Response: MTU
        0x04 => 5,        // Find Information Request: start, end
        0x05 => 6,        // Find Information Response: format, one handle + 16-bit UUID
        0x06 => 7,        // Find By Type Value Request: start, end, type
        0x07 => 5,        // Find By Type Value Response: one handle range
        0x08 => 7,        // Read By Type Request: start, end, 16-bit type
        0x09 => 4,        // Read By Type Response: length, one handle
        0x0A => 3,        // Read Request: handle
        0x0C => 5,        // Read Blob Request: handle, offset
        0x0E => 5,        // Read Multiple Request: two handles
        0x10 => 7,        // Read By Group Type Request: start, end, 16-bit type
        0x11 => 6,        // Read By Group Type Response: length, one start + end handle
        0x12 => 3,        // Write Request: handle
        0x16 | 0x17 => 5, // Prepare Write Request / Response: handle, offset
        0x18 => 2,        // Execute Write Request: flags
        0x1B | 0x1D => 3, // Handle Value Notification / Indication: handle
        0x20 => 5,        // Read Multiple Variable Request: two handles
        0x23 => 5,        // Multiple Handle Value Notification: handle, length
        0x52 => 3,        // Write Command: handle
        0xD2 => 15,       // Signed Write Command: handle, signature
        _ => 1,
    }
}

// LE signalling command codes and the exact length of their data.
fn signalling_data_len(code: u8) -> Option<usize> {
    match code {
        0x01 => None, // Command Reject: 2 bytes of reason and up to 4 of data (checked below)
        0x06 | 0x07 => Some(4), // Disconnection Request / Response: destination, source CID
        0x12 => Some(8), // Connection Parameter Update Request
        0x13 => Some(2), // Connection Parameter Update Response
        0x14 | 0x15 => Some(10), // LE Credit Based Connection Request / Response
        0x16 => Some(4), // Flow Control Credit Indication
        _ => Some(0), // unknown: the host rejects it; nothing of it is read
    }
}

fn check_signalling(length: usize, start: &[u8]) -> AclVerdict {
    let refuse = AclVerdict::Close(Rule::Signalling);
    // A signalling PDU is short; it must be whole in the first fragment.
    if start.len() != length {
        return refuse;
    }
    let [code, _identifier, l0, l1, data @ ..] = start else {
        return refuse;
    };
    let data_len = usize::from(u16::from_le_bytes([*l0, *l1]));
    if data_len != data.len() {
        return refuse;
    }
    let well_formed = match signalling_data_len(*code) {
        None => (2..=6).contains(&data_len),
        Some(expected) if matches!(*code, 0x06 | 0x07) => {
            data_len == expected && {
                let destination = u16::from_le_bytes([data[0], data[1]]);
                let source = u16::from_le_bytes([data[2], data[3]]);
                destination >= CID_DYNAMIC_FIRST && source >= CID_DYNAMIC_FIRST
            }
        }
        Some(0) => true,
        Some(expected) => data_len == expected,
    };
    if well_formed {
        AclVerdict::Deliver(Route::LeHost)
    } else {
        refuse
    }
}

const SMP_PAIRING_REQUEST: u8 = 0x01;
const SMP_SECURITY_REQUEST: u8 = 0x0B;

/// The length of each SMP command a peripheral may send (code included).
fn smp_len(code: u8) -> Option<usize> {
    match code {
        0x02 => Some(7),  // Pairing Response
        0x03 => Some(17), // Pairing Confirm
        0x04 => Some(17), // Pairing Random
        0x05 => Some(2),  // Pairing Failed
        0x06 => Some(17), // Encryption Information
        0x07 => Some(11), // Central Identification
        0x08 => Some(17), // Identity Information
        0x09 => Some(8),  // Identity Address Information
        0x0A => Some(17), // Signing Information
        0x0B => Some(2),  // Security Request
        0x0C => Some(65), // Pairing Public Key
        0x0D => Some(17), // Pairing DHKey Check
        0x0E => Some(2),  // Keypress Notification
        _ => None,
    }
}

fn check_smp(length: usize, start: &[u8], pairing_open: bool) -> AclVerdict {
    let Some(&code) = start.first() else {
        return AclVerdict::Close(Rule::Smp);
    };
    if smp_len(code) != Some(length) || code == SMP_PAIRING_REQUEST {
        return AclVerdict::Close(Rule::Smp);
    }
    match (code, pairing_open) {
        (SMP_SECURITY_REQUEST, _) => AclVerdict::Drop(Rule::SecurityRequest),
        (_, true) => AclVerdict::Deliver(Route::LeHost),
        (_, false) => AclVerdict::Close(Rule::Smp),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HANDLE: u16 = 0x0040;

    /// A guard with one open LE link at [`HANDLE`].
    fn guard() -> Guard<2> {
        let mut guard = Guard::new();
        guard.on_event(
            EVENT_LE_META,
            &[
                LE_CONNECTION_COMPLETE,
                0,
                0x40,
                0x00,
                0,
                1,
                0,
                0,
                0,
                0,
                0,
                0,
            ],
        );
        guard
    }

    /// An unfragmented L2CAP PDU on `channel`.
    fn pdu(channel: u16, payload: &[u8]) -> Vec<u8> {
        let mut data = Vec::new();
        data.extend_from_slice(&(payload.len() as u16).to_le_bytes());
        data.extend_from_slice(&channel.to_le_bytes());
        data.extend_from_slice(payload);
        data
    }

    fn first(guard: &mut Guard<2>, data: &[u8]) -> AclVerdict {
        guard.on_acl(HANDLE, 0b10, 0, data)
    }

    const DELIVER: AclVerdict = AclVerdict::Deliver(Route::LeHost);

    #[test]
    fn the_packets_of_a_working_pad_pass() {
        let window_closed: &[(&str, u16, &[u8])] = &[
            ("notification", CID_ATT, &[0x1B, 0x2A, 0x00, 1, 2, 3]),
            ("read response", CID_ATT, &[0x0B, 0x11, 0x01]),
            ("empty read response", CID_ATT, &[0x0B]),
            ("error response", CID_ATT, &[0x01, 0x0A, 0x03, 0x00, 0x05]),
            ("mtu request", CID_ATT, &[0x02, 0x17, 0x00]),
            ("write response", CID_ATT, &[0x13]),
            ("unknown opcode", CID_ATT, &[0x3F]),
            (
                "parameter request",
                CID_LE_SIGNALLING,
                &[0x12, 1, 8, 0, 6, 0, 12, 0, 0, 0, 0x58, 0x02],
            ),
            ("command reject", CID_LE_SIGNALLING, &[0x01, 1, 2, 0, 0, 0]),
        ];
        for (what, channel, payload) in window_closed {
            let mut guard = guard();
            assert_eq!(
                first(&mut guard, &pdu(*channel, payload)),
                DELIVER,
                "{what}"
            );
        }
        let mut guard = guard();
        guard.set_pairing_window(true);
        let pairing_response = [0x02, 0x03, 0x00, 0x0D, 0x10, 0x03, 0x03];
        assert_eq!(first(&mut guard, &pdu(CID_SMP, &pairing_response)), DELIVER);
        assert_eq!(guard.counters(), Counters::default());
        assert_eq!(guard.next_link_to_close(), None);
    }

    #[test]
    fn each_rule_drops_or_closes_and_counts() {
        use AclVerdict::{Close, Drop};
        let cases: &[(&str, bool, Vec<u8>, AclVerdict)] = &[
            (
                "empty ATT PDU",
                false,
                pdu(CID_ATT, &[]),
                Close(Rule::AttLength),
            ),
            (
                "MTU request without MTU",
                false,
                pdu(CID_ATT, &[0x02]),
                Close(Rule::AttLength),
            ),
            (
                "read with 1-byte handle",
                false,
                pdu(CID_ATT, &[0x0A, 1]),
                Close(Rule::AttLength),
            ),
            (
                "3-byte error response",
                false,
                pdu(CID_ATT, &[0x01, 0x0A, 0]),
                Close(Rule::AttLength),
            ),
            (
                "write command without handle",
                false,
                pdu(CID_ATT, &[0x52]),
                Close(Rule::AttLength),
            ),
            (
                "group type with 128-bit UUID",
                false,
                pdu(
                    CID_ATT,
                    &[
                        0x10, 1, 0, 0xFF, 0xFF, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
                    ],
                ),
                Close(Rule::AttLength),
            ),
            (
                "disconnection request for channel 0",
                false,
                pdu(CID_LE_SIGNALLING, &[0x06, 1, 4, 0, 0, 0, 0x40, 0]),
                Close(Rule::Signalling),
            ),
            (
                "disconnection response for channel 0",
                false,
                pdu(CID_LE_SIGNALLING, &[0x07, 1, 4, 0, 0x40, 0, 0, 0]),
                Close(Rule::Signalling),
            ),
            (
                "signalling length field too long",
                false,
                pdu(
                    CID_LE_SIGNALLING,
                    &[0x12, 1, 9, 0, 6, 0, 12, 0, 0, 0, 0x58, 0x02],
                ),
                Close(Rule::Signalling),
            ),
            (
                "short parameter request",
                false,
                pdu(CID_LE_SIGNALLING, &[0x12, 1, 2, 0, 6, 0]),
                Close(Rule::Signalling),
            ),
            (
                "two signalling commands",
                false,
                pdu(
                    CID_LE_SIGNALLING,
                    &[0x13, 1, 2, 0, 0, 0, 0x13, 2, 2, 0, 0, 0],
                ),
                Close(Rule::Signalling),
            ),
            (
                "truncated signalling header",
                false,
                pdu(CID_LE_SIGNALLING, &[0x12, 1]),
                Close(Rule::Signalling),
            ),
            ("channel 0", false, pdu(0, &[1, 2, 3]), Close(Rule::Channel)),
            (
                "dynamic channel",
                false,
                pdu(0x0040, &[1, 2, 3]),
                Close(Rule::Channel),
            ),
            (
                "security request, MITM",
                false,
                pdu(CID_SMP, &[0x0B, 0x0D]),
                Drop(Rule::SecurityRequest),
            ),
            (
                "security request, no MITM",
                false,
                pdu(CID_SMP, &[0x0B, 0x01]),
                Drop(Rule::SecurityRequest),
            ),
            (
                "security request in the window",
                true,
                pdu(CID_SMP, &[0x0B, 0x01]),
                Drop(Rule::SecurityRequest),
            ),
            (
                "pairing request from the peripheral",
                true,
                pdu(CID_SMP, &[0x01, 0x03, 0x00, 0x01, 0x10, 0x07, 0x07]),
                Close(Rule::Smp),
            ),
            (
                "pairing response outside the window",
                false,
                pdu(CID_SMP, &[0x02, 0x03, 0x00, 0x0D, 0x10, 0x03, 0x03]),
                Close(Rule::Smp),
            ),
            (
                "pairing failed outside the window",
                false,
                pdu(CID_SMP, &[0x05, 0x05]),
                Close(Rule::Smp),
            ),
            (
                "short pairing confirm in the window",
                true,
                pdu(CID_SMP, &[0x03, 1, 2]),
                Close(Rule::Smp),
            ),
            ("empty SMP", true, pdu(CID_SMP, &[]), Close(Rule::Smp)),
            (
                "unknown SMP code",
                true,
                pdu(CID_SMP, &[0x0F, 0]),
                Close(Rule::Smp),
            ),
            (
                "L2CAP header cut short",
                false,
                vec![4, 0, 4],
                Close(Rule::Framing),
            ),
            (
                "PDU longer than announced",
                false,
                vec![1, 0, 4, 0, 0x13, 0x13],
                Close(Rule::Framing),
            ),
        ];
        for (what, window, data, expected) in cases {
            let mut guard = guard();
            guard.set_pairing_window(*window);
            assert_eq!(first(&mut guard, data), *expected, "{what}");
            assert_eq!(guard.counters().dropped(), 1, "{what}: counted once");
            let closes = matches!(expected, Close(_));
            assert_eq!(
                guard.next_link_to_close(),
                closes.then_some(HANDLE),
                "{what}"
            );
            assert_eq!(guard.next_link_to_close(), None, "{what}: asked once");
            assert_eq!(guard.counters().links_closed, u32::from(closes), "{what}");
            // A closed link passes nothing more; a dropped security request keeps it.
            let next = first(&mut guard, &pdu(CID_ATT, &[0x1B, 1, 0, 7]));
            assert_eq!(next == DELIVER, !closes, "{what}: then {next:?}");
        }
    }

    #[test]
    fn fragments_pass_in_order_and_a_broken_sequence_closes_the_link() {
        // An 8-byte notification in two fragments.
        let mut guard = guard();
        let whole = pdu(CID_ATT, &[0x1B, 0x2A, 0x00, 1, 2, 3, 4, 5]);
        assert_eq!(first(&mut guard, &whole[..7]), DELIVER);
        assert_eq!(guard.on_acl(HANDLE, 0b01, 0, &whole[7..]), DELIVER);
        // The length check uses the L2CAP length, whatever the first fragment holds.
        let short_mtu = pdu(CID_ATT, &[0x02]);
        let mut guard = self::guard();
        assert_eq!(
            first(&mut guard, &short_mtu),
            AclVerdict::Close(Rule::AttLength)
        );

        // (what, fragments as (boundary flag, data)).
        type Case<'a> = (&'a str, &'a [(u8, &'a [u8])]);
        let cases: &[Case] = &[
            ("continuation without a start", &[(0b01, &[1, 2])]),
            (
                "new start before the end",
                &[(0b10, &[8, 0, 4, 0, 0x1B]), (0b10, &[1, 0, 4, 0, 0x13])],
            ),
            (
                "continuation overruns",
                &[(0b10, &[3, 0, 4, 0, 0x1B]), (0b01, &[1, 0, 9])],
            ),
            ("boundary flag 0b11", &[(0b11, &[1, 0, 4, 0, 0x13])]),
        ];
        for (what, fragments) in cases {
            let mut guard = self::guard();
            let verdicts: Vec<AclVerdict> = fragments
                .iter()
                .map(|(boundary, data)| guard.on_acl(HANDLE, *boundary, 0, data))
                .collect();
            assert_eq!(
                verdicts.last(),
                Some(&AclVerdict::Close(Rule::Framing)),
                "{what}"
            );
            assert_eq!(guard.next_link_to_close(), Some(HANDLE), "{what}");
        }
        let mut guard = self::guard();
        assert_eq!(
            guard.on_acl(HANDLE, 0b10, 1, &pdu(CID_ATT, &[0x13])),
            AclVerdict::Close(Rule::Framing),
            "broadcast flag"
        );
    }

    #[test]
    fn unknown_handles_are_dropped_and_a_disconnection_forgets_the_link() {
        let mut guard = guard();
        let packet = pdu(CID_ATT, &[0x13]);
        assert_eq!(
            guard.on_acl(0x0041, 0b10, 0, &packet),
            AclVerdict::Drop(Rule::UnknownHandle)
        );
        assert_eq!(
            first(&mut guard, &pdu(CID_ATT, &[])),
            AclVerdict::Close(Rule::AttLength)
        );
        assert_eq!(guard.next_link_to_close(), Some(HANDLE));
        guard.on_event(EVENT_DISCONNECTION_COMPLETE, &[0, 0x40, 0x00, 0x13]);
        assert_eq!(
            first(&mut guard, &packet),
            AclVerdict::Drop(Rule::UnknownHandle)
        );
        // The controller reuses the handle for the next link, which starts clean.
        guard.on_event(
            EVENT_LE_META,
            &[LE_ENHANCED_CONNECTION_COMPLETE, 0, 0x40, 0x00, 0, 1],
        );
        assert_eq!(first(&mut guard, &packet), DELIVER);
        // Encryption events pass for open links only.
        assert!(guard.on_event(EVENT_ENCRYPTION_CHANGE, &[0, 0x40, 0x00, 1]));
        assert!(!guard.on_event(EVENT_ENCRYPTION_CHANGE, &[0, 0x41, 0x00, 1]));
        assert!(!guard.on_event(EVENT_KEY_REFRESH_COMPLETE, &[0, 0x41, 0x00]));
        // A failed connection opens nothing.
        guard.on_event(EVENT_LE_META, &[LE_CONNECTION_COMPLETE, 0x3E, 0x41, 0x00]);
        assert_eq!(
            guard.on_acl(0x0041, 0b10, 0, &packet),
            AclVerdict::Drop(Rule::UnknownHandle)
        );
        assert_eq!(guard.counters().unknown_handle, 5);
    }

    #[test]
    fn a_link_is_closing_from_the_refused_packet_until_its_disconnection_complete() {
        let mut guard = guard();
        assert!(!guard.is_closing(HANDLE));
        first(&mut guard, &pdu(CID_ATT, &[]));
        assert!(guard.is_closing(HANDLE), "before the caller took it");
        assert_eq!(guard.next_link_to_close(), Some(HANDLE));
        assert!(
            guard.is_closing(HANDLE),
            "while its Disconnect is under way"
        );
        assert!(!guard.is_closing(0x0041), "another handle");
        guard.on_event(EVENT_DISCONNECTION_COMPLETE, &[0, 0x40, 0x00, 0x16]);
        assert!(!guard.is_closing(HANDLE));
    }

    #[test]
    fn commands_on_a_link_name_its_handle_and_others_none() {
        assert_eq!(command_link(0x0406, &[0x40, 0x00, 0x13]), Some(0x0040));
        assert_eq!(command_link(0x2019, &[0x41, 0x10, 0, 0]), Some(0x0041));
        assert_eq!(command_link(0x2013, &[0x42, 0x00]), Some(0x0042));
        assert_eq!(command_link(0x0406, &[0x40]), None, "too short");
        assert_eq!(command_link(0x0C03, &[]), None, "Reset");
        assert_eq!(
            command_link(0x200D, &[0x40, 0x00]),
            None,
            "LE Create Connection"
        );
    }

    #[test]
    fn the_rest_of_a_dropped_security_request_is_dropped_too() {
        let mut guard = guard();
        // A Security Request split after its code (legal, if odd).
        let whole = pdu(CID_SMP, &[0x0B, 0x0D]);
        assert_eq!(
            first(&mut guard, &whole[..5]),
            AclVerdict::Drop(Rule::SecurityRequest)
        );
        assert_eq!(
            guard.on_acl(HANDLE, 0b01, 0, &whole[5..]),
            AclVerdict::Drop(Rule::SecurityRequest)
        );
        assert_eq!(first(&mut guard, &pdu(CID_ATT, &[0x13])), DELIVER);
    }
}
