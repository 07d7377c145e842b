//! The Classic HID host: one pad at a time, bonded pads only.
//!
//! ```text
//!             Reset … Write Scan Enable, one command at a time
//!  Starting ─────────────────────────────────────────────────▶ Idle ◀──────────────────┐
//!                                                               │                      │
//!     ┌──── window open, back-off over: Inquiry ────────────────┤                      │
//!     ▼                                                         │ the bond's address   │
//!  Inquiring ── a gamepad answers: Create Connection ──┐        │ pages us: Accept     │
//!     │ nothing (Inquiry Complete): back to Idle       ▼        ▼ (as central)         │
//!     └────────────────────────────────────────▶ Connecting (pairing / bonded)         │
//!                                                     │ Connection Complete            │
//!                                                     ▼                                │
//!       link key or, in the window only, Just Works ─ Securing ── any failure ──┐      │
//!       Authentication Requested, Set Encryption      │ encrypted               ▼      │
//!                                                     ▼                   Disconnecting│
//!                                  HID channels ─▶ Ready ── link lost ─────────┼───────┘
//!                                                                   Disconnection Complete
//! ```
//!
//! - Page scan is on from start to end; the robot is never discoverable. Outside the
//!   pairing window only the bond's address is accepted, and it must authenticate with
//!   the stored link key: the host refuses IO capability, user confirmation and PIN
//!   requests, so a pad without the key is dropped and never paired again.
//! - Inside the window the host looks for a gamepad (inquiry, class of device), pages
//!   it and pairs with Secure Simple Pairing, Just Works; the new key is reported as
//!   [`PadEvent::Bonded`]. PIN (legacy) pairing is always refused.
//! - Accepting, the host asks to become central; once central it sets the link
//!   supervision timeout of [`Params`] (only the central may).
//! - After a failure (page timeout, authentication failure, a step that times out)
//!   it backs off 1, 2, 4 … 32 s before its own next inquiry or page. The bonded
//!   address's pages are rejected for 1 s after each failure only, so an impostor at
//!   that address cannot keep the owner out once it stops. A connection that reached
//!   the pad's channels starts over at 1 s.
//! - Malformed HCI events, ACL packets and L2CAP commands are refused and counted in
//!   [`Counters`]; none ends in a panic.

use base_core::time::Timestamp;
use heapless::{Deque, Vec};

use crate::acl::{self, AclPacket, AclSender, Reassembler};
use crate::channels::{HidChannel, HidChannels, Signals};
use crate::hci::{
    self, BdAddr, ClassOfDevice, Command, CommandPacket, Event as HciEvent, GIAC, Handle, LinkKey,
    ScanEnable, status,
};
use crate::l2cap::{self, SIGNALLING_CID};
use crate::{Bond, RECEIVE_MTU};

/// Our own class of device: a computer (major class 1), so that a pad that looks at
/// it sees a host.
pub const HOST_CLASS: ClassOfDevice = ClassOfDevice(0x00_0100);
/// The page timeout set at start: 8192 slots, 5.12 s (the specification's default).
pub const PAGE_TIMEOUT_SLOTS: u16 = 0x2000;
/// Link policy: role switch allowed, no hold, sniff or park (they would add latency
/// to the reports).
pub const LINK_POLICY_ROLE_SWITCH: u16 = 0x0001;
/// Inquiry length, in 1.28 s units: 5.12 s, then the next one starts.
pub const INQUIRY_LENGTH: u8 = 4;

/// How long a connection attempt may take before the host gives it up (ms): longer
/// than the controller's page timeout, which normally ends it first.
pub const CONNECT_TIMEOUT_MS: u64 = 8_000;
/// How long authentication and encryption may take (ms).
pub const SECURITY_TIMEOUT_MS: u64 = 10_000;
/// How long the pad may take to open its HID channels once encrypted (ms).
pub const CHANNELS_TIMEOUT_MS: u64 = 5_000;
/// How long a Disconnect may go unanswered before the link counts as gone (ms).
pub const DISCONNECT_TIMEOUT_MS: u64 = 3_000;
/// An inquiry that has not completed after this long is cancelled (ms).
pub const INQUIRY_TIMEOUT_MS: u64 = INQUIRY_LENGTH as u64 * 1_280 + 2_000;
/// How long after a failed setup command the host starts the controller again (ms).
pub const SETUP_RETRY_MS: u64 = 1_000;
/// How long a setup command may go unanswered (ms); Reset takes the longest.
pub const SETUP_TIMEOUT_MS: u64 = 2_000;
/// The first back-off after a failure (ms); it doubles up to [`MAX_BACK_OFF_MS`].
pub const FIRST_BACK_OFF_MS: u64 = 1_000;
pub const MAX_BACK_OFF_MS: u64 = 32_000;
/// How long the bonded address's pages are refused after a failure (ms), however long
/// the host's own back-off has grown: an impostor at that address gets one try a
/// second, and the owner's pad is accepted at most this long after the impostor stops.
pub const PAGE_BACK_OFF_MS: u64 = 1_000;

