//! The node: one thread owns the bus and the ROS 2 entities. Each turn of its loop
//! takes every waiting `/cmd_vel` and odometry reset, sends what is due, then waits
//! up to 1 ms for a frame from the base (so a new `/cmd_vel` waits at most that long
//! before it goes out). A second thread runs ros2-client's spinner, which answers the
//! parameter services.

use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use base_core::can::update::{UpdateCommand, UpdateReply, VersionAssembler};
use base_core::can::{Command, Mode, RawFrame, Rejection, Report, Status};
use base_core::registers::{BLE_OFF_AFTER_HOST_STOPS, BootInfo, Reg, UpdateReset};
use basectl::bus::{Bus, BusError};
use ros2_client::log::LogLevel;
use ros2_client::rosout::{NodeLoggingHandle, RosoutRaw};
use ros2_client::service::{Server, ServiceMapping};
use ros2_client::{
    Context, ContextOptions, Name, Node, NodeName, NodeOptions, ParameterValue, Publisher,
    QosProfile, RmwRequestId, ServiceTypeName, Subscription,
    qos::{Durability, History},
};

use crate::bridge::{
    CYCLE_REGISTER, CommandSide, Counts, OdometrySample, OdometrySide, ResetOutcome, SpeedLimits,
    WireSpeed, stamp_is_stale,
};
use crate::clock::ControllerClock;
use crate::msgs::{self, *};

/// How long the loop waits for a frame before it looks at DDS again.
const POLL: Duration = Duration::from_millis(1);
/// Without any frame from the base for this long, `/diagnostics` says it is stale.
const SILENCE: Duration = Duration::from_secs(3);
/// How often the base's feedback period (register `loop_end_delay`) is read again:
/// someone may change it while the node runs.
const CYCLE_READ_PERIOD: Duration = Duration::from_secs(5);

/// Everything the node is told by its command line.
#[derive(Debug, Clone)]
pub struct Settings {
    pub domain_id: u16,
    pub node_name: String,
    pub namespace: String,
    pub cmd_vel_timeout: Duration,
    pub command_period: Duration,
    pub stamped: bool,
    pub odom_frame: String,
    pub base_frame: String,
    pub publish_tf: bool,
    pub speed_limits: SpeedLimits,
    /// The names of the left and right wheel joints in `/joint_states`.
    pub wheel_joints: [String; 2],
    pub pose_covariance: [f64; 6],
    pub twist_covariance: [f64; 6],
    /// 0 = no heartbeat.
    pub heartbeat_period: Duration,
    pub hardware_id: String,
    /// Every setting as a ROS parameter (name, value), for the parameter services.
    pub parameters: Vec<(String, ParameterValue)>,
}

#[derive(Debug)]
pub enum Error {
    Ros(String),
    Bus(BusError),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Ros(what) => write!(f, "ROS 2: {what}"),
            Error::Bus(error) => write!(f, "CAN bus: {error}"),
        }
    }
}

impl std::error::Error for Error {}

impl From<BusError> for Error {
    fn from(error: BusError) -> Self {
        Error::Bus(error)
    }
}

fn ros<E: fmt::Debug>(what: &str) -> impl FnOnce(E) -> Error + '_ {
    move |error| Error::Ros(format!("{what}: {error:?}"))
}

enum CmdVel {
    Plain(Subscription<Twist>),
    Stamped(Subscription<TwistStamped>),
}

impl CmdVel {
    /// The next waiting command, with its stamp if it is a TwistStamped; `Err` for
    /// one that could not be decoded.
    fn take(&self) -> Option<Result<(Twist, Option<Time>), String>> {
        match self {
            CmdVel::Plain(subscription) => match subscription.take() {
                Ok(Some((twist, _))) => Some(Ok((twist, None))),
                Ok(None) => None,
                Err(error) => Some(Err(format!("{error:?}"))),
            },
            CmdVel::Stamped(subscription) => match subscription.take() {
                Ok(Some((stamped, _))) => Some(Ok((stamped.twist, Some(stamped.header.stamp)))),
                Ok(None) => None,
                Err(error) => Some(Err(format!("{error:?}"))),
            },
        }
    }
}

struct Ros {
    node: Node,
    logger: NodeLoggingHandle,
    cmd_vel: CmdVel,
    reset_service: Server<TriggerRequest, TriggerResponse>,
    odom: Publisher<Odometry>,
    joint_states: Publisher<JointState>,
    tf: Option<Publisher<TfMessage>>,
    battery: Publisher<BatteryState>,
    diagnostics: Publisher<DiagnosticArray>,
}

fn name(namespace: &str, topic: &str) -> Result<Name, Error> {
    Name::new(namespace, topic).map_err(ros("topic name"))
}

