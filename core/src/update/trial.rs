//! What a starting image does about otadata: a new image arms itself before anything
//! else can fail, so that a panic, a hang (the watchdog) or a power cut during its
//! trial boots the previous slot; it confirms only after its health checks. An image
//! that finds the bootloader refused the image activated last sets that entry aside,
//! and one whose own entry says its trial failed runs with motion locked until a
//! person decides. The [`ResetRecord`] it leaves for the next boot tells an update's
//! reset from a fault.

use super::otadata::{Entry, OtaData, OtaDataError, OtaState, SectorWrite, Slot};
use crate::registers::UpdateReset;

/// Where a starting image stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StartRole {
    /// Its entry is confirmed (`Valid`), or otadata is blank (fresh from a USB flash,
    /// the bootloader's own record of the slot not written yet): run normally.
    Confirmed,
    /// A new image on its first start, or one whose entry has a state nobody wrote:
    /// arm first, then prove itself.
    Trial,
    /// Started by a rollback bootloader, which aborts it by itself on the next reset:
    /// prove itself, nothing to arm.
    PendingVerify,
    /// Its entry says the trial failed, or no entry names it while others exist, yet
    /// it was started: no other slot holds an image that boots. It runs, so that the
    /// robot stays reachable over CAN, with motion locked until a person keeps it or
    /// starts another image.
    LastResort,
}

impl StartRole {
    /// Whether the image runs on trial: control sources are refused until it confirms.
    pub const fn on_trial(self) -> bool {
        matches!(self, Self::Trial | Self::PendingVerify)
    }
}

/// What a starting image finds in otadata and does about it, first thing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Start {
    pub role: StartRole,
    /// The one otadata write to make before anything else: the arming of a trial
    /// (`Aborted`), the record of an image on blank otadata (`Valid`, as the
    /// bootloader writes it), or the refused image's entry set aside (`Invalid`).
    pub write: Option<SectorWrite>,
    /// The entry the bootloader follows names the other slot: it refused to load that
    /// image (the one activated last) and started this one instead.
    pub refused_activation: bool,
}

impl Start {
    /// Whether the image runs **held**: nobody confirmed it and nothing would roll it
    /// back. Its trial failed yet it started (no other slot boots), or its arming
    /// write (`written` false) failed, so a failed trial would start it again. It runs
    /// so that the robot stays reachable over CAN, with motion locked and no deadline,
    /// until a person keeps it (CONFIRM) or tries the other slot (ROLLBACK).
    pub const fn held(&self, written: bool) -> bool {
        match self.role {
            StartRole::LastResort => true,
            StartRole::Trial => !written,
            StartRole::Confirmed | StartRole::PendingVerify => false,
        }
    }
}