/// The commands that prepare the controller, in order; each waits for its answer.
const SETUP: [Command; 8] = [
    Command::Reset,
    Command::ReadBufferSize,
    Command::SetEventMask(hci::EVENT_MASK),
    Command::WriteSimplePairingMode { enabled: true },
    Command::WriteClassOfDevice(HOST_CLASS),
    Command::WritePageTimeout {
        slots: PAGE_TIMEOUT_SLOTS,
    },
    Command::WriteDefaultLinkPolicy {
        settings: LINK_POLICY_ROLE_SWITCH,
    },
    Command::WriteScanEnable(ScanEnable::PageScan),
];

/// The setup in front of a controller that another host shares (the BLE host behind
/// an HCI splitter): that host resets the controller and sets its event mask (which
/// the splitter widens by [`hci::EVENT_MASK`]); this one only adds its own settings,
/// after each of that host's resets ([`Event::ControllerReset`]).
const SHARED_SETUP: [Command; 6] = [
    Command::ReadBufferSize,
    Command::WriteSimplePairingMode { enabled: true },
    Command::WriteClassOfDevice(HOST_CLASS),
    Command::WritePageTimeout {
        slots: PAGE_TIMEOUT_SLOTS,
    },
    Command::WriteDefaultLinkPolicy {
        settings: LINK_POLICY_ROLE_SWITCH,
    },
    Command::WriteScanEnable(ScanEnable::PageScan),
];

/// What the host reads from the registers and the bond store, on every step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Params {
    /// The bonded pad, if any.
    pub bond: Option<Bond>,
    /// The pairing window is open: a new pad may be found and paired.
    pub pairing_window_open: bool,
    /// The link supervision timeout the host sets as central, in slots of 0.625 ms.
    pub supervision_timeout_slots: u16,
}

/// Everything the host reacts to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event<'a> {
    /// An HCI event packet from the controller: code, length, parameters.
    Hci(&'a [u8]),
    /// An ACL data packet from the controller: header, payload.
    Acl(&'a [u8]),
    /// Send this on the pad's control channel (a GET_REPORT, say).
    SendControl(&'a [u8]),
    /// Send this on the pad's interrupt channel (an output report).
    SendInterrupt(&'a [u8]),
    /// Close the link to the pad (the remote switches it off).
    Disconnect,
    /// Time passed: deadlines and back-off are checked.
    Tick,
    /// The controller was reset by the host it is shared with (see
    /// [`ClassicHost::new_shared`]): every link is gone, the setup starts again.
    ControllerReset,
}

/// A packet for the controller.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Packet {
    Command(CommandPacket),
    Acl(AclPacket),
}

/// The longest payload handed up from a HID channel.
pub type Payload = Vec<u8, { RECEIVE_MTU as usize }>;

/// What the host tells the application about the pad.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PadEvent {
    /// Both HID channels are open on an encrypted link.
    Connected(BdAddr),
    /// The HID connection is gone (after `Connected`).
    Disconnected(BdAddr),
    /// A new pad paired inside the window: store this bond.
    Bonded(Bond),
    /// A payload from the control channel (a HANDSHAKE or a GET_REPORT answer).
    Control(Payload),
    /// A payload from the interrupt channel (an input report).
    Interrupt(Payload),
}

/// Why something was refused or went wrong; kept as counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    pub malformed_events: u32,
    pub malformed_acl: u32,
    pub malformed_signals: u32,
    /// Data for a channel or link that is not open.
    pub unrouted_data: u32,
    /// Pages we rejected: a stranger, or anyone while backing off.
    pub rejected_connections: u32,
    /// Pairing attempts refused outside the window, PIN requests always.
    pub refused_pairings: u32,
    /// Connections that ended before the pad's channels opened.
    pub failed_connections: u32,
    /// Frames to the pad dropped: channel not open, too long, or the queue full.
    pub dropped_sends: u32,
    /// Setup commands the controller failed.
    pub controller_errors: u32,
}

