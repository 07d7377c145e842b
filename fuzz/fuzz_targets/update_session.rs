//! Any stream of update frames into the update session: commands on 0x2E8 and data on
//! 0x2EC of any length and content, the flash's answers (done or failed) and time
//! passing, in any order, on a controller that starts idle or with an image on trial.
//! One op also sends a whole window of chosen bytes with its right CRC, so the
//! window's write, its flash failure and the header checks of window 0 are reached.
//! The controller is a development build or one that trusts a key (and has a
//! security version), so FINISH's signature checks run on whatever follows the image.
//! Nothing may panic, every reply must encode and decode back to itself, a window is
//! only ever written inside the slot at a window boundary, and motion is locked
//! whenever a session or trial runs.
#![no_main]

use base_core::can::update::{DATA_BYTES, DataFrame, Phase, UpdateCommand, UpdateReply};
use base_core::time::Timestamp;
use base_core::update::image::Chip;
use base_core::update::session::{
    Event, FlashOp, MotionGate, Params, Updater, WINDOW_LEN, frame_count, window_crc,
};
use base_core::update::signature::{PublicKey, Trust};
use libfuzzer_sys::fuzz_target;

const COMMAND_ID: u16 = 0x2E8;
const DATA_ID: u16 = 0x2EC;
/// A small slot, so that BEGINs of any size are refused as too large too.
const SLOT_LEN: u32 = 64 * 1024;

/// The key a keyed build trusts: any 32 bytes do, a signature the fuzzer makes up
/// fails either way.
const TRUSTED: [PublicKey; 1] = [[0x11; 32]];

fn params(build: u8) -> Params<'static> {
    Params {
        chip: Chip::Esp32c3,
        project: "base-controller",
        running_version: "0.2.0",
        running_slot: 0,
        slot_len: SLOT_LEN,
        trial_deadline_ms: 120_000,
        trust: if build & 2 == 0 {
            Trust::Development
        } else {
            Trust::Keys(&TRUSTED)
        },
        running_security_version: u32::from(build >> 4),
    }
}

fuzz_target!(|input: &[u8]| {
    let [on_trial, ops @ ..] = input else {
        return;
    };
    let params = params(*on_trial);
    let mut now = 0u64;
    // Bit 0: an image on trial; bit 1: the boot knows the session that activated it.
    let owner = (on_trial & 2 != 0).then_some(on_trial | 1);
    let mut updater = if on_trial & 1 == 1 {
        Updater::on_trial(Timestamp::from_millis(now), owner, &params)
    } else {
        Updater::idle()
    };
    let mut ops = ops.iter().copied();
    while let Some(op) = ops.next() {
        let event = match op % 6 {
            // A command frame: a length byte, then that many bytes (DLC 0..=8).
            0 | 1 => {
                let data: Vec<u8> = frame(&mut ops);
                let gate = MotionGate {
                    at_standstill: op & 0x10 != 0,
                    brakes_applied: op & 0x20 != 0,
                    control_active: op & 0x40 != 0,
                };
                match UpdateCommand::decode(COMMAND_ID, &data) {
                    Ok(Some(command)) => Event::Command(command, gate),
                    _ => continue,
                }
            }
            // A data frame of any length.
            2 => {
                let data: Vec<u8> = frame(&mut ops);
                match DataFrame::decode(DATA_ID, &data) {
                    Ok(Some(frame)) => Event::Data(frame),
                    _ => continue,
                }
            }
            3 => Event::FlashDone(op & 0x80 != 0),
            4 => {
                // Up to ~65 s at once, so the silence and trial deadlines are reached.
                now += u64::from(ops.next().unwrap_or(0)) * 256;
                Event::Tick
            }
            _ => {
                // A whole window: index, session and a fill byte from the input.
                let session = ops.next().unwrap_or(1);
                let index = u16::from(ops.next().unwrap_or(0) % 20);
                let fill = ops.next().unwrap_or(0xE9);
                let len = WINDOW_LEN;
                let bytes = vec![fill; len];
                let window = UpdateCommand::Window {
                    session,
                    index,
                    crc: window_crc(&bytes),
                };
                step(
                    &mut updater,
                    &mut now,
                    Event::Command(window, AT_REST),
                    &params,
                );
                for seq in 0..frame_count(len) {
                    let frame = DataFrame {
                        seq: seq as u8,
                        bytes: [fill; DATA_BYTES],
                    };
                    step(&mut updater, &mut now, Event::Data(frame), &params);
                }
                continue;
            }
        };
        step(&mut updater, &mut now, event, &params);
    }
});

const AT_REST: MotionGate = MotionGate {
    at_standstill: true,
    brakes_applied: true,
    control_active: false,
};

/// A length byte (0..=8 after the modulo) and that many bytes, as far as there are.
fn frame(ops: &mut impl Iterator<Item = u8>) -> Vec<u8> {
    let len = usize::from(ops.next().unwrap_or(0) % 9);
    ops.take(len).collect()
}

/// One event, then the invariants. The flash answers only when the input says so
/// (op 3), so commands and frames also arrive while a window is being written.
fn step(updater: &mut Updater, now: &mut u64, event: Event, params: &Params<'_>) {
    *now += 1;
    let effects = updater.step(Timestamp::from_millis(*now), event, params);
    for reply in &effects.replies {
        let frame = reply.encode();
        assert_eq!(
            UpdateReply::decode(frame.id(), frame.data()),
            Ok(Some(*reply)),
            "a reply must decode to itself"
        );
    }
    if let Some(FlashOp::WriteWindow { offset }) = effects.flash {
        let len = updater.window().len() as u32;
        assert_eq!(offset % WINDOW_LEN as u32, 0, "a window starts at a sector");
        assert!(
            len > 0 && offset + len <= SLOT_LEN,
            "a window stays in the slot"
        );
    }
    assert_eq!(
        updater.locks_motion(),
        updater.phase() != Phase::Idle,
        "motion is locked exactly while a session or a trial runs"
    );
}
