//! Plausibility of the drives' feedback: each drive reports two things about its
//! shaft, the position counter and the speed, and they must agree. The position that
//! the reported speeds predict over a window (the trapezoid integral of the samples)
//! is compared with the position change the counter shows:
//!
//! - the counter stands or lags while the speed says the shaft turns: a stuck encoder
//!   or a frozen position register ([`Finding::PositionStuck`]);
//! - the counter runs while the speed says it stands or runs slower: a stale (frozen)
//!   speed register ([`Finding::SpeedStale`]).
//!
//! Either lie breaks something the base relies on: the odometry (the pose drifts
//! without bound), or the standstill that gates the brakes, the flash and the motion
//! registers. So a mismatch latches a drive fault that stops the base.
//!
//! The same windows compare the counter with what the controller commanded: a counter
//! that runs against the sign of the command ([`Finding::WrongDirection`]) belongs to
//! a drive whose direction parameter differs from the one the controller was set up
//! for (a replaced drive, a parameter reset). Its position and speed agree with each
//! other, so the first check sees nothing, while the base spins or drives the wrong
//! way, or drives right with the odometry running backwards. The commanded speed is
//! the controller's own model of the ramps it sent ([`Commanded::expected`]), never
//! corrected by a measurement, so a wheel that keeps turning the wrong way cannot
//! drag it along. A wheel only counts as turning against its command when its counter,
//! averaged over a window, runs opposite to every target the wheel was told and to
//! every speed the model asked for over that window and the one before, each by at
//! least [`MIN_COMPARED_RPM`], in two windows in a row. The model integrates each
//! command from the moment the controller sent it; a command whose sign flips every
//! few tens of ms (two programs driving at once) makes it drift away from a healthy
//! drive that gets each command a few ms late, so a wheel told both ways within the
//! two windows is never judged against its command. A reversal passes through zero on
//! its ramp, and a drive follows it late (the command waits for the line, a failed
//! write is tried again, the drive's speed filter); a wheel that lags a reversal is
//! opposite only to the model's newest speeds, never to those of the window before.
//!
//! The samples come every 50 ms or so; a speed that bends between two of them (a ramp
//! that starts or ends, a PC turning the wheels round every few tens of ms at a high
//! `CAN_accel`) is missed by the speeds at the sampling moments, and their prediction
//! then misses an honest drive's counter. The controller knows where its commanded
//! ramps bend, so the tolerance grows by the most each bend can make the prediction
//! miss ([`bend_miss_rpm_ms`]), in the window of the bend and the one after (the
//! drive follows a little late). A steady speed, the stuck encoder's case, has no
//! bend and keeps the plain tolerance.
//!
//! Each sample also says whether the counter moved since the previous one, so that
//! standstill is judged from the position as well as from the reported speed
//! ([`Verdict::position_standing`]).
//!
//! What the drives' feedback cannot show: a shaft that turns as commanded but drives
//! its wheel the wrong way (swapped drive addresses, a wrong `motor_dir`, a drive
//! whose direction parameter turns its reports round with its shaft). Position, speed
//! and command all agree in the drive's own frame; only the mapping from shaft to
//! wheel is wrong, and nothing on the base measures the wheels independently. The
//! commissioning check (`basectl commission wheels`) covers that, with a person
//! watching the wheels.

use crate::drives::AT_REST_RPM;
use crate::kinematics::MotorRpm;
use crate::odometry::EncoderCounts;
use crate::supervisor::Wheel;
use crate::time::Timestamp;

/// A window is judged once it spans at least this long.
pub const WINDOW_MS: u64 = 100;
/// Two windows in a row must disagree before the fault latches: one odd window (a
/// reading taken mid-update) is no reason to stop the base.
pub const BAD_WINDOWS_TO_LATCH: u8 = 2;
/// Below this average speed, in r/min of the motor shaft, position and speed are not
/// compared: the difference between them is then within what a drive's speed filter
/// and the sampling moments explain. 40 r/min is 59 mm/s at the wheel (radius 142 mm,
/// gear 10:1).
pub const MIN_COMPARED_RPM: f64 = 40.0;
/// How far the counter may differ from the speeds' prediction, as a share of the
/// larger of the two: a drive's speed monitor is filtered and may lag a ramp.
pub const TOLERANCE: f64 = 0.3;
/// Counter change between two samples that still counts as standing: 0.36° of the
/// motor shaft, 0.04° at the wheel. A held (excited) shaft may jitter by a few counts.
pub const STANDING_COUNTS: u32 = 36;

