//! Debouncing of digital inputs: owns the stable level of one input. The input task
//! samples the pin and feeds every sample in; the supervisor and the power logic only
//! see the stable level's changes.
//!
//! Two kinds: [`Debouncer`] treats both directions alike (the front button, where a
//! bounce must not count as a second press), [`SafetyDebouncer`] is asymmetric (the
//! e-stop and the safety zone, where a chattering contact must count as active).

use crate::time::Timestamp;

/// Debounces one digital input: a new level is accepted only after the raw input has
/// shown it, without interruption, for `stable_ms`. A glitch shorter than that (contact
/// bounce, EMI) is ignored; any sample back at the stable level restarts the wait.
///
/// The wait is measured from the first sample that showed the new level, so the
/// accepted change comes `stable_ms` after the edge plus at most one sampling period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Debouncer {
    stable: bool,
    stable_ms: u32,
    /// When the raw input first differed from `stable`; `None` while it agrees.
    changing_since: Option<Timestamp>,
}

impl Debouncer {
    /// `initial` is the level assumed at start-up. Pick the safe one for the input (for
    /// the e-stop: "pressed"), so a wrong guess errs on the safe side until the real
    /// level has been stable for `stable_ms`.
    pub const fn new(initial: bool, stable_ms: u32) -> Self {
        Self {
            stable: initial,
            stable_ms,
            changing_since: None,
        }
    }

    /// Feed the raw level sampled at `now`. Returns the new stable level when it
    /// changes, `None` otherwise.
    pub fn update(&mut self, now: Timestamp, raw: bool) -> Option<bool> {
        if raw == self.stable {
            self.changing_since = None;
            return None;
        }
        let since = *self.changing_since.get_or_insert(now);
        if now.millis_since(since) >= u64::from(self.stable_ms) {
            self.stable = raw;
            self.changing_since = None;
            Some(raw)
        } else {
            None
        }
    }

    /// The current stable level.
    pub fn level(&self) -> bool {
        self.stable
    }
}

/// Debounces a safety input (e-stop, safety zone) towards its safe side: the first
/// active sample makes it active at once, and it becomes inactive only after the raw
/// input stayed inactive for more than `release_ms` without a single active sample.
///
/// So a contact that chatters, whatever its period and duty, reads as active as long as
/// any sample catches it active; and the input reads active whenever the raw input was
/// active within the last `release_ms`. The price is that one spike on the wire trips
/// the safe state, which for both inputs only costs a stop, never a motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SafetyDebouncer {
    active: bool,
    release_ms: u32,
    /// When the raw input was first seen inactive while `active`; `None` otherwise.
    releasing_since: Option<Timestamp>,
}

impl SafetyDebouncer {
    /// `initial` is the level assumed at start-up; an active start is released only
    /// after the input proved inactive for `release_ms`.
    pub const fn new(initial: bool, release_ms: u32) -> Self {
        Self {
            active: initial,
            release_ms,
            releasing_since: None,
        }
    }

    /// Feed the raw level (`true` = active) sampled at `now`. Returns the new stable
    /// level when it changes, `None` otherwise.
    ///
    /// The release needs `now − first inactive sample > release_ms` in whole
    /// milliseconds, so with timestamps truncated to the millisecond the input has
    /// really been inactive for more than `release_ms`.
    pub fn update(&mut self, now: Timestamp, raw: bool) -> Option<bool> {
        if raw {
            self.releasing_since = None;
            if self.active {
                return None;
            }
            self.active = true;
            return Some(true);
        }
        if !self.active {
            return None;
        }
        let since = *self.releasing_since.get_or_insert(now);
        if now.millis_since(since) > u64::from(self.release_ms) {
            self.active = false;
            self.releasing_since = None;
            Some(false)
        } else {
            None
        }
    }

