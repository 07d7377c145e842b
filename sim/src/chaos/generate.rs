//! The seeded generator: from a seed alone, the events of a run — every kind of input
//! at once, each kind an actor with its own rate (the PC driving in episodes, other
//! programs reading and writing registers, pads, the e-stop and the front button,
//! faults and resets), so the robot spends its time driving, stopping and recovering
//! rather than stuck in one fault.
//!
//! The RNG is `rand_xorshift`'s XorShiftRng seeded with `seed_from_u64`: a fixed
//! algorithm, so a seed gives the same events on every machine.

use rand::{RngExt, SeedableRng};
use rand_xorshift::XorShiftRng;

use super::event::{
    DriveFault, Event, FlashFault, ImageKind, PadAction, PadHands, PadKind, ResetKind, SessionEnd,
    SpeedPattern, StreamEnd, Timed, wire,
};
use super::registers::{self, FOLLOWED};

/// The drives answer 1 s after power-on and are set up half a second later: the
/// actors start after that.
const FIRST_MS: u64 = 2_000;

struct Plan {
    rng: XorShiftRng,
    mix: Mix,
    end_ms: u64,
    events: Vec<Timed>,
    /// The pad sessions so far, (pad, from, to) in ms.
    pad_sessions: Vec<(PadKind, u64, u64)>,
}

impl Plan {
    fn push(&mut self, at_ms: u64, event: Event) {
        if at_ms < self.end_ms {
            self.events.push(Timed { at_ms, event });
        }
    }

    /// The time to the next event of an actor with mean interval `mean_ms`
    /// (exponential, at least 1 ms).
    fn gap(&mut self, mean_ms: f64) -> u64 {
        let uniform: f64 = self.rng.random_range(1e-9..1.0);
        (-uniform.ln() * mean_ms).max(1.0) as u64
    }

    fn chance(&mut self, p: f64) -> bool {
        self.rng.random_bool(p)
    }

    fn range(&mut self, low: u64, high: u64) -> u64 {
        self.rng.random_range(low..=high)
    }

    /// Runs an actor from `FIRST_MS`: `step` adds its events at `t` and returns how
    /// long it is busy; then it rests `gap(mean_ms)`.
    fn actor(&mut self, mean_ms: f64, mut step: impl FnMut(&mut Plan, u64) -> u64) {
        let mut t = FIRST_MS + self.gap(mean_ms);
        while t < self.end_ms {
            let busy = step(self, t);
            t += busy + self.gap(mean_ms);
        }
    }
}

/// Which inputs a run throws: all of them, or all but those of defects that are known
/// and being fixed (each named with the reason), so that the test run stays green
/// until the fix is in and catches everything else meanwhile (docs/tests.md, "What
/// the tester found").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mix {
    /// Register-read and QUERY floods. Fixed: reply traffic once delayed and dropped
    /// the periodic frames (issue 30, item 4).
    pub floods: bool,
    /// A drive's speed register frozen at a wrong value. Fixed: the fault's stop once
    /// shared `estop_decel` out by the lying speed, so that wheel braked gently and was
    /// de-excited 300 ms later while still turning.
    pub speed_lies: bool,
    /// Velocity streams whose sign flips every frame, and a second program streaming
    /// velocity while the first does (its frames interleave: the wheels are told one
    /// way and the other every few ms). Fixed: the direction check once reported a
    /// healthy drive turning against its command (`WrongDirection`, 0x43). With them
    /// in, seed 20 once broke rule 1 in a pad case: the oracle's defect
    /// (`tests/chaos/oracle-update-state-disarmed-pad-seed-20-rule-1.jsonl`).
    pub reversals: bool,
    /// Both pads connected at once: the waiting pad's reports are dropped, and one
    /// takes over when the pad in control leaves (once a finding: a dead-man held on
    /// the waiting pad was unknown at the hand-over, and CAN drove under it).
    pub two_pads_at_once: bool,
    /// `disable_time` 0 ("brake as soon as both wheels stand"). Fixed: a drive was once
    /// de-excited by a standstill measured before its last command started it, while
    /// its shaft turned at 15 r/min.
    pub brake_at_once: bool,
}

