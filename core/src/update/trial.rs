//! What a starting image does about its own otadata entry: a new image arms itself
//! before anything else can fail, so that a panic, a hang (the watchdog) or a power cut
//! during its trial boots the previous slot; it confirms only after its health checks.
//! The [`ResetRecord`] it leaves for the next boot tells an update's reset from a fault.

use super::otadata::{OtaData, OtaDataError, OtaState, SectorWrite, Slot};
use crate::registers::UpdateReset;

/// Where a starting image stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StartRole {
    /// Its entry is confirmed (`Valid`): run normally.
    Confirmed,
    /// No entry names this slot: flashed over USB with otadata erased. Runs normally;
    /// the bootloader records it on its next start.
    Unrecorded,
    /// A new image on its first start, or one whose entry has a state nobody wrote: write
    /// `arm` first, then prove itself.
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
        // A state nobody meant (a torn write) counts as a new image: the cut falls back
        // to the previous image instead of confirming this one.
        OtaState::New | OtaState::Undefined(_) => StartRole::Trial {
            arm: SectorWrite {
                sector,
                entry: super::otadata::Entry::new(otadata.sectors[sector].seq, OtaState::Aborted),
            },
        },
        OtaState::PendingVerify => StartRole::PendingVerify,
        OtaState::Valid => StartRole::Confirmed,
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

/// What the chip keeps for the next boot across a reset (RTC RAM, which a power-on
/// clears), so that a reset an update causes is reported as such ([`UpdateReset`]), not
/// as a watchdog reset or a panic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetRecord {
    /// Nothing to report (also what a power-on, noise or a torn record reads as).
    #[default]
    Empty,
    /// An image on trial runs from this slot: if the next boot starts the other slot,
    /// the trial failed (a panic, a hang, or its deadline).
    OnTrial(Slot),
    /// Written just before the reset that follows an activation.
    Activation,
    /// Written just before the reset that follows the rejection of an image on trial
    /// (its deadline passed without a confirm, or the PC asked for a rollback).
    Rejection,
}

impl ResetRecord {
    const MAGIC: u32 = 0x7219_A1B0;
    const ON_TRIAL_OTA0: u32 = 1;
    const ON_TRIAL_OTA1: u32 = 2;
    const ACTIVATION: u32 = 3;
    const REJECTION: u32 = 4;

    /// Three words: a magic, the record and its complement, so that zeros, noise and a
    /// write torn by a reset read as [`ResetRecord::Empty`].
    pub const fn encode(self) -> [u32; 3] {
        let value = match self {
            Self::Empty => return [0; 3],
            Self::OnTrial(Slot::Ota0) => Self::ON_TRIAL_OTA0,
            Self::OnTrial(Slot::Ota1) => Self::ON_TRIAL_OTA1,
            Self::Activation => Self::ACTIVATION,
            Self::Rejection => Self::REJECTION,
        };
        [Self::MAGIC, value, !value]
    }

    pub const fn decode(words: [u32; 3]) -> Self {
        let [magic, value, check] = words;
        if magic != Self::MAGIC || check != !value {
            return Self::Empty;
        }
        match value {
            Self::ON_TRIAL_OTA0 => Self::OnTrial(Slot::Ota0),
            Self::ON_TRIAL_OTA1 => Self::OnTrial(Slot::Ota1),
            Self::ACTIVATION => Self::Activation,
            Self::REJECTION => Self::Rejection,
            _ => Self::Empty,
        }
    }
}