impl Ros {
    fn open(settings: &Settings) -> Result<Self, Error> {
        let context = Context::with_options(ContextOptions::new().domain_id(settings.domain_id))
            .map_err(ros("DDS participant"))?;
        // The parameters are read-only once the node runs: every setting is taken at
        // start (command line, --ros-args -p, --params-file). Their declaration passes
        // the validator too.
        let running = Arc::new(AtomicBool::new(false));
        let declared = Arc::clone(&running);
        let mut options = NodeOptions::new()
            .enable_rosout(true)
            .start_parameter_services(true)
            .parameter_validator(Box::new(move |name, _| {
                if !declared.load(Ordering::Relaxed) {
                    return Ok(());
                }
                Err(format!(
                    "{name} is read-only while base-ros2 runs: restart it with \
                     --ros-args -p {name}:=VALUE"
                ))
            }));
        for (name, value) in &settings.parameters {
            options = options.declare_parameter(name, value.clone());
        }
        let mut node = context
            .new_node(
                NodeName::new(&settings.namespace, &settings.node_name)
                    .map_err(ros("node name"))?,
                options,
            )
            .map_err(ros("node"))?;
        running.store(true, Ordering::Relaxed);
        let ns = &settings.namespace;
        // ROS 2's default: reliable, volatile, the last 10.
        let reliable = QosProfile::publisher_default()
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 10 });
        // A best-effort reader matches reliable and best-effort writers alike: any
        // teleop node's /cmd_vel is taken.
        let command_qos = QosProfile::subscription_default()
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 10 });

        let cmd_vel = if settings.stamped {
            let topic = node
                .create_topic(
                    &name(ns, "cmd_vel")?,
                    msgs::type_name("geometry_msgs", "TwistStamped"),
                    &command_qos,
                )
                .map_err(ros("/cmd_vel"))?;
            CmdVel::Stamped(
                node.create_subscription(&topic, None)
                    .map_err(ros("/cmd_vel"))?,
            )
        } else {
            let topic = node
                .create_topic(
                    &name(ns, "cmd_vel")?,
                    msgs::type_name("geometry_msgs", "Twist"),
                    &command_qos,
                )
                .map_err(ros("/cmd_vel"))?;
            CmdVel::Plain(
                node.create_subscription(&topic, None)
                    .map_err(ros("/cmd_vel"))?,
            )
        };
        // ROS 2's service default: reliable, volatile, the last 10.
        let reset_service = node
            .create_server(
                ServiceMapping::Enhanced,
                &name(ns, "reset_odometry")?,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                reliable.clone(),
                reliable.clone(),
            )
            .map_err(ros("reset_odometry service"))?;
        let topic = node
            .create_topic(
                &name(ns, "odom")?,
                msgs::type_name("nav_msgs", "Odometry"),
                &reliable,
            )
            .map_err(ros("/odom"))?;
        let odom = node.create_publisher(&topic, None).map_err(ros("/odom"))?;
        let topic = node
            .create_topic(
                &name(ns, "joint_states")?,
                msgs::type_name("sensor_msgs", "JointState"),
                &reliable,
            )
            .map_err(ros("/joint_states"))?;
        let joint_states = node
            .create_publisher(&topic, None)
            .map_err(ros("/joint_states"))?;
        let tf = if settings.publish_tf {
            // /tf is always the absolute topic: tf2 listens there.
            let tf_qos = reliable.clone().history(History::KeepLast { depth: 100 });
            let topic = node
                .create_topic(
                    &name("/", "tf")?,
                    msgs::type_name("tf2_msgs", "TFMessage"),
                    &tf_qos,
                )
                .map_err(ros("/tf"))?;
            Some(node.create_publisher(&topic, None).map_err(ros("/tf"))?)
        } else {
            None
        };
        let topic = node
            .create_topic(
                &name(ns, "battery_state")?,
                msgs::type_name("sensor_msgs", "BatteryState"),
                &reliable,
            )
            .map_err(ros("/battery_state"))?;
        let battery = node
            .create_publisher(&topic, None)
            .map_err(ros("/battery_state"))?;
        let topic = node
            .create_topic(
                &name("/", "diagnostics")?,
                msgs::type_name("diagnostic_msgs", "DiagnosticArray"),
                &reliable,
            )
            .map_err(ros("/diagnostics"))?;
        let diagnostics = node
            .create_publisher(&topic, None)
            .map_err(ros("/diagnostics"))?;
        let logger = node.logging_handle();
        Ok(Ros {
            node,
            logger,
            cmd_vel,
            reset_service,
            odom,
            joint_states,
            tf,
            battery,
            diagnostics,
        })
    }
}

impl Ros {
    /// A line on stderr and the same on `/rosout`.
    fn log(&self, level: LogLevel, message: &str) {
        eprintln!("base-ros2: {message}");
        self.logger.rosout_raw(
            Time::now(),
            level,
            self.logger.base_name(),
            message,
            file!(),
            "",
            line!(),
        );
    }
}

fn header(frame_id: &str) -> Header {
    Header {
        stamp: Time::now(),
        frame_id: frame_id.to_owned(),
    }
}

/// Runs the node until `stop` is set (Ctrl-C, SIGTERM) or the bus fails. Before it
/// returns, a driving base is stopped (zero velocity, enable withdrawn).
pub fn run(settings: &Settings, bus: &mut dyn Bus, stop: &Arc<AtomicBool>) -> Result<(), Error> {
    let mut ros = Ros::open(settings)?;
    let spinner = ros
        .node
        .spinner()
        .map_err(|error| Error::Ros(format!("spinner: {error:?}")))?;
    // The spinner answers the parameter services; it ends when the node is dropped.
    let spinning = std::thread::spawn(move || futures::executor::block_on(spinner.spin()));
    ros.log(
        LogLevel::Info,
        &format!(
            "node {}/{} on ROS_DOMAIN_ID {}; /cmd_vel time-out {} ms",
            settings.namespace.trim_end_matches('/'),
            settings.node_name,
            settings.domain_id,
            settings.cmd_vel_timeout.as_millis()
        ),
    );
    let mut state = State::new(settings);
    let result = state.run(&ros, bus, stop);
    // Whatever ended the loop: the base must not keep driving on our last command.
    let frames = state.commands.stop();
    let stopped = send_all(bus, &frames);
    leave_the_graph(ros, &spinning);
    result.and(stopped)
}

/// How long leaving the graph may take before the process ends anyway.
const LEAVE_TIMEOUT: Duration = Duration::from_secs(3);

