//! The command line (clap derive) and what each command runs.

use std::io::Write;
use std::time::Duration;

use clap::{Parser, Subcommand};

use crate::bus::{self, Interface};
use crate::calibrate::{self, Driving, OdometryPlan, ScalePlan, Terminal};
use crate::controller::{Controller, Error};
use crate::drive::{self, Steps};
use crate::heartbeat;
use crate::monitor::{self, Until};
use crate::registers;

/// Commissioning of the base controller over CAN: monitor, drive, registers and the
/// calibration wizards.
#[derive(Debug, Parser)]
#[command(version)]
pub struct Cli {
    /// The adapter kind.
    #[arg(long, value_enum, default_value = "slcan", global = true)]
    pub interface: Interface,
    /// SLCAN: the tty path (e.g. /dev/ttyACM0); SocketCAN: the interface (e.g. can0).
    #[arg(long, default_value = "/tmp/virtual-base-controller", global = true)]
    pub channel: String,
    /// The CAN bit rate an SLCAN adapter is set to (SocketCAN: set with `ip link`).
    #[arg(long, default_value_t = 500_000, global = true)]
    pub bitrate: u32,
    /// How long a register read may take to be answered, ms.
    #[arg(long, default_value_t = 500, global = true)]
    pub timeout_ms: u64,
    #[command(subcommand)]
    pub command: CliCommand,
}

#[derive(Debug, Subcommand)]
pub enum CliCommand {
    /// Print every report (pose, battery, weight, status, register replies), decoded.
    Monitor {
        /// Stop after this many frames.
        #[arg(long)]
        count: Option<u64>,
        /// Stop after this many seconds.
        #[arg(long)]
        seconds: Option<u64>,
    },
    /// Keyboard teleop: arrows/WASD, space stops, q quits.
    Drive {
        #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(i16).range(1..=2000))]
        step_mm_s: i16,
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(i16).range(1..=6000))]
        step_mrad_s: i16,
        #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(i16).range(1..=i64::from(i16::MAX)))]
        max_mm_s: i16,
        #[arg(long, default_value_t = 1500, value_parser = clap::value_parser!(i16).range(1..=i64::from(i16::MAX)))]
        max_mrad_s: i16,
    },
    /// Registers by name or address.
    #[command(subcommand)]
    Reg(RegCommand),
    /// The guided calibration wizards.
    #[command(subcommand)]
    Calibrate(CalibrateCommand),
    /// Send the PC heartbeat (006#01) every second.
    PcHeartbeat {
        /// Stop after this many seconds (default: until Ctrl-C).
        #[arg(long)]
        seconds: Option<u64>,
    },
}

#[derive(Debug, Subcommand)]
pub enum RegCommand {
    /// The register table (no bus needed).
    List,
    /// Read one register.
    Get { register: String },
    /// Write one register and read it back.
    Set { register: String, value: String },
    /// Read every readable register.
    Dump,
    /// Restore every writable register to its default.
    Restore {
        /// Yes, really.
        #[arg(long)]
        yes: bool,
    },
}

#[derive(Debug, Subcommand)]
pub enum CalibrateCommand {
    /// Straight line, clockwise and counter-clockwise turn; stores f_lin, f_cw, f_ccw.
    Odometry {
        /// Drive automatically (enable + velocity) this far by the uncalibrated
        /// odometry instead of asking the person to drive.
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        drive_mm: Option<u16>,
        /// With --drive-mm: turn this far in each direction, mrad.
        #[arg(long, default_value_t = 6283, value_parser = clap::value_parser!(u16).range(1..))]
        turn_mrad: u16,
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(i16).range(1..=1000))]
        speed_mm_s: i16,
        #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(i16).range(1..=3000))]
        turn_mrad_s: i16,
        /// The measured real distance, mm (asked if not given).
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        real_mm: Option<u16>,
        /// The measured real clockwise angle, mrad (asked if not given).
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        real_cw_mrad: Option<u16>,
        /// The measured real counter-clockwise angle, mrad (asked if not given).
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        real_ccw_mrad: Option<u16>,
    },
    /// Empty reading, then a known weight; stores the scale offset (19, and in full 44/45)
    /// and scale_value.
    Scale {
        /// The known weight, g (asked if not given).
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
        grams: Option<u16>,
    },
}

