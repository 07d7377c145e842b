//! Twist → wheel commands: the safety-zone clamp, the differential-drive inverse
//! kinematics with the `max_motor_vel` limit, and the synchronized acceleration ramp.
//! The drive-command logic calls it with the winning twist; the Modbus layer sends the result.
//!
//! f32 is enough here (a few operations at ≤ 50 Hz, results rounded to whole r/min).

use core::f32::consts::PI;

/// A velocity command in the robot frame, as it arrives on CAN (0x0C8) or from the remote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Twist {
    /// Positive = forward.
    pub linear_mm_s: i32,
    /// Positive = clockwise seen from above.
    pub rotation_mrad_s: i32,
}

/// The safety-zone limits (`sec_lin_vel`, `sec_turn_vel`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SafetyLimits {
    pub linear_mm_s: u16,
    pub rotation_mrad_s: u16,
}

impl Twist {
    pub const ZERO: Twist = Twist {
        linear_mm_s: 0,
        rotation_mrad_s: 0,
    };

    /// Clamps |linear| and |rotation| independently. The path's curvature may change,
    /// which is what the manual asks for: both limits are hard limits.
    pub fn clamped(self, limits: SafetyLimits) -> Twist {
        let lin = i32::from(limits.linear_mm_s);
        let rot = i32::from(limits.rotation_mrad_s);
        Twist {
            linear_mm_s: self.linear_mm_s.clamp(-lin, lin),
            rotation_mrad_s: self.rotation_mrad_s.clamp(-rot, rot),
        }
    }
}

/// The geometry and limits the inverse kinematics needs, from the registers.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct KinematicsParams {
    pub left_radius_mm: f32,
    pub right_radius_mm: f32,
    pub wheel_distance_mm: f32,
    /// Motor revolutions per wheel revolution.
    pub gear_ratio: f32,
    /// `max_motor_vel`, motor-shaft r/min.
    pub max_motor_rpm: f32,
    /// Mirror mounting: this motor turns the other way for forward motion.
    pub invert_left: bool,
    pub invert_right: bool,
}

/// Motor-shaft speeds in r/min, exactly as sent to each drive (inversion applied).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorRpm {
    pub left: i32,
    pub right: i32,
}

impl MotorRpm {
    pub const ZERO: MotorRpm = MotorRpm { left: 0, right: 0 };
}

/// Inverse kinematics: the motor speeds that make the base follow `twist`.
///
/// If either motor would exceed `max_motor_rpm`, both are scaled by the same factor so
/// the path keeps its curvature. Each speed is then **rounded to nearest** (half away
/// from zero) and **clamped to ±floor(max_motor_rpm)**: rounding to nearest keeps the
/// two wheels' ratio as close as integers allow, and the clamp is the backstop that
/// makes "never above the limit" independent of f32 rounding in the scale factor.
///
/// Parameters that make the result meaningless (a zero radius, a NaN, a negative
/// limit) yield standstill rather than an arbitrary speed; register validation should
/// keep them out anyway.
pub fn motor_rpm(params: &KinematicsParams, twist: Twist) -> MotorRpm {
    let linear = twist.linear_mm_s as f32;
    let rotation_rad_s = twist.rotation_mrad_s as f32 / 1000.0;
    let half_track = rotation_rad_s * params.wheel_distance_mm / 2.0;
    // Clockwise is positive and y points right, so a clockwise turn puts the left
    // wheel on the outside of the curve.
    let left_mm_s = linear + half_track;
    let right_mm_s = linear - half_track;

    let per_mm_s = |radius_mm: f32| 60.0 / (2.0 * PI * radius_mm) * params.gear_ratio;
    let mut left = left_mm_s * per_mm_s(params.left_radius_mm);
    let mut right = right_mm_s * per_mm_s(params.right_radius_mm);

    let max = params.max_motor_rpm;
    if !(left.is_finite() && right.is_finite() && max >= 0.0 && max.is_finite()) {
        return MotorRpm::ZERO;
    }
    let fastest = libm::fabsf(left).max(libm::fabsf(right));
    if fastest > max {
        let scale = max / fastest;
        left *= scale;
        right *= scale;
    }

    // `as i32` saturates, so a limit beyond i32 cannot wrap.
    let limit = libm::floorf(max) as i32;
    let to_int = |rpm: f32| (libm::roundf(rpm) as i32).clamp(-limit, limit);
    let (mut left, mut right) = (to_int(left), to_int(right));
    if params.invert_left {
        left = -left;
    }
    if params.invert_right {
        right = -right;
    }
    MotorRpm { left, right }
}

