//! Debouncing of digital inputs (e-stop button, safety-zone signal, front button): owns
//! the stable level of one input. The input task samples the pin and feeds every
//! sample in; the supervisor and the power logic only see the stable level's changes.

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

    proptest! {
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
