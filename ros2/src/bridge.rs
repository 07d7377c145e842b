//! The bridge's decisions, free of ROS and of the bus so that tests can drive them
//! with made-up times: when to send the enable and the velocity, when a `/cmd_vel` is
//! stale and the base must stop, and how the base's reports become odometry.

use std::time::{Duration, Instant};

use base_core::can::Command;

use crate::convert::{self, NotFinite, RosPose, WireVelocity};

/// Where the bridge's command side is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Drive {
    /// No fresh `/cmd_vel`: nothing is sent, the base's enable lapses (or was withdrawn).
    Idle,
    /// A fresh `/cmd_vel`: enable and velocity every period.
    Driving,
}

/// Counters the node logs and reports in `/diagnostics`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counts {
    /// `/cmd_vel` messages taken.
    pub commands: u64,
    /// `/cmd_vel` messages refused for a NaN or infinite component.
    pub not_finite: u64,
    /// `/cmd_vel` messages beyond the i16 range, clamped.
    pub clamped: u64,
    /// Times a stale `/cmd_vel` stopped the base.
    pub timeouts: u64,
}

/// The command side: `/cmd_vel` in, CAN commands out.
#[derive(Debug)]
pub struct CommandSide {
    timeout: Duration,
    period: Duration,
    state: Drive,
    velocity: WireVelocity,
    last_command: Option<Instant>,
    next_send: Option<Instant>,
    pub counts: Counts,
}

impl CommandSide {
    /// `timeout`: how old the last `/cmd_vel` may be while the base keeps driving;
    /// `period`: how often the enable and the velocity are sent meanwhile.
    pub fn new(timeout: Duration, period: Duration) -> Self {
        CommandSide {
            timeout,
            period,
            state: Drive::Idle,
            velocity: WireVelocity::default(),
            last_command: None,
            next_send: None,
            counts: Counts::default(),
        }
    }

    /// A `/cmd_vel` arrived: linear.x m/s, angular.z rad/s (REP-103). Returns the
    /// frames to send at once (enable, velocity), so a new command does not wait for
    /// the next period. A NaN or infinite command is refused: counted, nothing sent,
    /// and it does not keep the base driving.
    pub fn on_cmd_vel(
        &mut self,
        now: Instant,
        linear_x: f64,
        angular_z: f64,
    ) -> Result<Vec<Command>, NotFinite> {
        self.counts.commands += 1;
        let velocity = match convert::velocity_to_wire(linear_x, angular_z) {
            Ok(velocity) => velocity,
            Err(error) => {
                self.counts.not_finite += 1;
                return Err(error);
            }
        };
        if velocity.clamped {
            self.counts.clamped += 1;
        }
        self.velocity = velocity;
        self.last_command = Some(now);
        self.state = Drive::Driving;
        self.next_send = Some(now + self.period);
        Ok(self.drive_frames())
    }

    fn drive_frames(&self) -> Vec<Command> {
        vec![
            Command::Enable { refresh: true },
            Command::Velocity {
                linear_mm_s: self.velocity.linear_mm_s,
                rotation_mrad_s: self.velocity.rotation_mrad_s,
            },
        ]
    }

    /// The frames due at `now`: the periodic enable and velocity while the last
    /// `/cmd_vel` is fresh; once it is older than the time-out, a zero velocity and
    /// then the enable withdrawn, once.
    pub fn tick(&mut self, now: Instant) -> Vec<Command> {
        if self.state == Drive::Idle {
            return Vec::new();
        }
        let fresh = self
            .last_command
            .is_some_and(|last| now.saturating_duration_since(last) <= self.timeout);
        if !fresh {
            return self.stop();
        }
        match self.next_send {
            Some(due) if now < due => Vec::new(),
            _ => {
                self.next_send = Some(now + self.period);
                self.drive_frames()
            }
        }
    }

    /// Stops the base now (stale command, or the node is ending): zero velocity while
    /// the enable is still fresh, then the enable withdrawn.
    pub fn stop(&mut self) -> Vec<Command> {
        if self.state == Drive::Idle {
            return Vec::new();
        }
        self.state = Drive::Idle;
        self.counts.timeouts += 1;
        self.velocity = WireVelocity::default();
        vec![
            Command::Enable { refresh: true },
            Command::Velocity {
                linear_mm_s: 0,
                rotation_mrad_s: 0,
            },
            Command::Enable { refresh: false },
        ]
    }

    /// When [`tick`](Self::tick) next has something to do, if ever.
    pub fn next_deadline(&self) -> Option<Instant> {
        match self.state {
            Drive::Idle => None,
            Drive::Driving => {
                let stale = self.last_command.map(|last| last + self.timeout);
                match (self.next_send, stale) {
                    (Some(send), Some(stale)) => Some(send.min(stale)),
                    (send, stale) => send.or(stale),
                }
            }
        }
    }

    pub fn is_driving(&self) -> bool {
        self.state == Drive::Driving
    }
}

