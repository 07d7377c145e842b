//! Tables of (time, event) → packets and pad events. The harness answers every
//! command the host sends with a Command Status (success, one credit), as a controller
//! does, so that each row shows all the commands one event leads to.

use super::*;
use crate::hci::AclBuffers;
use crate::l2cap::{
    Command as Signalling, ConfigOptions, PSM_HID_CONTROL, PSM_HID_INTERRUPT, Signal,
    config_result, connect_result,
};
use crate::test_events::{self as ev, HANDLE, KEY, NEW_KEY, PAD, STRANGER};

const SUPERVISION_SLOTS: u16 = 160;
const BONDED: Params = Params {
    bond: Some(Bond {
        addr: PAD,
        key: KEY,
    }),
    pairing_window_open: false,
    supervision_timeout_slots: SUPERVISION_SLOTS,
};
const WINDOW: Params = Params {
    bond: None,
    pairing_window_open: true,
    supervision_timeout_slots: SUPERVISION_SLOTS,
};
const PAD_CONTROL: u16 = 0x0070;
const PAD_INTERRUPT: u16 = 0x0071;

/// What one event led to, the answers to the commands included.
#[derive(Debug, Default, PartialEq)]
struct Outcome {
    commands: std::vec::Vec<Command>,
    /// L2CAP frames sent (signalling decoded, data as bytes).
    signals: std::vec::Vec<Signalling>,
    data: std::vec::Vec<(u16, std::vec::Vec<u8>)>,
    pad: std::vec::Vec<PadEvent>,
}

struct Harness {
    host: ClassicHost,
    now: u64,
    params: Params,
}

/// Every command the host may send, to map bytes back to values.
fn decode_command(packet: &[u8]) -> Command {
    let candidates = [
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
        Command::Inquiry {
            lap: GIAC,
            length: INQUIRY_LENGTH,
            max_responses: 0,
        },
        Command::InquiryCancel,
        Command::CreateConnection {
            addr: PAD,
            page_scan_repetition_mode: 1,
            clock_offset: 0x9234,
            allow_role_switch: false,
        },
        Command::CreateConnectionCancel(PAD),
        Command::AcceptConnectionRequest(PAD),
        Command::RejectConnectionRequest {
            addr: STRANGER,
            reason: status::REJECTED_UNACCEPTABLE_ADDRESS,
        },
        Command::RejectConnectionRequest {
            addr: PAD,
            reason: status::REJECTED_LIMITED_RESOURCES,
        },
        Command::RejectConnectionRequest {
            addr: PAD,
            reason: status::REJECTED_UNACCEPTABLE_ADDRESS,
        },
        Command::LinkKeyRequestReply {
            addr: PAD,
            key: KEY,
        },
        Command::LinkKeyRequestReply {
            addr: PAD,
            key: NEW_KEY,
        },
        Command::LinkKeyRequestNegativeReply(PAD),
        Command::PinCodeRequestNegativeReply(PAD),
        Command::AuthenticationRequested(HANDLE),
        Command::SetConnectionEncryption {
            handle: HANDLE,
            enabled: true,
        },
        Command::IoCapabilityRequestReply(PAD),
        Command::IoCapabilityRequestNegativeReply {
            addr: PAD,
            reason: status::PAIRING_NOT_ALLOWED,
        },
        Command::UserConfirmationRequestReply(PAD),
        Command::UserConfirmationRequestNegativeReply(PAD),
        Command::SwitchRoleToCentral(PAD),
        Command::WriteLinkSupervisionTimeout {
            handle: HANDLE,
            slots: SUPERVISION_SLOTS,
        },
        Command::Disconnect {
            handle: HANDLE,
            reason: status::REMOTE_USER_TERMINATED,
        },
        Command::Disconnect {
            handle: HANDLE,
            reason: status::AUTHENTICATION_FAILURE,
        },
    ];
    *candidates
        .iter()
        .find(|c| c.encode().as_slice() == packet)
        .unwrap_or_else(|| panic!("unexpected command {packet:02x?}"))
}

