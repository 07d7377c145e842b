//! base-ros2: a ROS 2 node for the base controller, with no ROS installation needed
//! (ros2-client, pure Rust over RustDDS). `/cmd_vel` in; `/odom`, `/tf`,
//! `/battery_state` and `/diagnostics` out; over the same buses as basectl. The
//! conversions between ROS's conventions and the base's are in [`convert`], the
//! command time-out and odometry in [`bridge`], the ROS side in [`node`].

pub mod bridge;
pub mod cli;
pub mod clock;
pub mod convert;
pub mod msgs;
pub mod node;
