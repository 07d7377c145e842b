use super::*;

fn decode_one(bytes: &[u8]) -> Result<Command, SignalError> {
    let mut all = commands(bytes);
    let first = all.next().expect("one command");
    assert!(all.next().is_none(), "one command only");
    first
}

#[test]
fn signalling_commands_decode_from_the_specifications_bytes() {
    let table: [(&[u8], Signal); 8] = [
        (
            &[0x02, 0x01, 0x04, 0x00, 0x11, 0x00, 0x40, 0x00],
            Signal::ConnectionRequest {
                psm: PSM_HID_CONTROL,
                source_cid: 0x0040,
            },
        ),
        (
            &[
                0x03, 0x01, 0x08, 0x00, 0x41, 0x00, 0x40, 0x00, 0x01, 0x00, 0x01, 0x00,
            ],
            Signal::ConnectionResponse {
                destination_cid: 0x0041,
                source_cid: 0x0040,
                result: connect_result::PENDING,
                status: STATUS_AUTHENTICATION_PENDING,
            },
        ),
        // MTU 672 and a hinted (0x80) unknown option, which is ignored.
        (
            &[
                0x04, 0x01, 0x0B, 0x00, 0x40, 0x00, 0x00, 0x00, 0x01, 0x02, 0xA0, 0x02, 0x85, 0x01,
                0x00,
            ],
            Signal::ConfigurationRequest {
                destination_cid: 0x0040,
                continuation: false,
                options: ConfigOptions {
                    mtu: Some(672),
                    ..ConfigOptions::default()
                },
            },
        ),
        (
            &[0x05, 0x01, 0x06, 0x00, 0x40, 0x00, 0x00, 0x00, 0x00, 0x00],
            Signal::ConfigurationResponse {
                source_cid: 0x0040,
                continuation: false,
                result: config_result::SUCCESS,
                options: ConfigOptions::default(),
            },
        ),
        (
            &[0x06, 0x02, 0x04, 0x00, 0x40, 0x00, 0x41, 0x00],
            Signal::DisconnectionRequest {
                destination_cid: 0x0040,
                source_cid: 0x0041,
            },
        ),
        (&[0x08, 0x03, 0x02, 0x00, 0xAB, 0xCD], Signal::EchoRequest),
        (
            &[0x0A, 0x04, 0x02, 0x00, 0x02, 0x00],
            Signal::InformationRequest {
                info_type: info::EXTENDED_FEATURES,
            },
        ),
        (
            &[
                0x0B, 0x04, 0x08, 0x00, 0x02, 0x00, 0x00, 0x00, 0x80, 0x02, 0x00, 0x00,
            ],
            Signal::InformationResponse {
                info_type: info::EXTENDED_FEATURES,
                result: info::SUCCESS,
                features: Some(0x0280),
            },
        ),
    ];
    for (bytes, signal) in table {
        let command = decode_one(bytes).unwrap();
        assert_eq!(command.signal, signal, "{bytes:02x?}");
        assert_eq!(command.identifier, bytes[1]);
    }
}

#[test]
fn what_the_host_sends_decodes_back_to_itself() {
    let signals = [
        Signal::ConnectionRequest {
            psm: PSM_HID_INTERRUPT,
            source_cid: 0x0041,
        },
        Signal::ConnectionResponse {
            destination_cid: 0x0040,
            source_cid: 0x0072,
            result: connect_result::SUCCESS,
            status: 0,
        },
        Signal::ConfigurationRequest {
            destination_cid: 0x0072,
            continuation: false,
            options: ConfigOptions {
                mtu: Some(256),
                ..ConfigOptions::default()
            },
        },
        Signal::ConfigurationResponse {
            source_cid: 0x0072,
            continuation: false,
            result: config_result::UNKNOWN_OPTIONS,
            options: ConfigOptions {
                unknown: Some(0x07),
                ..ConfigOptions::default()
            },
        },
        Signal::DisconnectionResponse {
            destination_cid: 0x0040,
            source_cid: 0x0072,
        },
        Signal::EchoResponse,
        Signal::InformationResponse {
            info_type: 0x0003,
            result: info::NOT_SUPPORTED,
            features: None,
        },
        Signal::CommandReject {
            reason: reject_reason::NOT_UNDERSTOOD,
        },
    ];
    for signal in signals {
        let command = Command {
            identifier: 7,
            signal,
        };
        assert_eq!(decode_one(&encode(&command)), Ok(command));
    }
}

