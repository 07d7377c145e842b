//! The command line (clap derive) and what each command runs.

use std::io::Write;
use std::time::Duration;

use clap::{Parser, Subcommand};

use crate::base::{Base, Error};
use crate::bus::{self, Interface};
use crate::calibrate::{self, Driving, OdometryPlan, ScalePlan, Terminal};
use crate::commission::{self, WheelsPlan};
use crate::drive::{self, Speeds};
use crate::heartbeat;
use crate::monitor::{self, Until};
use crate::registers;
use crate::signing;
use crate::{config, firmware, info, log};

/// Commissioning of the base controller over CAN: monitor, drive, registers and the
/// calibration wizards.
#[derive(Debug, Parser)]
#[command(version)]
pub struct Cli {
    /// The adapter kind.
    #[arg(
        long,
        value_enum,
        default_value = "socketcand",
        env = "BASECTL_INTERFACE",
        global = true
    )]
    pub interface: Interface,
    /// socketcand: HOST:PORT[/BUS] (default 127.0.0.1:29536, the simulator); SLCAN:
    /// the tty path (default /tmp/virtual-base-controller, the simulator's port);
    /// SocketCAN: the interface (default can0).
    #[arg(long, env = "BASECTL_CHANNEL", global = true)]
    pub channel: Option<String>,
    /// The CAN bit rate an SLCAN adapter is set to (SocketCAN: set with `ip link`).
    #[arg(long, default_value_t = 500_000, global = true)]
    pub bitrate: u32,
    /// How long a register read may take to be answered, ms.
    #[arg(long, default_value_t = 500, global = true)]
    pub timeout_ms: u64,
    /// JSON for scripts: one object per report (monitor), one object (info, reg get,
    /// reg set), an array (reg dump).
    #[arg(long, global = true)]
    pub json: bool,
    #[command(subcommand)]
    pub command: CliCommand,
}

#[derive(Debug, Subcommand)]
pub enum CliCommand {
    /// Every report (pose, battery, weight, status, register replies), decoded: a
    /// live view on a terminal, one line per frame otherwise or with --scroll.
    Monitor {
        /// Stop after this many frames.
        #[arg(long)]
        count: Option<u64>,
        /// Stop after this many seconds.
        #[arg(long)]
        seconds: Option<u64>,
        /// One line per frame, scrolling, even on a terminal.
        #[arg(long)]
        scroll: bool,
    },
    /// Keyboard teleop: the base moves while w/s/a/d or an arrow key is held and
    /// stops when it is let go; space or any other key stops, +/- change the speed,
    /// q quits. Shows command, measured speed, pose, mode and faults live.
    Drive {
        /// Speed while w/s or up/down is held, mm/s.
        #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(i16).range(1..=2000))]
        speed_mm_s: i16,
        /// Turn rate while a/d or left/right is held, mrad/s.
        #[arg(long, default_value_t = 800, value_parser = clap::value_parser!(i16).range(1..=6000))]
        turn_mrad_s: i16,
        /// The most + can raise the speed to, mm/s.
        #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(i16).range(1..=i64::from(i16::MAX)))]
        max_mm_s: i16,
        /// The most + can raise the turn rate to, mrad/s.
        #[arg(long, default_value_t = 1500, value_parser = clap::value_parser!(i16).range(1..=i64::from(i16::MAX)))]
        max_mrad_s: i16,
    },
    /// Registers by name or address.
    #[command(subcommand)]
    Reg(RegCommand),
    /// Every register to a file and back (backup and restore).
    #[command(subcommand)]
    Config(ConfigCommand),
    /// Versions, mode, faults, drives, flash, error counters, battery and pose.
    Info,
    /// Record the bus to FILE: candump's log format, or CSV for PlotJuggler (a .csv
    /// file, or --format csv).
    Log {
        file: std::path::PathBuf,
        /// The file's format (default: by its name).
        #[arg(long, value_enum)]
        format: Option<log::Format>,
        /// Stop after this many seconds (default: until Ctrl-C).
        #[arg(long)]
        seconds: Option<u64>,
        /// Stop after this many frames.
        #[arg(long)]
        count: Option<u64>,
    },
    /// The guided calibration wizards.
    #[command(subcommand)]
    Calibrate(CalibrateCommand),
    /// Commissioning checks with a person at the base.
    #[command(subcommand)]
    Commission(CommissionCommand),
    /// The firmware: what runs, and updates over CAN with rollback.
    #[command(subcommand)]
    Firmware(FirmwareCommand),
    /// Send the PC heartbeat (006#01) every second.
    PcHeartbeat {
        /// Stop after this many seconds (default: until Ctrl-C).
        #[arg(long)]
        seconds: Option<u64>,
    },
}

