//! Any bytes as a CAN frame: the first two (LE) are the ID, unmasked so IDs above
//! 0x7FF are tried too; the rest is the data, of any length. Neither decoder may
//! panic, and whatever decodes must survive encode -> decode unchanged.
#![no_main]

use base_core::can::{Command, RawFrame, Report};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let [id_lsb, id_msb, data @ ..] = input else {
        return;
    };
    let id = u16::from_le_bytes([*id_lsb, *id_msb]);

    let frame = RawFrame::new(id, data);
    assert_eq!(frame.is_some(), id <= 0x7FF && data.len() <= 8);

    if let Ok(Some(command)) = Command::decode(id, data) {
        let encoded = command.encode();
        assert_eq!(encoded.id(), id);
        assert_eq!(
            Command::decode(encoded.id(), encoded.data()),
            Ok(Some(command))
        );
    }
    if let Ok(Some(report)) = Report::decode(id, data) {
        // Reports need their exact DLC, so the bytes themselves must come back.
        let encoded = report.encode();
        assert_eq!((encoded.id(), encoded.data()), (id, data));
    }
});
