//! The PlayStation pad's task: feeds the sans-IO Classic host (`base_bluetooth`) with
//! the controller's packets and time, sends what it answers, and hands the pad's
//! decoded reports to the controller as the BLE task does (`Input::Gamepad`,
//! `Input::RemoteLink`, `Input::RemotePaired`).
//!
//! ```text
//!   splitter ──packets──▶ ClassicHost::step ──packets──▶ splitter ──▶ controller (HCI)
//!   tick (10 ms) ────────▶      │
//!   remote requests ─────▶      └─ pad events: Connected ─▶ GET_REPORT 0x05 (full reports)
//!                                              Interrupt ─▶ PadDecoder ─▶ Input::Gamepad (on change)
//!                                              Bonded ────▶ bond to flash at rest, Input::RemotePaired
//!   base light (on change) ──▶ LightBar ──output report──▶ interrupt channel
//! ```
//!
//! The pad's kind shows in its first full report: from then on the task reports the
//! kind and battery (`Input::RemoteInfo`, again only when the battery changes) and
//! keeps the light bar showing the base's mode (`base_core::hid::light_bar`).
//!
//! Link loss: the host sets a link supervision timeout of [`SUPERVISION_TIMEOUT_MS`]
//! as central, and the pads stream their reports continuously, so a stream that
//! stops for [`REPORT_SILENCE_MS`] counts as a lost link too: the task reports the link
//! down (a held dead-man brakes) and drops it.

use core::ops::Range;

use embassy_futures::select::{Either, Either4, select, select4};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::Cache;
use sequential_storage::map::{MapConfig, MapStorage};

use base_bluetooth::hci::{BdAddr, LinkKey};
use base_bluetooth::{Bond, ClassicHost, Event, Packet, PadEvent, Params};
use base_core::controller::Input;
use base_core::gamepad::GamepadState;
use base_core::hid::light_bar::{self, LIGHT_BAR_PARAMS, LightBar};
use base_core::hid::playstation::{
    FULL_MODE_FEATURE_REQUEST, OUTPUT_REPORT_LEN, PadDecoder, PadKind, ReportMode,
    check_full_mode_feature,
};
use base_core::registers::RemoteInfo;
use base_core::remote::Pad;
use base_core::time::Timestamp;
use bt_hci::transport::Transport;

use super::split::{ClassicPacket, ClassicPort};
use crate::ble::{BOND_RECORD_LEN, RemoteEnds, RemoteRequest};

/// The link supervision timeout the host sets as central: as the BLE link's.
pub const SUPERVISION_TIMEOUT_MS: u64 = 500;
/// A pad in full-report mode streams every few milliseconds (4 ms the DualShock 4,
/// about as often the DualSense): this long without a good report is a lost link.
pub const REPORT_SILENCE_MS: u64 = 100;
/// How often the host's deadlines are looked at, and the silence watchdog.
const TICK: Duration = Duration::from_millis(10);
/// A pad still in its short mode is asked for feature report 0x05 again this often,
/// up to [`FEATURE_REQUESTS`] times (a clone may never leave it; its short reports
/// still drive).
const FEATURE_RETRY_MS: u64 = 1_000;
const FEATURE_REQUESTS: u8 = 5;

/// The Classic bond in the bonds partition: its own map key beside the BLE bond's.
const CLASSIC_BOND_KEY: u8 = 1;
const RECORD_VERSION: u8 = 1;
/// Version, address, link key.
const RECORD_LEN: usize = 1 + 6 + 16;
/// sequential-storage's work buffer: it reads every item of the partition while it
/// looks for ours, so it must hold the largest one, the BLE bond beside ours, with its
/// key and item header. Sized for our record alone, every read failed once a BLE pad
/// was bonded too, and the PlayStation pad was a stranger after each reboot.
const BOND_BUFFER: usize = max(RECORD_LEN, BOND_RECORD_LEN) + 16;
// The BLE task's buffer is sized for its own record: ours must never be larger.
const _: () = assert!(RECORD_LEN <= BOND_RECORD_LEN);

const fn max(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
}

fn slots(ms: u64) -> u16 {
    // 0.625 ms slots.
    (ms * 8 / 5) as u16
}

fn now() -> Timestamp {
    Timestamp::from_millis(Instant::now().as_millis())
}

