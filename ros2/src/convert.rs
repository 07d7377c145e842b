//! What is converted where: ROS (REP-103: metres, radians, x forward, y left, yaw
//! counter-clockwise) ↔ the base's CAN protocol (mm, mrad, x forward, y right, heading
//! clockwise). Every sign flip of the bridge is in this file.

/// A `/cmd_vel` the bridge refuses: a NaN or infinite component.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotFinite;

/// A velocity command on the wire: 0x0C8's linear mm/s (+ forward) and rotation
/// mrad/s (+ clockwise).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WireVelocity {
    pub linear_mm_s: i16,
    pub rotation_mrad_s: i16,
    /// A component was beyond ±32.767 m/s or rad/s and was clamped to the i16 range.
    pub clamped: bool,
}

/// `/cmd_vel`'s linear.x (m/s, + forward) and angular.z (rad/s, + counter-clockwise)
/// as the base's velocity command. The other components have no meaning for a
/// differential base and are ignored, as diff_drive_controller does.
pub fn velocity_to_wire(linear_x: f64, angular_z: f64) -> Result<WireVelocity, NotFinite> {
    if !linear_x.is_finite() || !angular_z.is_finite() {
        return Err(NotFinite);
    }
    let (linear_mm_s, clamped_linear) = to_i16(linear_x * 1000.0);
    // ROS counts counter-clockwise positive, the base clockwise.
    let (rotation_mrad_s, clamped_rotation) = to_i16(-angular_z * 1000.0);
    Ok(WireVelocity {
        linear_mm_s,
        rotation_mrad_s,
        clamped: clamped_linear || clamped_rotation,
    })
}

fn to_i16(value: f64) -> (i16, bool) {
    let rounded = value.round();
    if rounded > f64::from(i16::MAX) {
        (i16::MAX, true)
    } else if rounded < f64::from(i16::MIN) {
        (i16::MIN, true)
    } else {
        // In range after the checks above.
        (rounded as i16, false)
    }
}

/// A pose in the odom frame, REP-103: metres, radians, y left, yaw counter-clockwise
/// (cumulative, like the base's heading: not wrapped to ±π).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RosPose {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

/// The base's 0x0EC/0x0ED pose (mm, y right; mrad, clockwise) in REP-103.
pub fn pose_from_wire(x_mm: i32, y_mm: i32, heading_mrad: i32) -> RosPose {
    RosPose {
        x: f64::from(x_mm) / 1000.0,
        y: -f64::from(y_mm) / 1000.0,
        yaw: -f64::from(heading_mrad) / 1000.0,
    }
}

/// The body-frame twist between two poses `dt_s` apart: forward speed (m/s, the
/// displacement projected on the mean heading) and yaw rate (rad/s,
/// counter-clockwise). A differential base has no sideways speed.
pub fn twist_between(from: RosPose, to: RosPose, dt_s: f64) -> (f64, f64) {
    if dt_s <= 0.0 || !dt_s.is_finite() {
        return (0.0, 0.0);
    }
    let mean_yaw = (from.yaw + to.yaw) / 2.0;
    let dx = to.x - from.x;
    let dy = to.y - from.y;
    let forward = dx * mean_yaw.cos() + dy * mean_yaw.sin();
    (forward / dt_s, (to.yaw - from.yaw) / dt_s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_in_ros_is_forward_on_the_wire_in_mm_per_s() {
        let wire = velocity_to_wire(0.5, 0.0).unwrap();
        assert_eq!((wire.linear_mm_s, wire.rotation_mrad_s), (500, 0));
        assert!(!wire.clamped);
    }

    #[test]
    fn a_counter_clockwise_turn_in_ros_is_a_negative_rotation_on_the_wire() {
        let wire = velocity_to_wire(0.0, 1.0).unwrap();
        assert_eq!(wire.rotation_mrad_s, -1000);
        let wire = velocity_to_wire(-0.3, -0.25).unwrap();
        assert_eq!((wire.linear_mm_s, wire.rotation_mrad_s), (-300, 250));
    }

    #[test]
    fn speeds_beyond_i16_are_clamped_and_flagged() {
        let wire = velocity_to_wire(100.0, -100.0).unwrap();
        assert_eq!(
            (wire.linear_mm_s, wire.rotation_mrad_s),
            (i16::MAX, i16::MAX)
        );
        assert!(wire.clamped);
        let wire = velocity_to_wire(-100.0, 0.0).unwrap();
        assert_eq!(wire.linear_mm_s, i16::MIN);
        assert!(wire.clamped);
    }

    #[test]
    fn nan_and_infinity_are_refused() {
        assert_eq!(velocity_to_wire(f64::NAN, 0.0), Err(NotFinite));
        assert_eq!(velocity_to_wire(0.0, f64::INFINITY), Err(NotFinite));
        assert_eq!(velocity_to_wire(f64::NEG_INFINITY, 0.0), Err(NotFinite));
    }

    #[test]
    fn the_wire_pose_becomes_rep103_y_left_yaw_counter_clockwise() {
        // 1 m forward, 2 mm to the right, a quarter turn clockwise.
        let pose = pose_from_wire(1000, 2, 1571);
        assert_eq!(pose.x, 1.0);
        assert_eq!(pose.y, -0.002);
        assert!((pose.yaw + 1.571).abs() < 1e-12);
    }

    #[test]
    fn the_twist_is_forward_speed_in_the_body_frame_and_yaw_rate() {
        // Heading 90° counter-clockwise (facing +y), moved 0.1 m along +y in 0.5 s.
        let from = RosPose {
            x: 0.0,
            y: 0.0,
            yaw: std::f64::consts::FRAC_PI_2,
        };
        let to = RosPose {
            x: 0.0,
            y: 0.1,
            yaw: std::f64::consts::FRAC_PI_2 + 0.05,
        };
        let (forward, yaw_rate) = twist_between(from, to, 0.5);
        assert!((forward - 0.2).abs() < 1e-3, "{forward}");
        assert!((yaw_rate - 0.1).abs() < 1e-9, "{yaw_rate}");
        assert_eq!(twist_between(from, to, 0.0), (0.0, 0.0));
    }
}
