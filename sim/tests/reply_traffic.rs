//! Replies never push out the periodic frames. While the robot drives, other programs
//! ask for replies as fast as the bus carries their requests: firmware-update QUERYs
//! (seven replies each) and register reads. The controller cannot answer all of them,
//! and the replies it cannot send are dropped and counted; its position, heading,
//! battery, weight and status frames still go out, every one, on their schedule.
//!
//! On the virtual clock with the timed bus, so the figures are exact.

use base_core::can::update::UpdateCommand;
use base_core::can::{Command, RawFrame, id};
use base_core::registers::{Reg, TABLE};
use embassy_futures::join::join3;
use embassy_time::{Duration, Instant};
use virtual_robot::can::{SentFrame, SimFrame, frame_time};
use virtual_robot::robot::{Pc, VirtualRobot, wait_ms};

/// The drives answer 1 s after power-on; their setup takes a few transactions more.
const BOOT_MS: u64 = 1_500;
/// How long the other programs flood the bus.
const FLOOD_MS: u64 = 10_000;
const SPEED_MM_S: i16 = 300;

fn sim_frame(frame: RawFrame) -> SimFrame {
    SimFrame::standard(frame.id(), frame.data()).expect("a protocol frame")
}

/// A program that sends the next frame `next` gives it as soon as its previous one has
/// left the wire, until `until`: the bus carries its requests as fast as it can.
async fn flood(pc: &Pc, until: Instant, mut next: impl FnMut() -> RawFrame) -> u32 {
    let mut sent = 0;
    while Instant::now() < until {
        pc.peer.transmit(sim_frame(next()), Instant::now()).await;
        sent += 1;
    }
    sent
}

/// Tagged reads of every register in turn.
fn register_reads() -> impl FnMut() -> RawFrame {
    let mut addresses = TABLE.iter().map(|info| info.address).cycle();
    let mut tag: u16 = 0;
    move || {
        tag = tag.wrapping_add(1).max(1);
        Command::RegisterRead {
            address: addresses.next().expect("an endless cycle"),
            tag,
        }
        .encode()
    }
}

/// The frames the controller sent with `frame_id` inside `from..to`.
fn times(sent: &[SentFrame], frame_id: u16, from: Instant, to: Instant) -> Vec<Instant> {
    sent.iter()
        .filter(|sent| sent.frame.standard_id() == Some(frame_id))
        .filter(|sent| (from..to).contains(&sent.at))
        .map(|sent| sent.at)
        .collect()
}

/// How far each frame of a periodic series lies from where its period puts it, relative
/// to the earliest one: 0 for a series that keeps its period exactly. A missing frame
/// shifts every later one by a period.
fn schedule_spread(times: &[Instant], period: Duration) -> Duration {
    let Some(&first) = times.first() else {
        return Duration::MAX;
    };
    let offsets: Vec<i64> = times
        .iter()
        .enumerate()
        .map(|(k, at)| (*at - first).as_micros() as i64 - (k as u64 * period.as_micros()) as i64)
        .collect();
    let spread = offsets.iter().max().unwrap() - offsets.iter().min().unwrap();
    Duration::from_micros(spread.unsigned_abs())
}

#[test]
fn queries_and_register_reads_at_the_bus_limit_neither_drop_nor_delay_the_periodic_frames() {
    let robot = VirtualRobot::new();
    let (sent, window, requests, dropped) = robot.run_with_update(async |pc| {
        wait_ms(BOOT_MS).await;
        let start = Instant::now() + Duration::from_millis(1_000);
        let end = start + Duration::from_millis(FLOOD_MS);
        let query = UpdateCommand::Query.encode();
        let (_, queries, reads) = join3(
            pc.drive(SPEED_MM_S, 0, FLOOD_MS + 2_000),
            async {
                wait_ms(1_000).await;
                flood(pc, end, || query).await
            },
            async {
                wait_ms(1_000).await;
                flood(pc, end, register_reads()).await
            },
        )
        .await;
        wait_ms(100).await;
        let dropped = pc
            .read_register(Reg::CanTxDropped.address())
            .await
            .expect("can_tx_dropped is read on a quiet bus");
        (pc.peer.sent(), (start, end), (queries, reads), dropped)
    });
    let (start, end) = window;
    let (queries, reads) = requests;
    // The requests kept the bus busy: a QUERY and a read in every round, and the
    // controller could not answer them all.
    let seconds = FLOOD_MS as f64 / 1000.0;
    eprintln!(
        "{:.0} QUERYs/s and {:.0} register reads/s; the controller dropped {dropped} replies",
        f64::from(queries) / seconds,
        f64::from(reads) / seconds
    );
    assert!(
        queries > 10_000 && reads > 10_000,
        "{queries} QUERYs, {reads} reads"
    );
    assert!(dropped > 1_000, "only {dropped} replies dropped");
    let replies = times(&sent, id::UPDATE_REPLY, start, end).len()
        + times(&sent, id::REGISTER_READ, start, end).len();
    assert!(replies > 5_000, "only {replies} replies sent");

    // The controller hands the bus one frame at a time. A periodic frame that falls due
    // just after a reply was handed over waits for that reply, which waits for the
    // request each other program offered before it (the virtual bus serves frames in
    // the order offered), and then for the requests they offered meanwhile.
    let longest_reply = frame_time(&sim_frame(
        base_core::can::update::UpdateReply::Version {
            part: 0,
            text: [b'x'; 6],
        }
        .encode(),
    ));
    let requests_ahead = frame_time(&sim_frame(UpdateCommand::Query.encode()))
        + frame_time(&sim_frame(register_reads()()));
    let on_time = longest_reply + requests_ahead * 2;
    for (frame_id, register, name) in [
        (id::POSITION, Reg::LoopEndDelay, "position"),
        (id::HEADING, Reg::LoopEndDelay, "heading"),
        (id::BATTERY, Reg::VoltTime, "battery"),
        (id::WEIGHT, Reg::WeightTime, "weight"),
        (id::STATUS, Reg::StatusTime, "status"),
    ] {
        let period = Duration::from_millis(u64::from(register.info().default));
        let times = times(&sent, frame_id, start, end);
        let expected = (FLOOD_MS / period.as_millis()) as usize;
        assert!(
            times.len() >= expected,
            "{name} frames: {} in {FLOOD_MS} ms, expected {expected}",
            times.len()
        );
        let spread = schedule_spread(&times, period);
        eprintln!(
            "{name}: {} frames, at most {} µs from their schedule",
            times.len(),
            spread.as_micros()
        );
        // Frames due together (position, heading, status) go one after the other, each
        // with its own wait.
        let bound = on_time * 5;
        assert!(
            spread <= bound,
            "{name} frames stray {} µs from their schedule (bound {} µs)",
            spread.as_micros(),
            bound.as_micros()
        );
        if frame_id == id::POSITION {
            assert!(
                spread <= on_time,
                "position frames stray {} µs from their schedule; one reply and the \
                 requests ahead take {} µs",
                spread.as_micros(),
                on_time.as_micros()
            );
        }
    }
}
