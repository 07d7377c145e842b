//! The PC's programs: a velocity stream, a register write with its read-back, read
//! and QUERY floods, and a firmware update session that answers the controller's
//! replies as a PC tool does. Each frame is written from docs/protocol.md.

use embassy_time::{Duration, Timer};

use super::event::{Event, ImageKind, SessionEnd, SpeedPattern, StreamEnd, wire};
use super::world::World;
use crate::app_flash;
use crate::runtime::now;
use base_core::update::signature::{self, PublicKey};

/// Runs one program event to its end.
pub async fn run(world: &World, event: &Event) {
    match event {
        Event::Stream {
            linear,
            rotation,
            period_ms,
            enable_every,
            ms,
            pattern,
            end,
        } => {
            stream(
                world,
                (*linear, *rotation),
                u64::from((*period_ms).max(1)),
                (*enable_every).max(1),
                u64::from(*ms),
                *pattern,
                *end,
            )
            .await
        }
        Event::Frame { id, data } => world.send(*id, data).await,
        Event::WriteRegister { address, value } => {
            world
                .send(
                    wire::REGISTER_WRITE,
                    &wire::register_write(*address, *value),
                )
                .await;
            Timer::after_millis(5).await;
            let tag = world.tag();
            world
                .send(wire::REGISTER_READ, &wire::register_read(*address, tag))
                .await;
        }
        Event::ReadFlood { ms, period_us } => {
            let end = now() + Duration::from_millis(u64::from(*ms));
            let mut address = 0u8;
            while now() < end {
                let tag = world.tag();
                world
                    .send(wire::REGISTER_READ, &wire::register_read(address, tag))
                    .await;
                address = (address + 1) % 50;
                Timer::after(Duration::from_micros(u64::from(*period_us))).await;
            }
        }
        Event::QueryFlood { ms, period_us } => {
            let end = now() + Duration::from_millis(u64::from(*ms));
            while now() < end {
                world.send(wire::UPDATE_COMMAND, &[0x01]).await;
                Timer::after(Duration::from_micros(u64::from(*period_us))).await;
            }
        }
        Event::Update {
            session,
            image,
            windows,
            bad_crc_window,
            stray_window,
            end,
        } => {
            let plan = SessionPlan {
                image: *image,
                windows: (*windows).max(1),
                bad_crc_window: *bad_crc_window,
                stray_window: *stray_window,
                end: *end,
            };
            update(world, (*session).max(1), plan).await
        }
        _ => {}
    }
}

async fn stream(
    world: &World,
    (linear, rotation): (i16, i16),
    period_ms: u64,
    enable_every: u8,
    ms: u64,
    pattern: SpeedPattern,
    end: StreamEnd,
) {
    let stop = now() + Duration::from_millis(ms);
    let mut frame: u64 = 0;
    let (mut linear_now, mut rotation_now) = (linear, rotation);
    while now() < stop {
        if frame.is_multiple_of(u64::from(enable_every)) {
            world.send(wire::ENABLE, &wire::enable(true)).await;
        }
        let (send_linear, send_rotation) = match pattern {
            SpeedPattern::Constant => (linear, rotation),
            SpeedPattern::Alternating if frame % 2 == 1 => (-linear, -rotation),
            SpeedPattern::Alternating => (linear, rotation),
            SpeedPattern::Wander => {
                // A deterministic walk: the frame number picks the step.
                let step = [37i16, -53, 11, -7, 61, -29, 0, 19][(frame % 8) as usize];
                linear_now = linear_now.saturating_add(step).clamp(-1500, 1500);
                rotation_now = rotation_now.saturating_add(step * 3).clamp(-3000, 3000);
                (linear_now, rotation_now)
            }
        };
        world
            .send(wire::VELOCITY, &wire::velocity(send_linear, send_rotation))
            .await;
        frame += 1;
        Timer::after_millis(period_ms).await;
    }
    match end {
        StreamEnd::Lapse => {}
        StreamEnd::Withdraw => world.send(wire::ENABLE, &wire::enable(false)).await,
        StreamEnd::ZeroVelocity => world.send(wire::VELOCITY, &wire::velocity(0, 0)).await,
    }
}