/// One step's answer. Packets are in the order they must reach the controller. What
/// does not fit, or waits for the controller's credits or buffers, goes out with a
/// later step: the runtime steps the host on every packet and on a periodic `Tick`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Effects {
    pub packets: Vec<Packet, 8>,
    pub pad: Vec<PadEvent, 3>,
}

/// A link that exists on the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Link {
    handle: Handle,
    addr: BdAddr,
    /// Pairing a new pad (inside the window) rather than meeting the bonded one.
    pairing: bool,
    /// We paged: we open the HID channels. A bonded pad that paged us opens them.
    we_paged: bool,
    central: bool,
    /// When the current step began (for its deadline).
    since: Timestamp,
    channels: HidChannels,
    /// The key the controller made while pairing.
    new_key: Option<LinkKey>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Security {
    Authenticating,
    Encrypting,
}

/// Where the controller's setup is: at which of the [`SETUP`] commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Setup {
    /// Send this one next.
    Next(usize),
    /// Sent at `since`, its Command Complete not in yet.
    Awaiting { step: usize, since: Timestamp },
    /// A command failed or went unanswered: start over with Reset at this time.
    RetryAt(Timestamp),
    /// A shared controller: waiting for the other host's Reset.
    AwaitingReset,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    Starting(Setup),
    Idle,
    Inquiring {
        since: Timestamp,
    },
    Connecting {
        addr: BdAddr,
        pairing: bool,
        we_paged: bool,
        /// A Role Change before Connection Complete.
        central: bool,
        since: Timestamp,
    },
    Securing(Link, Security),
    /// Encrypted; `connected` once both HID channels opened.
    Ready {
        link: Link,
        connected: bool,
    },
    Disconnecting {
        handle: Handle,
        addr: BdAddr,
        connected: bool,
        since: Timestamp,
    },
}

/// The host. See the module documentation for the diagram and the rules.
#[derive(Debug, Clone)]
pub struct ClassicHost {
    state: State,
    /// Failures in a row, for the back-off, and when the next attempt may start.
    failures: u32,
    retry_at: Timestamp,
    /// When the bonded address's pages are accepted again after a failure.
    accept_pages_at: Timestamp,
    commands: Deque<Command, 8>,
    /// How many commands the controller takes now.
    command_credits: u8,
    acl_out: AclSender,
    acl_in: Reassembler,
    counters: Counters,
    /// The controller is shared with another host, which resets it.
    shared: bool,
}

impl Default for ClassicHost {
    fn default() -> Self {
        Self::new()
    }
}

impl ClassicHost {
    pub const fn new() -> ClassicHost {
        ClassicHost {
            state: State::Starting(Setup::Next(0)),
            failures: 0,
            retry_at: Timestamp::BOOT,
            accept_pages_at: Timestamp::BOOT,
            commands: Deque::new(),
            command_credits: 1,
            acl_out: AclSender::new(),
            acl_in: Reassembler::new(),
            counters: Counters {
                malformed_events: 0,
                malformed_acl: 0,
                malformed_signals: 0,
                unrouted_data: 0,
                rejected_connections: 0,
                refused_pairings: 0,
                failed_connections: 0,
                dropped_sends: 0,
                controller_errors: 0,
            },
            shared: false,
        }
    }

    /// A host for a controller shared with another host that resets it and sets its
    /// event mask (see [`SHARED_SETUP`]): it waits for [`Event::ControllerReset`].
    pub const fn new_shared() -> ClassicHost {
        let mut host = ClassicHost::new();
        host.state = State::Starting(Setup::AwaitingReset);
        host.shared = true;
        host
    }

    fn setup(&self) -> &'static [Command] {
        if self.shared { &SHARED_SETUP } else { &SETUP }
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// The pad whose HID channels are open, if any.
    pub fn connected_pad(&self) -> Option<BdAddr> {
        match self.state {
            State::Ready {
                link,
                connected: true,
            } => Some(link.addr),
            _ => None,
        }
    }