/// A speed command for both drives with the acceleration each one ramps with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WheelCommand {
    pub rpm: MotorRpm,
    /// Magnitudes in (1/min)/s; the drive uses them for speeding up and slowing down.
    pub left_accel: u32,
    pub right_accel: u32,
}

/// Splits `accel_rpm_per_s` between the wheels so that both reach `target` from
/// `previous` at the same moment, which keeps the base on the commanded curvature
/// while it ramps.
///
/// The wheel with the larger change gets the full value, the other its share
/// `accel · |Δ| / max|Δ|`, rounded to nearest. A wheel that must change gets at least
/// 1 (0 would leave it short of its target, or mean something else to the drive), so
/// tiny shares and `accel_rpm_per_s == 0` are the only cases where the arrival times
/// can differ. A wheel that does not change gets the full value: it does not ramp, and
/// the full value is what it will brake with if the next command interrupts.
pub fn ramp(previous: MotorRpm, target: MotorRpm, accel_rpm_per_s: u32) -> WheelCommand {
    // i64: the difference of two i32 speeds can exceed i32.
    let delta_left = (i64::from(target.left) - i64::from(previous.left)).unsigned_abs();
    let delta_right = (i64::from(target.right) - i64::from(previous.right)).unsigned_abs();
    let largest = delta_left.max(delta_right);
    let share = |delta: u64| -> u32 {
        if delta == 0 {
            return accel_rpm_per_s;
        }
        // accel and delta are both < 2³², so accel·delta + largest/2 < 2⁶⁴; the quotient
        // is ≤ accel (= accel exactly for the larger change), so it fits u32.
        let scaled = (u64::from(accel_rpm_per_s) * delta + largest / 2) / largest;
        u32::try_from(scaled).unwrap_or(accel_rpm_per_s).max(1)
    };
    WheelCommand {
        rpm: target,
        left_accel: share(delta_left),
        right_accel: share(delta_right),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The robot's register defaults, gear 10, no mirror mounting.
    fn robot() -> KinematicsParams {
        KinematicsParams {
            left_radius_mm: 142.0,
            right_radius_mm: 142.0,
            wheel_distance_mm: 250.0,
            gear_ratio: 10.0,
            max_motor_rpm: 900.0,
            invert_left: false,
            invert_right: false,
        }
    }

    fn twist(linear_mm_s: i32, rotation_mrad_s: i32) -> Twist {
        Twist {
            linear_mm_s,
            rotation_mrad_s,
        }
    }

    #[test]
    fn straight_forward_turns_both_motors_equally_with_hand_computed_rpm() {
        // 500 / (2π·142) · 60 · 10 = 336.24 → 336.
        let rpm = motor_rpm(&robot(), twist(500, 0));
        assert_eq!(
            rpm,
            MotorRpm {
                left: 336,
                right: 336
            }
        );
    }

    #[test]
    fn straight_backward_is_the_mirror_of_forward() {
        let rpm = motor_rpm(&robot(), twist(-500, 0));
        assert_eq!(
            rpm,
            MotorRpm {
                left: -336,
                right: -336
            }
        );
    }

    #[test]
    fn clockwise_spin_runs_left_forward_and_right_backward() {
        // 1 rad/s · 125 mm = 125 mm/s → 125 / (2π·142) · 600 = 84.06 → 84.
        let rpm = motor_rpm(&robot(), twist(0, 1000));
        assert_eq!(
            rpm,
            MotorRpm {
                left: 84,
                right: -84
            }
        );
    }

    #[test]
    fn counter_clockwise_spin_runs_right_forward() {
        let rpm = motor_rpm(&robot(), twist(0, -1000));
        assert_eq!(
            rpm,
            MotorRpm {
                left: -84,
                right: 84
            }
        );
    }

    #[test]
    fn clockwise_arc_speeds_up_the_left_wheel() {
        // left 500 + 62.5 = 562.5 mm/s → 378.27 → 378; right 437.5 → 294.21 → 294.
        let rpm = motor_rpm(&robot(), twist(500, 500));
        assert_eq!(
            rpm,
            MotorRpm {
                left: 378,
                right: 294
            }
        );
        assert!(rpm.left > rpm.right);
    }

    #[test]
    fn counter_clockwise_arc_speeds_up_the_right_wheel() {
        let rpm = motor_rpm(&robot(), twist(500, -500));
        assert_eq!(
            rpm,
            MotorRpm {
                left: 294,
                right: 378
            }
        );
    }

    #[test]
    fn gear_ratio_scales_motor_speed_proportionally() {
        let params = KinematicsParams {
            gear_ratio: 20.0,
            ..robot()
        };
        // 336.24 · 2 = 672.49 → 672.
        assert_eq!(
            motor_rpm(&params, twist(500, 0)),
            MotorRpm {
                left: 672,
                right: 672
            }
        );
    }

    #[test]
    fn smaller_radius_needs_more_rpm_for_the_same_speed() {
        let params = KinematicsParams {
            left_radius_mm: 100.0,
            right_radius_mm: 100.0,
            ..robot()
        };
        // 500 / (2π·100) · 600 = 477.46 → 477.
        assert_eq!(
            motor_rpm(&params, twist(500, 0)),
            MotorRpm {
                left: 477,
                right: 477
            }
        );
    }

    #[test]
    fn each_wheel_uses_its_own_radius() {
        let params = KinematicsParams {
            left_radius_mm: 140.0,
            right_radius_mm: 144.0,
            ..robot()
        };
        // 500 / (2π·140) · 600 = 341.05 → 341; 500 / (2π·144) · 600 = 331.57 → 332.
        assert_eq!(
            motor_rpm(&params, twist(500, 0)),
            MotorRpm {
                left: 341,
                right: 332
            }
        );
    }

    #[test]
    fn inversion_flags_flip_only_their_own_motor() {
        let left = KinematicsParams {
            invert_left: true,
            ..robot()
        };
        let right = KinematicsParams {
            invert_right: true,
            ..robot()
        };
        assert_eq!(
            motor_rpm(&left, twist(500, 500)),
            MotorRpm {
                left: -378,
                right: 294
            }
        );
        assert_eq!(
            motor_rpm(&right, twist(500, 500)),
            MotorRpm {
                left: 378,
                right: -294
            }
        );
    }

    #[test]
    fn over_the_limit_both_wheels_scale_by_the_same_factor() {
        // Unlimited: left 2000 + 125 = 2125 mm/s → 1429.0; right 1875 → 1260.9.
        let rpm = motor_rpm(&robot(), twist(2000, 1000));
        assert_eq!(rpm.left, 900);
        // 1875/2125 · 900 = 794.1
        assert_eq!(rpm.right, 794);
        let commanded_ratio = 1875.0 / 2125.0;
        let sent_ratio = rpm.right as f32 / rpm.left as f32;
        assert!((sent_ratio - commanded_ratio).abs() < 0.5 / 900.0);
    }

    #[test]
    fn scaling_keeps_curvature_when_the_slower_wheel_runs_backward() {
        // left 600 + 1500 = 2100, right 600 − 1500 = −900 mm/s: ratio −3/7.
        let rpm = motor_rpm(&robot(), twist(600, 12_000));
        assert_eq!(rpm.left, 900);
        assert_eq!(rpm.right, -386); // −900/2100 · 900 = −385.7
    }

    #[test]
    fn safety_clamp_limits_each_component_independently() {
        let limits = SafetyLimits {
            linear_mm_s: 200,
            rotation_mrad_s: 100,
        };
        assert_eq!(twist(1000, -500).clamped(limits), twist(200, -100));
        assert_eq!(twist(-1000, 50).clamped(limits), twist(-200, 50));
        assert_eq!(twist(150, 0).clamped(limits), twist(150, 0));
        assert_eq!(twist(i32::MIN, i32::MAX).clamped(limits), twist(-200, 100));
    }

    #[test]
    fn zero_radius_commands_standstill_instead_of_infinity() {
        let params = KinematicsParams {
            left_radius_mm: 0.0,
            ..robot()
        };
        assert_eq!(motor_rpm(&params, twist(500, 0)), MotorRpm::ZERO);
    }

    #[test]
    fn the_larger_change_gets_the_full_acceleration_and_the_other_its_share() {
        let previous = MotorRpm { left: 0, right: 0 };
        let target = MotorRpm {
            left: 900,
            right: 300,
        };
        let cmd = ramp(previous, target, 700);
        assert_eq!(cmd.rpm, target);
        assert_eq!(cmd.left_accel, 700);
        assert_eq!(cmd.right_accel, 233); // 700 · 300/900 = 233.3
    }

    #[test]
    fn both_wheels_reach_their_targets_at_the_same_moment() {
        let cases = [
            (
                MotorRpm { left: 0, right: 0 },
                MotorRpm {
                    left: 900,
                    right: 300,
                },
            ),
            (
                MotorRpm {
                    left: 336,
                    right: 336,
                },
                MotorRpm {
                    left: -84,
                    right: 84,
                },
            ),
            (
                MotorRpm {
                    left: -900,
                    right: 17,
                },
                MotorRpm {
                    left: 900,
                    right: 0,
                },
            ),
            (
                MotorRpm {
                    left: 5,
                    right: 800,
                },
                MotorRpm {
                    left: -300,
                    right: -800,
                },
            ),
        ];
        for (previous, target) in cases {
            let cmd = ramp(previous, target, 700);
            let delta_left = (target.left - previous.left).abs() as f64;
            let delta_right = (target.right - previous.right).abs() as f64;
            let t_left = delta_left / f64::from(cmd.left_accel);
            let t_right = delta_right / f64::from(cmd.right_accel);
            let t = t_left.max(t_right);
            // Rounding the smaller share to an integer moves its time by at most
            // 0.5/share of itself. (Shares below 1 are raised to 1 and cannot be
            // synchronized; `a_tiny_change_still_gets_at_least_one` covers them.)
            let slower = f64::from(cmd.left_accel.min(cmd.right_accel));
            assert!(
                (t_left - t_right).abs() <= t * 0.5 / slower + 1e-12,
                "{previous:?} → {target:?}: {t_left} s vs {t_right} s"
            );
        }
    }

    #[test]
    fn a_wheel_without_change_keeps_the_full_acceleration() {
        let cmd = ramp(
            MotorRpm {
                left: 100,
                right: 200,
            },
            MotorRpm {
                left: 100,
                right: 500,
            },
            350,
        );
        assert_eq!((cmd.left_accel, cmd.right_accel), (350, 350));
        let still = ramp(MotorRpm::ZERO, MotorRpm::ZERO, 350);
        assert_eq!((still.left_accel, still.right_accel), (350, 350));
    }

    #[test]
    fn a_tiny_change_still_gets_at_least_one() {
        let cmd = ramp(
            MotorRpm::ZERO,
            MotorRpm {
                left: 900,
                right: 1,
            },
            350,
        );
        // 350/900 = 0.39 would round to 0, which would never get there.
        assert_eq!((cmd.left_accel, cmd.right_accel), (350, 1));
    }

    #[test]
    fn zero_acceleration_still_gives_changing_wheels_one() {
        let cmd = ramp(
            MotorRpm::ZERO,
            MotorRpm {
                left: 900,
                right: 0,
            },
            0,
        );
        assert_eq!((cmd.left_accel, cmd.right_accel), (1, 0));
    }

    #[test]
    fn extreme_speed_changes_do_not_overflow() {
        let cmd = ramp(
            MotorRpm {
                left: i32::MIN,
                right: i32::MAX,
            },
            MotorRpm {
                left: i32::MAX,
                right: 0,
            },
            u32::MAX,
        );
        assert_eq!(cmd.left_accel, u32::MAX);
        // u32::MAX · (2³¹ − 1) / (2³² − 1) = 2³¹ − 1 exactly.
        assert_eq!(cmd.right_accel, i32::MAX as u32);
    }

    fn params_strategy() -> impl Strategy<Value = KinematicsParams> {
        (
            10.0f32..=1000.0,
            10.0f32..=1000.0,
            50.0f32..=2000.0,
            1.0f32..=100.0,
            1.0f32..=4000.0,
            any::<bool>(),
            any::<bool>(),
        )
            .prop_map(|(l, r, d, g, m, il, ir)| KinematicsParams {
                left_radius_mm: l,
                right_radius_mm: r,
                wheel_distance_mm: d,
                gear_ratio: g,
                max_motor_rpm: m,
                invert_left: il,
                invert_right: ir,
            })
    }

    /// The limited motor speeds in f64, before rounding and inversion: an independent
    /// restatement of docs/behaviour.md, "Wheel speeds", to check the f32 implementation against.
    fn exact_scaled_rpm(params: &KinematicsParams, lin: i32, rot: i32) -> (f64, f64) {
        let half_track = f64::from(rot) / 1000.0 * f64::from(params.wheel_distance_mm) / 2.0;
        let rpm = |mm_s: f64, radius: f32| {
            mm_s * 60.0 / (2.0 * core::f64::consts::PI * f64::from(radius))
                * f64::from(params.gear_ratio)
        };
        let left = rpm(f64::from(lin) + half_track, params.left_radius_mm);
        let right = rpm(f64::from(lin) - half_track, params.right_radius_mm);
        let max = f64::from(params.max_motor_rpm);
        let fastest = left.abs().max(right.abs());
        let scale = if fastest > max { max / fastest } else { 1.0 };
        (left * scale, right * scale)
    }

    proptest! {
        #[test]
        fn never_exceeds_max_motor_rpm(
            params in params_strategy(),
            lin in any::<i16>(),
            rot in any::<i16>(),
        ) {
            let rpm = motor_rpm(&params, twist(lin.into(), rot.into()));
            prop_assert!(rpm.left.unsigned_abs() as f32 <= params.max_motor_rpm);
            prop_assert!(rpm.right.unsigned_abs() as f32 <= params.max_motor_rpm);
        }

        #[test]
        fn sent_speeds_are_the_exactly_scaled_speeds_within_rounding(
            params in params_strategy(),
            lin in any::<i16>(),
            rot in any::<i16>(),
        ) {
            // Both wheels within rounding of one common scale factor: the ratio, and
            // with it the curvature, is kept.
            let (left, right) = exact_scaled_rpm(&params, lin.into(), rot.into());
            let sent = motor_rpm(&params, twist(lin.into(), rot.into()));
            let sign = |inverted: bool| if inverted { -1.0 } else { 1.0 };
            // ≤ 0.5 from rounding, + 1 from the floor(max) clamp, + f32's ~7 digits.
            let slack = |v: f64| 1.5 + v.abs() * 1e-5;
            prop_assert!((f64::from(sent.left) * sign(params.invert_left) - left).abs() <= slack(left));
            prop_assert!((f64::from(sent.right) * sign(params.invert_right) - right).abs() <= slack(right));
        }
    }
}
