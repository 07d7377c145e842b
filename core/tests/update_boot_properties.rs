//! The A/B update's promise, over random sequences of updates, power cuts at any flash
//! write, images that panic or never confirm, images the bootloader refuses, and both
//! bootloaders: an image always boots, a new image runs its trial at most once unless
//! it confirmed, and what runs is always the image confirmed last: a confirmed image
//! keeps booting until the next confirmed one. Images that die before their first
//! write, or never write at all, show what only a bootloader with rollback can take
//! back (docs/flashing.md, "What cannot be rolled back").

use base_core::update::boot::{Bootloader, boot};
use base_core::update::otadata::{ERASED_ENTRY, Entry, OtaData, SectorWrite, Slot};
use base_core::update::trial::{StartRole, confirm, on_start, reject};
use proptest::prelude::*;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Behaviour {
    Healthy,
    /// Panics (or hangs until the watchdog) after its arming write.
    PanicsAtBoot,
    /// Panics before its arming write: in `esp_hal::init` or the startup code before
    /// `main`, the only code the firmware runs before it arms.
    PanicsBeforeArming,
    /// Never writes otadata: an image built before the update code existed. It runs
    /// unlocked until the next reset.
    NeverArms,
    NeverConfirms,
    /// Written completely and activated, but the bootloader refuses to load it (built
    /// for another chip or eFuse revision, a header it rejects).
    Refused,
}

#[derive(Debug, Clone, Copy)]
struct Image {
    id: u32,
    /// Passes the bootloader's checks (written completely).
    intact: bool,
    behaviour: Behaviour,
}

#[derive(Debug, Clone, Copy)]
enum Step {
    /// Write an image to the inactive slot and activate it; the power fails at
    /// `cut` (counted over the flash writes of this step and the boots after it).
    Update {
        behaviour: Behaviour,
        cut: Option<u8>,
    },
    /// The power fails while the running image runs, and the boots after it may see
    /// another cut.
    PowerCycle { cut: Option<u8> },
}

/// Where a write is cut.
#[derive(Debug, Clone, Copy)]
enum CutPoint {
    AfterErase,
    MidProgram,
}

struct Robot {
    otadata: OtaData,
    images: [Image; 2],
    bootloader: Bootloader,
    running: Slot,
    next_id: u32,
    /// Per image id: trial runs without a confirm.
    unconfirmed_trial_runs: std::collections::HashMap<u32, u32>,
    confirmed: std::collections::HashSet<u32>,
    /// Counts flash writes; the write whose number equals the cut fails.
    writes_left_before_cut: Option<u8>,
    /// The image whose confirm was written last: the one that must run.
    last_confirmed: u32,
}

/// A write either completes or leaves the sector as a cut leaves it; `true` when it
/// completed.
fn write(robot: &mut Robot, write: SectorWrite, cut_point: CutPoint) -> bool {
    match robot.writes_left_before_cut {
        Some(0) => {
            robot.writes_left_before_cut = None;
            robot.otadata.sectors[write.sector] = match cut_point {
                CutPoint::AfterErase => ERASED_ENTRY,
                // The sequence number is programmed, the CRC after it is not.
                CutPoint::MidProgram => Entry {
                    crc_ok: false,
                    ..write.entry
                },
            };
            false
        }
        ref mut left => {
            if let Some(n) = left {
                *n -= 1;
            }
            robot.otadata = robot.otadata.with(write);
            true
        }
    }
}

impl Robot {
    fn cut_point(&self) -> CutPoint {
        if self.next_id.is_multiple_of(2) {
            CutPoint::AfterErase
        } else {
            CutPoint::MidProgram
        }
    }

    /// Boots until an image runs normally; returns false if nothing boots.
    fn boot_until_running(&mut self) -> bool {
        // A trial that fails resets once more; a handful of resets always settle.
        for _ in 0..8 {
            let outcome = boot(
                &self.otadata,
                [self.images[0].intact, self.images[1].intact],
                self.bootloader,
            );
            let Some(slot) = outcome.started else {
                return false;
            };
            let cut = self.cut_point();
            let mut cut_happened = false;
            for w in outcome.writes {
                if !write(self, w, cut) {
                    cut_happened = true;
                    break;
                }
            }
            if cut_happened {
                continue;
            }
            self.running = slot;
            let image = self.images[slot.index()];
            match image.behaviour {
                // Nothing of it reaches otadata.
                Behaviour::PanicsBeforeArming => continue,
                Behaviour::NeverArms => return true,
                _ => {}
            }
            let start = on_start(&self.otadata, slot);
            // The image's first write (arming a trial, recording itself on blank
            // otadata, setting aside a refused image's entry), cut like any other.
            if let Some(first) = start.write
                && !write(self, first, cut)
            {
                continue;
            }
            let role = start.role;
            if role.on_trial() {
                let runs = self.unconfirmed_trial_runs.entry(image.id).or_default();
                *runs += 1;
                assert!(
                    *runs <= 1 || self.confirmed.contains(&image.id),
                    "image {} ran its trial twice without a confirm",
                    image.id
                );
                match image.behaviour {
                    Behaviour::Healthy => {
                        let w = confirm(&self.otadata, slot).expect("a trial image has an entry");
                        if write(self, w, cut) {
                            self.confirmed.insert(image.id);
                            self.last_confirmed = image.id;
                            return true;
                        }
                        continue;
                    }
                    Behaviour::PanicsAtBoot => continue,
                    Behaviour::NeverConfirms => {
                        let w = reject(&self.otadata, slot).expect("a trial image has an entry");
                        let _ = write(self, w, cut);
                        continue;
                    }
                    Behaviour::Refused => unreachable!("the bootloader never starts it"),
                    Behaviour::PanicsBeforeArming | Behaviour::NeverArms => {
                        unreachable!("it does not get this far")
                    }
                }
            }
            return true;
        }
        false
    }

