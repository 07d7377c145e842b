//! ESP-IDF's OTA data partition (`otadata`): which of the two app slots the second-stage
//! bootloader starts. Two sectors hold one 32-byte entry each; the entry with the higher
//! sequence number among the valid ones wins, and sequence number `n` names slot
//! `(n - 1) % 2`. Each write rewrites one sector (erase, then program), so a power cut
//! while writing leaves that sector blank or half written, which the bootloader reads as
//! invalid, and the other sector's entry decides: that is what makes every write here
//! safe on its own.
//!
//! The codec is ours rather than esp-bootloader-esp-idf's updater because that one
//! switches the slot and the state in two writes (a power cut between them boots an
//! image in the wrong state) and gives up when one copy is corrupt, where the
//! bootloader simply uses the other.

use core::ops::Range;

use crc::{Algorithm, Crc};

/// Bytes of one entry: sequence number, a 20-byte label, state, CRC.
pub const ENTRY_LEN: usize = 32;
/// Where an entry's CRC starts: it is the last word.
const CRC_AT: usize = 28;
/// The program operations that write an entry into its erased sector, in this order,
/// each read back before the next: the sequence number, label and state, then the
/// CRC. The CRC is what makes an entry valid to the bootloader, so a cut before the
/// last operation completed leaves an entry it ignores, whichever words of the first
/// one were programmed (a NOR flash programs the words of one operation in no
/// promised order). One operation for the whole entry could leave the sequence number
/// and the CRC programmed and the state still erased: a valid entry in a state nobody
/// wrote.
pub const PROGRAM_ORDER: [Range<usize>; 2] = [0..CRC_AT, CRC_AT..ENTRY_LEN];
/// Each entry has a flash sector of its own.
pub const SECTOR_LEN: u32 = 4096;
/// The app slots the sequence numbers count over (`ota_0`, `ota_1`).
pub const SLOTS: u32 = 2;

/// The ROM's `crc32_le(u32::MAX, ..)`: reflected CRC-32 whose register starts at 0 (the
/// ROM inverts the seed it is given) and is inverted at the end. Over the sequence
/// number only; the state is not covered, which is why a state can change in place.
const OTA_CRC: Algorithm<u32> = Algorithm {
    width: 32,
    poly: 0x04C1_1DB7,
    init: 0,
    refin: true,
    refout: true,
    xorout: 0xFFFF_FFFF,
    check: 0x2DFD_2D88,
    residue: 0xDEBB_20E3,
};

/// An entry's `ota_state`, as the bootloader and ESP-IDF number them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OtaState {
    /// Just activated, not booted yet.
    New,
    /// Booted once by a rollback-enabled bootloader, not confirmed: the next boot
    /// turns it into `Aborted`.
    PendingVerify,
    /// Confirmed healthy.
    Valid,
    /// Rejected by the app; the bootloader skips it.
    Invalid,
    /// A trial that ended without a confirm; the bootloader skips it. Our images write
    /// it themselves first thing on a trial boot ("armed"), so any reset before the
    /// confirm falls back to the previous slot even with a bootloader without rollback.
    Aborted,
    /// `0xFFFF_FFFF` or any other value: the bootloader treats it as bootable. Neither
    /// this firmware nor the bootloader writes it; a torn write of another bootloader
    /// or a tool can leave it, and an image that finds it starts on trial.
    Undefined(u32),
}

impl OtaState {
    pub const fn to_raw(self) -> u32 {
        match self {
            Self::New => 0,
            Self::PendingVerify => 1,
            Self::Valid => 2,
            Self::Invalid => 3,
            Self::Aborted => 4,
            Self::Undefined(raw) => raw,
        }
    }

    pub const fn from_raw(raw: u32) -> Self {
        match raw {
            0 => Self::New,
            1 => Self::PendingVerify,
            2 => Self::Valid,
            3 => Self::Invalid,
            4 => Self::Aborted,
            other => Self::Undefined(other),
        }
    }

    /// The bootloader never starts an entry in this state.
    pub const fn is_rejected(self) -> bool {
        matches!(self, Self::Invalid | Self::Aborted)
    }
}

/// One decoded entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Entry {
    pub seq: u32,
    pub state: OtaState,
    /// Whether the stored CRC matches the sequence number.
    pub crc_ok: bool,
}

impl Entry {
    /// A fresh entry for `seq` in `state`, as this firmware writes them.
    pub const fn new(seq: u32, state: OtaState) -> Self {
        Self {
            seq,
            state,
            crc_ok: true,
        }
    }

