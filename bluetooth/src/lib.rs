//! The firmware's Bluetooth below the hosts, sans IO: it takes HCI packets as bytes and
//! answers with the packets to send and what happened. No radio, no async, no
//! allocation, no clock: time is an argument. The runtime owns the HCI transport.
//!
//! - [`guard`]: every event and ACL packet from the radio passes it before the BLE
//!   host (trouble-host) sees it; what the host would choke on is dropped, counted,
//!   and its link closed.
//! - [`split`]: one controller, two hosts: which host gets each packet the controller
//!   sends.
//! - The Bluetooth Classic (BR/EDR) HID host for the PlayStation pads, [`ClassicHost`];
//!   the pads' reports are decoded by the core (`base_core::hid::playstation`).
//!   Layers, bottom up: [`hci`] (commands and events as values and bytes; the one
//!   reader of a connection handle, [`hci::Handle::from_bits`]), [`acl`] (reassembly,
//!   fragmentation to the controller's buffer size, flow control), [`l2cap`] (frames
//!   and signalling commands), [`channels`] (the HID control and interrupt channels),
//!   [`host`] (link management: page scan, inquiry in the pairing window, page,
//!   security, back-off). The host is written like the core's state machines:
//!   `step(now, Event, &Params) -> Effects`, the state an enum with the data in its
//!   variants, a diagram in its documentation, tables of transitions in its tests.
//!
//! The Classic host is hand-written rather than built on bt-hci 0.10 (which
//! trouble-host, the BLE stack, uses): bt-hci depends on embassy-sync and the async
//! embedded-io traits, and this crate must stay as pure as the core; the host needs 26
//! commands and 18 events, each a few bytes.
#![cfg_attr(not(test), no_std)]

#[macro_use]
mod fmt;

pub mod acl;
pub mod channels;
pub mod guard;
pub mod hci;
pub mod host;
pub mod l2cap;
pub mod split;
#[cfg(test)]
mod test_events;

pub use host::{ClassicHost, Counters, Effects, Event, Packet, PadEvent, Params};

use hci::{BdAddr, LinkKey};

/// The MTU the host announces on its HID channels: the pads' longest report (79
/// bytes) with room to spare, small enough for a fixed reassembly buffer.
pub const RECEIVE_MTU: u16 = 256;

/// A bonded pad: its address and the link key made when it paired.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Bond {
    pub addr: BdAddr,
    pub key: LinkKey,
}