    fn update(&mut self, behaviour: Behaviour) -> bool {
        // Updates start only from an image that runs normally, never during a trial.
        let target = self.running.other();
        self.next_id += 1;
        // The transfer: a cut during it leaves a partial image and no activation.
        if self.writes_left_before_cut == Some(0) {
            self.writes_left_before_cut = None;
            self.images[target.index()] = Image {
                id: self.next_id,
                intact: false,
                behaviour,
            };
            return false;
        }
        if let Some(n) = &mut self.writes_left_before_cut {
            *n -= 1;
        }
        self.images[target.index()] = Image {
            id: self.next_id,
            intact: behaviour != Behaviour::Refused,
            behaviour,
        };
        let activation = self
            .otadata
            .activate(target)
            .expect("sequence numbers last");
        let cut = self.cut_point();
        write(self, activation, cut)
    }
}

/// The images an update may bring with `bootloader`. One that dies before its arming
/// write only a bootloader with rollback takes back: with espflash's it starts again
/// and again (see the test below), which the property would report as nothing booting.
fn behaviour(bootloader: Bootloader) -> impl Strategy<Value = Behaviour> {
    let mut behaviours = vec![
        Behaviour::Healthy,
        Behaviour::PanicsAtBoot,
        Behaviour::NeverConfirms,
        Behaviour::Refused,
    ];
    if bootloader == Bootloader::Rollback {
        behaviours.push(Behaviour::PanicsBeforeArming);
    }
    proptest::sample::select(behaviours)
}

