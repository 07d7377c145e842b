//! The bridge's decisions, free of ROS and of the bus so that tests can drive them
//! with made-up times: when to send the enable and the velocity, when a `/cmd_vel` is
//! stale and the base must stop, and how the base's reports become odometry.

use std::time::{Duration, Instant};

use base_core::can::{Command, ReadEcho};
use base_core::registers::Reg;

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
    /// The pose's moment on the controller's clock (0x0EF), when it came.
    pub controller_ms: Option<u32>,
    /// The wheels' joint states, when the pose came with its measured speed (0x0F0).
    pub wheels: Option<WheelJoints>,
}

/// 0x0F0 (ext) as it came: see `Report::MeasuredSpeed`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WireSpeed {
    pub linear_mm_s: i16,
    /// Clockwise.
    pub rotation_mrad_s: i16,
    pub left_wheel_crad_s: i16,
    pub right_wheel_crad_s: i16,
}

/// Both wheels' joints: left, right. Positive is the sense that drives the base
/// forward.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelJoints {
    /// Integrated from the measured speeds over the pose times, rad.
    pub position_rad: [f64; 2],
    pub velocity_rad_s: [f64; 2],
}

/// What the base can physically do (parameters `max_linear_speed`,
/// `max_angular_speed`): a twist beyond it is a jump of the pose, not motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedLimits {
    pub linear_m_s: f64,
    pub angular_rad_s: f64,
}

impl Default for SpeedLimits {
    fn default() -> Self {
        Self {
            linear_m_s: 3.0,
            angular_rad_s: 10.0,
        }
    }
}

impl SpeedLimits {
    fn holds(&self, (linear, angular): (f64, f64)) -> bool {
        linear.abs() <= self.linear_m_s && angular.abs() <= self.angular_rad_s
    }

    fn clamp(&self, (linear, angular): (f64, f64)) -> (f64, f64) {
        (
            linear.clamp(-self.linear_m_s, self.linear_m_s),
            angular.clamp(-self.angular_rad_s, self.angular_rad_s),
        )
    }
}

/// Where the twist of `/odom` comes from, best first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwistSource {
    /// The drives' measured speed (0x0F0).
    MeasuredSpeed,
    /// Pose differences over the poses' times on the controller's clock (0x0EF).
    ControllerClock,
    /// Pose differences over whole cycles of arrival time: a controller without the
    /// extensions.
    Arrival,
}

impl TwistSource {
    pub fn name(self) -> &'static str {
        match self {
            TwistSource::MeasuredSpeed => "measured_speed",
            TwistSource::ControllerClock => "controller_clock",
            TwistSource::Arrival => "arrival",
        }
    }
}

/// The register the base's feedback period is read from: the position frames come
/// every `loop_end_delay` ms.
pub const CYCLE_REGISTER: u8 = Reg::LoopEndDelay.address();

/// How long the base controller may take to answer the read that follows a reset.
const RESET_ANSWER_TIMEOUT: Duration = Duration::from_secs(1);

/// Where an odometry reset is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ResetPhase {
    /// `005#01` and a tagged register read were sent. The controller handles frames
    /// in order, so the read's reply comes after the reset took effect; a pose that
    /// arrives before the reply may be from before or after the reset, and is not
    /// published.
    AwaitingAnswer { tag: u16, deadline: Instant },
    /// The reply came: every pose from now on is from after the reset. Without a pose
    /// by `deadline` the base sends none (emergency mode).
    AwaitingPose { deadline: Instant },
}

/// How a reset ended, for the service caller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResetOutcome {
    /// A pose from after the reset was published.
    Shown,
    /// The base applied the reset but sends no position now (emergency mode).
    NoPositionStream,
    /// The base controller did not answer: whether it reset is unknown.
    NoAnswer,
}

/// Whether a TwistStamped stamped `stamp_ns` (ns since the epoch) is older than
/// `timeout` at `now_ns`. A zero stamp (the publisher left it unset) is never stale,
/// nor is one from the future (the publisher's clock is ahead): only a command known
/// to be old is dropped.
pub fn stamp_is_stale(stamp_ns: i64, now_ns: i64, timeout: Duration) -> bool {
    let timeout_ns = i64::try_from(timeout.as_nanos()).unwrap_or(i64::MAX);
    stamp_ns != 0 && now_ns.saturating_sub(stamp_ns) > timeout_ns
}