impl Harness {
    /// A host whose controller answered every setup command, idle (the window opens
    /// only after setup, at the first step of the test).
    fn ready(params: Params) -> Harness {
        let mut harness = Harness {
            host: ClassicHost::new(),
            now: 0,
            params: Params {
                pairing_window_open: false,
                ..params
            },
        };
        let mut sent = harness.raw(Event::Tick).commands;
        for command in SETUP {
            assert_eq!(sent, [command]);
            let answer = match command {
                Command::ReadBufferSize => ev::command_complete(
                    command.opcode(),
                    &[0, 0xFD, 0x00, 0x00, 0x08, 0x00, 0x00, 0x00],
                ),
                _ => ev::command_complete(command.opcode(), &[0]),
            };
            sent = harness.raw(Event::Hci(&answer)).commands;
        }
        assert_eq!(sent, []);
        assert_eq!(harness.host.state, State::Idle);
        harness.params = params;
        harness
    }

    /// One event without answering the commands it sends.
    fn raw(&mut self, event: Event<'_>) -> Outcome {
        let effects = self
            .host
            .step(Timestamp::from_millis(self.now), event, &self.params);
        let mut outcome = Outcome::default();
        self.collect(effects, &mut outcome);
        outcome
    }

    fn collect(&mut self, effects: Effects, outcome: &mut Outcome) {
        outcome.pad.extend(effects.pad);
        for packet in effects.packets {
            match packet {
                Packet::Command(bytes) => outcome.commands.push(decode_command(&bytes)),
                Packet::Acl(bytes) => {
                    let (handle, _, frame) = acl::split(&bytes).unwrap();
                    assert_eq!(handle, HANDLE);
                    let (cid, payload) = l2cap::split_frame(frame).unwrap();
                    if cid == SIGNALLING_CID {
                        outcome
                            .signals
                            .extend(l2cap::commands(payload).map(Result::unwrap));
                    } else {
                        outcome.data.push((cid, payload.to_vec()));
                    }
                }
            }
        }
    }

    /// One event, every command answered with a successful Command Status.
    fn at(&mut self, ms: u64, event: Event<'_>) -> Outcome {
        self.now = ms;
        let mut outcome = self.raw(event);
        let mut answered = 0;
        while answered < outcome.commands.len() {
            let opcode = outcome.commands[answered].opcode();
            answered += 1;
            let effects = self.host.step(
                Timestamp::from_millis(self.now),
                Event::Hci(&ev::command_status(0, opcode)),
                &self.params,
            );
            self.collect(effects, &mut outcome);
        }
        outcome
    }

    fn hci(&mut self, ms: u64, packet: std::vec::Vec<u8>) -> Outcome {
        self.at(ms, Event::Hci(&packet))
    }

    fn signal(&mut self, ms: u64, identifier: u8, signal: Signal) -> Outcome {
        let bytes = l2cap::encode(&Signalling { identifier, signal });
        self.at(ms, Event::Acl(&ev::acl_frame(SIGNALLING_CID, &bytes)))
    }

    /// The bonded pad pages us and encrypts with its key: link up, channels closed.
    fn bonded_pad_encrypted(&mut self) {
        self.hci(0, ev::connection_request(PAD));
        self.hci(10, ev::role_change(PAD, true));
        self.hci(20, ev::connection_complete(0, PAD));
        self.hci(30, ev::link_key_request(PAD));
        self.hci(40, ev::authentication_complete(0));
        self.hci(50, ev::encryption_change(true));
    }

    /// The pad opens and configures both channels.
    fn pad_opens_channels(&mut self, ms: u64) -> Outcome {
        let mut last = Outcome::default();
        for (psm, remote, local, id) in [
            (PSM_HID_CONTROL, PAD_CONTROL, 0x0040, 1),
            (PSM_HID_INTERRUPT, PAD_INTERRUPT, 0x0041, 3),
        ] {
            let answer = self.signal(
                ms,
                id,
                Signal::ConnectionRequest {
                    psm,
                    source_cid: remote,
                },
            );
            let ours = answer.signals[1].identifier;
            self.signal(
                ms,
                id + 1,
                Signal::ConfigurationRequest {
                    destination_cid: local,
                    continuation: false,
                    options: ConfigOptions::default(),
                },
            );
            last = self.signal(
                ms,
                ours,
                Signal::ConfigurationResponse {
                    source_cid: local,
                    continuation: false,
                    result: config_result::SUCCESS,
                    options: ConfigOptions::default(),
                },
            );
        }
        last
    }