/// What a window showed about one wheel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Finding {
    /// The reported speed says the shaft turns; the counter lags far behind or stands.
    PositionStuck,
    /// The counter runs; the reported speed lags far behind or says it stands.
    SpeedStale,
    /// The counter runs against the sign of what the wheel was commanded.
    WrongDirection,
}

/// What the controller commanded each drive, as its own model has it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Commanded {
    /// The speed each drive would run at now had it followed every command since the
    /// drives were set up, each from the moment it was sent and at its rate: the
    /// commanded ramps alone, never corrected by a measurement.
    pub expected: MotorRpm,
    /// The speed each drive was last told to reach, in force now.
    pub target: MotorRpm,
    /// Every target each drive was told since the previous sample, `target` included:
    /// left, right.
    pub targets: [SpeedRange; 2],
    /// How much that model's acceleration changed since the previous sample, summed
    /// over every change (a ramp that starts, ends or turns round), in (r/min)/s: left,
    /// right. Each change bends the speed between two samples, which the speeds at the
    /// sampling moments cannot see.
    pub bends_rpm_per_s: [f64; 2],
}

/// What one sample showed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Verdict {
    /// A latched finding per wheel, reported once when it latches.
    pub left: Option<Finding>,
    pub right: Option<Finding>,
    /// Neither counter moved since the previous sample. The first sample after a
    /// (re)start shows no motion yet, so it reads `true` and standstill rests on the
    /// reported speed alone for that one sample: a restart comes with drives set up
    /// from scratch (standing, de-excited) or with a counter that jumped, where the
    /// counter says nothing either way.
    pub position_standing: bool,
}

impl Verdict {
    /// The wheels with a finding that latched with this sample.
    pub fn findings(&self) -> impl Iterator<Item = (Wheel, Finding)> {
        [(Wheel::Left, self.left), (Wheel::Right, self.right)]
            .into_iter()
            .filter_map(|(wheel, finding)| finding.map(|finding| (wheel, finding)))
    }
}

/// One drive's samples since the window started.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct WheelWindow {
    /// The counter at the window's start.
    start_counts: i32,
    /// The previous sample's counter and speed.
    last_counts: i32,
    last_rpm: i32,
    /// The position the reported speeds predict since the window's start, in
    /// revolution-milliseconds per minute (r/min × ms): divide by 60 000 for turns.
    predicted_rpm_ms: f64,
    /// How far the reported speeds' prediction may miss the counter in this window and
    /// in the previous one because the commanded speed bent between two samples, in
    /// r/min × ms (see [`bend_miss_rpm_ms`]).
    bend_miss_rpm_ms: f64,
    previous_bend_miss_rpm_ms: f64,
    /// The commanded speeds (the model's) this window and the previous one saw.
    expected: SpeedRange,
    previous_expected: SpeedRange,
    /// The targets the wheel was told in this window and in the previous one.
    targets: SpeedRange,
    previous_targets: SpeedRange,
    /// Windows in a row whose counter and reported speed disagreed.
    bad_windows: u8,
    /// Windows in a row whose counter ran against the command.
    wrong_way_windows: u8,
    latched: bool,
}

/// The lowest and highest of some speeds, r/min.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpeedRange {
    low: i32,
    high: i32,
}

impl SpeedRange {
    pub const fn of(rpm: i32) -> Self {
        Self {
            low: rpm,
            high: rpm,
        }
    }

    pub fn with(self, other: Self) -> Self {
        Self {
            low: self.low.min(other.low),
            high: self.high.max(other.high),
        }
    }

