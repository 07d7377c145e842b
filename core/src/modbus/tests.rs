use super::*;
use proptest::prelude::*;

/// Spaces and line breaks in the hex are for reading only.
fn hex(text: &str) -> std::vec::Vec<u8> {
    let digits: std::vec::Vec<u8> = text
        .bytes()
        .filter(|byte| !byte.is_ascii_whitespace())
        .collect();
    digits
        .chunks(2)
        .map(|pair| u8::from_str_radix(std::str::from_utf8(pair).unwrap(), 16).unwrap())
        .collect()
}

#[track_caller]
fn assert_golden(frame: &Frame, expected: &str) {
    assert_eq!(frame[..], hex(expected)[..]);
}

fn with_crc(mut body: std::vec::Vec<u8>) -> std::vec::Vec<u8> {
    let crc = crc16(&body);
    body.extend_from_slice(&crc.to_le_bytes());
    body
}

/// An ID-share read reply as a group would send it, written here without the parser's
/// helpers: after each member's data, the CRC of everything so far.
fn share_reply(gid: u8, function: u8, per_member: &[&[u32]], trailer: bool) -> std::vec::Vec<u8> {
    let items = per_member[0].len();
    let byte_count = per_member.len() * (4 * items + 2);
    let mut reply = vec![gid, function, byte_count as u8];
    for values in per_member {
        for value in *values {
            reply.extend_from_slice(&value.to_be_bytes());
        }
        reply = with_crc(reply);
    }
    if trailer { with_crc(reply) } else { reply }
}

// The wiring of docs/drives.md: left = slave 1 (local ID 1), right = slave 2, group 15.
const GID: u8 = 0x0F;
const READ_LIST: [u32; 4] = [102, 103, 64, 86];
const WRITE_LIST: [u32; 5] = [45, 47, 48, 49, 51];
const LEFT_COMMAND: [u32; 5] = [16, 600, 1000, 1000, 1];
const RIGHT_COMMAND: [u32; 5] = [16, -600i32 as u32, 1000, 1000, 1];

const SHARE_WRITE_6_2: &str = "0F 10 00 00 00 14 28
    00 00 00 10  00 00 02 58  00 00 03 E8  00 00 03 E8  00 00 00 01
    00 00 00 10  FF FF FD A8  00 00 03 E8  00 00 03 E8  00 00 00 01
    49 84";
const SHARE_READ_REPLY_6_3: &str = "0F 03 24
    00 01 E2 40  00 00 02 58  00 00 00 00  00 00 00 00   3F 55
    FF FE 1D F8  FF FF FD AA  00 00 00 00  00 00 00 00   4B C8
    00 00";
const SHARE_READ_WRITE_6_3: &str = "0F 17 00 00 00 12 00 00 00 14 28
    00 00 00 10  00 00 02 58  00 00 03 E8  00 00 03 E8  00 00 00 01
    00 00 00 10  FF FF FD A8  00 00 03 E8  00 00 03 E8  00 00 00 01
    A1 4F";

fn share_lists() -> [u32; 24] {
    let mut lists = [0; 24];
    lists[..4].copy_from_slice(&READ_LIST);
    lists[12..17].copy_from_slice(&WRITE_LIST);
    lists
}

#[test]
fn crc_of_the_alarm_read_matches_the_manual_check() {
    assert_eq!(crc16(&hex("01 03 00 80 00 02")), 0xE3C5);
}

#[test]
fn alarm_read_golden() {
    assert_golden(&read_items(1, 0x0080, 1), "01 03 00 80 00 02 C5 E3");
}

#[test]
fn share_group_setup_golden_for_both_slaves() {
    assert_golden(
        &write_items(1, 0x0980, &[15, 2, 1]),
        "01 10 09 80 00 06 0C 00 00 00 0F 00 00 00 02 00 00 00 01 44 D5",
    );
    assert_golden(
        &write_items(2, 0x0980, &[15, 2, 2]),
        "02 10 09 80 00 06 0C 00 00 00 0F 00 00 00 02 00 00 00 02 40 90",
    );
}