/// The connected pad, as the task follows it.
struct PadSession {
    decoder: Option<PadDecoder>,
    last_good_report: Timestamp,
    last_state: Option<GamepadState>,
    feature_requests: u8,
    last_feature_request: Timestamp,
    full_mode: bool,
    /// The kind and battery last reported to the controller; `None` until the first
    /// full report tells the kind.
    info: Option<RemoteInfo>,
}

impl PadSession {
    fn new(at: Timestamp) -> Self {
        Self {
            decoder: None,
            last_good_report: at,
            last_state: None,
            feature_requests: 0,
            last_feature_request: at,
            full_mode: false,
            info: None,
        }
    }
}

/// Runs the PlayStation pad's Classic host for ever, on `port` (the splitter's Classic
/// end); the bond lives in `bond_flash` over `bond_range` (the bonds partition).
pub async fn run<T: Transport, F: NorFlash>(
    port: ClassicPort<'_, T>,
    bond_flash: F,
    bond_range: Range<u32>,
    ends: RemoteEnds<'_>,
) -> ! {
    let mut store = ClassicBondStore {
        flash: bond_flash,
        range: bond_range,
    };
    let mut params = Params {
        bond: store.load().await,
        pairing_window_open: false,
        supervision_timeout_slots: slots(SUPERVISION_TIMEOUT_MS),
    };
    ends.inputs
        .send(Input::RemoteLink {
            pad: Pad::Classic,
            bonded: params.bond.is_some(),
            connected: false,
        })
        .await;
    let unsaved: Signal<NoopRawMutex, Bond> = Signal::new();
    let store_at_rest = async {
        loop {
            let bond = unsaved.wait().await;
            wait_at_rest(&ends).await;
            let bond = unsaved.try_take().unwrap_or(bond);
            if store.store(&bond).await.is_err() {
                warn!("classic: the bond could not be stored; it lasts until reboot");
            }
        }
    };
    let serve = async {
        let mut host = ClassicHost::new_shared();
        let mut request = RemoteRequest::default();
        let mut session: Option<PadSession> = None;
        let mut light_bar = LightBar::new();
        loop {
            // The tick, or the light bar's next report if that is due sooner.
            let wake = match light_bar.next_due(&LIGHT_BAR_PARAMS) {
                Some(due) => Duration::from_millis(due.millis_since(now())).min(TICK),
                None => TICK,
            };
            let event = select4(
                port.receive(),
                Timer::after(wake),
                ends.remote_requests.wait(),
                ends.base_light.wait(),
            )
            .await;
            let at = now();
            let mut disconnect = false;
            // The base's light is taken at once (the bar keeps the newest); what the pad
            // does to the bar (connect, disconnect) is stepped after the pad's events.
            if let Either4::Fourth(light) = event {
                let effects = light_bar.step(at, light_bar::Event::Base(light), &LIGHT_BAR_PARAMS);
                show_light(&mut host, effects.report, at, &params, &port).await;
            }
            let mut light_event = light_bar::Event::Tick;
            if let Either4::Third(new) = event {
                disconnect =
                    new.disconnects_of(Pad::Classic) != request.disconnects_of(Pad::Classic);
                request = new;
            }
            params.pairing_window_open = request.pairing_open;
            let effects = match &event {
                Either4::First(ClassicPacket::Event(bytes)) => {
                    host.step(at, Event::Hci(bytes), &params)
                }
                Either4::First(ClassicPacket::Acl(bytes)) => {
                    host.step(at, Event::Acl(bytes), &params)
                }
                Either4::First(ClassicPacket::ControllerReset) => {
                    host.step(at, Event::ControllerReset, &params)
                }
                Either4::Third(_) if disconnect => {
                    info!("classic: the pad is switched off by the controller");
                    host.step(at, Event::Disconnect, &params)
                }
                _ => host.step(at, Event::Tick, &params),
            };
            send(&port, &effects.packets).await;
            for pad in effects.pad {
                match pad {
                    PadEvent::Connected(_) => {
                        info!("classic: pad connected, asking for full reports");
                        let mut fresh = PadSession::new(at);
                        request_full_mode(&mut host, &mut fresh, at, &params, &port).await;
                        session = Some(fresh);
                        link(&ends, &params, true).await;
                    }
                    PadEvent::Disconnected(_) => {
                        light_bar.step(at, light_bar::Event::Disconnected, &LIGHT_BAR_PARAMS);
                        if session.take().is_some() {
                            link(&ends, &params, false).await;
                        }
                    }
                    PadEvent::Bonded(bond) => {
                        info!("classic: new pad paired");
                        params.bond = Some(bond);
                        unsaved.signal(bond);
                        ends.inputs.send(Input::RemotePaired).await;
                    }
                    PadEvent::Control(payload) => {
                        if check_full_mode_feature(&payload).is_err() {
                            warn!("classic: the pad's feature report 0x05 was refused");
                        }
                    }
                    PadEvent::Interrupt(payload) => {
                        if let Some(session) = session.as_mut()
                            && let Some(kind) = report(session, &payload, at, &ends).await
                        {
                            // The kind is known: the light bar can be set.
                            light_event = light_bar::Event::Connected(kind);
                        }
                    }
                }
            }
            // The watchdogs: a silent stream is a lost link; a pad still short is asked
            // again.
            let silent = session
                .as_ref()
                .is_some_and(|s| at.millis_since(s.last_good_report) >= REPORT_SILENCE_MS);
            if silent {
                warn!(
                    "classic: no report for {=u64} ms: the link counts as lost",
                    REPORT_SILENCE_MS
                );
                session = None;
                light_event = light_bar::Event::Disconnected;
                link(&ends, &params, false).await;
                let effects = host.step(at, Event::Disconnect, &params);
                send(&port, &effects.packets).await;
            } else if let Some(active) = session.as_mut()
                && !active.full_mode
                && active.feature_requests < FEATURE_REQUESTS
                && at.millis_since(active.last_feature_request) >= FEATURE_RETRY_MS
            {
                request_full_mode(&mut host, active, at, &params, &port).await;
            }
            let effects = light_bar.step(at, light_event, &LIGHT_BAR_PARAMS);
            show_light(&mut host, effects.report, at, &params, &port).await;
        }
    };
    match select(store_at_rest, serve).await {
        Either::First(never) | Either::Second(never) => never,
    }
}