    /// The bootloader's "valid": a written sequence number, a matching CRC and a state
    /// it may start.
    pub const fn is_bootable(&self) -> bool {
        self.seq != u32::MAX && self.crc_ok && !self.state.is_rejected()
    }

    /// The slot this entry starts.
    pub const fn slot(&self) -> Slot {
        Slot::of_seq(self.seq)
    }

    /// Reads an entry from the first [`ENTRY_LEN`] bytes of its sector.
    pub fn decode(bytes: &[u8; ENTRY_LEN]) -> Self {
        let word = |at: usize| {
            u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
        };
        let seq = word(0);
        Self {
            seq,
            state: OtaState::from_raw(word(24)),
            crc_ok: word(CRC_AT) == crc_of(seq),
        }
    }

    /// The bytes to program at the start of an erased sector. The label stays erased
    /// (`0xFF`), as ESP-IDF leaves it.
    pub fn encode(&self) -> [u8; ENTRY_LEN] {
        let mut bytes = [0xFF; ENTRY_LEN];
        bytes[0..4].copy_from_slice(&self.seq.to_le_bytes());
        bytes[24..28].copy_from_slice(&self.state.to_raw().to_le_bytes());
        let crc = if self.crc_ok {
            crc_of(self.seq)
        } else {
            !crc_of(self.seq)
        };
        bytes[CRC_AT..].copy_from_slice(&crc.to_le_bytes());
        bytes
    }
}

/// The smallest sequence number above `above` that names `slot`.
fn next_seq(above: u32, slot: Slot) -> Result<u32, OtaDataError> {
    let mut seq = above
        .checked_add(1)
        .ok_or(OtaDataError::SequenceExhausted)?;
    if Slot::of_seq(seq) != slot {
        seq = seq.checked_add(1).ok_or(OtaDataError::SequenceExhausted)?;
    }
    if seq == u32::MAX {
        return Err(OtaDataError::SequenceExhausted);
    }
    Ok(seq)
}

fn crc_of(seq: u32) -> u32 {
    Crc::<u32>::new(&OTA_CRC).checksum(&seq.to_le_bytes())
}

/// An app slot: `ota_0` or `ota_1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Slot {
    Ota0,
    Ota1,
}

impl Slot {
    pub const fn index(self) -> usize {
        match self {
            Self::Ota0 => 0,
            Self::Ota1 => 1,
        }
    }

    pub const fn other(self) -> Self {
        match self {
            Self::Ota0 => Self::Ota1,
            Self::Ota1 => Self::Ota0,
        }
    }

    /// The slot sequence number `seq` starts (`seq` ≥ 1).
    pub const fn of_seq(seq: u32) -> Self {
        if seq.wrapping_sub(1).is_multiple_of(SLOTS) {
            Self::Ota0
        } else {
            Self::Ota1
        }
    }

    pub const fn from_index(index: usize) -> Self {
        if index == 0 { Self::Ota0 } else { Self::Ota1 }
    }
}

/// Both sectors as the bootloader reads them: `None` where a sector is erased.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OtaData {
    pub sectors: [Entry; 2],
}

/// A rewrite of one sector: erase it, then program `entry` at its start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SectorWrite {
    pub sector: usize,
    pub entry: Entry,
}

/// Why an otadata change was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OtaDataError {
    /// No entry names the slot that is running, so there is nothing to change, and
    /// no activation: it would leave no entry that boots the running image again.
    NoEntryForSlot,
    /// The sequence number cannot grow any more (after four billion updates).
    SequenceExhausted,
}

impl OtaData {
    /// Reads both sectors from their first [`ENTRY_LEN`] bytes each.
    pub fn decode(first: &[u8; ENTRY_LEN], second: &[u8; ENTRY_LEN]) -> Self {
        Self {
            sectors: [Entry::decode(first), Entry::decode(second)],
        }
    }

    /// The sector whose entry the bootloader follows: the bootable one with the higher
    /// sequence number (the first on a tie), or `None` when neither is bootable.
    pub fn active_sector(&self) -> Option<usize> {
        let [a, b] = &self.sectors;
        match (a.is_bootable(), b.is_bootable()) {
            (true, true) => Some(if a.seq >= b.seq { 0 } else { 1 }),
            (true, false) => Some(0),
            (false, true) => Some(1),
            (false, false) => None,
        }
    }

    /// The newest entry that names `slot`, bootable or not.
    pub fn entry_of(&self, slot: Slot) -> Option<usize> {
        let names = |i: usize| {
            let entry = &self.sectors[i];
            entry.seq != u32::MAX && entry.crc_ok && entry.slot() == slot
        };
        match (names(0), names(1)) {
            (true, true) => Some(if self.sectors[0].seq >= self.sectors[1].seq {
                0
            } else {
                1
            }),
            (true, false) => Some(0),
            (false, true) => Some(1),
            (false, false) => None,
        }
    }