    /// Handles one event at `now` and returns the packets for the controller and the
    /// news for the application.
    pub fn step(&mut self, now: Timestamp, event: Event<'_>, params: &Params) -> Effects {
        let mut effects = Effects::default();
        match event {
            Event::Hci(packet) => match HciEvent::decode(packet) {
                Ok(event) => self.hci_event(now, event, params, &mut effects),
                Err(error) => {
                    warn!("malformed HCI event refused: {}", error);
                    self.counters.malformed_events += 1;
                }
            },
            Event::Acl(packet) => self.acl(now, packet, &mut effects),
            Event::SendControl(payload) => self.send(HidChannel::Control, payload),
            Event::SendInterrupt(payload) => self.send(HidChannel::Interrupt, payload),
            Event::Disconnect => {
                if let State::Securing(link, _) | State::Ready { link, .. } = self.state {
                    self.disconnect(now, link, status::REMOTE_USER_TERMINATED);
                }
            }
            Event::Tick => {}
            Event::ControllerReset => {
                if let State::Ready {
                    link,
                    connected: true,
                } = self.state
                {
                    let _ = effects.pad.push(PadEvent::Disconnected(link.addr));
                }
                self.restart_at(now);
            }
        }
        self.deadlines(now, params);
        self.start_next(now, params);
        self.flush(&mut effects);
        effects
    }

    fn command(&mut self, command: Command) {
        if self.commands.push_back(command).is_err() {
            // Eight commands in flight means the controller stopped answering.
            warn!("HCI command queue full: {} dropped", command);
        }
    }

    /// Hands the controller what it can take now: commands while it has credits, ACL
    /// packets while it has buffers.
    fn flush(&mut self, effects: &mut Effects) {
        while self.command_credits > 0 && !effects.packets.is_full() {
            let Some(command) = self.commands.pop_front() else {
                break;
            };
            self.command_credits -= 1;
            let _ = effects.packets.push(Packet::Command(command.encode()));
        }
        while !effects.packets.is_full() {
            let Some(packet) = self.acl_out.next_packet() else {
                break;
            };
            let _ = effects.packets.push(Packet::Acl(packet));
        }
    }

    fn fail(&mut self, now: Timestamp) {
        self.counters.failed_connections += 1;
        let back_off = FIRST_BACK_OFF_MS
            .saturating_mul(1 << self.failures.min(5))
            .min(MAX_BACK_OFF_MS);
        self.failures = self.failures.saturating_add(1);
        self.retry_at = now.plus_millis(back_off);
        self.accept_pages_at = now.plus_millis(back_off.min(PAGE_BACK_OFF_MS));
    }

    fn disconnect(&mut self, now: Timestamp, link: Link, reason: u8) {
        let connected = matches!(
            self.state,
            State::Ready {
                connected: true,
                ..
            }
        );
        if !connected {
            self.fail(now);
        }
        self.command(Command::Disconnect {
            handle: link.handle,
            reason,
        });
        self.state = State::Disconnecting {
            handle: link.handle,
            addr: link.addr,
            connected,
            since: now,
        };
    }

    /// Starts what the state asks for once nothing is in progress.
    fn start_next(&mut self, now: Timestamp, params: &Params) {
        match self.state {
            State::Starting(Setup::Next(step)) => {
                if let Some(command) = self.setup().get(step) {
                    self.command(*command);
                    self.state = State::Starting(Setup::Awaiting { step, since: now });
                }
            }
            State::Idle if params.pairing_window_open && now >= self.retry_at => {
                info!("pairing window open: looking for a gamepad");
                self.command(Command::Inquiry {
                    lap: GIAC,
                    length: INQUIRY_LENGTH,
                    max_responses: 0,
                });
                self.state = State::Inquiring { since: now };
            }
            _ => {}
        }
    }

