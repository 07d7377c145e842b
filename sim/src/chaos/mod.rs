//! The robot tests itself: a seeded, deterministic simulation of the whole robot that
//! throws every input at once — the PC's programs on CAN (driving at any rate and
//! sign, register reads and writes, calibrations, floods, firmware updates good and
//! bad), two pads, the e-stop and the zone (clean and chattering), the front button,
//! battery and weight, drive faults, flash faults, resets, panics and power cuts — at
//! the firmware's real tasks on the virtual clock, and checks the safety rules of
//! docs/behaviour.md ([`rules`]) at every observation and control cycle ([`oracle`]).
//!
//! A run is fixed by its event list, which a seed generates ([`generate`]); the same
//! list gives the same run on any machine. A violation comes with its seed, its rule,
//! the last events and what the robot did; [`shrink`] cuts the list down to the
//! events that still break the rule, and [`case`] writes it as a file that the test
//! run replays. docs/tests.md says how to run, read and replay.

pub mod case;
pub mod event;
pub mod generate;
pub mod oracle;
mod programs;
pub mod registers;
pub mod rules;
pub mod shrink;
pub mod world;

use std::cell::RefCell;
use std::future::Future;
use std::pin::Pin;
use std::sync::Once;
use std::task::Poll;

use embassy_futures::select::{Either, select, select3};
use embassy_time::{Duration, Instant, Timer};

pub use event::{Event, Timed};
pub use oracle::Violation;
pub use rules::Rule;

use crate::runtime::{block_on, now};
use world::{World, WorldConfig, micros};

/// A chip's bootloader and start-up: the line to the drives is silent meanwhile.
pub const BOOT_TIME_MS: u64 = 300;

/// What one run did.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Virtual time the run lasted (to its end, or to the violation).
    pub virtual_ms: u64,
    /// Events started.
    pub events: u64,
    pub violation: Option<Found>,
    /// Wall-clock time the run took.
    pub wall: std::time::Duration,
}

/// A violation with its context, times from the run's start.
#[derive(Debug, Clone)]
pub struct Found {
    pub rule: Rule,
    pub at_ms: f64,
    pub what: String,
    /// The last events started before it.
    pub last_events: Vec<String>,
    /// The last things the robot did (orders, modes, boots).
    pub last_observations: Vec<String>,
}

impl std::fmt::Display for Found {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{} broken at {:.3} s:", self.rule, self.at_ms / 1000.0)?;
        writeln!(f, "  {}", self.what)?;
        writeln!(f, "the last events:")?;
        for line in &self.last_events {
            writeln!(f, "  {line}")?;
        }
        writeln!(f, "what the robot did last (times since the run's start):")?;
        for line in &self.last_observations {
            writeln!(f, "  {line}")?;
        }
        Ok(())
    }
}

thread_local! {
    /// While a run is on: the first panic's message and place, instead of printing it.
    static PANIC: RefCell<Option<Option<String>>> = const { RefCell::new(None) };
}

/// Panics inside a run are the controller's: recorded for the oracle, not printed.
fn quiet_panics() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let recorded = PANIC.with(|panic| {
                let mut panic = panic.borrow_mut();
                match panic.as_mut() {
                    Some(slot) => {
                        if slot.is_none() {
                            *slot = Some(info.to_string());
                        }
                        true
                    }
                    None => false,
                }
            });
            if !recorded {
                previous(info);
            }
        }));
    });
}

/// Runs `events` for `duration_ms` of virtual time (or to the first violation).
pub fn run(events: &[Timed], duration_ms: u64) -> Outcome {
    quiet_panics();
    let wall = std::time::Instant::now();
    let world = World::new(WorldConfig {
        boot_time: Duration::from_millis(BOOT_TIME_MS),
    });
    let start = now();
    let end = start + Duration::from_millis(duration_ms);
    PANIC.with(|panic| *panic.borrow_mut() = Some(None));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        block_on(async {
            let script = select3(
                world.monitor(),
                world.ticks(end),
                dispatch(&world, events, start),
            );
            match select(world.controller(), script).await {
                Either::First(never) => never,
                Either::Second(_) => {}
            }
        })
    }));
    let panic_message = PANIC.with(|panic| panic.borrow_mut().take().flatten());
    if result.is_err() {
        let message = panic_message.unwrap_or_else(|| "(no message)".to_owned());
        world.observe(|oracle, at| oracle.panicked(at, &message));
    }
    let ended = now();
    let events_started = world.events_started.get();
    let last_events: Vec<String> = world.applied.borrow().iter().cloned().collect();
    let start_us = micros(start);
    let (violation, recent) =
        world.observe(|oracle, _| (oracle.violation().cloned(), oracle.recent()));
    let violation = violation.map(|violation| Found {
        rule: violation.rule,
        at_ms: violation.at_us.saturating_sub(start_us) as f64 / 1000.0,
        what: violation.what,
        last_events: last_events
            .iter()
            .rev()
            .take(16)
            .rev()
            .map(|line| shift_times(line, start_us))
            .collect(),
        last_observations: recent
            .into_iter()
            .map(|line| shift_times(&line, start_us))
            .collect(),
    });
    Outcome {
        virtual_ms: (ended - start).as_millis(),
        events: events_started,
        violation,
        wall: wall.elapsed(),
    }
}

/// The oracle's lines carry absolute virtual seconds: make them the run's.
fn shift_times(line: &str, start_us: u64) -> String {
    let trimmed = line.trim_start();
    match trimmed.split_once(" s  ") {
        Some((seconds, rest)) => match seconds.parse::<f64>() {
            Ok(seconds) => format!("{:>10.3} s  {rest}", seconds - start_us as f64 / 1e6),
            Err(_) => line.to_owned(),
        },
        None => line.to_owned(),
    }
}