/// The report side: 0x0EC (x, y) then 0x0ED (heading) make one pose. The twist is the
/// speed the drives measured (0x0F0, sent with the pose): exact to their resolution
/// however late any frame arrives, and untouched by a jump of the pose. Without it
/// (older firmware, or a cycle without a fresh reading) the pose change over the time
/// between the poses on the controller's clock (0x0EF), which carries 1 mm and 1 mrad
/// of rounding per pose; without 0x0EF as well, over whole cycles of the base
/// (register `loop_end_delay`) nearest to the arrival times, which a pose the
/// controller itself sent late still gets wrong. A pose-difference twist beyond
/// [`SpeedLimits`] is a jump (someone reset the odometry): the twist before it holds.
#[derive(Debug, Default)]
pub struct OdometrySide {
    /// The controller's time of the pose that the next 0x0EC and 0x0ED make.
    pose_time: Option<u32>,
    /// The measured speed that goes with that pose.
    speed: Option<WireSpeed>,
    position: Option<(i32, i32)>,
    previous: Option<PreviousPose>,
    /// Whether the controller has sent its pose times (0x0EF).
    speaks_pose_time: bool,
    /// Whether the controller has sent measured speeds (0x0F0).
    speaks_measured_speed: bool,
    /// Where the last twist came from.
    twist_source: Option<TwistSource>,
    limits: SpeedLimits,
    /// Pose-difference twists beyond the limits, held instead.
    jumps: u64,
    wheels: WheelIntegral,
    /// The twist last published: kept across a reset, where the pose jumps.
    last_twist: (f64, f64),
    /// The base's feedback period, once its register was read.
    cycle: Option<Duration>,
    reset: Option<ResetPhase>,
}

/// The last pose published, with its arrival and its time on the controller's clock.
#[derive(Debug, Clone, Copy)]
struct PreviousPose {
    arrival: Instant,
    controller_ms: Option<u32>,
    pose: RosPose,
}

/// The wheels' angles, integrated from their measured speeds over the pose times
/// (trapezoids). They are for a robot model's wheels to turn (RViz), not for
/// odometry, which the controller integrates from the counters.
#[derive(Debug, Default)]
struct WheelIntegral {
    position_rad: [f64; 2],
    /// The last speeds and their pose time.
    last: Option<(u32, [f64; 2])>,
}

impl WheelIntegral {
    /// Longer than this between two speeds (the drives were silent, the PC paused),
    /// nothing is known of what the wheels did: the angles stay.
    const MAX_GAP_MS: u32 = 1_000;

    fn step(&mut self, controller_ms: Option<u32>, speed: &WireSpeed) -> WheelJoints {
        let velocity_rad_s = [
            f64::from(speed.left_wheel_crad_s) / 100.0,
            f64::from(speed.right_wheel_crad_s) / 100.0,
        ];
        if let (Some((then, before)), Some(at)) = (self.last, controller_ms) {
            let gap = at.wrapping_sub(then);
            if (1..=Self::MAX_GAP_MS).contains(&gap) {
                let dt = f64::from(gap) / 1000.0;
                for wheel in 0..2 {
                    self.position_rad[wheel] += (before[wheel] + velocity_rad_s[wheel]) / 2.0 * dt;
                }
            }
        }
        self.last = controller_ms.map(|at| (at, velocity_rad_s));
        WheelJoints {
            position_rad: self.position_rad,
            velocity_rad_s,
        }
    }
}

impl OdometrySide {
    pub fn new(limits: SpeedLimits) -> Self {
        Self {
            limits,
            ..Self::default()
        }
    }

    /// 0x0EF (ext): the controller's time of the pose in the 0x0EC and 0x0ED that follow.
    pub fn on_pose_time(&mut self, controller_ms: u32) {
        self.pose_time = Some(controller_ms);
        self.speed = None;
        self.position = None;
        self.speaks_pose_time = true;
    }

    /// 0x0F0 (ext): the measured speed of the pose the next 0x0EC and 0x0ED make.
    pub fn on_measured_speed(&mut self, speed: WireSpeed) {
        self.speed = Some(speed);
        self.speaks_measured_speed = true;
    }

    /// Which extensions the controller has spoken: pose times (0x0EF), measured
    /// speeds (0x0F0).
    pub fn extensions(&self) -> (bool, bool) {
        (self.speaks_pose_time, self.speaks_measured_speed)
    }

