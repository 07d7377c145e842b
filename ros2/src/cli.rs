//! The command line: `base-ros2 --help`. Every ROS parameter of the node is an
//! option here (with an environment variable for the bus, like basectl), and ROS's
//! own arguments set them too: `--ros-args -p NAME:=VALUE --params-file FILE
//! -r __node:=NAME -r __ns:=NS`, as `ros2 run` and `ros2 launch` pass them.

use std::ffi::OsString;

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use basectl::bus::{self, Interface};
use clap::Parser;
use ros2_client::ParameterValue;
use yaml_rust2::{Yaml, YamlLoader};

use crate::bridge::SpeedLimits;
use crate::node::{self, Settings};

/// The accepted `cmd_vel_timeout`, s.
const CMD_VEL_TIMEOUT_S: std::ops::RangeInclusive<f64> = 0.05..=2.0;
/// The accepted `command_rate`, Hz.
const COMMAND_RATE_HZ: std::ops::RangeInclusive<f64> = 1.0..=100.0;
/// The accepted `max_linear_speed`, m/s.
const MAX_LINEAR_SPEED: std::ops::RangeInclusive<f64> = 0.1..=20.0;
/// The accepted `max_angular_speed`, rad/s.
const MAX_ANGULAR_SPEED: std::ops::RangeInclusive<f64> = 0.1..=100.0;

/// A ROS 2 node for the base controller: /cmd_vel in; /odom, /tf, /battery_state and
/// /diagnostics out. No ROS installation needed; talks to the base over socketcand,
/// SLCAN or SocketCAN.
#[derive(Debug, Parser)]
#[command(version, args_override_self = true)]
pub struct Cli {
    /// The adapter kind.
    #[arg(
        long,
        value_enum,
        default_value = "socketcand",
        env = "BASECTL_INTERFACE"
    )]
    pub interface: Interface,
    /// socketcand: HOST:PORT[/BUS] (default 127.0.0.1:29536, the simulator); SLCAN:
    /// the tty path (default /tmp/virtual-base-controller); SocketCAN: the interface
    /// (default can0).
    #[arg(long, env = "BASECTL_CHANNEL")]
    pub channel: Option<String>,
    /// The CAN bit rate an SLCAN adapter is set to (SocketCAN: set with `ip link`).
    #[arg(long, default_value_t = 500_000)]
    pub bitrate: u32,
    /// The DDS domain.
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0)]
    pub domain_id: u16,
    /// The node's name (also `--ros-args -r __node:=NAME`).
    #[arg(long, default_value = "base_ros2")]
    pub node_name: String,
    /// The namespace of the node and its topics (/tf and /diagnostics stay absolute;
    /// also `--ros-args -r __ns:=NS`).
    #[arg(long, default_value = "/")]
    pub namespace: String,
    /// Stop the base when the last /cmd_vel is older than this, seconds.
    #[arg(long, default_value_t = 0.5)]
    pub cmd_vel_timeout: f64,
    /// How often the enable and velocity are sent while /cmd_vel is fresh, Hz.
    #[arg(long, default_value_t = 20.0)]
    pub command_rate: f64,
    /// /cmd_vel is geometry_msgs/TwistStamped instead of geometry_msgs/Twist.
    #[arg(long, num_args = 0..=1, default_missing_value = "true", action = clap::ArgAction::Set, default_value_t = false)]
    pub stamped: bool,
    /// frame_id of /odom and the parent frame of the TF.
    #[arg(long, default_value = "odom")]
    pub odom_frame: String,
    /// child_frame_id of /odom and the child frame of the TF.
    #[arg(long, default_value = "base_link")]
    pub base_frame: String,
    /// Publish no odom → base_link transform on /tf (e.g. when robot_localization
    /// does).
    #[arg(long, num_args = 0..=1, default_missing_value = "true", action = clap::ArgAction::Set, default_value_t = false)]
    pub no_tf: bool,
    /// The fastest the base can drive, m/s: /odom's twist is clamped to it, and a
    /// pose step that would be faster is a jump (an odometry reset), not motion.
    #[arg(long, default_value_t = 3.0)]
    pub max_linear_speed: f64,
    /// The fastest the base can turn, rad/s (as `max_linear_speed`).
    #[arg(long, default_value_t = 10.0)]
    pub max_angular_speed: f64,
    /// The left wheel's joint in /joint_states (as the robot's URDF names it).
    #[arg(long, default_value = "left_wheel_joint")]
    pub left_wheel_joint: String,
    /// The right wheel's joint in /joint_states.
    #[arg(long, default_value = "right_wheel_joint")]
    pub right_wheel_joint: String,
    /// Diagonal of /odom's pose covariance: x, y, z, roll, pitch, yaw.
    #[arg(long, value_delimiter = ',', num_args = 6,
          default_values_t = [0.001, 0.001, 1e6, 1e6, 1e6, 0.01])]
    pub pose_covariance: Vec<f64>,
    /// Diagonal of /odom's twist covariance: x, y, z, roll, pitch, yaw.
    #[arg(long, value_delimiter = ',', num_args = 6,
          default_values_t = [0.001, 0.001, 1e6, 1e6, 1e6, 0.01])]
    pub twist_covariance: Vec<f64>,
    /// Send the PC heartbeat (006#01) this often, ms; 0 = not at all (another program
    /// on the PC sends it).
    #[arg(long, default_value_t = 1000)]
    pub heartbeat_ms: u64,
    /// hardware_id in /diagnostics.
    #[arg(long, default_value = "base_controller")]
    pub hardware_id: String,
}