/// Runs the parsed command; `reg list` needs no bus.
pub fn run(cli: Cli, out: &mut dyn Write) -> Result<(), Error> {
    if let CliCommand::Reg(RegCommand::List) = cli.command {
        return Ok(registers::list(out)?);
    }
    // Argument errors first: nothing is sent for a command that cannot run.
    let register_value = match &cli.command {
        CliCommand::Reg(RegCommand::Set { register, value }) => {
            let register = registers::lookup(register)?;
            Some((register, registers::parse_value(register, value)?))
        }
        _ => None,
    };
    let register = match &cli.command {
        CliCommand::Reg(RegCommand::Get { register }) => Some(registers::lookup(register)?),
        _ => None,
    };
    let mut bus = bus::open(cli.interface, &cli.channel, cli.bitrate)?;
    let mut controller = Controller::new(bus.as_mut(), Duration::from_millis(cli.timeout_ms));
    let controller = &mut controller;
    match cli.command {
        CliCommand::Monitor { count, seconds } => {
            monitor::monitor(controller, Until { count, seconds }, out)
        }
        CliCommand::Drive {
            step_mm_s,
            step_mrad_s,
            max_mm_s,
            max_mrad_s,
        } => drive::drive(
            controller,
            Steps {
                linear_mm_s: step_mm_s,
                rotation_mrad_s: step_mrad_s,
                max_linear_mm_s: max_mm_s,
                max_rotation_mrad_s: max_mrad_s,
            },
            out,
        ),
        CliCommand::Reg(RegCommand::List) => Ok(registers::list(out)?),
        CliCommand::Reg(RegCommand::Get { .. }) => {
            registers::get(controller, register.expect("looked up above"), out)
        }
        CliCommand::Reg(RegCommand::Set { .. }) => {
            let (register, value) = register_value.expect("looked up above");
            registers::set(controller, register, value, out)
        }
        CliCommand::Reg(RegCommand::Dump) => registers::dump(controller, out),
        CliCommand::Reg(RegCommand::Restore { yes }) => registers::restore(controller, yes, out),
        CliCommand::Calibrate(CalibrateCommand::Odometry {
            drive_mm,
            turn_mrad,
            speed_mm_s,
            turn_mrad_s,
            real_mm,
            real_cw_mrad,
            real_ccw_mrad,
        }) => {
            let driving = match drive_mm {
                Some(distance_mm) => Driving::Automatic {
                    distance_mm,
                    angle_mrad: turn_mrad,
                    speed_mm_s,
                    turn_mrad_s,
                },
                None => Driving::ByHand,
            };
            calibrate::odometry(
                controller,
                OdometryPlan {
                    driving,
                    real_mm,
                    real_cw_mrad,
                    real_ccw_mrad,
                },
                &mut Terminal,
                out,
            )
        }
        CliCommand::Calibrate(CalibrateCommand::Scale { grams }) => {
            calibrate::scale(controller, ScalePlan { known_g: grams }, &mut Terminal, out)
        }
        CliCommand::PcHeartbeat { seconds } => heartbeat::pc_heartbeat(controller, seconds, out),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_simulator_is_the_default_bus() {
        let cli = Cli::try_parse_from(["basectl", "monitor", "--count", "3"]).unwrap();
        assert_eq!(cli.interface, Interface::Slcan);
        assert_eq!(cli.channel, "/tmp/virtual-base-controller");
        assert_eq!(cli.bitrate, 500_000);
        assert!(matches!(
            cli.command,
            CliCommand::Monitor {
                count: Some(3),
                seconds: None
            }
        ));
    }

    #[test]
    fn socketcan_is_chosen_by_interface_and_channel() {
        let cli = Cli::try_parse_from([
            "basectl",
            "--interface",
            "socketcan",
            "--channel",
            "can0",
            "reg",
            "dump",
        ])
        .unwrap();
        assert_eq!(cli.interface, Interface::Socketcan);
        assert_eq!(cli.channel, "can0");
    }

    #[test]
    fn out_of_range_wizard_arguments_are_refused_by_the_parser() {
        assert!(Cli::try_parse_from(["basectl", "calibrate", "scale", "--grams", "0"]).is_err());
        assert!(
            Cli::try_parse_from(["basectl", "calibrate", "odometry", "--real-mm", "70000"])
                .is_err()
        );
        assert!(
            Cli::try_parse_from([
                "basectl",
                "calibrate",
                "odometry",
                "--drive-mm",
                "1000",
                "--real-mm",
                "1020"
            ])
            .is_ok()
        );
    }

    #[test]
    fn an_invalid_register_value_fails_before_the_bus_is_opened() {
        let cli = Cli::try_parse_from([
            "basectl",
            "--channel",
            "/nonexistent",
            "reg",
            "set",
            "loop_end_delay",
            "0",
        ])
        .unwrap();
        let error = run(cli, &mut Vec::new()).unwrap_err().to_string();
        assert!(error.contains("allowed"), "{error}");
    }
}