    /// `rpm` is at least [`MIN_COMPARED_RPM`] on one side of zero, and every speed in
    /// the range at least as far on the other.
    fn all_opposite(self, rpm: f64) -> bool {
        (rpm >= MIN_COMPARED_RPM && f64::from(self.high) <= -MIN_COMPARED_RPM)
            || (rpm <= -MIN_COMPARED_RPM && f64::from(self.low) >= MIN_COMPARED_RPM)
    }
}

/// The most a speed's trapezoid over one sampling interval of `elapsed_ms` can miss
/// its position when its acceleration changes by `bends_rpm_per_s` in between, r/min ×
/// ms: a bend of Δa at c ms into an interval of h ms misses Δa·c·(h − c)/2, at most
/// Δa·h²/8 (with Δa in (r/min)/s, divided by 1000 for r/min × ms).
fn bend_miss_rpm_ms(bends_rpm_per_s: f64, elapsed_ms: u64) -> f64 {
    let h = elapsed_ms as f64;
    bends_rpm_per_s * h * h / 8.0 / 1000.0
}

impl WheelWindow {
    fn start(counts: i32, rpm: i32, expected_rpm: i32, targets: SpeedRange) -> Self {
        Self {
            start_counts: counts,
            last_counts: counts,
            last_rpm: rpm,
            expected: SpeedRange::of(expected_rpm),
            previous_expected: SpeedRange::of(expected_rpm),
            targets,
            previous_targets: targets,
            ..Self::default()
        }
    }

    /// Adds one sample `elapsed_ms` after the previous, with how much the commanded
    /// acceleration changed since then; whether the counter stood.
    fn add(
        &mut self,
        elapsed_ms: u64,
        counts: i32,
        rpm: i32,
        expected_rpm: i32,
        targets: SpeedRange,
        bends_rpm_per_s: f64,
    ) -> bool {
        let mean_rpm = (f64::from(self.last_rpm) + f64::from(rpm)) / 2.0;
        self.predicted_rpm_ms += mean_rpm * elapsed_ms as f64;
        self.bend_miss_rpm_ms += bend_miss_rpm_ms(bends_rpm_per_s, elapsed_ms);
        self.expected = self.expected.with(SpeedRange::of(expected_rpm));
        self.targets = self.targets.with(targets);
        let standing = counts.wrapping_sub(self.last_counts).unsigned_abs() <= STANDING_COUNTS;
        self.last_counts = counts;
        self.last_rpm = rpm;
        standing
    }

    /// Judges the window that spans `span_ms` and starts the next one at the last
    /// sample (commanded `expected_rpm`, the target `target_rpm` in force now).
    /// Returns a finding once it latches: one per wheel until the check restarts.
    fn judge(
        &mut self,
        span_ms: u64,
        counts_per_rev: f64,
        expected_rpm: i32,
        target_rpm: i32,
    ) -> Option<Finding> {
        let counted = f64::from(self.last_counts.wrapping_sub(self.start_counts));
        let counted_rpm = counted / counts_per_rev * 60_000.0 / span_ms as f64;
        let predicted_rpm = self.predicted_rpm_ms / span_ms as f64;
        // A drive follows the model a little late, so its bends may fall into the
        // window after the model's.
        let bend_miss_rpm =
            (self.bend_miss_rpm_ms + self.previous_bend_miss_rpm_ms) / span_ms as f64;
        // Against everything the model asked for over two windows: a wheel that
        // follows a reversal late runs opposite to the model's latest speeds only.
        let commanded = self.expected.with(self.previous_expected);
        let told = self.targets.with(self.previous_targets);
        self.start_counts = self.last_counts;
        self.predicted_rpm_ms = 0.0;
        self.previous_bend_miss_rpm_ms = self.bend_miss_rpm_ms;
        self.bend_miss_rpm_ms = 0.0;
        self.previous_expected = self.expected;
        self.expected = SpeedRange::of(expected_rpm);
        self.previous_targets = self.targets;
        self.targets = SpeedRange::of(target_rpm);
        let larger = counted_rpm.abs().max(predicted_rpm.abs());
        let disagree = larger >= MIN_COMPARED_RPM
            && (counted_rpm - predicted_rpm).abs() > TOLERANCE * larger + bend_miss_rpm;
        let wrong_way = commanded.all_opposite(counted_rpm) && told.all_opposite(counted_rpm);
        let in_a_row = |windows: u8, bad: bool| if bad { windows.saturating_add(1) } else { 0 };
        self.bad_windows = in_a_row(self.bad_windows, disagree);
        self.wrong_way_windows = in_a_row(self.wrong_way_windows, wrong_way);
        if self.latched {
            return None;
        }
        let finding = if self.bad_windows >= BAD_WINDOWS_TO_LATCH {
            if counted_rpm.abs() < predicted_rpm.abs() {
                Finding::PositionStuck
            } else {
                Finding::SpeedStale
            }
        } else if self.wrong_way_windows >= BAD_WINDOWS_TO_LATCH {
            Finding::WrongDirection
        } else {
            return None;
        };
        self.latched = true;
        Some(finding)
    }
}