    fn connected(params: Params) -> Harness {
        let mut harness = Harness::ready(params);
        harness.bonded_pad_encrypted();
        let outcome = harness.pad_opens_channels(60);
        assert_eq!(outcome.pad, [PadEvent::Connected(PAD)]);
        harness
    }
}

fn commands(outcome: &Outcome) -> &[Command] {
    &outcome.commands
}

#[test]
fn setup_prepares_the_controller_one_command_at_a_time() {
    // `ready` checks the order; here, that nothing goes out before its predecessor
    // is answered, and that the buffer size is taken from Read Buffer Size.
    let mut host = ClassicHost::new();
    let t0 = Timestamp::BOOT;
    let first = host.step(t0, Event::Tick, &BONDED);
    assert_eq!(first.packets.len(), 1);
    assert!(host.step(t0, Event::Tick, &BONDED).packets.is_empty());
    let harness = Harness::ready(BONDED);
    assert_eq!(harness.host.acl_out.queued(), 0);
}

#[test]
fn a_failed_setup_command_starts_the_controller_again_a_second_later() {
    let mut harness = Harness {
        host: ClassicHost::new(),
        now: 0,
        params: BONDED,
    };
    harness.raw(Event::Tick);
    let failed = ev::command_complete(Command::Reset.opcode(), &[0x01]);
    assert_eq!(commands(&harness.raw(Event::Hci(&failed))), []);
    harness.now = 999;
    assert_eq!(commands(&harness.raw(Event::Tick)), []);
    harness.now = 1_000;
    assert_eq!(commands(&harness.raw(Event::Tick)), [Command::Reset]);
    assert_eq!(harness.host.counters().controller_errors, 1);
}

#[test]
fn the_bonded_pad_reconnects_with_its_key_and_its_channels() {
    let mut h = Harness::ready(BONDED);
    let table: [(u64, std::vec::Vec<u8>, &[Command]); 6] = [
        (
            0,
            ev::connection_request(PAD),
            &[Command::AcceptConnectionRequest(PAD)],
        ),
        (10, ev::role_change(PAD, true), &[]),
        (
            20,
            ev::connection_complete(0, PAD),
            &[
                Command::WriteLinkSupervisionTimeout {
                    handle: HANDLE,
                    slots: SUPERVISION_SLOTS,
                },
                Command::AuthenticationRequested(HANDLE),
            ],
        ),
        (
            30,
            ev::link_key_request(PAD),
            &[Command::LinkKeyRequestReply {
                addr: PAD,
                key: KEY,
            }],
        ),
        (
            40,
            ev::authentication_complete(0),
            &[Command::SetConnectionEncryption {
                handle: HANDLE,
                enabled: true,
            }],
        ),
        (50, ev::encryption_change(true), &[]),
    ];
    for (ms, packet, expected) in table {
        let outcome = h.hci(ms, packet.clone());
        assert_eq!(commands(&outcome), expected, "at {ms} ms: {packet:02x?}");
        assert_eq!(outcome.pad, []);
    }
    let outcome = h.pad_opens_channels(60);
    assert_eq!(outcome.pad, [PadEvent::Connected(PAD)]);
    assert_eq!(h.host.connected_pad(), Some(PAD));
    // An input report on the interrupt channel goes up as it came.
    let report = [
        0xA1, 0x01, 0x80, 0x80, 0x80, 0x80, 0x08, 0x02, 0x00, 0x00, 0x00,
    ];
    let outcome = h.at(70, Event::Acl(&ev::acl_frame(0x0041, &report)));
    assert_eq!(
        outcome.pad,
        [PadEvent::Interrupt(Payload::from_slice(&report).unwrap())]
    );
}