#[derive(Debug, Subcommand)]
pub enum FirmwareCommand {
    /// The running version, its slot, and whether an update runs or it is on trial.
    Info,
    /// Check an image file offline (no bus needed).
    Check { file: std::path::PathBuf },
    /// Update to FILE (from `espflash save-image`): check, ask, save the registers,
    /// write, activate, wait for it on trial, check its health, confirm.
    Update {
        file: std::path::PathBuf,
        /// Do not ask.
        #[arg(long)]
        yes: bool,
        /// Write even the version that runs.
        #[arg(long)]
        force: bool,
        /// Write even an older version.
        #[arg(long)]
        allow_downgrade: bool,
        /// Where the registers are saved first (default: beside FILE).
        #[arg(long)]
        save_registers: Option<std::path::PathBuf>,
    },
    /// Make a new owner's key for signed images: the secret key in KEY (readable by
    /// you only), the public key in KEY.pub (docs/flashing.md, "Signed images").
    Keygen { key: std::path::PathBuf },
    /// Sign the image IN with the secret key and write the signed image to OUT.
    Sign {
        /// The secret key (PKCS#8 PEM, from `keygen` or `openssl genpkey -algorithm ed25519`).
        #[arg(long)]
        key: std::path::PathBuf,
        input: std::path::PathBuf,
        output: std::path::PathBuf,
        /// Let this image go below the running image's security version: the owner's
        /// explicit downgrade.
        #[arg(long)]
        allow_security_downgrade: bool,
    },
    /// Keep the image on trial.
    Confirm {
        /// The update session that activated the image (`firmware update` prints it):
        /// only it may decide while the controller knows it.
        #[arg(long)]
        session: Option<u8>,
    },
    /// Reject the image on trial: the previous one starts.
    Rollback {
        /// As for `confirm`.
        #[arg(long)]
        session: Option<u8>,
    },
    /// End a running update session (before activation).
    Abort,
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
pub enum ConfigCommand {
    /// Save every read-write register, with names, units and versions, as JSON.
    Save { file: std::path::PathBuf },
    /// Check a saved file, show the changes, write them and read them back.
    Load {
        file: std::path::PathBuf,
        /// Check and show the changes, write nothing.
        #[arg(long)]
        dry_run: bool,
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

#[derive(Debug, Subcommand)]
pub enum CommissionCommand {
    /// Turns each wheel alone, slowly forward, and asks which wheel turned and which
    /// way: finds swapped drive addresses and a wrong motor_dir.
    Wheels {
        /// The turning wheel's speed, mm/s.
        #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(i16).range(2..=300))]
        speed_mm_s: i16,
        /// How long each wheel turns, s.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(1..=10))]
        seconds: u64,
    },
}

/// The whole program: parses `args` (the program name first), watches for Ctrl-C,
/// runs the command, prints an error to stderr. Exit code 0 on success, 1 on an error,
/// 2 for a bad command line, 130 after Ctrl-C or SIGTERM.
pub fn main(args: impl IntoIterator<Item = std::ffi::OsString>) -> std::process::ExitCode {
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(error) => error.exit(),
    };
    // Ctrl-C and SIGTERM close the channel too (an SLCAN adapter gets its `C`).
    if let Err(error) = bus::exit::on_signals() {
        eprintln!("basectl: cannot watch for Ctrl-C: {error}");
        return std::process::ExitCode::FAILURE;
    }
    let result = run(cli, &mut std::io::stdout());
    bus::exit::run_all();
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("basectl: {error}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// The channel when neither `--channel` nor `BASECTL_CHANNEL` names one: the
/// simulator's, for socketcand and SLCAN.
pub fn default_channel(interface: Interface) -> &'static str {
    match interface {
        Interface::Socketcand => "127.0.0.1:29536",
        Interface::Slcan => "/tmp/virtual-base-controller",
        Interface::Socketcan => "can0",
    }
}

/// Runs the parsed command; `reg list` needs no bus.
pub fn run(cli: Cli, out: &mut dyn Write) -> Result<(), Error> {
    if let CliCommand::Reg(RegCommand::List) = cli.command {
        return Ok(registers::list(out)?);
    }
    match &cli.command {
        CliCommand::Firmware(FirmwareCommand::Check { file }) => {
            return firmware::check(file, cli.json, out);
        }
        CliCommand::Firmware(FirmwareCommand::Keygen { key }) => return signing::keygen(key, out),
        CliCommand::Firmware(FirmwareCommand::Sign {
            key,
            input,
            output,
            allow_security_downgrade,
        }) => return signing::sign(key, input, output, *allow_security_downgrade, out),
        _ => {}
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
    let channel = cli
        .channel
        .clone()
        .unwrap_or_else(|| default_channel(cli.interface).to_owned());
    let mut bus = bus::open(cli.interface, &channel, cli.bitrate)?;
    if let CliCommand::Log {
        file,
        format,
        seconds,
        count,
    } = &cli.command
    {
        let format = format.unwrap_or_else(|| log::Format::for_path(file));
        return log::log(bus.as_mut(), file, format, *seconds, *count, out);
    }
    if let CliCommand::Firmware(command) = &cli.command {
        let timeout = Duration::from_millis(cli.timeout_ms);
        let bus = bus.as_mut();
        return match command {
            FirmwareCommand::Info => firmware::info(bus, timeout, cli.json, out),
            FirmwareCommand::Check { .. }
            | FirmwareCommand::Keygen { .. }
            | FirmwareCommand::Sign { .. } => unreachable!("run above, without a bus"),
            FirmwareCommand::Update {
                file,
                yes,
                force,
                allow_downgrade,
                save_registers,
            } => {
                if let Ok(mut target) = firmware::ABORT_TARGET.lock() {
                    *target = Some((cli.interface, channel.clone(), cli.bitrate));
                }
                let plan = firmware::UpdatePlan {
                    file: file.clone(),
                    yes: *yes,
                    force: *force,
                    allow_downgrade: *allow_downgrade,
                    registers_file: save_registers.clone(),
                    json: cli.json,
                };
                firmware::update(bus, &plan, timeout, out)
            }
            FirmwareCommand::Confirm { session } => firmware::confirm(bus, *session, timeout, out),
            FirmwareCommand::Rollback { session } => {
                firmware::rollback(bus, *session, timeout, out)
            }
            FirmwareCommand::Abort => firmware::abort(bus, timeout, out),
        };
    }
    let mut base = Base::new(bus.as_mut(), Duration::from_millis(cli.timeout_ms));
    let base = &mut base;
    match cli.command {
        CliCommand::Monitor {
            count,
            seconds,
            scroll,
        } => {
            use std::io::IsTerminal;
            let style = if cli.json {
                monitor::Style::Json
            } else if scroll || !std::io::stdout().is_terminal() {
                monitor::Style::Lines
            } else {
                monitor::Style::Live
            };
            monitor::monitor(base, Until { count, seconds }, style, out)
        }
        CliCommand::Info => info::info(base, cli.json, out),
        CliCommand::Log { .. } => unreachable!("logged above, before the controller"),
        CliCommand::Config(ConfigCommand::Save { file }) => config::save(base, &file, out),
        CliCommand::Config(ConfigCommand::Load { file, dry_run }) => {
            config::load(base, &file, dry_run, out)
        }
        CliCommand::Drive {
            speed_mm_s,
            turn_mrad_s,
            max_mm_s,
            max_mrad_s,
        } => drive::drive(
            base,
            Speeds {
                linear_mm_s: speed_mm_s.min(max_mm_s),
                rotation_mrad_s: turn_mrad_s.min(max_mrad_s),
                max_linear_mm_s: max_mm_s,
                max_rotation_mrad_s: max_mrad_s,
            },
            out,
        ),
        CliCommand::Reg(RegCommand::List) => Ok(registers::list(out)?),
        CliCommand::Reg(RegCommand::Get { .. }) => {
            registers::get(base, register.expect("looked up above"), cli.json, out)
        }
        CliCommand::Reg(RegCommand::Set { .. }) => {
            let (register, value) = register_value.expect("looked up above");
            registers::set(base, register, value, cli.json, out)
        }
        CliCommand::Reg(RegCommand::Dump) => registers::dump(base, cli.json, out),
        CliCommand::Reg(RegCommand::Restore { yes }) => registers::restore(base, yes, out),
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
                base,
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
            calibrate::scale(base, ScalePlan { known_g: grams }, &mut Terminal, out)
        }
        CliCommand::Commission(CommissionCommand::Wheels {
            speed_mm_s,
            seconds,
        }) => commission::wheels(
            base,
            WheelsPlan {
                speed_mm_s,
                duration: Duration::from_secs(seconds),
            },
            &mut Terminal,
            out,
        ),
        CliCommand::PcHeartbeat { seconds } => heartbeat::pc_heartbeat(base, seconds, out),
        CliCommand::Firmware(_) => unreachable!("run above, on the bus itself"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_simulators_socketcand_server_is_the_default_bus() {
        use clap::CommandFactory;
        let command = Cli::command();
        let argument = |name: &str| {
            command
                .get_arguments()
                .find(|argument| argument.get_id() == name)
                .unwrap()
        };
        assert_eq!(argument("interface").get_default_values(), ["socketcand"]);
        assert_eq!(
            argument("interface").get_env(),
            Some(std::ffi::OsStr::new("BASECTL_INTERFACE"))
        );
        assert_eq!(
            argument("channel").get_env(),
            Some(std::ffi::OsStr::new("BASECTL_CHANNEL"))
        );
        assert_eq!(default_channel(Interface::Socketcand), "127.0.0.1:29536");
        assert_eq!(
            default_channel(Interface::Slcan),
            "/tmp/virtual-base-controller"
        );
        let cli = Cli::try_parse_from(["basectl", "monitor", "--count", "3"]).unwrap();
        assert_eq!(cli.bitrate, 500_000);
        assert!(matches!(
            cli.command,
            CliCommand::Monitor {
                count: Some(3),
                seconds: None,
                scroll: false
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
        assert_eq!(cli.channel.as_deref(), Some("can0"));
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
            "--interface",
            "slcan",
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
