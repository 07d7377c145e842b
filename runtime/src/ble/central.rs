//! The Bluetooth remote's task: a BLE central (trouble-host) that keeps one bonded HID
//! gamepad (HID over GATT) connected and hands its reports to the controller.
//!
//! ```text
//!   boot: bond from flash ──▶ reconnect loop ──▶ encrypted? ──▶ HID discovery ──▶ reports ──▶ Input::Gamepad
//!   pairing window open ──▶ scan for gamepads ──▶ connect ──▶ pair + bond ──▶ bond to flash, Input::RemotePaired
//! ```
//!
//! Security: a pad drives only over an encrypted link with the stored bond. A new pad
//! is paired only while the controller holds the pairing window open (a deliberate
//! act on the robot); outside it the task connects to the bonded address alone and
//! refuses to pair: it never asks for security itself there (trouble would answer a
//! failed bonded encryption with a fresh Pairing Request), it lets the GATT client
//! encrypt with the stored key, and it drops a link that is not encrypted with it or
//! on which any pairing happens. One bond is kept: pairing a new pad replaces the old
//! one.
//!
//! A failed attempt (a connection that fails, a pad that does not pair, a pad at the
//! bonded address without its key, a link the guard closed) is followed by a 1 s pause,
//! so that a pad that keeps failing does not keep the radio and the pad busy.
//! Connection parameter requests are answered with our own parameters, whatever the
//! pad asks for: the 500 ms supervision timeout holds from the first packet on.
//!
//! Link loss is the supervision timeout (500 ms, asked for at connection), reported as
//! [`Input::RemoteLink`] with `connected: false`; pads send reports only on change, so
//! silence is not loss. A host that stops is reported the same way before a fresh one
//! starts ([`run`]).

use core::ops::Range;

use bt_hci::cmd::controller_baseband::Reset;
use bt_hci::cmd::le::LeSetScanParams;
use bt_hci::controller::ControllerCmdSync;
use embassy_futures::select::{Either, Either3, Either4, select, select3, select4};
use embassy_time::{Duration, Instant, Timer, with_timeout};
use embedded_storage_async::nor_flash::NorFlash;
use heapless::Vec;
use sequential_storage::cache::Cache;
use sequential_storage::map::{MapConfig, MapStorage};
use trouble_host::Controller as HciController;
use trouble_host::advertise::AdStructure;
use trouble_host::prelude::*;

use base_core::controller::Input;
use base_core::hid::{GamepadLayout, VidPid};
use base_core::remote::Pad;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;

use crate::sync::RawMutex;

use super::bond::{BOND_RECORD_LEN, decode_bond, encode_bond};
use super::guard::{GuardState, GuardedController};
use super::{RemoteEnds, RemoteRequest};

/// One gamepad, and the L2CAP channels the host needs for it (signalling, ATT, SMP).
const CONNECTIONS: usize = 1;
const L2CAP_CHANNELS: usize = 3;
/// GATT services the client remembers (HID, Device Information, and a few others).
const MAX_SERVICES: usize = 8;
/// Characteristics of the HID service: a Report Map, up to a dozen Reports, control.
const MAX_CHARACTERISTICS: usize = 24;
/// The longest Report Map we read (the Xbox Elite 2's is about 1 KiB).
const MAX_REPORT_MAP: usize = 1_536;

const HID_SERVICE: u16 = 0x1812;
const REPORT_MAP: u16 = 0x2A4B;
const REPORT: u16 = 0x2A4D;
const REPORT_REFERENCE: u16 = 0x2908;
const DEVICE_INFORMATION: u16 = 0x180A;
const PNP_ID: u16 = 0x2A50;
const GAMEPAD_APPEARANCE: u16 = 0x03C4;
/// Report Reference type of an input report.
const INPUT_REPORT: u8 = 1;

/// The connection the dead-man needs: a short interval for a responsive stick, and a
/// supervision timeout that turns a dead link into a stop within half a second.
fn connection_params() -> RequestedConnParams {
    RequestedConnParams {
        min_connection_interval: Duration::from_micros(7_500),
        max_connection_interval: Duration::from_millis(15),
        max_latency: 0,
        min_event_length: Duration::from_secs(0),
        max_event_length: Duration::from_secs(0),
        supervision_timeout: Duration::from_millis(500),
    }
}