#[test]
fn share_list_setup_golden_for_both_slaves() {
    let data = "00000066 00000067 00000040 00000056
        00000000 00000000 00000000 00000000 00000000 00000000 00000000 00000000
        0000002D 0000002F 00000030 00000031 00000033
        00000000 00000000 00000000 00000000 00000000 00000000 00000000";
    let left = write_items(1, 0x0990, &share_lists());
    let right = write_items(2, 0x0990, &share_lists());
    assert_golden(&left, &format!("01 10 09 90 00 30 60 {data} 10 4C"));
    assert_golden(&right, &format!("02 10 09 90 00 30 60 {data} E2 3A"));
}

#[test]
fn servo_on_and_off_golden() {
    assert_golden(
        &write_items(1, 0x007C, &[1]),
        "01 10 00 7C 00 02 04 00 00 00 01 35 1E",
    );
    assert_golden(
        &write_items(2, 0x007C, &[1]),
        "02 10 00 7C 00 02 04 00 00 00 01 3A 5A",
    );
    assert_golden(
        &write_items(1, 0x007C, &[0]),
        "01 10 00 7C 00 02 04 00 00 00 00 F4 DE",
    );
}

#[test]
fn alarm_reset_golden() {
    assert_golden(
        &write_items(1, 0x0180, &[1]),
        "01 10 01 80 00 02 04 00 00 00 01 37 9F",
    );
    assert_golden(
        &write_items(1, 0x0180, &[0]),
        "01 10 01 80 00 02 04 00 00 00 00 F6 5F",
    );
}

#[test]
fn share_write_and_its_echo_golden() {
    let request = share_write(GID, 0, &[&LEFT_COMMAND, &RIGHT_COMMAND]);
    assert_golden(&request, SHARE_WRITE_6_2);
    let echo = hex("0F 10 00 00 00 14 C1 28");
    assert_eq!(
        expected_reply_len(&request, Target::Share),
        Some(echo.len())
    );
    assert_eq!(parse_write_echo(&echo, GID, 0, 0x14), Ok(()));
}

#[test]
fn share_read_query_golden() {
    let request = share_read(GID, 0, 4, 2);
    assert_golden(&request, "0F 03 00 00 00 12 C4 E9");
    assert_eq!(expected_reply_len(&request, Target::Share), Some(39));
}

#[test]
fn share_read_write_query_golden() {
    let request = share_read_write(GID, 0, 4, 0, &[&LEFT_COMMAND, &RIGHT_COMMAND]);
    assert_golden(&request, SHARE_READ_WRITE_6_3);
    assert_eq!(expected_reply_len(&request, Target::Share), Some(39));
}

fn assert_spec_values(reply: &ShareReply) {
    assert_eq!(reply.members(), 2);
    assert_eq!(reply.items(), 4);
    assert_eq!(reply.member(0), &[123_456, 600, 0, 0]);
    assert_eq!(reply.member(1), &[-123_400i32 as u32, -598i32 as u32, 0, 0]);
    assert_eq!(reply.member(2), &[] as &[u32]);
}

#[test]
fn share_read_reply_golden_with_trailer() {
    let reply = hex(SHARE_READ_REPLY_6_3);
    assert_eq!(reply.len(), 41);
    let left = [123_456, 600, 0, 0];
    let right = [-123_400i32 as u32, -598i32 as u32, 0, 0];
    assert_eq!(
        share_reply(GID, READ_HOLDING, &[&left, &right], true),
        reply
    );
    assert_spec_values(&parse_share_reply(&reply, GID, READ_HOLDING, 2, 4).unwrap());
}

#[test]
fn share_read_reply_accepted_without_trailer() {
    let reply = hex(SHARE_READ_REPLY_6_3);
    assert_spec_values(&parse_share_reply(&reply[..39], GID, READ_HOLDING, 2, 4).unwrap());
}