/// At boot, after [`on_start`]: how this boot came about, from the record the last run
/// left, and the record this run keeps (an image on trial names its slot, so that a
/// reset that ends its trial without a confirm reads as a failed trial on the next
/// boot; any other image keeps none).
pub fn boot_cause(left: ResetRecord, role: StartRole, running: Slot) -> (UpdateReset, ResetRecord) {
    let cause = match left {
        ResetRecord::Empty => UpdateReset::None,
        ResetRecord::Activation => UpdateReset::Activation,
        ResetRecord::Rejection => UpdateReset::FailedTrial,
        ResetRecord::OnTrial(slot) if slot != running => UpdateReset::FailedTrial,
        // The same slot started again (its trial failed but no other slot boots): the
        // reset was the panic or the watchdog that ended it.
        ResetRecord::OnTrial(_) => UpdateReset::None,
    };
    let keep = if role.on_trial() {
        ResetRecord::OnTrial(running)
    } else {
        ResetRecord::Empty
    };
    (cause, keep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::update::otadata::{ERASED_ENTRY, Entry};

    #[test]
    fn the_reset_record_round_trips_and_rejects_noise() {
        let records = [
            ResetRecord::Empty,
            ResetRecord::OnTrial(Slot::Ota0),
            ResetRecord::OnTrial(Slot::Ota1),
            ResetRecord::Activation,
            ResetRecord::Rejection,
        ];
        for record in records {
            assert_eq!(ResetRecord::decode(record.encode()), record);
        }
        let [magic, value, _] = ResetRecord::Activation.encode();
        // Torn (the check word from before), zeros after a power-on, an unknown value.
        assert_eq!(ResetRecord::decode([magic, value, 0]), ResetRecord::Empty);
        assert_eq!(ResetRecord::decode([0; 3]), ResetRecord::Empty);
        assert_eq!(ResetRecord::decode([magic, 9, !9]), ResetRecord::Empty);
    }

    #[test]
    fn boot_cause_reports_update_resets_and_keeps_the_trial() {
        let armed = StartRole::Trial {
            arm: SectorWrite {
                sector: 1,
                entry: Entry::new(2, OtaState::Aborted),
            },
        };
        let on_trial = |slot| ResetRecord::OnTrial(slot);
        let cases = [
            // what the last run left, the role, the slot, the cause, the record kept
            (
                "power-on",
                ResetRecord::Empty,
                StartRole::Confirmed,
                Slot::Ota0,
                UpdateReset::None,
                ResetRecord::Empty,
            ),
            (
                "activation, new image on trial",
                ResetRecord::Activation,
                armed,
                Slot::Ota1,
                UpdateReset::Activation,
                on_trial(Slot::Ota1),
            ),
            (
                "activation, the bootloader refused the new image",
                ResetRecord::Activation,
                StartRole::Confirmed,
                Slot::Ota0,
                UpdateReset::Activation,
                ResetRecord::Empty,
            ),
            (
                "rejected by its deadline or the PC",
                ResetRecord::Rejection,
                StartRole::Confirmed,
                Slot::Ota0,
                UpdateReset::FailedTrial,
                ResetRecord::Empty,
            ),
            (
                "the trial image panicked or hung",
                on_trial(Slot::Ota1),
                StartRole::Confirmed,
                Slot::Ota0,
                UpdateReset::FailedTrial,
                ResetRecord::Empty,
            ),
            (
                "a confirmed image's later panic",
                on_trial(Slot::Ota1),
                StartRole::Confirmed,
                Slot::Ota1,
                UpdateReset::None,
                ResetRecord::Empty,
            ),
            (
                "no other slot boots",
                on_trial(Slot::Ota1),
                StartRole::LastResort,
                Slot::Ota1,
                UpdateReset::None,
                ResetRecord::Empty,
            ),
            (
                "a rollback bootloader's trial",
                ResetRecord::Activation,
                StartRole::PendingVerify,
                Slot::Ota1,
                UpdateReset::Activation,
                on_trial(Slot::Ota1),
            ),
        ];
        for (what, left, role, running, cause, keep) in cases {
            assert_eq!(boot_cause(left, role, running), (cause, keep), "{what}");
        }
    }

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
            (
                OtaState::Undefined(u32::MAX),
                StartRole::Trial {
                    arm: SectorWrite {
                        sector: 1,
                        entry: Entry::new(2, OtaState::Aborted),
                    },
                },
            ),
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