#[test]
fn one_frame_carries_several_commands() {
    let frame = [
        0x08, 0x01, 0x00, 0x00, // echo request
        0x0A, 0x02, 0x02, 0x00, 0x02, 0x00, // information request
    ];
    let decoded: std::vec::Vec<_> = commands(&frame).collect();
    assert_eq!(
        decoded,
        [
            Ok(Command {
                identifier: 1,
                signal: Signal::EchoRequest
            }),
            Ok(Command {
                identifier: 2,
                signal: Signal::InformationRequest {
                    info_type: info::EXTENDED_FEATURES
                }
            }),
        ]
    );
}

#[test]
fn malformed_commands_are_refused_with_what_is_known_of_them() {
    let table: [(&[u8], SignalError); 8] = [
        (&[0x02, 0x01, 0x04], SignalError::Truncated),
        // Length says 4, three bytes follow.
        (
            &[0x02, 0x01, 0x04, 0x00, 0x11, 0x00, 0x40],
            SignalError::Truncated,
        ),
        // A connection request one byte short of its fields.
        (
            &[0x02, 0x05, 0x03, 0x00, 0x11, 0x00, 0x40],
            SignalError::BadLength {
                code: 0x02,
                identifier: 5,
            },
        ),
        // An MTU option of length 1.
        (
            &[
                0x04, 0x06, 0x07, 0x00, 0x40, 0x00, 0x00, 0x00, 0x01, 0x01, 0x30,
            ],
            SignalError::BadLength {
                code: 0x04,
                identifier: 6,
            },
        ),
        // An option overrunning the command.
        (
            &[
                0x04, 0x06, 0x07, 0x00, 0x40, 0x00, 0x00, 0x00, 0x01, 0x04, 0x30,
            ],
            SignalError::BadLength {
                code: 0x04,
                identifier: 6,
            },
        ),
        // Extended features answered with success but no mask.
        (
            &[0x0B, 0x02, 0x04, 0x00, 0x02, 0x00, 0x00, 0x00],
            SignalError::BadLength {
                code: 0x0B,
                identifier: 2,
            },
        ),
        (
            &[0x12, 0x09, 0x00, 0x00],
            SignalError::UnknownCode {
                code: 0x12,
                identifier: 9,
            },
        ),
        (&[0x08, 0x00, 0x00, 0x00], SignalError::ZeroIdentifier),
    ];
    for (bytes, error) in table {
        assert_eq!(decode_one(bytes), Err(error), "{bytes:02x?}");
    }
}

#[test]
fn after_a_malformed_command_the_rest_of_the_frame_is_skipped() {
    let frame = [0x02, 0x01, 0x09, 0x00, 0x08, 0x02, 0x00, 0x00];
    let decoded: std::vec::Vec<_> = commands(&frame).collect();
    assert_eq!(decoded, [Err(SignalError::Truncated)]);
}

#[test]
fn unknown_and_mode_options_are_noted() {
    // Retransmission mode 3 (ERTM) and an unknown non-hint option 0x07.
    let bytes = [
        0x04, 0x01, 0x11, 0x00, 0x40, 0x00, 0x00, 0x00, 0x04, 0x09, 0x03, 0, 0, 0, 0, 0, 0, 0, 0,
        0x07, 0x00,
    ];
    let Ok(Command {
        signal: Signal::ConfigurationRequest { options, .. },
        ..
    }) = decode_one(&bytes)
    else {
        panic!("not decoded");
    };
    assert_eq!(options.mode, Some(3));
    assert_eq!(options.unknown, Some(0x07));
}

#[test]
fn frames_split_into_channel_and_payload_when_their_length_matches() {
    assert_eq!(
        split_frame(&[0x02, 0x00, 0x41, 0x00, 0xA1, 0x11]),
        Some((0x0041, &[0xA1, 0x11][..]))
    );
    assert_eq!(split_frame(&[0x03, 0x00, 0x41, 0x00, 0xA1, 0x11]), None);
    assert_eq!(split_frame(&[0x00, 0x00, 0x41]), None);
    assert_eq!(frame_header(79, 0x0072), [79, 0, 0x72, 0]);
}
