//! The flash record of one register and the rule that carries old records into a new
//! firmware. The flash task stores one record per persistent register, keyed by its
//! address, and hands the records back to [`super::Registers::load`] at boot.
//!
//! Layout (6 bytes): `[schema_version, address, value MSB, value LSB, crc LSB, crc MSB]`,
//! CRC-16/IBM-3740 over the first four bytes.
//!
//! Migration rule: addresses 0–23 are the manual's and never move or change meaning.
//! A record written under an older schema is converted by [`migrate`]; a record from a
//! newer schema than this firmware knows (after a downgrade) is kept only for 0–23 and
//! dropped for the extensions, whose meaning a newer map may have changed.

use crc::{CRC_16_IBM_3740, Crc, NoTable};

use super::table::LAST_MANUAL_ADDRESS;

/// Version of the record encoding and of the meaning of the stored values. Bump it
/// when an extension register changes unit or meaning, and add the conversion to
/// [`migrate`]. Version 0 has never been written.
pub const SCHEMA_VERSION: u8 = 1;

/// The schema byte of the records the register store keeps for itself (its wear count,
/// its batch journal) under keys beyond the register map. Above every schema a register
/// record will ever have, so [`decode_record`] (and every older firmware) takes such a
/// record for a newer firmware's extension and drops it without a fault.
pub const STORE_SCHEMA: u8 = 0x80;

/// A record of the store's own under `key` (see [`STORE_SCHEMA`]).
pub const fn encode_store_record(key: u8, value: u16) -> [u8; RECORD_LEN] {
    encode_with_schema(STORE_SCHEMA, key, value)
}

/// Bytes in one record.
pub const RECORD_LEN: usize = 6;

/// CRC-16/IBM-3740 (better known as CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF).
/// The non-zero init makes an all-zero record fail; Hamming distance 4 at this length
/// catches every 1- to 3-bit error and every burst up to 16 bits; and it is the CRC-16
/// that hand tools offer first, so a flash dump can be checked without this code.
/// No table: the record is four bytes, and 512 bytes of flash for a table buy nothing.
const RECORD_CRC: Crc<u16, NoTable> = Crc::<u16, NoTable>::new(&CRC_16_IBM_3740);

/// Why a record could not be used. Never leaves the device (the status frame shows only
/// the flash fault bit), so no wire codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// The record is not [`RECORD_LEN`] bytes long.
    WrongLength { len: usize },
    /// The stored CRC does not match the first four bytes.
    BadCrc { stored: u16, computed: u16 },
    /// A schema version no firmware writes (0).
    UnknownSchema { version: u8 },
    /// A newer firmware's record for an extension register: dropped on purpose, since
    /// that firmware may have given the address another meaning. Not a fault.
    NewerSchema { version: u8, address: u8 },
}

pub(super) const fn record_crc(header: &[u8]) -> u16 {
    RECORD_CRC.checksum(header)
}

/// The record that stores `value` at `address` under the current schema.
pub const fn encode_record(address: u8, value: u16) -> [u8; RECORD_LEN] {
    encode_with_schema(SCHEMA_VERSION, address, value)
}

pub(super) const fn encode_with_schema(
    schema_version: u8,
    address: u8,
    value: u16,
) -> [u8; RECORD_LEN] {
    let [value_msb, value_lsb] = value.to_be_bytes();
    let header = [schema_version, address, value_msb, value_lsb];
    let [crc_lsb, crc_msb] = record_crc(&header).to_le_bytes();
    [
        schema_version,
        address,
        value_msb,
        value_lsb,
        crc_lsb,
        crc_msb,
    ]
}

/// Checks and migrates one record into `(address, value)` for this firmware. The value
/// is not range-checked here; [`super::Registers::load`] does that.
pub fn decode_record(bytes: &[u8]) -> Result<(u8, u16), RecordError> {
    let &[
        schema_version,
        address,
        value_msb,
        value_lsb,
        crc_lsb,
        crc_msb,
    ] = bytes
    else {
        return Err(RecordError::WrongLength { len: bytes.len() });
    };
    let stored = u16::from_le_bytes([crc_lsb, crc_msb]);
    let computed = record_crc(&bytes[..4]);
    if stored != computed {
        return Err(RecordError::BadCrc { stored, computed });
    }
    let value = u16::from_be_bytes([value_msb, value_lsb]);
    migrate(schema_version, address, value).ok_or(if schema_version > SCHEMA_VERSION {
        RecordError::NewerSchema {
            version: schema_version,
            address,
        }
    } else {
        RecordError::UnknownSchema {
            version: schema_version,
        }
    })
}

