//! Dead reckoning: owns the robot's pose, integrated from the drives' encoder counters.
//! The control loop feeds it one `EncoderCounts` sample per cycle and re-baselines it
//! after a drive reconnect, or when a counter steps further than a motor can turn
//! ([`Odometry::discontinuity`]); CAN reads `pose()` and 0x005 calls `reset()`; the
//! odometry calibration accumulates the uncorrected `RawMotion` it returns.
//!
//! All arithmetic is f64, and the pose sums are compensated (double-double) so that
//! rounding does not grow with the distance travelled or the number of samples.

use crate::kinematics::MotorRpm;
use core::f64::consts::TAU;

/// Geometry, scaling and calibration factors, from the registers.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OdometryParams {
    pub left_radius_mm: f64,
    pub right_radius_mm: f64,
    pub wheel_distance_mm: f64,
    /// Motor revolutions per wheel revolution.
    pub gear_ratio: f64,
    /// Position counts per motor revolution (36000 on BLV R: 0.01° steps).
    pub counts_per_motor_rev: f64,
    /// Mirror mounting, the same flags as [`crate::kinematics::KinematicsParams`]: the
    /// counter of an inverted motor runs backward when the robot drives forward.
    pub invert_left: bool,
    pub invert_right: bool,
    /// Linear correction `f_lin`, already divided by 10000.
    pub f_lin: f64,
    /// Clockwise rotation correction `f_cw`, already divided by 10000.
    pub f_cw: f64,
    /// Counter-clockwise rotation correction `f_ccw`, already divided by 10000.
    pub f_ccw: f64,
}

/// The drives' raw position counters, as read (no inversion applied).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderCounts {
    pub left: i32,
    pub right: i32,
}

/// One sample's motion **before** the calibration factors, for the odometry calibration.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RawMotion {
    /// Distance of the axle centre, positive forward.
    pub distance_mm: f64,
    /// Rotation, positive clockwise.
    pub rotation_mrad: f64,
}

/// The pose as reported on CAN (0x0EC / 0x0ED).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Pose {
    /// Forward of the pose origin.
    pub x_mm: i32,
    /// To the right of the pose origin.
    pub y_mm: i32,
    /// Clockwise, cumulative (not wrapped).
    pub heading_mrad: i32,
}

/// The pose at full precision, for tests and diagnostics.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PrecisePose {
    pub x_mm: f64,
    pub y_mm: f64,
    /// Clockwise, cumulative (not wrapped).
    pub heading_rad: f64,
}

/// The base's speed as the drives measured it, with the calibration factors applied
/// like the pose's ([`measured_speed`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MeasuredSpeed {
    /// Of the axle centre, positive forward.
    pub linear_mm_s: f64,
    /// Positive clockwise.
    pub rotation_rad_s: f64,
    /// Each wheel's own rotation, positive when it drives the base forward (no
    /// calibration factor: this is how fast the wheel turns).
    pub left_wheel_rad_s: f64,
    pub right_wheel_rad_s: f64,
}

/// The speed at which the pose moves while the motors turn at `rpm` (the drives' own
/// reading, in their raw sense like the counters): the same geometry and calibration
/// as [`Odometry::update`], so a PC that integrates these speeds follows the pose.
pub fn measured_speed(params: &OdometryParams, rpm: MotorRpm) -> MeasuredSpeed {
    let wheel_rad_s = |rpm: i32, inverted: bool| {
        let sign = if inverted { -1.0 } else { 1.0 };
        sign * f64::from(rpm) / 60.0 * TAU / params.gear_ratio
    };
    let left_wheel_rad_s = wheel_rad_s(rpm.left, params.invert_left);
    let right_wheel_rad_s = wheel_rad_s(rpm.right, params.invert_right);
    let rim_left = left_wheel_rad_s * params.left_radius_mm;
    let rim_right = right_wheel_rad_s * params.right_radius_mm;
    let rotation = (rim_left - rim_right) / params.wheel_distance_mm;
    let rotation_factor = if rotation > 0.0 {
        params.f_cw
    } else {
        params.f_ccw
    };
    MeasuredSpeed {
        linear_mm_s: (rim_left + rim_right) / 2.0 * params.f_lin,
        rotation_rad_s: rotation * rotation_factor,
        left_wheel_rad_s,
        right_wheel_rad_s,
    }
}

