//! The PlayStation pads over Bluetooth Classic, beside the BLE remote on one
//! controller (the ESP32's dual-mode radio, or the simulator's HCI transport):
//!
//! ```text
//!   controller ══HCI══ split::LeTransport ── ExternalController ── guard ── trouble-host (BLE task)
//!                          │   (core::hci_split decides)
//!                          └── split::ClassicPort ── task::run (classic-host, PlayStation decoder)
//!   controller task ◀──▶ RemoteFanout ◀──▶ both remote tasks
//! ```
//!
//! [`RemoteFanout`] gives each remote task its own request signal and input queue:
//! both see every request of the controller (the pairing window, a switch-off), and
//! their link reports are merged into one.

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
use embassy_futures::select::{Either3, select3};
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use embedded_storage_async::nor_flash::NorFlash;

use base_core::controller::Input;

use crate::ble::{RemoteEnds, RemoteRequest};
use crate::channels::{INPUT_QUEUE, RawMutex};

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
            fanout.ends(Remote::Ble, ends),
        ),
        run(
            ClassicPort::new(transport, &split),
            bond_flash,
            bond_range,
            fanout.ends(Remote::Classic, ends),
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

/// The two remote tasks' channel ends, and the merge of what they report.
pub struct RemoteFanout {
    requests: [Signal<RawMutex, RemoteRequest>; 2],
    inputs: [Channel<RawMutex, Input, INPUT_QUEUE>; 2],
}

/// Which remote task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Remote {
    Ble = 0,
    Classic = 1,
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
            inputs: [Channel::new(), Channel::new()],
        }
    }

    /// The channel ends of one remote task (the flash gate is the controller's).
    pub fn ends<'a>(&'a self, remote: Remote, ends: RemoteEnds<'a>) -> RemoteEnds<'a> {
        RemoteEnds {
            remote_requests: &self.requests[remote as usize],
            inputs: self.inputs[remote as usize].sender(),
            flash_gate: ends.flash_gate,
            base_light: ends.base_light,
        }
    }

    /// Hands every request to both tasks and their inputs to the controller, for ever.
    /// A pad's link going down is always reported down, even while the other pad is
    /// connected (so a dead-man held on the lost pad brakes), then up again.
    pub async fn run(&self, ends: RemoteEnds<'_>) -> ! {
        // (bonded, connected) of each task.
        let mut links = [(false, false); 2];
        loop {
            let (remote, input) = match select3(
                ends.remote_requests.wait(),
                self.inputs[0].receive(),
                self.inputs[1].receive(),
            )
            .await
            {
                Either3::First(request) => {
                    for signal in &self.requests {
                        signal.signal(request);
                    }
                    continue;
                }
                Either3::Second(input) => (0, input),
                Either3::Third(input) => (1, input),
            };
            match input {
                Input::RemoteLink { bonded, connected } => {
                    let lost = links[remote].1 && !connected;
                    links[remote] = (bonded, connected);
                    let bonded = links.iter().any(|link| link.0);
                    let connected = links.iter().any(|link| link.1);
                    if lost && connected {
                        ends.inputs
                            .send(Input::RemoteLink {
                                bonded,
                                connected: false,
                            })
                            .await;
                    }
                    ends.inputs
                        .send(Input::RemoteLink { bonded, connected })
                        .await;
                }
                // Reports of a pad whose link is down are stale.
                Input::Gamepad(_) if !links[remote].1 => {}
                input => ends.inputs.send(input).await,
            }
        }
    }
}
