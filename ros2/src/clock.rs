//! The controller's clock mapped onto ROS time, so that `/odom` and `/tf` carry the
//! moment each pose holds (its 0x0EF time) rather than the moment the PC got round to
//! it.
//!
//! Every pose gives one sample `arrival − controller time`: the true offset between
//! the two clocks plus that frame's transit delay (queueing in the controller, the
//! bus, the adapter, a busy PC), which is never negative. The estimate is the smallest
//! sample seen, allowed to rise by at most [`RISE_PPM`] of the controller time since
//! the previous pose:
//! - a late frame (any delay, a 2 s pause of the PC) cannot move it by more than that
//!   rise, so late frames are stamped with their own moment, not their arrival;
//! - a prompt frame pulls it down at once;
//! - crystal drift up to ±100 ppm is followed: a PC clock that runs slower lowers the
//!   samples (followed at once), one that runs faster raises them by less than the
//!   rise allows.
//!
//! The stamp is then late by the smallest transit delay (a constant: sub-millisecond
//! on a local bus) plus at most `RISE_PPM` × the time since the last prompt frame,
//! and it never goes backwards: a stamp that would is set 1 µs after the one before.

use std::collections::VecDeque;

/// How fast the offset estimate may rise, in parts per million of controller time:
/// twice a drift of ±100 ppm between the two clocks (the PC's is usually disciplined
/// by NTP; the controller's crystal is good to a few tens of ppm).
pub const RISE_PPM: i64 = 200;
/// How many recent poses the delay figures in `/diagnostics` cover (5 s at 20 Hz).
const WINDOW: usize = 100;

/// One pose's time, mapped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mapped {
    /// The pose's moment in ROS time, ns since the epoch.
    pub stamp_ns: i64,
    /// How much later than the estimate this frame arrived, ns (≥ 0).
    pub delay_ns: i64,
}

/// Figures for `/diagnostics`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClockFigures {
    /// ROS time minus controller time, s.
    pub offset_s: f64,
    /// The median and the largest delay beyond the estimate over the last poses, ms.
    pub delay_p50_ms: f64,
    pub delay_max_ms: f64,
    /// Times the controller's clock went back: it rebooted.
    pub reboots: u64,
}

#[derive(Debug, Default)]
pub struct ControllerClock {
    /// The last pose's time as sent and unwrapped to 64 bits, ms.
    last: Option<(u32, u64)>,
    offset_ns: Option<i64>,
    last_stamp_ns: Option<i64>,
    delays_ns: VecDeque<i64>,
    reboots: u64,
}

impl ControllerClock {
    /// Maps a pose time (0x0EF) that arrived at `arrival_ns` (ROS time).
    pub fn map(&mut self, controller_ms: u32, arrival_ns: i64) -> Mapped {
        // Differences modulo 2^32: the counter wraps after 49.7 days. A step back (by
        // 2^31 ms or more) is a reboot: the old offset says nothing about the new
        // clock.
        let (unwrapped, elapsed_ms) = match self.last {
            Some((raw, unwrapped)) => match controller_ms.wrapping_sub(raw) {
                gap @ 0..0x8000_0000 => (unwrapped + u64::from(gap), Some(u64::from(gap))),
                _ => {
                    self.reboots += 1;
                    (u64::from(controller_ms), None)
                }
            },
            None => (u64::from(controller_ms), None),
        };
        self.last = Some((controller_ms, unwrapped));
        let controller_ns = i64::try_from(unwrapped)
            .unwrap_or(i64::MAX)
            .saturating_mul(1_000_000);
        let sample = arrival_ns.saturating_sub(controller_ns);
        let offset = match (self.offset_ns, elapsed_ms) {
            (Some(offset), Some(elapsed_ms)) => {
                // RISE_PPM of `elapsed_ms` ms, in ns.
                let rise = i64::try_from(elapsed_ms)
                    .unwrap_or(i64::MAX)
                    .saturating_mul(RISE_PPM);
                sample.min(offset.saturating_add(rise))
            }
            _ => sample,
        };
        self.offset_ns = Some(offset);
        let mut stamp_ns = controller_ns.saturating_add(offset);
        if let Some(last) = self.last_stamp_ns
            && stamp_ns <= last
        {
            stamp_ns = last + 1_000;
        }
        self.last_stamp_ns = Some(stamp_ns);
        let delay_ns = sample - offset;
        if self.delays_ns.len() == WINDOW {
            self.delays_ns.pop_front();
        }
        self.delays_ns.push_back(delay_ns);
        Mapped { stamp_ns, delay_ns }
    }