/// The check over both drives. Restart it whenever the counters restart (drives set
/// up again, a counter discontinuity): the next sample is a new start.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeedbackCheck {
    /// `None` until the first sample after a (re)start.
    window: Option<Window>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Window {
    started: Timestamp,
    last_sample: Timestamp,
    left: WheelWindow,
    right: WheelWindow,
}

impl FeedbackCheck {
    pub const fn new() -> Self {
        Self { window: None }
    }

    /// Forgets every sample: the next one starts afresh. Latched findings are the
    /// supervisor's to keep; this only stops comparing across a counter restart.
    pub fn restart(&mut self) {
        self.window = None;
    }

    /// One feedback sample at `now`: raw counters and reported speeds, as read, and
    /// what the controller commanded.
    pub fn sample(
        &mut self,
        now: Timestamp,
        counts: EncoderCounts,
        rpm: MotorRpm,
        commanded: Commanded,
        counts_per_rev: f64,
    ) -> Verdict {
        let expected = commanded.expected;
        let [left_targets, right_targets] = commanded.targets;
        let Some(window) = &mut self.window else {
            self.window = Some(Window {
                started: now,
                last_sample: now,
                left: WheelWindow::start(counts.left, rpm.left, expected.left, left_targets),
                right: WheelWindow::start(counts.right, rpm.right, expected.right, right_targets),
            });
            return Verdict {
                position_standing: true,
                ..Verdict::default()
            };
        };
        let elapsed_ms = now.millis_since(window.last_sample);
        window.last_sample = now;
        let [left_bends, right_bends] = commanded.bends_rpm_per_s;
        let left_standing = window.left.add(
            elapsed_ms,
            counts.left,
            rpm.left,
            expected.left,
            left_targets,
            left_bends,
        );
        let right_standing = window.right.add(
            elapsed_ms,
            counts.right,
            rpm.right,
            expected.right,
            right_targets,
            right_bends,
        );
        let mut verdict = Verdict {
            left: None,
            right: None,
            position_standing: left_standing && right_standing,
        };
        let span_ms = now.millis_since(window.started);
        if span_ms >= WINDOW_MS {
            let target = commanded.target;
            verdict.left = window
                .left
                .judge(span_ms, counts_per_rev, expected.left, target.left);
            verdict.right =
                window
                    .right
                    .judge(span_ms, counts_per_rev, expected.right, target.right);
            window.started = now;
        }
        verdict
    }
}

/// Whether a reported speed counts as standing.
pub fn speed_standing(rpm: i32) -> bool {
    // A range, not `abs()`: i32::MIN from a drive would overflow.
    (-AT_REST_RPM..=AT_REST_RPM).contains(&rpm)
}

#[cfg(test)]
mod tests {
    use super::*;

    const COUNTS_PER_REV: f64 = 36_000.0;
    /// Counts per millisecond at 1 r/min.
    const COUNTS_PER_RPM_MS: f64 = COUNTS_PER_REV / 60_000.0;

    /// A drive over time: its true shaft speed, and what it reports.
    #[derive(Clone, Copy)]
    enum Report {
        /// Position and speed both true.
        Honest,
        /// The counter froze at the moment the fault began.
        StuckCounter,
        /// The speed register reads this, whatever the shaft does.
        FrozenSpeed(i32),
    }