/// Starts each event at its time and runs the programs among them side by side.
async fn dispatch(world: &World, events: &[Timed], start: Instant) -> ! {
    let mut running: Vec<Pin<Box<dyn Future<Output = ()> + '_>>> = Vec::new();
    let mut next = 0;
    let mut timer: Option<(Instant, Timer)> = None;
    core::future::poll_fn(|cx| {
        loop {
            while let Some(timed) = events.get(next)
                && start + Duration::from_millis(timed.at_ms) <= now()
            {
                if let Some(program) = world.start(&timed.event) {
                    running.push(program);
                }
                next += 1;
            }
            running.retain_mut(|program| program.as_mut().poll(cx).is_pending());
            let Some(timed) = events.get(next) else {
                return Poll::Pending;
            };
            let due = start + Duration::from_millis(timed.at_ms);
            if timer.as_ref().is_none_or(|(at, _)| *at != due) {
                timer = Some((due, Timer::at(due)));
            }
            let Some((_, waiting)) = timer.as_mut() else {
                return Poll::Pending;
            };
            if Pin::new(waiting).poll(cx).is_pending() {
                return Poll::Pending;
            }
            timer = None;
        }
    })
    .await
}

/// A seed's run: its events and what happened.
pub fn run_seed(seed: u64, duration_ms: u64, mix: generate::Mix) -> (Vec<Timed>, Outcome) {
    let events = generate::generate(seed, duration_ms, mix);
    let outcome = run(&events, duration_ms);
    (events, outcome)
}

/// What many runs did, for the report line.
#[derive(Debug, Clone, Copy, Default)]
pub struct Totals {
    pub runs: u64,
    pub virtual_ms: u64,
    pub events: u64,
    pub violations: u64,
    pub wall: std::time::Duration,
}

impl Totals {
    pub fn add(&mut self, outcome: &Outcome) {
        self.runs += 1;
        self.virtual_ms += outcome.virtual_ms;
        self.events += outcome.events;
        self.violations += u64::from(outcome.violation.is_some());
        self.wall += outcome.wall;
    }
}

impl std::fmt::Display for Totals {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let hours = self.virtual_ms as f64 / 3.6e6;
        let speed = self.virtual_ms as f64 / 1000.0 / self.wall.as_secs_f64().max(1e-9);
        write!(
            f,
            "whole-robot simulation: {} runs, {hours:.2} virtual hours, {} events, {} violations ({speed:.0} times real time)",
            self.runs, self.events, self.violations
        )
    }
}

/// A seed's run broke a rule: the report a person reads, the shrunk case, and where
/// it was written.
#[derive(Debug, Clone)]
pub struct Finding {
    pub seed: u64,
    pub mix: generate::Mix,
    pub duration_ms: u64,
    pub found: Found,
    pub shrunk: Option<shrink::Shrunk>,
    pub case_file: Option<std::path::PathBuf>,
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "whole-robot simulation: seed {} ({} virtual minutes) breaks {}",
            self.seed,
            self.duration_ms / 60_000,
            self.found.rule
        )?;
        write!(f, "{}", self.found)?;
        writeln!(
            f,
            "replay the seed: cargo run -p virtual-robot --release --example chaos -- --seed {} --runs 1 --minutes {} {}",
            self.seed,
            self.duration_ms.div_ceil(60_000),
            self.mix.option()
        )?;
        if let Some(shrunk) = &self.shrunk {
            writeln!(
                f,
                "shrunk to {} events in {} runs:",
                shrunk.events.len(),
                shrunk.runs
            )?;
            for timed in &shrunk.events {
                writeln!(f, "  {timed}")?;
            }
        }
        if let Some(path) = &self.case_file {
            writeln!(
                f,
                "replay the shrunk case: cargo run -p virtual-robot --release --example chaos -- --replay {}",
                path.display()
            )?;
        }
        Ok(())
    }
}

/// Shrinks a seed's violation and writes the case into `directory` (if given) as
/// `seed-S-rule-R.jsonl`.
pub fn investigate(
    seed: u64,
    mix: generate::Mix,
    duration_ms: u64,
    events: &[Timed],
    found: Found,
    budget: Option<shrink::Budget>,
    directory: Option<&std::path::Path>,
) -> Finding {
    let shrunk = budget.map(|budget| shrink::shrink(events, found.rule, found.at_ms, budget));
    let case_file = match (&shrunk, directory) {
        (Some(shrunk), Some(directory)) => {
            let case = case::Case {
                comments: vec![
                    format!(
                        "{} broken at {:.3} s: {}",
                        found.rule,
                        found.at_ms / 1000.0,
                        found.what
                    ),
                    format!(
                        "found with seed {seed} ({} virtual minutes), shrunk from {} events",
                        duration_ms / 60_000,
                        events.len()
                    ),
                ],
                header: case::Header {
                    duration_ms: shrunk.duration_ms,
                    seed: Some(seed),
                    rule: Some(found.rule.number()),
                },
                events: shrunk.events.clone(),
            };
            let path = directory.join(format!("seed-{seed}-rule-{}.jsonl", found.rule.number()));
            std::fs::create_dir_all(directory)
                .and_then(|()| std::fs::write(&path, case.to_text()))
                .ok()
                .map(|()| path)
        }
        _ => None,
    };
    Finding {
        seed,
        mix,
        duration_ms,
        found,
        shrunk,
        case_file,
    }
}
