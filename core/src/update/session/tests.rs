use super::*;
use crate::can::update::UpdateCommand as C;
use crate::update::image::synthetic_image;
use std::vec::Vec as StdVec;

const PROJECT: &str = "base-controller";
const SID: u8 = 0x5A;
const AT_REST: MotionGate = MotionGate {
    at_standstill: true,
    brakes_applied: true,
    control_active: false,
};

fn params() -> Params<'static> {
    Params {
        chip: Chip::Esp32c3,
        project: PROJECT,
        running_version: "0.2.0",
        running_slot: 0,
        slot_len: 0x1F_0000,
        trial_deadline_ms: 60_000,
        trust: Trust::Development,
        running_security_version: 0,
    }
}

fn at(ms: u64) -> Timestamp {
    Timestamp::from_millis(ms)
}

fn image(version: &str) -> StdVec<u8> {
    // Three windows and a bit: the last window is short.
    let payload: StdVec<u8> = (0..3 * WINDOW_LEN + 100)
        .map(|i| (i * 7 + 3) as u8)
        .collect();
    synthetic_image(Chip::Esp32c3, PROJECT, version, &payload)
}

/// A PC side driving the updater, and a flash that records what was written where.
struct Bench {
    params: Params<'static>,
    updater: Updater,
    now: u64,
    slot: StdVec<u8>,
    written: StdVec<u32>,
    flash_fails: bool,
}

impl Bench {
    fn new() -> Self {
        Self::with(params())
    }

    fn with(params: Params<'static>) -> Self {
        Self {
            params,
            updater: Updater::idle(),
            now: 0,
            slot: std::vec![0xFF; 0x1F_0000],
            written: StdVec::new(),
            flash_fails: false,
        }
    }

    /// One event; a flash operation it asks for is done at once, as the update task does.
    fn step(&mut self, event: Event) -> StdVec<UpdateReply> {
        self.now += 1;
        let mut effects = self.updater.step(at(self.now), event, &self.params);
        let mut replies: StdVec<UpdateReply> = effects.replies.iter().copied().collect();
        while let Some(op) = effects.flash.take() {
            if let FlashOp::WriteWindow { offset } = op {
                let window = self.updater.window().to_vec();
                let at = offset as usize;
                self.slot[at..at + window.len()].copy_from_slice(&window);
                self.written.push(offset);
            }
            effects = self.updater.step(
                at(self.now),
                Event::FlashDone(!self.flash_fails),
                &self.params,
            );
            replies.extend(effects.replies.iter().copied());
        }
        replies
    }

    fn command(&mut self, command: UpdateCommand) -> StdVec<UpdateReply> {
        self.step(Event::Command(command, AT_REST))
    }

    fn begin(&mut self, image: &[u8], flags: BeginFlags) -> StdVec<UpdateReply> {
        let mut replies = self.command(C::Begin {
            session: SID,
            size: image.len() as u32,
            flags,
        });
        let digest = Sha256::digest(image);
        for part in 0..DIGEST_PARTS {
            let at = usize::from(part) * 4;
            replies.extend(self.command(C::Digest {
                session: SID,
                part,
                bytes: digest[at..at + 4].try_into().unwrap(),
            }));
        }
        replies
    }

    fn frames(bytes: &[u8]) -> StdVec<DataFrame> {
        bytes
            .chunks(DATA_BYTES)
            .enumerate()
            .map(|(i, chunk)| {
                let mut data = [0; DATA_BYTES];
                data[..chunk.len()].copy_from_slice(chunk);
                DataFrame {
                    seq: i as u8,
                    bytes: data,
                }
            })
            .collect()
    }

    fn window(&mut self, image: &[u8], index: u16) -> StdVec<UpdateReply> {
        let start = usize::from(index) * WINDOW_LEN;
        let bytes = &image[start..start + window_len(image.len() as u32, index)];
        let mut replies = self.command(C::Window {
            session: SID,
            index,
            crc: window_crc(bytes),
        });
        for frame in Self::frames(bytes) {
            replies.extend(self.step(Event::Data(frame)));
        }
        replies
    }

    fn transfer(&mut self, image: &[u8]) -> StdVec<UpdateReply> {
        let mut replies = StdVec::new();
        for index in 0..window_count(image.len() as u32) {
            replies.extend(self.window(image, index));
        }
        replies
    }
}

fn refused(error: UpdateError) -> impl Fn(&UpdateReply) -> bool {
    move |reply| matches!(reply, UpdateReply::Refused { error: e, .. } if *e == error)
}

fn done(step: Step) -> UpdateReply {
    UpdateReply::Done { session: SID, step }
}