// ---------------------------------------------------------------------------------
// A firmware update session (docs/protocol.md, "Firmware update")
// ---------------------------------------------------------------------------------

const WINDOW: usize = 4096;
const DATA_BYTES: usize = 7;
/// Frames the PC may send past the frame a READY names.
const SUB_BLOCK: usize = 24;
const REPLY_TIMEOUT: Duration = Duration::from_millis(1_500);

/// The version each session's image claims: newer than everything before it.
pub fn image_version(session: u8, image: ImageKind) -> String {
    let base = format!("0.2.{session}");
    match image {
        ImageKind::PanicsAtBoot => format!("{base}{}", app_flash::PANIC_SUFFIX),
        ImageKind::NeverConfirms => format!("{base}{}", app_flash::NO_CONFIRM_SUFFIX),
        ImageKind::RefusedDriveSettings => format!("{base}{}", app_flash::REFUSED_DRIVES_SUFFIX),
        ImageKind::Unsigned => format!("{base}-unsigned"),
        ImageKind::SignedByStranger => format!("{base}-stranger"),
        ImageKind::Forged => format!("{base}-forged"),
        _ => base,
    }
}

/// Whether a version is one of the images no trusted key signed: it must never boot.
pub fn untrusted(version: &str) -> bool {
    ["-unsigned", "-stranger", "-forged"]
        .iter()
        .any(|suffix| version.ends_with(suffix))
}

/// The owner's key the tester's controller trusts, and a stranger's.
const OWNER_SECRET: [u8; 32] = [0x5C; 32];
const STRANGER_SECRET: [u8; 32] = [0x5D; 32];

/// The public keys the tester's controller is built with.
pub fn trusted_keys() -> &'static [PublicKey] {
    static KEYS: std::sync::LazyLock<[PublicKey; 1]> =
        std::sync::LazyLock::new(|| [signature::public_key(&OWNER_SECRET)]);
    &*KEYS
}

fn signed(image: &[u8], secret: &[u8; 32]) -> Vec<u8> {
    let (len, block) = signature::sign(image, secret, 0).expect("a well-formed image");
    [&image[..len], &block.to_bytes()[..]].concat()
}

fn image_bytes(session: u8, image: ImageKind, windows: u8) -> Vec<u8> {
    let version = image_version(session, image);
    // The image fills `windows` windows (the last one partly).
    let payload = (usize::from(windows) * WINDOW)
        .saturating_sub(WINDOW / 2)
        .max(512);
    let bytes = match image {
        ImageKind::OtherChip => app_flash::synthetic_image(
            base_core::update::image::Chip::Esp32c6,
            base_runtime::update::PROJECT,
            &version,
            payload,
        ),
        _ => app_flash::sim_image(&version, payload),
    };
    match image {
        ImageKind::Unsigned => bytes,
        ImageKind::SignedByStranger => signed(&bytes, &STRANGER_SECRET),
        ImageKind::Forged => {
            let mut forged = signed(&bytes, &OWNER_SECRET);
            let flags_at = forged.len() - signature::BLOCK_LEN + 40;
            forged[flags_at] ^= 1;
            forged
        }
        _ => signed(&bytes, &OWNER_SECRET),
    }
}

/// What came back for a command, or nothing in time.
async fn reply(world: &World, cursor: &mut u64, accept: impl Fn(&[u8]) -> bool) -> Option<Vec<u8>> {
    let deadline = now() + REPLY_TIMEOUT;
    world
        .inbox
        .wait_for(cursor, wire::UPDATE_REPLY, deadline, accept)
        .await
}

