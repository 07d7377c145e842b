//! The HCI splitter: one Bluetooth controller, two hosts. The BLE host (trouble-host,
//! behind the [`crate::guard`]) and the Classic host ([`crate::host`], for the
//! PlayStation pads) share the controller's one HCI transport; the splitter decides,
//! packet by packet, which host gets what the controller sends.
//!
//! ```text
//!                    ┌── Route::Le ──────▶ guard ─▶ BLE host
//!   controller ──HCI─┤
//!                    ├── Route::Classic ─▶ Classic host
//!                    └── Route::Both ────▶ each host its own share
//!   commands of both hosts ──▶ Splitter::command_sent (who owns the answer) ──▶ controller
//! ```
//!
//! - **Links**: a Classic link is born at its Connection Complete (event 0x03); its
//!   handle is remembered until its Disconnection Complete. Every event that names a
//!   handle, and every ACL packet, goes to the host of that handle: the BLE host never
//!   sees a Classic handle (it disconnects unknown handles).
//! - **Classic events** (inquiry, connection request, role change, the link key and
//!   Simple Pairing events) go to the Classic host; LE Meta events to the BLE host.
//! - **Command answers**: each Command Complete and Command Status goes to the host
//!   that sent the oldest unanswered command with that opcode (both send Disconnect,
//!   say). The credit count in it is the controller's, shared: each host sends one
//!   command at a time per answer it waits for.
//! - **Number of Completed Packets** is split: each host gets the entries of its own
//!   handles ([`Splitter::completed_packets_for`]).
//! - **Setup once**: the BLE host resets the controller and sets its event mask; the
//!   splitter widens that mask by the Classic host's events ([`Splitter::patch_command`])
//!   and, once the controller answered the BLE host's Reset, tells the Classic host the
//!   controller is fresh ([`Route::Both`] for that answer; the Classic host then runs
//!   its own setup without Reset and Set Event Mask).
//! - A Hardware Error goes to both.
//! - **Oversized packets**: a packet longer than the room a host reads it into (an ACL
//!   packet beyond the 255 bytes the hosts asked for with Host Buffer Size, up to the
//!   1021 bytes of a 3-DH5 packet) is read to its end and dropped, counted
//!   ([`Splitter::admit`]): never an error for either host, which would stop it.

use heapless::Deque;

use crate::hci::Handle;

/// Which host a packet goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Route {
    Le,
    Classic,
    /// Each host gets it (a Number of Completed Packets event: its own share of it).
    Both,
}

/// Which host sent a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Sender {
    Le,
    Classic,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Events too short for what their code says: refused (the BLE host gets them,
    /// as without the splitter; its guard counts them).
    pub malformed_events: u32,
    /// Classic links beyond [`Splitter`]'s table: refused by the Classic host.
    pub links_overflow: u32,
    /// Command answers no host waits for (after a reset, say).
    pub unowned_answers: u32,
    /// Packets longer than the host's room for them: read to their end and dropped.
    pub oversized_packets: u32,
}

// HCI opcodes the splitter looks at.
const OPCODE_RESET: u16 = 0x0C03;
const OPCODE_SET_EVENT_MASK: u16 = 0x0C01;

