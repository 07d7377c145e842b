use super::*;
use crate::l2cap::reject_reason;

const PAD_CONTROL: u16 = 0x0070;
const PAD_INTERRUPT: u16 = 0x0071;
const CONTROL: u16 = FIRST_DYNAMIC_CID;
const INTERRUPT: u16 = FIRST_DYNAMIC_CID + 1;

fn cmd(identifier: u8, signal: Signal) -> Result<Command, SignalError> {
    Ok(Command { identifier, signal })
}

fn step(
    channels: &mut HidChannels,
    command: Result<Command, SignalError>,
    encrypted: bool,
) -> (Result<(), ChannelFailure>, std::vec::Vec<Command>) {
    let mut out = Signals::new();
    let result = channels.signal(command, encrypted, &mut out);
    (result, out.to_vec())
}

fn connect(psm: u16, source_cid: u16) -> Signal {
    Signal::ConnectionRequest { psm, source_cid }
}

fn response(destination_cid: u16, source_cid: u16, result: u16, status: u16) -> Signal {
    Signal::ConnectionResponse {
        destination_cid,
        source_cid,
        result,
        status,
    }
}

fn our_config(identifier: u8, remote_cid: u16) -> Command {
    Command {
        identifier,
        signal: Signal::ConfigurationRequest {
            destination_cid: remote_cid,
            continuation: false,
            options: ConfigOptions {
                mtu: Some(crate::RECEIVE_MTU),
                ..ConfigOptions::default()
            },
        },
    }
}

fn their_config(local_cid: u16, mtu: Option<u16>) -> Signal {
    Signal::ConfigurationRequest {
        destination_cid: local_cid,
        continuation: false,
        options: ConfigOptions {
            mtu,
            ..ConfigOptions::default()
        },
    }
}

fn config_ok(source_cid: u16) -> Signal {
    Signal::ConfigurationResponse {
        source_cid,
        continuation: false,
        result: config_result::SUCCESS,
        options: ConfigOptions::default(),
    }
}

/// The pad opens both channels on an encrypted link, configures them, and accepts ours.
fn opened_by_the_pad() -> HidChannels {
    let mut channels = HidChannels::new();
    for (local, remote, psm, id) in [
        (CONTROL, PAD_CONTROL, PSM_HID_CONTROL, 1),
        (INTERRUPT, PAD_INTERRUPT, PSM_HID_INTERRUPT, 3),
    ] {
        let (result, out) = step(&mut channels, cmd(id, connect(psm, remote)), true);
        assert_eq!(result, Ok(()));
        assert_eq!(out[0].signal, response(local, remote, 0, 0));
        let ours = out[1].identifier;
        let (result, _) = step(
            &mut channels,
            cmd(id + 1, their_config(local, Some(672))),
            true,
        );
        assert_eq!(result, Ok(()));
        let (result, _) = step(
            &mut channels,
            cmd(
                ours,
                Signal::ConfigurationResponse {
                    source_cid: local,
                    continuation: false,
                    result: config_result::SUCCESS,
                    options: ConfigOptions::default(),
                },
            ),
            true,
        );
        assert_eq!(result, Ok(()));
    }
    channels
}

#[test]
fn the_pad_opens_both_channels_and_they_are_routed() {
    let channels = opened_by_the_pad();
    assert!(channels.open());
    assert_eq!(
        channels.remote(HidChannel::Control),
        Some((PAD_CONTROL, 672))
    );
    assert_eq!(channels.route(INTERRUPT), Some(HidChannel::Interrupt));
    assert_eq!(channels.route(0x0050), None);
}

#[test]
fn a_connect_before_encryption_is_pending_and_accepted_once_encrypted() {
    let mut channels = HidChannels::new();
    let (result, out) = step(
        &mut channels,
        cmd(1, connect(PSM_HID_CONTROL, PAD_CONTROL)),
        false,
    );
    assert_eq!(result, Ok(()));
    assert_eq!(
        out,
        [Command {
            identifier: 1,
            signal: response(
                CONTROL,
                PAD_CONTROL,
                connect_result::PENDING,
                STATUS_AUTHENTICATION_PENDING
            ),
        }]
    );
    let mut out = Signals::new();
    channels.encrypted(false, &mut out);
    // Success under the pad's identifier, then our configuration request; the
    // interrupt channel is left to the pad, which made the connection.
    assert_eq!(
        out.to_vec(),
        [
            Command {
                identifier: 1,
                signal: response(CONTROL, PAD_CONTROL, connect_result::SUCCESS, 0),
            },
            our_config(1, PAD_CONTROL),
        ]
    );
}

