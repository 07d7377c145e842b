use super::*;
use crate::test_events::{self as ev, HANDLE, KEY, PAD};

fn bytes(hex: &str) -> std::vec::Vec<u8> {
    hex.split_whitespace()
        .map(|pair| u8::from_str_radix(pair, 16).unwrap())
        .collect()
}

#[test]
fn commands_encode_to_the_specifications_bytes() {
    // Addresses go least significant byte first: C0:11:22:33:44:55 is 55 44 33 22 11 C0.
    let pad = "55 44 33 22 11 C0";
    let key = "5A 5A 5A 5A 5A 5A 5A 5A 5A 5A 5A 5A 5A 5A 5A 5A";
    let table: [(Command, String); 16] = [
        (Command::Reset, "03 0C 00".into()),
        (Command::ReadBufferSize, "05 10 00".into()),
        (
            Command::SetEventMask(EVENT_MASK),
            "01 0C 08 FF FF FF FF FF 1F FF 00".into(),
        ),
        (
            Command::WriteSimplePairingMode { enabled: true },
            "56 0C 01 01".into(),
        ),
        (
            Command::WriteClassOfDevice(ClassOfDevice(0x000100)),
            "24 0C 03 00 01 00".into(),
        ),
        (
            Command::WriteScanEnable(ScanEnable::PageScan),
            "1A 0C 01 02".into(),
        ),
        (
            Command::Inquiry {
                lap: GIAC,
                length: 4,
                max_responses: 0,
            },
            "01 04 05 33 8B 9E 04 00".into(),
        ),
        (
            Command::CreateConnection {
                addr: PAD,
                page_scan_repetition_mode: 1,
                clock_offset: 0x9234,
                allow_role_switch: false,
            },
            format!("05 04 0D {pad} 18 CC 01 00 34 92 00"),
        ),
        (
            Command::AcceptConnectionRequest(PAD),
            format!("09 04 07 {pad} 00"),
        ),
        (
            Command::RejectConnectionRequest {
                addr: PAD,
                reason: status::REJECTED_UNACCEPTABLE_ADDRESS,
            },
            format!("0A 04 07 {pad} 0F"),
        ),
        (
            Command::LinkKeyRequestReply {
                addr: PAD,
                key: KEY,
            },
            format!("0B 04 16 {pad} {key}"),
        ),
        (
            Command::PinCodeRequestNegativeReply(PAD),
            format!("0E 04 06 {pad}"),
        ),
        (
            Command::SetConnectionEncryption {
                handle: HANDLE,
                enabled: true,
            },
            "13 04 03 42 00 01".into(),
        ),
        (
            Command::IoCapabilityRequestReply(PAD),
            format!("2B 04 09 {pad} 03 00 04"),
        ),
        (
            Command::IoCapabilityRequestNegativeReply {
                addr: PAD,
                reason: status::PAIRING_NOT_ALLOWED,
            },
            format!("34 04 07 {pad} 18"),
        ),
        (
            Command::WriteLinkSupervisionTimeout {
                handle: HANDLE,
                slots: 320,
            },
            "37 0C 04 42 00 40 01".into(),
        ),
    ];
    for (command, expected) in table {
        assert_eq!(command.encode().to_vec(), bytes(&expected), "{command:?}");
    }
}

#[test]
fn events_decode_to_their_values() {
    let table: [(std::vec::Vec<u8>, Event); 8] = [
        (
            ev::connection_request(PAD),
            Event::ConnectionRequest {
                addr: PAD,
                class: ClassOfDevice(0x002508),
                link_type: 1,
            },
        ),
        (
            ev::connection_complete(0, PAD),
            Event::ConnectionComplete {
                status: 0,
                handle: HANDLE,
                addr: PAD,
                encrypted: false,
            },
        ),
        (ev::link_key_request(PAD), Event::LinkKeyRequest(PAD)),
        (
            ev::link_key_notification(PAD, KEY),
            Event::LinkKeyNotification {
                addr: PAD,
                key: KEY,
                key_type: 4,
            },
        ),
        (
            ev::encryption_change(true),
            Event::EncryptionChange {
                status: 0,
                handle: HANDLE,
                enabled: true,
            },
        ),
        (
            ev::role_change(PAD, true),
            Event::RoleChange {
                status: 0,
                addr: PAD,
                central: true,
            },
        ),
        (
            ev::command_complete(0x1005, &[0, 0xFD, 0x00, 0x40, 0x05, 0x00, 0x00, 0x00]),
            Event::CommandComplete {
                credits: 1,
                opcode: 0x1005,
                status: 0,
                acl_buffers: Some(AclBuffers {
                    packet_len: 253,
                    packets: 5,
                }),
            },
        ),
        (
            ev::completed_packets(3),
            Event::NumberOfCompletedPackets(Vec::from_slice(&[(HANDLE, 3)]).unwrap()),
        ),
    ];
    for (packet, event) in table {
        assert_eq!(Event::decode(&packet), Ok(event), "{packet:02x?}");
    }
    let Ok(Event::InquiryResult(found)) = Event::decode(&ev::inquiry_result(PAD, 0x002508)) else {
        panic!("inquiry result not decoded");
    };
    assert_eq!(
        found.as_slice(),
        &[InquiryResponse {
            addr: PAD,
            page_scan_repetition_mode: 1,
            class: ClassOfDevice(0x002508),
            clock_offset: 0x1234,
        }]
    );
}

#[test]
fn malformed_events_are_refused_and_unknown_ones_are_other() {
    let mut trailing = ev::link_key_request(PAD);
    trailing.push(0);
    trailing[1] += 1;
    let mut short = ev::connection_complete(0, PAD);
    short.truncate(short.len() - 1);
    short[1] -= 1;
    let mut lying = ev::encryption_change(true);
    lying[1] = 9;
    // An inquiry result that claims two responses but carries one.
    let mut two = ev::inquiry_result(PAD, 0x002508);
    two[2] = 2;
    let table: [(&[u8], Result<Event, HciError>); 7] = [
        (&[], Err(HciError::Truncated)),
        (&[0x05], Err(HciError::Truncated)),
        (&lying, Err(HciError::Truncated)),
        (
            &trailing,
            Err(HciError::BadLength {
                code: 0x17,
                length: 7,
            }),
        ),
        (
            &short,
            Err(HciError::BadLength {
                code: 0x03,
                length: 10,
            }),
        ),
        (
            &two,
            Err(HciError::BadLength {
                code: 0x02,
                length: 15,
            }),
        ),
        (&[0x3E, 0x01, 0x02], Ok(Event::Other { code: 0x3E })),
    ];
    for (packet, expected) in table {
        assert_eq!(Event::decode(packet), expected, "{packet:02x?}");
    }
}

#[test]
fn the_pads_class_of_device_is_a_gamepad_and_others_are_not() {
    let table = [
        // DualShock 4 / DualSense in pairing mode (limited discoverable), and without.
        (0x002508, true),
        (0x000508, true),
        // A joystick, a keyboard, a phone.
        (0x000504, false),
        (0x000540, false),
        (0x5A020C, false),
    ];
    for (class, gamepad) in table {
        assert_eq!(ClassOfDevice(class).is_gamepad(), gamepad, "{class:#08x}");
    }
}