/// One odometry sample: the pose and the twist since the previous sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometrySample {
    pub pose: RosPose,
    /// Forward speed, m/s.
    pub linear_x: f64,
    /// Yaw rate, rad/s, counter-clockwise.
    pub angular_z: f64,
}

/// The report side: 0x0EC (x, y) then 0x0ED (heading) make one pose.
#[derive(Debug, Default)]
pub struct OdometrySide {
    position: Option<(i32, i32)>,
    previous: Option<(Instant, RosPose)>,
}

impl OdometrySide {
    pub fn on_position(&mut self, x_mm: i32, y_mm: i32) {
        self.position = Some((x_mm, y_mm));
    }

    /// 0x0ED completes the pose the last 0x0EC started. `None` without a position
    /// yet.
    pub fn on_heading(&mut self, now: Instant, heading_mrad: i32) -> Option<OdometrySample> {
        let (x_mm, y_mm) = self.position.take()?;
        let pose = convert::pose_from_wire(x_mm, y_mm, heading_mrad);
        let (linear_x, angular_z) = match self.previous {
            Some((then, previous)) => {
                convert::twist_between(previous, pose, (now - then).as_secs_f64())
            }
            None => (0.0, 0.0),
        };
        self.previous = Some((now, pose));
        Some(OdometrySample {
            pose,
            linear_x,
            angular_z,
        })
    }

    /// After an odometry reset the pose jumps to zero: no twist across the jump.
    pub fn forget_previous(&mut self) {
        self.previous = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TIMEOUT: Duration = Duration::from_millis(500);
    const PERIOD: Duration = Duration::from_millis(50);

    #[test]
    fn a_fresh_cmd_vel_sends_enable_then_velocity_at_once_and_every_period() {
        let start = Instant::now();
        let mut side = CommandSide::new(TIMEOUT, PERIOD);
        let frames = side.on_cmd_vel(start, 0.5, 1.0).unwrap();
        assert_eq!(
            frames,
            [
                Command::Enable { refresh: true },
                Command::Velocity {
                    linear_mm_s: 500,
                    rotation_mrad_s: -1000
                }
            ]
        );
        assert!(side.tick(start + Duration::from_millis(10)).is_empty());
        assert_eq!(side.tick(start + PERIOD).len(), 2);
        assert!(
            side.tick(start + PERIOD + Duration::from_millis(1))
                .is_empty()
        );
        assert_eq!(side.tick(start + PERIOD * 2).len(), 2);
    }

    #[test]
    fn a_stale_cmd_vel_sends_zero_then_withdraws_the_enable_once() {
        let start = Instant::now();
        let mut side = CommandSide::new(TIMEOUT, PERIOD);
        side.on_cmd_vel(start, 0.5, 0.0).unwrap();
        let frames = side.tick(start + TIMEOUT + Duration::from_millis(1));
        assert_eq!(
            frames,
            [
                Command::Enable { refresh: true },
                Command::Velocity {
                    linear_mm_s: 0,
                    rotation_mrad_s: 0
                },
                Command::Enable { refresh: false },
            ]
        );
        assert!(!side.is_driving());
        assert_eq!(side.counts.timeouts, 1);
        assert!(side.tick(start + TIMEOUT * 4).is_empty());
        assert_eq!(side.next_deadline(), None);
    }

    #[test]
    fn a_nan_cmd_vel_is_counted_and_does_not_keep_the_base_driving() {
        let start = Instant::now();
        let mut side = CommandSide::new(TIMEOUT, PERIOD);
        side.on_cmd_vel(start, 0.2, 0.0).unwrap();
        let later = start + Duration::from_millis(400);
        assert_eq!(side.on_cmd_vel(later, f64::NAN, 0.0), Err(NotFinite));
        assert_eq!(side.counts.not_finite, 1);
        // The NaN did not refresh the command: it goes stale 0.5 s after the good one.
        let frames = side.tick(start + TIMEOUT + Duration::from_millis(1));
        assert_eq!(frames.last(), Some(&Command::Enable { refresh: false }));
    }

    #[test]
    fn position_and_heading_make_a_pose_and_the_twist_from_their_differences() {
        let start = Instant::now();
        let mut odometry = OdometrySide::default();
        assert_eq!(odometry.on_heading(start, 0), None, "no position yet");
        odometry.on_position(0, 0);
        let first = odometry.on_heading(start, 0).unwrap();
        assert_eq!((first.linear_x, first.angular_z), (0.0, 0.0));
        // 25 mm forward and 50 mrad clockwise in 50 ms.
        odometry.on_position(25, 0);
        let second = odometry
            .on_heading(start + Duration::from_millis(50), 50)
            .unwrap();
        assert!((second.linear_x - 0.5).abs() < 1e-3, "{second:?}");
        assert!((second.angular_z + 1.0).abs() < 1e-9, "{second:?}");
        assert!((second.pose.yaw + 0.05).abs() < 1e-12);
    }
}
