//! The Bluetooth remote: what the controller asks of it ([`RemoteRequest`]) and, with
//! the `ble` feature, the BLE central task that keeps the bonded gamepad connected.

#[cfg(feature = "ble")]
mod bond;
#[cfg(feature = "ble")]
mod central;
#[cfg(feature = "ble")]
mod guard;
mod switch;

#[cfg(feature = "ble")]
pub use bond::{BOND_RECORD_LEN, decode_bond, encode_bond};
#[cfg(feature = "ble")]
pub use central::*;
#[cfg(feature = "ble")]
pub use guard::{GUARD_LINKS, GuardState, GuardedController};
pub use switch::wait_until_on;

use embassy_sync::signal::Signal;

use base_core::hid::light_bar::BaseLight;
use base_core::remote::Pad;

use crate::store::PendingWrites;
use crate::sync::{InputSender, RawMutex};

/// What the controller asks of the Bluetooth remote task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RemoteRequest {
    /// A new pad may be paired (and replace the bonded one) while this is true.
    pub pairing_open: bool,
    /// Counts the controller's requests to switch each task's pad off (indexed by
    /// [`Pad`], read with [`RemoteRequest::disconnects_of`]); a change means "drop the
    /// link now" (a counter, so two requests in a row are not merged into one state).
    pub disconnects: [u16; 2],
    /// Counts the controller's turn-ons of Bluetooth ([`Output::bluetooth_on`]): after
    /// a panic loop ([`wait_until_on`]), or after the BLE task gave up its host; a
    /// change means "start now" (a counter, so a second turn-on is not lost in the
    /// first one's state).
    ///
    /// [`Output::bluetooth_on`]: base_core::controller::Output::bluetooth_on
    pub turn_ons: u16,
}

impl RemoteRequest {
    /// The switch-off requests so far for `pad`'s task.
    pub fn disconnects_of(&self, pad: Pad) -> u16 {
        self.disconnects[pad as usize]
    }

    /// One more switch-off request for `pad`'s task.
    pub fn disconnect(&mut self, pad: Pad) {
        let count = &mut self.disconnects[pad as usize];
        *count = count.wrapping_add(1);
    }
}

/// The remote task's channel ends (see [`crate::channels::Channels`]).
#[derive(Clone, Copy)]
pub struct RemoteEnds<'a> {
    pub remote_requests: &'a Signal<RawMutex, RemoteRequest>,
    pub inputs: InputSender<'a>,
    /// The bond is written to flash only at rest ([`PendingWrites::wait_at_rest`]).
    pub flash_gate: &'a PendingWrites,
    /// The base's mode for a PlayStation pad's light bar (the Classic task's only; the
    /// BLE pads have no light to set).
    pub base_light: &'a Signal<RawMutex, BaseLight>,
}