// HCI event codes.
const INQUIRY_COMPLETE: u8 = 0x01;
const INQUIRY_RESULT: u8 = 0x02;
const CONNECTION_COMPLETE: u8 = 0x03;
const CONNECTION_REQUEST: u8 = 0x04;
const DISCONNECTION_COMPLETE: u8 = 0x05;
const AUTHENTICATION_COMPLETE: u8 = 0x06;
const REMOTE_NAME_REQUEST_COMPLETE: u8 = 0x07;
const ENCRYPTION_CHANGE: u8 = 0x08;
const CHANGE_LINK_KEY_COMPLETE: u8 = 0x09;
const READ_REMOTE_FEATURES_COMPLETE: u8 = 0x0B;
const READ_REMOTE_VERSION_COMPLETE: u8 = 0x0C;
const COMMAND_COMPLETE: u8 = 0x0E;
const COMMAND_STATUS: u8 = 0x0F;
const HARDWARE_ERROR: u8 = 0x10;
const ROLE_CHANGE: u8 = 0x12;
const NUMBER_OF_COMPLETED_PACKETS: u8 = 0x13;
const MODE_CHANGE: u8 = 0x14;
const PIN_CODE_REQUEST: u8 = 0x16;
const LINK_KEY_REQUEST: u8 = 0x17;
const LINK_KEY_NOTIFICATION: u8 = 0x18;
const MAX_SLOTS_CHANGE: u8 = 0x1B;
const READ_CLOCK_OFFSET_COMPLETE: u8 = 0x1C;
const PACKET_TYPE_CHANGED: u8 = 0x1D;
const PAGE_SCAN_REPETITION_MODE_CHANGE: u8 = 0x20;
const INQUIRY_RESULT_WITH_RSSI: u8 = 0x22;
const READ_REMOTE_EXTENDED_FEATURES_COMPLETE: u8 = 0x23;
const EXTENDED_INQUIRY_RESULT: u8 = 0x2F;
const ENCRYPTION_KEY_REFRESH_COMPLETE: u8 = 0x30;
const IO_CAPABILITY_REQUEST: u8 = 0x31;
const IO_CAPABILITY_RESPONSE: u8 = 0x32;
const USER_CONFIRMATION_REQUEST: u8 = 0x33;
const USER_PASSKEY_REQUEST: u8 = 0x34;
const SIMPLE_PAIRING_COMPLETE: u8 = 0x36;
const LINK_SUPERVISION_TIMEOUT_CHANGED: u8 = 0x38;
const USER_PASSKEY_NOTIFICATION: u8 = 0x3B;
const KEYPRESS_NOTIFICATION: u8 = 0x3C;
const ENCRYPTION_CHANGE_V2: u8 = 0x59;

/// Where an event names its connection handle: after a status byte, or first.
fn handle_offset(code: u8) -> Option<usize> {
    match code {
        DISCONNECTION_COMPLETE
        | AUTHENTICATION_COMPLETE
        | ENCRYPTION_CHANGE
        | CHANGE_LINK_KEY_COMPLETE
        | READ_REMOTE_FEATURES_COMPLETE
        | READ_REMOTE_VERSION_COMPLETE
        | MODE_CHANGE
        | READ_CLOCK_OFFSET_COMPLETE
        | PACKET_TYPE_CHANGED
        | READ_REMOTE_EXTENDED_FEATURES_COMPLETE
        | ENCRYPTION_KEY_REFRESH_COMPLETE
        | ENCRYPTION_CHANGE_V2 => Some(1),
        MAX_SLOTS_CHANGE | LINK_SUPERVISION_TIMEOUT_CHANGED => Some(0),
        _ => None,
    }
}

/// Events only a BR/EDR link or procedure raises.
fn is_classic_only(code: u8) -> bool {
    matches!(
        code,
        INQUIRY_COMPLETE
            | INQUIRY_RESULT
            | CONNECTION_COMPLETE
            | CONNECTION_REQUEST
            | REMOTE_NAME_REQUEST_COMPLETE
            | ROLE_CHANGE
            | PIN_CODE_REQUEST
            | LINK_KEY_REQUEST
            | LINK_KEY_NOTIFICATION
            | PAGE_SCAN_REPETITION_MODE_CHANGE
            | INQUIRY_RESULT_WITH_RSSI
            | EXTENDED_INQUIRY_RESULT
            | IO_CAPABILITY_REQUEST
            | IO_CAPABILITY_RESPONSE
            | USER_CONFIRMATION_REQUEST
            | USER_PASSKEY_REQUEST
            | SIMPLE_PAIRING_COMPLETE
            | USER_PASSKEY_NOTIFICATION
            | KEYPRESS_NOTIFICATION
    )
}

fn handle_at(params: &[u8], offset: usize) -> Option<u16> {
    let bytes = params.get(offset..offset + 2)?;
    Some(Handle::from_field(bytes[0], bytes[1]).0)
}

/// The splitter's state: the Classic links (up to `LINKS`) and the commands that wait
/// for their answer (up to `PENDING`).
#[derive(Debug, Clone)]
pub struct Splitter<const LINKS: usize, const PENDING: usize> {
    classic_links: [Option<u16>; LINKS],
    pending: Deque<(u16, Sender), PENDING>,
    counters: Counters,
}