    fn deadlines(&mut self, now: Timestamp, params: &Params) {
        match self.state {
            State::Starting(Setup::RetryAt(at)) if now >= at => {
                self.state = State::Starting(Setup::Next(0));
            }
            State::Starting(Setup::Awaiting { since, .. })
                if now.millis_since(since) >= SETUP_TIMEOUT_MS =>
            {
                error!("controller did not answer a setup command: starting again");
                self.counters.controller_errors += 1;
                self.restart_at(now.plus_millis(SETUP_RETRY_MS));
            }
            State::Inquiring { since }
                if !params.pairing_window_open || now.millis_since(since) >= INQUIRY_TIMEOUT_MS =>
            {
                self.command(Command::InquiryCancel);
                self.state = State::Idle;
            }
            State::Connecting {
                addr,
                we_paged,
                since,
                ..
            } if now.millis_since(since) >= CONNECT_TIMEOUT_MS => {
                // A connection that completes after all is closed again (see Idle).
                if we_paged {
                    self.command(Command::CreateConnectionCancel(addr));
                }
                self.fail(now);
                self.state = State::Idle;
            }
            State::Securing(link, _) if now.millis_since(link.since) >= SECURITY_TIMEOUT_MS => {
                warn!("pad did not authenticate in time");
                self.disconnect(now, link, status::AUTHENTICATION_FAILURE);
            }
            State::Ready {
                link,
                connected: false,
            } if now.millis_since(link.since) >= CHANNELS_TIMEOUT_MS => {
                warn!("pad did not open its HID channels in time");
                self.disconnect(now, link, status::REMOTE_USER_TERMINATED);
            }
            State::Disconnecting {
                handle,
                addr,
                connected,
                since,
            } if now.millis_since(since) >= DISCONNECT_TIMEOUT_MS => {
                warn!("Disconnect unanswered: the link counts as gone");
                let _ = (addr, connected);
                self.link_gone(handle);
            }
            _ => {}
        }
    }

    fn link_gone(&mut self, handle: Handle) {
        self.acl_out.link_closed(handle);
        self.acl_in = Reassembler::new();
        self.state = State::Idle;
    }

