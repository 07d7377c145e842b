//! When each periodic frame is due: odometry (0x0EC + 0x0ED), battery (0x0EB), weight
//! (0x0EA) and status (0x0EE). The controller polls it with the time and the periods from
//! the registers; the CAN task sends what is due.

use crate::time::Timestamp;

/// The periods in ms, straight from the registers. A status period of 0 turns the status
/// frame off; the others are never 0 (the register table forbids it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeedbackPeriods {
    pub odometry_ms: u32,
    pub battery_ms: u32,
    pub weight_ms: u32,
    pub status_ms: u32,
}

/// Which frames are due now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeedbackDue {
    pub odometry: bool,
    pub battery: bool,
    pub weight: bool,
    pub status: bool,
}

/// One periodic frame's next deadline. Deadlines advance by whole periods so the frames
/// keep their rate without drift; after a long stall (or a period change) the deadline
/// restarts from `now` instead of firing a burst of catch-up frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Periodic {
    next: Timestamp,
}

impl Periodic {
    fn due(&mut self, now: Timestamp, period_ms: u32) -> bool {
        if period_ms == 0 || now < self.next {
            return false;
        }
        let period = u64::from(period_ms);
        let advanced = self.next.plus_millis(period);
        self.next = if advanced > now {
            advanced
        } else {
            now.plus_millis(period)
        };
        true
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeedbackSchedule {
    odometry: Periodic,
    battery: Periodic,
    weight: Periodic,
    status: Periodic,
}

impl FeedbackSchedule {
    /// Every frame is first due at `start`.
    pub const fn new(start: Timestamp) -> Self {
        let first = Periodic { next: start };
        Self {
            odometry: first,
            battery: first,
            weight: first,
            status: first,
        }
    }

    /// The frames due at `now`. In emergency mode odometry, battery and weight are never
    /// due (the manual forbids them); their deadlines still advance, so they resume on
    /// their old rhythm afterwards instead of all at once.
    pub fn poll(
        &mut self,
        now: Timestamp,
        periods: &FeedbackPeriods,
        emergency: bool,
    ) -> FeedbackDue {
        let odometry = self.odometry.due(now, periods.odometry_ms);
        let battery = self.battery.due(now, periods.battery_ms);
        let weight = self.weight.due(now, periods.weight_ms);
        FeedbackDue {
            odometry: odometry && !emergency,
            battery: battery && !emergency,
            weight: weight && !emergency,
            status: self.status.due(now, periods.status_ms),
        }
    }

    /// When the next odometry frame (position and heading) is due.
    pub fn odometry_due_at(&self) -> Timestamp {
        self.odometry.next
    }

    /// The earliest deadline, so the shell can sleep until then.
    pub fn next_deadline(&self, periods: &FeedbackPeriods) -> Option<Timestamp> {
        [
            (self.odometry, periods.odometry_ms),
            (self.battery, periods.battery_ms),
            (self.weight, periods.weight_ms),
            (self.status, periods.status_ms),
        ]
        .into_iter()
        .filter(|(_, period)| *period != 0)
        .map(|(periodic, _)| periodic.next)
        .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIODS: FeedbackPeriods = FeedbackPeriods {
        odometry_ms: 50,
        battery_ms: 5000,
        weight_ms: 1000,
        status_ms: 1000,
    };

    fn count_over(
        schedule: &mut FeedbackSchedule,
        from_ms: u64,
        to_ms: u64,
        emergency: bool,
    ) -> [u32; 4] {
        let mut counts = [0; 4];
        for ms in from_ms..to_ms {
            let due = schedule.poll(Timestamp::from_millis(ms), &PERIODS, emergency);
            for (count, fired) in
                counts
                    .iter_mut()
                    .zip([due.odometry, due.battery, due.weight, due.status])
            {
                *count += u32::from(fired);
            }
        }
        counts
    }

    #[test]
    fn default_periods_give_the_manuals_rates_over_ten_seconds() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        assert_eq!(
            count_over(&mut schedule, 0, 10_000, false),
            [200, 2, 10, 10]
        );
    }

    #[test]
    fn emergency_suppresses_every_feedback_frame_but_not_the_status() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        assert_eq!(count_over(&mut schedule, 0, 10_000, true), [0, 0, 0, 10]);
    }

    #[test]
    fn feedback_resumes_on_its_rhythm_after_an_emergency() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        count_over(&mut schedule, 0, 1_000, true);
        let due = schedule.poll(Timestamp::from_millis(1_000), &PERIODS, false);
        assert!(due.odometry && due.weight && due.status && !due.battery);
    }

    #[test]
    fn status_period_zero_turns_the_status_frame_off() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        let periods = FeedbackPeriods {
            status_ms: 0,
            ..PERIODS
        };
        for ms in 0..3_000 {
            assert!(
                !schedule
                    .poll(Timestamp::from_millis(ms), &periods, false)
                    .status
            );
        }
    }

    #[test]
    fn a_stalled_caller_gets_one_frame_not_a_burst() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        assert!(schedule.poll(Timestamp::BOOT, &PERIODS, false).odometry);
        assert!(
            schedule
                .poll(Timestamp::from_millis(1_000), &PERIODS, false)
                .odometry
        );
        assert!(
            !schedule
                .poll(Timestamp::from_millis(1_001), &PERIODS, false)
                .odometry
        );
        assert!(
            schedule
                .poll(Timestamp::from_millis(1_050), &PERIODS, false)
                .odometry
        );
    }

    #[test]
    fn late_polls_keep_the_average_rate_without_drift() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        // Polled every 7 ms: each frame goes out up to 6 ms late, but 1000 s still give
        // exactly 20 000 odometry frames.
        let sent = (0..1_000_000u64)
            .step_by(7)
            .filter(|&ms| {
                schedule
                    .poll(Timestamp::from_millis(ms), &PERIODS, false)
                    .odometry
            })
            .count();
        assert_eq!(sent, 20_000);
    }

    #[test]
    fn next_deadline_is_the_earliest_enabled_one() {
        let mut schedule = FeedbackSchedule::new(Timestamp::BOOT);
        schedule.poll(Timestamp::BOOT, &PERIODS, false);
        assert_eq!(
            schedule.next_deadline(&PERIODS),
            Some(Timestamp::from_millis(50))
        );
    }
}