/// The ROS parameters, each the option of the same name with `-` for `_`.
const PARAMETERS: [&str; 17] = [
    "interface",
    "channel",
    "bitrate",
    "cmd_vel_timeout",
    "command_rate",
    "stamped",
    "odom_frame",
    "base_frame",
    "publish_tf",
    "max_linear_speed",
    "max_angular_speed",
    "left_wheel_joint",
    "right_wheel_joint",
    "pose_covariance",
    "twist_covariance",
    "heartbeat_ms",
    "hardware_id",
];

/// `args` with ROS's arguments (`--ros-args ... [--]`, any number of times) turned
/// into options: a parameters file first, then `-p` in order, each later one winning.
pub fn expand_ros_args(args: Vec<OsString>) -> Result<Vec<OsString>, String> {
    let mut plain = Vec::new();
    let mut remaps = Vec::new();
    let mut from_files = Vec::new();
    let mut from_params = Vec::new();
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        if arg != "--ros-args" {
            plain.push(arg);
            continue;
        }
        while let Some(arg) = args.next() {
            let text = arg
                .to_str()
                .ok_or_else(|| format!("{arg:?} is not UTF-8"))?
                .to_owned();
            let mut value = |what: &str| {
                args.next()
                    .and_then(|value| value.to_str().map(str::to_owned))
                    .ok_or_else(|| format!("--ros-args {what} needs a value"))
            };
            match text.as_str() {
                "--" => break,
                "-p" | "--param" => {
                    let assignment = value(&text)?;
                    let (name, value) = assignment.split_once(":=").ok_or_else(|| {
                        format!("--ros-args -p {assignment}: expected NAME:=VALUE")
                    })?;
                    let value = YamlLoader::load_from_str(value)
                        .ok()
                        .and_then(|mut docs| docs.pop())
                        .unwrap_or(Yaml::String(value.to_owned()));
                    from_params.extend(parameter_option(name, &value)?);
                }
                "--params-file" => {
                    let path = value(&text)?;
                    from_files.extend(parameters_file(&path)?);
                }
                "-r" | "--remap" => {
                    let rule = value(&text)?;
                    match rule.split_once(":=") {
                        Some(("__node" | "__name", name)) => {
                            remaps.push(format!("--node-name={name}").into())
                        }
                        Some(("__ns", namespace)) => {
                            remaps.push(format!("--namespace={namespace}").into())
                        }
                        _ => {
                            return Err(format!(
                                "--ros-args -r {rule}: only __node:= and __ns:= are supported; \
                                 topic names are options (--namespace)"
                            ));
                        }
                    }
                }
                // Logging goes to stderr and /rosout at every level the node uses.
                "--log-level"
                | "--disable-rosout-logs"
                | "--disable-stdout-logs"
                | "--disable-external-lib-logs"
                | "--enable-rosout-logs"
                | "--enable-stdout-logs" => {
                    if text == "--log-level" {
                        value(&text)?;
                    }
                }
                other => return Err(format!("--ros-args {other} is not supported")),
            }
        }
    }
    // As in ROS: parameters files first, then -p, whatever their order.
    plain.extend(remaps);
    plain.extend(from_files);
    plain.extend(from_params);
    Ok(plain)
}