fn step(bootloader: Bootloader) -> impl Strategy<Value = Step> {
    prop_oneof![
        (behaviour(bootloader), proptest::option::of(0u8..6))
            .prop_map(|(behaviour, cut)| Step::Update { behaviour, cut }),
        proptest::option::of(0u8..4).prop_map(|cut| Step::PowerCycle { cut }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn an_image_always_boots_and_a_trial_never_runs_twice(
        (bootloader, steps) in prop_oneof![Just(Bootloader::Plain), Just(Bootloader::Rollback)]
            .prop_flat_map(|bootloader| {
                (Just(bootloader), proptest::collection::vec(step(bootloader), 1..24))
            }),
    ) {
        // Fresh from USB: otadata erased, our image in ota_0.
        let mut robot = Robot {
            otadata: OtaData::erased(),
            images: [
                Image { id: 0, intact: true, behaviour: Behaviour::Healthy },
                Image { id: u32::MAX, intact: false, behaviour: Behaviour::Healthy },
            ],
            bootloader,
            running: Slot::Ota0,
            next_id: 0,
            unconfirmed_trial_runs: Default::default(),
            confirmed: [0].into_iter().collect(),
            writes_left_before_cut: None,
            last_confirmed: 0,
        };
        prop_assert!(robot.boot_until_running());
        for step in steps {
            match step {
                Step::Update { behaviour, cut } => {
                    robot.writes_left_before_cut = cut;
                    robot.update(behaviour);
                }
                Step::PowerCycle { cut } => robot.writes_left_before_cut = cut,
            }
            let before = robot.images[robot.running.index()].id;
            let was_confirmed = robot.confirmed.contains(&before);
            prop_assert!(robot.boot_until_running(), "nothing boots after {step:?}");
            let now = robot.images[robot.running.index()];
            // A confirmed image that was running keeps running after a plain power
            // cycle: no rollback of a healthy image.
            if matches!(step, Step::PowerCycle { .. }) && was_confirmed {
                prop_assert_eq!(now.id, before, "a confirmed image was rolled back");
            }
            // What runs is the image confirmed last: a new image that did not confirm,
            // whatever stopped it, left the previous one running.
            prop_assert_eq!(
                now.id, robot.last_confirmed,
                "image {} runs, but {} was confirmed last (after {:?}; otadata {:?})",
                now.id, robot.last_confirmed, step, robot.otadata
            );
            // It runs confirmed, with motion unlocked: never as a last resort.
            let role = on_start(&robot.otadata, robot.running).role;
            prop_assert_eq!(role, StartRole::Confirmed, "image {} runs", now.id);
        }
    }
}

#[test]
fn a_healthy_update_without_cuts_runs_the_new_image_confirmed() {
    for bootloader in [Bootloader::Plain, Bootloader::Rollback] {
        let mut robot = Robot {
            otadata: OtaData::erased(),
            images: [
                Image {
                    id: 0,
                    intact: true,
                    behaviour: Behaviour::Healthy,
                },
                Image {
                    id: u32::MAX,
                    intact: false,
                    behaviour: Behaviour::Healthy,
                },
            ],
            bootloader,
            running: Slot::Ota0,
            next_id: 0,
            unconfirmed_trial_runs: Default::default(),
            confirmed: [0].into_iter().collect(),
            writes_left_before_cut: None,
            last_confirmed: 0,
        };
        assert!(robot.boot_until_running());
        assert!(robot.update(Behaviour::Healthy));
        assert!(robot.boot_until_running());
        assert_eq!(robot.running, Slot::Ota1);
        assert!(robot.confirmed.contains(&1));
        // And a panicking one after it is rolled back to the healthy one.
        assert!(robot.update(Behaviour::PanicsAtBoot));
        assert!(robot.boot_until_running());
        assert_eq!(robot.running, Slot::Ota1, "{bootloader:?}");
    }
}

fn fresh_robot(bootloader: Bootloader) -> Robot {
    let mut robot = Robot {
        otadata: OtaData::erased(),
        images: [
            Image {
                id: 0,
                intact: true,
                behaviour: Behaviour::Healthy,
            },
            Image {
                id: u32::MAX,
                intact: false,
                behaviour: Behaviour::Healthy,
            },
        ],
        bootloader,
        running: Slot::Ota0,
        next_id: 0,
        unconfirmed_trial_runs: Default::default(),
        confirmed: [0].into_iter().collect(),
        writes_left_before_cut: None,
        last_confirmed: 0,
    };
    assert!(robot.boot_until_running());
    robot
}

#[test]
fn a_refused_image_then_an_update_that_fails_its_trial_goes_back_to_the_confirmed_image() {
    for bootloader in [Bootloader::Plain, Bootloader::Rollback] {
        for failing in [Behaviour::PanicsAtBoot, Behaviour::NeverConfirms] {
            let mut robot = fresh_robot(bootloader);
            assert!(robot.update(Behaviour::Refused));
            assert!(robot.boot_until_running());
            assert_eq!(robot.images[robot.running.index()].id, 0, "{bootloader:?}");
            assert!(robot.update(failing));
            assert!(robot.boot_until_running());
            assert_eq!(
                (robot.running, robot.images[robot.running.index()].id),
                (Slot::Ota0, 0),
                "{bootloader:?}, {failing:?}: otadata {:?}",
                robot.otadata
            );
            assert_eq!(
                on_start(&robot.otadata, robot.running).role,
                StartRole::Confirmed,
                "{bootloader:?}, {failing:?}"
            );
        }
    }
}

/// The firmware arms first thing after `esp_hal::init`; what dies before that, or an
/// image without the update code, only the rollback bootloader takes back: it marks a
/// new image pending at its first start and gives up on it at the next.
#[test]
fn with_the_rollback_bootloader_an_image_that_never_arms_goes_back_at_the_next_reset() {
    let mut robot = fresh_robot(Bootloader::Rollback);
    assert!(robot.update(Behaviour::PanicsBeforeArming));
    assert!(robot.boot_until_running());
    assert_eq!(robot.images[robot.running.index()].id, 0);
    assert_eq!(
        on_start(&robot.otadata, robot.running).role,
        StartRole::Confirmed
    );

    assert!(robot.update(Behaviour::NeverArms));
    assert!(robot.boot_until_running());
    // It runs once, unlocked (it knows nothing of trials), until a reset.
    assert_eq!(robot.images[robot.running.index()].id, 2);
    assert!(robot.boot_until_running());
    assert_eq!(robot.images[robot.running.index()].id, 0);
    assert_eq!(
        on_start(&robot.otadata, robot.running).role,
        StartRole::Confirmed
    );
}

/// The limit docs/flashing.md states: espflash's bootloader starts the active entry
/// whatever its state, so an image that dies before its arming write starts again at
/// every reset, and one without the update code keeps running. Only USB brings the
/// robot back.
#[test]
fn with_espflashs_bootloader_an_image_that_never_arms_keeps_starting() {
    let mut robot = fresh_robot(Bootloader::Plain);
    assert!(robot.update(Behaviour::PanicsBeforeArming));
    assert!(!robot.boot_until_running(), "it panics at every start");
    assert_eq!(robot.running, Slot::Ota1);

    let mut robot = fresh_robot(Bootloader::Plain);
    assert!(robot.update(Behaviour::NeverArms));
    for _ in 0..3 {
        assert!(robot.boot_until_running());
        assert_eq!(robot.images[robot.running.index()].id, 1);
    }
}