async fn request_full_mode<T: Transport>(
    host: &mut ClassicHost,
    session: &mut PadSession,
    at: Timestamp,
    params: &Params,
    port: &ClassicPort<'_, T>,
) {
    session.feature_requests += 1;
    session.last_feature_request = at;
    let effects = host.step(at, Event::SendControl(&FULL_MODE_FEATURE_REQUEST), params);
    send(port, &effects.packets).await;
}

/// Sends the light bar's output report, if any, on the pad's interrupt channel.
async fn show_light<T: Transport>(
    host: &mut ClassicHost,
    report: Option<[u8; OUTPUT_REPORT_LEN]>,
    at: Timestamp,
    params: &Params,
    port: &ClassicPort<'_, T>,
) {
    if let Some(report) = report {
        let effects = host.step(at, Event::SendInterrupt(&report), params);
        send(port, &effects.packets).await;
    }
}

async fn send<T: Transport>(port: &ClassicPort<'_, T>, packets: &[Packet]) {
    for packet in packets {
        let sent = match packet {
            Packet::Command(bytes) => port.send_command(bytes).await,
            Packet::Acl(bytes) => port.send_acl(bytes).await,
        };
        if sent.is_err() {
            // The transport broke: the host's deadlines end what waited for it.
            warn!("classic: an HCI packet could not be sent");
        }
    }
}

async fn link(ends: &RemoteEnds<'_>, params: &Params, connected: bool) {
    ends.inputs
        .send(Input::RemoteLink {
            pad: Pad::Classic,
            bonded: params.bond.is_some(),
            connected,
        })
        .await;
}