/// How long one attempt to reach the bonded pad lasts before the task looks at the
/// controller's requests again.
const RECONNECT_ATTEMPT: Duration = Duration::from_secs(5);
/// How long pairing may take once a pad is connected.
const PAIRING_TIMEOUT: Duration = Duration::from_secs(15);
/// The wait after a failed attempt. One attempt a second at most: a pad that keeps
/// failing (an impostor at the bonded address, say) costs the radio and the pads little,
/// and once it is gone the owner's pad is back within 2 s. (A back-off that doubled up
/// to 32 s kept the owner out for up to half a minute after an attack.)
const PAUSE_AFTER_FAILURE: Duration = Duration::from_secs(1);

/// How one attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Attempt {
    /// A pad was served (or paired and served) until its link ended.
    Served,
    /// Nothing to blame: no pad answered in time, or the controller's request changed.
    Idle,
    /// The connection, the pairing or the encryption failed, or a pad was refused.
    Failed,
}

/// How long the task waits before it starts a stopped host again: time for a
/// controller that failed to settle, and no tight loop if it fails at once again.
const PAUSE_BEFORE_RESTART: Duration = Duration::from_millis(500);
/// A host that stopped this many times within [`STOPS_WINDOW`] stays stopped: the BLE
/// remote is off until a person turns it on (a confirm press, or `command` 0xB1E1): a
/// controller that keeps failing, or a peer that keeps making it fail, must not keep
/// the radio in a restart loop.
const STOPS_BEFORE_OFF: usize = 3;
const STOPS_WINDOW: Duration = Duration::from_secs(60);
/// How long the controller may take to answer the HCI Reset that ends the remote.
const RESET_TIMEOUT: Duration = Duration::from_secs(1);

/// Runs the remote forever. `address` is the chip's Bluetooth address (random static),
/// `bond_flash` over `bond_range` holds the bond.
///
/// The host (trouble-host) stops only when the controller fails it (a transport read
/// error, an answer it cannot parse). Then the link is reported down at once, so a
/// held dead-man brakes as on link loss, and a fresh host starts over the same
/// controller (it resets the controller first) after [`PAUSE_BEFORE_RESTART`]; after
/// [`STOPS_BEFORE_OFF`] stops within [`STOPS_WINDOW`] the remote stays off, and the
/// controller shows it (register 36 reads 2), until it turns Bluetooth on again.
pub async fn run<C, F>(
    controller: C,
    address: [u8; 6],
    bond_flash: F,
    bond_range: Range<u32>,
    channels: RemoteEnds<'_>,
) -> !
where
    C: HciController + ControllerCmdSync<LeSetScanParams>,
    F: NorFlash,
{
    let mut bonds = BondStore::new(bond_flash, bond_range);
    let bonded = bonds.load().await;
    // A new bond waits here for the next standstill: on the chip a flash erase stalls
    // everything for up to 400 ms, which must never happen while the wheels turn. The
    // pad is served meanwhile; the bond lasts in the stack until it is stored.
    let unsaved_bond: Signal<NoopRawMutex, BondInformation> = Signal::new();
    let store_bonds_at_rest = async {
        loop {
            let bond = unsaved_bond.wait().await;
            channels.flash_gate.wait_at_rest().await;
            // A pad paired meanwhile replaces this one.
            let bond = unsaved_bond.try_take().unwrap_or(bond);
            if bonds.store(&bond).await.is_err() {
                warn!("remote: the bond could not be stored; it lasts until reboot");
            }
        }
    };
    let hosts = async {
        // Runs for ever: a host that stops is started again, or waits to be turned on.
        let mut host = Host {
            bonded,
            request: RemoteRequest::default(),
        };
        let mut stops = StopHistory::default();
        loop {
            host.run(&controller, address, channels, &unsaved_bond)
                .await;
            // The pad may be holding the dead-man: its link is gone with the host.
            report(
                channels,
                Input::RemoteLink {
                    pad: Pad::Ble,
                    bonded: host.bonded.is_some(),
                    connected: false,
                },
            )
            .await;
            if stops.one_more(Instant::now()) {
                error!(
                    "remote: the Bluetooth host stopped again; the BLE remote is off until a \
                     confirm press or command 0xB1E1"
                );
                // No link may outlive the host: the reset ends them (and stops any scan).
                if with_timeout(
                    RESET_TIMEOUT,
                    ControllerCmdSync::<Reset>::exec(&controller, &Reset::new()),
                )
                .await
                .is_err()
                {
                    error!("remote: the Bluetooth controller does not answer its reset");
                }
                host.wait_until_turned_on(channels).await;
                stops = StopHistory::default();
                info!("remote: Bluetooth turned on; the BLE host starts again");
                continue;
            }
            error!("remote: the Bluetooth host stopped; it starts again");
            Timer::after(PAUSE_BEFORE_RESTART).await;
        }
    };
    match select(store_bonds_at_rest, hosts).await {
        Either::First(never) | Either::Second(never) => never,
    }
}