#[test]
fn a_channel_the_pad_opens_before_encryption_is_pending_until_then() {
    let mut h = Harness::ready(BONDED);
    h.hci(0, ev::connection_request(PAD));
    h.hci(20, ev::connection_complete(0, PAD));
    let outcome = h.signal(
        25,
        1,
        Signal::ConnectionRequest {
            psm: PSM_HID_CONTROL,
            source_cid: PAD_CONTROL,
        },
    );
    assert_eq!(
        outcome.signals[0].signal,
        Signal::ConnectionResponse {
            destination_cid: 0x0040,
            source_cid: PAD_CONTROL,
            result: connect_result::PENDING,
            status: l2cap::STATUS_AUTHENTICATION_PENDING,
        }
    );
    h.hci(30, ev::link_key_request(PAD));
    h.hci(40, ev::authentication_complete(0));
    let outcome = h.hci(50, ev::encryption_change(true));
    assert_eq!(
        outcome.signals[0].signal,
        Signal::ConnectionResponse {
            destination_cid: 0x0040,
            source_cid: PAD_CONTROL,
            result: connect_result::SUCCESS,
            status: 0,
        }
    );
    // Data on a channel that is not open yet is not handed up.
    let outcome = h.at(60, Event::Acl(&ev::acl_frame(0x0040, &[0xA3, 0x05])));
    assert_eq!(outcome.pad, []);
    assert_eq!(h.host.counters().unrouted_data, 1);
}

#[test]
fn accepted_as_peripheral_the_host_asks_for_the_central_role_and_then_supervises() {
    let mut h = Harness::ready(BONDED);
    h.hci(0, ev::connection_request(PAD));
    let outcome = h.hci(20, ev::connection_complete(0, PAD));
    assert_eq!(
        commands(&outcome),
        [
            Command::SwitchRoleToCentral(PAD),
            Command::AuthenticationRequested(HANDLE)
        ]
    );
    let outcome = h.hci(30, ev::role_change(PAD, true));
    assert_eq!(
        commands(&outcome),
        [Command::WriteLinkSupervisionTimeout {
            handle: HANDLE,
            slots: SUPERVISION_SLOTS
        }]
    );
}

#[test]
fn a_stranger_outside_the_window_is_rejected() {
    let mut h = Harness::ready(BONDED);
    let outcome = h.hci(0, ev::connection_request(STRANGER));
    assert_eq!(
        commands(&outcome),
        [Command::RejectConnectionRequest {
            addr: STRANGER,
            reason: status::REJECTED_UNACCEPTABLE_ADDRESS
        }]
    );
    assert_eq!(h.host.counters().rejected_connections, 1);
    // Without any bond, the bonded address is a stranger too.
    let mut h = Harness::ready(Params {
        bond: None,
        ..BONDED
    });
    h.params.pairing_window_open = false;
    let outcome = h.hci(0, ev::connection_request(PAD));
    assert!(matches!(
        commands(&outcome),
        [Command::RejectConnectionRequest { .. }]
    ));
}

