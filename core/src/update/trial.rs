//! What a starting image does about its own otadata entry: a new image arms itself
//! before anything else can fail, so that a panic, a hang (the watchdog) or a power cut
//! during its trial boots the previous slot; it confirms only after its health checks
//! ([`healthy`]), and rejects itself when they have not passed by the deadline
//! ([`TrialWatch`]).

use super::otadata::{OtaData, OtaDataError, OtaState, SectorWrite, Slot};
use crate::can::{Mode, Status};
use crate::time::Timestamp;

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

/// How long a new image has to pass its health checks before it rejects itself: long
/// enough for the drives to answer (the controller keeps asking them) and for the PC
/// that sent the update to see the new version; short enough that a robot whose new
/// image cannot prove itself runs the old one again within a minute.
pub const TRIAL_DEADLINE_MS: u64 = 60_000;

/// The trial's timing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrialParams {
    pub deadline_ms: u64,
}

impl TrialParams {
    pub const DEFAULT: Self = Self {
        deadline_ms: TRIAL_DEADLINE_MS,
    };
}

/// What the trial watch learns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TrialEvent {
    /// The controller's status frame went out; `bus_active`: the CAN controller is
    /// error-active after it, so another node acknowledged our frames.
    StatusSent { status: Status, bus_active: bool },
    /// Time passed.
    Tick,
}

/// What the firmware does about its otadata entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TrialEffect {
    /// Nothing yet.
    Wait,
    /// The health checks passed: write [`confirm`].
    Confirm,
    /// The deadline passed without them: write [`reject`] and reset, so the previous
    /// image starts.
    Reject,
}

/// A running image's trial: watching its health until the deadline, then over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TrialWatch {
    Watching {
        since: Timestamp,
    },
    /// Confirmed or rejected: every later event is ignored.
    Ended,
}

impl TrialWatch {
    pub const fn start(now: Timestamp) -> Self {
        Self::Watching { since: now }
    }

    pub fn step(&mut self, now: Timestamp, event: TrialEvent, params: &TrialParams) -> TrialEffect {
        let Self::Watching { since } = *self else {
            return TrialEffect::Wait;
        };
        let effect = match event {
            TrialEvent::StatusSent { status, bus_active } if healthy(&status, bus_active) => {
                TrialEffect::Confirm
            }
            _ if now.millis_since(since) >= params.deadline_ms => TrialEffect::Reject,
            _ => TrialEffect::Wait,
        };
        if effect != TrialEffect::Wait {
            *self = Self::Ended;
        }
        effect
    }
}

/// The health checks of an image on trial, all read from a status frame it sent: the
/// drives answered (the controller left `Starting`, neither drive is silent), CAN is up
/// (the frame went out and the controller stays error-active, so another node
/// acknowledged it), and the register store was read (no flash fault; a first boot's
/// blank store is none).
pub fn healthy(status: &Status, bus_active: bool) -> bool {
    let faults = &status.faults;
    bus_active
        && status.mode != Mode::Starting
        && !faults.left_drive_silent
        && !faults.right_drive_silent
        && !faults.flash
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::Faults;
    use crate::update::otadata::{ERASED_ENTRY, Entry};

    fn standby() -> Status {
        Status {
            mode: Mode::Standby,
            ..Status::default()
        }
    }

    #[test]
    fn a_healthy_status_confirms_and_the_watch_ends() {
        let params = TrialParams::DEFAULT;
        let mut watch = TrialWatch::start(Timestamp::from_millis(0));
        let sent = |status| TrialEvent::StatusSent {
            status,
            bus_active: true,
        };
        let starting = Status {
            mode: Mode::Starting,
            ..Status::default()
        };
        assert_eq!(
            watch.step(Timestamp::from_millis(500), sent(starting), &params),
            TrialEffect::Wait
        );
        assert_eq!(
            watch.step(Timestamp::from_millis(1_500), sent(standby()), &params),
            TrialEffect::Confirm
        );
        assert_eq!(watch, TrialWatch::Ended);
        let late = Timestamp::from_millis(params.deadline_ms + 1);
        assert_eq!(
            watch.step(late, TrialEvent::Tick, &params),
            TrialEffect::Wait
        );
    }

    #[test]
    fn each_failed_check_keeps_the_trial_waiting() {
        let cases = [
            ("CAN not acknowledged", standby(), false),
            (
                "a drive silent",
                Status {
                    faults: Faults {
                        right_drive_silent: true,
                        ..Faults::default()
                    },
                    ..standby()
                },
                true,
            ),
            (
                "the store not read",
                Status {
                    faults: Faults {
                        flash: true,
                        ..Faults::default()
                    },
                    ..standby()
                },
                true,
            ),
        ];
        for (what, status, bus_active) in cases {
            assert!(!healthy(&status, bus_active), "{what}");
            let mut watch = TrialWatch::start(Timestamp::from_millis(0));
            let event = TrialEvent::StatusSent { status, bus_active };
            assert_eq!(
                watch.step(Timestamp::from_millis(1_000), event, &TrialParams::DEFAULT),
                TrialEffect::Wait,
                "{what}"
            );
        }
        assert!(healthy(&standby(), true));
    }

    #[test]
    fn no_healthy_status_by_the_deadline_rejects_once() {
        let params = TrialParams::DEFAULT;
        let mut watch = TrialWatch::start(Timestamp::from_millis(1_000));
        let just_before = Timestamp::from_millis(1_000 + params.deadline_ms - 1);
        assert_eq!(
            watch.step(just_before, TrialEvent::Tick, &params),
            TrialEffect::Wait
        );
        let at = Timestamp::from_millis(1_000 + params.deadline_ms);
        assert_eq!(
            watch.step(at, TrialEvent::Tick, &params),
            TrialEffect::Reject
        );
        // A healthy status after the verdict changes nothing.
        let event = TrialEvent::StatusSent {
            status: standby(),
            bus_active: true,
        };
        assert_eq!(watch.step(at, event, &params), TrialEffect::Wait);
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