/// When the host stopped lately: whether it stops too often to start again.
#[derive(Default)]
struct StopHistory {
    stops: Vec<Instant, STOPS_BEFORE_OFF>,
}

impl StopHistory {
    /// One more stop at `now`; true if it is the [`STOPS_BEFORE_OFF`]th within
    /// [`STOPS_WINDOW`].
    fn one_more(&mut self, now: Instant) -> bool {
        self.stops
            .retain(|&stop| now.saturating_duration_since(stop) < STOPS_WINDOW);
        if self.stops.is_full() {
            self.stops.remove(0);
        }
        let _ = self.stops.push(now);
        self.stops.is_full()
    }
}

/// What outlives one host: the bond and the controller's last request.
struct Host {
    bonded: Option<BondInformation>,
    request: RemoteRequest,
}

impl Host {
    /// Tells the controller that the BLE host stays stopped, and waits until it turns
    /// Bluetooth on again (a new count in the request). The pairing window and the
    /// disconnects that come meanwhile are kept for the next host.
    async fn wait_until_turned_on(&mut self, channels: RemoteEnds<'_>) {
        if let Some(request) = channels.remote_requests.try_take() {
            self.request = request;
        }
        let turned_on_before = self.request.turn_ons;
        report(channels, Input::BleHostOff).await;
        loop {
            self.request = channels.remote_requests.wait().await;
            if self.request.turn_ons != turned_on_before {
                // The next host takes the request as its first.
                channels.remote_requests.signal(self.request);
                return;
            }
        }
    }

    /// One host, from its start (HCI Reset) until it stops.
    async fn run<C>(
        &mut self,
        controller: &C,
        address: [u8; 6],
        channels: RemoteEnds<'_>,
        unsaved_bond: &Signal<NoopRawMutex, BondInformation>,
    ) where
        C: HciController + ControllerCmdSync<LeSetScanParams>,
    {
        let mut resources: HostResources<DefaultPacketPool, CONNECTIONS, L2CAP_CHANNELS> =
            HostResources::new();
        // trouble-host sees the controller only through the guard (see `guard`).
        let guard = GuardState::new();
        let stack = trouble_host::new(GuardedController::new(controller, &guard), &mut resources)
            .set_random_address(Address::random(address))
            .set_io_capabilities(IoCapabilities::NoInputNoOutput)
            .build();
        if let Some(bond) = &self.bonded {
            // A bond that the stack refuses cannot be used: forget it.
            if stack.add_bond_information(bond.clone()).is_err() {
                self.bonded = None;
            }
        }
        report(
            channels,
            Input::RemoteLink {
                pad: Pad::Ble,
                bonded: self.bonded.is_some(),
                connected: false,
            },
        )
        .await;

        let finder = PadFinder::default();
        let mut runner = stack.runner();
        let mut central = stack.central();
        let mut remote = PadLink {
            stack: &stack,
            guard: &guard,
            channels,
            request: self.request,
        };
        let bonded = &mut self.bonded;
        let stopped = select3(
            runner.run_with_handler(&finder),
            guard.close_links(controller),
            async {
                loop {
                    remote.refresh_request();
                    let attempt = if remote.request.pairing_open {
                        match remote.pair_new_pad(&mut central, &finder).await {
                            Ok((conn, bond)) => {
                                if let Some(old) = bonded.replace(bond.clone()) {
                                    // The stack holds the new bond already; drop the old
                                    // pad's, unless the same pad paired again.
                                    if old.identity.addr != bond.identity.addr {
                                        let _ = stack.remove_bond_information(old.identity);
                                    }
                                }
                                unsaved_bond.signal(bond);
                                report(channels, Input::RemotePaired).await;
                                remote.serve(&conn).await
                            }
                            Err(attempt) => attempt,
                        }
                    } else if let Some(bond) = bonded.as_ref() {
                        remote.reconnect(&mut central, bond).await
                    } else {
                        remote.wait_for_request().await;
                        Attempt::Idle
                    };
                    if attempt == Attempt::Failed {
                        remote.back_off(PAUSE_AFTER_FAILURE).await;
                    }
                }
            },
        )
        .await;
        self.request = remote.request;
        match stopped {
            // The runner returns only when the controller failed it.
            Either3::First(_) => {}
            Either3::Second(never) | Either3::Third(never) => never,
        }
    }
}