    /// A finding and when (ms) it latched.
    type FoundAt = (u64, Finding);

    /// Runs the check over `ms` with a sample every `period_ms`: the left shaft at
    /// `rpm(t)`, reported as `left`; the right shaft honest at the same speed; both
    /// commanded as they turn. Returns the first finding per wheel with its time.
    fn run(
        ms: u64,
        period_ms: u64,
        rpm: impl Fn(u64) -> f64,
        left: Report,
    ) -> [Option<FoundAt>; 2] {
        let commanded = |t: u64| (rpm(t), rpm(t));
        run_commanded(ms, period_ms, &rpm, left, &commanded)
    }

    /// Runs the check over `ms` with a sample every `period_ms`: the left shaft at
    /// `left_shaft(t)`, reported as `left`; both wheels commanded `commanded(t)` =
    /// (the model's speed now, the target in force); the right shaft follows the model
    /// honestly. Returns the first finding per wheel with its time.
    fn run_commanded(
        ms: u64,
        period_ms: u64,
        left_shaft: &dyn Fn(u64) -> f64,
        left: Report,
        commanded: &dyn Fn(u64) -> (f64, f64),
    ) -> [Option<FoundAt>; 2] {
        let right_shaft = |t: u64| commanded(t).0;
        let shafts: [&dyn Fn(u64) -> f64; 2] = [left_shaft, &right_shaft];
        let mut check = FeedbackCheck::new();
        let mut position = [0.0f64; 2];
        let mut frozen_at: Option<i32> = None;
        let (mut left_found, mut right_found) = (None, None);
        for t in (0..=ms).step_by(period_ms as usize) {
            if t > 0 {
                for (position, shaft) in position.iter_mut().zip(shafts) {
                    // Trapezoids of 1 ms: exact for ramps, close for anything else.
                    for ms in t - period_ms..t {
                        let mean = (shaft(ms) + shaft(ms + 1)) / 2.0;
                        *position += mean * COUNTS_PER_RPM_MS;
                    }
                }
            }
            let true_counts = position.map(|counts| counts.round() as i32);
            let true_rpm = shafts.map(|shaft| shaft(t).round() as i32);
            let (left_counts, left_rpm) = match left {
                Report::Honest => (true_counts[0], true_rpm[0]),
                Report::StuckCounter => (*frozen_at.get_or_insert(true_counts[0]), true_rpm[0]),
                Report::FrozenSpeed(reads) => (true_counts[0], reads),
            };
            let (expected, target) = commanded(t);
            // Every target told since the previous sample, each ms's.
            let told = |wheel_target: fn(f64) -> i32| {
                (t.saturating_sub(period_ms)..=t)
                    .skip(usize::from(t > 0))
                    .map(|ms| SpeedRange::of(wheel_target(commanded(ms).1)))
                    .fold(SpeedRange::of(wheel_target(target)), SpeedRange::with)
            };
            let told = told(|rpm| rpm.round() as i32);
            // The model's bends since the previous sample: its acceleration's changes,
            // from its speed each ms.
            let slope = |ms: u64| (commanded(ms + 1).0 - commanded(ms).0) * 1000.0;
            let bends: f64 = (t.saturating_sub(period_ms)..t)
                .map(|ms| (slope(ms) - slope(ms.saturating_sub(1))).abs())
                .sum();
            let both = |rpm: f64| MotorRpm {
                left: rpm.round() as i32,
                right: rpm.round() as i32,
            };
            let verdict = check.sample(
                Timestamp::from_millis(t),
                EncoderCounts {
                    left: left_counts,
                    right: true_counts[1],
                },
                MotorRpm {
                    left: left_rpm,
                    right: true_rpm[1],
                },
                Commanded {
                    expected: both(expected),
                    target: both(target),
                    targets: [told; 2],
                    bends_rpm_per_s: [bends; 2],
                },
                COUNTS_PER_REV,
            );
            left_found = left_found.or(verdict.left.map(|finding| (t, finding)));
            right_found = right_found.or(verdict.right.map(|finding| (t, finding)));
        }
        [left_found, right_found]
    }