#[test]
fn an_impostor_without_the_key_is_dropped_never_paired_and_backed_off() {
    let mut h = Harness::ready(BONDED);
    h.hci(0, ev::connection_request(PAD));
    h.hci(20, ev::connection_complete(0, PAD));
    h.hci(30, ev::link_key_request(PAD));
    // It tries to pair instead: every pairing request is refused.
    let table: [(std::vec::Vec<u8>, Command); 3] = [
        (
            ev::io_capability_request(PAD),
            Command::IoCapabilityRequestNegativeReply {
                addr: PAD,
                reason: status::PAIRING_NOT_ALLOWED,
            },
        ),
        (
            ev::user_confirmation_request(PAD),
            Command::UserConfirmationRequestNegativeReply(PAD),
        ),
        (
            ev::pin_code_request(PAD),
            Command::PinCodeRequestNegativeReply(PAD),
        ),
    ];
    for (packet, refusal) in table {
        assert_eq!(commands(&h.hci(35, packet)), [refusal]);
    }
    assert_eq!(h.host.counters().refused_pairings, 3);
    let outcome = h.hci(
        40,
        ev::authentication_complete(status::AUTHENTICATION_FAILURE),
    );
    assert_eq!(
        commands(&outcome),
        [Command::Disconnect {
            handle: HANDLE,
            reason: status::AUTHENTICATION_FAILURE
        }]
    );
    let outcome = h.hci(50, ev::disconnection_complete(status::CONNECTION_TIMEOUT));
    assert_eq!(outcome.pad, []);
    // Backing off 1 s: its pages are rejected until then, accepted after.
    let rejected = Command::RejectConnectionRequest {
        addr: PAD,
        reason: status::REJECTED_LIMITED_RESOURCES,
    };
    assert_eq!(
        commands(&h.hci(1_039, ev::connection_request(PAD))),
        [rejected]
    );
    assert_eq!(
        commands(&h.hci(1_040, ev::connection_request(PAD))),
        [Command::AcceptConnectionRequest(PAD)]
    );
    // A second failure doubles the back-off of the host's own attempts, not the
    // refusal of the bonded address's pages: 1 s again.
    h.hci(1_050, ev::connection_complete(0, PAD));
    h.hci(
        1_060,
        ev::authentication_complete(status::PIN_OR_KEY_MISSING),
    );
    h.hci(
        1_070,
        ev::disconnection_complete(status::CONNECTION_TIMEOUT),
    );
    assert_eq!(
        commands(&h.hci(2_059, ev::connection_request(PAD))),
        [rejected]
    );
    assert_eq!(h.host.retry_at.as_millis(), 3_060);
    assert_eq!(
        commands(&h.hci(2_060, ev::connection_request(PAD))),
        [Command::AcceptConnectionRequest(PAD)]
    );
    assert_eq!(h.host.counters().failed_connections, 2);
}

/// An impostor at the bonded address that fails again and again must not lock the
/// owner out: however long the back-off of the host's own attempts has grown, the
/// bonded address's pages are accepted again 1 s after the last failure.
#[test]
fn after_many_failed_pages_the_owner_is_accepted_1_s_after_the_last_failure() {
    let mut h = Harness::ready(BONDED);
    let mut at = 0;
    for _ in 0..8 {
        // Each page accepted, its authentication failed, the link gone.
        assert_eq!(
            commands(&h.hci(at, ev::connection_request(PAD))),
            [Command::AcceptConnectionRequest(PAD)]
        );
        h.hci(at + 10, ev::connection_complete(0, PAD));
        h.hci(
            at + 20,
            ev::authentication_complete(status::AUTHENTICATION_FAILURE),
        );
        h.hci(
            at + 30,
            ev::disconnection_complete(status::CONNECTION_TIMEOUT),
        );
        at += 30 + PAGE_BACK_OFF_MS;
    }
    assert_eq!(h.host.counters().failed_connections, 8);
}

#[test]
fn the_back_off_doubles_up_to_32_seconds() {
    let mut host = ClassicHost::new();
    let mut backs = std::vec::Vec::new();
    for _ in 0..8 {
        host.fail(Timestamp::BOOT);
        backs.push(host.retry_at.as_millis());
    }
    assert_eq!(
        backs,
        [1_000, 2_000, 4_000, 8_000, 16_000, 32_000, 32_000, 32_000]
    );
}