#[test]
fn after_our_page_we_open_control_then_interrupt() {
    let mut channels = HidChannels::new();
    let mut out = Signals::new();
    channels.encrypted(true, &mut out);
    assert_eq!(
        out.to_vec(),
        [
            Command {
                identifier: 1,
                signal: connect(PSM_HID_CONTROL, CONTROL),
            },
            Command {
                identifier: 2,
                signal: connect(PSM_HID_INTERRUPT, INTERRUPT),
            },
        ]
    );
    // Pending first, then success: our configuration request follows.
    let pending = response(PAD_CONTROL, CONTROL, connect_result::PENDING, 1);
    assert_eq!(step(&mut channels, cmd(1, pending), true), (Ok(()), vec![]));
    let success = response(PAD_CONTROL, CONTROL, connect_result::SUCCESS, 0);
    let (result, out) = step(&mut channels, cmd(1, success), true);
    assert_eq!((result, out), (Ok(()), vec![our_config(3, PAD_CONTROL)]));
    // A refusal of the interrupt channel ends the connection.
    let refused = response(0, INTERRUPT, connect_result::SECURITY_BLOCK, 0);
    assert_eq!(
        step(&mut channels, cmd(2, refused), true).0,
        Err(ChannelFailure::Refused {
            channel: HidChannel::Interrupt,
            result: connect_result::SECURITY_BLOCK
        })
    );
}

#[test]
fn answers_to_requests_we_did_not_make_change_nothing() {
    let mut channels = HidChannels::new();
    let stray = response(PAD_CONTROL, CONTROL, connect_result::SUCCESS, 0);
    assert_eq!(step(&mut channels, cmd(9, stray), true), (Ok(()), vec![]));
    assert_eq!(
        step(&mut channels, cmd(9, config_ok(CONTROL)), true),
        (Ok(()), vec![])
    );
    assert_eq!(channels, HidChannels::new());
}

#[test]
fn connection_requests_table() {
    let table: [(Signal, u16); 3] = [
        // SDP (PSM 1) and RFCOMM (PSM 3) are not served.
        (connect(0x0001, 0x0050), connect_result::PSM_NOT_SUPPORTED),
        (connect(0x0003, 0x0050), connect_result::PSM_NOT_SUPPORTED),
        // A source CID in the reserved range.
        (
            connect(PSM_HID_CONTROL, 0x0001),
            connect_result::NO_RESOURCES,
        ),
    ];
    for (signal, result) in table {
        let mut channels = HidChannels::new();
        let Signal::ConnectionRequest { source_cid, .. } = signal else {
            unreachable!()
        };
        let (outcome, out) = step(&mut channels, cmd(4, signal), true);
        assert_eq!(outcome, Ok(()));
        assert_eq!(
            out[0].signal,
            response(0, source_cid, result, 0),
            "{signal:?}"
        );
    }
    // A second request for an open channel.
    let mut channels = opened_by_the_pad();
    let (_, out) = step(
        &mut channels,
        cmd(8, connect(PSM_HID_CONTROL, 0x0090)),
        true,
    );
    assert_eq!(
        out[0].signal,
        response(0, 0x0090, connect_result::NO_RESOURCES, 0)
    );
}