    /// 0 → 900 r/min at `accel`, then back down to 0 at `decel`: the hardest honest
    /// profiles the registers allow, at every sampling period the link may run.
    #[test]
    fn honest_drives_never_raise_a_finding_through_any_ramp() {
        for period_ms in [5, 10, 20, 37, 50] {
            for (accel, decel) in [(700.0, 700.0), (30_000.0, 30_000.0), (1.0, 4_500.0)] {
                let up_ms = (900.0 / accel * 1000.0) as u64;
                let down_ms = (900.0 / decel * 1000.0) as u64;
                let total = up_ms.min(10_000) + 1_000 + down_ms + 500;
                let rpm = |t: u64| {
                    let up = (accel * t as f64 / 1000.0).min(900.0);
                    let down_from = up_ms.min(10_000) + 1_000;
                    if t < down_from {
                        up
                    } else {
                        let peak = (accel * down_from as f64 / 1000.0).min(900.0);
                        (peak - decel * (t - down_from) as f64 / 1000.0).max(0.0)
                    }
                };
                let found = run(total, period_ms, rpm, Report::Honest);
                assert_eq!(found, [None, None], "{period_ms} ms, {accel}/{decel}");
            }
        }
    }

    /// The cases of the fault-injection review, each at 336 r/min (500 mm/s): found
    /// within two windows plus the one the fault began in, and only on the left.
    #[test]
    fn a_lying_drive_is_found_within_three_windows() {
        let cases = [
            (Report::StuckCounter, Finding::PositionStuck),
            (Report::FrozenSpeed(0), Finding::SpeedStale),
            (Report::FrozenSpeed(100), Finding::SpeedStale),
            (Report::FrozenSpeed(-336), Finding::SpeedStale),
        ];
        for period_ms in [10, 20, 50] {
            for (report, expected) in cases {
                let [left, right] = run(2_000, period_ms, |_| 336.0, report);
                let (at, finding) = left.expect("found");
                assert_eq!(finding, expected);
                assert!(at <= 3 * WINDOW_MS + period_ms, "found at {at} ms");
                assert_eq!(right, None);
            }
        }
    }

    /// Speed at `t` of a ramp from `from` to `to` that starts at `at_ms` at `rate`
    /// (r/min)/s.
    fn ramp(t: u64, at_ms: u64, from: f64, to: f64, rate: f64) -> f64 {
        let step = rate * t.saturating_sub(at_ms) as f64 / 1000.0;
        if to > from {
            (from + step).min(to)
        } else {
            (from - step).max(to)
        }
    }

    /// A drive whose direction parameter is at the other value, at 336 r/min (500 mm/s)
    /// unless said otherwise, at each sampling period the link may run: found on the
    /// left wheel alone, within two windows plus the window it began in (plus two
    /// windows more from rest, where the commanded speed still passes below 40 r/min).
    #[test]
    fn a_wheel_turning_against_its_command_is_found_within_three_windows_of_it() {
        type Shaft = &'static dyn Fn(u64) -> f64;
        type Commands = &'static dyn Fn(u64) -> (f64, f64);
        let cases: [(&str, Shaft, Commands, u64); 5] = [
            ("steadily against", &|_| -336.0, &|_| (336.0, 336.0), 0),
            (
                "turned round while driving",
                &|t| if t < 1_000 { 336.0 } else { -336.0 },
                &|_| (336.0, 336.0),
                1_000,
            ),
            (
                "from rest at 700 (r/min)/s, the drive 50 ms late",
                &|t| -ramp(t, 50, 0.0, 336.0, 700.0),
                &|t| (ramp(t, 0, 0.0, 336.0, 700.0), 336.0),
                2 * WINDOW_MS,
            ),
            ("commanded backwards", &|_| 336.0, &|_| (-336.0, -336.0), 0),
            ("at 45 r/min", &|_| -45.0, &|_| (45.0, 45.0), 0),
        ];
        for period_ms in [10, 20, 37, 50] {
            for (case, shaft, commanded, began_ms) in cases {
                let [left, right] =
                    run_commanded(2_000, period_ms, shaft, Report::Honest, commanded);
                let (at, finding) = left.unwrap_or_else(|| panic!("{case}: found"));
                assert_eq!(finding, Finding::WrongDirection, "{case}");
                let by = began_ms + 3 * WINDOW_MS + period_ms;
                assert!(at <= by, "{case} at {period_ms} ms: found at {at} ms");
                assert_eq!(right, None, "{case}");
            }
        }
    }