    /// Where the last twist came from; `None` before the first pose.
    pub fn twist_source(&self) -> Option<TwistSource> {
        self.twist_source
    }

    /// Pose-difference twists beyond the limits, held instead.
    pub fn jumps(&self) -> u64 {
        self.jumps
    }

    pub fn on_position(&mut self, x_mm: i32, y_mm: i32) {
        self.position = Some((x_mm, y_mm));
    }

    /// 0x0ED completes the pose the last 0x0EC started. `None` without a position
    /// yet, and while a reset waits for the controller's answer. The second value says
    /// that a reset has now shown in the published poses.
    pub fn on_heading(
        &mut self,
        now: Instant,
        heading_mrad: i32,
    ) -> (Option<OdometrySample>, Option<ResetOutcome>) {
        // A time and a speed belong to the one pose that follows them, never to a later
        // one.
        let controller_ms = self.pose_time.take();
        let speed = self.speed.take();
        let Some((x_mm, y_mm)) = self.position.take() else {
            return (None, None);
        };
        let mut outcome = None;
        match self.reset {
            Some(ResetPhase::AwaitingAnswer { .. }) => return (None, None),
            Some(ResetPhase::AwaitingPose { .. }) => {
                // The first pose after the reset: no twist across the jump.
                self.previous = None;
                self.reset = None;
                outcome = Some(ResetOutcome::Shown);
            }
            None => {}
        }
        let pose = convert::pose_from_wire(x_mm, y_mm, heading_mrad);
        let (twist, source) = match speed {
            Some(speed) => (
                // The wire's rotation is clockwise; ROS's yaw rate counter-clockwise.
                self.limits.clamp((
                    f64::from(speed.linear_mm_s) / 1000.0,
                    -f64::from(speed.rotation_mrad_s) / 1000.0,
                )),
                TwistSource::MeasuredSpeed,
            ),
            None => self.twist_from_poses(now, controller_ms, pose),
        };
        self.previous = Some(PreviousPose {
            arrival: now,
            controller_ms,
            pose,
        });
        self.last_twist = twist;
        self.twist_source = Some(source);
        let sample = OdometrySample {
            pose,
            linear_x: twist.0,
            angular_z: twist.1,
            controller_ms,
            wheels: speed.map(|speed| self.wheels.step(controller_ms, &speed)),
        };
        (Some(sample), outcome)
    }

    /// The twist between the last pose and `pose`, and the clock it was taken on.
    fn twist_from_poses(
        &mut self,
        now: Instant,
        controller_ms: Option<u32>,
        pose: RosPose,
    ) -> ((f64, f64), TwistSource) {
        let source = match controller_ms {
            Some(_) => TwistSource::ControllerClock,
            None => TwistSource::Arrival,
        };
        let twist = match self.previous {
            Some(previous) => match (previous.controller_ms, controller_ms) {
                // Differences modulo 2^32: the controller's counter wraps after 49.7
                // days. A gap of 2^31 ms or more is time running backwards (the
                // controller rebooted); like the same moment twice, it gives no rate.
                (Some(then), Some(at)) => match at.wrapping_sub(then) {
                    gap @ 1..0x8000_0000 => {
                        convert::twist_between(previous.pose, pose, f64::from(gap) / 1000.0)
                    }
                    _ => self.last_twist,
                },
                _ => convert::twist_between(
                    previous.pose,
                    pose,
                    self.elapsed(now - previous.arrival),
                ),
            },
            // The first pose: at rest as far as anyone knows; after a reset, moving
            // as before it.
            None => self.last_twist,
        };
        if self.limits.holds(twist) {
            (twist, source)
        } else {
            self.jumps += 1;
            (self.last_twist, source)
        }
    }

    /// The time between two poses that arrived `arrival` apart: the whole number of
    /// the base's cycles nearest to it (at least one). Until the cycle is known, the
    /// arrival time itself.
    fn elapsed(&self, arrival: Duration) -> f64 {
        match self.cycle {
            Some(cycle) if !cycle.is_zero() => {
                let cycle = cycle.as_secs_f64();
                (arrival.as_secs_f64() / cycle).round().max(1.0) * cycle
            }
            _ => arrival.as_secs_f64(),
        }
    }