#[test]
fn share_read_write_reply_has_the_read_format() {
    let reply = share_reply(
        GID,
        READ_WRITE_MULTIPLE,
        &[
            &[123_456, 600, 0, 0],
            &[-123_400i32 as u32, -598i32 as u32, 0, 0],
        ],
        true,
    );
    assert_spec_values(&parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, 4).unwrap());
    assert_eq!(
        parse_share_reply(&reply, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::WrongFunction)
    );
}

#[test]
fn every_single_byte_corruption_of_the_share_reply_is_rejected() {
    for len in [41, 39] {
        let good = &hex(SHARE_READ_REPLY_6_3)[..len];
        for at in 0..len {
            for flip in 1..=255u8 {
                let mut bad = good.to_vec();
                bad[at] ^= flip;
                assert!(
                    parse_share_reply(&bad, GID, READ_HOLDING, 2, 4).is_err(),
                    "accepted {bad:02X?}"
                );
            }
        }
    }
}

#[test]
fn corruption_names_the_member_whose_check_fails() {
    let mut reply = hex(SHARE_READ_REPLY_6_3);
    reply[5] ^= 0x01;
    assert_eq!(
        parse_share_reply(&reply, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::BadCheck { member: 1 })
    );
    let mut reply = hex(SHARE_READ_REPLY_6_3);
    reply[30] ^= 0x01;
    assert_eq!(
        parse_share_reply(&reply, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::BadCheck { member: 2 })
    );
    let mut reply = hex(SHARE_READ_REPLY_6_3);
    reply[40] = 0x01;
    assert_eq!(
        parse_share_reply(&reply, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::BadCrc)
    );
}

#[test]
fn truncated_share_reply_tells_how_many_members_answered() {
    let reply = hex(SHARE_READ_REPLY_6_3);
    for len in 0..41 {
        let expected = match len {
            0..21 => Err(ReplyError::PartialShare { answered: 0 }),
            21..39 => Err(ReplyError::PartialShare { answered: 1 }),
            39 => Ok(()),
            _ => Err(ReplyError::BadLength),
        };
        let parsed = parse_share_reply(&reply[..len], GID, READ_HOLDING, 2, 4).map(|_| ());
        assert_eq!(parsed, expected, "length {len}");
    }
}

#[test]
fn share_reply_with_extra_bytes_is_rejected() {
    let mut reply = hex(SHARE_READ_REPLY_6_3);
    reply.push(0x00);
    assert_eq!(
        parse_share_reply(&reply, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::BadLength)
    );
}

#[test]
fn share_reply_header_is_checked_after_the_first_check_word() {
    let left: &[u32] = &[1, 2, 3, 4];
    let right: &[u32] = &[5, 6, 7, 8];
    let from_other_group = share_reply(0x0E, READ_HOLDING, &[left, right], true);
    assert_eq!(
        parse_share_reply(&from_other_group, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::WrongAddress)
    );
    // A group of one: its byte count covers one member, so it is no two-member reply.
    let one_member = share_reply(GID, READ_HOLDING, &[left], false);
    assert_eq!(
        parse_share_reply(&one_member, GID, READ_HOLDING, 1, 4)
            .unwrap()
            .member(0),
        left
    );
    let mut two_blocks = one_member.clone();
    two_blocks.extend_from_slice(&share_reply(GID, READ_HOLDING, &[right], false)[3..]);
    assert_eq!(
        parse_share_reply(&two_blocks, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::BadLength)
    );
}

#[test]
fn share_exception_is_reported() {
    let reply = with_crc(vec![GID, 0x83, exception::ILLEGAL_DATA_ADDRESS]);
    assert_eq!(
        parse_share_reply(&reply, GID, READ_HOLDING, 2, 4),
        Err(ReplyError::Exception(exception::ILLEGAL_DATA_ADDRESS))
    );
    let reply = with_crc(vec![GID, 0x97, exception::SLAVE_DEVICE_FAILURE]);
    assert_eq!(
        parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, 4),
        Err(ReplyError::Exception(exception::SLAVE_DEVICE_FAILURE))
    );
}