/// Drops the node, then waits for the spinner's thread: it holds the last handle on
/// the DDS participant, whose drop announces the departure (the node list without us,
/// then the participant's dispose) and joins the threads that send it. Ending the
/// process before that loses the announcement whenever those threads have not run
/// yet (a busy machine), and the others then see the node for the whole lease.
fn leave_the_graph<T>(ros: Ros, spinning: &std::thread::JoinHandle<T>) {
    drop(ros);
    let deadline = Instant::now() + LEAVE_TIMEOUT;
    while !spinning.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn send_all(bus: &mut dyn Bus, commands: &[Command]) -> Result<(), Error> {
    for command in commands {
        bus.send(&command.encode())?;
    }
    Ok(())
}

struct State<'a> {
    settings: &'a Settings,
    commands: CommandSide,
    odometry: OdometrySide,
    /// Maps the poses' times (0x0EF) onto ROS time for the stamps.
    clock: ControllerClock,
    /// When the pose time of the pose under way arrived, ROS time in ns.
    pose_time_arrival_ns: Option<i64>,
    /// The last pose's time, for the poses missed in between.
    last_pose_ms: Option<u32>,
    /// Poses that arrived more than a cycle after their moment.
    late_poses: u64,
    /// Poses that never came: gaps of whole cycles between pose times.
    missed_poses: u64,
    last_status: Option<Status>,
    last_frame: Instant,
    next_heartbeat: Instant,
    next_silence_report: Instant,
    malformed_cmd_vel: u64,
    /// TwistStamped commands older than the timeout, dropped.
    stale_cmd_vel: u64,
    malformed_frames: u64,
    /// The tag of the node's last register read (the reply echoes it).
    last_tag: u16,
    next_cycle_read: Instant,
    /// How the base controller's current boot came about (register `boot_info`), read
    /// with the cycle: `None` until it answers, or from firmware without it.
    boot_info: Option<BootInfo>,
    /// Register `bluetooth_off`, read with the cycle: `None` until it answers.
    bluetooth_off: Option<u16>,
    /// The running image's whole version, asked with the cycle (the update's QUERY).
    image: ImageVersion,
    /// Reset service calls waiting for the reset to show in the poses.
    reset_callers: Vec<RmwRequestId>,
}

impl<'a> State<'a> {
    fn new(settings: &'a Settings) -> Self {
        let now = Instant::now();
        State {
            settings,
            commands: CommandSide::new(settings.cmd_vel_timeout, settings.command_period),
            odometry: OdometrySide::new(settings.speed_limits),
            clock: ControllerClock::default(),
            pose_time_arrival_ns: None,
            last_pose_ms: None,
            late_poses: 0,
            missed_poses: 0,
            last_status: None,
            last_frame: now,
            next_heartbeat: now,
            next_silence_report: now + SILENCE,
            malformed_cmd_vel: 0,
            stale_cmd_vel: 0,
            malformed_frames: 0,
            last_tag: 0,
            next_cycle_read: now,
            boot_info: None,
            bluetooth_off: None,
            image: ImageVersion::default(),
            reset_callers: Vec::new(),
        }
    }

    /// A tag for the node's next register read, never 0 (the manual's untagged read).
    fn next_tag(&mut self) -> u16 {
        self.last_tag = self.last_tag.wrapping_add(1).max(1);
        self.last_tag
    }

    fn start_reset(&mut self, ros: &Ros, bus: &mut dyn Bus, now: Instant) -> Result<(), Error> {
        let tag = self.next_tag();
        send_all(bus, &self.odometry.start_reset(now, tag))?;
        ros.log(LogLevel::Info, "odometry reset requested");
        Ok(())
    }

    /// Answers every waiting reset call.
    fn reset_ended(&mut self, ros: &Ros, outcome: ResetOutcome) {
        let (success, message) = match outcome {
            ResetOutcome::Shown => (true, "odometry reset; /odom now starts from zero"),
            ResetOutcome::NoPositionStream => (
                true,
                "odometry reset; the base sends no position in its current mode (emergency?)",
            ),
            ResetOutcome::NoAnswer => (
                false,
                "the base controller did not answer within 1 s: whether it reset is unknown",
            ),
        };
        let level = if success {
            LogLevel::Info
        } else {
            LogLevel::Warn
        };
        ros.log(level, message);
        for caller in self.reset_callers.drain(..) {
            let response = TriggerResponse {
                success,
                message: message.to_owned(),
            };
            if let Err(error) = ros.reset_service.send_response(caller, response) {
                ros.log(
                    LogLevel::Warn,
                    &format!("reset_odometry: the answer was not sent: {error:?}"),
                );
            }
        }
    }