/// DONE `step` for `session`, or a REFUSED for `opcode`.
fn done_or_refused(session: u8, step: u8, opcode: u8) -> impl Fn(&[u8]) -> bool {
    move |data| {
        matches!(data, [0x85, sid, done, ..] if *sid == session && *done == step)
            || matches!(data, [0xFF, op, ..] if *op == opcode)
    }
}

/// How one update session goes (see [`Event::Update`]).
struct SessionPlan {
    image: ImageKind,
    windows: u8,
    bad_crc_window: Option<u8>,
    stray_window: Option<u16>,
    end: SessionEnd,
}

async fn update(world: &World, session: u8, plan: SessionPlan) {
    let SessionPlan {
        image,
        windows,
        bad_crc_window,
        stray_window,
        end,
    } = plan;
    let bytes = image_bytes(session, image, windows);
    let version = image_version(session, image);
    world.observe(|oracle, _| oracle.session_image(session, &version));
    let mut digest = [0u8; 32];
    digest.copy_from_slice(&<sha2::Sha256 as sha2::Digest>::digest(&bytes));
    if image == ImageKind::WrongDigest {
        digest[0] ^= 0xA5;
    }
    let size = bytes.len() as u32;
    let mut cursor = world.inbox.cursor();
    world.send(wire::UPDATE_COMMAND, &[0x01]).await;
    // BEGIN, again while the base is not ready for it (moving, controlled, on trial).
    let mut begun = false;
    for _ in 0..5 {
        let [s0, s1, s2, _] = size.to_le_bytes();
        // Force and allow-downgrade: every image here is acceptable by version.
        world
            .send(wire::UPDATE_COMMAND, &[0x02, session, s0, s1, s2, 0x03])
            .await;
        match reply(world, &mut cursor, done_or_refused(session, 1, 0x02)).await {
            Some(data) if data[0] == 0x85 => {
                begun = true;
                break;
            }
            _ => Timer::after_millis(2_000).await,
        }
    }
    if !begun {
        return;
    }
    for part in 0..8u8 {
        let at = usize::from(part) * 4;
        let mut data = vec![0x03, session, part];
        data.extend_from_slice(&digest[at..at + 4]);
        world.send(wire::UPDATE_COMMAND, &data).await;
    }
    let count = bytes.len().div_ceil(WINDOW);
    for index in 0..count {
        let windows_done = index as u8;
        match end {
            SessionEnd::Abort { after_windows } if windows_done >= after_windows => {
                world.send(wire::UPDATE_COMMAND, &[0x07, session]).await;
                return;
            }
            // The PC vanishes: the session must end by itself.
            SessionEnd::Vanish { after_windows } if windows_done >= after_windows => return,
            _ => {}
        }
        let start = index * WINDOW;
        let window = &bytes[start..(start + WINDOW).min(bytes.len())];
        if !send_window(
            world,
            &mut cursor,
            session,
            index as u16,
            window,
            bad_crc_window == Some(index as u8),
        )
        .await
        {
            // The controller went away or refused: end as a PC tool does.
            world.send(wire::UPDATE_COMMAND, &[0x07, session]).await;
            return;
        }
        if let (0, Some(stray)) = (index, stray_window) {
            // Refused as out of turn (WrongWindow), or answered WRITTEN again if it
            // names the window just written; either way the session goes on.
            let [i0, i1] = stray.to_le_bytes();
            world
                .send(wire::UPDATE_COMMAND, &[0x04, session, i0, i1, 0, 0, 0, 0])
                .await;
            let answered = |data: &[u8]| matches!(data, [0xFF, 0x04, ..] | [0x84, ..]);
            let _ = reply(world, &mut cursor, answered).await;
        }
    }
    world.send(wire::UPDATE_COMMAND, &[0x05, session]).await;
    match reply(world, &mut cursor, done_or_refused(session, 2, 0x05)).await {
        Some(data) if data[0] == 0x85 => {}
        _ => {
            world.send(wire::UPDATE_COMMAND, &[0x07, session]).await;
            return;
        }
    }
    if matches!(end, SessionEnd::Abort { .. } | SessionEnd::Vanish { .. }) {
        world.send(wire::UPDATE_COMMAND, &[0x07, session]).await;
        return;
    }
    world.send(wire::UPDATE_COMMAND, &[0x06, session]).await;
    if reply(world, &mut cursor, done_or_refused(session, 3, 0x06))
        .await
        .is_none_or(|data| data[0] != 0x85)
    {
        return;
    }
    // The controller resets; ask until it answers from its new boot.
    let deadline = now() + Duration::from_secs(20);
    let mut on_trial = false;
    while now() < deadline {
        Timer::after_millis(500).await;
        world.send(wire::UPDATE_COMMAND, &[0x01]).await;
        if let Some(state) = reply(world, &mut cursor, |data| data.first() == Some(&0x81)).await {
            on_trial = state.get(1) == Some(&5);
            break;
        }
    }
    if !on_trial {
        return;
    }
    match end {
        SessionEnd::Confirm => world.send(wire::UPDATE_COMMAND, &[0x08, session]).await,
        SessionEnd::Rollback => world.send(wire::UPDATE_COMMAND, &[0x09, session]).await,
        SessionEnd::Stranger { offset, keep } => {
            let stranger = session.wrapping_add(offset.max(1));
            let opcode = if keep { 0x08 } else { 0x09 };
            world.send(wire::UPDATE_COMMAND, &[opcode, stranger]).await;
        }
        _ => {}
    }
}