#[test]
fn a_whole_update_writes_every_window_once_then_activates() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    assert_eq!(
        bench.begin(&image, BeginFlags::default()),
        [done(Step::Begun)]
    );
    assert!(bench.updater.locks_motion());
    let replies = bench.transfer(&image);
    let windows = window_count(image.len() as u32);
    let written: StdVec<_> = replies
        .iter()
        .filter(|reply| matches!(reply, UpdateReply::Written { .. }))
        .collect();
    assert_eq!(written.len(), usize::from(windows));
    assert!(
        !replies
            .iter()
            .any(|r| matches!(r, UpdateReply::Refused { .. }))
    );
    // READY at the window's start and after every 12 frames of a 4 KiB window (586
    // frames), each naming the next frame it expects.
    let readies: StdVec<u16> = replies
        .iter()
        .filter_map(|r| match r {
            UpdateReply::Ready {
                window: 0, next, ..
            } => Some(*next),
            _ => None,
        })
        .collect();
    assert_eq!(
        readies,
        (0..=585 / 12).map(|n| n * 12).collect::<StdVec<_>>()
    );
    assert_eq!(&bench.slot[..image.len()], &image[..]);
    assert_eq!(
        bench.written,
        (0..u32::from(windows))
            .map(|i| i * 4096)
            .collect::<StdVec<_>>()
    );
    assert_eq!(
        bench.command(C::Finish { session: SID }),
        [done(Step::Finished)]
    );
    let mut effects = bench.updater.step(
        at(100),
        Event::Command(C::Activate { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Activate { session: SID }));
    effects = bench
        .updater
        .step(at(101), Event::FlashDone(true), &params());
    assert_eq!(effects.replies.as_slice(), [done(Step::Activated)]);
    assert!(effects.reset);
}

#[test]
fn begin_needs_a_standing_braked_base_and_no_control_source() {
    let image = image("0.3.0");
    let cases = [
        (
            MotionGate {
                at_standstill: false,
                ..AT_REST
            },
            UpdateError::NotAtRest,
        ),
        (
            MotionGate {
                brakes_applied: false,
                ..AT_REST
            },
            UpdateError::NotAtRest,
        ),
        (
            MotionGate {
                control_active: true,
                ..AT_REST
            },
            UpdateError::ControlActive,
        ),
    ];
    for (gate, error) in cases {
        let mut bench = Bench::new();
        let replies = bench.step(Event::Command(
            C::Begin {
                session: SID,
                size: image.len() as u32,
                flags: BeginFlags::default(),
            },
            gate,
        ));
        assert!(replies.iter().any(refused(error)), "{gate:?}: {replies:?}");
        assert!(!bench.updater.locks_motion(), "{gate:?}");
    }
}

#[test]
fn a_second_pc_is_refused_busy_and_cannot_touch_the_running_session() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    let other = SID + 1;
    let intruders = [
        C::Begin {
            session: other,
            size: 1000,
            flags: BeginFlags::default(),
        },
        C::Window {
            session: other,
            index: 0,
            crc: 0,
        },
        C::Abort { session: other },
        C::Finish { session: other },
    ];
    for command in intruders {
        let replies = bench.command(command);
        assert!(
            replies.iter().any(refused(UpdateError::Busy)),
            "{command:?}"
        );
    }
    // The session carries on undisturbed.
    bench.transfer(&image);
    assert_eq!(
        bench.command(C::Finish { session: SID }),
        [done(Step::Finished)]
    );
}

#[test]
fn a_corrupted_window_is_refused_and_written_only_when_resent_intact() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    bench.window(&image, 0);
    // Window 1 with a flipped byte on the wire.
    let mut corrupt = image.clone();
    corrupt[WINDOW_LEN + 10] ^= 0x40;
    let start = WINDOW_LEN;
    let crc = window_crc(&image[start..start + WINDOW_LEN]);
    let mut replies = bench.command(C::Window {
        session: SID,
        index: 1,
        crc,
    });
    for frame in Bench::frames(&corrupt[start..start + WINDOW_LEN]) {
        replies.extend(bench.step(Event::Data(frame)));
    }
    assert!(replies.iter().any(refused(UpdateError::BadCrc)));
    assert_eq!(bench.written, [0]);
    // Resent intact: written.
    let replies = bench.window(&image, 1);
    assert!(replies.contains(&UpdateReply::Written {
        session: SID,
        window: 1
    }));
    assert_eq!(bench.written, [0, 4096]);
}