/// The dead-reckoning state: the last counter sample and the integrated pose.
#[derive(Debug, Clone, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Odometry {
    /// `None` until the first sample after `new()` or `rebaseline()`.
    baseline: Option<EncoderCounts>,
    x_mm: CompensatedSum,
    y_mm: CompensatedSum,
    heading_rad: CompensatedSum,
}

impl Odometry {
    pub const fn new() -> Self {
        Self {
            baseline: None,
            x_mm: CompensatedSum::ZERO,
            y_mm: CompensatedSum::ZERO,
            heading_rad: CompensatedSum::ZERO,
        }
    }

    /// Integrates the motion since the previous sample and returns it uncorrected.
    ///
    /// Returns `None` and moves nothing when this sample only sets the baseline (first
    /// sample after `new()` or `rebaseline()`), or when the parameters turn the motion
    /// into a non-finite number (a zero gear ratio or wheel distance): dropping that
    /// sample keeps one bad register value from poisoning the pose for ever.
    pub fn update(&mut self, params: &OdometryParams, counts: EncoderCounts) -> Option<RawMotion> {
        let previous = self.baseline.replace(counts)?;
        // The counters are free-running i32: a wrapping difference is right across the
        // i32::MAX → i32::MIN boundary as long as one cycle moves less than 2³¹ counts.
        let arc_left = wheel_arc_mm(
            counts.left.wrapping_sub(previous.left),
            params.left_radius_mm,
            params.invert_left,
            params,
        );
        let arc_right = wheel_arc_mm(
            counts.right.wrapping_sub(previous.right),
            params.right_radius_mm,
            params.invert_right,
            params,
        );
        let distance_mm = (arc_left + arc_right) / 2.0;
        // Clockwise positive: the left wheel is on the outside of a clockwise turn.
        let rotation_rad = (arc_left - arc_right) / params.wheel_distance_mm;

        let rotation_factor = if rotation_rad > 0.0 {
            params.f_cw
        } else {
            params.f_ccw
        };
        let d = distance_mm * params.f_lin;
        let dtheta = rotation_rad * rotation_factor;
        if !(d.is_finite() && dtheta.is_finite()) {
            return None;
        }
        self.integrate(d, dtheta);
        Some(RawMotion {
            distance_mm,
            rotation_mrad: rotation_rad * 1000.0,
        })
    }

    /// Which counters stepped further since the last sample than a motor at
    /// `max_motor_rpm` can turn in `elapsed_ms` (bit 0 left, bit 1 right; 0 = none, or
    /// no baseline yet). Such a step is a discontinuity, not motion: a drive that
    /// restarted (its counter starts again at 0) without the link seeing a reconnect,
    /// or a garbled value. The caller re-baselines instead of integrating it.
    ///
    /// The allowance is generous, so that no real motion is ever dropped: 1.5 times
    /// `max_motor_rpm`, over the elapsed time plus [`STEP_SLACK_MS`] (the sample is
    /// timed when it arrives, not when the drive latched it).
    pub fn discontinuity(
        &self,
        params: &OdometryParams,
        counts: EncoderCounts,
        max_motor_rpm: u32,
        elapsed_ms: u64,
    ) -> u8 {
        let Some(previous) = self.baseline else {
            return 0;
        };
        let counts_per_ms = params.counts_per_motor_rev * f64::from(max_motor_rpm) / 60_000.0;
        let allowed = 1.5 * counts_per_ms * (elapsed_ms as f64 + STEP_SLACK_MS);
        let jumped = |now: i32, before: i32| f64::from(now.wrapping_sub(before)).abs() > allowed;
        u8::from(jumped(counts.left, previous.left))
            | u8::from(jumped(counts.right, previous.right)) << 1
    }