impl Mix {
    pub const ALL: Mix = Mix {
        floods: true,
        speed_lies: true,
        reversals: true,
        two_pads_at_once: true,
        brake_at_once: true,
    };
    /// No defect the tester found is open: the fixed budget throws every input.
    pub const WITHOUT_OPEN_DEFECTS: Mix = Mix::ALL;

    /// The option of the example that gives this mix.
    pub fn option(self) -> &'static str {
        if self == Mix::ALL { "--all-inputs" } else { "" }
    }
}

/// Every event of a run of `duration_ms` from `seed`, in time order.
pub fn generate(seed: u64, duration_ms: u64, mix: Mix) -> Vec<Timed> {
    let mut plan = Plan {
        rng: XorShiftRng::seed_from_u64(seed),
        mix,
        end_ms: duration_ms,
        events: Vec::new(),
        pad_sessions: Vec::new(),
    };
    plan.actor(3_000.0, pc_driving);
    if mix.reversals {
        plan.actor(40_000.0, second_program_driving);
    }
    plan.actor(2_000.0, single_frame);
    plan.actor(15_000.0, register_write);
    if mix.floods {
        plan.actor(150_000.0, flood);
    }
    plan.actor(200_000.0, update_session);
    for pad in PadKind::ALL {
        plan.actor(25_000.0, |plan, t| pad_session(plan, t, pad));
    }
    plan.actor(60_000.0, estop);
    plan.actor(20_000.0, button);
    plan.actor(45_000.0, zone);
    plan.actor(30_000.0, sensors);
    plan.actor(40_000.0, drive_fault);
    plan.actor(150_000.0, flash_fault);
    plan.actor(200_000.0, bus_fault);
    plan.actor(180_000.0, reset);
    // Last, so that the actors before it draw the same events as before it came.
    plan.actor(90_000.0, radio_fault);
    plan.actor(120_000.0, pad_through_update);
    plan.events.sort_by_key(|timed| timed.at_ms);
    plan.events
}

fn speed(plan: &mut Plan) -> (i16, i16) {
    let linear = if plan.chance(0.1) {
        plan.rng.random_range(-5000..=5000)
    } else {
        plan.rng.random_range(-900..=900)
    };
    let rotation = match plan.range(0, 3) {
        0 => 0,
        1 => plan.rng.random_range(-500..=500),
        2 => plan.rng.random_range(-3000..=3000),
        _ => plan.rng.random_range(-20000..=20000),
    };
    (linear, rotation)
}

fn stream(plan: &mut Plan, t: u64) -> u64 {
    let (linear, rotation) = speed(plan);
    let ms = plan.range(300, 15_000) as u32;
    let period_ms = *[10u16, 20, 30, 50, 50, 50, 100, 200]
        .get(plan.range(0, 7) as usize)
        .unwrap_or(&50);
    let pattern = match plan.range(0, 9) {
        0 if plan.mix.reversals => SpeedPattern::Alternating,
        1..=3 => SpeedPattern::Wander,
        _ => SpeedPattern::Constant,
    };
    let end = match plan.range(0, 2) {
        0 => StreamEnd::Lapse,
        1 => StreamEnd::Withdraw,
        _ => StreamEnd::ZeroVelocity,
    };
    let enable_every = plan.range(1, 3) as u8;
    plan.push(
        t,
        Event::Stream {
            linear,
            rotation,
            period_ms,
            enable_every,
            ms,
            pattern,
            end,
        },
    );
    u64::from(ms)
}

fn pc_driving(plan: &mut Plan, t: u64) -> u64 {
    stream(plan, t)
}

fn second_program_driving(plan: &mut Plan, t: u64) -> u64 {
    stream(plan, t) / 2
}

