//! The liveness task: feeds the hardware watchdog only while every critical task keeps
//! checking in. A task stuck in a loop or waiting forever stops the feeding, and the
//! watchdog resets the chip; the next boot reports it in the status frame.

use embassy_time::{Duration, Ticker};

use crate::hw::Watchdog;

use core::cell::Cell;
use embassy_sync::blocking_mutex::Mutex;

use crate::sync::RawMutex;

/// How often the check-ins are collected. Every critical task checks in at least every
/// 200 ms (the drive link's poll interval), so a healthy firmware feeds each period;
/// the board sets the hardware timeout to several periods (≥ 2 s).
pub const CHECK_PERIOD: Duration = Duration::from_millis(500);

pub async fn run<W: Watchdog>(mut watchdog: W, liveness: &Liveness) -> ! {
    let mut ticker = Ticker::every(CHECK_PERIOD);
    loop {
        ticker.next().await;
        if liveness.all_checked_in() {
            watchdog.feed();
        }
    }
}

/// The tasks whose silence means the firmware hangs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CriticalTask {
    Controller = 0,
    DriveLink = 1,
    Inputs = 2,
}

impl CriticalTask {
    pub const ALL: [CriticalTask; 3] = [Self::Controller, Self::DriveLink, Self::Inputs];
    const fn bit(self) -> u8 {
        1 << self as u8
    }
}

/// Check-in marks: each critical task marks itself on every loop; the liveness task
/// feeds the watchdog only when all marks are set, then clears them.
pub struct Liveness {
    marks: Mutex<RawMutex, Cell<u8>>,
}

impl Liveness {
    pub const fn new() -> Self {
        Self {
            marks: Mutex::new(Cell::new(0)),
        }
    }

    pub fn check_in(&self, task: CriticalTask) {
        self.marks.lock(|marks| marks.set(marks.get() | task.bit()));
    }

    /// True if every critical task checked in since the last call; clears the marks.
    pub fn all_checked_in(&self) -> bool {
        let all = CriticalTask::ALL
            .iter()
            .fold(0, |bits, task| bits | task.bit());
        self.marks.lock(|marks| marks.replace(0)) & all == all
    }
}

impl Default for Liveness {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_watchdog_is_fed_only_when_every_critical_task_checked_in() {
        let liveness = Liveness::new();
        liveness.check_in(CriticalTask::Controller);
        liveness.check_in(CriticalTask::Inputs);
        assert!(!liveness.all_checked_in(), "the drive link is missing");
        for task in CriticalTask::ALL {
            liveness.check_in(task);
        }
        assert!(liveness.all_checked_in());
        assert!(!liveness.all_checked_in(), "the marks were cleared");
    }
}