#[test]
fn share_reply_shapes_outside_the_limits_match_nothing() {
    let reply = hex(SHARE_READ_REPLY_6_3);
    for (members, items) in [(0, 4), (3, 4), (2, 0), (2, 13)] {
        assert_eq!(
            parse_share_reply(&reply, GID, READ_HOLDING, members, items),
            Err(ReplyError::BadLength)
        );
    }
    assert_eq!(
        parse_share_reply(&reply, GID, WRITE_MULTIPLE, 2, 4),
        Err(ReplyError::WrongFunction)
    );
}

#[test]
fn unicast_read_reply_is_parsed() {
    let reply = with_crc(hex("01 03 04 00 00 00 84"));
    assert_eq!(
        expected_reply_len(&read_items(1, 0x0080, 1), Target::Unicast),
        Some(9)
    );
    assert_eq!(parse_read(&reply, 1, 1).unwrap(), [0x84]);
    let reply = with_crc(hex("02 03 08 FF FF FF FF 00 00 02 58"));
    assert_eq!(parse_read(&reply, 2, 2).unwrap(), [u32::MAX, 600]);
}

#[test]
fn unicast_read_errors() {
    let good = with_crc(hex("01 03 04 00 00 00 84"));
    assert_eq!(parse_read(&good[..8], 1, 1), Err(ReplyError::TooShort));
    assert_eq!(parse_read(&[], 1, 1), Err(ReplyError::TooShort));
    assert_eq!(parse_read(&good, 1, 2), Err(ReplyError::TooShort));
    let mut long = good.clone();
    long.push(0);
    assert_eq!(parse_read(&long, 1, 1), Err(ReplyError::BadLength));
    let mut noisy = good.clone();
    noisy[5] ^= 0x40;
    assert_eq!(parse_read(&noisy, 1, 1), Err(ReplyError::BadCrc));
    assert_eq!(parse_read(&good, 2, 1), Err(ReplyError::WrongAddress));
    let written = with_crc(hex("01 10 04 00 00 00 84"));
    assert_eq!(parse_read(&written, 1, 1), Err(ReplyError::WrongFunction));
    let miscounted = with_crc(hex("01 03 06 00 00 00 84"));
    assert_eq!(parse_read(&miscounted, 1, 1), Err(ReplyError::BadLength));
    assert_eq!(parse_read(&good, 1, 0), Err(ReplyError::BadLength));
    assert_eq!(
        parse_read(&good, 1, MAX_ITEMS + 1),
        Err(ReplyError::BadLength)
    );
}

#[test]
fn exception_replies_are_checked_like_any_frame() {
    let refused = with_crc(hex("01 83 02"));
    assert_eq!(parse_read(&refused, 1, 1), Err(ReplyError::Exception(2)));
    assert_eq!(parse_read(&refused, 2, 1), Err(ReplyError::WrongAddress));
    let mut noisy = refused.clone();
    noisy[2] = 0x03;
    assert_eq!(parse_read(&noisy, 1, 1), Err(ReplyError::BadCrc));
    let refused_write = with_crc(hex("01 90 04"));
    assert_eq!(
        parse_write_echo(&refused_write, 1, 0x007C, 2),
        Err(ReplyError::Exception(4))
    );
    assert_eq!(
        parse_read(&refused_write, 1, 1),
        Err(ReplyError::WrongFunction)
    );
}