    /// Activation of `target` while the other slot runs: one write of `{seq, New}`,
    /// with a sequence number above every entry's, into the sector that does not hold
    /// the running image's entry. That entry is what boots the running image again
    /// when the new one fails: it is never overwritten, also not when the entry the
    /// bootloader follows is another one (an image it refused, whose entry still wins
    /// on its sequence number). Until the write completes the old entries decide;
    /// after it, the new entry does.
    pub fn activate(&self, target: Slot) -> Result<SectorWrite, OtaDataError> {
        let kept = self
            .entry_of(target.other())
            .ok_or(OtaDataError::NoEntryForSlot)?;
        let newest = self
            .sectors
            .iter()
            .filter(|entry| entry.seq != u32::MAX && entry.crc_ok)
            .map(|entry| entry.seq)
            .max()
            .unwrap_or(0);
        Ok(SectorWrite {
            sector: 1 - kept,
            entry: Entry::new(next_seq(newest, target)?, OtaState::New),
        })
    }

    /// Rewrites the entry that started `running` with `state` (arming with `Aborted`,
    /// confirming with `Valid`, rejecting with `Invalid`).
    pub fn set_state(&self, running: Slot, state: OtaState) -> Result<SectorWrite, OtaDataError> {
        let sector = self.entry_of(running).ok_or(OtaDataError::NoEntryForSlot)?;
        Ok(SectorWrite {
            sector,
            entry: Entry::new(self.sectors[sector].seq, state),
        })
    }

    /// Both sectors erased or holding no valid entry: the bootloader starts `ota_0` (or
    /// the first slot that loads) and records it.
    pub fn is_blank(&self) -> bool {
        self.sectors
            .iter()
            .all(|entry| entry.seq == u32::MAX || !entry.crc_ok)
    }

    /// The state after `write` completed.
    pub fn with(mut self, write: SectorWrite) -> Self {
        self.sectors[write.sector] = write.entry;
        self
    }

    /// Blank otadata, as after `espflash --erase-parts otadata`.
    pub const fn erased() -> Self {
        Self {
            sectors: [ERASED_ENTRY; 2],
        }
    }
}