#[test]
fn lost_duplicate_and_early_frames_each_get_a_defined_answer() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    let bytes = &image[..WINDOW_LEN];
    let frames = Bench::frames(bytes);
    bench.command(C::Window {
        session: SID,
        index: 0,
        crc: window_crc(bytes),
    });
    for frame in &frames[..5] {
        assert!(bench.step(Event::Data(*frame)).is_empty());
    }
    // A duplicate: dropped, answered once.
    let replies = bench.step(Event::Data(frames[4]));
    assert!(
        replies.iter().any(refused(UpdateError::Duplicate)),
        "{replies:?}"
    );
    assert!(bench.step(Event::Data(frames[3])).is_empty());
    // Frame 5 lost: 6 is out of order, answered once with READY from 5.
    let replies = bench.step(Event::Data(frames[6]));
    assert!(replies.iter().any(refused(UpdateError::OutOfOrder)));
    assert!(replies.contains(&UpdateReply::Ready {
        session: SID,
        window: 0,
        next: 5
    }));
    assert!(bench.step(Event::Data(frames[7])).is_empty());
    // The PC goes back to 5 and completes the window.
    let mut replies = StdVec::new();
    for frame in &frames[5..] {
        replies.extend(bench.step(Event::Data(*frame)));
    }
    assert!(replies.contains(&UpdateReply::Written {
        session: SID,
        window: 0
    }));
    assert_eq!(&bench.slot[..WINDOW_LEN], bytes);
}

#[test]
fn frames_after_an_abort_or_without_a_session_are_refused() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    let frame = Bench::frames(&image[..7])[0];
    let replies = bench.step(Event::Data(frame));
    assert!(replies.iter().any(refused(UpdateError::NoSession)));
    bench.begin(&image, BeginFlags::default());
    // Data before any WINDOW.
    let replies = bench.step(Event::Data(frame));
    assert!(replies.iter().any(refused(UpdateError::WrongWindow)));
    assert_eq!(
        bench.command(C::Abort { session: SID }),
        [done(Step::Aborted)]
    );
    assert!(!bench.updater.locks_motion());
    let replies = bench.step(Event::Data(frame));
    assert!(replies.iter().any(refused(UpdateError::NoSession)));
    let replies = bench.command(C::Window {
        session: SID,
        index: 0,
        crc: 0,
    });
    assert!(replies.iter().any(refused(UpdateError::NoSession)));
    assert!(bench.written.is_empty());
}

#[test]
fn windows_out_of_turn_are_refused_and_a_lost_written_reply_is_repeated() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    let replies = bench.command(C::Window {
        session: SID,
        index: 2,
        crc: 0,
    });
    assert!(replies.iter().any(refused(UpdateError::WrongWindow)));
    bench.window(&image, 0);
    let replies = bench.command(C::Window {
        session: SID,
        index: 0,
        crc: 0,
    });
    assert_eq!(
        replies,
        [UpdateReply::Written {
            session: SID,
            window: 0
        }]
    );
    assert_eq!(bench.written, [0]);
}

/// A WINDOW for the last index a frame can name (0xFFFF) is out of turn like any
/// other: refused with WrongWindow, never an overflow of the "repeat WRITTEN" check.
#[test]
fn a_window_index_of_0xffff_is_refused_as_out_of_turn() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    for written in 0..2 {
        let replies = bench.command(C::Window {
            session: SID,
            index: u16::MAX,
            crc: 0,
        });
        assert_eq!(
            replies,
            [UpdateReply::Refused {
                opcode: 0x04,
                error: UpdateError::WrongWindow,
                detail: 0,
                session: SID,
            }],
            "after {written} windows written"
        );
        bench.window(&image, written);
    }
    assert_eq!(bench.written, [0, WINDOW_LEN as u32]);
}

#[test]
fn image_checks_refuse_before_any_write() {
    let other_chip = synthetic_image(Chip::Esp32c6, PROJECT, "0.3.0", &[0; 5000]);
    let other_project = synthetic_image(Chip::Esp32c3, "other", "0.3.0", &[0; 5000]);
    let cases: [(StdVec<u8>, BeginFlags, UpdateError); 5] = [
        (other_chip, BeginFlags::default(), UpdateError::BadImage),
        (other_project, BeginFlags::default(), UpdateError::BadImage),
        (
            image("0.1.9"),
            BeginFlags::default(),
            UpdateError::Downgrade,
        ),
        (
            image("0.2.0"),
            BeginFlags::default(),
            UpdateError::SameVersion,
        ),
        (
            image("0.2.0"),
            BeginFlags {
                force: false,
                allow_downgrade: true,
            },
            UpdateError::SameVersion,
        ),
    ];
    for (image, flags, error) in cases {
        let mut bench = Bench::new();
        bench.begin(&image, flags);
        let replies = bench.window(&image, 0);
        assert!(replies.iter().any(refused(error)), "{error:?}: {replies:?}");
        assert!(bench.written.is_empty(), "{error:?}");
        assert!(!bench.updater.locks_motion());
    }
    let allowed = [
        (
            image("0.1.9"),
            BeginFlags {
                force: false,
                allow_downgrade: true,
            },
        ),
        (
            image("0.2.0"),
            BeginFlags {
                force: true,
                allow_downgrade: false,
            },
        ),
    ];
    for (image, flags) in allowed {
        let mut bench = Bench::new();
        bench.begin(&image, flags);
        bench.window(&image, 0);
        assert_eq!(bench.written, [0], "{flags:?}");
    }
}