    /// The pose `ahead_ms` after the last sample, had both motors kept turning at `rpm`
    /// (the drives' own reading, in their raw sense like the counters) since: the pose
    /// at the moment a position frame goes out rather than at the moment of the
    /// reading. The reading's moment moves by a few ms from cycle to cycle (a command
    /// write may hold the line when the read is due), and a PC that takes the frames
    /// as one cycle apart would see those ms as speed. Without a baseline it is the
    /// pose itself.
    pub fn pose_ahead(&self, params: &OdometryParams, rpm: MotorRpm, ahead_ms: u64) -> Pose {
        let Some(baseline) = self.baseline else {
            return self.pose();
        };
        let counts_ahead = |rpm: i32| {
            let counts = f64::from(rpm) * params.counts_per_motor_rev * ahead_ms as f64 / 60_000.0;
            // Saturating: a huge step is then dropped by `update` as non-finite motion
            // only if the parameters are broken; a real one is a few thousand counts.
            libm::round(counts) as i32
        };
        let mut ahead = self.clone();
        ahead.update(
            params,
            EncoderCounts {
                left: baseline.left.wrapping_add(counts_ahead(rpm.left)),
                right: baseline.right.wrapping_add(counts_ahead(rpm.right)),
            },
        );
        ahead.pose()
    }

    /// After a drive reconnect its counter restarts: the next sample is a new baseline,
    /// so the jump is not integrated and the pose does not move.
    pub fn rebaseline(&mut self) {
        self.baseline = None;
    }

    /// Pose back to the origin (CAN 0x005). The baseline stays: the next sample
    /// integrates only what moved since the last one.
    pub fn reset(&mut self) {
        self.x_mm = CompensatedSum::ZERO;
        self.y_mm = CompensatedSum::ZERO;
        self.heading_rad = CompensatedSum::ZERO;
    }

    /// The pose rounded to nearest (half away from zero). Beyond the i32 range
    /// (±2147 km, or ±341 000 turns) each field saturates at i32::MIN / i32::MAX.
    pub fn pose(&self) -> Pose {
        // `as i32` saturates (and maps NaN to 0, which `update` never lets in).
        let round = |v: f64| libm::round(v) as i32;
        Pose {
            x_mm: round(self.x_mm.value()),
            y_mm: round(self.y_mm.value()),
            heading_mrad: round(self.heading_rad.value() * 1000.0),
        }
    }

    pub fn precise_pose(&self) -> PrecisePose {
        PrecisePose {
            x_mm: self.x_mm.value(),
            y_mm: self.y_mm.value(),
            heading_rad: self.heading_rad.value(),
        }
    }

    /// Moves along the exact circular arc of length `d` that turns by `dtheta`.
    ///
    /// The arc's chord has length `d · sin(dθ/2) / (dθ/2)` and points along the mid
    /// heading `θ + dθ/2`. That form is exact for any constant-curvature motion and,
    /// unlike `R · (sin θ₁ − sin θ₀)`, has no cancellation for nearly straight motion.
    fn integrate(&mut self, d: f64, dtheta: f64) {
        let half = dtheta / 2.0;
        let chord = d * sin_x_over_x(half);
        // The low word of the heading carries the bits a plain f64 heading would lose
        // once it has grown to many turns.
        let mid_heading = self.heading_rad.hi + (self.heading_rad.lo + half);
        let (sin, cos) = libm::sincos(mid_heading);
        // Clockwise-positive heading with y to the right: heading +90° drives along +y.
        self.x_mm.add(chord * cos);
        self.y_mm.add(chord * sin);
        self.heading_rad.add(dtheta);
    }
}