    fn hci_event(
        &mut self,
        now: Timestamp,
        event: HciEvent,
        params: &Params,
        effects: &mut Effects,
    ) {
        // Flow control first, whatever the state.
        match &event {
            HciEvent::CommandComplete { credits, .. } | HciEvent::CommandStatus { credits, .. } => {
                self.command_credits = *credits;
            }
            HciEvent::NumberOfCompletedPackets(completed) => {
                // Only our link's: another host's handles (BLE, behind a splitter)
                // free buffers that are not ours.
                let ours = match self.state {
                    State::Securing(link, _) | State::Ready { link, .. } => Some(link.handle),
                    State::Disconnecting { handle, .. } => Some(handle),
                    _ => None,
                };
                for (handle, packets) in completed {
                    if Some(*handle) == ours {
                        self.acl_out.completed(*packets);
                    }
                }
                return;
            }
            _ => {}
        }
        match (self.state, event) {
            (_, HciEvent::HardwareError { code }) => {
                error!("controller hardware error {=u8}: starting it again", code);
                if let State::Ready {
                    link,
                    connected: true,
                } = self.state
                {
                    let _ = effects.pad.push(PadEvent::Disconnected(link.addr));
                }
                self.restart_at(now);
            }
            (
                State::Starting(Setup::Awaiting { step, .. }),
                HciEvent::CommandComplete {
                    opcode,
                    status,
                    acl_buffers,
                    ..
                },
            ) if self.setup().get(step).is_some_and(|c| c.opcode() == opcode) => {
                if status != status::SUCCESS {
                    error!(
                        "controller setup failed: opcode {=u16:#x}, status {=u8:#x}",
                        opcode, status
                    );
                    self.counters.controller_errors += 1;
                    self.restart_at(now.plus_millis(SETUP_RETRY_MS));
                    return;
                }
                if let Some(buffers) = acl_buffers {
                    self.acl_out.set_buffers(buffers);
                }
                self.state = if step + 1 == self.setup().len() {
                    info!("Classic controller ready, page scan on");
                    self.failures = 0;
                    self.retry_at = now;
                    self.accept_pages_at = now;
                    State::Idle
                } else {
                    State::Starting(Setup::Next(step + 1))
                };
            }
            (State::Inquiring { .. }, HciEvent::InquiryResult(found)) => {
                if let Some(pad) = found.iter().find(|r| r.class.is_gamepad()) {
                    info!("gamepad found: paging it");
                    self.command(Command::InquiryCancel);
                    self.command(Command::CreateConnection {
                        addr: pad.addr,
                        page_scan_repetition_mode: pad.page_scan_repetition_mode,
                        clock_offset: pad.clock_offset | 0x8000,
                        allow_role_switch: false,
                    });
                    self.state = State::Connecting {
                        addr: pad.addr,
                        pairing: true,
                        we_paged: true,
                        central: true,
                        since: now,
                    };
                }
            }
            (State::Inquiring { .. }, HciEvent::InquiryComplete { .. }) => {
                self.state = State::Idle;
            }
            (
                state,
                HciEvent::ConnectionRequest {
                    addr, link_type, ..
                },
            ) => {
                let bonded = params.bond.is_some_and(|bond| bond.addr == addr);
                let free = matches!(state, State::Idle | State::Inquiring { .. });
                let accept = free && link_type == 0x01 && bonded && now >= self.accept_pages_at;
                if accept {
                    if let State::Inquiring { .. } = state {
                        // The bonded pad came back while the window is open.
                        self.command(Command::InquiryCancel);
                    }
                    self.command(Command::AcceptConnectionRequest(addr));
                    self.state = State::Connecting {
                        addr,
                        pairing: false,
                        we_paged: false,
                        central: false,
                        since: now,
                    };
                } else {
                    let reason = if bonded {
                        status::REJECTED_LIMITED_RESOURCES
                    } else {
                        status::REJECTED_UNACCEPTABLE_ADDRESS
                    };
                    self.counters.rejected_connections += 1;
                    self.command(Command::RejectConnectionRequest { addr, reason });
                }
            }
            (
                State::Connecting {
                    addr,
                    pairing,
                    we_paged,
                    central,
                    ..
                },
                HciEvent::RoleChange {
                    status: status::SUCCESS,
                    addr: changed,
                    central: now_central,
                },
            ) if changed == addr => {
                self.state = State::Connecting {
                    addr,
                    pairing,
                    we_paged,
                    central: central || now_central,
                    since: now,
                };
            }
            (
                State::Connecting {
                    addr,
                    pairing,
                    we_paged,
                    central,
                    ..
                },
                HciEvent::ConnectionComplete {
                    status,
                    handle,
                    addr: connected,
                    ..
                },
            ) if connected == addr => {
                if status != status::SUCCESS {
                    warn!("connection failed: status {=u8:#x}", status);
                    self.fail(now);
                    self.state = State::Idle;
                    return;
                }
                let link = Link {
                    handle,
                    addr,
                    pairing,
                    we_paged,
                    central,
                    since: now,
                    channels: HidChannels::new(),
                    new_key: None,
                };
                if central {
                    self.supervise(link, params);
                } else {
                    self.command(Command::SwitchRoleToCentral(addr));
                }
                self.command(Command::AuthenticationRequested(handle));
                self.state = State::Securing(link, Security::Authenticating);
            }
            (
                State::Securing(mut link, _) | State::Ready { mut link, .. },
                HciEvent::RoleChange {
                    status: status::SUCCESS,
                    addr,
                    central: true,
                },
            ) if addr == link.addr && !link.central => {
                link.central = true;
                self.supervise(link, params);
                self.set_link(link);
            }
            (
                State::Securing(link, _) | State::Ready { link, .. },
                HciEvent::LinkKeyRequest(addr),
            ) if addr == link.addr => {
                // A new pad has no key before it paired, and after that only its new one.
                let key = if link.pairing {
                    link.new_key
                } else {
                    params
                        .bond
                        .filter(|bond| bond.addr == addr)
                        .map(|bond| bond.key)
                };
                match key {
                    Some(key) => self.command(Command::LinkKeyRequestReply { addr, key }),
                    None => self.command(Command::LinkKeyRequestNegativeReply(addr)),
                }
            }
            (State::Securing(link, _), HciEvent::IoCapabilityRequest(addr))
                if addr == link.addr =>
            {
                if link.pairing && params.pairing_window_open {
                    self.command(Command::IoCapabilityRequestReply(addr));
                } else {
                    warn!("pairing refused outside the pairing window");
                    self.counters.refused_pairings += 1;
                    self.command(Command::IoCapabilityRequestNegativeReply {
                        addr,
                        reason: status::PAIRING_NOT_ALLOWED,
                    });
                }
            }
            (State::Securing(link, _), HciEvent::UserConfirmationRequest(addr))
                if addr == link.addr =>
            {
                if link.pairing && params.pairing_window_open {
                    self.command(Command::UserConfirmationRequestReply(addr));
                } else {
                    self.counters.refused_pairings += 1;
                    self.command(Command::UserConfirmationRequestNegativeReply(addr));
                }
            }
            (_, HciEvent::PinCodeRequest(addr)) => {
                warn!("PIN pairing refused");
                self.counters.refused_pairings += 1;
                self.command(Command::PinCodeRequestNegativeReply(addr));
            }
            (
                State::Securing(mut link, security),
                HciEvent::LinkKeyNotification { addr, key, .. },
            ) if addr == link.addr && link.pairing => {
                link.new_key = Some(key);
                self.state = State::Securing(link, security);
            }
            (
                State::Securing(link, Security::Authenticating),
                HciEvent::AuthenticationComplete { status, handle },
            ) if handle == link.handle => {
                if status == status::SUCCESS {
                    self.command(Command::SetConnectionEncryption {
                        handle,
                        enabled: true,
                    });
                    self.state = State::Securing(link, Security::Encrypting);
                } else {
                    warn!("pad failed to authenticate: status {=u8:#x}", status);
                    self.disconnect(now, link, status::AUTHENTICATION_FAILURE);
                }
            }
            (
                State::Securing(mut link, Security::Encrypting),
                HciEvent::EncryptionChange {
                    status,
                    handle,
                    enabled,
                },
            ) if handle == link.handle => {
                if status != status::SUCCESS || !enabled {
                    self.disconnect(now, link, status::AUTHENTICATION_FAILURE);
                    return;
                }
                if let (true, Some(key)) = (link.pairing, link.new_key) {
                    info!("new pad paired");
                    let _ = effects.pad.push(PadEvent::Bonded(Bond {
                        addr: link.addr,
                        key,
                    }));
                }
                link.since = now;
                let mut signals = Signals::new();
                link.channels.encrypted(link.we_paged, &mut signals);
                self.send_signals(link.handle, &signals);
                self.state = State::Ready {
                    link,
                    connected: false,
                };
            }
            (
                State::Ready { link, .. },
                HciEvent::EncryptionChange {
                    handle,
                    enabled: false,
                    ..
                },
            ) if handle == link.handle => {
                warn!("pad's link lost its encryption");
                self.disconnect(now, link, status::AUTHENTICATION_FAILURE);
            }
            (
                State::Securing(link, _) | State::Ready { link, .. },
                HciEvent::DisconnectionComplete { handle, .. },
            ) if handle == link.handle => {
                if let State::Ready {
                    connected: true, ..
                } = self.state
                {
                    info!("pad's link lost");
                    let _ = effects.pad.push(PadEvent::Disconnected(link.addr));
                } else {
                    self.fail(now);
                }
                self.link_gone(handle);
            }
            (
                State::Disconnecting {
                    handle,
                    addr,
                    connected,
                    ..
                },
                HciEvent::DisconnectionComplete { handle: gone, .. },
            ) if gone == handle => {
                if connected {
                    let _ = effects.pad.push(PadEvent::Disconnected(addr));
                }
                self.link_gone(handle);
            }
            (
                State::Securing(link, _) | State::Ready { link, .. },
                HciEvent::CommandStatus { status, opcode, .. },
            ) if status != status::SUCCESS
                && (opcode == Command::AuthenticationRequested(link.handle).opcode()
                    || opcode
                        == (Command::SetConnectionEncryption {
                            handle: link.handle,
                            enabled: true,
                        })
                        .opcode()) =>
            {
                self.disconnect(now, link, status::AUTHENTICATION_FAILURE);
            }
            (State::Connecting { addr, .. }, HciEvent::CommandStatus { status, opcode, .. })
                if status != status::SUCCESS
                    && (opcode == Command::AcceptConnectionRequest(addr).opcode()
                        || opcode
                            == (Command::CreateConnection {
                                addr,
                                page_scan_repetition_mode: 0,
                                clock_offset: 0,
                                allow_role_switch: false,
                            })
                            .opcode()) =>
            {
                self.fail(now);
                self.state = State::Idle;
            }
            (
                State::Idle | State::Inquiring { .. },
                HciEvent::ConnectionComplete {
                    status: status::SUCCESS,
                    handle,
                    ..
                },
            ) => {
                // A page we gave up on that succeeded after all: not wanted any more.
                self.command(Command::Disconnect {
                    handle,
                    reason: status::REMOTE_USER_TERMINATED,
                });
            }
            // Everything else: answers to commands that need no follow-up, events for
            // links that are not ours, and events of no use in this state.
            _ => {}
        }
    }