struct PadLink<'s, 'r, C: HciController + ControllerCmdSync<LeSetScanParams>> {
    stack: &'s Stack<'r, C, DefaultPacketPool>,
    guard: &'s GuardState,
    channels: RemoteEnds<'s>,
    request: RemoteRequest,
}

impl<C: HciController + ControllerCmdSync<LeSetScanParams>> PadLink<'_, '_, C> {
    fn refresh_request(&mut self) {
        if let Some(request) = self.channels.remote_requests.try_take() {
            self.request = request;
        }
    }

    async fn wait_for_request(&mut self) {
        self.request = self.channels.remote_requests.wait().await;
    }

    /// Waits `wait` before the next attempt; a new request from the controller (the
    /// pairing window opening, say) ends the wait.
    async fn back_off(&mut self, wait: Duration) {
        info!("remote: next attempt in {=u64} ms", wait.as_millis());
        if let Either::Second(request) =
            select(Timer::after(wait), self.channels.remote_requests.wait()).await
        {
            self.request = request;
        }
    }

    /// Scans for a gamepad while the pairing window is open, connects and pairs it;
    /// returns the connection and the new bond.
    async fn pair_new_pad<'c>(
        &mut self,
        central: &mut Central<'c, C, DefaultPacketPool>,
        finder: &PadFinder,
    ) -> Result<(Connection<'c, DefaultPacketPool>, BondInformation), Attempt> {
        info!("remote: pairing window open, scanning for gamepads");
        let found = {
            let mut scanner = Scanner::new(central);
            let config = ScanConfig {
                active: true,
                ..ScanConfig::default()
            };
            finder.found.reset();
            let _session = scanner.scan(&config).await.map_err(|_| Attempt::Failed)?;
            match select(finder.found.wait(), self.channels.remote_requests.wait()).await {
                Either::First(address) => address,
                Either::Second(request) => {
                    self.request = request;
                    return Err(Attempt::Idle);
                }
            }
        };
        info!("remote: gamepad found, connecting");
        let targets = [found];
        let config = connect_config(&targets);
        let conn = match with_timeout(RECONNECT_ATTEMPT, central.connect(&config)).await {
            Ok(Ok(conn)) => conn,
            // The pad stopped advertising, or the controller refused the connection.
            _ => return Err(Attempt::Failed),
        };
        // The guard lets the pad's pairing messages through only now.
        self.guard.set_pairing_window(true);
        if conn.set_bondable(true).is_err() || conn.request_security().is_err() {
            self.guard.set_pairing_window(false);
            conn.disconnect();
            return Err(Attempt::Failed);
        }
        let bond = with_timeout(PAIRING_TIMEOUT, async {
            loop {
                match conn.next().await {
                    ConnectionEvent::PairingComplete { bond, .. } => return bond,
                    ConnectionEvent::PairingFailed(_) | ConnectionEvent::Disconnected { .. } => {
                        return None;
                    }
                    ConnectionEvent::RequestConnectionParams(request) => {
                        answer_params(request, self.stack).await;
                    }
                    _ => {}
                }
            }
        })
        .await
        .ok()
        .flatten();
        self.guard.set_pairing_window(false);
        match bond {
            Some(bond) => {
                info!("remote: paired and bonded");
                Ok((conn, bond))
            }
            None => {
                warn!("remote: pairing failed");
                conn.disconnect();
                Err(Attempt::Failed)
            }
        }
    }

    /// One attempt to reach the bonded pad; serves it while it stays connected.
    async fn reconnect(
        &mut self,
        central: &mut Central<'_, C, DefaultPacketPool>,
        bond: &BondInformation,
    ) -> Attempt {
        // The stack's copy of the bond is put back before every attempt, so whatever a
        // peer made the stack do with it, the owner's pad finds it there.
        if self.stack.add_bond_information(bond.clone()).is_err() {
            warn!("remote: the stack refused the bond");
        }
        let targets = [bond.identity.addr];
        let config = connect_config(&targets);
        let attempt = with_timeout(RECONNECT_ATTEMPT, central.connect(&config));
        match select(attempt, self.channels.remote_requests.wait()).await {
            Either::First(Ok(Ok(conn))) => {
                let closed_before = self.guard.counters().links_closed;
                // Never pair here: not bondable, no security request of ours.
                if conn.set_bondable(false).is_err() {
                    conn.disconnect();
                    return Attempt::Failed;
                }
                match self.encrypt_with_bond(&conn).await {
                    Some(client) => self.serve_with(&conn, &client, closed_before).await,
                    None => {
                        warn!(
                            "remote: the pad at the bonded address did not encrypt with the bond; refused"
                        );
                        conn.disconnect();
                        Attempt::Failed
                    }
                }
            }
            // No pad answered within the attempt: nothing failed, try again.
            Either::First(Err(_)) => Attempt::Idle,
            Either::First(Ok(Err(_))) => Attempt::Failed,
            Either::Second(request) => {
                self.request = request;
                Attempt::Idle
            }
        }
    }

    /// Encrypts the link with the stored bond, and nothing else: the GATT client asks
    /// for the bonded encryption (and, unlike our own security request, does not fall
    /// back to a fresh pairing when it fails). The link counts only if it is encrypted
    /// afterwards and no failed pairing, lost bond or disconnection came up meanwhile.
    async fn encrypt_with_bond<'c>(
        &self,
        conn: &Connection<'c, DefaultPacketPool>,
    ) -> Option<GattClient<'c, C, DefaultPacketPool, MAX_SERVICES>> {
        let secured = with_timeout(PAIRING_TIMEOUT, async {
            let mut client = core::pin::pin!(
                GattClient::<C, DefaultPacketPool, MAX_SERVICES>::new(self.stack, conn)
            );
            loop {
                match select(client.as_mut(), conn.next()).await {
                    Either::First(client) => return client.ok(),
                    // The bonded encryption ends in PairingComplete as well; a failed one
                    // in BondLost (and no fresh pairing, as we did not ask for security
                    // ourselves).
                    Either::Second(
                        ConnectionEvent::PairingFailed(_)
                        | ConnectionEvent::BondLost
                        | ConnectionEvent::Disconnected { .. },
                    ) => return None,
                    // Answered to the end outside the race with the client: an answer cut
                    // short when the client gets ready would leave the pad's parameters.
                    Either::Second(ConnectionEvent::RequestConnectionParams(request)) => {
                        answer_params(request, self.stack).await;
                    }
                    Either::Second(_) => {}
                }
            }
        })
        .await;
        match secured {
            Ok(Some(client))
                if conn.is_bonded_peer()
                    && conn
                        .security_level()
                        .is_ok_and(|level| level != SecurityLevel::NoEncryption) =>
            {
                Some(client)
            }
            _ => None,
        }
    }

    /// Discovers the pad's HID service, subscribes to its input reports and forwards
    /// them until the link drops or the controller asks to disconnect. `Failed` when
    /// the pad could not be served, or the guard closed its link.
    async fn serve(&mut self, conn: &Connection<'_, DefaultPacketPool>) -> Attempt {
        let closed_before = self.guard.counters().links_closed;
        match GattClient::<C, DefaultPacketPool, MAX_SERVICES>::new(self.stack, conn).await {
            Ok(client) => self.serve_with(conn, &client, closed_before).await,
            Err(_) => {
                self.report_link(true).await;
                conn.disconnect();
                self.report_link(false).await;
                Attempt::Failed
            }
        }
    }

    /// [`Self::serve`] with the GATT client of the connection. `closed_before`: the
    /// guard's count of closed links when this link came up.
    async fn serve_with(
        &mut self,
        conn: &Connection<'_, DefaultPacketPool>,
        client: &GattClient<'_, C, DefaultPacketPool, MAX_SERVICES>,
        closed_before: u32,
    ) -> Attempt {
        self.report_link(true).await;
        {
            let disconnects_before = self.request.disconnects_of(Pad::Ble);
            let outcome = select4(
                client.task(),
                forward_reports(client, self.channels),
                watch_link(conn, self.stack),
                async {
                    loop {
                        let request = self.channels.remote_requests.wait().await;
                        self.request = request;
                        if request.disconnects_of(Pad::Ble) != disconnects_before {
                            return;
                        }
                    }
                },
            )
            .await;
            match outcome {
                Either4::Second(Err(error)) => warn!("remote: HID setup failed: {}", error),
                Either4::Fourth(()) => info!("remote: switched off by the controller"),
                _ => {}
            }
        }
        conn.disconnect();
        self.report_link(false).await;
        // A pad whose packets the guard refuses is backed off like a failed attempt,
        // and counted on CAN: one that does it after every reconnect is not served in
        // a loop (it was reconnected 33 times in 10 s).
        if self.guard.counters().links_closed != closed_before {
            report(self.channels, Input::RadioPacketRefused { pad: Pad::Ble }).await;
            Attempt::Failed
        } else {
            Attempt::Served
        }
    }

    /// The link of the bonded pad came up or went down (down brakes a held dead-man).
    async fn report_link(&self, connected: bool) {
        report(
            self.channels,
            Input::RemoteLink {
                pad: Pad::Ble,
                bonded: true,
                connected,
            },
        )
        .await;
    }
}