#[test]
fn inside_the_window_a_gamepad_is_found_paged_paired_and_bonded() {
    let mut h = Harness::ready(WINDOW);
    let outcome = h.at(0, Event::Tick);
    assert_eq!(
        commands(&outcome),
        [Command::Inquiry {
            lap: GIAC,
            length: INQUIRY_LENGTH,
            max_responses: 0
        }]
    );
    let table: [(u64, std::vec::Vec<u8>, &[Command]); 9] = [
        // A phone answers: ignored.
        (100, ev::inquiry_result(STRANGER, 0x5A020C), &[]),
        (
            200,
            ev::inquiry_result(PAD, 0x002508),
            &[
                Command::InquiryCancel,
                Command::CreateConnection {
                    addr: PAD,
                    page_scan_repetition_mode: 1,
                    clock_offset: 0x9234,
                    allow_role_switch: false,
                },
            ],
        ),
        (
            300,
            ev::connection_complete(0, PAD),
            &[
                Command::WriteLinkSupervisionTimeout {
                    handle: HANDLE,
                    slots: SUPERVISION_SLOTS,
                },
                Command::AuthenticationRequested(HANDLE),
            ],
        ),
        (
            310,
            ev::link_key_request(PAD),
            &[Command::LinkKeyRequestNegativeReply(PAD)],
        ),
        (
            320,
            ev::io_capability_request(PAD),
            &[Command::IoCapabilityRequestReply(PAD)],
        ),
        (
            330,
            ev::user_confirmation_request(PAD),
            &[Command::UserConfirmationRequestReply(PAD)],
        ),
        (340, ev::link_key_notification(PAD, NEW_KEY), &[]),
        // PIN pairing stays refused, also in the window.
        (
            345,
            ev::pin_code_request(PAD),
            &[Command::PinCodeRequestNegativeReply(PAD)],
        ),
        (
            350,
            ev::authentication_complete(0),
            &[Command::SetConnectionEncryption {
                handle: HANDLE,
                enabled: true,
            }],
        ),
    ];
    for (ms, packet, expected) in table {
        let outcome = h.hci(ms, packet.clone());
        assert_eq!(commands(&outcome), expected, "at {ms} ms: {packet:02x?}");
    }
    let outcome = h.hci(360, ev::encryption_change(true));
    assert_eq!(
        outcome.pad,
        [PadEvent::Bonded(Bond {
            addr: PAD,
            key: NEW_KEY
        })]
    );
    // We paged, so we open control, then interrupt.
    let psms: std::vec::Vec<_> = outcome.signals.iter().map(|c| c.signal).collect();
    assert_eq!(
        psms,
        [
            Signal::ConnectionRequest {
                psm: PSM_HID_CONTROL,
                source_cid: 0x0040
            },
            Signal::ConnectionRequest {
                psm: PSM_HID_INTERRUPT,
                source_cid: 0x0041
            },
        ]
    );
}

#[test]
fn closing_the_window_cancels_the_inquiry_and_a_page_timeout_backs_off() {
    let mut h = Harness::ready(WINDOW);
    h.at(0, Event::Tick);
    h.params.pairing_window_open = false;
    assert_eq!(commands(&h.at(100, Event::Tick)), [Command::InquiryCancel]);
    assert_eq!(commands(&h.at(200, Event::Tick)), []);

    let mut h = Harness::ready(WINDOW);
    h.at(0, Event::Tick);
    h.hci(100, ev::inquiry_result(PAD, 0x002508));
    assert_eq!(
        commands(&h.hci(5_200, ev::connection_complete(status::PAGE_TIMEOUT, PAD))),
        []
    );
    assert_eq!(commands(&h.at(6_199, Event::Tick)), []);
    assert!(matches!(
        commands(&h.at(6_200, Event::Tick)),
        [Command::Inquiry { .. }]
    ));
}

#[test]
fn an_inquiry_without_a_gamepad_starts_the_next_one() {
    let mut h = Harness::ready(WINDOW);
    h.at(0, Event::Tick);
    assert!(matches!(
        commands(&h.hci(5_120, ev::inquiry_complete())),
        [Command::Inquiry { .. }]
    ));
}

#[test]
fn the_bonded_pad_may_come_back_while_the_window_is_open() {
    let mut h = Harness::ready(Params {
        pairing_window_open: true,
        ..BONDED
    });
    h.at(0, Event::Tick);
    assert_eq!(
        commands(&h.hci(100, ev::connection_request(PAD))),
        [
            Command::InquiryCancel,
            Command::AcceptConnectionRequest(PAD)
        ]
    );
    // Not pairing: the stored key is used.
    h.hci(200, ev::connection_complete(0, PAD));
    assert_eq!(
        commands(&h.hci(210, ev::link_key_request(PAD))),
        [Command::LinkKeyRequestReply {
            addr: PAD,
            key: KEY
        }]
    );
}