/// The option that sets parameter `name` to `value`.
fn parameter_option(name: &str, value: &Yaml) -> Result<Vec<OsString>, String> {
    if !PARAMETERS.contains(&name) {
        return Err(format!(
            "no parameter {name}; base-ros2 has {}",
            PARAMETERS.join(", ")
        ));
    }
    let scalar = |value: &Yaml| -> Result<String, String> {
        match value {
            Yaml::Real(text) | Yaml::String(text) => Ok(text.clone()),
            Yaml::Integer(number) => Ok(number.to_string()),
            Yaml::Boolean(flag) => Ok(flag.to_string()),
            other => Err(format!("parameter {name}: {other:?} is not a value")),
        }
    };
    let option = format!("--{}", name.replace('_', "-"));
    Ok(match (name, value) {
        ("stamped", Yaml::Boolean(stamped)) => vec![format!("--stamped={stamped}").into()],
        ("publish_tf", Yaml::Boolean(publish)) => {
            vec![format!("--no-tf={}", !publish).into()]
        }
        ("stamped" | "publish_tf", other) => {
            return Err(format!("parameter {name} is true or false, not {other:?}"));
        }
        (_, Yaml::Array(values)) => {
            let values: Result<Vec<OsString>, String> = values
                .iter()
                .map(|value| scalar(value).map(OsString::from))
                .collect();
            std::iter::once(option.into()).chain(values?).collect()
        }
        (_, value) => vec![format!("{option}={}", scalar(value)?).into()],
    })
}

/// The options a ROS 2 parameters file sets for this node: the `ros__parameters` of
/// `/**` (every node) and of any key naming base-ros2's node (`base_ros2`,
/// `/ns/base_ros2`).
fn parameters_file(path: &str) -> Result<Vec<OsString>, String> {
    let text = std::fs::read_to_string(path).map_err(|error| format!("{path}: {error}"))?;
    let documents = YamlLoader::load_from_str(&text).map_err(|error| format!("{path}: {error}"))?;
    let mut options = Vec::new();
    for document in &documents {
        let Yaml::Hash(nodes) = document else {
            return Err(format!("{path}: expected NODE: ros__parameters: ..."));
        };
        for (node, section) in nodes {
            let node = node.as_str().unwrap_or_default();
            let Yaml::Hash(parameters) = &section["ros__parameters"] else {
                return Err(format!("{path}: {node} has no ros__parameters"));
            };
            for (name, value) in parameters {
                let name = name
                    .as_str()
                    .ok_or_else(|| format!("{path}: a parameter name is not text"))?;
                options.extend(parameter_option(name, value)?);
            }
        }
    }
    Ok(options)
}

impl Cli {
    /// The settings as ROS parameters, for the parameter services.
    fn parameters(&self, channel: &str) -> Vec<(String, ParameterValue)> {
        let interface = match self.interface {
            Interface::Socketcand => "socketcand",
            Interface::Slcan => "slcan",
            Interface::Socketcan => "socketcan",
        };
        vec![
            ("interface".into(), ParameterValue::String(interface.into())),
            ("channel".into(), ParameterValue::String(channel.into())),
            (
                "bitrate".into(),
                ParameterValue::Integer(self.bitrate.into()),
            ),
            (
                "cmd_vel_timeout".into(),
                ParameterValue::Double(self.cmd_vel_timeout),
            ),
            (
                "command_rate".into(),
                ParameterValue::Double(self.command_rate),
            ),
            ("stamped".into(), ParameterValue::Boolean(self.stamped)),
            (
                "odom_frame".into(),
                ParameterValue::String(self.odom_frame.clone()),
            ),
            (
                "base_frame".into(),
                ParameterValue::String(self.base_frame.clone()),
            ),
            ("publish_tf".into(), ParameterValue::Boolean(!self.no_tf)),
            (
                "max_linear_speed".into(),
                ParameterValue::Double(self.max_linear_speed),
            ),
            (
                "max_angular_speed".into(),
                ParameterValue::Double(self.max_angular_speed),
            ),
            (
                "left_wheel_joint".into(),
                ParameterValue::String(self.left_wheel_joint.clone()),
            ),
            (
                "right_wheel_joint".into(),
                ParameterValue::String(self.right_wheel_joint.clone()),
            ),
            (
                "pose_covariance".into(),
                ParameterValue::DoubleArray(self.pose_covariance.clone()),
            ),
            (
                "twist_covariance".into(),
                ParameterValue::DoubleArray(self.twist_covariance.clone()),
            ),
            (
                "heartbeat_ms".into(),
                ParameterValue::Integer(i64::try_from(self.heartbeat_ms).unwrap_or(i64::MAX)),
            ),
            (
                "hardware_id".into(),
                ParameterValue::String(self.hardware_id.clone()),
            ),
        ]
    }