/// One window: WINDOW, the data frames paced by READY, until WRITTEN. False when
/// the controller stopped answering or refused for good.
async fn send_window(
    world: &World,
    cursor: &mut u64,
    session: u8,
    index: u16,
    window: &[u8],
    bad_crc_once: bool,
) -> bool {
    let crc = base_core::update::session::window_crc(window);
    let frames: Vec<Vec<u8>> = window
        .chunks(DATA_BYTES)
        .enumerate()
        .map(|(seq, chunk)| {
            let mut data = vec![seq as u8];
            data.extend_from_slice(chunk);
            data.resize(1 + DATA_BYTES, 0);
            data
        })
        .collect();
    for attempt in 0..4 {
        let sent_crc = if bad_crc_once && attempt == 0 {
            crc ^ 1
        } else {
            crc
        };
        let [i0, i1] = index.to_le_bytes();
        let [c0, c1, c2, c3] = sent_crc.to_le_bytes();
        world
            .send(
                wire::UPDATE_COMMAND,
                &[0x04, session, i0, i1, c0, c1, c2, c3],
            )
            .await;
        let mut sent = 0usize;
        loop {
            let ours = |data: &[u8]| match data {
                [0x83, sid, w0, w1, ..] | [0x84, sid, w0, w1, ..] => {
                    *sid == session && u16::from_le_bytes([*w0, *w1]) == index
                }
                // The controller's word on data frames (opcode 0) and on this window.
                [0xFF, 0x00 | 0x04, ..] => true,
                _ => false,
            };
            let Some(data) = reply(world, cursor, ours).await else {
                break;
            };
            match data.as_slice() {
                [0x83, _, _, _, n0, n1, ..] => {
                    let next = usize::from(u16::from_le_bytes([*n0, *n1]));
                    let end = (next + SUB_BLOCK).min(frames.len());
                    for frame in &frames[sent.max(next).min(end)..end] {
                        world.send(wire::UPDATE_DATA, frame).await;
                    }
                    sent = sent.max(end);
                }
                [0x84, ..] => return true,
                // BadCrc, WrongWindow: the window again.
                [0xFF, _, 8 | 9, ..] => break,
                // OutOfOrder, Duplicate: the next READY says where to go on.
                [0xFF, 0x00, 6, ..] => sent = 0,
                [0xFF, 0x00, 7, ..] => {}
                // Anything else ends the session.
                _ => return false,
            }
        }
    }
    false
}
