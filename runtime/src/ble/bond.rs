//! The bond as a fixed flash record. trouble-host's `BondInformation` is plain data, so
//! it is written field by field rather than through serde: no extra crates, and a
//! record whose layout is written down here.
//!
//! | bytes | field |
//! |---|---|
//! | 0 | record version (1) |
//! | 1 | peer address kind (HCI) |
//! | 2..8 | peer address |
//! | 8..24 | peer identity resolving key, LE (all zero: none) |
//! | 24..40 | long-term key, LE |
//! | 40 | bonded (0/1) |
//! | 41 | security level (0 none, 1 encrypted, 2 authenticated) |
//! | 42..44 | EDIV, LE (legacy pairing; 0 for Secure Connections) |
//! | 44..52 | Rand (legacy pairing) |
//! | 52 | key length in bytes |

use trouble_host::prelude::{
    AddrKind, Address, BdAddr, BondInformation, Identity, IdentityResolvingKey, LongTermKey,
    SecurityLevel,
};

pub const BOND_RECORD_LEN: usize = 53;
const VERSION: u8 = 1;

pub fn encode_bond(bond: &BondInformation) -> [u8; BOND_RECORD_LEN] {
    let mut record = [0u8; BOND_RECORD_LEN];
    record[0] = VERSION;
    record[1] = bond.identity.addr.kind.as_raw();
    record[2..8].copy_from_slice(bond.identity.addr.addr.raw());
    if let Some(irk) = bond.identity.irk {
        record[8..24].copy_from_slice(&irk.to_le_bytes());
    }
    record[24..40].copy_from_slice(&bond.ltk.to_le_bytes());
    record[40] = u8::from(bond.is_bonded);
    record[41] = match bond.security_level {
        SecurityLevel::NoEncryption => 0,
        SecurityLevel::Encrypted => 1,
        SecurityLevel::EncryptedAuthenticated => 2,
    };
    record[42..44].copy_from_slice(&bond.ediv.to_le_bytes());
    record[44..52].copy_from_slice(&bond.rand);
    record[52] = bond.encryption_key_len;
    record
}

/// The bond of a record; `None` for a record of another version or with an impossible
/// field (an unknown security level, a key length outside 7..=16).
pub fn decode_bond(record: &[u8; BOND_RECORD_LEN]) -> Option<BondInformation> {
    if record[0] != VERSION {
        return None;
    }
    let security_level = match record[41] {
        0 => SecurityLevel::NoEncryption,
        1 => SecurityLevel::Encrypted,
        2 => SecurityLevel::EncryptedAuthenticated,
        _ => return None,
    };
    let key_len = record[52];
    if !(7..=16).contains(&key_len) || record[40] > 1 {
        return None;
    }
    let mut addr = [0u8; 6];
    addr.copy_from_slice(&record[2..8]);
    let identity = Identity {
        addr: Address {
            kind: AddrKind::new(record[1]),
            addr: BdAddr::new(addr),
        },
        irk: IdentityResolvingKey::from_le_bytes(bytes16(&record[8..24])),
    };
    let mut bond = BondInformation::new(
        identity,
        LongTermKey::from_le_bytes(bytes16(&record[24..40])),
        security_level,
        record[40] == 1,
    );
    bond.ediv = u16::from_le_bytes([record[42], record[43]]);
    bond.rand.copy_from_slice(&record[44..52]);
    bond.encryption_key_len = key_len;
    Some(bond)
}

fn bytes16(slice: &[u8]) -> [u8; 16] {
    let mut bytes = [0u8; 16];
    bytes.copy_from_slice(slice);
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bond() -> BondInformation {
        let identity = Identity {
            addr: Address {
                kind: AddrKind::PUBLIC,
                addr: BdAddr::new([0x98, 0x7A, 0x14, 0x2B, 0x5C, 0x44]),
            },
            irk: IdentityResolvingKey::new(0x0123_4567_89AB_CDEF_0011_2233_4455_6677),
        };
        let mut bond = BondInformation::new(
            identity,
            LongTermKey::new(0xFEDC_BA98_7654_3210_8899_AABB_CCDD_EEFF),
            SecurityLevel::Encrypted,
            true,
        );
        bond.ediv = 0xBEEF;
        bond.rand = [1, 2, 3, 4, 5, 6, 7, 8];
        bond.encryption_key_len = 16;
        bond
    }

    fn same(a: &BondInformation, b: &BondInformation) -> bool {
        a.identity.addr.kind.as_raw() == b.identity.addr.kind.as_raw()
            && a.identity.addr.addr.raw() == b.identity.addr.addr.raw()
            && a.identity.irk.map(|k| k.to_le_bytes()) == b.identity.irk.map(|k| k.to_le_bytes())
            && a.ltk.to_le_bytes() == b.ltk.to_le_bytes()
            && a.is_bonded == b.is_bonded
            && a.security_level == b.security_level
            && a.ediv == b.ediv
            && a.rand == b.rand
            && a.encryption_key_len == b.encryption_key_len
    }

    #[test]
    fn a_bond_survives_its_record() {
        let original = bond();
        let decoded = decode_bond(&encode_bond(&original)).expect("decodes");
        assert!(same(&original, &decoded));
    }

    #[test]
    fn a_bond_without_identity_key_survives_its_record() {
        let mut original = bond();
        original.identity.irk = None;
        let decoded = decode_bond(&encode_bond(&original)).expect("decodes");
        assert!(decoded.identity.irk.is_none());
        assert!(same(&original, &decoded));
    }

    #[test]
    fn records_of_another_version_or_with_impossible_fields_are_refused() {
        let good = encode_bond(&bond());
        for (index, value) in [(0, 2), (41, 3), (52, 0), (52, 17), (40, 2)] {
            let mut record = good;
            record[index] = value;
            assert!(decode_bond(&record).is_none(), "byte {index} = {value}");
        }
    }

    #[test]
    fn an_erased_record_is_no_bond() {
        assert!(decode_bond(&[0xFF; BOND_RECORD_LEN]).is_none());
    }
}