    fn run(&mut self, ros: &Ros, bus: &mut dyn Bus, stop: &AtomicBool) -> Result<(), Error> {
        while !stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            while let Some(taken) = ros.cmd_vel.take() {
                match taken {
                    Ok((_, Some(stamp)))
                        if stamp_is_stale(
                            stamp.to_nanos(),
                            Time::now().to_nanos(),
                            self.settings.cmd_vel_timeout,
                        ) =>
                    {
                        self.stale_cmd_vel += 1;
                        // The first, then every 100th: a publisher whose clock is
                        // behind sends nothing but these.
                        if self.stale_cmd_vel % 100 == 1 {
                            ros.log(
                                LogLevel::Warn,
                                &format!(
                                    "a /cmd_vel stamped {:.3} s ago dropped: older than \
                                     cmd_vel_timeout ({} so far; is the publisher's clock \
                                     behind?)",
                                    (Time::now().to_nanos() - stamp.to_nanos()) as f64 / 1e9,
                                    self.stale_cmd_vel
                                ),
                            );
                        }
                    }
                    Ok((twist, _)) => {
                        match self
                            .commands
                            .on_cmd_vel(now, twist.linear.x, twist.angular.z)
                        {
                            Ok(frames) => send_all(bus, &frames)?,
                            Err(_) => ros.log(
                                LogLevel::Warn,
                                &format!(
                                    "/cmd_vel refused: linear.x {} angular.z {} is not finite \
                                     ({} so far)",
                                    twist.linear.x,
                                    twist.angular.z,
                                    self.commands.counts.not_finite
                                ),
                            ),
                        }
                    }
                    Err(error) => {
                        self.malformed_cmd_vel += 1;
                        ros.log(
                            LogLevel::Warn,
                            &format!(
                                "a /cmd_vel could not be decoded ({} so far): {error}",
                                self.malformed_cmd_vel
                            ),
                        );
                    }
                }
            }
            while let Ok(Some((caller, _))) = ros.reset_service.receive_request() {
                self.reset_callers.push(caller);
                self.start_reset(ros, bus, now)?;
            }
            if let Some(outcome) = self.odometry.tick(now) {
                self.reset_ended(ros, outcome);
            }
            if now >= self.next_cycle_read {
                let tag = self.next_tag();
                let read = Command::RegisterRead {
                    address: CYCLE_REGISTER,
                    tag,
                };
                bus.send(&read.encode())?;
                // A reboot of the base changes it: read it as often as the cycle.
                let boot_info = Command::RegisterRead {
                    address: Reg::BootInfo.address(),
                    tag: self.next_tag(),
                };
                bus.send(&boot_info.encode())?;
                let bluetooth_off = Command::RegisterRead {
                    address: Reg::BluetoothOff.address(),
                    tag: self.next_tag(),
                };
                bus.send(&bluetooth_off.encode())?;
                // Seven replies, once a cycle: the image after an update shows.
                bus.send(&UpdateCommand::Query.encode())?;
                self.next_cycle_read = now + CYCLE_READ_PERIOD;
            }
            let timeouts = self.commands.counts.timeouts;
            send_all(bus, &self.commands.tick(now))?;
            if self.commands.counts.timeouts != timeouts {
                ros.log(
                    LogLevel::Warn,
                    &format!(
                        "/cmd_vel older than {} ms: base stopped",
                        self.settings.cmd_vel_timeout.as_millis()
                    ),
                );
            }
            if !self.settings.heartbeat_period.is_zero() && now >= self.next_heartbeat {
                bus.send(&Command::Heartbeat.encode())?;
                self.next_heartbeat = now + self.settings.heartbeat_period;
            }
            if now >= self.next_silence_report && now - self.last_frame >= SILENCE {
                self.publish_silence(ros, now - self.last_frame);
                self.next_silence_report = now + Duration::from_secs(1);
            }
            if let Some(frame) = bus.receive(POLL)? {
                self.on_frame(ros, &frame);
            }
        }
        Ok(())
    }

    fn on_frame(&mut self, ros: &Ros, frame: &RawFrame) {
        let now = Instant::now();
        if let Ok(Some(reply)) = UpdateReply::decode(frame.id(), frame.data()) {
            self.image.on_reply(&reply);
            self.last_frame = now;
            self.next_silence_report = now + SILENCE;
            return;
        }
        let report = match Report::decode(frame.id(), frame.data()) {
            Ok(Some(report)) => report,
            Ok(None) => return,
            Err(error) => {
                self.malformed_frames += 1;
                ros.log(
                    LogLevel::Warn,
                    &format!(
                        "frame 0x{:03X} ignored: {error} ({} so far)",
                        frame.id(),
                        self.malformed_frames
                    ),
                );
                return;
            }
        };
        self.last_frame = now;
        self.next_silence_report = now + SILENCE;
        match report {
            Report::PoseTime { controller_ms } => {
                self.pose_time_arrival_ns = Some(Time::now().to_nanos());
                self.odometry.on_pose_time(controller_ms);
            }
            Report::MeasuredSpeed {
                linear_mm_s,
                rotation_mrad_s,
                left_wheel_crad_s,
                right_wheel_crad_s,
            } => self.odometry.on_measured_speed(WireSpeed {
                linear_mm_s,
                rotation_mrad_s,
                left_wheel_crad_s,
                right_wheel_crad_s,
            }),
            Report::Position { x_mm, y_mm } => self.odometry.on_position(x_mm, y_mm),
            Report::Heading { heading_mrad } => {
                let (sample, reset) = self.odometry.on_heading(now, heading_mrad);
                let arrival_ns = self.pose_time_arrival_ns.take();
                if let Some(sample) = sample {
                    let stamp = self.stamp(sample.controller_ms, arrival_ns);
                    self.publish_odometry(ros, &sample, stamp);
                }
                if let Some(outcome) = reset {
                    self.reset_ended(ros, outcome);
                }
            }
            Report::RegisterValue {
                value,
                echo: Some(echo),
            } => {
                if echo.address == Reg::BootInfo.address() {
                    self.boot_info = BootInfo::from_bits(value);
                }
                if echo.address == Reg::BluetoothOff.address() {
                    self.bluetooth_off = Some(value);
                }
                self.odometry.on_register_value(now, echo, value)
            }
            Report::Battery {
                percent,
                voltage_mv,
            } => self.publish_battery(ros, percent, voltage_mv),
            Report::Status(status) => {
                if self.last_status.map(|last| last.mode) != Some(status.mode) {
                    ros.log(
                        LogLevel::Info,
                        &format!("base controller mode {:?}", status.mode),
                    );
                }
                self.last_status = Some(status);
                self.publish_status(ros, &status);
            }
            Report::Weight { .. }
            | Report::RegisterValue { .. }
            | Report::RegisterReadError { .. } => {}
        }
    }

    /// The ROS time of a pose: its moment on the controller's clock mapped by the
    /// clock estimate, or its arrival from a controller without pose times.
    fn stamp(&mut self, controller_ms: Option<u32>, arrival_ns: Option<i64>) -> Time {
        let (Some(controller_ms), Some(arrival_ns)) = (controller_ms, arrival_ns) else {
            return Time::now();
        };
        let mapped = self.clock.map(controller_ms, arrival_ns);
        let cycle_ms = self.odometry.cycle().map(|cycle| cycle.as_millis() as u32);
        if let Some(cycle_ms) = cycle_ms.filter(|&cycle| cycle > 0) {
            if mapped.delay_ns > i64::from(cycle_ms) * 1_000_000 {
                self.late_poses += 1;
            }
            // A gap of whole cycles beyond the first, up to a minute (longer is a pause
            // of the controller's poses: an emergency, a reboot).
            if let Some(last) = self.last_pose_ms {
                let gap = controller_ms.wrapping_sub(last);
                if gap < 60_000 {
                    let cycles = (gap + cycle_ms / 2) / cycle_ms;
                    self.missed_poses += u64::from(cycles.saturating_sub(1));
                }
            }
        }
        self.last_pose_ms = Some(controller_ms);
        Time::from_nanos(mapped.stamp_ns)
    }

    fn publish_odometry(&self, ros: &Ros, sample: &OdometrySample, stamp: Time) {
        let settings = self.settings;
        let orientation = Quaternion::from_yaw(sample.pose.yaw);
        let header = Header {
            stamp,
            frame_id: settings.odom_frame.clone(),
        };
        if let Some(wheels) = sample.wheels {
            let joints = JointState {
                header: Header {
                    stamp,
                    frame_id: settings.base_frame.clone(),
                },
                name: settings.wheel_joints.to_vec(),
                position: wheels.position_rad.to_vec(),
                velocity: wheels.velocity_rad_s.to_vec(),
                effort: Vec::new(),
            };
            if let Err(error) = ros.joint_states.publish(joints) {
                eprintln!("base-ros2: /joint_states not published: {error:?}");
            }
        }
        let odometry = Odometry {
            header: header.clone(),
            child_frame_id: settings.base_frame.clone(),
            pose: PoseWithCovariance {
                pose: Pose {
                    position: Point {
                        x: sample.pose.x,
                        y: sample.pose.y,
                        z: 0.0,
                    },
                    orientation,
                },
                covariance: Covariance::diagonal(settings.pose_covariance),
            },
            twist: TwistWithCovariance {
                twist: Twist {
                    linear: Vector3 {
                        x: sample.linear_x,
                        y: 0.0,
                        z: 0.0,
                    },
                    angular: Vector3 {
                        x: 0.0,
                        y: 0.0,
                        z: sample.angular_z,
                    },
                },
                covariance: Covariance::diagonal(settings.twist_covariance),
            },
        };
        if let Err(error) = ros.odom.publish(odometry) {
            eprintln!("base-ros2: /odom not published: {error:?}");
        }
        if let Some(tf) = &ros.tf {
            let transform = TransformStamped {
                header,
                child_frame_id: settings.base_frame.clone(),
                transform: Transform {
                    translation: Vector3 {
                        x: sample.pose.x,
                        y: sample.pose.y,
                        z: 0.0,
                    },
                    rotation: orientation,
                },
            };
            if let Err(error) = tf.publish(TfMessage {
                transforms: vec![transform],
            }) {
                eprintln!("base-ros2: /tf not published: {error:?}");
            }
        }
    }

    fn publish_battery(&self, ros: &Ros, percent: u8, voltage_mv: u16) {
        let battery = BatteryState {
            header: header(&self.settings.base_frame),
            voltage: f32::from(voltage_mv) / 1000.0,
            temperature: f32::NAN,
            current: f32::NAN,
            charge: f32::NAN,
            capacity: f32::NAN,
            design_capacity: f32::NAN,
            percentage: f32::from(percent) / 100.0,
            // UNKNOWN: the base does not report charging or health.
            power_supply_status: 0,
            power_supply_health: 0,
            power_supply_technology: 0,
            present: true,
            cell_voltage: Vec::new(),
            cell_temperature: Vec::new(),
            location: String::new(),
            serial_number: String::new(),
        };
        if let Err(error) = ros.battery.publish(battery) {
            eprintln!("base-ros2: /battery_state not published: {error:?}");
        }
    }

    fn publish_status(&self, ros: &Ros, status: &Status) {
        let mut diagnostic = diagnose(status, &self.settings.hardware_id, self.counts());
        add_boot_info(&mut diagnostic, self.boot_info);
        diagnostic.values.push(KeyValue {
            key: "firmware_image".to_owned(),
            value: self.image.version().unwrap_or("unknown").to_owned(),
        });
        add_update_trust(&mut diagnostic, self.image.trust);
        add_bluetooth_state(&mut diagnostic, self.bluetooth_off);
        self.add_odometry_figures(&mut diagnostic);
        self.publish_diagnostic(ros, diagnostic);
    }

    /// Where the twist and the stamps come from, and how the frames arrive: a
    /// controller that predates the extensions leaves only the frames' arrival times.
    fn add_odometry_figures(&self, diagnostic: &mut DiagnosticStatus) {
        let mut push = |key: &str, value: String| {
            diagnostic.values.push(KeyValue {
                key: key.to_owned(),
                value,
            })
        };
        let extensions: Vec<&str> = match self.odometry.extensions() {
            (true, true) => vec!["pose_time", "measured_speed"],
            (true, false) => vec!["pose_time"],
            (false, true) => vec!["measured_speed"],
            (false, false) => vec![],
        };
        push("odometry_extensions", extensions.join(","));
        if let Some(source) = self.odometry.twist_source() {
            push("twist_source", source.name().to_owned());
        }
        push("twist_jumps_held", self.odometry.jumps().to_string());
        match self.clock.figures() {
            Some(figures) => {
                push("stamp_clock", "controller".to_owned());
                push("clock_offset_s", format!("{:.6}", figures.offset_s));
                push("pose_delay_p50_ms", format!("{:.2}", figures.delay_p50_ms));
                push("pose_delay_max_ms", format!("{:.2}", figures.delay_max_ms));
                push("controller_reboots_seen", figures.reboots.to_string());
            }
            None => push("stamp_clock", "arrival".to_owned()),
        }
        push("poses_late", self.late_poses.to_string());
        push("poses_missed", self.missed_poses.to_string());
    }

    fn publish_silence(&self, ros: &Ros, silent: Duration) {
        let diagnostic = DiagnosticStatus {
            level: DIAGNOSTIC_STALE,
            name: DIAGNOSTIC_NAME.into(),
            message: format!(
                "no frame from the base controller for {:.0} s",
                silent.as_secs_f64()
            ),
            hardware_id: self.settings.hardware_id.clone(),
            values: Vec::new(),
        };
        self.publish_diagnostic(ros, diagnostic);
    }

    fn publish_diagnostic(&self, ros: &Ros, diagnostic: DiagnosticStatus) {
        let array = DiagnosticArray {
            header: header(""),
            status: vec![diagnostic],
        };
        if let Err(error) = ros.diagnostics.publish(array) {
            eprintln!("base-ros2: /diagnostics not published: {error:?}");
        }
    }

    fn counts(&self) -> BridgeCounts {
        BridgeCounts {
            commands: self.commands.counts,
            malformed_cmd_vel: self.malformed_cmd_vel,
            stale_cmd_vel: self.stale_cmd_vel,
            malformed_frames: self.malformed_frames,
        }
    }
}

