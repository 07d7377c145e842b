//! The command line: `base-ros2 --help`. Every ROS parameter of the node is an
//! option here (with an environment variable for the bus, like basectl).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use basectl::bus::{self, Interface};
use clap::Parser;

use crate::node::{self, Settings};

/// A ROS 2 node for the base controller: /cmd_vel in; /odom, /tf, /battery_state and
/// /diagnostics out. No ROS installation needed; talks to the base over socketcand,
/// SLCAN or SocketCAN.
#[derive(Debug, Parser)]
#[command(version)]
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
    /// The node's name.
    #[arg(long, default_value = "base_ros2")]
    pub node_name: String,
    /// The namespace of the node and its topics (/tf and /diagnostics stay absolute).
    #[arg(long, default_value = "/")]
    pub namespace: String,
    /// Stop the base when the last /cmd_vel is older than this, seconds.
    #[arg(long, default_value_t = 0.5)]
    pub cmd_vel_timeout: f64,
    /// How often the enable and velocity are sent while /cmd_vel is fresh, Hz.
    #[arg(long, default_value_t = 20.0)]
    pub command_rate: f64,
    /// /cmd_vel is geometry_msgs/TwistStamped instead of geometry_msgs/Twist.
    #[arg(long)]
    pub stamped: bool,
    /// frame_id of /odom and the parent frame of the TF.
    #[arg(long, default_value = "odom")]
    pub odom_frame: String,
    /// child_frame_id of /odom and the child frame of the TF.
    #[arg(long, default_value = "base_link")]
    pub base_frame: String,
    /// Publish no odom → base_link transform on /tf (e.g. when robot_localization
    /// does).
    #[arg(long)]
    pub no_tf: bool,
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

impl Cli {
    /// The node's settings; `Err` names a bad value.
    pub fn settings(&self) -> Result<Settings, String> {
        if !(self.cmd_vel_timeout.is_finite() && self.cmd_vel_timeout > 0.0) {
            return Err(format!(
                "--cmd-vel-timeout {} is not a positive number of seconds",
                self.cmd_vel_timeout
            ));
        }
        if !(self.command_rate.is_finite() && self.command_rate >= 1.0) {
            return Err(format!(
                "--command-rate {} Hz: at least 1 Hz",
                self.command_rate
            ));
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
            pose_covariance: six(&self.pose_covariance, "--pose-covariance")?,
            twist_covariance: six(&self.twist_covariance, "--twist-covariance")?,
            heartbeat_period: Duration::from_millis(self.heartbeat_ms),
            hardware_id: self.hardware_id.clone(),
        })
    }
}

/// Parses `args`, opens the bus and runs the node until Ctrl-C or SIGTERM (exit code
/// 0) or an error (1; 2 for a bad command line).
pub fn main(args: impl IntoIterator<Item = std::ffi::OsString>) -> std::process::ExitCode {
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
    let channel = cli
        .channel
        .clone()
        .unwrap_or_else(|| basectl::cli::default_channel(cli.interface).to_owned());
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
