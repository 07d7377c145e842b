//! The CAN bus as basectl sees it: send a standard data frame, receive one with a
//! timeout. Implementations: a socketcand server over TCP (the simulator, or
//! socketcand on the robot), an SLCAN adapter on a tty (CANable, the simulator's
//! pseudo-terminal) and, on Linux, a SocketCAN interface.

use std::fmt;
use std::time::Duration;

use base_core::can::RawFrame;

pub mod exit;
mod slcan_port;
#[cfg(target_os = "linux")]
mod socketcan_bus;
pub mod socketcand_bus;

pub use slcan_port::SlcanPort;
pub use socketcand_bus::SocketcandBus;

/// A CAN bus carrying the base controller's protocol (standard data frames only).
pub trait Bus {
    fn send(&mut self, frame: &RawFrame) -> Result<(), BusError>;
    /// The next standard data frame, or `None` when `timeout` passed without one.
    /// Extended and remote frames are skipped: the protocol uses neither.
    fn receive(&mut self, timeout: Duration) -> Result<Option<RawFrame>, BusError>;
}

/// Which kind of adapter `--channel` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Interface {
    /// A socketcand server (the simulator, or socketcand on the robot): `--channel` is
    /// HOST:PORT, or HOST:PORT/BUS for a bus not named can0. Any number of programs
    /// share the bus this way.
    Socketcand,
    /// A serial SLCAN adapter (CANable, the simulator): `--channel` is its tty path.
    /// One program at a time has it.
    Slcan,
    /// A Linux SocketCAN interface (`--channel can0`), already configured and up.
    Socketcan,
}

/// Opens the bus `channel` names.
pub fn open(
    interface: Interface,
    channel: &str,
    bitrate_bps: u32,
) -> Result<Box<dyn Bus>, BusError> {
    match interface {
        Interface::Socketcand => Ok(Box::new(SocketcandBus::open(channel)?)),
        Interface::Slcan => Ok(Box::new(SlcanPort::open(channel, bitrate_bps)?)),
        #[cfg(target_os = "linux")]
        Interface::Socketcan => Ok(Box::new(socketcan_bus::SocketCanBus::open(channel)?)),
        #[cfg(not(target_os = "linux"))]
        Interface::Socketcan => Err(BusError::Unsupported("SocketCAN exists only on Linux")),
    }
}

/// Why the bus could not be used.
#[derive(Debug)]
pub enum BusError {
    /// The device or interface could not be opened, read or written.
    Io {
        what: String,
        source: std::io::Error,
    },
    /// The SLCAN adapter answered a setup command with an error (BEL).
    AdapterRefused { command: String, hint: String },
    /// The SLCAN adapter did not answer a setup command.
    AdapterSilent { command: String },
    /// The bit rate is not one the adapter can set.
    BadBitrate(u32),
    /// Another program has the SLCAN adapter open.
    Busy { path: String },
    /// The path is a link a simulator left behind when it was killed.
    StaleLink { path: String },
    #[cfg(not(target_os = "linux"))]
    Unsupported(&'static str),
}

impl fmt::Display for BusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusError::Io { what, source } => write!(f, "{what}: {source}"),
            BusError::AdapterRefused { command, hint } => {
                write!(f, "the SLCAN adapter refused {command:?} ({hint})")
            }
            BusError::AdapterSilent { command } => write!(
                f,
                "the SLCAN adapter did not answer {command:?} (is --channel an SLCAN device?)"
            ),
            BusError::BadBitrate(bps) => write!(
                f,
                "bit rate {bps} bit/s is not an SLCAN rate (allowed: {})",
                slcan::BITRATES_BPS.map(|rate| rate.to_string()).join(", ")
            ),
            BusError::Busy { path } => write!(
                f,
                "{path} is busy: another program has the SLCAN adapter open (an SLCAN port \
                 serves one program; the simulator serves many through --interface \
                 socketcand)"
            ),
            BusError::StaleLink { path } => write!(
                f,
                "{path} was left behind by a simulator that is no longer running; start the \
                 simulator again"
            ),
            #[cfg(not(target_os = "linux"))]
            BusError::Unsupported(why) => f.write_str(why),
        }
    }
}

impl std::error::Error for BusError {}