/// Why the HID setup of a connected pad failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum HidSetupError {
    NoHidService,
    NoReportMap,
    /// The Report Map describes no gamepad we can read.
    UnusableReportMap,
    /// A GATT request failed (the link dropped, or the pad refused).
    Gatt,
}

/// Reads the Report Map and the report IDs, subscribes to the input reports and sends
/// each decoded report to the controller.
async fn forward_reports<C: HciController>(
    client: &GattClient<'_, C, DefaultPacketPool, MAX_SERVICES>,
    channels: RemoteEnds<'_>,
) -> Result<(), HidSetupError> {
    let ids = read_vid_pid(client).await;
    let services = client
        .services_by_uuid(&Uuid::new_short(HID_SERVICE))
        .await
        .map_err(|_| HidSetupError::Gatt)?;
    let hid = services.first().ok_or(HidSetupError::NoHidService)?;
    let characteristics = client
        .characteristics::<MAX_CHARACTERISTICS>(hid)
        .await
        .map_err(|_| HidSetupError::Gatt)?;

    let report_map = characteristics
        .iter()
        .find(|c| c.uuid == Uuid::new_short(REPORT_MAP))
        .ok_or(HidSetupError::NoReportMap)?;
    let mut map = [0u8; MAX_REPORT_MAP];
    let len = client
        .read_characteristic(report_map, &mut map)
        .await
        .map_err(|_| HidSetupError::Gatt)?;
    let mut layout = GamepadLayout::parse(&map[..len.min(MAX_REPORT_MAP)], ids)
        .map_err(|_| HidSetupError::UnusableReportMap)?;

    // Listen before the first CCCD write: the pad may notify as soon as it is
    // subscribed, and a report lost then (a released dead-man, say) is not repeated.
    let mut listener = client.listen_all().map_err(|_| HidSetupError::Gatt)?;
    // HOGP notifications carry no report ID: the Report Reference descriptor of each
    // Report characteristic says which one it is.
    let mut inputs: Vec<(u16, u8), MAX_CHARACTERISTICS> = Vec::new();
    for report in characteristics
        .iter()
        .filter(|c| c.uuid == Uuid::new_short(REPORT))
    {
        let Some(cccd) = report.cccd_handle else {
            continue;
        };
        let reference = client
            .descriptor_by_uuid::<_, [u8]>(report, &Uuid::new_short(REPORT_REFERENCE))
            .await
            .map_err(|_| HidSetupError::Gatt)?;
        let mut value = [0u8; 2];
        client
            .read_descriptor(&reference, &mut value)
            .await
            .map_err(|_| HidSetupError::Gatt)?;
        let [report_id, kind] = value;
        if kind != INPUT_REPORT {
            continue;
        }
        client
            .write_handle(cccd, &[0x01, 0x00])
            .await
            .map_err(|_| HidSetupError::Gatt)?;
        let _ = inputs.push((report.handle, report_id));
    }

    info!(
        "remote: gamepad ready, {=usize} input reports",
        inputs.len()
    );
    loop {
        let notification = listener.next().await;
        let Some(&(_, report_id)) = inputs
            .iter()
            .find(|(handle, _)| *handle == notification.handle())
        else {
            continue;
        };
        // A report that does not decode is dropped: the next one carries the whole
        // state again.
        if let Ok(Some(state)) = layout.decode(report_id, notification.as_ref()) {
            channels
                .inputs
                .send(Input::Gamepad {
                    pad: Pad::Ble,
                    state,
                })
                .await;
        }
    }
}