const DIAGNOSTIC_NAME: &str = "base_controller";
const DIAGNOSTIC_STALE: u8 = 3;

/// The bridge's own counters, shown next to the base's status.
#[derive(Debug, Clone, Copy, Default)]
pub struct BridgeCounts {
    pub commands: Counts,
    pub malformed_cmd_vel: u64,
    pub stale_cmd_vel: u64,
    pub malformed_frames: u64,
}

/// The running image's version from the update's replies: every STATE is followed by
/// the version in parts, whoever asked (docs/protocol.md, "Firmware update").
#[derive(Debug, Default)]
struct ImageVersion {
    parts: VersionAssembler,
    /// The last whole version: it stays until a whole one replaces it.
    version: Option<String>,
    /// From the last STATE: whether updates must be signed, and the running security
    /// version.
    trust: Option<UpdateTrust>,
}

/// What the last STATE said about the update's signatures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UpdateTrust {
    pub signatures_required: bool,
    pub security_version: u8,
}

impl ImageVersion {
    fn on_reply(&mut self, reply: &UpdateReply) {
        match reply {
            UpdateReply::State {
                signatures_required,
                security_version,
                ..
            } => {
                self.parts.restart();
                self.trust = Some(UpdateTrust {
                    signatures_required: *signatures_required,
                    security_version: *security_version,
                });
            }
            UpdateReply::Version { part, text } => {
                if let Some(whole) = self.parts.add(*part, text) {
                    self.version = Some(String::from_utf8_lossy(whole).into_owned());
                }
            }
            _ => {}
        }
    }