fn single_frame(plan: &mut Plan, t: u64) -> u64 {
    let (id, data): (u16, Vec<u8>) = match plan.range(0, 13) {
        0 => (wire::ENABLE, wire::enable(plan.chance(0.7))),
        1 => {
            let (linear, rotation) = speed(plan);
            (wire::VELOCITY, wire::velocity(linear, rotation))
        }
        2 => (wire::HEARTBEAT, vec![0x01]),
        3 => (wire::RESET_ODOMETRY, vec![0x01]),
        4 => {
            let address = plan.range(0, 60) as u8;
            let tag = plan.range(1, 0xFFFF) as u16;
            match plan.range(0, 2) {
                0 => (wire::REGISTER_READ, vec![0x01, address]),
                1 => (wire::REGISTER_READ, wire::register_read(address, tag)),
                // Counts of 0 and 9 too: those are refused whole.
                _ => {
                    let count = plan.range(0, u64::from(wire::BULK_READ_MAX) + 1) as u8;
                    (
                        wire::REGISTER_READ,
                        wire::register_bulk_read(address, count, tag),
                    )
                }
            }
        }
        5 => {
            // Any frame to a known ID: wrong lengths, markers and sub-commands.
            let ids = [
                wire::ENABLE,
                wire::VELOCITY,
                wire::REGISTER_WRITE,
                wire::REGISTER_READ,
                wire::RESET_ODOMETRY,
                wire::HEARTBEAT,
                wire::SCALE_CALIBRATION,
                wire::ODOMETRY_CALIBRATION,
                wire::UPDATE_COMMAND,
                wire::UPDATE_DATA,
            ];
            let id = ids[plan.range(0, ids.len() as u64 - 1) as usize];
            let len = plan.range(0, 8) as usize;
            let data = (0..len).map(|_| plan.rng.random::<u8>()).collect();
            (id, data)
        }
        6 => (
            plan.range(0, 0x7FF) as u16,
            vec![plan.rng.random::<u8>(); plan.range(0, 8) as usize],
        ),
        7 => {
            let steps: [&[u8]; 7] = [
                &[0x01],
                &[0x02],
                &[0x03],
                &[0x0C, 0x03, 0xE8],
                &[0x16, 0x18, 0x8C],
                &[0x20, 0x18, 0x8C],
                &[0x04],
            ];
            let step = steps[plan.range(0, 6) as usize];
            (wire::ODOMETRY_CALIBRATION, step.to_vec())
        }
        8 => {
            let steps: [&[u8]; 3] = [&[0x01], &[0x02], &[0x03, 0x03, 0xE8]];
            let step = steps[plan.range(0, 2) as usize];
            (wire::SCALE_CALIBRATION, step.to_vec())
        }
        9 => {
            // Update commands out of any session: QUERY, CONFIRM, ROLLBACK, ABORT.
            let commands: [&[u8]; 4] = [&[0x01], &[0x08], &[0x09], &[0x07, 0x42]];
            let command = commands[plan.range(0, 3) as usize];
            (wire::UPDATE_COMMAND, command.to_vec())
        }
        10 => (
            wire::REGISTER_WRITE,
            wire::register_write(registers::address::COMMAND, registers::BLUETOOTH_ON),
        ),
        _ => (wire::ENABLE, wire::enable(true)),
    };
    plan.push(t, Event::Frame { id, data });
    0
}

fn register_write(plan: &mut Plan, t: u64) -> u64 {
    if plan.chance(0.03) {
        plan.push(
            t,
            Event::WriteRegister {
                address: registers::address::COMMAND,
                value: registers::RESTORE_DEFAULTS,
            },
        );
        return 0;
    }
    let (address, default) = FOLLOWED[plan.range(0, FOLLOWED.len() as u64 - 2) as usize];
    let value = match plan.range(0, 9) {
        0 => plan.rng.random::<u16>(),
        1 => 0,
        2..=4 => default,
        _ => {
            // Near the default, where most values are valid.
            let spread = (u64::from(default) / 2).max(10);
            let low = u64::from(default).saturating_sub(spread);
            plan.range(low, u64::from(default) + spread).min(0xFFFF) as u16
        }
    };
    let value =
        if address == registers::address::DISABLE_TIME && value == 0 && !plan.mix.brake_at_once {
            1
        } else {
            value
        };
    plan.push(t, Event::WriteRegister { address, value });
    0
}

fn flood(plan: &mut Plan, t: u64) -> u64 {
    let ms = plan.range(500, 5_000) as u32;
    let period_us = plan.range(300, 3_000) as u32;
    if plan.chance(0.5) {
        plan.push(t, Event::ReadFlood { ms, period_us });
    } else {
        plan.push(t, Event::QueryFlood { ms, period_us });
    }
    u64::from(ms)
}