/// Decides what the image in `running` does with the otadata it finds.
pub fn on_start(otadata: &OtaData, running: Slot) -> Start {
    let active = otadata.active_sector();
    let refused = active.filter(|&sector| otadata.sectors[sector].slot() != running);
    // The refused entry is set aside, so that nothing written into its slot later
    // boots without an activation of its own. It never holds this image's entry.
    let set_aside = refused.map(|sector| SectorWrite {
        sector,
        entry: Entry::new(otadata.sectors[sector].seq, OtaState::Invalid),
    });
    let (role, write) = match otadata.entry_of(running) {
        None if otadata.is_blank() => (
            StartRole::Confirmed,
            Some(SectorWrite {
                sector: 0,
                entry: Entry::new(running.index() as u32 + 1, OtaState::Valid),
            }),
        ),
        None => (StartRole::LastResort, set_aside),
        Some(sector) => match otadata.sectors[sector].state {
            // A state nobody meant (a torn write) counts as a new image: the cut falls
            // back to the previous image instead of confirming this one.
            OtaState::New | OtaState::Undefined(_) => (
                StartRole::Trial,
                Some(SectorWrite {
                    sector,
                    entry: Entry::new(otadata.sectors[sector].seq, OtaState::Aborted),
                }),
            ),
            OtaState::PendingVerify => (StartRole::PendingVerify, None),
            OtaState::Valid => (StartRole::Confirmed, set_aside),
            OtaState::Invalid | OtaState::Aborted => (StartRole::LastResort, set_aside),
        },
    };
    Start {
        role,
        write,
        refused_activation: refused.is_some(),
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
    /// Written just before the reset that follows an activation, with the session
    /// that activated the image (0: unknown), which alone may confirm or roll it back.
    Activation { session: u8 },
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
    /// write torn by a reset read as [`ResetRecord::Empty`]. The record's low byte says
    /// which it is; an activation's session is the byte above (0 in records from
    /// before the session was kept, which read as unknown).
    pub const fn encode(self) -> [u32; 3] {
        let value = match self {
            Self::Empty => return [0; 3],
            Self::OnTrial(Slot::Ota0) => Self::ON_TRIAL_OTA0,
            Self::OnTrial(Slot::Ota1) => Self::ON_TRIAL_OTA1,
            Self::Activation { session } => Self::ACTIVATION | (session as u32) << 8,
            Self::Rejection => Self::REJECTION,
        };
        [Self::MAGIC, value, !value]
    }

    pub const fn decode(words: [u32; 3]) -> Self {
        let [magic, value, check] = words;
        if magic != Self::MAGIC || check != !value {
            return Self::Empty;
        }
        let session = (value >> 8) as u8;
        match value {
            Self::ON_TRIAL_OTA0 => Self::OnTrial(Slot::Ota0),
            Self::ON_TRIAL_OTA1 => Self::OnTrial(Slot::Ota1),
            Self::REJECTION => Self::Rejection,
            _ if value & !0xFF00 == Self::ACTIVATION => Self::Activation { session },
            _ => Self::Empty,
        }
    }
}

/// How this boot came about ([`boot_cause`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BootCause {
    /// Whether an update's reset started this boot, for `boot_info`.
    pub cause: UpdateReset,
    /// The record this run keeps for the next boot.
    pub keep: ResetRecord,
    /// The session that activated the image now on trial (or held after its failed
    /// arming): only its CONFIRM or ROLLBACK counts. `None` where nobody can know it
    /// (the power was cut between the activation and this start, or an image whose
    /// trial failed runs as the last resort): then any program may decide.
    pub trial_owner: Option<u8>,
}