    /// Keeps the state and puts `link` in it.
    fn set_link(&mut self, link: Link) {
        self.state = match self.state {
            State::Securing(_, security) => State::Securing(link, security),
            State::Ready { connected, .. } => State::Ready { link, connected },
            state => state,
        };
    }

    fn supervise(&mut self, link: Link, params: &Params) {
        self.command(Command::WriteLinkSupervisionTimeout {
            handle: link.handle,
            slots: params.supervision_timeout_slots,
        });
    }

    /// Forgets every link and command and sets the controller up again from `at`
    /// (its links are gone with the Reset).
    fn restart_at(&mut self, at: Timestamp) {
        self.commands.clear();
        self.command_credits = 1;
        self.acl_out = AclSender::new();
        self.acl_in = Reassembler::new();
        self.state = State::Starting(Setup::RetryAt(at));
    }

    fn acl(&mut self, now: Timestamp, packet: &[u8], effects: &mut Effects) {
        let link = match self.state {
            State::Securing(link, _) | State::Ready { link, .. } => link,
            _ => {
                self.counters.unrouted_data += 1;
                return;
            }
        };
        let (handle, boundary, piece) = match acl::split(packet) {
            Ok(split) => split,
            Err(error) => {
                warn!("malformed ACL packet refused: {}", error);
                self.counters.malformed_acl += 1;
                return;
            }
        };
        if handle != link.handle {
            self.counters.unrouted_data += 1;
            return;
        }
        let frame = match self.acl_in.push(boundary, piece) {
            Ok(Some(frame)) => frame,
            Ok(None) => return,
            Err(_) => {
                self.counters.malformed_acl += 1;
                return;
            }
        };
        let Some((cid, payload)) = l2cap::split_frame(frame) else {
            self.counters.malformed_acl += 1;
            return;
        };
        let Ok(payload) = Payload::from_slice(payload) else {
            self.counters.malformed_acl += 1;
            return;
        };
        if cid == SIGNALLING_CID {
            self.signalling(now, link, &payload, effects);
            return;
        }
        let encrypted = matches!(self.state, State::Ready { .. });
        match link.channels.route(cid) {
            Some(HidChannel::Control) if encrypted => {
                let _ = effects.pad.push(PadEvent::Control(payload));
            }
            Some(HidChannel::Interrupt) if encrypted => {
                let _ = effects.pad.push(PadEvent::Interrupt(payload));
            }
            _ => self.counters.unrouted_data += 1,
        }
    }