/// An erased sector read as an entry.
pub const ERASED_ENTRY: Entry = Entry {
    seq: u32::MAX,
    state: OtaState::Undefined(u32::MAX),
    // 0xFFFF_FFFF is not the CRC of sequence number 0xFFFF_FFFF.
    crc_ok: false,
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_roms_for_known_sequence_numbers() {
        assert_eq!(crc_of(1), 0x4743_989A);
        assert_eq!(crc_of(2), 0x55F6_3774);
    }

    /// The power-cut and boot tests write entries with a broken CRC through
    /// `encode`: it must keep the CRC broken, or they would test a valid entry.
    #[test]
    fn an_entry_round_trips_through_its_bytes_a_broken_crc_too() {
        for crc_ok in [true, false] {
            let entry = Entry {
                crc_ok,
                ..Entry::new(7, OtaState::Valid)
            };
            assert_eq!(Entry::decode(&entry.encode()), entry);
        }
    }

    #[test]
    fn an_entry_has_the_bootloaders_byte_layout() {
        let bytes = Entry::new(1, OtaState::Valid).encode();
        let mut expected = [0xFF; ENTRY_LEN];
        expected[0..4].copy_from_slice(&[1, 0, 0, 0]);
        expected[24..28].copy_from_slice(&[2, 0, 0, 0]);
        expected[28..32].copy_from_slice(&0x4743_989Au32.to_le_bytes());
        assert_eq!(bytes, expected);
        assert_eq!(Entry::decode(&bytes), Entry::new(1, OtaState::Valid));
    }

    #[test]
    fn an_erased_sector_decodes_as_not_bootable() {
        let entry = Entry::decode(&[0xFF; ENTRY_LEN]);
        assert_eq!(entry, ERASED_ENTRY);
        assert!(!entry.is_bootable());
    }

    #[test]
    fn a_corrupt_crc_or_a_rejected_state_is_not_bootable() {
        let mut bytes = Entry::new(3, OtaState::Valid).encode();
        bytes[28] ^= 1;
        assert!(!Entry::decode(&bytes).is_bootable());
        for state in [OtaState::Invalid, OtaState::Aborted] {
            assert!(!Entry::new(3, state).is_bootable());
        }
        for state in [
            OtaState::New,
            OtaState::PendingVerify,
            OtaState::Valid,
            OtaState::Undefined(7),
        ] {
            assert!(Entry::new(3, state).is_bootable());
        }
    }

    #[test]
    fn sequence_numbers_alternate_between_the_slots() {
        assert_eq!(Slot::of_seq(1), Slot::Ota0);
        assert_eq!(Slot::of_seq(2), Slot::Ota1);
        assert_eq!(Slot::of_seq(3), Slot::Ota0);
        assert_eq!(Slot::of_seq(u32::MAX - 1), Slot::Ota1);
    }

    #[test]
    fn the_higher_bootable_sequence_number_is_active_and_a_broken_copy_is_ignored() {
        let data = OtaData {
            sectors: [
                Entry::new(4, OtaState::Valid),
                Entry::new(5, OtaState::Valid),
            ],
        };
        assert_eq!(data.active_sector(), Some(1));
        let aborted = OtaData {
            sectors: [
                Entry::new(4, OtaState::Valid),
                Entry::new(5, OtaState::Aborted),
            ],
        };
        assert_eq!(aborted.active_sector(), Some(0));
        let one_erased = OtaData {
            sectors: [ERASED_ENTRY, Entry::new(2, OtaState::Valid)],
        };
        assert_eq!(one_erased.active_sector(), Some(1));
        assert_eq!(OtaData::erased().active_sector(), None);
    }

    #[test]
    fn activation_writes_the_next_sequence_number_of_the_target_into_the_inactive_sector() {
        let data = OtaData {
            sectors: [Entry::new(4, OtaState::Valid), ERASED_ENTRY],
        };
        // seq 4 runs ota_1; the next for ota_0 is 5.
        let write = data.activate(Slot::Ota0).unwrap();
        assert_eq!(
            write,
            SectorWrite {
                sector: 1,
                entry: Entry::new(5, OtaState::New)
            }
        );
        // Past an older entry of the same slot, the number keeps the parity.
        let older = OtaData {
            sectors: [
                Entry::new(4, OtaState::Valid),
                Entry::new(3, OtaState::Valid),
            ],
        };
        assert_eq!(
            older.activate(Slot::Ota0),
            Ok(SectorWrite {
                sector: 1,
                entry: Entry::new(5, OtaState::New)
            })
        );
        // Without an entry for the running image (blank otadata, or only the other
        // slot's), nothing would boot it again after a failed trial: refused.
        assert_eq!(
            OtaData::erased().activate(Slot::Ota1),
            Err(OtaDataError::NoEntryForSlot)
        );
        let other_only = OtaData {
            sectors: [Entry::new(2, OtaState::Valid), ERASED_ENTRY],
        };
        assert_eq!(
            other_only.activate(Slot::Ota1),
            Err(OtaDataError::NoEntryForSlot)
        );
    }

    #[test]
    fn activation_refuses_to_wrap_the_sequence_number() {
        let data = OtaData {
            sectors: [Entry::new(u32::MAX - 1, OtaState::Valid), ERASED_ENTRY],
        };
        // u32::MAX - 1 names ota_1; the next number for ota_0 would be the erased value.
        assert_eq!(
            data.activate(Slot::Ota0),
            Err(OtaDataError::SequenceExhausted)
        );
    }

    #[test]
    fn a_state_change_rewrites_the_entry_that_names_the_running_slot() {
        let data = OtaData {
            sectors: [Entry::new(4, OtaState::Valid), Entry::new(5, OtaState::New)],
        };
        assert_eq!(
            data.set_state(Slot::Ota0, OtaState::Aborted),
            Ok(SectorWrite {
                sector: 1,
                entry: Entry::new(5, OtaState::Aborted)
            })
        );
        assert_eq!(
            OtaData::erased().set_state(Slot::Ota0, OtaState::Valid),
            Err(OtaDataError::NoEntryForSlot)
        );
    }

    #[test]
    fn activation_after_a_refused_image_keeps_the_running_images_entry() {
        // ota_1's image was activated ({2, New}) and refused by the bootloader, which
        // fell back to ota_0: its entry in sector 0 is the one that boots it.
        let data = OtaData {
            sectors: [Entry::new(1, OtaState::Valid), Entry::new(2, OtaState::New)],
        };
        let write = data.activate(Slot::Ota1).unwrap();
        assert_ne!(
            write.sector, 0,
            "the running image's entry would be overwritten"
        );
        assert_eq!(
            write,
            SectorWrite {
                sector: 1,
                entry: Entry::new(4, OtaState::New)
            }
        );
    }
}