    /// The current stable level (`true` = active).
    pub fn level(&self) -> bool {
        self.active
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn ms(ms: u64) -> Timestamp {
        Timestamp::from_millis(ms)
    }

    /// Feed (time, raw) samples, return the reported changes as (time, level).
    fn run(debouncer: &mut Debouncer, samples: &[(u64, bool)]) -> Vec<(u64, bool)> {
        samples
            .iter()
            .filter_map(|&(t, raw)| debouncer.update(ms(t), raw).map(|level| (t, level)))
            .collect()
    }

    #[test]
    fn level_held_for_stable_ms_is_accepted() {
        let mut d = Debouncer::new(false, 20);
        let changes = run(
            &mut d,
            &[
                (0, false),
                (5, true),
                (10, true),
                (20, true),
                (25, true),
                (30, true),
            ],
        );
        assert_eq!(changes, vec![(25, true)]);
        assert!(d.level());
    }

    #[test]
    fn change_is_reported_once() {
        let mut d = Debouncer::new(false, 10);
        let changes = run(&mut d, &[(0, true), (10, true), (20, true), (30, true)]);
        assert_eq!(changes, vec![(10, true)]);
    }

    #[test]
    fn glitch_shorter_than_stable_ms_is_ignored() {
        let mut d = Debouncer::new(true, 20);
        let changes = run(
            &mut d,
            &[(0, true), (1, false), (19, false), (20, true), (50, true)],
        );
        assert!(changes.is_empty());
        assert!(d.level());
    }

    #[test]
    fn chattering_contact_settles_only_after_it_stops_bouncing() {
        // A button closing: 1 ms samples, bouncing for 12 ms, then solidly closed.
        let mut samples = Vec::new();
        for t in 0..12u64 {
            samples.push((t, t % 3 != 0));
        }
        for t in 12..60u64 {
            samples.push((t, true));
        }
        let mut d = Debouncer::new(false, 20);
        let changes = run(&mut d, &samples);
        // The last bounce back to open was at 9 ms; closed from 10 ms on.
        assert_eq!(changes, vec![(30, true)]);
    }

    #[test]
    fn release_is_debounced_as_well() {
        let mut d = Debouncer::new(true, 15);
        let changes = run(
            &mut d,
            &[(0, false), (5, true), (6, false), (15, false), (21, false)],
        );
        assert_eq!(changes, vec![(21, false)]);
        assert!(!d.level());
    }

    #[test]
    fn zero_stable_ms_follows_the_raw_level() {
        let mut d = Debouncer::new(false, 0);
        assert_eq!(d.update(ms(0), true), Some(true));
        assert_eq!(d.update(ms(0), false), Some(false));
    }

    #[test]
    fn initial_level_holds_until_the_input_proves_otherwise() {
        let mut d = Debouncer::new(true, 50);
        assert_eq!(d.update(ms(0), false), None);
        assert!(d.level());
        assert_eq!(d.update(ms(50), false), Some(false));
    }

    /// A chattering contact, as a level over time in microseconds: active for
    /// `active_us` of every `period_us`, starting `phase_us` into the pattern.
    struct Chatter {
        period_us: u64,
        active_us: u64,
        phase_us: u64,
    }

    impl Chatter {
        fn active_at(&self, t_us: u64) -> bool {
            (t_us + self.phase_us) % self.period_us < self.active_us
        }
    }

    /// The input task's sampling period for the safety inputs.
    const SAMPLE_US: u64 = 200;

    /// Samples `chatter` every [`SAMPLE_US`] for `for_us` from `start_us` into
    /// `debouncer`; returns the first time (µs) the level was active, and whether it
    /// stayed active from then on.
    fn sample_chatter(
        debouncer: &mut SafetyDebouncer,
        chatter: &Chatter,
        start_us: u64,
        for_us: u64,
    ) -> (Option<u64>, bool) {
        let mut first_active = None;
        let mut stayed = true;
        for t_us in (start_us..start_us + for_us).step_by(SAMPLE_US as usize) {
            debouncer.update(ms(t_us / 1000), chatter.active_at(t_us));
            match (first_active, debouncer.level()) {
                (None, true) => first_active = Some(t_us),
                (Some(_), false) => stayed = false,
                _ => {}
            }
        }
        (first_active, stayed)
    }

    /// Every pattern of the fault-injection review (e-stop chatter at 0.5–2 ms periods,
    /// 50–90 % active; the zone at 9 ms on / 1 ms off and 50/50 ms), at several phases
    /// against the sampling: active within one period, and active throughout.
    #[test]
    fn every_chatter_pattern_is_active_from_its_first_period_on() {
        let mut patterns = Vec::new();
        for period_us in [500, 700, 1_000, 1_300, 1_500, 2_000] {
            for percent in [50, 60, 70, 80, 90] {
                patterns.push((period_us, period_us * percent / 100));
            }
        }
        patterns.push((10_000, 9_000));
        patterns.push((100_000, 50_000));
        for (period_us, active_us) in patterns {
            for phase_us in (0..period_us).step_by(37) {
                let chatter = Chatter {
                    period_us,
                    active_us,
                    phase_us,
                };
                let mut debouncer = SafetyDebouncer::new(false, 100);
                let (first, stayed) = sample_chatter(&mut debouncer, &chatter, 0, 500_000);
                let first = first.unwrap_or_else(|| {
                    panic!("{active_us}/{period_us} µs at phase {phase_us} not detected")
                });
                assert!(
                    first <= period_us,
                    "{active_us}/{period_us} µs at phase {phase_us}: active at {first} µs"
                );
                assert!(
                    stayed,
                    "{active_us}/{period_us} µs at phase {phase_us} released while chattering"
                );
            }
        }
    }

    #[test]
    fn a_safety_input_is_active_on_its_first_active_sample() {
        let mut d = SafetyDebouncer::new(false, 10);
        assert_eq!(d.update(ms(0), false), None);
        assert_eq!(d.update(ms(1), true), Some(true));
        assert_eq!(d.update(ms(2), true), None);
        assert!(d.level());
    }

    #[test]
    fn a_safety_input_is_released_only_after_a_stable_release() {
        let mut d = SafetyDebouncer::new(true, 10);
        let changes: Vec<(u64, bool)> = [
            (0, false),
            (5, false),
            (10, true), // one active sample restarts the wait
            (11, false),
            (21, false),
            (22, false),
        ]
        .iter()
        .filter_map(|&(t, raw)| d.update(ms(t), raw).map(|level| (t, level)))
        .collect();
        assert_eq!(changes, vec![(22, false)]);
    }

    #[test]
    fn a_safety_input_that_starts_active_waits_for_the_release() {
        let mut d = SafetyDebouncer::new(true, 50);
        assert_eq!(d.update(ms(0), false), None);
        assert_eq!(d.update(ms(50), false), None);
        assert_eq!(d.update(ms(51), false), Some(false));
    }

    #[test]
    fn a_zero_release_time_releases_on_the_next_millisecond() {
        let mut d = SafetyDebouncer::new(false, 0);
        assert_eq!(d.update(ms(0), true), Some(true));
        assert_eq!(d.update(ms(0), false), None);
        assert_eq!(d.update(ms(1), false), Some(false));
    }

    proptest! {
        /// The zone's rule: the input reads active exactly when the raw input was
        /// active within the last `release_ms` (+1 ms for the unknown moment between
        /// the last active and the first inactive sample), sampled every millisecond.
        #[test]
        fn a_safety_input_reads_active_iff_it_was_active_within_the_release_window(
            raw in proptest::collection::vec(proptest::bool::weighted(0.2), 1..400),
            release_ms in 0u32..30,
        ) {
            let mut d = SafetyDebouncer::new(false, release_ms);
            let mut last_active: Option<u64> = None;
            for (t, &active) in raw.iter().enumerate() {
                let t = t as u64;
                d.update(ms(t), active);
                if active {
                    last_active = Some(t);
                }
                let expected =
                    last_active.is_some_and(|s| t - s <= u64::from(release_ms) + 1);
                prop_assert_eq!(d.level(), expected, "at {} ms", t);
            }
        }

        #[test]
        fn bursts_shorter_than_stable_ms_never_change_the_level(
            bursts in proptest::collection::vec((1u64..20, 1u64..50), 1..30),
        ) {
            // Opposite-level bursts of at most 19 ms (sampled every ms), separated by
            // returns to the stable level; stable_ms is 20.
            let mut d = Debouncer::new(false, 20);
            let mut t = 0u64;
            for (burst_ms, gap_ms) in bursts {
                for _ in 0..burst_ms {
                    prop_assert_eq!(d.update(ms(t), true), None);
                    t += 1;
                }
                for _ in 0..gap_ms {
                    prop_assert_eq!(d.update(ms(t), false), None);
                    t += 1;
                }
            }
            prop_assert!(!d.level());
        }
    }
}