    /// The node's settings; `Err` names a bad value (NaN is outside every range).
    pub fn settings(&self) -> Result<Settings, String> {
        // Shorter than a few command periods stops the base between two messages of a
        // steady 20 Hz publisher; longer than 2 s lets a dead publisher's last twist
        // drive on for longer than anyone would stand beside a moving base.
        if !CMD_VEL_TIMEOUT_S.contains(&self.cmd_vel_timeout) {
            return Err(format!(
                "--cmd-vel-timeout {} s: between {} and {} s",
                self.cmd_vel_timeout,
                CMD_VEL_TIMEOUT_S.start(),
                CMD_VEL_TIMEOUT_S.end()
            ));
        }
        // More than 100 Hz only adds bus load (the base's cycle is 50 ms); a rate of
        // 1e20 made the send period zero, and the node sent flat out.
        if !COMMAND_RATE_HZ.contains(&self.command_rate) {
            return Err(format!(
                "--command-rate {} Hz: between {} and {} Hz",
                self.command_rate,
                COMMAND_RATE_HZ.start(),
                COMMAND_RATE_HZ.end()
            ));
        }
        for (option, value, range, unit) in [
            (
                "--max-linear-speed",
                self.max_linear_speed,
                MAX_LINEAR_SPEED,
                "m/s",
            ),
            (
                "--max-angular-speed",
                self.max_angular_speed,
                MAX_ANGULAR_SPEED,
                "rad/s",
            ),
        ] {
            if !range.contains(&value) {
                return Err(format!(
                    "{option} {value} {unit}: between {} and {} {unit}",
                    range.start(),
                    range.end()
                ));
            }
        }
        let six = |values: &[f64], what: &str| -> Result<[f64; 6], String> {
            <[f64; 6]>::try_from(values)
                .map_err(|_| format!("{what} takes 6 values, got {}", values.len()))
        };
        Ok(Settings {
            domain_id: self.domain_id,
            node_name: self.node_name.clone(),
            namespace: self.namespace.clone(),
            cmd_vel_timeout: Duration::from_secs_f64(self.cmd_vel_timeout),
            command_period: Duration::from_secs_f64(1.0 / self.command_rate),
            stamped: self.stamped,
            odom_frame: self.odom_frame.clone(),
            base_frame: self.base_frame.clone(),
            publish_tf: !self.no_tf,
            speed_limits: SpeedLimits {
                linear_m_s: self.max_linear_speed,
                angular_rad_s: self.max_angular_speed,
            },
            wheel_joints: [
                self.left_wheel_joint.clone(),
                self.right_wheel_joint.clone(),
            ],
            pose_covariance: six(&self.pose_covariance, "--pose-covariance")?,
            twist_covariance: six(&self.twist_covariance, "--twist-covariance")?,
            heartbeat_period: Duration::from_millis(self.heartbeat_ms),
            hardware_id: self.hardware_id.clone(),
            parameters: self.parameters(&self.channel()),
        })
    }

    /// `--channel`, or the adapter kind's default.
    fn channel(&self) -> String {
        self.channel
            .clone()
            .unwrap_or_else(|| basectl::cli::default_channel(self.interface).to_owned())
    }
}