#[test]
fn an_image_larger_than_the_slot_is_refused_at_begin() {
    let mut bench = Bench::new();
    let replies = bench.command(C::Begin {
        session: SID,
        size: 0x1F_0001,
        flags: BeginFlags::default(),
    });
    assert!(replies.iter().any(refused(UpdateError::TooLarge)));
    assert!(!bench.updater.locks_motion());
}

#[test]
fn finish_compares_the_sha256_and_refuses_an_incomplete_transfer() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    bench.window(&image, 0);
    let replies = bench.command(C::Finish { session: SID });
    assert!(replies.iter().any(refused(UpdateError::Incomplete)));
    let replies = bench.command(C::Activate { session: SID });
    assert!(replies.iter().any(refused(UpdateError::NotFinished)));
    // The rest, with a wrong digest part announced.
    for index in 1..window_count(image.len() as u32) {
        bench.window(&image, index);
    }
    bench.command(C::Digest {
        session: SID,
        part: 7,
        bytes: [0; 4],
    });
    let replies = bench.command(C::Finish { session: SID });
    assert!(replies.iter().any(refused(UpdateError::DigestMismatch)));
    assert!(!bench.updater.locks_motion());
}

#[test]
fn a_silent_pc_ends_the_session_after_ten_seconds() {
    let image = image("0.3.0");
    let mut updater = Updater::idle();
    updater.step(
        at(0),
        Event::Command(
            C::Begin {
                session: SID,
                size: image.len() as u32,
                flags: BeginFlags::default(),
            },
            AT_REST,
        ),
        &params(),
    );
    assert!(
        updater
            .step(at(9_999), Event::Tick, &params())
            .replies
            .is_empty()
    );
    assert!(updater.locks_motion());
    let effects = updater.step(at(10_000), Event::Tick, &params());
    assert!(effects.replies.iter().any(refused(UpdateError::TimedOut)));
    assert!(!updater.locks_motion());
}

#[test]
fn a_flash_failure_ends_the_session_with_a_defined_error() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.flash_fails = true;
    bench.begin(&image, BeginFlags::default());
    let replies = bench.window(&image, 0);
    assert!(replies.iter().any(refused(UpdateError::FlashFailed)));
    assert!(!bench.updater.locks_motion());
}

