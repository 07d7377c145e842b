//! The PlayStation pads over Bluetooth Classic, beside the BLE remote on one
//! controller (the ESP32's dual-mode radio, or the simulator's HCI transport):
//!
//! ```text
//!   controller ══HCI══ split::LeTransport ── ExternalController ── guard ── trouble-host (BLE task)
//!                          │   (base_bluetooth::split decides)
//!                          └── split::ClassicPort ── task::run (the Classic host, PlayStation decoder)
//!   controller task ──requests──▶ RemoteFanout ──▶ both remote tasks ──inputs (tagged)──▶ controller task
//! ```
//!
//! [`RemoteFanout`] gives each remote task its own request signal: both see every
//! request of the controller (the pairing window, a switch-off). Each task tags its
//! links and reports with its [`Pad`], and the controller decides which pad controls.

mod split;
mod task;

pub use split::{ClassicPacket, ClassicPort, LeTransport, PACKET_MAX, SplitState};
pub use task::{REPORT_SILENCE_MS, SUPERVISION_TIMEOUT_MS, decode_bond, encode_bond, run};

use core::convert::Infallible;
use core::ops::Range;

use bt_hci::ReadHciError;
use bt_hci::controller::ExternalController;
use bt_hci::transport::Transport;
use embassy_futures::join::join3;
use embassy_sync::signal::Signal;
use embedded_storage_async::nor_flash::NorFlash;

use base_core::remote::Pad;

use crate::ble::{RemoteEnds, RemoteRequest};
use crate::sync::RawMutex;

/// Runs both remotes for ever on one controller reached through `transport`: the BLE
/// central (`crate::ble::run`, with the random static `ble_address`) and the
/// PlayStation pad host, through the HCI splitter, their bonds in `bond_flash` over
/// `bond_range` (a clone per task: two records in one partition). `SLOTS` is the BLE
/// host's number of commands in flight.
pub async fn run_both<T, F, const SLOTS: usize>(
    transport: &T,
    ble_address: [u8; 6],
    bond_flash: F,
    bond_range: Range<u32>,
    ends: RemoteEnds<'_>,
) -> !
where
    T: Transport,
    T::Error: From<ReadHciError<Infallible>> + TransportError,
    F: NorFlash + Clone,
{
    let split = SplitState::new();
    let ble_controller: ExternalController<_, SLOTS> =
        ExternalController::new(LeTransport::new(transport, &split));
    let fanout = RemoteFanout::new();
    let (never, _, _) = join3(
        crate::ble::run(
            ble_controller,
            ble_address,
            bond_flash.clone(),
            bond_range.clone(),
            fanout.ends(Pad::Ble, ends),
        ),
        run(
            ClassicPort::new(transport, &split),
            bond_flash,
            bond_range,
            fanout.ends(Pad::Classic, ends),
        ),
        fanout.run(ends),
    )
    .await;
    never
}

/// What trouble-host needs of the transport's error: with `defmt` it logs it.
#[cfg(feature = "defmt")]
pub trait TransportError: defmt::Format {}
#[cfg(feature = "defmt")]
impl<E: defmt::Format> TransportError for E {}
/// What trouble-host needs of the transport's error: nothing without `defmt`.
#[cfg(not(feature = "defmt"))]
pub trait TransportError {}
#[cfg(not(feature = "defmt"))]
impl<E> TransportError for E {}

/// The two remote tasks' request signals: both hear every request of the controller
/// (the pairing window, a switch-off of either task's pad, Bluetooth on). Their inputs
/// go straight to the controller, each tagged with its [`Pad`]: which pad controls is
/// the controller's decision (`base_core::remote::arbiter`).
pub struct RemoteFanout {
    requests: [Signal<RawMutex, RemoteRequest>; 2],
}

impl Default for RemoteFanout {
    fn default() -> Self {
        Self::new()
    }
}

impl RemoteFanout {
    pub const fn new() -> Self {
        Self {
            requests: [Signal::new(), Signal::new()],
        }
    }

    /// The channel ends of `pad`'s task: its own request signal, the rest the
    /// controller's.
    pub fn ends<'a>(&'a self, pad: Pad, ends: RemoteEnds<'a>) -> RemoteEnds<'a> {
        RemoteEnds {
            remote_requests: &self.requests[pad as usize],
            ..ends
        }
    }

    /// Hands every request of the controller to both tasks, for ever.
    pub async fn run(&self, ends: RemoteEnds<'_>) -> ! {
        loop {
            let request = ends.remote_requests.wait().await;
            for signal in &self.requests {
                signal.signal(request);
            }
        }
    }
}