#[test]
fn write_echo_errors() {
    let echo = hex("0F 10 00 00 00 14 C1 28");
    assert_eq!(
        parse_write_echo(&echo, GID, 0, 0x12),
        Err(ReplyError::BadEcho)
    );
    assert_eq!(
        parse_write_echo(&echo, GID, 2, 0x14),
        Err(ReplyError::BadEcho)
    );
    assert_eq!(
        parse_write_echo(&echo, 1, 0, 0x14),
        Err(ReplyError::WrongAddress)
    );
    assert_eq!(
        parse_write_echo(&echo[..7], GID, 0, 0x14),
        Err(ReplyError::TooShort)
    );
    let mut long = echo.clone();
    long.extend([0, 0]);
    assert_eq!(
        parse_write_echo(&long, GID, 0, 0x14),
        Err(ReplyError::BadLength)
    );
    let mut noisy = echo.clone();
    noisy[3] = 0x01;
    assert_eq!(
        parse_write_echo(&noisy, GID, 0, 0x14),
        Err(ReplyError::BadCrc)
    );
    let read_reply = with_crc(hex("0F 03 00 00 00 14"));
    assert_eq!(
        parse_write_echo(&read_reply, GID, 0, 0x14),
        Err(ReplyError::WrongFunction)
    );
}

#[test]
fn requests_outside_the_limits_are_refused() {
    assert_eq!(try_read_items(1, 0, 0), Err(RequestError::Empty));
    assert_eq!(try_read_items(1, 0, 13), Err(RequestError::TooLarge));
    assert_eq!(try_write_items(1, 0, &[]), Err(RequestError::Empty));
    assert_eq!(try_write_items(1, 0, &[0; 62]), Err(RequestError::TooLarge));
    assert_eq!(try_write_items(1, 0, &[0; 61]).unwrap().len(), 253);
    assert_eq!(try_share_read(GID, 0, 4, 0), Err(RequestError::Empty));
    assert_eq!(try_share_read(GID, 0, 4, 3), Err(RequestError::TooLarge));
    assert_eq!(try_share_read(GID, 0, 13, 2), Err(RequestError::TooLarge));
    assert_eq!(try_share_write(GID, 0, &[]), Err(RequestError::Empty));
    assert_eq!(
        try_share_write(GID, 0, &[&[], &[]]),
        Err(RequestError::Empty)
    );
    assert_eq!(
        try_share_write(GID, 0, &[&[1, 2], &[1]]),
        Err(RequestError::UnevenMembers)
    );
    assert_eq!(
        try_share_write(GID, 0, &[&[1], &[1], &[1]]),
        Err(RequestError::TooLarge)
    );
    assert_eq!(
        try_share_read_write(GID, 0, 0, 0, &[&[1], &[1]]),
        Err(RequestError::Empty)
    );
    assert_eq!(
        try_share_read_write(GID, 0, 4, 0, &[&[0; 13], &[0; 13]]),
        Err(RequestError::TooLarge)
    );
}

#[test]
#[cfg(debug_assertions)]
#[should_panic(expected = "outside the limits")]
fn request_outside_the_limits_stops_a_debug_build() {
    share_read(GID, 0, 0, 2);
}

#[test]
fn expected_reply_len_by_request() {
    assert_eq!(
        expected_reply_len(&write_items(1, 0x007C, &[1]), Target::Unicast),
        Some(8)
    );
    assert_eq!(
        expected_reply_len(&write_items(0, 0x007C, &[1]), Target::Unicast),
        None
    );
    assert_eq!(
        expected_reply_len(&read_items(1, 0x00CC, 2), Target::Unicast),
        Some(13)
    );
    assert_eq!(
        expected_reply_len(&[0x01, 0x03, 0x00], Target::Unicast),
        None
    );
    assert_eq!(
        expected_reply_len(&hex("01 06 00 7C 00 01 00 00"), Target::Unicast),
        None
    );
    let one_member = share_read(GID, 0, 4, 1);
    let reply = share_reply(GID, READ_HOLDING, &[&[1, 2, 3, 4]], false);
    assert_eq!(
        expected_reply_len(&one_member, Target::Share),
        Some(reply.len())
    );
}

fn values(max: usize) -> impl Strategy<Value = std::vec::Vec<u32>> {
    prop::collection::vec(any::<u32>(), 1..=max)
}

