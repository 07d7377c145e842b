//! The simulator's command line: `cargo run -p virtual-robot -- --help`.

use std::path::PathBuf;
use std::process::ExitCode;

use virtual_robot::ble::HciSpec;
use virtual_robot::simulator::{self, DEFAULT_LINK, Demo, Options, console::HELP};

fn usage() -> String {
    format!(
        "virtual-base-controller: the base controller's firmware on a simulated robot,
on the wall clock, with an SLCAN (Lawicel) serial port for the robot PC's software.

usage: virtual-base-controller [--link PATH | --no-link] [--flash PATH] [--demo [--stay]]
                               [--hci tcp:HOST:PORT]

  --link PATH   symbolic link to the serial port (default {DEFAULT_LINK})
  --no-link     make no link; the port's /dev/pts path is printed at start
  --flash PATH  file holding the register store's flash, so registers survive
                restarts (default {})
  --demo        drive a short path by itself, show the odometry, then quit
  --stay        with --demo: keep running afterwards
  --hci tcp:HOST:PORT
                the Bluetooth remote: a Bluetooth controller behind an HCI
                transport (H4 over TCP), e.g. the Bumble gamepad peer
                (sim/ble-peer/bumble_gamepad.py) or a USB dongle behind Bumble's
                HCI bridge; the bond is kept in the flash file + .bond.
                docs/remote.md says how to pair a pad and drive
  --help        this text

Connect: python-can  can.Bus(interface=\"slcan\", channel=\"{DEFAULT_LINK}\", bitrate=500000)
         SocketCAN   sudo slcand -o -s6 {DEFAULT_LINK} slcan0 && sudo ip link set slcan0 up

Console commands (one per line on stdin):
{HELP}",
        simulator::default_flash_path().display()
    )
}

fn parse_options(mut args: impl Iterator<Item = String>) -> Result<Option<Options>, String> {
    let mut options = Options {
        flash_path: simulator::default_flash_path(),
        link: Some(PathBuf::from(DEFAULT_LINK)),
        demo: Demo::Off,
        hci: None,
    };
    let mut stay = false;
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--help" | "-h" => return Ok(None),
            "--link" => options.link = Some(args.next().ok_or("--link needs a path")?.into()),
            "--no-link" => options.link = None,
            "--flash" => options.flash_path = args.next().ok_or("--flash needs a path")?.into(),
            "--demo" => options.demo = Demo::ThenQuit,
            "--stay" => stay = true,
            "--hci" => {
                let spec = args.next().ok_or("--hci needs tcp:HOST:PORT")?;
                options.hci = Some(HciSpec::parse(&spec)?);
            }
            other => return Err(format!("unknown option {other:?} (see --help)")),
        }
    }
    match (options.demo, stay) {
        (Demo::Off, true) => return Err("--stay goes with --demo".into()),
        (_, true) => options.demo = Demo::ThenStay,
        _ => {}
    }
    Ok(Some(options))
}

fn main() -> ExitCode {
    let options = match parse_options(std::env::args().skip(1)) {
        Ok(Some(options)) => options,
        Ok(None) => {
            println!("{}", usage());
            return ExitCode::SUCCESS;
        }
        Err(error) => {
            eprintln!("virtual-base-controller: {error}");
            return ExitCode::from(2);
        }
    };
    match simulator::run(&options) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("virtual-base-controller: {error}");
            ExitCode::FAILURE
        }
    }
}