/// Timing slack of [`Odometry::discontinuity`], ms.
pub const STEP_SLACK_MS: f64 = 50.0;

/// Wheel arc in mm for a counter difference, positive when that wheel rolls forward.
fn wheel_arc_mm(delta: i32, radius_mm: f64, inverted: bool, params: &OdometryParams) -> f64 {
    // Negate in f64: -i32::MIN would overflow.
    let counts = if inverted {
        -f64::from(delta)
    } else {
        f64::from(delta)
    };
    counts / params.counts_per_motor_rev / params.gear_ratio * TAU * radius_mm
}

/// sin(a)/a without the 0/0 at a = 0. Below 1e-4 the series 1 − a²/6 is exact to
/// f64 precision (the next term, a⁴/120, is below 1e-18).
fn sin_x_over_x(a: f64) -> f64 {
    if libm::fabs(a) < 1e-4 {
        1.0 - a * a / 6.0
    } else {
        libm::sin(a) / a
    }
}

/// A double-double running sum (Knuth's TwoSum): `hi + lo` holds the sum to about
/// 106 bits, so a million samples of rounding error stay far below a micrometre even
/// 100 km from the origin, instead of piling up one f64 rounding per sample.
#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct CompensatedSum {
    hi: f64,
    lo: f64,
}

impl CompensatedSum {
    const ZERO: CompensatedSum = CompensatedSum { hi: 0.0, lo: 0.0 };

    fn add(&mut self, value: f64) {
        let (sum, error) = two_sum(self.hi, value);
        let (hi, lo) = two_sum(sum, self.lo + error);
        self.hi = hi;
        self.lo = lo;
    }

    fn value(&self) -> f64 {
        self.hi + self.lo
    }
}