    /// The frames that reset the odometry (`tag`: the node's own, for the read that
    /// proves the reset was handled). A reset already under way starts over.
    pub fn start_reset(&mut self, now: Instant, tag: u16) -> [Command; 2] {
        self.reset = Some(ResetPhase::AwaitingAnswer {
            tag,
            deadline: now + RESET_ANSWER_TIMEOUT,
        });
        self.position = None;
        [
            Command::ResetOdometry,
            Command::RegisterRead {
                address: CYCLE_REGISTER,
                tag,
            },
        ]
    }

    /// A register reply (anyone's): its address says which register it is, so a
    /// reply of `loop_end_delay` sets the cycle, and the reply to our reset's read
    /// ends the wait for the controller.
    pub fn on_register_value(&mut self, now: Instant, echo: ReadEcho, value: u16) {
        if echo.address != CYCLE_REGISTER {
            return;
        }
        self.cycle = Some(Duration::from_millis(u64::from(value)));
        if let Some(ResetPhase::AwaitingAnswer { tag, .. }) = self.reset
            && tag == echo.tag
        {
            // Two cycles and a margin: a base that sends poses sends one by then.
            let wait = self.cycle.unwrap_or_default() * 2 + Duration::from_millis(100);
            self.reset = Some(ResetPhase::AwaitingPose {
                deadline: now + wait,
            });
            self.position = None;
        }
    }

    /// The base's feedback period, once read.
    pub fn cycle(&self) -> Option<Duration> {
        self.cycle
    }

    /// A reset that ended without a pose by `now`.
    pub fn tick(&mut self, now: Instant) -> Option<ResetOutcome> {
        match self.reset {
            Some(ResetPhase::AwaitingAnswer { deadline, .. }) if now >= deadline => {
                self.reset = None;
                self.previous = None;
                Some(ResetOutcome::NoAnswer)
            }
            Some(ResetPhase::AwaitingPose { deadline }) if now >= deadline => {
                self.reset = None;
                self.previous = None;
                Some(ResetOutcome::NoPositionStream)
            }
            _ => None,
        }
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
        assert_eq!(
            odometry.on_heading(start, 0),
            (None, None),
            "no position yet"
        );
        odometry.on_position(0, 0);
        let first = odometry.on_heading(start, 0).0.unwrap();
        assert_eq!((first.linear_x, first.angular_z), (0.0, 0.0));
        // 25 mm forward and 50 mrad clockwise in 50 ms.
        odometry.on_position(25, 0);
        let second = odometry
            .on_heading(start + Duration::from_millis(50), 50)
            .0
            .unwrap();
        assert!((second.linear_x - 0.5).abs() < 1e-3, "{second:?}");
        assert!((second.angular_z + 1.0).abs() < 1e-9, "{second:?}");
        assert!((second.pose.yaw + 0.05).abs() < 1e-12);
    }

    /// A pose every 50 ms (`loop_end_delay` 50), its frames up to 20 ms late:
    /// `pose(cycle)` is (x mm, heading mrad clockwise).
    fn jittered(
        odometry: &mut OdometrySide,
        pose: impl Fn(i32) -> (i32, i32),
    ) -> Vec<OdometrySample> {
        let start = Instant::now();
        let late_ms = [0, 20, 3, 17, 0, 9, 20, 1];
        (0..40)
            .filter_map(|cycle: i32| {
                let (x_mm, heading_mrad) = pose(cycle);
                odometry.on_position(x_mm, 0);
                let arrival = start
                    + Duration::from_millis(
                        50 * cycle as u64 + late_ms[cycle as usize % late_ms.len()],
                    );
                odometry.on_heading(arrival, heading_mrad).0
            })
            .collect()
    }

    fn knowing_the_cycle() -> OdometrySide {
        let mut odometry = OdometrySide::default();
        let echo = ReadEcho {
            address: CYCLE_REGISTER,
            tag: 0,
        };
        odometry.on_register_value(Instant::now(), echo, 50);
        odometry
    }

    #[test]
    fn the_twist_is_exact_over_the_bases_cycle_however_late_the_frames_arrive() {
        // 0.3 m/s straight ahead: 15 mm per cycle.
        let samples = jittered(&mut knowing_the_cycle(), |cycle| (cycle * 15, 0));
        for sample in &samples[1..] {
            assert!((sample.linear_x - 0.3).abs() < 1e-9, "{sample:?}");
        }
        // 0.2 rad/s counter-clockwise on the spot: -10 mrad (clockwise) per cycle.
        let samples = jittered(&mut knowing_the_cycle(), |cycle| (0, -10 * cycle));
        for sample in &samples[1..] {
            assert!((sample.angular_z - 0.2).abs() < 1e-9, "{sample:?}");
        }
    }

