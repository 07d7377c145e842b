//! What a starting image does about its own otadata entry: a new image arms itself
//! before anything else can fail, so that a panic, a hang (the watchdog) or a power cut
//! during its trial boots the previous slot; it confirms only after its health checks.

use super::otadata::{OtaData, OtaDataError, OtaState, SectorWrite, Slot};

/// Where a starting image stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StartRole {
    /// Its entry is confirmed (`Valid`, or written without states): run normally.
    Confirmed,
    /// No entry names this slot: flashed over USB with otadata erased. Runs normally;
    /// the bootloader records it on its next start.
    Unrecorded,
    /// A new image on its first start: write `arm` first, then prove itself.
    Trial { arm: SectorWrite },
    /// Started by a rollback bootloader, which aborts it by itself on the next reset:
    /// prove itself, nothing to arm.
    PendingVerify,
    /// Its entry says the trial failed, yet it was started: no other slot holds an image
    /// that boots. It runs, so that the robot stays reachable over CAN, and reports it.
    LastResort,
}

impl StartRole {
    /// Whether the image runs on trial: control sources are refused until it confirms.
    pub const fn on_trial(self) -> bool {
        matches!(self, Self::Trial { .. } | Self::PendingVerify)
    }
}

/// Decides the role of the image in `running` from the otadata it finds.
pub fn on_start(otadata: &OtaData, running: Slot) -> StartRole {
    let Some(sector) = otadata.entry_of(running) else {
        return StartRole::Unrecorded;
    };
    match otadata.sectors[sector].state {
        OtaState::New => StartRole::Trial {
            arm: SectorWrite {
                sector,
                entry: super::otadata::Entry::new(otadata.sectors[sector].seq, OtaState::Aborted),
            },
        },
        OtaState::PendingVerify => StartRole::PendingVerify,
        OtaState::Valid | OtaState::Undefined(_) => StartRole::Confirmed,
        OtaState::Invalid | OtaState::Aborted => StartRole::LastResort,
    }
}

/// The write that confirms the running image after its health checks.
pub fn confirm(otadata: &OtaData, running: Slot) -> Result<SectorWrite, OtaDataError> {
    otadata.set_state(running, OtaState::Valid)
}

/// The write that rejects the running image (a failed trial, or a rollback asked for):
/// after it and a reset, the previous slot starts.
pub fn reject(otadata: &OtaData, running: Slot) -> Result<SectorWrite, OtaDataError> {
    otadata.set_state(running, OtaState::Invalid)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::update::otadata::{ERASED_ENTRY, Entry};

    fn data(first: Entry, second: Entry) -> OtaData {
        OtaData {
            sectors: [first, second],
        }
    }

    #[test]
    fn each_entry_state_gives_its_role() {
        let cases = [
            (
                OtaState::New,
                StartRole::Trial {
                    arm: SectorWrite {
                        sector: 1,
                        entry: Entry::new(2, OtaState::Aborted),
                    },
                },
            ),
            (OtaState::PendingVerify, StartRole::PendingVerify),
            (OtaState::Valid, StartRole::Confirmed),
            (OtaState::Undefined(u32::MAX), StartRole::Confirmed),
            (OtaState::Aborted, StartRole::LastResort),
            (OtaState::Invalid, StartRole::LastResort),
        ];
        for (state, role) in cases {
            let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, state));
            assert_eq!(on_start(&d, Slot::Ota1), role, "{state:?}");
        }
    }

    #[test]
    fn an_image_no_entry_names_is_unrecorded() {
        assert_eq!(
            on_start(&OtaData::erased(), Slot::Ota0),
            StartRole::Unrecorded
        );
        let d = data(Entry::new(2, OtaState::Valid), ERASED_ENTRY);
        assert_eq!(on_start(&d, Slot::Ota0), StartRole::Unrecorded);
    }

    #[test]
    fn only_trials_refuse_control() {
        assert!(StartRole::PendingVerify.on_trial());
        assert!(!StartRole::Confirmed.on_trial());
        assert!(!StartRole::LastResort.on_trial());
    }

    #[test]
    fn confirm_and_reject_rewrite_the_running_entry() {
        let d = data(
            Entry::new(1, OtaState::Valid),
            Entry::new(2, OtaState::Aborted),
        );
        assert_eq!(
            confirm(&d, Slot::Ota1).unwrap().entry,
            Entry::new(2, OtaState::Valid)
        );
        assert_eq!(
            reject(&d, Slot::Ota1).unwrap().entry,
            Entry::new(2, OtaState::Invalid)
        );
    }
}