/// The pad's USB vendor and product ID from the Device Information service, which
/// refines the button map of pads the generic map gets wrong.
async fn read_vid_pid<C: HciController>(
    client: &GattClient<'_, C, DefaultPacketPool, MAX_SERVICES>,
) -> Option<VidPid> {
    let services = client
        .services_by_uuid(&Uuid::new_short(DEVICE_INFORMATION))
        .await
        .ok()?;
    let info = services.first()?;
    let pnp = client
        .characteristic_by_uuid::<[u8]>(info, &Uuid::new_short(PNP_ID))
        .await
        .ok()?;
    let mut value = [0u8; 7];
    let len = client.read_characteristic(&pnp, &mut value).await.ok()?;
    // Vendor ID source (1 byte), vendor ID, product ID, product version (LE u16s).
    (len >= 5).then(|| {
        VidPid::new(
            u16::from_le_bytes([value[1], value[2]]),
            u16::from_le_bytes([value[3], value[4]]),
        )
    })
}

/// Answers the pad's connection parameter requests and returns when the link drops.
async fn watch_link<C: HciController>(
    conn: &Connection<'_, DefaultPacketPool>,
    stack: &Stack<'_, C, DefaultPacketPool>,
) {
    loop {
        match conn.next().await {
            // The bond failed on a link in use (the pad asked for security again and
            // the stored key did not work): this is not the pad we bonded.
            ConnectionEvent::Disconnected { .. } | ConnectionEvent::BondLost => return,
            ConnectionEvent::RequestConnectionParams(request) => {
                answer_params(request, stack).await
            }
            _ => {}
        }
    }
}

