//! trouble-host's ATT decoder against every short PDU, with and without the guard.
//!
//! trouble-host 0.8 indexes into ATT PDUs without checking their length, so a peer's
//! short PDU panics the host (and resets the chip). The guard (`base_bluetooth::guard`)
//! drops every ATT PDU shorter than its opcode needs. These sweeps run trouble's own
//! decoder, so a new trouble-host version is checked too:
//!
//! - everything the guard lets through decodes without a panic;
//! - the opcodes that still panic without the guard are listed: when a release fixes
//!   some, the list shrinks, and the guard's rule for them may go (docs/remote.md).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Once;

use base_bluetooth::guard::{AclVerdict, CID_ATT, Guard};
use trouble_host::att::Att;

/// Every PDU length up to this is tried (the longest fixed ATT PDU is 21 bytes).
const LONGEST: usize = 24;
/// Fill bytes after the opcode: all zero, all one, and counting up.
const FILLS: [fn(usize) -> u8; 3] = [|_| 0x00, |_| 0xFF, |i| i as u8];

fn quiet_panics() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| std::panic::set_hook(Box::new(|_| {})));
}

/// Every short ATT PDU: (opcode, PDU).
fn short_pdus() -> impl Iterator<Item = (u8, Vec<u8>)> {
    (0..=255u8).flat_map(|opcode| {
        (1..=LONGEST).flat_map(move |len| {
            FILLS.iter().map(move |fill| {
                let mut pdu: Vec<u8> = (0..len).map(fill).collect();
                pdu[0] = opcode;
                (opcode, pdu)
            })
        })
    })
}

fn decode_panics(pdu: &[u8]) -> bool {
    catch_unwind(AssertUnwindSafe(|| {
        let _ = Att::decode(pdu);
    }))
    .is_err()
}

/// Whether the guard passes `pdu` as one unfragmented ATT PDU on an open link.
fn guard_passes(pdu: &[u8]) -> bool {
    let mut guard: Guard<1> = Guard::new();
    // LE Connection Complete, handle 0x0040.
    guard.on_event(0x3E, &[0x01, 0x00, 0x40, 0x00, 0x00, 0x01]);
    let mut acl = Vec::new();
    acl.extend_from_slice(&(pdu.len() as u16).to_le_bytes());
    acl.extend_from_slice(&CID_ATT.to_le_bytes());
    acl.extend_from_slice(pdu);
    matches!(guard.on_acl(0x0040, 0b10, 0, &acl), AclVerdict::Deliver(_))
}

#[test]
fn every_att_pdu_the_guard_lets_through_decodes_without_a_panic() {
    quiet_panics();
    let mut passed = 0;
    for (opcode, pdu) in short_pdus() {
        if guard_passes(&pdu) {
            passed += 1;
            assert!(
                !decode_panics(&pdu),
                "trouble-host panics on ATT opcode {opcode:#04x}, {} bytes {pdu:02x?}, which the guard lets through",
                pdu.len()
            );
        }
    }
    // The sweep is not empty: most opcodes have lengths that pass.
    assert!(passed > 10_000, "{passed} PDUs passed the guard");
}

#[test]
fn trouble_host_0_8_still_panics_on_short_pdus_of_these_opcodes() {
    quiet_panics();
    let mut panicking: Vec<u8> = short_pdus()
        .filter(|(_, pdu)| decode_panics(pdu))
        .map(|(opcode, _)| opcode)
        .collect();
    panicking.dedup();
    assert_eq!(
        panicking,
        [
            0x01, 0x02, 0x04, 0x06, 0x08, 0x0A, 0x0C, 0x10, 0x12, 0x16, 0x18, 0x52
        ],
        "trouble-host's ATT decoder changed: the opcodes whose short PDUs panic are now \
         {panicking:02x?}; the guard's length rules for the others may go (docs/remote.md)"
    );
}