#[test]
fn configuration_requests_table() {
    let options = |mtu, mode, unknown| ConfigOptions {
        mtu,
        flush_timeout: None,
        mode,
        unknown,
    };
    let table: [(ConfigOptions, u16, ConfigOptions); 5] = [
        (
            options(None, None, None),
            config_result::SUCCESS,
            options(None, None, None),
        ),
        (
            options(Some(48), Some(0), None),
            config_result::SUCCESS,
            options(None, None, None),
        ),
        (
            options(Some(47), None, None),
            config_result::UNACCEPTABLE_PARAMETERS,
            options(Some(48), None, None),
        ),
        (
            options(None, Some(3), None),
            config_result::REJECTED,
            options(None, None, None),
        ),
        (
            options(None, None, Some(0x07)),
            config_result::UNKNOWN_OPTIONS,
            options(None, None, Some(0x07)),
        ),
    ];
    for (request, result, answer) in table {
        let mut channels = HidChannels::new();
        let (connected, _) = step(
            &mut channels,
            cmd(1, connect(PSM_HID_CONTROL, PAD_CONTROL)),
            true,
        );
        assert_eq!(connected, Ok(()));
        let signal = Signal::ConfigurationRequest {
            destination_cid: CONTROL,
            continuation: false,
            options: request,
        };
        let (outcome, out) = step(&mut channels, cmd(2, signal), true);
        assert_eq!(outcome, Ok(()));
        assert_eq!(
            out,
            [Command {
                identifier: 2,
                signal: Signal::ConfigurationResponse {
                    source_cid: PAD_CONTROL,
                    continuation: false,
                    result,
                    options: answer,
                },
            }],
            "{request:?}"
        );
    }
    // For a channel that is not being configured: invalid CID.
    let mut channels = HidChannels::new();
    let (_, out) = step(&mut channels, cmd(2, their_config(CONTROL, None)), true);
    assert_eq!(
        out[0].signal,
        Signal::CommandReject {
            reason: reject_reason::INVALID_CID
        }
    );
}

#[test]
fn the_pad_closing_a_channel_ends_the_connection() {
    let mut channels = opened_by_the_pad();
    let close = Signal::DisconnectionRequest {
        destination_cid: INTERRUPT,
        source_cid: PAD_INTERRUPT,
    };
    let (result, out) = step(&mut channels, cmd(5, close), true);
    assert_eq!(result, Err(ChannelFailure::Closed(HidChannel::Interrupt)));
    assert_eq!(
        out[0].signal,
        Signal::DisconnectionResponse {
            destination_cid: INTERRUPT,
            source_cid: PAD_INTERRUPT
        }
    );
    assert!(!channels.open());
}

#[test]
fn echo_information_unknown_and_malformed_commands_are_answered() {
    let mut channels = opened_by_the_pad();
    let table: [(Result<Command, SignalError>, std::vec::Vec<Command>); 5] = [
        (
            cmd(3, Signal::EchoRequest),
            vec![Command {
                identifier: 3,
                signal: Signal::EchoResponse,
            }],
        ),
        (
            cmd(
                4,
                Signal::InformationRequest {
                    info_type: info::EXTENDED_FEATURES,
                },
            ),
            vec![Command {
                identifier: 4,
                signal: Signal::InformationResponse {
                    info_type: info::EXTENDED_FEATURES,
                    result: info::SUCCESS,
                    features: Some(0),
                },
            }],
        ),
        (
            cmd(5, Signal::InformationRequest { info_type: 0x0003 }),
            vec![Command {
                identifier: 5,
                signal: Signal::InformationResponse {
                    info_type: 0x0003,
                    result: info::NOT_SUPPORTED,
                    features: None,
                },
            }],
        ),
        (
            Err(SignalError::UnknownCode {
                code: 0x20,
                identifier: 6,
            }),
            vec![Command {
                identifier: 6,
                signal: Signal::CommandReject {
                    reason: reject_reason::NOT_UNDERSTOOD,
                },
            }],
        ),
        (Err(SignalError::Truncated), vec![]),
    ];
    for (command, expected) in table {
        assert_eq!(step(&mut channels, command, true), (Ok(()), expected));
    }
    assert!(channels.open());
}

#[test]
fn a_rejected_request_of_ours_ends_the_connection_a_stray_reject_does_not() {
    let mut channels = HidChannels::new();
    let mut out = Signals::new();
    channels.encrypted(true, &mut out);
    let reject = Signal::CommandReject { reason: 0 };
    assert_eq!(step(&mut channels, cmd(9, reject), true).0, Ok(()));
    assert_eq!(
        step(&mut channels, cmd(1, reject), true).0,
        Err(ChannelFailure::CommandRejected { reason: 0 })
    );
}