fn update_session(plan: &mut Plan, t: u64) -> u64 {
    let session = plan.range(1, 255) as u8;
    let image = match plan.range(0, 23) {
        0..=9 => ImageKind::Healthy,
        10..=12 => ImageKind::PanicsAtBoot,
        13..=14 => ImageKind::NeverConfirms,
        15..=16 => ImageKind::OtherChip,
        17 => ImageKind::RefusedDriveSettings,
        18 => ImageKind::Unsigned,
        19 => ImageKind::SignedByStranger,
        20 => ImageKind::Forged,
        _ => ImageKind::WrongDigest,
    };
    let windows = plan.range(1, 6) as u8;
    let bad_crc_window = plan
        .chance(0.2)
        .then(|| plan.range(0, u64::from(windows) - 1) as u8);
    // Out of turn: past the image, at the top of the index's range, or anywhere.
    let stray_window = plan.chance(0.2).then(|| match plan.range(0, 3) {
        0 => u16::MAX,
        1 => u16::MAX - 1,
        2 => u16::from(windows) + 1,
        _ => plan.range(0, u64::from(u16::MAX)) as u16,
    });
    let end = match plan.range(0, 21) {
        0..=7 => SessionEnd::Confirm,
        8..=11 => SessionEnd::Rollback,
        12..=13 => SessionEnd::Walk,
        14..=15 => SessionEnd::Stranger {
            offset: plan.range(1, 255) as u8,
            keep: plan.chance(0.5),
        },
        16..=18 => SessionEnd::Abort {
            after_windows: plan.range(0, u64::from(windows)) as u8,
        },
        _ => SessionEnd::Vanish {
            after_windows: plan.range(0, u64::from(windows)) as u8,
        },
    };
    plan.push(
        t,
        Event::Update {
            session,
            image,
            windows,
            bad_crc_window,
            stray_window,
            end,
        },
    );
    30_000
}

fn hands(plan: &mut Plan, dead_man: bool) -> PadHands {
    let stick = |plan: &mut Plan| -> i8 {
        if plan.chance(0.3) {
            0
        } else {
            plan.rng.random_range(-100..=100)
        }
    };
    let combination = plan.chance(0.03);
    PadHands {
        dead_man,
        left_y: stick(plan),
        right_x: stick(plan),
        l2: combination || plan.chance(0.05),
        // Now and then Home (switch-off with L2) or Menu (odometry reset with L2), or
        // a D-pad press (speed levels).
        buttons: if combination {
            if plan.chance(0.5) { 1 << 8 } else { 1 << 7 }
        } else if plan.chance(0.1) {
            1 << (12 + plan.range(0, 1))
        } else {
            0
        },
    }
}

fn pad_session(plan: &mut Plan, t: u64, pad: PadKind) -> u64 {
    let ms = plan.range(2_000, 60_000);
    let overlaps = plan
        .pad_sessions
        .iter()
        .any(|&(other, from, to)| other != pad && from <= t + ms + 1_000 && t <= to + 1_000);
    if overlaps && !plan.mix.two_pads_at_once {
        return ms;
    }
    plan.pad_sessions.push((pad, t, t + ms));
    plan.push(
        t,
        Event::Pad {
            pad,
            action: PadAction::Connect,
        },
    );
    let mut at = t + plan.range(5, 300);
    let mut dead_man = plan.chance(0.3);
    while at < t + ms {
        if plan.chance(0.25) {
            dead_man = !dead_man;
        }
        let hands = hands(plan, dead_man);
        plan.push(
            at,
            Event::Pad {
                pad,
                action: PadAction::Report(hands),
            },
        );
        at += plan.range(8, 600);
    }
    plan.push(
        t + ms,
        Event::Pad {
            pad,
            action: PadAction::Drop,
        },
    );
    ms
}

/// The radio's own faults: a packet of a pad's the guard refuses (and the pad trying
/// again, perhaps inside the task's back-off), or the BLE host stopping, up to three
/// times in a row (given up then, until Bluetooth is turned on).
fn radio_fault(plan: &mut Plan, t: u64) -> u64 {
    if plan.chance(0.5) {
        let pad = PadKind::ALL[plan.range(0, 1) as usize];
        plan.push(
            t,
            Event::Pad {
                pad,
                action: PadAction::PacketRefused,
            },
        );
        let again = plan.range(200, 3_000);
        plan.push(
            t + again,
            Event::Pad {
                pad,
                action: PadAction::Connect,
            },
        );
        again
    } else {
        let mut at = t;
        for _ in 0..plan.range(1, 3) {
            plan.push(
                at,
                Event::Pad {
                    pad: PadKind::Ble,
                    action: PadAction::HostStops,
                },
            );
            at += plan.range(100, 20_000);
        }
        at - t
    }
}

