//! Any bytes as a drive's reply, fed to every Modbus parser. The first six bytes pick
//! what the master asked (address, function, members, items, start); the rest is the
//! reply. No parser may panic, and whatever one accepts must have exactly the shape the
//! request asked for.
#![no_main]

use base_core::modbus::{
    self, READ_HOLDING, READ_WRITE_MULTIPLE, Target, parse_read, parse_share_reply,
    parse_write_echo,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let [
        address,
        function,
        members,
        items,
        start_high,
        start_low,
        reply @ ..,
    ] = input
    else {
        return;
    };
    let (address, members) = (*address, *members % 4);
    // One past the limits on each side, so the refusals are exercised too.
    let items = usize::from(*items % (modbus::MAX_ITEMS as u8 + 2));
    let function = if function & 1 == 0 {
        READ_HOLDING
    } else {
        READ_WRITE_MULTIPLE
    };
    let start = u16::from_be_bytes([*start_high, *start_low]);
    // Nobody answers a broadcast, so no reply length is expected for address 0.
    let answered = |len: usize| (address != 0).then_some(len);

    if let Ok(values) = parse_read(reply, address, items) {
        assert_eq!(values.len(), items);
        assert_eq!(reply.len(), 5 + 4 * items);
        let request = modbus::read_items(address, start, items as u16);
        assert_eq!(
            modbus::expected_reply_len(&request, Target::Unicast),
            answered(reply.len())
        );
    }

    let count = 2 * items as u16 * u16::from(members);
    if parse_write_echo(reply, address, start, count).is_ok() {
        assert_eq!(reply.len(), 8);
        assert_eq!(&reply[..2], &[address, modbus::WRITE_MULTIPLE]);
    }

    if let Ok(share) = parse_share_reply(reply, address, function, members, items) {
        assert_eq!(share.members(), usize::from(members));
        assert_eq!(share.items(), items);
        let blocks_end = 3 + usize::from(members) * (4 * items + 2);
        assert!(reply.len() == blocks_end || reply.len() == blocks_end + 2);
        for k in 0..share.members() {
            let block = &reply[3 + k * (4 * items + 2)..];
            for (i, value) in share.member(k).iter().enumerate() {
                assert_eq!(block[4 * i..4 * i + 4], value.to_be_bytes());
            }
        }
        let request = modbus::share_read(address, start, items as u16, members);
        assert_eq!(
            modbus::expected_reply_len(&request, Target::Share),
            answered(blocks_end)
        );
    }

    let _ = modbus::expected_reply_len(reply, Target::Unicast);
    let _ = modbus::expected_reply_len(reply, Target::Share);
});