#[test]
fn a_lost_link_and_a_switch_off_are_reported() {
    let mut h = Harness::connected(BONDED);
    let outcome = h.hci(
        1_000,
        ev::disconnection_complete(status::CONNECTION_TIMEOUT),
    );
    assert_eq!(outcome.pad, [PadEvent::Disconnected(PAD)]);
    assert_eq!(h.host.connected_pad(), None);
    // A connection that served the pad leaves no back-off behind.
    assert_eq!(
        commands(&h.hci(1_001, ev::connection_request(PAD))),
        [Command::AcceptConnectionRequest(PAD)]
    );

    let mut h = Harness::connected(BONDED);
    assert_eq!(
        commands(&h.at(1_000, Event::Disconnect)),
        [Command::Disconnect {
            handle: HANDLE,
            reason: status::REMOTE_USER_TERMINATED
        }]
    );
    let outcome = h.hci(
        1_050,
        ev::disconnection_complete(status::REMOTE_USER_TERMINATED),
    );
    assert_eq!(outcome.pad, [PadEvent::Disconnected(PAD)]);
}

#[test]
fn the_pad_closing_its_interrupt_channel_drops_the_link() {
    let mut h = Harness::connected(BONDED);
    let outcome = h.signal(
        1_000,
        9,
        Signal::DisconnectionRequest {
            destination_cid: 0x0041,
            source_cid: PAD_INTERRUPT,
        },
    );
    assert_eq!(
        commands(&outcome),
        [Command::Disconnect {
            handle: HANDLE,
            reason: status::REMOTE_USER_TERMINATED
        }]
    );
}

#[test]
fn deadlines_end_a_stalled_connection() {
    // Authentication never completes.
    let mut h = Harness::ready(BONDED);
    h.hci(0, ev::connection_request(PAD));
    h.hci(20, ev::connection_complete(0, PAD));
    assert_eq!(commands(&h.at(10_019, Event::Tick)), []);
    assert_eq!(
        commands(&h.at(10_020, Event::Tick)),
        [Command::Disconnect {
            handle: HANDLE,
            reason: status::AUTHENTICATION_FAILURE
        }]
    );
    // The controller never confirms the disconnection: the link counts as gone.
    assert_eq!(
        h.host.state,
        State::Disconnecting {
            handle: HANDLE,
            addr: PAD,
            connected: false,
            since: Timestamp::from_millis(10_020),
        }
    );
    h.at(13_020, Event::Tick);
    assert_eq!(h.host.state, State::Idle);

    // Encrypted, but the channels never open.
    let mut h = Harness::ready(BONDED);
    h.bonded_pad_encrypted();
    assert_eq!(commands(&h.at(5_049, Event::Tick)), []);
    assert!(matches!(
        commands(&h.at(5_050, Event::Tick)),
        [Command::Disconnect { .. }]
    ));
}

#[test]
fn outputs_go_out_on_the_interrupt_channel_only_when_connected() {
    let mut h = Harness::ready(BONDED);
    let report = [0xA2u8, 0x11, 0xC4];
    assert_eq!(h.at(0, Event::SendInterrupt(&report)).data, []);
    assert_eq!(h.host.counters().dropped_sends, 1);

    let mut h = Harness::connected(BONDED);
    let outcome = h.at(1_000, Event::SendInterrupt(&report));
    assert_eq!(outcome.data, [(PAD_INTERRUPT, report.to_vec())]);
    let get_feature = [0x43u8, 0x05];
    let outcome = h.at(1_000, Event::SendControl(&get_feature));
    assert_eq!(outcome.data, [(PAD_CONTROL, get_feature.to_vec())]);
}

#[test]
fn acl_packets_wait_for_the_controllers_buffers() {
    let mut h = Harness::connected(BONDED);
    // The controller reported 8 buffers; the signalling used some, all completed now.
    h.hci(900, ev::completed_packets(8));
    let report = [0xA2u8; 79];
    let mut sent = 0;
    for _ in 0..12 {
        sent += h.at(1_000, Event::SendInterrupt(&report)).data.len();
    }
    assert_eq!(sent, 8);
    assert_eq!(h.hci(1_010, ev::completed_packets(2)).data.len(), 2);
    // Completions for another handle (a BLE link, say) free none of ours.
    let mut other = ev::completed_packets(2);
    other[3] = 0x43;
    assert_eq!(h.hci(1_020, other).data.len(), 0);
}