/// A pad held through an update: connected and seen released, its dead-man pressed
/// while a session runs (one that ends without a reboot, so the pad stays) and still
/// held, the stick pushed, after the lock lifts. Such a dead-man must be released
/// after the lift before it drives (docs/behaviour.md, "Who may move the base"); the
/// random pads and sessions cross this way too seldom to test it.
fn pad_through_update(plan: &mut Plan, t: u64) -> u64 {
    let pad = PadKind::ALL[plan.range(0, 1) as usize];
    plan.push(
        t,
        Event::Pad {
            pad,
            action: PadAction::Connect,
        },
    );
    let released = hands(plan, false);
    plan.push(
        t + 100,
        Event::Pad {
            pad,
            action: PadAction::Report(released),
        },
    );
    let (image, end) = match plan.range(0, 2) {
        0 => (ImageKind::WrongDigest, SessionEnd::Confirm),
        1 => (ImageKind::Healthy, SessionEnd::Abort { after_windows: 1 }),
        _ => (ImageKind::Healthy, SessionEnd::Vanish { after_windows: 1 }),
    };
    let session = plan.range(1, 255) as u8;
    plan.push(
        t + 500,
        Event::Update {
            session,
            image,
            windows: 2,
            bad_crc_window: None,
            stray_window: None,
            end,
        },
    );
    let until = t + plan.range(3_000, 20_000);
    let mut at = t + 600;
    while at < until {
        let held = hands(plan, true);
        plan.push(
            at,
            Event::Pad {
                pad,
                action: PadAction::Report(held),
            },
        );
        at += plan.range(50, 1_000);
    }
    plan.push(
        until,
        Event::Pad {
            pad,
            action: PadAction::Drop,
        },
    );
    until - t
}

fn estop(plan: &mut Plan, t: u64) -> u64 {
    let held = if plan.chance(0.3) {
        let ms = plan.range(20, 3_000) as u32;
        // Pulses of two input samples (400 µs) at least: a shorter one may fall
        // between two samples and never be seen, on the robot as here.
        let period_us = plan.range(500, 60_000) as u32;
        let on_us = plan.range((u64::from(period_us) / 10).max(400), u64::from(period_us)) as u32;
        plan.push(
            t,
            Event::EstopChatter {
                period_us,
                on_us,
                ms,
            },
        );
        u64::from(ms)
    } else {
        let ms = plan.range(50, 5_000);
        plan.push(t, Event::Estop { pressed: true });
        plan.push(t + ms, Event::Estop { pressed: false });
        ms
    };
    // Most of the time someone confirms soon after.
    if plan.chance(0.85) {
        let after = held + plan.range(100, 3_000);
        let press = plan.range(60, 1_500) as u32;
        plan.push(t + after, Event::Button { ms: press });
        after + u64::from(press)
    } else {
        held
    }
}

fn button(plan: &mut Plan, t: u64) -> u64 {
    let ms = if plan.chance(0.05) {
        plan.range(3_000, 9_000)
    } else {
        plan.range(30, 1_200)
    } as u32;
    plan.push(t, Event::Button { ms });
    u64::from(ms)
}

fn zone(plan: &mut Plan, t: u64) -> u64 {
    if plan.chance(0.3) {
        let ms = plan.range(50, 5_000) as u32;
        let period_us = plan.range(1_000, 100_000) as u32;
        let on_us = plan.range((u64::from(period_us) / 10).max(400), u64::from(period_us)) as u32;
        plan.push(
            t,
            Event::ZoneChatter {
                period_us,
                on_us,
                ms,
            },
        );
        u64::from(ms)
    } else {
        let ms = plan.range(200, 10_000);
        plan.push(t, Event::Zone { occupied: true });
        plan.push(t + ms, Event::Zone { occupied: false });
        ms
    }
}