    #[test]
    fn before_the_cycle_is_known_the_arrival_times_are_used() {
        let samples = jittered(&mut OdometrySide::default(), |cycle| (cycle * 15, 0));
        assert!(
            samples[1..]
                .iter()
                .any(|sample| (sample.linear_x - 0.3).abs() > 0.03),
            "arrival jitter shows without the cycle"
        );
    }

    /// 0.3 m/s straight ahead, a pose every 50 ms of the controller's clock, except the
    /// 6th, which the controller sent 10 ms late (it carries its pose to the moment it
    /// sends), and the 12th, whose frames were then held up 30 ms on the way. Returns
    /// the twists.
    fn late_sends_and_late_frames(odometry: &mut OdometrySide, with_pose_time: bool) -> Vec<f64> {
        let start = Instant::now();
        (0..20u32)
            .filter_map(|cycle| {
                let sent_ms = 50 * cycle + if cycle == 6 { 10 } else { 0 };
                let arrival_ms = sent_ms + if cycle == 12 { 30 } else { 1 };
                if with_pose_time {
                    odometry.on_pose_time(100_000 + sent_ms);
                }
                // 0.3 m/s is 0.3 mm per ms.
                odometry.on_position((sent_ms * 3 / 10) as i32, 0);
                let arrival = start + Duration::from_millis(u64::from(arrival_ms));
                odometry.on_heading(arrival, 0).0
            })
            .map(|sample| sample.linear_x)
            .collect()
    }

    /// One cycle as a controller with both extensions sends it.
    fn cycle(
        odometry: &mut OdometrySide,
        controller_ms: u32,
        speed: WireSpeed,
        pose: (i32, i32),
        arrival: Instant,
    ) -> OdometrySample {
        odometry.on_pose_time(controller_ms);
        odometry.on_measured_speed(speed);
        odometry.on_position(pose.0, 0);
        odometry.on_heading(arrival, pose.1).0.unwrap()
    }

    const FORWARD_300: WireSpeed = WireSpeed {
        linear_mm_s: 300,
        rotation_mrad_s: 0,
        left_wheel_crad_s: 211,
        right_wheel_crad_s: 211,
    };

    #[test]
    fn with_the_measured_speed_the_twist_is_exact_through_late_frames_sends_and_a_new_cycle() {
        // Never told the cycle. Frames up to 30 ms late, sends 10 ms late, and from
        // the 20th pose on a cycle of 20 ms the node has not read yet: each of these
        // made the twist from poses wrong by tens of percent.
        let start = Instant::now();
        let mut odometry = OdometrySide::default();
        let mut sent_ms = 0;
        for index in 0..40u32 {
            sent_ms += if index < 20 { 50 } else { 20 } + if index % 7 == 3 { 10 } else { 0 };
            let late_ms = [0, 30, 2, 17][index as usize % 4];
            let arrival = start + Duration::from_millis(u64::from(sent_ms + late_ms));
            // The pose as the wire rounds it: 0.3 mm per ms.
            let pose = ((sent_ms * 3 / 10) as i32, 0);
            let sample = cycle(&mut odometry, 10_000 + sent_ms, FORWARD_300, pose, arrival);
            assert_eq!(
                (sample.linear_x, sample.angular_z),
                (0.3, 0.0),
                "pose {index}"
            );
        }
        assert_eq!(odometry.twist_source(), Some(TwistSource::MeasuredSpeed));
        assert_eq!(odometry.extensions(), (true, true));
    }

    #[test]
    fn a_reset_by_someone_else_makes_no_spike_with_or_without_the_measured_speed() {
        let start = Instant::now();
        let at = |ms: u32| start + Duration::from_millis(u64::from(ms));
        // With 0x0F0 the pose's jump does not touch the twist.
        let mut odometry = OdometrySide::default();
        cycle(&mut odometry, 1_000, FORWARD_300, (4_000, 0), at(0));
        let sample = cycle(&mut odometry, 1_050, FORWARD_300, (0, 0), at(50));
        assert_eq!(sample.linear_x, 0.3);
        // With 0x0EF alone the 4 m jump would read 80 m/s: the twist before it holds.
        let mut odometry = OdometrySide::default();
        for (index, x_mm) in [3_970, 3_985, 4_000, 0, 15].into_iter().enumerate() {
            let controller_ms = 1_000 + 50 * index as u32;
            odometry.on_pose_time(controller_ms);
            odometry.on_position(x_mm, 0);
            let sample = odometry.on_heading(at(controller_ms), 0).0.unwrap();
            if index > 0 {
                assert!((sample.linear_x - 0.3).abs() < 1e-9, "{index}: {sample:?}");
            }
        }
        assert_eq!(odometry.jumps(), 1);
    }