/// At boot, after [`on_start`]: how this boot came about, from the record the last run
/// left and what otadata says, and the record this run keeps (an image on trial names
/// its slot, so that a reset that ends its trial without a confirm reads as a failed
/// trial on the next boot; any other image keeps none).
///
/// The trial's owner needs no place in the kept record: no reset during a trial
/// starts the same image on trial again (it armed itself, or a rollback bootloader
/// aborts it), so the owner is only ever read from the activation's record.
pub fn boot_cause(left: ResetRecord, start: &Start, written: bool, running: Slot) -> BootCause {
    let role = start.role;
    let cause = match left {
        // What matters most now: motion stays locked until a person decides.
        _ if start.held(written) => UpdateReset::Held,
        // Whatever reset came before: the image activated last did not start.
        _ if start.refused_activation => UpdateReset::Refused,
        ResetRecord::Empty => UpdateReset::None,
        ResetRecord::Activation { .. } => UpdateReset::Activation,
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
    let trial_owner = match left {
        ResetRecord::Activation { session } if role.on_trial() => {
            Some(session).filter(|&session| session != 0)
        }
        _ => None,
    };
    BootCause {
        cause,
        keep,
        trial_owner,
    }
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
            ResetRecord::Activation { session: 0 },
            ResetRecord::Activation { session: 0xC3 },
            ResetRecord::Rejection,
        ];
        for record in records {
            assert_eq!(ResetRecord::decode(record.encode()), record);
        }
        let [magic, value, _] = ResetRecord::Activation { session: 1 }.encode();
        // Torn (the check word from before), zeros after a power-on, an unknown value.
        assert_eq!(ResetRecord::decode([magic, value, 0]), ResetRecord::Empty);
        assert_eq!(ResetRecord::decode([0; 3]), ResetRecord::Empty);
        assert_eq!(ResetRecord::decode([magic, 9, !9]), ResetRecord::Empty);
        // A slot record with a session byte, an activation with bits above the session.
        assert_eq!(
            ResetRecord::decode([magic, 0x101, !0x101]),
            ResetRecord::Empty
        );
        assert_eq!(
            ResetRecord::decode([magic, 0x1_0003, !0x1_0003]),
            ResetRecord::Empty
        );
    }

    #[test]
    fn boot_cause_reports_update_resets_and_keeps_the_trial() {
        let start = |role| Start {
            role,
            write: None,
            refused_activation: false,
        };
        let refused = Start {
            role: StartRole::Confirmed,
            write: None,
            refused_activation: true,
        };
        let on_trial = |slot| ResetRecord::OnTrial(slot);
        let activation = ResetRecord::Activation { session: 0x2A };
        let cases = [
            // what the last run left, the start, the slot, the cause, the record kept,
            // the trial's owner
            (
                "power-on",
                ResetRecord::Empty,
                start(StartRole::Confirmed),
                Slot::Ota0,
                UpdateReset::None,
                ResetRecord::Empty,
                None,
            ),
            (
                "activation, new image on trial",
                activation,
                start(StartRole::Trial),
                Slot::Ota1,
                UpdateReset::Activation,
                on_trial(Slot::Ota1),
                Some(0x2A),
            ),
            (
                "activation by a controller that did not keep the session",
                ResetRecord::Activation { session: 0 },
                start(StartRole::Trial),
                Slot::Ota1,
                UpdateReset::Activation,
                on_trial(Slot::Ota1),
                None,
            ),
            (
                "a power cut between the activation and the start",
                ResetRecord::Empty,
                start(StartRole::Trial),
                Slot::Ota1,
                UpdateReset::None,
                on_trial(Slot::Ota1),
                None,
            ),
            (
                "activation, the bootloader refused the new image",
                activation,
                refused,
                Slot::Ota0,
                UpdateReset::Refused,
                ResetRecord::Empty,
                None,
            ),
            (
                "a power cycle after the refusal, before the entry was set aside",
                ResetRecord::Empty,
                refused,
                Slot::Ota0,
                UpdateReset::Refused,
                ResetRecord::Empty,
                None,
            ),
            (
                "rejected by its deadline or the PC",
                ResetRecord::Rejection,
                start(StartRole::Confirmed),
                Slot::Ota0,
                UpdateReset::FailedTrial,
                ResetRecord::Empty,
                None,
            ),
            (
                "the trial image panicked or hung",
                on_trial(Slot::Ota1),
                start(StartRole::Confirmed),
                Slot::Ota0,
                UpdateReset::FailedTrial,
                ResetRecord::Empty,
                None,
            ),
            (
                "a confirmed image's later panic",
                on_trial(Slot::Ota1),
                start(StartRole::Confirmed),
                Slot::Ota1,
                UpdateReset::None,
                ResetRecord::Empty,
                None,
            ),
            (
                "no other slot boots",
                on_trial(Slot::Ota1),
                start(StartRole::LastResort),
                Slot::Ota1,
                UpdateReset::Held,
                ResetRecord::Empty,
                None,
            ),
            (
                "a rollback bootloader's trial",
                activation,
                start(StartRole::PendingVerify),
                Slot::Ota1,
                UpdateReset::Activation,
                on_trial(Slot::Ota1),
                Some(0x2A),
            ),
        ];
        // A new image whose arming write failed runs held, whatever came before; the
        // session that activated it still decides.
        assert_eq!(
            boot_cause(activation, &start(StartRole::Trial), false, Slot::Ota1),
            BootCause {
                cause: UpdateReset::Held,
                keep: on_trial(Slot::Ota1),
                trial_owner: Some(0x2A),
            },
            "arming failed"
        );
        for (what, left, start, running, cause, keep, trial_owner) in cases {
            assert_eq!(
                boot_cause(left, &start, true, running),
                BootCause {
                    cause,
                    keep,
                    trial_owner
                },
                "{what}"
            );
        }
    }

    fn data(first: Entry, second: Entry) -> OtaData {
        OtaData {
            sectors: [first, second],
        }
    }

    #[test]
    fn each_entry_state_gives_its_role() {
        let arm = Some(SectorWrite {
            sector: 1,
            entry: Entry::new(2, OtaState::Aborted),
        });
        // Started although ota_0's entry wins: ota_0's image did not load, and its
        // entry is set aside.
        let set_aside = Some(SectorWrite {
            sector: 0,
            entry: Entry::new(1, OtaState::Invalid),
        });
        let cases = [
            (OtaState::New, StartRole::Trial, arm),
            (OtaState::PendingVerify, StartRole::PendingVerify, None),
            (OtaState::Valid, StartRole::Confirmed, None),
            (OtaState::Undefined(u32::MAX), StartRole::Trial, arm),
            (OtaState::Undefined(7), StartRole::Trial, arm),
            (OtaState::Aborted, StartRole::LastResort, set_aside),
            (OtaState::Invalid, StartRole::LastResort, set_aside),
        ];
        for (state, role, write) in cases {
            let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, state));
            let start = on_start(&d, Slot::Ota1);
            assert_eq!((start.role, start.write), (role, write), "{state:?}");
        }
    }

    #[test]
    fn an_image_on_blank_otadata_records_itself_as_the_bootloader_does() {
        let start = on_start(&OtaData::erased(), Slot::Ota0);
        assert_eq!(start.role, StartRole::Confirmed);
        assert_eq!(
            start.write,
            Some(SectorWrite {
                sector: 0,
                entry: Entry::new(1, OtaState::Valid)
            })
        );
        assert!(!start.refused_activation);
    }

    #[test]
    fn an_image_no_entry_names_while_others_exist_runs_as_last_resort() {
        // Only ota_1's entry, whose image did not load: the bootloader fell back.
        let d = data(Entry::new(2, OtaState::Valid), ERASED_ENTRY);
        let start = on_start(&d, Slot::Ota0);
        assert_eq!(start.role, StartRole::LastResort);
        assert!(start.refused_activation);
        assert_eq!(
            start.write,
            Some(SectorWrite {
                sector: 0,
                entry: Entry::new(2, OtaState::Invalid)
            })
        );
    }

    #[test]
    fn after_a_refused_activation_the_refused_entry_is_set_aside() {
        for refused in [OtaState::New, OtaState::PendingVerify] {
            let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, refused));
            let start = on_start(&d, Slot::Ota0);
            assert_eq!(
                start,
                Start {
                    role: StartRole::Confirmed,
                    write: Some(SectorWrite {
                        sector: 1,
                        entry: Entry::new(2, OtaState::Invalid)
                    }),
                    refused_activation: true,
                },
                "{refused:?}"
            );
            // Once set aside, the next boot is an ordinary one.
            let after = d.with(start.write.unwrap());
            let next = on_start(&after, Slot::Ota0);
            assert_eq!((next.role, next.write), (StartRole::Confirmed, None));
            assert!(!next.refused_activation);
        }
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

    #[test]
    fn a_boot_after_a_refused_activation_does_not_read_as_a_trial() {
        // ota_1 was activated and refused; the bootloader fell back to ota_0.
        let d = data(Entry::new(1, OtaState::Valid), Entry::new(2, OtaState::New));
        let start = on_start(&d, Slot::Ota0);
        let boot = boot_cause(
            ResetRecord::Activation { session: 9 },
            &start,
            true,
            Slot::Ota0,
        );
        assert_eq!(boot.cause, UpdateReset::Refused, "nothing runs on trial");
        assert_eq!(boot.trial_owner, None);
    }
}