impl<const LINKS: usize, const PENDING: usize> Default for Splitter<LINKS, PENDING> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const LINKS: usize, const PENDING: usize> Splitter<LINKS, PENDING> {
    pub const fn new() -> Self {
        Self {
            classic_links: [None; LINKS],
            pending: Deque::new(),
            counters: Counters {
                malformed_events: 0,
                links_overflow: 0,
                unowned_answers: 0,
                oversized_packets: 0,
            },
        }
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Whether a packet of `len` bytes (header and body, as its header announces it)
    /// may be handed to a host that reads it into `room` bytes. One that does not fit
    /// is counted; the caller reads it to its end (the next packet starts after it)
    /// and drops it.
    pub fn admit(&mut self, len: usize, room: usize) -> bool {
        let fits = len <= room;
        if !fits {
            self.counters.oversized_packets = self.counters.oversized_packets.saturating_add(1);
        }
        fits
    }

    fn is_classic(&self, handle: u16) -> bool {
        self.classic_links.contains(&Some(handle))
    }

    /// A host sends a command packet (opcode, length, parameters): remembers who
    /// waits for its answer. The oldest entry makes room when the queue is full (a
    /// controller that stopped answering).
    pub fn command_sent(&mut self, sender: Sender, packet: &[u8]) {
        let [lo, hi, ..] = *packet else {
            return;
        };
        let opcode = u16::from_le_bytes([lo, hi]);
        if self.pending.is_full() {
            self.pending.pop_front();
        }
        let _ = self.pending.push_back((opcode, sender));
    }

    /// Changes a BLE host's command before it goes out: its Set Event Mask is widened
    /// by `classic_mask`, so that the controller raises the Classic host's events too.
    pub fn patch_command(&self, packet: &mut [u8], classic_mask: u64) {
        if let [lo, hi, 8, mask @ ..] = packet
            && u16::from_le_bytes([*lo, *hi]) == OPCODE_SET_EVENT_MASK
            && mask.len() >= 8
        {
            let mut bytes = [0u8; 8];
            bytes.copy_from_slice(&mask[..8]);
            let widened = u64::from_le_bytes(bytes) | classic_mask;
            mask[..8].copy_from_slice(&widened.to_le_bytes());
        }
    }

    /// Decides where an event (code, parameters) goes, and follows the Classic links.
    pub fn route_event(&mut self, code: u8, params: &[u8]) -> Route {
        match code {
            COMMAND_COMPLETE | COMMAND_STATUS => {
                let at = if code == COMMAND_COMPLETE { 1 } else { 2 };
                let Some(opcode) = params
                    .get(at..at + 2)
                    .map(|bytes| u16::from_le_bytes([bytes[0], bytes[1]]))
                else {
                    self.counters.malformed_events += 1;
                    return Route::Le;
                };
                if opcode == 0 {
                    // A credit update with no command: both may send again.
                    return Route::Both;
                }
                match self.take_pending(opcode) {
                    Some(Sender::Classic) => Route::Classic,
                    Some(Sender::Le) if opcode == OPCODE_RESET => {
                        // The controller is fresh: every Classic link is gone, and the
                        // Classic host sets it up again.
                        self.classic_links = [None; LINKS];
                        Route::Both
                    }
                    Some(Sender::Le) => Route::Le,
                    None => {
                        self.counters.unowned_answers += 1;
                        Route::Le
                    }
                }
            }
            CONNECTION_COMPLETE => {
                if let [0x00, lo, hi, ..] = params {
                    self.open_link(Handle::from_field(*lo, *hi).0);
                }
                Route::Classic
            }
            NUMBER_OF_COMPLETED_PACKETS => Route::Both,
            HARDWARE_ERROR => {
                self.classic_links = [None; LINKS];
                Route::Both
            }
            code if is_classic_only(code) => Route::Classic,
            code => match handle_offset(code) {
                Some(offset) => match handle_at(params, offset) {
                    Some(handle) if self.is_classic(handle) => {
                        if code == DISCONNECTION_COMPLETE && params.first() == Some(&0) {
                            self.close_link(handle);
                        }
                        Route::Classic
                    }
                    Some(_) => Route::Le,
                    None => {
                        self.counters.malformed_events += 1;
                        Route::Le
                    }
                },
                // LE Meta, vendor events and the rest: the BLE host, as without the
                // splitter.
                None => Route::Le,
            },
        }
    }

    /// Which host an ACL packet with this handle (its 12 bits) goes to.
    pub fn route_acl(&self, handle: u16) -> Route {
        if self.is_classic(Handle::from_bits(handle).0) {
            Route::Classic
        } else {
            Route::Le
        }
    }

    /// The share of `host` of a Number of Completed Packets event's parameters,
    /// written to `out` (its length returned); `None` when none of its handles is
    /// in it. A malformed event is nobody's.
    pub fn completed_packets_for(
        &self,
        params: &[u8],
        host: Sender,
        out: &mut [u8],
    ) -> Option<usize> {
        let (&count, entries) = params.split_first()?;
        let count = usize::from(count);
        if entries.len() != count * 4 || out.len() < 1 + entries.len() {
            return None;
        }
        let mut kept = 0;
        for entry in entries.as_chunks::<4>().0 {
            let handle = Handle::from_field(entry[0], entry[1]).0;
            let owner = if self.is_classic(handle) {
                Sender::Classic
            } else {
                Sender::Le
            };
            if owner == host {
                out[1 + kept * 4..1 + kept * 4 + 4].copy_from_slice(entry);
                kept += 1;
            }
        }
        out[0] = kept as u8;
        (kept > 0).then_some(1 + kept * 4)
    }

    /// Removes and returns the oldest sender waiting for `opcode`'s answer.
    fn take_pending(&mut self, opcode: u16) -> Option<Sender> {
        let mut found = None;
        for _ in 0..self.pending.len() {
            let Some(entry) = self.pending.pop_front() else {
                break;
            };
            if found.is_none() && entry.0 == opcode {
                found = Some(entry.1);
            } else {
                let _ = self.pending.push_back(entry);
            }
        }
        found
    }

    fn open_link(&mut self, handle: u16) {
        if self.is_classic(handle) {
            return;
        }
        match self.classic_links.iter_mut().find(|slot| slot.is_none()) {
            Some(slot) => *slot = Some(handle),
            None => self.counters.links_overflow += 1,
        }
    }

    fn close_link(&mut self, handle: u16) {
        for slot in self.classic_links.iter_mut() {
            if *slot == Some(handle) {
                *slot = None;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Split = Splitter<2, 8>;

    fn connection_complete(handle: u16) -> [u8; 11] {
        let [lo, hi] = handle.to_le_bytes();
        [0x00, lo, hi, 1, 2, 3, 4, 5, 6, 0x01, 0x00]
    }

    #[test]
    fn classic_events_and_links_go_to_the_classic_host_le_to_the_ble_host() {
        let mut split = Split::new();
        // (code, params, route)
        let table: &[(u8, &[u8], Route)] = &[
            (
                CONNECTION_REQUEST,
                &[1, 2, 3, 4, 5, 6, 0x08, 0x25, 0x00, 0x01],
                Route::Classic,
            ),
            (
                CONNECTION_COMPLETE,
                &connection_complete(0x0B),
                Route::Classic,
            ),
            (0x3E, &[0x01, 0x00, 0x40, 0x00], Route::Le),
            (AUTHENTICATION_COMPLETE, &[0x00, 0x0B, 0x00], Route::Classic),
            (ENCRYPTION_CHANGE, &[0x00, 0x0B, 0x00, 0x01], Route::Classic),
            (ENCRYPTION_CHANGE, &[0x00, 0x40, 0x00, 0x01], Route::Le),
            (LINK_KEY_REQUEST, &[1, 2, 3, 4, 5, 6], Route::Classic),
            (ROLE_CHANGE, &[0, 1, 2, 3, 4, 5, 6, 0], Route::Classic),
            (
                LINK_SUPERVISION_TIMEOUT_CHANGED,
                &[0x0B, 0x00, 0x50, 0x00],
                Route::Classic,
            ),
            (DISCONNECTION_COMPLETE, &[0x00, 0x40, 0x00, 0x08], Route::Le),
            (
                DISCONNECTION_COMPLETE,
                &[0x00, 0x0B, 0x00, 0x08],
                Route::Classic,
            ),
            // The handle is free again: a later LE link may get it.
            (ENCRYPTION_CHANGE, &[0x00, 0x0B, 0x00, 0x01], Route::Le),
            (HARDWARE_ERROR, &[0x01], Route::Both),
        ];
        for (code, params, route) in table {
            assert_eq!(
                split.route_event(*code, params),
                *route,
                "event {code:#x} {params:?}"
            );
        }
    }

    #[test]
    fn acl_goes_to_the_host_of_its_handle() {
        let mut split = Split::new();
        split.route_event(CONNECTION_COMPLETE, &connection_complete(0x0B));
        assert_eq!(split.route_acl(0x0B), Route::Classic);
        // Boundary flags in the top bits do not matter.
        assert_eq!(split.route_acl(0x200B), Route::Classic);
        assert_eq!(split.route_acl(0x40), Route::Le);
        // A failed connection opens no link.
        split.route_event(
            CONNECTION_COMPLETE,
            &[0x04, 0x0C, 0x00, 1, 2, 3, 4, 5, 6, 1, 0],
        );
        assert_eq!(split.route_acl(0x0C), Route::Le);
    }

    #[test]
    fn command_answers_go_to_the_oldest_sender_of_the_opcode() {
        let mut split = Split::new();
        let disconnect = [0x06, 0x04, 0x03, 0x40, 0x00, 0x13];
        split.command_sent(Sender::Classic, &disconnect);
        split.command_sent(Sender::Le, &disconnect);
        split.command_sent(Sender::Le, &[0x05, 0x10, 0x00]);
        let status = |opcode: u16| {
            let [lo, hi] = opcode.to_le_bytes();
            [0x00, 0x01, lo, hi]
        };
        let complete = |opcode: u16| {
            let [lo, hi] = opcode.to_le_bytes();
            [0x01, lo, hi, 0x00]
        };
        assert_eq!(
            split.route_event(COMMAND_STATUS, &status(0x0406)),
            Route::Classic
        );
        assert_eq!(
            split.route_event(COMMAND_COMPLETE, &complete(0x1005)),
            Route::Le
        );
        assert_eq!(
            split.route_event(COMMAND_STATUS, &status(0x0406)),
            Route::Le
        );
        // Nobody waits for it: the BLE host, counted.
        assert_eq!(
            split.route_event(COMMAND_STATUS, &status(0x0406)),
            Route::Le
        );
        assert_eq!(split.counters().unowned_answers, 1);
        // A credit update (opcode 0) is for both.
        assert_eq!(
            split.route_event(COMMAND_COMPLETE, &complete(0)),
            Route::Both
        );
        // Too short to name an opcode.
        assert_eq!(split.route_event(COMMAND_STATUS, &[0x00]), Route::Le);
        assert_eq!(split.counters().malformed_events, 1);
    }

    #[test]
    fn the_ble_hosts_reset_is_told_to_both_and_ends_every_classic_link() {
        let mut split = Split::new();
        split.route_event(CONNECTION_COMPLETE, &connection_complete(0x0B));
        split.command_sent(Sender::Le, &[0x03, 0x0C, 0x00]);
        assert_eq!(
            split.route_event(COMMAND_COMPLETE, &[1, 0x03, 0x0C, 0]),
            Route::Both
        );
        assert_eq!(split.route_acl(0x0B), Route::Le);
    }

    #[test]
    fn set_event_mask_is_widened_by_the_classic_events_and_nothing_else_is() {
        let split = Split::new();
        let mut set_mask = [0x01, 0x0C, 8, 0x10, 0, 0, 0, 0, 0, 0, 0x20];
        split.patch_command(&mut set_mask, 0x0000_0000_0000_0F01);
        assert_eq!(set_mask, [0x01, 0x0C, 8, 0x11, 0x0F, 0, 0, 0, 0, 0, 0x20]);
        let mut other = [0x03, 0x0C, 0x00];
        split.patch_command(&mut other, u64::MAX);
        assert_eq!(other, [0x03, 0x0C, 0x00]);
    }

    #[test]
    fn completed_packets_are_split_by_handle() {
        let mut split = Split::new();
        split.route_event(CONNECTION_COMPLETE, &connection_complete(0x0B));
        let event = [2, 0x40, 0x00, 3, 0x00, 0x0B, 0x00, 1, 0x00];
        let mut out = [0u8; 16];
        assert_eq!(
            split.completed_packets_for(&event, Sender::Le, &mut out),
            Some(5)
        );
        assert_eq!(out[..5], [1, 0x40, 0x00, 3, 0x00]);
        assert_eq!(
            split.completed_packets_for(&event, Sender::Classic, &mut out),
            Some(5)
        );
        assert_eq!(out[..5], [1, 0x0B, 0x00, 1, 0x00]);
        // Only LE handles: nothing for the Classic host.
        let le_only = [1, 0x40, 0x00, 3, 0x00];
        assert_eq!(
            split.completed_packets_for(&le_only, Sender::Classic, &mut out),
            None
        );
        // A count that does not match the entries: nobody's.
        assert_eq!(
            split.completed_packets_for(&[3, 0x40, 0x00, 1, 0], Sender::Le, &mut out),
            None
        );
    }

    #[test]
    fn a_packet_longer_than_the_room_for_it_is_refused_and_counted() {
        let mut split = Split::new();
        // (announced length, room, admitted)
        let table = [
            (263, 263, true),
            (0, 263, true),
            (264, 263, false),
            (1025, 263, false),
        ];
        for (len, room, admitted) in table {
            assert_eq!(split.admit(len, room), admitted, "{len} bytes into {room}");
        }
        assert_eq!(split.counters().oversized_packets, 2);
        assert_eq!(split.counters().malformed_events, 0);
    }

    #[test]
    fn a_full_link_table_is_counted() {
        let mut split = Split::new();
        for handle in [1, 2, 3] {
            split.route_event(CONNECTION_COMPLETE, &connection_complete(handle));
        }
        assert_eq!(split.counters().links_overflow, 1);
        assert_eq!(split.route_acl(3), Route::Le);
    }

    proptest::proptest! {
        /// Whatever the controller sends, the splitter answers without a panic, and an
        /// ACL packet goes to the Classic host exactly while a Classic Connection
        /// Complete has opened its handle and no Disconnection Complete (or hardware
        /// error) has closed it. The events are drawn mostly from the codes that open
        /// and close links, on a few handles, so that links do open and close.
        #[test]
        fn any_event_stream_is_routed_without_a_panic(
            events in proptest::collection::vec(
                (
                    proptest::sample::select(vec![
                        CONNECTION_COMPLETE, DISCONNECTION_COMPLETE, HARDWARE_ERROR,
                        COMMAND_COMPLETE, NUMBER_OF_COMPLETED_PACKETS, ENCRYPTION_CHANGE, 0x3E, 0xFF,
                    ]),
                    0u8..2,
                    0u16..3,
                    proptest::collection::vec(proptest::prelude::any::<u8>(), 0..12),
                    proptest::prelude::any::<bool>(),
                ),
                0..60,
            ),
        ) {
            // Room for every handle drawn: no link is refused for a full table.
            let mut split = Splitter::<4, 8>::new();
            let handle = 1;
            let mut open = false;
            for (code, status, event_handle, tail, whole) in &events {
                let [lo, hi] = event_handle.to_le_bytes();
                let mut params = std::vec![*status, lo, hi];
                params.extend_from_slice(tail);
                // Sometimes cut short, even below a handle.
                let params = if *whole { &params[..] } else { &params[..tail.len().min(2)] };
                split.command_sent(Sender::Classic, params);
                split.route_event(*code, params);
                let mut out = [0u8; 64];
                split.completed_packets_for(params, Sender::Le, &mut out);
                let names_handle = *status == 0 && params.len() >= 3 && *event_handle == handle;
                match *code {
                    CONNECTION_COMPLETE if names_handle => open = true,
                    DISCONNECTION_COMPLETE if names_handle => open = false,
                    HARDWARE_ERROR => open = false,
                    _ => {}
                }
                proptest::prop_assert_eq!(split.route_acl(handle) == Route::Classic, open);
            }
        }
    }
}