    #[test]
    fn a_measured_speed_beyond_the_limits_is_clamped_to_them() {
        let mut odometry = OdometrySide::new(SpeedLimits {
            linear_m_s: 1.0,
            angular_rad_s: 2.0,
        });
        let fast = WireSpeed {
            linear_mm_s: -1500,
            rotation_mrad_s: -2500,
            ..WireSpeed::default()
        };
        let sample = cycle(&mut odometry, 0, fast, (0, 0), Instant::now());
        assert_eq!((sample.linear_x, sample.angular_z), (-1.0, 2.0));
    }

    #[test]
    fn the_wheels_turn_by_their_measured_speed_over_the_pose_times() {
        let start = Instant::now();
        let mut odometry = OdometrySide::default();
        let turning = WireSpeed {
            left_wheel_crad_s: 250,
            right_wheel_crad_s: -100,
            ..WireSpeed::default()
        };
        let mut wheels = WheelJoints::default();
        for index in 0..=20u32 {
            let sample = cycle(&mut odometry, 500 + 50 * index, turning, (0, 0), start);
            wheels = sample.wheels.expect("a speed came with the pose");
        }
        // Twenty cycles of 50 ms: one second.
        assert!((wheels.position_rad[0] - 2.5).abs() < 1e-9, "{wheels:?}");
        assert!((wheels.position_rad[1] + 1.0).abs() < 1e-9, "{wheels:?}");
        assert_eq!(wheels.velocity_rad_s, [2.5, -1.0]);
        // Two seconds without a speed: nobody knows what the wheels did meanwhile.
        let later = cycle(&mut odometry, 3_500, turning, (0, 0), start);
        assert_eq!(later.wheels.unwrap().position_rad, wheels.position_rad);
        // A pose without its 0x0F0 has no joint states.
        odometry.on_pose_time(3_550);
        odometry.on_position(0, 0);
        assert_eq!(odometry.on_heading(start, 0).0.unwrap().wheels, None);
    }

    #[test]
    fn a_stamped_command_older_than_the_timeout_is_stale_an_unset_or_future_one_is_not() {
        let timeout = Duration::from_millis(500);
        let now = 1_800_000_000_000_000_000;
        assert!(stamp_is_stale(now - 501_000_000, now, timeout));
        assert!(!stamp_is_stale(now - 500_000_000, now, timeout));
        assert!(!stamp_is_stale(now - 20_000_000, now, timeout));
        assert!(!stamp_is_stale(now + 3_000_000_000, now, timeout));
        assert!(!stamp_is_stale(0, now, timeout));
        assert!(stamp_is_stale(i64::MIN + 1, now, timeout));
    }

    #[test]
    fn on_the_controllers_clock_the_twist_is_exact_through_late_sends_and_late_frames() {
        let mut odometry = knowing_the_cycle();
        let twists = late_sends_and_late_frames(&mut odometry, true);
        for twist in &twists[1..] {
            assert!((twist - 0.3).abs() < 1e-9, "{twists:?}");
        }
        assert_eq!(odometry.twist_source(), Some(TwistSource::ControllerClock));
    }

    #[test]
    fn without_the_controllers_clock_late_sends_and_late_frames_show_in_the_twist() {
        // A controller that predates 0x0EF: whole cycles of arrival times, as before.
        let mut odometry = knowing_the_cycle();
        let twists = late_sends_and_late_frames(&mut odometry, false);
        let worst = twists[1..]
            .iter()
            .map(|twist| (twist - 0.3).abs())
            .fold(0.0, f64::max);
        assert!(worst > 0.05, "{twists:?}");
        assert_eq!(odometry.twist_source(), Some(TwistSource::Arrival));
    }