/// Answers a pad's connection parameter request with our parameters, whatever it
/// asked for: the 500 ms supervision timeout is what stops the base on a dead link.
async fn answer_params<C: Controller>(
    request: ConnectionParamsRequest,
    stack: &Stack<'_, C, DefaultPacketPool>,
) {
    let _ = request.accept(Some(&connection_params()), stack).await;
}

fn connect_config(targets: &[Address]) -> ConnectConfig<'_> {
    ConnectConfig {
        scan_config: ScanConfig {
            filter_accept_list: targets,
            ..ScanConfig::default()
        },
        connect_params: connection_params(),
    }
}

async fn report(channels: RemoteEnds<'_>, input: Input) {
    channels.inputs.send(input).await;
}

/// Watches advertising reports while scanning and signals the first gamepad: one that
/// shows the gamepad appearance or lists the HID service.
#[derive(Default)]
struct PadFinder {
    found: Signal<RawMutex, Address>,
}

impl EventHandler for PadFinder {
    fn on_adv_reports(&self, mut reports: LeAdvReportsIter<'_>) {
        while let Some(Ok(report)) = reports.next() {
            if advertises_gamepad(report.data) {
                self.found.signal(Address {
                    kind: report.addr_kind,
                    addr: report.addr,
                });
            }
        }
    }
}