/// Carries a record written under `schema_version` into this firmware's map, or
/// `None` if it must not be used.
///
/// A v2 firmware adds one arm per change, matching the old version and address, e.g.
/// if v2 moved `estop_decel` to 10 (1/min)/s steps:
/// `(1, 26) => Some((26, value / 10))`, followed by `(1, _) => Some((address, value))`
/// for everything v2 left alone. Addresses 0–23 never get such an arm.
pub const fn migrate(schema_version: u8, address: u8, value: u16) -> Option<(u8, u16)> {
    match schema_version {
        0 => None,
        SCHEMA_VERSION => Some((address, value)),
        // Older than us: none exists yet (v1 is the first schema).
        v if v < SCHEMA_VERSION => None,
        // Newer than us (a downgrade): only the manual's registers keep their meaning.
        _ if address <= LAST_MANUAL_ADDRESS => Some((address, value)),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_crc_is_crc16_ccitt_false() {
        // The published check value of CRC-16/IBM-3740 over "123456789".
        assert_eq!(record_crc(b"123456789"), 0x29B1);
    }

    #[test]
    fn record_of_loop_end_delay_50_has_golden_bytes() {
        // CRC-16/IBM-3740 of [01 0F 00 32] is 0xC854, stored LSB first.
        assert_eq!(encode_record(15, 50), [0x01, 0x0F, 0x00, 0x32, 0x54, 0xC8]);
    }

    #[test]
    fn record_round_trips_every_address_and_edge_value() {
        for address in 0..=u8::MAX {
            for value in [0, 1, 0x00FF, 0xFF00, u16::MAX] {
                assert_eq!(
                    decode_record(&encode_record(address, value)),
                    Ok((address, value))
                );
            }
        }
    }

    #[test]
    fn record_of_wrong_length_is_rejected() {
        let record = encode_record(15, 50);
        assert_eq!(
            decode_record(&record[..5]),
            Err(RecordError::WrongLength { len: 5 })
        );
        assert_eq!(decode_record(&[]), Err(RecordError::WrongLength { len: 0 }));
        let mut long = [0u8; 7];
        long[..6].copy_from_slice(&record);
        assert_eq!(
            decode_record(&long),
            Err(RecordError::WrongLength { len: 7 })
        );
    }

    #[test]
    fn any_flipped_bit_fails_the_crc() {
        let record = encode_record(15, 50);
        for byte in 0..RECORD_LEN {
            for bit in 0..8 {
                let mut damaged = record;
                damaged[byte] ^= 1 << bit;
                assert!(
                    matches!(decode_record(&damaged), Err(RecordError::BadCrc { .. })),
                    "byte {byte} bit {bit}"
                );
            }
        }
    }

    #[test]
    fn erased_and_zeroed_flash_are_not_records() {
        assert!(matches!(
            decode_record(&[0xFF; RECORD_LEN]),
            Err(RecordError::BadCrc { .. })
        ));
        assert!(matches!(
            decode_record(&[0x00; RECORD_LEN]),
            Err(RecordError::BadCrc { .. })
        ));
    }

    #[test]
    fn schema_zero_is_unknown() {
        assert_eq!(
            decode_record(&encode_with_schema(0, 2, 250)),
            Err(RecordError::UnknownSchema { version: 0 })
        );
    }

    #[test]
    fn newer_schema_keeps_manual_registers_and_drops_extensions() {
        let newer = SCHEMA_VERSION + 1;
        assert_eq!(
            decode_record(&encode_with_schema(newer, 2, 300)),
            Ok((2, 300))
        );
        assert_eq!(
            decode_record(&encode_with_schema(newer, 23, 9000)),
            Ok((23, 9000))
        );
        assert_eq!(
            decode_record(&encode_with_schema(newer, 24, 1000)),
            Err(RecordError::NewerSchema {
                version: newer,
                address: 24
            })
        );
        assert_eq!(migrate(u8::MAX, 25, 500), None);
    }

    #[test]
    fn current_schema_migrates_as_identity() {
        for address in 0..=u8::MAX {
            assert_eq!(
                migrate(SCHEMA_VERSION, address, 4242),
                Some((address, 4242))
            );
        }
    }
}