    /// What a PC may ask, followed by honest drives: the target turning round between
    /// ±336 and ±900 r/min every 20 ms to 1 s, at 700, 4500 and 30 000 (r/min)/s, each
    /// drive following the commanded ramp up to 150 ms late (a command behind two
    /// failed writes, each tried again after the next read). No finding.
    #[test]
    fn honest_drives_following_reversals_late_raise_no_finding() {
        const MS: u64 = 3_000;
        for rate in [700.0, 4_500.0, 30_000.0] {
            for every_ms in [20, 37, 50, 100, 250, 1_000] {
                for speed in [336.0, 900.0] {
                    let target = |t: u64| {
                        if (t / every_ms).is_multiple_of(2) {
                            speed
                        } else {
                            -speed
                        }
                    };
                    let mut model = vec![0.0f64; MS as usize + 1];
                    for t in 1..=MS {
                        let previous = model[t as usize - 1];
                        model[t as usize] = ramp(1, 0, previous, target(t - 1), rate);
                    }
                    for late_ms in [0, 20, 60, 150] {
                        let shaft =
                            |t: u64| t.checked_sub(late_ms).map_or(0.0, |t| model[t as usize]);
                        let commanded = |t: u64| (model[t as usize], target(t));
                        for period_ms in [10, 20, 37, 50] {
                            let found =
                                run_commanded(MS, period_ms, &shaft, Report::Honest, &commanded);
                            assert_eq!(
                                found,
                                [None, None],
                                "{rate} (r/min)/s, ±{speed} every {every_ms} ms, {late_ms} ms late, sampled every {period_ms} ms"
                            );
                        }
                    }
                }
            }
        }
    }

    /// Two programs streaming at once: the wheel told -675 r/min for 7 ms and +100
    /// r/min for 13 ms, over and over, at 700 (r/min)/s. The model of the commanded
    /// ramps integrates each command from the moment it was sent and drifts away from
    /// an honest drive that gets each a few ms late: here it runs 500 r/min above the
    /// shaft, on the other side of zero. A wheel told both ways is not judged against
    /// its command. (The shrunk whole-robot case: 0x43 on the healthy left drive.)
    #[test]
    fn an_honest_drive_told_both_ways_every_20_ms_is_not_called_backwards() {
        const MS: u64 = 1_500;
        let target = |t: u64| if (t + 10) % 20 < 7 { -675.0 } else { 100.0 };
        let follow = |from: f64| {
            let mut speed = vec![from; MS as usize + 1];
            for t in 1..=MS as usize {
                speed[t] = ramp(1, 0, speed[t - 1], target(t as u64 - 1), 700.0);
            }
            speed
        };
        let (model, shaft) = (follow(250.0), follow(-250.0));
        let shaft = |t: u64| shaft[t as usize];
        let commanded = |t: u64| (model[t as usize], target(t));
        for period_ms in [10, 20, 37, 50] {
            let found = run_commanded(MS, period_ms, &shaft, Report::Honest, &commanded);
            assert_eq!(found[0], None, "sampled every {period_ms} ms");
        }
    }

    /// The allowance for bends does not hide a stuck encoder from a PC that changes
    /// its speed every 50 ms (between 300 and 400 r/min at 700 (r/min)/s, as a planner
    /// does).
    #[test]
    fn a_stuck_encoder_is_found_while_the_speed_changes_every_50_ms() {
        let mut model = vec![300.0f64; 2_001];
        for t in 1..=2_000usize {
            let target = if (t / 50).is_multiple_of(2) {
                400.0
            } else {
                300.0
            };
            model[t] = ramp(1, 0, model[t - 1], target, 700.0);
        }
        for period_ms in [20, 50] {
            let [left, right] = run(
                2_000,
                period_ms,
                |t| model[t as usize],
                Report::StuckCounter,
            );
            let (at, finding) = left.expect("found");
            assert_eq!(finding, Finding::PositionStuck);
            assert!(at <= 3 * WINDOW_MS + period_ms, "found at {at} ms");
            assert_eq!(right, None);
        }
    }