/// Whether advertising data announces a HID gamepad.
pub fn advertises_gamepad(data: &[u8]) -> bool {
    AdStructure::decode(data)
        .flatten()
        .any(|structure| match structure {
            AdStructure::IncompleteServiceUuids16(uuids)
            | AdStructure::CompleteServiceUuids16(uuids) => uuids
                .iter()
                .any(|uuid| u16::from_le_bytes(*uuid) == HID_SERVICE),
            AdStructure::Unknown { ty: 0x19, data } => data == GAMEPAD_APPEARANCE.to_le_bytes(),
            _ => false,
        })
}

/// The bond in its partition: one sequential-storage map item, key 0.
struct BondStore<F: NorFlash> {
    flash: F,
    range: Range<u32>,
}

const BOND_KEY: u8 = 0;
/// sequential-storage's work buffer: the record, its key and the item header.
const BOND_BUFFER: usize = BOND_RECORD_LEN + 16;

/// Why the bond could not be stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BondStoreError {
    /// The partition is not whole pages.
    Misconfigured,
    Flash,
}

impl<F: NorFlash> BondStore<F> {
    fn new(flash: F, range: Range<u32>) -> Self {
        Self { flash, range }
    }

    /// The stored bond; `None` for none, or for a record that does not decode (it is
    /// then as if no pad were bonded: pairing again replaces it).
    async fn load(&mut self) -> Option<BondInformation> {
        let mut buffer = [0u8; BOND_BUFFER];
        let config = MapConfig::try_new(self.range.clone()).ok()?;
        let mut map = MapStorage::<u8, _, _>::new(&mut self.flash, config, Cache::new_uncached());
        let record: [u8; BOND_RECORD_LEN] = map.fetch_item(&mut buffer, &BOND_KEY).await.ok()??;
        decode_bond(&record)
    }

    async fn store(&mut self, bond: &BondInformation) -> Result<(), BondStoreError> {
        store_bond(&mut self.flash, self.range.clone(), bond).await
    }
}

/// Writes `bond` as the BLE bond record into the bonds partition `range` of `flash`
/// (the task's own store; a test bonds a pad ahead of a boot with it).
pub async fn store_bond<F: NorFlash>(
    flash: &mut F,
    range: Range<u32>,
    bond: &BondInformation,
) -> Result<(), BondStoreError> {
    let mut buffer = [0u8; BOND_BUFFER];
    let config = MapConfig::try_new(range).map_err(|_| BondStoreError::Misconfigured)?;
    let mut map = MapStorage::<u8, _, _>::new(flash, config, Cache::new_uncached());
    map.store_item(&mut buffer, &BOND_KEY, &encode_bond(bond))
        .await
        .map_err(|_| BondStoreError::Flash)
}

/// A random static Bluetooth address from the chip's MAC (6 bytes, most significant
/// first): the MAC's bytes in the little-endian order of the air, with the two top
/// bits set as random static addresses require. Stable across reboots, so a pad's
/// bond stays valid.
pub fn random_static_address(mac: &[u8]) -> [u8; 6] {
    let mut address = [0u8; 6];
    for (to, from) in address.iter_mut().zip(mac.iter().rev()) {
        *to = *from;
    }
    address[5] |= 0xC0;
    address
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_address_is_the_mac_reversed_with_the_random_static_bits() {
        let address = random_static_address(&[0x10, 0x20, 0x30, 0x40, 0x50, 0x60]);
        assert_eq!(address, [0x60, 0x50, 0x40, 0x30, 0x20, 0xD0]);
    }

    #[test]
    fn gamepads_are_recognised_by_appearance_or_hid_service() {
        // Flags, then appearance 0x03C4 (gamepad).
        assert!(advertises_gamepad(&[
            0x02, 0x01, 0x06, 0x03, 0x19, 0xC4, 0x03
        ]));
        // Complete list of 16-bit service UUIDs with 0x180F and 0x1812.
        assert!(advertises_gamepad(&[0x05, 0x03, 0x0F, 0x18, 0x12, 0x18]));
        // A keyboard appearance (0x03C1) and the battery service only.
        assert!(!advertises_gamepad(&[
            0x03, 0x19, 0xC1, 0x03, 0x03, 0x03, 0x0F, 0x18
        ]));
        // Garbage that claims more bytes than there are.
        assert!(!advertises_gamepad(&[0x09, 0x19, 0xC4]));
    }
}