#[test]
fn malformed_input_is_refused_and_counted() {
    let mut h = Harness::connected(BONDED);
    let mut lying = ev::encryption_change(true);
    lying[1] = 3;
    h.at(1_000, Event::Hci(&lying));
    h.at(1_000, Event::Hci(&[0x17]));
    h.at(1_000, Event::Acl(&[0x42, 0x20, 0x09, 0x00, 0x01]));
    // A signalling frame with a truncated command, and one with an unknown code.
    h.at(
        1_000,
        Event::Acl(&ev::acl_frame(SIGNALLING_CID, &[0x02, 0x07, 0x04])),
    );
    let outcome = h.at(
        1_000,
        Event::Acl(&ev::acl_frame(SIGNALLING_CID, &[0x55, 0x07, 0x00, 0x00])),
    );
    assert_eq!(
        outcome.signals[0].signal,
        Signal::CommandReject {
            reason: l2cap::reject_reason::NOT_UNDERSTOOD
        }
    );
    // Data for a channel that does not exist, and for another handle.
    h.at(1_000, Event::Acl(&ev::acl_frame(0x0099, &[0xA1])));
    h.at(
        1_000,
        Event::Acl(&[0x43, 0x20, 0x04, 0x00, 0x00, 0x00, 0x41, 0x00]),
    );
    let counters = h.host.counters();
    assert_eq!(
        (
            counters.malformed_events,
            counters.malformed_acl,
            counters.malformed_signals,
            counters.unrouted_data
        ),
        (2, 1, 2, 2)
    );
    // None of it disturbed the connection.
    assert_eq!(h.host.connected_pad(), Some(PAD));
}

#[test]
fn a_hardware_error_restarts_the_controller_and_reports_the_pad_gone() {
    let mut h = Harness::connected(BONDED);
    let outcome = h.hci(1_000, ev::hardware_error());
    assert_eq!(outcome.pad, [PadEvent::Disconnected(PAD)]);
    assert_eq!(commands(&outcome), [Command::Reset]);
}

#[test]
fn buffers_from_read_buffer_size_set_the_fragment_length() {
    let mut sender = AclSender::new();
    sender.set_buffers(AclBuffers {
        packet_len: 253,
        packets: 8,
    });
    let mut h = Harness::connected(BONDED);
    h.host.acl_out = sender;
    let outcome = h.at(1_000, Event::SendInterrupt(&[0xA2; 79]));
    assert_eq!(outcome.data.len(), 1);
}

#[test]
fn a_shared_controller_is_set_up_only_after_the_other_hosts_reset_and_never_reset_here() {
    let mut harness = Harness {
        host: ClassicHost::new_shared(),
        now: 0,
        params: BONDED,
    };
    // No setup before the other host reset the controller; a page meanwhile is refused.
    assert_eq!(commands(&harness.raw(Event::Tick)), []);
    assert_eq!(
        commands(&harness.hci(5_000, ev::connection_request(PAD))),
        [Command::RejectConnectionRequest {
            addr: PAD,
            reason: status::REJECTED_LIMITED_RESOURCES,
        }]
    );
    // Then the setup, without Reset and Set Event Mask, one command per answer.
    let mut sent = commands(&harness.raw(Event::ControllerReset)).to_vec();
    let mut order = std::vec::Vec::new();
    while let [command] = sent[..] {
        order.push(command);
        let answer = match command {
            Command::ReadBufferSize => ev::command_complete(
                command.opcode(),
                &[0x00, 0xFD, 0x03, 0x00, 0x08, 0x00, 0x00, 0x00],
            ),
            _ => ev::command_complete(command.opcode(), &[0x00]),
        };
        sent = commands(&harness.raw(Event::Hci(&answer))).to_vec();
    }
    assert_eq!(order, SHARED_SETUP);
    assert_eq!(harness.host.state, State::Idle);
    // A connected pad is reported gone when the other host resets the controller again.
    let mut harness = Harness::connected(BONDED);
    harness.host.shared = true;
    let outcome = harness.raw(Event::ControllerReset);
    assert_eq!(outcome.pad, [PadEvent::Disconnected(PAD)]);
    assert_eq!(commands(&outcome), [Command::ReadBufferSize]);
}