/// `a + b` as the rounded sum and its exact rounding error.
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let sum = a + b;
    let b_virtual = sum - a;
    let a_virtual = sum - b_virtual;
    (sum, (a - a_virtual) + (b - b_virtual))
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f64::consts::{FRAC_PI_2, PI};

    /// BLV R scaling on the robot's default geometry, no corrections, no mirroring.
    fn robot() -> OdometryParams {
        OdometryParams {
            left_radius_mm: 142.0,
            right_radius_mm: 142.0,
            wheel_distance_mm: 250.0,
            gear_ratio: 10.0,
            counts_per_motor_rev: 36000.0,
            invert_left: false,
            invert_right: false,
            f_lin: 1.0,
            f_cw: 1.0,
            f_ccw: 1.0,
        }
    }

    /// Counts per wheel revolution with `robot()`.
    const WHEEL_REV: i32 = 360_000;
    /// Wheel circumference with `robot()`.
    const CIRCUMFERENCE_MM: f64 = 2.0 * PI * 142.0;

    fn counts(left: i32, right: i32) -> EncoderCounts {
        EncoderCounts { left, right }
    }

    #[test]
    fn a_counter_step_beyond_max_motor_vel_is_a_discontinuity_and_real_motion_is_not() {
        let mut odometry = Odometry::new();
        assert_eq!(
            odometry.discontinuity(&robot(), counts(5, 5), 900, 50),
            0,
            "no baseline"
        );
        odometry.update(&robot(), counts(1_000_000, 1_000_000));
        // 900 r/min for 50 ms is 27 000 counts; the allowance is 1.5 × over 100 ms.
        let full_speed = counts(1_027_000, 1_000_000 - 27_000);
        assert_eq!(odometry.discontinuity(&robot(), full_speed, 900, 50), 0);
        assert_eq!(
            odometry.discontinuity(&robot(), counts(1_081_000, 1_000_000), 900, 50),
            0
        );
        // The left drive restarted: its counter is back near 0.
        assert_eq!(
            odometry.discontinuity(&robot(), counts(12, 1_000_000), 900, 50),
            0b01
        );
        assert_eq!(
            odometry.discontinuity(&robot(), counts(1_081_001, 0), 900, 50),
            0b11
        );
        // A long gap (the link held the drives) allows more.
        assert_eq!(
            odometry.discontinuity(&robot(), counts(12, 1_000_000), 900, 10_000),
            0
        );
        // Across the i32 wrap the step is small.
        let mut wrapped = Odometry::new();
        wrapped.update(&robot(), counts(i32::MAX - 10, i32::MIN + 10));
        assert_eq!(
            wrapped.discontinuity(&robot(), counts(i32::MIN + 10, i32::MAX - 10), 900, 50),
            0
        );
    }

    #[test]
    fn the_measured_speed_moves_the_pose_as_the_counters_do() {
        // Mirrored left motor and every calibration factor off 1: the speed must use
        // each of them exactly as the counters' integration does.
        let params = OdometryParams {
            invert_left: true,
            f_lin: 1.02,
            f_cw: 0.97,
            f_ccw: 1.05,
            ..robot()
        };
        for (left, right) in [(-600, 600), (-600, 300), (300, -300), (200, 500), (0, 0)] {
            let rpm = MotorRpm { left, right };
            let speed = measured_speed(&params, rpm);
            // One second at `rpm`, in counts (whole numbers for these speeds).
            let mut odometry = Odometry::new();
            odometry.update(&params, counts(0, 0));
            odometry.update(&params, counts(left * 600, right * 600));
            let moved = odometry.precise_pose();
            assert!(
                (moved.heading_rad - speed.rotation_rad_s).abs() < 1e-9,
                "{rpm:?}: turned {} rad, speed says {} rad/s",
                moved.heading_rad,
                speed.rotation_rad_s
            );
            // The arc's length, from its chord and its turn.
            let chord = moved.x_mm.hypot(moved.y_mm);
            let arc = chord / sin_x_over_x(moved.heading_rad / 2.0);
            assert!(
                (arc - speed.linear_mm_s.abs()).abs() < 1e-6,
                "{rpm:?}: rolled {arc} mm, speed says {} mm/s",
                speed.linear_mm_s
            );
            // 600 r/min of the motor is 60 r/min of the wheel: 2π rad/s.
            let wheel = |rpm: i32| f64::from(rpm) / 600.0 * 2.0 * PI;
            assert!((speed.left_wheel_rad_s - wheel(-left)).abs() < 1e-12);
            assert!((speed.right_wheel_rad_s - wheel(right)).abs() < 1e-12);
        }
    }

    /// Counts each wheel must roll (opposite ways) for a spin of `angle_rad`.
    fn spin_counts(angle_rad: f64) -> f64 {
        angle_rad * 125.0 / CIRCUMFERENCE_MM * f64::from(WHEEL_REV)
    }

    /// Feeds `start` (the baseline of a fresh `Odometry`), then `steps` equal
    /// increments; returns the last counts.
    fn drive(
        odo: &mut Odometry,
        params: &OdometryParams,
        start: EncoderCounts,
        per_step: (i32, i32),
        steps: i32,
    ) -> EncoderCounts {
        odo.update(params, start);
        let mut c = start;
        for _ in 0..steps {
            c = counts(
                c.left.wrapping_add(per_step.0),
                c.right.wrapping_add(per_step.1),
            );
            odo.update(params, c);
        }
        c
    }

    fn assert_close(actual: f64, expected: f64, tolerance: f64) {
        assert!(
            (actual - expected).abs() <= tolerance,
            "{actual} vs {expected} (±{tolerance})"
        );
    }

    #[test]
    fn one_wheel_revolution_straight_ahead_moves_one_circumference_along_x() {
        let mut odo = Odometry::new();
        assert_eq!(odo.update(&robot(), counts(0, 0)), None);
        let motion = odo.update(&robot(), counts(WHEEL_REV, WHEEL_REV));
        let p = odo.precise_pose();
        assert_close(p.x_mm, CIRCUMFERENCE_MM, 1e-9);
        assert_eq!((p.y_mm, p.heading_rad), (0.0, 0.0));
        assert_eq!(
            odo.pose(),
            Pose {
                x_mm: 892,
                y_mm: 0,
                heading_mrad: 0
            }
        );
        let motion = motion.expect("second sample is motion");
        assert_close(motion.distance_mm, CIRCUMFERENCE_MM, 1e-9);
        assert_eq!(motion.rotation_mrad, 0.0);
    }

    #[test]
    fn driving_backward_gives_negative_x() {
        let mut odo = Odometry::new();
        drive(&mut odo, &robot(), counts(0, 0), (-1000, -1000), 10);
        assert_close(
            odo.precise_pose().x_mm,
            -10_000.0 / 360_000.0 * CIRCUMFERENCE_MM,
            1e-9,
        );
    }

    #[test]
    fn quarter_turn_clockwise_in_place_reads_plus_1571_mrad() {
        let mut odo = Odometry::new();
        // 79225.35 counts per wheel for 90°; 10 samples of 7923 ≈ 90.00 °.
        drive(&mut odo, &robot(), counts(0, 0), (7923, -7923), 10);
        let p = odo.precise_pose();
        assert_close(p.heading_rad, FRAC_PI_2, 2e-4);
        assert_close(p.x_mm, 0.0, 1e-9);
        assert_close(p.y_mm, 0.0, 1e-9);
        assert_eq!(odo.pose().heading_mrad, 1571);
    }

    #[test]
    fn quarter_turn_counter_clockwise_reads_minus_1571_mrad() {
        let mut odo = Odometry::new();
        drive(&mut odo, &robot(), counts(0, 0), (-7923, 7923), 10);
        assert_eq!(odo.pose().heading_mrad, -1571);
    }

    #[test]
    fn clockwise_quarter_turn_then_forward_increases_y() {
        let params = robot();
        let mut odo = Odometry::new();
        assert_eq!(odo.update(&params, counts(0, 0)), None);
        let quarter = libm::round(spin_counts(FRAC_PI_2)) as i32;
        odo.update(&params, counts(quarter, -quarter));
        odo.update(&params, counts(quarter + WHEEL_REV, -quarter + WHEEL_REV));
        let p = odo.pose();
        assert_eq!((p.x_mm, p.y_mm), (0, 892));
    }

    #[test]
    fn clockwise_arc_curves_to_the_right_along_the_exact_circle() {
        // Left 3, right 1 parts: radius of the centre path = 125 · (3 + 1)/(3 − 1) = 250 mm.
        let mut odo = Odometry::new();
        let steps = 200;
        drive(&mut odo, &robot(), counts(0, 0), (3000, 1000), steps);
        let p = odo.precise_pose();
        let per_count = CIRCUMFERENCE_MM / f64::from(WHEEL_REV);
        let theta = f64::from(steps) * 2000.0 * per_count / 250.0;
        let radius = 250.0;
        assert_close(p.heading_rad, theta, 1e-12);
        // Centre of the turn is at +y (to the right).
        assert_close(p.x_mm, radius * libm::sin(theta), 1e-9);
        assert_close(p.y_mm, radius * (1.0 - libm::cos(theta)), 1e-9);
        assert!(p.y_mm > 0.0);
    }

    #[test]
    fn counter_wrap_across_i32_max_gives_the_small_true_motion() {
        let mut odo = Odometry::new();
        odo.update(&robot(), counts(i32::MAX - 99, i32::MIN + 50));
        // Left rolls forward across MAX → MIN, right rolls backward across MIN → MAX.
        let motion = odo
            .update(&robot(), counts(i32::MIN + 100, i32::MAX - 149))
            .expect("motion");
        let per_count = CIRCUMFERENCE_MM / f64::from(WHEEL_REV);
        // Δleft = +200, Δright = −200: a pure clockwise spin.
        assert_close(motion.distance_mm, 0.0, 1e-12);
        assert_close(
            motion.rotation_mrad,
            400.0 * per_count / 250.0 * 1000.0,
            1e-9,
        );
    }

    #[test]
    fn first_sample_after_new_is_only_a_baseline() {
        let mut odo = Odometry::new();
        assert_eq!(
            odo.update(&robot(), counts(123_456_789, -987_654_321)),
            None
        );
        assert_eq!(odo.pose(), Pose::default());
        let motion = odo.update(&robot(), counts(123_456_789 + 360, -987_654_321 + 360));
        assert!(motion.is_some());
        assert_close(odo.precise_pose().x_mm, CIRCUMFERENCE_MM / 1000.0, 1e-9);
    }

    #[test]
    fn a_counter_jump_after_rebaseline_does_not_move_the_pose() {
        let mut odo = Odometry::new();
        let last = drive(&mut odo, &robot(), counts(0, 0), (1000, 1000), 5);
        let before = odo.precise_pose();
        odo.rebaseline();
        // The drive restarted: its counter is back near zero.
        assert_eq!(odo.update(&robot(), counts(3, -2)), None);
        assert_eq!(odo.precise_pose(), before);
        drive(&mut odo, &robot(), counts(3, -2), (1000, 1000), 1);
        let moved = odo.precise_pose().x_mm - before.x_mm;
        assert_close(moved, 1000.0 / 360_000.0 * CIRCUMFERENCE_MM, 1e-9);
        assert_ne!(last, counts(3, -2));
    }

    #[test]
    fn reset_zeroes_the_pose_but_keeps_the_baseline() {
        let mut odo = Odometry::new();
        let last = drive(&mut odo, &robot(), counts(0, 0), (5000, 3000), 20);
        assert_ne!(odo.pose(), Pose::default());
        odo.reset();
        assert_eq!(odo.pose(), Pose::default());
        assert_eq!(odo.precise_pose(), PrecisePose::default());
        // Only the motion after the reset counts, from the kept baseline.
        let motion = odo.update(&robot(), counts(last.left + 360, last.right + 360));
        assert!(motion.is_some());
        let p = odo.precise_pose();
        assert_close(p.x_mm, CIRCUMFERENCE_MM / 1000.0, 1e-9);
        assert_eq!(p.heading_rad, 0.0);
    }

    #[test]
    fn correction_factors_apply_per_direction_and_raw_motion_stays_uncorrected() {
        let params = OdometryParams {
            f_lin: 1.25,
            f_cw: 0.5,
            f_ccw: 2.0,
            ..robot()
        };
        let per_count = CIRCUMFERENCE_MM / f64::from(WHEEL_REV);
        let raw_spin = 2000.0 * per_count / 250.0;

        let mut cw = Odometry::new();
        cw.update(&params, counts(0, 0));
        let motion = cw.update(&params, counts(1000, -1000)).expect("motion");
        assert_close(motion.rotation_mrad, raw_spin * 1000.0, 1e-9);
        assert_close(cw.precise_pose().heading_rad, raw_spin * 0.5, 1e-15);

        let mut ccw = Odometry::new();
        ccw.update(&params, counts(0, 0));
        let motion = ccw.update(&params, counts(-1000, 1000)).expect("motion");
        assert_close(motion.rotation_mrad, -raw_spin * 1000.0, 1e-9);
        assert_close(ccw.precise_pose().heading_rad, -raw_spin * 2.0, 1e-15);

        let mut straight = Odometry::new();
        straight.update(&params, counts(0, 0));
        let motion = straight
            .update(&params, counts(1000, 1000))
            .expect("motion");
        assert_close(motion.distance_mm, 1000.0 * per_count, 1e-12);
        assert_close(
            straight.precise_pose().x_mm,
            1000.0 * per_count * 1.25,
            1e-12,
        );
    }

    #[test]
    fn inversion_flags_negate_their_own_counter() {
        let mirrored = OdometryParams {
            invert_left: true,
            ..robot()
        };
        let mut plain = Odometry::new();
        let mut inverted = Odometry::new();
        plain.update(&robot(), counts(0, 0));
        inverted.update(&mirrored, counts(0, 0));
        // The same clockwise arc, seen through a mirrored left counter.
        plain.update(&robot(), counts(3000, 1000));
        inverted.update(&mirrored, counts(-3000, 1000));
        assert_eq!(plain.precise_pose(), inverted.precise_pose());
        assert!(plain.precise_pose().heading_rad > 0.0);

        let right_mirrored = OdometryParams {
            invert_right: true,
            ..robot()
        };
        let mut inverted_right = Odometry::new();
        inverted_right.update(&right_mirrored, counts(0, 0));
        inverted_right.update(&right_mirrored, counts(3000, -1000));
        assert_eq!(plain.precise_pose(), inverted_right.precise_pose());
    }

    #[test]
    fn an_inverted_counter_at_i32_min_difference_does_not_overflow() {
        let params = OdometryParams {
            invert_left: true,
            ..robot()
        };
        let mut odo = Odometry::new();
        odo.update(&params, counts(0, 0));
        // Δ = i32::MIN: negating it in i32 would overflow.
        let motion = odo.update(&params, counts(i32::MIN, 0)).expect("motion");
        assert!(motion.distance_mm > 0.0);
    }

    #[test]
    fn invalid_parameters_drop_the_sample_instead_of_poisoning_the_pose() {
        let broken = OdometryParams {
            gear_ratio: 0.0,
            ..robot()
        };
        let mut odo = Odometry::new();
        drive(&mut odo, &robot(), counts(0, 0), (1000, 1000), 3);
        let before = odo.precise_pose();
        assert_eq!(odo.update(&broken, counts(5000, 5000)), None);
        assert_eq!(odo.precise_pose(), before);
        // The good parameters work again from the broken sample's counts.
        odo.update(&robot(), counts(5360, 5360));
        assert_close(
            odo.precise_pose().x_mm - before.x_mm,
            CIRCUMFERENCE_MM / 1000.0,
            1e-9,
        );
    }

    #[test]
    fn pose_rounds_to_nearest_and_saturates_beyond_i32() {
        let mut odo = Odometry::new();
        odo.x_mm.add(2.5);
        odo.y_mm.add(-2.5);
        odo.heading_rad.add(0.0004999);
        assert_eq!(
            odo.pose(),
            Pose {
                x_mm: 3,
                y_mm: -3,
                heading_mrad: 0
            }
        );
        odo.x_mm.add(1e12);
        odo.y_mm.add(-1e12);
        odo.heading_rad.add(1e10);
        assert_eq!(
            odo.pose(),
            Pose {
                x_mm: i32::MAX,
                y_mm: i32::MIN,
                heading_mrad: i32::MAX
            }
        );
    }

    #[test]
    fn compensated_sum_keeps_increments_a_plain_f64_would_lose() {
        let mut sum = CompensatedSum::ZERO;
        let mut plain = 0.0f64;
        sum.add(1e8);
        plain += 1e8;
        for _ in 0..1_000_000 {
            // 1e-9 is below half an ulp of 1e8 (7.5e-9): a plain f64 never moves.
            sum.add(1e-9);
            plain += 1e-9;
        }
        assert_eq!(plain, 1e8);
        assert_close((sum.hi - 1e8) + sum.lo, 1e-3, 1e-12);
    }

    #[test]
    fn tiny_rotation_uses_the_series_without_a_division_by_zero() {
        assert_eq!(sin_x_over_x(0.0), 1.0);
        let a = 0.99e-4;
        assert_close(sin_x_over_x(a), libm::sin(a) / a, 3e-16);
        let b = 1.01e-4;
        assert_close(sin_x_over_x(b), 1.0 - b * b / 6.0, 3e-16);
    }
}
