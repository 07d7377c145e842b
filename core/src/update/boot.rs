//! A model of ESP-IDF's second-stage bootloader choosing an app slot from `otadata` and
//! the images, with and without its app-rollback option (espflash ships it without).
//! The simulator boots through it, and the tests use it to prove that every sequence of
//! update steps and power cuts leaves an image that boots.
//!
//! What the bootloader does, in order:
//! 1. With rollback: every entry still `PendingVerify` (booted once, never confirmed)
//!    becomes `Aborted`.
//! 2. When neither entry is usable (both erased, or both rejected), it starts at
//!    `ota_0`; otherwise at the slot of the active entry ([`OtaData::active_sector`]),
//!    and when no entry is active at all (broken CRCs) at `ota_0` as well.
//! 3. With rollback: the chosen entry, if `New`, becomes `PendingVerify`.
//! 4. It loads the first slot whose image passes its checks, trying the chosen slot,
//!    then the slots below it, then the ones above. When it loaded a slot while the
//!    otadata was blank (erased or broken CRCs in both sectors), it records that slot
//!    as `{seq = slot + 1, Valid}` in the first sector.

use heapless::Vec;

use super::otadata::{Entry, OtaData, OtaState, SectorWrite, Slot};

/// Which bootloader is on the chip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bootloader {
    /// espflash's bootloader: no app rollback.
    Plain,
    /// A bootloader built with `CONFIG_BOOTLOADER_APP_ROLLBACK_ENABLE`.
    Rollback,
}

/// What the bootloader did.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BootOutcome {
    /// The slot it started, or `None` when no image passed (the chip resets and tries
    /// again forever: a bricked robot).
    pub started: Option<Slot>,
    /// Its writes to otadata, in order.
    pub writes: Vec<SectorWrite, 3>,
}

/// Boots: `image_ok[slot]` says whether that slot's image passes the bootloader's checks
/// (magic, chip, segments, checksum, appended SHA-256).
pub fn boot(otadata: &OtaData, image_ok: [bool; 2], bootloader: Bootloader) -> BootOutcome {
    let mut data = *otadata;
    let mut writes = Vec::new();
    let mut record = |data: &mut OtaData, write: SectorWrite| {
        *data = data.with(write);
        // At most three writes happen: two aborts and one pending mark, or one record.
        let _ = writes.push(write);
    };

    if bootloader == Bootloader::Rollback {
        for sector in 0..2 {
            let entry = data.sectors[sector];
            if entry.state == OtaState::PendingVerify {
                record(
                    &mut data,
                    SectorWrite {
                        sector,
                        entry: Entry {
                            state: OtaState::Aborted,
                            ..entry
                        },
                    },
                );
            }
        }
    }

    let unusable = |entry: &Entry| entry.seq == u32::MAX || entry.state.is_rejected();
    let blank = |entry: &Entry| entry.seq == u32::MAX || !entry.crc_ok;
    let both_unusable = data.sectors.iter().all(unusable);
    let initial_contents = both_unusable && data.sectors.iter().all(blank);

    let start = if both_unusable {
        Slot::Ota0
    } else if let Some(active) = data.active_sector() {
        let entry = data.sectors[active];
        if bootloader == Bootloader::Rollback && entry.state == OtaState::New {
            record(
                &mut data,
                SectorWrite {
                    sector: active,
                    entry: Entry {
                        state: OtaState::PendingVerify,
                        ..entry
                    },
                },
            );
        }
        entry.slot()
    } else {
        Slot::Ota0
    };

    // The chosen slot, the ones below it, then the ones above.
    let order: [Slot; 2] = match start {
        Slot::Ota0 => [Slot::Ota0, Slot::Ota1],
        Slot::Ota1 => [Slot::Ota1, Slot::Ota0],
    };
    let started = order.into_iter().find(|slot| image_ok[slot.index()]);
    if let (Some(slot), true) = (started, initial_contents) {
        record(
            &mut data,
            SectorWrite {
                sector: 0,
                entry: Entry::new(slot.index() as u32 + 1, OtaState::Valid),
            },
        );
    }
    BootOutcome { started, writes }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::update::otadata::ERASED_ENTRY;

    fn data(first: Entry, second: Entry) -> OtaData {
        OtaData {
            sectors: [first, second],
        }
    }

    #[test]
    fn blank_otadata_boots_ota_0_and_records_it() {
        let outcome = boot(&OtaData::erased(), [true, true], Bootloader::Plain);
        assert_eq!(outcome.started, Some(Slot::Ota0));
        assert_eq!(
            outcome.writes.as_slice(),
            &[SectorWrite {
                sector: 0,
                entry: Entry::new(1, OtaState::Valid)
            }]
        );
    }

    #[test]
    fn blank_otadata_with_a_bad_ota_0_falls_forward_to_ota_1() {
        let outcome = boot(&OtaData::erased(), [false, true], Bootloader::Plain);
        assert_eq!(outcome.started, Some(Slot::Ota1));
        assert_eq!(outcome.writes[0].entry, Entry::new(2, OtaState::Valid));
    }

    #[test]
    fn the_newest_bootable_entry_chooses_the_slot() {
        let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, OtaState::New));
        let plain = boot(&d, [true, true], Bootloader::Plain);
        assert_eq!(plain.started, Some(Slot::Ota1));
        assert!(
            plain.writes.is_empty(),
            "the plain bootloader writes nothing"
        );
    }

    #[test]
    fn an_aborted_trial_falls_back_to_the_previous_entry() {
        let d = data(
            Entry::new(1, OtaState::Valid),
            Entry::new(2, OtaState::Aborted),
        );
        for bootloader in [Bootloader::Plain, Bootloader::Rollback] {
            assert_eq!(boot(&d, [true, true], bootloader).started, Some(Slot::Ota0));
        }
    }

    #[test]
    fn a_rollback_bootloader_marks_new_pending_and_pending_aborted() {
        let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, OtaState::New));
        let first = boot(&d, [true, true], Bootloader::Rollback);
        assert_eq!(first.started, Some(Slot::Ota1));
        assert_eq!(
            first.writes.as_slice(),
            &[SectorWrite {
                sector: 1,
                entry: Entry::new(2, OtaState::PendingVerify)
            }]
        );
        let d = d.with(first.writes[0]);
        let second = boot(&d, [true, true], Bootloader::Rollback);
        assert_eq!(second.started, Some(Slot::Ota0));
        assert_eq!(second.writes[0].entry.state, OtaState::Aborted);
    }

    #[test]
    fn an_image_that_fails_its_checks_is_skipped() {
        let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, OtaState::New));
        assert_eq!(
            boot(&d, [true, false], Bootloader::Plain).started,
            Some(Slot::Ota0)
        );
        assert_eq!(boot(&d, [false, false], Bootloader::Plain).started, None);
    }

    #[test]
    fn a_half_written_sector_is_ignored_and_the_other_decides() {
        let mut broken = Entry::new(3, OtaState::New);
        broken.crc_ok = false;
        let d = data(broken, Entry::new(2, OtaState::Valid));
        assert_eq!(
            boot(&d, [true, true], Bootloader::Plain).started,
            Some(Slot::Ota1)
        );
        let d = data(ERASED_ENTRY, Entry::new(2, OtaState::Valid));
        assert_eq!(
            boot(&d, [true, true], Bootloader::Plain).started,
            Some(Slot::Ota1)
        );
    }
}