    /// The version, once all its parts came.
    fn version(&self) -> Option<&str> {
        self.version.as_deref()
    }
}

/// Adds how the base controller's boot came about (register `boot_info`): a
/// `first_boot` value, and on a first boot, an update's reset or a rollback a note in
/// the message. None of them changes the level: a first boot is no fault.
pub fn add_boot_info(diagnostic: &mut DiagnosticStatus, boot_info: Option<BootInfo>) {
    let first_boot = match boot_info {
        Some(info) if info.first_boot => "yes",
        Some(_) => "no",
        None => "unknown",
    };
    diagnostic.values.push(KeyValue {
        key: "first_boot".to_owned(),
        value: first_boot.to_owned(),
    });
    let Some(info) = boot_info else {
        return;
    };
    if info.first_boot {
        diagnostic
            .message
            .push_str("; first boot: register defaults written");
    }
    match info.update_reset {
        UpdateReset::None => {}
        UpdateReset::Activation => diagnostic.message.push_str("; started by an update"),
        UpdateReset::FailedTrial => diagnostic
            .message
            .push_str("; rolled back: a new image failed its trial"),
        UpdateReset::Refused => diagnostic
            .message
            .push_str("; update refused: the bootloader did not load the new image"),
        UpdateReset::Held => {
            // Nobody confirmed the image that runs: the base stays locked until a
            // person keeps it or tries the other slot.
            diagnostic.level = diagnostic.level.max(DIAGNOSTIC_WARN);
            diagnostic.message.push_str(
                "; held: unconfirmed image, no rollback possible, motion locked until basectl firmware confirm or rollback",
            )
        }
    }
}

/// Whether the controller activates only signed images: a development build, which
/// takes any image over CAN, is a warning (docs/flashing.md, "Signed images").
/// `None` (no STATE heard yet) says nothing.
pub fn add_update_trust(diagnostic: &mut DiagnosticStatus, trust: Option<UpdateTrust>) {
    let Some(trust) = trust else {
        return;
    };
    let signatures = if trust.signatures_required {
        "required"
    } else {
        diagnostic.level = diagnostic.level.max(DIAGNOSTIC_WARN);
        diagnostic
            .message
            .push_str("; development build: updates over CAN accept unsigned images");
        "not required (development build)"
    };
    diagnostic.values.push(KeyValue {
        key: "update_signatures".to_owned(),
        value: signatures.to_owned(),
    });
    diagnostic.values.push(KeyValue {
        key: "security_version".to_owned(),
        value: trust.security_version.to_string(),
    });
}

/// Register `bluetooth_off` (36): a remote that is off is a warning, with the way to
/// turn it on; `None` (not read yet, or a firmware without it) says nothing.
pub fn add_bluetooth_state(diagnostic: &mut DiagnosticStatus, bluetooth_off: Option<u16>) {
    let Some(state) = bluetooth_off else {
        return;
    };
    let (value, message) = match state {
        0 => ("on", None),
        BLE_OFF_AFTER_HOST_STOPS => (
            "ble_off_after_host_stops",
            Some("; BLE remote off: its host stopped 3 times within a minute"),
        ),
        // BLUETOOTH_OFF_AFTER_PANICS, and anything a later firmware may add.
        _ => (
            "off_after_panics",
            Some("; Bluetooth remote off after a panic loop"),
        ),
    };
    diagnostic.values.push(KeyValue {
        key: "bluetooth".to_owned(),
        value: value.to_owned(),
    });
    if let Some(message) = message {
        diagnostic.level = diagnostic.level.max(DIAGNOSTIC_WARN);
        diagnostic.message.push_str(message);
        diagnostic
            .message
            .push_str(" (a confirm press or command 0xB1E1 turns it on)");
    }
}

