//! Every otadata write the update makes, cut by a power failure in the middle of one of
//! its program operations. A NOR flash programs the words of one operation in no
//! promised order, so a cut may leave any of them programmed and the rest erased: the
//! sweep tries every subset of the words, for every operation. Whatever the cut left,
//! the bootloader (both variants) starts an image, and the image that runs with
//! motion unlocked is one that ran unlocked before the write or would after it: a cut
//! falls back, it never confirms.

use std::ops::Range;

use base_core::update::boot::{Bootloader, boot};
use base_core::update::otadata::{
    ENTRY_LEN, ERASED_ENTRY, Entry, OtaData, OtaState, PROGRAM_ORDER, SectorWrite, Slot,
};
use base_core::update::trial::{StartRole, on_start};

/// The program operations that write an entry into its erased sector, in order.
fn program_order() -> Vec<Range<usize>> {
    PROGRAM_ORDER.to_vec()
}

/// The image that runs with motion unlocked (confirmed) after a boot from `otadata`,
/// with both slots holding images that load; `None` when the image that starts is on
/// trial or otherwise locked. Panics when nothing starts.
fn unlocked(otadata: &OtaData, bootloader: Bootloader) -> Option<Slot> {
    let outcome = boot(otadata, [true, true], bootloader);
    let started = outcome.started.expect("an image starts");
    let mut after = *otadata;
    for write in outcome.writes {
        after = after.with(write);
    }
    match on_start(&after, started).role {
        StartRole::Confirmed => Some(started),
        _ => None,
    }
}

/// What a cut leaves in the sector: the operations before `op` complete, the words of
/// `op` in `programmed` (a bit set over its words) programmed, the rest erased.
fn torn(entry: &Entry, op: usize, programmed: u32) -> Entry {
    let bytes = entry.encode();
    let mut sector = [0xFF; ENTRY_LEN];
    let order = program_order();
    for range in &order[..op] {
        sector[range.clone()].copy_from_slice(&bytes[range.clone()]);
    }
    let range = order[op].clone();
    for (word, at) in range.step_by(4).enumerate() {
        if programmed & (1 << word) != 0 {
            sector[at..at + 4].copy_from_slice(&bytes[at..at + 4]);
        }
    }
    Entry::decode(&sector)
}

/// The writes of an update and its trial, each with the otadata it is made on.
fn writes() -> Vec<(&'static str, OtaData, SectorWrite)> {
    let valid = |seq| Entry::new(seq, OtaState::Valid);
    let data = |a, b| OtaData { sectors: [a, b] };
    let activation = data(valid(1), ERASED_ENTRY);
    let on_trial = data(valid(1), Entry::new(2, OtaState::New));
    let armed = data(valid(1), Entry::new(2, OtaState::Aborted));
    let refused = data(valid(1), Entry::new(2, OtaState::New));
    let first_write = |otadata: &OtaData, running| on_start(otadata, running).write.unwrap();
    vec![
        (
            "record on blank otadata",
            OtaData::erased(),
            first_write(&OtaData::erased(), Slot::Ota0),
        ),
        (
            "a refused image's entry set aside",
            refused,
            first_write(&refused, Slot::Ota0),
        ),
        (
            "activation",
            activation,
            activation.activate(Slot::Ota1).unwrap(),
        ),
        (
            "arming",
            on_trial,
            on_trial.set_state(Slot::Ota1, OtaState::Aborted).unwrap(),
        ),
        (
            "confirm",
            armed,
            armed.set_state(Slot::Ota1, OtaState::Valid).unwrap(),
        ),
        (
            "rejection",
            armed,
            armed.set_state(Slot::Ota1, OtaState::Invalid).unwrap(),
        ),
    ]
}

#[test]
fn a_cut_at_any_word_of_an_otadata_write_falls_back_and_never_confirms() {
    let mut cuts = 0;
    for bootloader in [Bootloader::Plain, Bootloader::Rollback] {
        for (what, before, write) in writes() {
            let after = before.with(write);
            let allowed = [unlocked(&before, bootloader), unlocked(&after, bootloader)];
            for (op, range) in program_order().into_iter().enumerate() {
                let words = range.len() / 4;
                for programmed in 0..(1u32 << words) {
                    let left = before.with(SectorWrite {
                        sector: write.sector,
                        entry: torn(&write.entry, op, programmed),
                    });
                    let runs = unlocked(&left, bootloader);
                    assert!(
                        runs.is_none() || allowed.contains(&runs),
                        "{bootloader:?}, {what} cut in operation {op} with words \
                         {programmed:#b} programmed: {:?} runs unlocked (before {:?}, \
                         after {:?}), otadata {left:?}",
                        runs,
                        allowed[0],
                        allowed[1]
                    );
                    cuts += 1;
                }
            }
        }
    }
    assert!(cuts >= 2 * 6 * (128 + 2), "{cuts} cuts");
}

/// The rollback bootloader writes its marks as ESP-IDF does, in one program operation
/// of the whole entry: a cut can leave a valid entry whose state word is still erased
/// or half programmed. The image that starts from it is on trial, not confirmed.
#[test]
fn a_torn_bootloader_mark_starts_the_image_on_trial() {
    let on_trial = OtaData {
        sectors: [Entry::new(1, OtaState::Valid), Entry::new(2, OtaState::New)],
    };
    let outcome = boot(&on_trial, [true, true], Bootloader::Rollback);
    let mark = outcome.writes[0];
    assert_eq!(mark.entry.state, OtaState::PendingVerify);
    let bytes = mark.entry.encode();
    // Every word programmed but the state's (bytes 24..28), which a cut left erased or
    // with only some of its bits programmed.
    for state_word in [0xFFFF_FFFFu32, 0xFFFF_FF01, 0x0000_FFFF] {
        let mut sector = bytes;
        sector[24..28].copy_from_slice(&state_word.to_le_bytes());
        let left = on_trial.with(SectorWrite {
            sector: mark.sector,
            entry: Entry::decode(&sector),
        });
        let role = on_start(&left, Slot::Ota1).role;
        assert!(
            role == StartRole::Trial,
            "state word {state_word:#x}: {role:?}"
        );
    }
}