    #[test]
    fn a_lost_pose_time_falls_back_to_the_cycle_and_a_reboot_gives_no_rate() {
        let start = Instant::now();
        let at = |ms: u64| start + Duration::from_millis(ms);
        let mut odometry = knowing_the_cycle();
        odometry.on_pose_time(1_000);
        odometry.on_position(0, 0);
        odometry.on_heading(at(0), 0);
        // The next 0x0EF is lost: the pose's time is the cycle nearest its arrival.
        odometry.on_position(15, 0);
        let twist = odometry.on_heading(at(52), 0).0.unwrap().linear_x;
        assert!((twist - 0.3).abs() < 1e-9, "{twist}");
        // A time from an earlier pose never dates a later one.
        odometry.on_pose_time(1_100);
        odometry.on_heading(at(99), 0);
        odometry.on_position(30, 0);
        let twist = odometry.on_heading(at(101), 0).0.unwrap().linear_x;
        assert!((twist - 0.3).abs() < 1e-9, "{twist}");
        // Time running backwards (the controller rebooted, its pose from zero): the
        // twist before it is held, no spike.
        odometry.on_pose_time(1_150);
        odometry.on_position(45, 0);
        odometry.on_heading(at(150), 0);
        odometry.on_pose_time(300);
        odometry.on_position(0, 0);
        let twist = odometry.on_heading(at(200), 0).0.unwrap().linear_x;
        assert!((twist - 0.3).abs() < 1e-9, "{twist}");
    }

    #[test]
    fn a_pose_sent_before_the_reset_took_effect_makes_no_velocity_spike() {
        let start = Instant::now();
        let ms = |ms: u64| start + Duration::from_millis(ms);
        let mut odometry = OdometrySide::default();
        let cycle_echo = |tag| ReadEcho {
            address: CYCLE_REGISTER,
            tag,
        };
        odometry.on_register_value(start, cycle_echo(0), 50);
        // Driving at 0.3 m/s, 2 m out.
        for (cycle, arrival) in [(0, 0), (1, 50), (2, 100)] {
            odometry.on_position(2000 + cycle * 15, 0);
            odometry.on_heading(ms(arrival as u64), 0);
        }
        assert_eq!(
            odometry.start_reset(ms(110), 7),
            [
                Command::ResetOdometry,
                Command::RegisterRead {
                    address: CYCLE_REGISTER,
                    tag: 7
                }
            ]
        );
        // A pose the controller sent before it handled the reset: not published.
        odometry.on_position(2045, 0);
        assert_eq!(odometry.on_heading(ms(150), 0), (None, None));
        // Another program's read of the same register is not our answer.
        odometry.on_register_value(ms(151), cycle_echo(8), 50);
        odometry.on_position(2060, 0);
        assert_eq!(odometry.on_heading(ms(152), 0), (None, None));
        odometry.on_register_value(ms(155), cycle_echo(7), 50);
        // After the answer: the pose from zero, moving as before.
        odometry.on_position(10, 0);
        let (sample, outcome) = odometry.on_heading(ms(200), 0);
        let sample = sample.unwrap();
        assert_eq!(outcome, Some(ResetOutcome::Shown));
        assert!((sample.pose.x - 0.010).abs() < 1e-9, "{sample:?}");
        assert!((sample.linear_x - 0.3).abs() < 1e-3, "{sample:?}");
        odometry.on_position(25, 0);
        let sample = odometry.on_heading(ms(250), 0).0.unwrap();
        assert!((sample.linear_x - 0.3).abs() < 1e-3, "{sample:?}");
    }

    #[test]
    fn a_reset_without_an_answer_or_without_poses_ends_and_says_so() {
        let start = Instant::now();
        let mut odometry = OdometrySide::default();
        odometry.start_reset(start, 1);
        assert_eq!(odometry.tick(start + Duration::from_millis(999)), None);
        assert_eq!(
            odometry.tick(start + RESET_ANSWER_TIMEOUT),
            Some(ResetOutcome::NoAnswer)
        );
        odometry.start_reset(start, 2);
        let echo = ReadEcho {
            address: CYCLE_REGISTER,
            tag: 2,
        };
        odometry.on_register_value(start, echo, 50);
        assert_eq!(odometry.tick(start + Duration::from_millis(150)), None);
        assert_eq!(
            odometry.tick(start + Duration::from_millis(200)),
            Some(ResetOutcome::NoPositionStream)
        );
    }
}