fn sensors(plan: &mut Plan, t: u64) -> u64 {
    match plan.range(0, 5) {
        0..=1 => {
            let millivolts = plan.range(18_000, 28_000) as u16;
            plan.push(t, Event::Battery { millivolts });
            0
        }
        2..=3 => {
            let grams = plan.range(0, 120_000) as u32;
            plan.push(t, Event::Weight { grams });
            0
        }
        _ => {
            let ms = plan.range(500, 10_000);
            plan.push(t, Event::LoadCellMissing { missing: true });
            plan.push(t + ms, Event::LoadCellMissing { missing: false });
            ms
        }
    }
}

fn drive_fault(plan: &mut Plan, t: u64) -> u64 {
    let slave = plan.range(1, 2) as u8;
    let ms = plan.range(50, 5_000);
    let mut kind = plan.range(0, 13);
    if (10..=11).contains(&kind) && !plan.mix.speed_lies {
        // A stuck encoder instead: its feedback lies too, its speed tells the truth.
        kind = 9;
    }
    let (on, off) = match kind {
        0 => (
            DriveFault::Silent { slave, on: true },
            Some(DriveFault::Silent { slave, on: false }),
        ),
        1 => (
            DriveFault::Alarm {
                slave,
                code: [0x30, 0x42, 0x6E][plan.range(0, 2) as usize],
            },
            None,
        ),
        2 => (
            DriveFault::Power { on: false },
            Some(DriveFault::Power { on: true }),
        ),
        3 => (DriveFault::PowerCycle { slave }, None),
        4 => (
            DriveFault::LoseReplies { on: true },
            Some(DriveFault::LoseReplies { on: false }),
        ),
        5 => (
            DriveFault::GarbleNext {
                replies: plan.range(1, 6) as u8,
            },
            None,
        ),
        6 => (
            DriveFault::GarbleOf { slave, on: true },
            Some(DriveFault::GarbleOf { slave, on: false }),
        ),
        7 => (
            DriveFault::Busy { slave, on: true },
            Some(DriveFault::Busy { slave, on: false }),
        ),
        8 => (
            DriveFault::FailLongerThan {
                bytes: Some(plan.range(8, 40) as u8),
            },
            Some(DriveFault::FailLongerThan { bytes: None }),
        ),
        9 => (
            DriveFault::StuckEncoder { slave, on: true },
            Some(DriveFault::StuckEncoder { slave, on: false }),
        ),
        10 => (
            DriveFault::SpeedReads {
                slave,
                rpm: Some(0),
            },
            Some(DriveFault::SpeedReads { slave, rpm: None }),
        ),
        12..=13 => {
            let motion = kind == 12;
            (
                DriveFault::Reversed {
                    slave,
                    motion,
                    on: true,
                },
                Some(DriveFault::Reversed {
                    slave,
                    motion,
                    on: false,
                }),
            )
        }
        _ => (
            DriveFault::SpeedReads {
                slave,
                rpm: Some(plan.rng.random_range(-300..=300)),
            },
            Some(DriveFault::SpeedReads { slave, rpm: None }),
        ),
    };
    plan.push(t, Event::Drive(on));
    if let Some(off) = off {
        plan.push(t + ms, Event::Drive(off));
    }
    // Someone confirms the fault after it healed.
    let confirm_at = t + ms + plan.range(200, 2_000);
    let press = plan.range(60, 800) as u32;
    plan.push(confirm_at, Event::Button { ms: press });
    ms + 2_000
}

fn flash_fault(plan: &mut Plan, t: u64) -> u64 {
    let fault = match plan.range(0, 2) {
        0 => FlashFault::StallNextErase {
            ms: plan.range(100, 400) as u16,
        },
        1 => FlashFault::FailWrites {
            count: plan.range(1, 3) as u8,
        },
        _ => FlashFault::PowerCut {
            after_bytes: plan.range(0, 8_192) as u32,
        },
    };
    plan.push(t, Event::Flash(fault));
    0
}

fn bus_fault(plan: &mut Plan, t: u64) -> u64 {
    let fault = if plan.chance(0.5) {
        Event::BusOff
    } else {
        Event::RxOverrun
    };
    plan.push(t, fault);
    0
}

fn reset(plan: &mut Plan, t: u64) -> u64 {
    let kind = match plan.range(0, 19) {
        0..=9 => ResetKind::Button,
        10..=16 => ResetKind::Panic,
        _ => ResetKind::PowerOn,
    };
    plan.push(t, Event::Reset(kind));
    0
}