/// The status frame as one diagnostic: ERROR in an emergency, a fault mode or with a
/// drive or CAN fault latched; WARN with another fault latched (flash, scale,
/// watchdog reset) or while starting, awaiting the confirm press or recovering; OK
/// otherwise. Every field is a key/value, the last rejection by name.
pub fn diagnose(status: &Status, hardware_id: &str, counts: BridgeCounts) -> DiagnosticStatus {
    let flags = status.flags;
    let faults = status.faults;
    let fault_names: Vec<&str> = [
        (faults.left_drive_silent, "left_drive_silent"),
        (faults.left_drive_alarm, "left_drive_alarm"),
        (faults.right_drive_silent, "right_drive_silent"),
        (faults.right_drive_alarm, "right_drive_alarm"),
        (faults.flash, "flash"),
        (faults.scale, "scale"),
        (faults.can_bus, "can_bus"),
        (faults.watchdog_reset, "watchdog_reset"),
    ]
    .into_iter()
    .filter_map(|(set, name)| set.then_some(name))
    .collect();
    // A drive or the CAN bus failing stops the base or loses frames; defaults loaded
    // from a corrupt store, a missing scale or a watchdog reset leave it able to drive.
    let grave_fault = faults.left_drive_silent
        || faults.left_drive_alarm
        || faults.right_drive_silent
        || faults.right_drive_alarm
        || faults.can_bus;
    let level = match status.mode {
        Mode::Emergency | Mode::Fault => DIAGNOSTIC_ERROR,
        _ if grave_fault => DIAGNOSTIC_ERROR,
        _ if faults.any() => DIAGNOSTIC_WARN,
        Mode::Starting | Mode::AwaitingConfirm | Mode::Recovering => DIAGNOSTIC_WARN,
        Mode::Standby | Mode::Active => DIAGNOSTIC_OK,
    };
    let mut message = format!("{:?}", status.mode);
    if flags.estop_pressed {
        message.push_str(": e-stop pressed");
    }
    if !fault_names.is_empty() {
        message.push_str(&format!("; faults: {}", fault_names.join(", ")));
    }
    if flags.remote_in_control {
        message.push_str("; the gamepad is in control");
    }
    let last_rejection = match status.last_rejection {
        0 => "none".to_owned(),
        code => Rejection::from_code(code)
            .map(|reason| reason.name().to_owned())
            .unwrap_or_else(|| format!("unknown code 0x{code:02X}")),
    };
    let yes_no = |value: bool| if value { "yes" } else { "no" }.to_owned();
    let value = |key: &str, value: String| KeyValue {
        key: key.to_owned(),
        value,
    };
    DiagnosticStatus {
        level,
        name: DIAGNOSTIC_NAME.into(),
        message,
        hardware_id: hardware_id.to_owned(),
        values: vec![
            value("mode", format!("{:?}", status.mode)),
            value("control", format!("{:?}", status.control)),
            value("estop_pressed", yes_no(flags.estop_pressed)),
            value("enable_fresh", yes_no(flags.enable_fresh)),
            value("pc_on", yes_no(flags.pc_on)),
            value("safety_zone", yes_no(flags.safety_zone)),
            value("remote_bonded", yes_no(flags.remote_bonded)),
            value("remote_connected", yes_no(flags.remote_connected)),
            value("remote_in_control", yes_no(flags.remote_in_control)),
            value("brakes_applied", yes_no(flags.brakes_applied)),
            value(
                "faults",
                if fault_names.is_empty() {
                    "none".into()
                } else {
                    fault_names.join(", ")
                },
            ),
            value("rejected_count", status.rejected_count.to_string()),
            value("last_rejection", last_rejection),
            value(
                "last_rejection_subject",
                format!("0x{:02X}", status.last_rejection_subject),
            ),
            value("drive_alarm", format!("0x{:02X}", status.drive_alarm)),
            value("modbus_errors", status.modbus_errors.to_string()),
            value("cmd_vel_taken", counts.commands.commands.to_string()),
            value("cmd_vel_not_finite", counts.commands.not_finite.to_string()),
            value("cmd_vel_clamped", counts.commands.clamped.to_string()),
            value("cmd_vel_timeouts", counts.commands.timeouts.to_string()),
            value("cmd_vel_undecodable", counts.malformed_cmd_vel.to_string()),
            value("cmd_vel_stale", counts.stale_cmd_vel.to_string()),
            value("frames_malformed", counts.malformed_frames.to_string()),
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use base_core::can::update::{VERSION_CHUNK, VERSION_CHUNKS};
    use base_core::can::{Faults, StatusFlags};

    #[test]
    fn an_emergency_with_the_estop_pressed_is_an_error_that_says_so() {
        let status = Status {
            mode: Mode::Emergency,
            flags: StatusFlags {
                estop_pressed: true,
                ..StatusFlags::default()
            },
            ..Status::default()
        };
        let diagnostic = diagnose(&status, "base", BridgeCounts::default());
        assert_eq!(diagnostic.level, DIAGNOSTIC_ERROR);
        assert_eq!(diagnostic.message, "Emergency: e-stop pressed");
    }

    #[test]
    fn the_last_rejection_is_named_and_faults_listed() {
        let status = Status {
            mode: Mode::Standby,
            faults: Faults {
                left_drive_alarm: true,
                ..Faults::default()
            },
            rejected_count: 3,
            last_rejection: 0x02,
            last_rejection_subject: 0xC8,
            ..Status::default()
        };
        let diagnostic = diagnose(&status, "base", BridgeCounts::default());
        assert_eq!(diagnostic.level, DIAGNOSTIC_ERROR);
        let get = |key: &str| {
            diagnostic
                .values
                .iter()
                .find(|pair| pair.key == key)
                .map(|pair| pair.value.clone())
        };
        assert_eq!(get("last_rejection").as_deref(), Some("BadVelocityMarker"));
        assert_eq!(get("last_rejection_subject").as_deref(), Some("0xC8"));
        assert_eq!(get("faults").as_deref(), Some("left_drive_alarm"));
    }

    #[test]
    fn the_image_version_is_whole_once_every_part_after_a_state_came() {
        let mut image = ImageVersion::default();
        let version = b"0.1.0+412.g7efef4d";
        let part = |index: u8| {
            let mut text = [0u8; VERSION_CHUNK];
            let at = usize::from(index) * VERSION_CHUNK;
            for (byte, source) in text.iter_mut().zip(version.iter().skip(at)) {
                *byte = *source;
            }
            UpdateReply::Version { part: index, text }
        };
        let state = UpdateReply::State {
            phase: base_core::can::update::Phase::Idle,
            session: 0,
            running_slot: 0,
            windows_written: 0,
            signatures_required: true,
            security_version: 1,
        };
        image.on_reply(&state);
        for index in 0..VERSION_CHUNKS - 1 {
            image.on_reply(&part(index));
        }
        assert_eq!(image.version(), None, "a part is missing");
        image.on_reply(&part(VERSION_CHUNKS - 1));
        assert_eq!(image.version(), Some("0.1.0+412.g7efef4d"));
        // A new STATE starts over; the version stays until a whole one replaces it.
        image.on_reply(&state);
        image.on_reply(&part(0));
        assert_eq!(image.version(), Some("0.1.0+412.g7efef4d"));
    }

    #[test]
    fn a_development_build_is_a_warning_and_a_signed_one_is_not() {
        let status = Status {
            mode: Mode::Standby,
            ..Status::default()
        };
        let level = diagnose(&status, "base", BridgeCounts::default()).level;
        assert!(level < DIAGNOSTIC_WARN);
        let mut signed = diagnose(&status, "base", BridgeCounts::default());
        let trust = UpdateTrust {
            signatures_required: true,
            security_version: 3,
        };
        add_update_trust(&mut signed, Some(trust));
        assert_eq!(signed.level, level);
        let value = |diagnostic: &DiagnosticStatus, key: &str| {
            let pair = diagnostic.values.iter().find(|pair| pair.key == key);
            pair.map(|pair| pair.value.clone())
        };
        assert_eq!(value(&signed, "security_version").as_deref(), Some("3"));
        let mut development = diagnose(&status, "base", BridgeCounts::default());
        add_update_trust(
            &mut development,
            Some(UpdateTrust {
                signatures_required: false,
                ..trust
            }),
        );
        assert_eq!(development.level, DIAGNOSTIC_WARN);
        assert!(development.message.contains("development build"));
        assert_eq!(
            value(&development, "update_signatures").as_deref(),
            Some("not required (development build)")
        );
    }

    #[test]
    fn a_first_boot_is_named_without_raising_the_level() {
        let status = Status {
            mode: Mode::Standby,
            ..Status::default()
        };
        let mut diagnostic = diagnose(&status, "base", BridgeCounts::default());
        let level = diagnostic.level;
        add_boot_info(
            &mut diagnostic,
            Some(BootInfo {
                first_boot: true,
                update_reset: UpdateReset::None,
            }),
        );
        assert_eq!(diagnostic.level, level);
        assert!(
            diagnostic.message.contains("first boot"),
            "{}",
            diagnostic.message
        );
        let value = diagnostic
            .values
            .iter()
            .find(|value| value.key == "first_boot")
            .map(|value| value.value.as_str());
        assert_eq!(value, Some("yes"));

        let mut unknown = diagnose(&status, "base", BridgeCounts::default());
        add_boot_info(&mut unknown, None);
        assert!(!unknown.message.contains("first boot"));
        assert!(
            unknown
                .values
                .iter()
                .any(|value| value.key == "first_boot" && value.value == "unknown")
        );
    }

    #[test]
    fn a_remote_that_is_off_is_a_warning_that_says_how_to_turn_it_on() {
        use base_core::registers::BLUETOOTH_OFF_AFTER_PANICS;
        let status = Status {
            mode: Mode::Standby,
            ..Status::default()
        };
        for (state, value) in [
            (BLE_OFF_AFTER_HOST_STOPS, "ble_off_after_host_stops"),
            (BLUETOOTH_OFF_AFTER_PANICS, "off_after_panics"),
        ] {
            let mut diagnostic = diagnose(&status, "base", BridgeCounts::default());
            add_bluetooth_state(&mut diagnostic, Some(state));
            assert_eq!(diagnostic.level, DIAGNOSTIC_WARN, "{state}");
            assert!(
                diagnostic.message.contains("0xB1E1"),
                "{}",
                diagnostic.message
            );
            assert!(
                diagnostic
                    .values
                    .iter()
                    .any(|kv| kv.key == "bluetooth" && kv.value == value)
            );
        }
        let mut on = diagnose(&status, "base", BridgeCounts::default());
        add_bluetooth_state(&mut on, Some(0));
        assert_eq!(on.level, DIAGNOSTIC_OK);
    }

    #[test]
    fn a_flash_fault_is_a_warning() {
        let status = Status {
            mode: Mode::Standby,
            faults: Faults {
                flash: true,
                ..Faults::default()
            },
            ..Status::default()
        };
        let diagnostic = diagnose(&status, "base", BridgeCounts::default());
        assert_eq!(diagnostic.level, DIAGNOSTIC_WARN);
        assert_eq!(diagnostic.message, "Standby; faults: flash");
    }

    #[test]
    fn standby_without_faults_is_ok() {
        let status = Status {
            mode: Mode::Standby,
            ..Status::default()
        };
        assert_eq!(
            diagnose(&status, "base", BridgeCounts::default()).level,
            DIAGNOSTIC_OK
        );
    }
}