/// Decodes one interrupt-channel payload and forwards the pad's state when it changed,
/// and its kind and battery when they changed. Returns the pad's kind when this report
/// is the first to tell it.
async fn report(
    session: &mut PadSession,
    payload: &[u8],
    at: Timestamp,
    ends: &RemoteEnds<'_>,
) -> Option<PadKind> {
    // The kind shows in the first full report; the short report is the same for both.
    let kind = PadKind::from_full_report(payload);
    let decoder = match (&mut session.decoder, kind) {
        (Some(decoder), Some(kind)) if decoder.kind() != kind => {
            session.decoder.insert(PadDecoder::new(kind))
        }
        (Some(_), _) => session.decoder.as_mut().expect("checked"),
        (None, kind) => session
            .decoder
            .insert(PadDecoder::new(kind.unwrap_or(PadKind::DualShock4))),
    };
    let Ok(decoded) = decoder.decode(payload) else {
        return None;
    };
    session.last_good_report = at;
    if decoded.mode == ReportMode::Full && !session.full_mode {
        info!("classic: the pad sends full reports");
        session.full_mode = true;
    }
    let mut new_kind = None;
    if let (ReportMode::Full, Some(kind)) = (decoded.mode, kind) {
        let info = RemoteInfo::playstation(kind, decoded.battery);
        if session.info.is_none_or(|sent| sent.kind != info.kind) {
            new_kind = Some(kind);
        }
        if session.info != Some(info) {
            session.info = Some(info);
            ends.inputs
                .send(Input::RemoteInfo {
                    pad: Pad::Classic,
                    info,
                })
                .await;
        }
    }
    if session.last_state != Some(decoded.state) {
        session.last_state = Some(decoded.state);
        ends.inputs
            .send(Input::Gamepad {
                pad: Pad::Classic,
                state: decoded.state,
            })
            .await;
    }
    new_kind
}

/// Waits until the base is at rest. The gate wakes one waiter (the BLE task may wait
/// too), so it is looked at again every 100 ms.
async fn wait_at_rest(ends: &RemoteEnds<'_>) {
    while let Either::Second(()) =
        select(ends.flash_gate.wait_at_rest(), Timer::after_millis(100)).await
    {}
}

struct ClassicBondStore<F: NorFlash> {
    flash: F,
    range: Range<u32>,
}

impl<F: NorFlash> ClassicBondStore<F> {
    /// The stored bond; `None` for none or for a record that does not decode.
    async fn load(&mut self) -> Option<Bond> {
        let mut buffer = [0u8; BOND_BUFFER];
        let config = MapConfig::try_new(self.range.clone()).ok()?;
        let mut map = MapStorage::<u8, _, _>::new(&mut self.flash, config, Cache::new_uncached());
        let record: [u8; RECORD_LEN] = map
            .fetch_item(&mut buffer, &CLASSIC_BOND_KEY)
            .await
            .ok()??;
        decode_bond(&record)
    }

    async fn store(&mut self, bond: &Bond) -> Result<(), ()> {
        let mut buffer = [0u8; BOND_BUFFER];
        let config = MapConfig::try_new(self.range.clone()).map_err(|_| ())?;
        let mut map = MapStorage::<u8, _, _>::new(&mut self.flash, config, Cache::new_uncached());
        map.store_item(&mut buffer, &CLASSIC_BOND_KEY, &encode_bond(bond))
            .await
            .map_err(|_| ())
    }
}

/// The record: version 1, the pad's address (as on the air, least significant byte
/// first), its link key.
pub fn encode_bond(bond: &Bond) -> [u8; RECORD_LEN] {
    let mut record = [0u8; RECORD_LEN];
    record[0] = RECORD_VERSION;
    record[1..7].copy_from_slice(&bond.addr.0);
    record[7..23].copy_from_slice(&bond.key.0);
    record
}

pub fn decode_bond(record: &[u8]) -> Option<Bond> {
    let [RECORD_VERSION, rest @ ..] = record else {
        return None;
    };
    let addr: [u8; 6] = rest.get(..6)?.try_into().ok()?;
    let key: [u8; 16] = rest.get(6..22)?.try_into().ok()?;
    Some(Bond {
        addr: BdAddr(addr),
        key: LinkKey(key),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bond_record_round_trips_and_a_foreign_one_is_refused() {
        let bond = Bond {
            addr: BdAddr([1, 2, 3, 4, 5, 6]),
            key: LinkKey([7; 16]),
        };
        assert_eq!(decode_bond(&encode_bond(&bond)), Some(bond));
        let mut other_version = encode_bond(&bond);
        other_version[0] = 2;
        assert_eq!(decode_bond(&other_version), None);
        assert_eq!(decode_bond(&encode_bond(&bond)[..10]), None);
    }

    #[test]
    fn the_supervision_timeout_is_given_in_slots() {
        assert_eq!(slots(SUPERVISION_TIMEOUT_MS), 800);
    }
}