/// Values for each member of a share group, as many for each.
fn share_group() -> impl Strategy<Value = std::vec::Vec<std::vec::Vec<u32>>> {
    (1..=MAX_ITEMS, 1..=MAX_MEMBERS).prop_flat_map(|(items, members)| {
        prop::collection::vec(prop::collection::vec(any::<u32>(), items), members)
    })
}

fn slices(group: &[std::vec::Vec<u32>]) -> std::vec::Vec<&[u32]> {
    group.iter().map(|values| values.as_slice()).collect()
}

proptest! {
    #[test]
    fn random_bytes_never_panic_any_parser(
        reply in prop::collection::vec(any::<u8>(), 0..300),
        address: u8,
        function: u8,
        members in 0u8..4,
        items in 0usize..14,
        start: u16,
        count: u16,
    ) {
        let _ = parse_read(&reply, address, items);
        let _ = parse_write_echo(&reply, address, start, count);
        let _ = parse_share_reply(&reply, address, function, members, items);
        let _ = expected_reply_len(&reply, Target::Unicast);
        let _ = expected_reply_len(&reply, Target::Share);
    }

    #[test]
    fn share_read_round_trips(
        gid in 1u8..=247,
        start: u16,
        group in share_group(),
        trailer: bool,
    ) {
        let per_member = slices(&group);
        let items = per_member[0].len();
        let members = per_member.len() as u8;

        let request = share_read(gid, start, items as u16, members);
        let reply = share_reply(gid, READ_HOLDING, &per_member, trailer);
        let reply_len = expected_reply_len(&request, Target::Share).unwrap();
        prop_assert_eq!(reply.len(), reply_len + if trailer { 2 } else { 0 });
        let parsed = parse_share_reply(&reply, gid, READ_HOLDING, members, items).unwrap();
        prop_assert_eq!(parsed.members(), per_member.len());
        for (k, values) in per_member.iter().enumerate() {
            prop_assert_eq!(parsed.member(k), *values);
        }
    }

    #[test]
    fn share_write_round_trips_through_its_echo(
        gid in 1u8..=247,
        start: u16,
        group in share_group(),
    ) {
        let per_member = slices(&group);
        let items = per_member[0].len();
        let request = share_write(gid, start, &per_member);
        let count = u16::from_be_bytes([request[4], request[5]]);
        prop_assert_eq!(usize::from(count), per_member.len() * 2 * items);
        prop_assert_eq!(usize::from(request[6]), 2 * usize::from(count));
        prop_assert_eq!(request.len(), 9 + per_member.len() * 4 * items);
        let echo = with_crc(request[..6].to_vec());
        prop_assert_eq!(Some(echo.len()), expected_reply_len(&request, Target::Share));
        prop_assert_eq!(parse_write_echo(&echo, gid, start, count), Ok(()));
    }

    #[test]
    fn unicast_read_round_trips(
        slave in 1u8..=247,
        start: u16,
        sent in values(MAX_ITEMS),
    ) {
        let request = read_items(slave, start, sent.len() as u16);
        let mut reply = vec![slave, READ_HOLDING, (4 * sent.len()) as u8];
        sent.iter().for_each(|value| reply.extend_from_slice(&value.to_be_bytes()));
        let reply = with_crc(reply);
        prop_assert_eq!(Some(reply.len()), expected_reply_len(&request, Target::Unicast));
        let received = parse_read(&reply, slave, sent.len()).unwrap();
        prop_assert_eq!(received.as_slice(), &sent[..]);
    }

    #[test]
    fn any_single_byte_change_of_a_share_reply_is_rejected(
        group in share_group(),
        trailer: bool,
        at: prop::sample::Index,
        flip in 1u8..=255,
    ) {
        let per_member = slices(&group);
        let items = per_member[0].len();
        let members = per_member.len() as u8;
        let mut reply = share_reply(GID, READ_WRITE_MULTIPLE, &per_member, trailer);
        let at = at.index(reply.len());
        reply[at] ^= flip;
        prop_assert!(parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, members, items).is_err());
    }
}
