//! Shrinking: delta debugging (Zeller's ddmin) over a failing run's event list. Every
//! event after the violation is dropped first (a run is deterministic, so nothing
//! later can matter); then chunks of the list are removed as long as the run still
//! breaks the same rule, down to single events. Hand-written: the list is plain data
//! and each test is a whole run, which no property-testing shrinker models directly.

use super::{Rule, Timed, run};

/// How far shrinking may go.
#[derive(Debug, Clone, Copy)]
pub struct Budget {
    /// Runs at most.
    pub runs: u32,
    /// Wall-clock time at most.
    pub wall: std::time::Duration,
}

impl Default for Budget {
    fn default() -> Self {
        Self {
            runs: 400,
            wall: std::time::Duration::from_secs(300),
        }
    }
}

/// The shrunk list, how long a run of it lasts, and the runs it took.
#[derive(Debug, Clone)]
pub struct Shrunk {
    pub events: Vec<Timed>,
    pub duration_ms: u64,
    pub runs: u32,
}

/// Cuts `events`, whose run breaks `rule` at `at_ms`, down to a short list that still
/// breaks it.
pub fn shrink(events: &[Timed], rule: Rule, at_ms: f64, budget: Budget) -> Shrunk {
    let started = std::time::Instant::now();
    // The run may end a little after the violation's moment.
    let duration_ms = at_ms.ceil() as u64 + 2_000;
    let mut current: Vec<Timed> = events
        .iter()
        .filter(|timed| timed.at_ms as f64 <= at_ms)
        .cloned()
        .collect();
    let runs = std::cell::Cell::new(0u32);
    let fails = |candidate: &[Timed]| -> bool {
        runs.set(runs.get() + 1);
        run(candidate, duration_ms)
            .violation
            .is_some_and(|found| found.rule == rule)
    };
    let out_of_budget = || runs.get() >= budget.runs || started.elapsed() >= budget.wall;
    let mut chunks = 2usize;
    while current.len() >= 2 && !out_of_budget() {
        let size = current.len().div_ceil(chunks);
        let mut removed_one = false;
        let mut start = 0;
        while start < current.len() && !out_of_budget() {
            let candidate: Vec<Timed> = current[..start]
                .iter()
                .chain(current[(start + size).min(current.len())..].iter())
                .cloned()
                .collect();
            if fails(&candidate) {
                current = candidate;
                removed_one = true;
                chunks = (chunks - 1).max(2);
            } else {
                start += size;
            }
        }
        if !removed_one {
            if size == 1 {
                break;
            }
            chunks = (chunks * 2).min(current.len());
        }
    }
    // A rule broken with no event at all.
    if current.len() == 1 && !out_of_budget() && fails(&[]) {
        current.clear();
    }
    Shrunk {
        events: current,
        duration_ms,
        runs: runs.get(),
    }
}