    fn signalling(
        &mut self,
        now: Timestamp,
        mut link: Link,
        payload: &[u8],
        effects: &mut Effects,
    ) {
        let encrypted = matches!(self.state, State::Ready { .. });
        for command in l2cap::commands(payload) {
            if command.is_err() {
                self.counters.malformed_signals += 1;
            }
            let mut signals = Signals::new();
            let result = link.channels.signal(command, encrypted, &mut signals);
            self.send_signals(link.handle, &signals);
            if let Err(failure) = result {
                warn!("HID channel failed: {}", failure);
                self.set_link(link);
                self.disconnect(now, link, status::REMOTE_USER_TERMINATED);
                return;
            }
        }
        let newly_open = matches!(
            self.state,
            State::Ready {
                connected: false,
                ..
            }
        ) && link.channels.open();
        if newly_open {
            info!("pad connected: HID channels open");
            self.failures = 0;
            let _ = effects.pad.push(PadEvent::Connected(link.addr));
            self.state = State::Ready {
                link,
                connected: true,
            };
        } else {
            self.set_link(link);
        }
    }

    fn send_signals(&mut self, handle: Handle, signals: &Signals) {
        for command in signals {
            let bytes = l2cap::encode(command);
            let mut frame: Vec<u8, { 4 + l2cap::MAX_SIGNAL_LEN }> = Vec::new();
            let _ =
                frame.extend_from_slice(&l2cap::frame_header(bytes.len() as u16, SIGNALLING_CID));
            let _ = frame.extend_from_slice(&bytes);
            if self.acl_out.queue(handle, &frame).is_err() {
                self.counters.dropped_sends += 1;
            }
        }
    }

    fn send(&mut self, which: HidChannel, payload: &[u8]) {
        let State::Ready {
            link,
            connected: true,
        } = self.state
        else {
            self.counters.dropped_sends += 1;
            return;
        };
        let Some((remote_cid, remote_mtu)) = link.channels.remote(which) else {
            self.counters.dropped_sends += 1;
            return;
        };
        let mut frame: Vec<u8, { acl::MAX_TX_FRAME }> = Vec::new();
        let fits = payload.len() <= usize::from(remote_mtu)
            && frame
                .extend_from_slice(&l2cap::frame_header(payload.len() as u16, remote_cid))
                .is_ok()
            && frame.extend_from_slice(payload).is_ok();
        if !fits || self.acl_out.queue(link.handle, &frame).is_err() {
            self.counters.dropped_sends += 1;
        }
    }
}

#[cfg(test)]
mod tests;