    /// `None` before the first pose time.
    pub fn figures(&self) -> Option<ClockFigures> {
        let offset_ns = self.offset_ns?;
        let mut delays: Vec<i64> = self.delays_ns.iter().copied().collect();
        delays.sort_unstable();
        let ms = |ns: i64| ns as f64 / 1e6;
        Some(ClockFigures {
            offset_s: offset_ns as f64 / 1e9,
            delay_p50_ms: delays.get(delays.len() / 2).copied().map_or(0.0, ms),
            delay_max_ms: delays.last().copied().map_or(0.0, ms),
            reboots: self.reboots,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CYCLE_MS: u32 = 50;
    /// Where the controller booted on the ROS clock.
    const BOOT_NS: i64 = 1_764_000_000_000_000_000;
    /// The smallest transit delay: bus and adapter.
    const MIN_DELAY_NS: i64 = 300_000;

    /// A pose time's true ROS moment, the controller's clock running `ppm` fast.
    fn truth_ns(controller_ms: u64, ppm: f64) -> i64 {
        BOOT_NS + (controller_ms as f64 * 1e6 / (1.0 + ppm * 1e-6)) as i64
    }

    /// A made-up delay between 0 and 20 ms, the same for the same pose.
    fn jitter_ns(cycle: u64) -> i64 {
        ((cycle * 7919 + 13) % 41) as i64 * 500_000
    }

    /// Checks every stamp against its truth (from `after` on) and that they increase.
    fn check(stamps: &[(i64, i64)], after: usize) {
        for pair in stamps.windows(2) {
            assert!(pair[1].0 > pair[0].0, "a stamp went backwards: {pair:?}");
        }
        for (index, &(stamp, truth)) in stamps.iter().enumerate().skip(after) {
            let late = stamp - truth;
            assert!(
                (0..=2_000_000).contains(&late),
                "pose {index}: stamp {:.3} ms from its moment",
                late as f64 / 1e6
            );
        }
    }

    #[test]
    fn jittered_arrivals_are_stamped_with_the_poses_moment_whatever_the_drift() {
        for ppm in [-100.0, 0.0, 100.0] {
            let mut clock = ControllerClock::default();
            let mut stamps = Vec::new();
            // Ten minutes of poses; every 20th arrives with only the smallest delay.
            for cycle in 0..12_000u64 {
                let controller_ms = 1_000 + cycle * u64::from(CYCLE_MS);
                let delay = MIN_DELAY_NS + if cycle % 20 == 0 { 0 } else { jitter_ns(cycle) };
                let truth = truth_ns(controller_ms, ppm);
                let mapped = clock.map(controller_ms as u32, truth + delay);
                stamps.push((mapped.stamp_ns, truth));
            }
            check(&stamps, 20);
        }
    }

    #[test]
    fn a_two_second_pause_of_the_pc_leaves_the_stamps_on_the_poses_moments() {
        let mut clock = ControllerClock::default();
        let mut stamps = Vec::new();
        let mut cycle = 0u64;
        // A pose's (stamp, truth); `arrival` None: with its usual delay.
        fn pose(clock: &mut ControllerClock, cycle: u64, arrival: Option<i64>) -> (i64, i64) {
            let controller_ms = 500 + cycle * u64::from(CYCLE_MS);
            let truth = truth_ns(controller_ms, 100.0);
            let arrival = arrival.unwrap_or(truth + MIN_DELAY_NS + jitter_ns(cycle));
            (clock.map(controller_ms as u32, arrival).stamp_ns, truth)
        }
        for _ in 0..100 {
            stamps.push(pose(&mut clock, cycle, None));
            cycle += 1;
        }
        // The PC stops for 2 s; the 40 poses of that time arrive at once after it.
        let resumed = truth_ns(500 + (cycle + 40) * u64::from(CYCLE_MS), 100.0);
        for _ in 0..40 {
            stamps.push(pose(&mut clock, cycle, Some(resumed + MIN_DELAY_NS)));
            cycle += 1;
        }
        for _ in 0..100 {
            stamps.push(pose(&mut clock, cycle, None));
            cycle += 1;
        }
        // From the first pose that came with only the smallest delay (within 41).
        check(&stamps, 41);
    }

    #[test]
    fn a_reboot_of_the_controller_starts_the_estimate_anew_and_the_stamps_go_on() {
        let mut clock = ControllerClock::default();
        let mut last = 0;
        for cycle in 0..100u32 {
            let controller_ms = 600_000 + cycle * CYCLE_MS;
            last = clock
                .map(
                    controller_ms,
                    BOOT_NS + i64::from(controller_ms) * 1_000_000,
                )
                .stamp_ns;
        }
        // Rebooted: its clock starts near zero, 2 s after the last pose.
        let rebooted_at = last + 2_000_000_000;
        let mapped = clock.map(300, rebooted_at + MIN_DELAY_NS);
        assert_eq!(mapped.stamp_ns, rebooted_at + MIN_DELAY_NS);
        let next = clock.map(350, rebooted_at + 50_000_000 + MIN_DELAY_NS);
        assert_eq!(next.stamp_ns, rebooted_at + 50_000_000 + MIN_DELAY_NS);
        assert_eq!(clock.figures().map(|figures| figures.reboots), Some(1));
    }

    #[test]
    fn the_counter_wrapping_after_49_days_is_not_a_reboot() {
        let mut clock = ControllerClock::default();
        let before = clock.map(u32::MAX - 10, BOOT_NS);
        let after = clock.map(39, BOOT_NS + 50_000_000);
        assert_eq!(after.stamp_ns - before.stamp_ns, 50_000_000);
        assert_eq!(clock.figures().map(|figures| figures.reboots), Some(0));
    }
}