/// Parses `args`, opens the bus and runs the node until Ctrl-C or SIGTERM (exit code
/// 0) or an error (1; 2 for a bad command line).
pub fn main(args: impl IntoIterator<Item = std::ffi::OsString>) -> std::process::ExitCode {
    let args = match expand_ros_args(args.into_iter().collect()) {
        Ok(args) => args,
        Err(error) => {
            eprintln!("base-ros2: {error}");
            return std::process::ExitCode::from(2);
        }
    };
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(error) => error.exit(),
    };
    let settings = match cli.settings() {
        Ok(settings) => settings,
        Err(error) => {
            eprintln!("base-ros2: {error}");
            return std::process::ExitCode::from(2);
        }
    };
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [
        signal_hook::consts::SIGINT,
        signal_hook::consts::SIGTERM,
        signal_hook::consts::SIGHUP,
    ] {
        if let Err(error) = signal_hook::flag::register(signal, Arc::clone(&stop)) {
            eprintln!("base-ros2: cannot watch for Ctrl-C: {error}");
            return std::process::ExitCode::FAILURE;
        }
    }
    let channel = cli.channel();
    let result = bus::open(cli.interface, &channel, cli.bitrate)
        .map_err(node::Error::from)
        .and_then(|mut bus| node::run(&settings, bus.as_mut(), &stop));
    // An SLCAN adapter is closed (`C`) and its tty given back.
    bus::exit::run_all();
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("base-ros2: {error}");
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(args: &[&str]) -> Result<Cli, String> {
        let args = expand_ros_args(args.iter().map(OsString::from).collect())?;
        Cli::try_parse_from(args).map_err(|error| error.to_string())
    }

    #[test]
    fn ros_args_set_parameters_and_remap_the_node_as_ros2_launch_passes_them() {
        let file = std::env::temp_dir().join(format!("base-ros2-{}.yaml", std::process::id()));
        std::fs::write(
            &file,
            "/**:\n  ros__parameters:\n    cmd_vel_timeout: 0.8\n    odom_frame: odom_file\n\
             base_ros2:\n  ros__parameters:\n    pose_covariance: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]\n\
             \x20   publish_tf: false\n",
        )
        .unwrap();
        // -p comes before the file on the command line, yet wins, as in ROS.
        let cli = parse(&[
            "base-ros2",
            "--stamped",
            "--ros-args",
            "-p",
            "cmd_vel_timeout:=0.25",
            "--params-file",
            file.to_str().unwrap(),
            "-r",
            "__node:=left_base",
            "-r",
            "__ns:=/robot",
            "--",
        ])
        .unwrap();
        std::fs::remove_file(&file).unwrap();
        assert_eq!(cli.cmd_vel_timeout, 0.25);
        assert_eq!(cli.odom_frame, "odom_file");
        assert_eq!(cli.pose_covariance, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert!(cli.no_tf && cli.stamped);
        assert_eq!(
            (cli.node_name.as_str(), cli.namespace.as_str()),
            ("left_base", "/robot")
        );
        let settings = cli.settings().unwrap();
        assert!(
            settings
                .parameters
                .contains(&("cmd_vel_timeout".to_owned(), ParameterValue::Double(0.25)))
        );
        assert!(
            settings
                .parameters
                .contains(&("publish_tf".to_owned(), ParameterValue::Boolean(false)))
        );
    }

    #[test]
    fn a_timeout_or_rate_out_of_its_range_is_refused_with_the_range() {
        let settings = |option: &str, value: &str| {
            parse(&["base-ros2", &format!("{option}={value}")])
                .unwrap()
                .settings()
        };
        // 1e20 s panicked in Duration::from_secs_f64.
        for timeout in ["1e20", "2.01", "0.049", "0", "-1", "NaN", "inf"] {
            let error = settings("--cmd-vel-timeout", timeout).err();
            assert!(
                error.is_some_and(|error| error.contains("between 0.05 and 2 s")),
                "{timeout}"
            );
        }
        for timeout in ["0.05", "0.5", "2"] {
            assert!(settings("--cmd-vel-timeout", timeout).is_ok(), "{timeout}");
        }
        for rate in ["1e20", "100.5", "0.5", "NaN"] {
            let error = settings("--command-rate", rate).err();
            assert!(
                error.is_some_and(|error| error.contains("between 1 and 100 Hz")),
                "{rate}"
            );
        }
        assert!(settings("--command-rate", "100").is_ok());
        for (option, bad) in [
            ("--max-linear-speed", "0"),
            ("--max-linear-speed", "NaN"),
            ("--max-angular-speed", "1e9"),
        ] {
            let error = settings(option, bad).err();
            assert!(
                error.is_some_and(|error| error.contains("between")),
                "{option} {bad}"
            );
        }
    }

    #[test]
    fn an_unknown_parameter_or_ros_argument_is_refused_by_name() {
        let error = parse(&["base-ros2", "--ros-args", "-p", "speed:=3"]).unwrap_err();
        assert!(error.contains("no parameter speed"), "{error}");
        let error = parse(&["base-ros2", "--ros-args", "-r", "cmd_vel:=/teleop"]).unwrap_err();
        assert!(error.contains("only __node:= and __ns:="), "{error}");
        let error = parse(&["base-ros2", "--ros-args", "-p", "stamped:=3"]).unwrap_err();
        assert!(error.contains("true or false"), "{error}");
    }
}