#[test]
fn an_image_on_trial_locks_motion_until_confirmed_and_rejects_itself_at_the_deadline() {
    let mut updater = Updater::on_trial(at(0), Some(SID), &params());
    assert!(updater.locks_motion());
    assert_eq!(updater.phase(), Phase::OnTrial);
    let begin = Event::Command(
        C::Begin {
            session: SID,
            size: 5000,
            flags: BeginFlags::default(),
        },
        AT_REST,
    );
    let effects = updater.step(at(1), begin, &params());
    assert!(effects.replies.iter().any(refused(UpdateError::OnTrial)));
    let effects = updater.step(
        at(2),
        Event::Command(C::Confirm { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Confirm));
    let effects = updater.step(at(3), Event::FlashDone(true), &params());
    assert!(matches!(
        effects.replies.as_slice(),
        [UpdateReply::Done {
            step: Step::Confirmed,
            ..
        }]
    ));
    assert!(!updater.locks_motion());
    let effects = updater.step(
        at(4),
        Event::Command(C::Confirm { session: SID }, AT_REST),
        &params(),
    );
    assert!(effects.replies.iter().any(refused(UpdateError::NotOnTrial)));

    let mut unconfirmed = Updater::on_trial(at(0), Some(SID), &params());
    assert_eq!(
        unconfirmed.step(at(59_999), Event::Tick, &params()).flash,
        None
    );
    let effects = unconfirmed.step(at(60_000), Event::Tick, &params());
    assert_eq!(effects.flash, Some(FlashOp::Reject));
    let effects = unconfirmed.step(at(60_001), Event::FlashDone(true), &params());
    assert!(effects.reset);
}

#[test]
fn rollback_rejects_the_trial_image_and_resets() {
    let mut updater = Updater::on_trial(at(0), Some(SID), &params());
    let effects = updater.step(
        at(1),
        Event::Command(C::Rollback { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Reject));
    let effects = updater.step(at(2), Event::FlashDone(true), &params());
    assert!(effects.reset);
    let mut confirmed = Updater::idle();
    let effects = confirmed.step(
        at(1),
        Event::Command(C::Rollback { session: SID }, AT_REST),
        &params(),
    );
    assert!(effects.replies.iter().any(refused(UpdateError::NotOnTrial)));
    assert_eq!(effects.flash, None);
}

/// A failed rejection write still resets (the image armed itself at start), and the
/// PC hears that the write failed.
#[test]
fn a_failed_rollback_write_is_reported_and_still_resets() {
    let mut updater = Updater::on_trial(at(0), Some(SID), &params());
    updater.step(
        at(1),
        Event::Command(C::Rollback { session: SID }, AT_REST),
        &params(),
    );
    let effects = updater.step(at(2), Event::FlashDone(false), &params());
    assert!(effects.reset);
    assert!(
        effects
            .replies
            .iter()
            .any(refused(UpdateError::FlashFailed)),
        "{effects:?}"
    );
    let mut written = Updater::on_trial(at(0), Some(SID), &params());
    written.step(
        at(1),
        Event::Command(C::Rollback { session: SID }, AT_REST),
        &params(),
    );
    let effects = written.step(at(2), Event::FlashDone(true), &params());
    assert!(
        !effects
            .replies
            .iter()
            .any(refused(UpdateError::FlashFailed))
    );
}

/// The shortest size BEGIN takes is an image's prefix (header, segment header, app
/// descriptor); one byte less is too short to be an image.
#[test]
fn begin_takes_an_image_the_size_of_its_prefix_and_no_shorter() {
    for (size, refused_too_short) in [
        (image::PREFIX_LEN as u32, false),
        (image::PREFIX_LEN as u32 - 1, true),
    ] {
        let mut bench = Bench::new();
        let replies = bench.command(C::Begin {
            session: SID,
            size,
            flags: BeginFlags::default(),
        });
        let too_short = replies.iter().any(refused(UpdateError::BadImage));
        assert_eq!(too_short, refused_too_short, "{size}: {replies:?}");
    }
}

#[test]
fn a_held_image_stays_locked_without_a_deadline_until_a_person_decides() {
    let mut held = Updater::held(None);
    assert!(held.locks_motion());
    assert_eq!(held.phase(), Phase::OnTrial);
    // Rejecting itself would only start it again: no deadline.
    for ms in [60_000, 3_600_000] {
        assert_eq!(held.step(at(ms), Event::Tick, &params()).flash, None);
        assert!(held.locks_motion());
    }
    // A failed confirm leaves it held; a good one keeps it and lifts the lock.
    held.step(
        at(1),
        Event::Command(C::Confirm { session: SID }, AT_REST),
        &params(),
    );
    let effects = held.step(at(2), Event::FlashDone(false), &params());
    assert!(
        effects
            .replies
            .iter()
            .any(refused(UpdateError::FlashFailed))
    );
    assert!(held.locks_motion());
    assert_eq!(held.step(at(90_000), Event::Tick, &params()).flash, None);
    let effects = held.step(
        at(90_001),
        Event::Command(C::Confirm { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Confirm));
    held.step(at(90_002), Event::FlashDone(true), &params());
    assert!(!held.locks_motion());
    // Or ROLLBACK: the bootloader tries the other slot. A held image whose activating
    // session is known (its arming write failed) is that session's to decide.
    let mut owned = Updater::held(Some(SID));
    let effects = owned.step(
        at(1),
        Event::Command(C::Rollback { session: 0x77 }, AT_REST),
        &params(),
    );
    assert!(
        effects
            .replies
            .iter()
            .any(refused(UpdateError::NotTrialOwner))
    );
    let mut other = Updater::held(None);
    let effects = other.step(
        at(1),
        Event::Command(C::Rollback { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Reject));
    assert!(other.step(at(2), Event::FlashDone(true), &params()).reset);
}

/// A second program on the bus (another basectl, a script) cannot keep or send back an
/// image another session activated; the owner still can, and the deadline still
/// rejects an image nobody confirms.
#[test]
fn only_the_session_that_activated_an_image_decides_about_its_trial() {
    const STRANGER: u8 = 0x77;
    let mut updater = Updater::on_trial(at(0), Some(SID), &params());
    for (ms, command) in [
        (1, C::Confirm { session: STRANGER }),
        (2, C::Rollback { session: STRANGER }),
        // A tool from before the session byte names none.
        (3, C::Confirm { session: 0 }),
        (4, C::Rollback { session: 0 }),
    ] {
        let effects = updater.step(at(ms), Event::Command(command, AT_REST), &params());
        assert_eq!(effects.flash, None, "{command:?}");
        let refusal = UpdateReply::Refused {
            opcode: command.opcode(),
            error: UpdateError::NotTrialOwner,
            detail: 0,
            session: command.session(),
        };
        assert_eq!(effects.replies.as_slice(), [refusal], "{command:?}");
        assert!(updater.locks_motion());
    }
    let effects = updater.step(
        at(5),
        Event::Command(C::Confirm { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Confirm));
    let effects = updater.step(at(6), Event::FlashDone(true), &params());
    assert_eq!(
        effects.replies.as_slice(),
        [UpdateReply::Done {
            session: SID,
            step: Step::Confirmed
        }]
    );

    // A failed confirm write leaves the trial with its owner.
    let mut failed = Updater::on_trial(at(0), Some(SID), &params());
    failed.step(
        at(1),
        Event::Command(C::Confirm { session: SID }, AT_REST),
        &params(),
    );
    failed.step(at(2), Event::FlashDone(false), &params());
    let effects = failed.step(
        at(3),
        Event::Command(C::Rollback { session: STRANGER }, AT_REST),
        &params(),
    );
    assert!(
        effects
            .replies
            .iter()
            .any(refused(UpdateError::NotTrialOwner))
    );

    let mut ignored = Updater::on_trial(at(0), Some(SID), &params());
    ignored.step(
        at(1),
        Event::Command(C::Rollback { session: STRANGER }, AT_REST),
        &params(),
    );
    assert_eq!(
        ignored.step(at(60_000), Event::Tick, &params()).flash,
        Some(FlashOp::Reject)
    );
}

/// Where the boot cannot know who activated the image (a power cut between the
/// activation and the start), any program may decide, as before the session was kept.
#[test]
fn a_trial_whose_owner_is_unknown_takes_anyones_decision() {
    for command in [C::Confirm { session: 0 }, C::Rollback { session: 0x77 }] {
        let mut updater = Updater::on_trial(at(0), None, &params());
        let effects = updater.step(at(1), Event::Command(command, AT_REST), &params());
        assert!(effects.flash.is_some(), "{command:?}");
        let effects = updater.step(at(2), Event::FlashDone(true), &params());
        assert!(
            matches!(effects.replies.as_slice(), [UpdateReply::Done { session, .. }] if *session == command.session()),
            "{effects:?}"
        );
    }
}

#[test]
fn query_reports_the_phase_and_the_running_version() {
    let mut updater = Updater::idle();
    let effects = updater.step(at(1), Event::Command(C::Query, AT_REST), &params());
    assert_eq!(effects.replies.len(), 1 + usize::from(VERSION_CHUNKS));
    let mut version = StdVec::new();
    for reply in &effects.replies[1..] {
        if let UpdateReply::Version { text, .. } = reply {
            version.extend_from_slice(text);
        }
    }
    assert!(version.starts_with(b"0.2.0\0"));
}

#[test]
fn release_numbers_compare_as_versions() {
    assert_eq!(release("0.3.1"), Some((0, 3, 1)));
    assert_eq!(release("0.3.1-sim-panic"), Some((0, 3, 1)));
    assert_eq!(release("1.2"), None);
    assert_eq!(release("abc"), None);
    assert!(release("0.10.0") > release("0.9.9"));
}

#[test]
fn between_builds_of_one_release_the_build_number_decides() {
    assert_eq!(build_number("0.1.0+412.g7efef4d"), Some(412));
    assert_eq!(build_number("0.1.0+412.g7efef4d.dirty"), Some(412));
    assert_eq!(build_number("0.1.0+unknown"), None);
    assert_eq!(build_number("0.1.0"), None);
    assert!(is_older("0.1.0+398.gabcdef0", "0.1.0+412.g7efef4d"));
    assert!(!is_older("0.1.0+412.g7efef4d", "0.1.0+398.gabcdef0"));
    assert!(!is_older("0.1.0+412.g7efef4d.dirty", "0.1.0+412.g7efef4d"));
    // The release decides first, whatever the build numbers say.
    assert!(is_older("0.1.9+900.gaaaaaaa", "0.2.0+1.gbbbbbbb"));
    assert!(!is_older("0.2.0+1.gbbbbbbb", "0.1.9+900.gaaaaaaa"));
    // Without a build number on both sides, builds of one release are not ordered.
    assert!(!is_older("0.1.0", "0.1.0+412.g7efef4d"));
    assert!(!is_older("0.1.0+unknown", "0.1.0+412.g7efef4d"));
    assert!(!is_older("nightly", "0.1.0"));
}

#[test]
fn an_older_build_of_the_running_release_is_a_downgrade() {
    let running = Params {
        running_version: "0.2.0+7.g2222222",
        ..params()
    };
    let window_0 = |version: &str| image(version)[..WINDOW_LEN].to_vec();
    let older = window_0("0.2.0+5.g1111111");
    let allow_downgrade = BeginFlags {
        force: false,
        allow_downgrade: true,
    };
    assert_eq!(
        check_image(&older, BeginFlags::default(), &running).err(),
        Some((UpdateError::Downgrade, 0))
    );
    assert!(check_image(&older, allow_downgrade, &running).is_ok());
    let newer = window_0("0.2.0+9.g3333333");
    assert!(check_image(&newer, BeginFlags::default(), &running).is_ok());
}

#[test]
fn an_abort_while_otadata_is_written_for_activation_is_refused() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    bench.transfer(&image);
    bench.command(C::Finish { session: SID });
    let effects = bench.updater.step(
        at(100),
        Event::Command(C::Activate { session: SID }, AT_REST),
        &params(),
    );
    assert_eq!(effects.flash, Some(FlashOp::Activate { session: SID }));
    // The activation write is under way: an abort cannot undo it.
    let effects = bench.updater.step(
        at(101),
        Event::Command(C::Abort { session: SID }, AT_REST),
        &params(),
    );
    assert!(effects.replies.iter().any(refused(UpdateError::Writing)));
    let effects = bench
        .updater
        .step(at(102), Event::FlashDone(true), &params());
    assert!(effects.reset, "the activated image must be started");
}

#[test]
fn begin_with_the_running_sessions_own_id_is_busy_and_leaves_the_session_as_it_was() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    bench.window(&image, 0);
    bench.window(&image, 1);
    let replies = bench.command(C::Begin {
        session: SID,
        size: image.len() as u32,
        flags: BeginFlags::default(),
    });
    assert!(
        replies.iter().any(refused(UpdateError::Busy)),
        "{replies:?}"
    );
    let state = bench.command(C::Query);
    assert!(
        matches!(
            state[0],
            UpdateReply::State {
                windows_written: 2,
                ..
            }
        ),
        "windows written 2 → {state:?}"
    );
}

/// Whole transfers of images whose window 0 is good but which the bootloader would
/// refuse: FINISH must not answer DONE, so no client can activate them.
#[test]
fn finish_refuses_an_image_the_bootloader_would_refuse() {
    let good = image("0.3.0");
    let mut bad_checksum = good.clone();
    // A byte of the segment's data past window 0: the XOR checksum no longer matches
    // (the appended SHA-256 is over the changed bytes, as a careless tool would make it).
    bad_checksum[2 * WINDOW_LEN] ^= 0x40;
    let checksum_end = good.len() - image::SHA256_LEN;
    let digest = Sha256::digest(&bad_checksum[..checksum_end]);
    bad_checksum[checksum_end..].copy_from_slice(&digest);
    let mut bad_digest = good.clone();
    *bad_digest.last_mut().unwrap() ^= 0x01;
    let truncated = good[..good.len() - 100].to_vec();
    let no_digest = good[..good.len() - image::SHA256_LEN].to_vec();
    for (name, image, detail) in [
        (
            "truncated in the segment",
            &truncated,
            image::ImageError::BadSegments,
        ),
        (
            "bad checksum",
            &bad_checksum,
            image::ImageError::BadChecksum,
        ),
        (
            "bad appended SHA-256",
            &bad_digest,
            image::ImageError::BadDigest,
        ),
        (
            "no appended SHA-256",
            &no_digest,
            image::ImageError::BadDigest,
        ),
    ] {
        let mut bench = Bench::new();
        assert_eq!(
            bench.begin(image, BeginFlags::default()),
            [done(Step::Begun)]
        );
        let replies = bench.transfer(image);
        assert!(
            !replies
                .iter()
                .any(|r| matches!(r, UpdateReply::Refused { .. })),
            "{name}: refused during the transfer: {replies:?}"
        );
        assert_eq!(
            bench.command(C::Finish { session: SID }),
            [UpdateReply::Refused {
                opcode: 0x05,
                error: UpdateError::BadImage,
                detail: detail.code(),
                session: SID,
            }],
            "{name}"
        );
        assert!(!bench.updater.locks_motion(), "{name}: the session ends");
        assert!(
            bench
                .command(C::Activate { session: SID })
                .iter()
                .any(refused(UpdateError::NoSession)),
            "{name}: ACTIVATE after the refusal"
        );
    }
}

/// On the wire, a refusal names the session of the frame it answers (byte 4, after
/// the four bytes every controller sends), so a session's owner can tell another
/// program's refusals from its own.
#[test]
fn refusals_on_the_wire_name_the_session_they_answer() {
    let image = image("0.3.0");
    let mut bench = Bench::new();
    bench.begin(&image, BeginFlags::default());
    let wire = |replies: StdVec<UpdateReply>| -> StdVec<StdVec<u8>> {
        replies.iter().map(|r| r.encode().data().to_vec()).collect()
    };
    // Another program's BEGIN and FINISH, with its own session 0x33.
    let other = bench.command(C::Begin {
        session: 0x33,
        size: 5000,
        flags: BeginFlags::default(),
    });
    assert_eq!(wire(other), [std::vec![0xFF, 0x02, 0x01, 0x00, 0x33]]);
    let other = bench.command(C::Finish { session: 0x33 });
    assert_eq!(wire(other), [std::vec![0xFF, 0x05, 0x01, 0x00, 0x33]]);
    // The owner's own FINISH, too early, and a data frame before any WINDOW: the
    // running session.
    let own = bench.command(C::Finish { session: SID });
    assert_eq!(wire(own), [std::vec![0xFF, 0x05, 0x0F, 0x00, SID]]);
    let data = bench.step(Event::Data(DataFrame {
        seq: 4,
        bytes: [0; DATA_BYTES],
    }));
    assert_eq!(wire(data), [std::vec![0xFF, 0x00, 0x09, 0x04, SID]]);
    // A CONFIRM names its own session, here with nothing on trial.
    bench.command(C::Abort { session: SID });
    let confirm = bench.command(C::Confirm { session: 0x44 });
    assert_eq!(wire(confirm), [std::vec![0xFF, 0x08, 0x11, 0x00, 0x44]]);
}

const OWNER_SECRET: [u8; 32] = [0x0A; 32];

/// A controller built with the owner's key, running security version 2.
fn signed_params() -> Params<'static> {
    let keys: &'static [signature::PublicKey] =
        std::boxed::Box::leak(std::boxed::Box::new([signature::public_key(&OWNER_SECRET)]));
    Params {
        trust: Trust::Keys(keys),
        running_security_version: 2,
        ..params()
    }
}

fn signed_by(image: &[u8], secret: &[u8; 32], flags: u32) -> StdVec<u8> {
    let (len, block) = signature::sign(image, secret, flags).unwrap();
    [&image[..len], &block.to_bytes()[..]].concat()
}

/// BEGIN, every window, FINISH: FINISH's replies.
fn finish_after_transfer(params: Params<'static>, file: &[u8]) -> StdVec<UpdateReply> {
    let mut bench = Bench::with(params);
    assert_eq!(
        bench.begin(file, BeginFlags::default()),
        [done(Step::Begun)]
    );
    let replies = bench.transfer(file);
    assert!(
        !replies
            .iter()
            .any(|r| matches!(r, UpdateReply::Refused { .. })),
        "refused during the transfer: {replies:?}"
    );
    let finish = bench.command(C::Finish { session: SID });
    if finish != [done(Step::Finished)] {
        assert!(!bench.updater.locks_motion(), "a refusal ends the session");
    }
    finish
}

fn refused_at_finish(error: UpdateError, detail: u8) -> StdVec<UpdateReply> {
    std::vec![UpdateReply::Refused {
        opcode: 0x05,
        error,
        detail,
        session: SID,
    }]
}

#[test]
fn a_build_with_a_key_activates_only_images_its_owner_signed() {
    let at_floor = image::with_security_version(image("0.3.0"), 2);
    let stranger = [0x0B; 32];
    let mut forged = signed_by(&at_floor, &OWNER_SECRET, 0);
    let image_len = at_floor.len();
    forged[3 * WINDOW_LEN] ^= 0x01;
    image::reseal(&mut forged[..image_len]);
    for (name, file, expected) in [
        (
            "signed by the owner",
            signed_by(&at_floor, &OWNER_SECRET, 0),
            std::vec![done(Step::Finished)],
        ),
        (
            "unsigned",
            at_floor.clone(),
            refused_at_finish(UpdateError::Untrusted, 1),
        ),
        (
            "signed by another key",
            signed_by(&at_floor, &stranger, 0),
            refused_at_finish(UpdateError::Untrusted, 2),
        ),
        (
            "a byte changed after signing",
            forged,
            refused_at_finish(UpdateError::Untrusted, 3),
        ),
    ] {
        assert_eq!(
            finish_after_transfer(signed_params(), &file),
            expected,
            "{name}"
        );
    }
}

#[test]
fn below_the_security_version_only_a_downgrade_the_owner_signed_activates() {
    let older = image::with_security_version(image("0.3.0"), 1);
    assert_eq!(
        finish_after_transfer(signed_params(), &signed_by(&older, &OWNER_SECRET, 0)),
        refused_at_finish(UpdateError::SecurityDowngrade, 2)
    );
    assert_eq!(
        finish_after_transfer(
            signed_params(),
            &signed_by(&older, &OWNER_SECRET, signature::DOWNGRADE)
        ),
        [done(Step::Finished)]
    );
    let newer = image::with_security_version(image("0.3.0"), 3);
    assert_eq!(
        finish_after_transfer(signed_params(), &signed_by(&newer, &OWNER_SECRET, 0)),
        [done(Step::Finished)]
    );
}

#[test]
fn a_development_build_activates_unsigned_images_of_any_security_version() {
    let older = image::with_security_version(image("0.3.0"), 1);
    let development = Params {
        running_security_version: 2,
        ..params()
    };
    assert_eq!(
        finish_after_transfer(development, &older),
        [done(Step::Finished)]
    );
}

#[test]
fn query_says_whether_signatures_are_required_and_the_security_version() {
    for (params, required) in [(params(), false), (signed_params(), true)] {
        let mut bench = Bench::with(params);
        let state = bench.command(C::Query)[0];
        assert_eq!(
            state,
            UpdateReply::State {
                phase: Phase::Idle,
                session: 0,
                running_slot: 0,
                windows_written: 0,
                signatures_required: required,
                security_version: params.running_security_version as u8,
            }
        );
    }
}