    /// Nothing to compare: a wheel pushed while it is told to stand, one creeping
    /// below 40 r/min against its command, and one turning against a command that
    /// already stops it (the stop is on its way either way).
    #[test]
    fn a_wheel_against_a_standstill_or_below_the_compared_speed_is_no_finding() {
        type Shaft = &'static dyn Fn(u64) -> f64;
        type Commands = &'static dyn Fn(u64) -> (f64, f64);
        let cases: [(&str, Shaft, Commands); 3] = [
            ("pushed at rest", &|_| -100.0, &|_| (0.0, 0.0)),
            ("creeping", &|_| -30.0, &|_| (30.0, 30.0)),
            ("stopping", &|t| -ramp(t, 0, 336.0, 0.0, 700.0), &|t| {
                (ramp(t, 0, 336.0, 0.0, 700.0), 0.0)
            }),
        ];
        for (case, shaft, commanded) in cases {
            let found = run_commanded(2_000, 20, shaft, Report::Honest, commanded);
            assert_eq!(found, [None, None], "{case}");
        }
    }

    #[test]
    fn a_stuck_counter_at_standstill_is_no_finding() {
        let [left, _] = run(2_000, 20, |_| 0.0, Report::StuckCounter);
        assert_eq!(left, None);
    }

    #[test]
    fn slow_creeping_below_the_compared_speed_is_not_judged() {
        let [left, _] = run(2_000, 20, |_| 30.0, Report::StuckCounter);
        assert_eq!(left, None);
    }

    #[test]
    fn a_finding_is_reported_once() {
        let mut check = FeedbackCheck::new();
        let mut found = 0;
        for t in (0..3_000u64).step_by(20) {
            let verdict = check.sample(
                Timestamp::from_millis(t),
                EncoderCounts { left: 0, right: 0 },
                MotorRpm {
                    left: 336,
                    right: 0,
                },
                Commanded::default(),
                COUNTS_PER_REV,
            );
            found += verdict.findings().count();
        }
        assert_eq!(found, 1);
    }

    #[test]
    fn the_position_decides_standing_as_well_as_the_speed() {
        let mut check = FeedbackCheck::new();
        let at = Timestamp::from_millis;
        let rpm = MotorRpm::ZERO;
        let first = check.sample(
            at(0),
            EncoderCounts { left: 0, right: 0 },
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        assert!(first.position_standing, "one sample shows no motion");
        let still = check.sample(
            at(20),
            EncoderCounts {
                left: 30,
                right: -36,
            },
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        assert!(still.position_standing, "jitter within 36 counts");
        let rolling = check.sample(
            at(40),
            EncoderCounts {
                left: 30,
                right: 2_000,
            },
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        assert!(!rolling.position_standing, "the right counter ran");
        // Across the counters' wrap, a small step is a small step.
        let mut check = FeedbackCheck::new();
        check.sample(
            at(0),
            EncoderCounts {
                left: i32::MAX,
                right: 0,
            },
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        let wrapped = check.sample(
            at(20),
            EncoderCounts {
                left: i32::MIN,
                right: 0,
            },
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        assert!(wrapped.position_standing);
    }

    #[test]
    fn a_restart_takes_the_next_sample_as_a_new_start() {
        let mut check = FeedbackCheck::new();
        let rpm = MotorRpm::ZERO;
        check.sample(
            Timestamp::from_millis(0),
            EncoderCounts {
                left: 5_000_000,
                right: 0,
            },
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        check.restart();
        // The drives restarted at zero: no motion, no finding, just a new start.
        let verdict = check.sample(
            Timestamp::from_millis(200),
            EncoderCounts::default(),
            rpm,
            Commanded::default(),
            COUNTS_PER_REV,
        );
        assert_eq!(verdict.findings().count(), 0);
        assert!(verdict.position_standing);
    }
}
