//! The simulator's command line: `cargo run -p virtual-robot -- --help`.

use std::path::PathBuf;
use std::process::ExitCode;

use virtual_robot::ble::HciSpec;
use virtual_robot::simulator::{self, DEFAULT_LINK, Demo, Options, console::HELP, socketcand};

fn usage() -> String {
    format!(
        "virtual-base-controller: the base controller's firmware on a simulated robot,
on the wall clock, with an SLCAN (Lawicel) serial port and a socketcand
server for the robot PC's software.

usage: virtual-base-controller [--link PATH | --no-link]
         [--socketcand ADDR:PORT | --no-socketcand] [--socketcan IF]
         [--flash PATH] [--hci tcp:HOST:PORT] [--demo [--stay]]
         [--swap-drive-addresses] [--reverse-drive 1|2]
         [--update-key FILE]...

  --link PATH      symbolic link to the serial port (default
                   {DEFAULT_LINK});
                   refused while another simulator serves it
  --no-link        make no link; the port's /dev/pts path is printed at start
  --socketcand A:P serve the bus as socketcand does, bus name {bus}, to
                   any number of programs at once (default {address})
  --no-socketcand  no socketcand server
  --socketcan IF   also be a node on the Linux CAN interface IF (e.g.
                   vcan0: ip link add vcan0 type vcan; ip link set vcan0 up)
                   for candump, cansend, ros2_socketcan; needs a kernel with CAN
  --flash PATH     file holding the register store's flash, so registers
                   survive restarts (default
                   {})
  --hci tcp:HOST:PORT
                   the Bluetooth remote's controller over H4/TCP: the Bumble
                   gamepad peer (sim/ble-peer/bumble_gamepad.py) or a USB dongle
                   behind Bumble's HCI bridge; the bond is kept in the flash
                   file + .bond (docs/remote.md: pairing and driving)
  --demo           drive a short path by itself, show the odometry, then quit
  --stay           with --demo: keep running afterwards
  --swap-drive-addresses
                   the drives' address switches swapped (slave 1 on the
                   right wheel), for `basectl commission wheels` to find
  --reverse-drive SLAVE
                   the drive with address 1 or 2 has its direction parameter
                   at the other value: it turns against its command (the
                   controller stops the base; `basectl commission wheels`
                   names it)
  --update-key FILE
                   activate only update images signed by this key (the .pub
                   file of `basectl firmware keygen`; repeat for more keys),
                   as a build made with BASE_UPDATE_KEY does; without it the
                   firmware is a development build that takes unsigned images
  --help           this text

Connect (any number at once through socketcand, one at a time through SLCAN):
  python-can  can.Bus(interface=\"socketcand\", host=\"127.0.0.1\", port=29536,
                      channel=\"{bus}\")
  basectl     basectl monitor   (socketcand on {address} is its default)
  SLCAN       can.Bus(interface=\"slcan\", bitrate=500000,
                      channel=\"{DEFAULT_LINK}\")
  SocketCAN   (slcand puts /dev/ in front of the tty name itself)
              sudo slcand -o -s6 $(readlink {DEFAULT_LINK} | cut -c6-) slcan0
              sudo ip link set slcan0 up

Console commands (one per line on stdin):
{HELP}",
        simulator::default_flash_path().display(),
        bus = socketcand::BUS_NAME,
        address = socketcand::DEFAULT_ADDRESS,
    )
}

fn parse_options(mut args: impl Iterator<Item = String>) -> Result<Option<Options>, String> {
    let mut options = Options {
        flash_path: simulator::default_flash_path(),
        link: Some(PathBuf::from(DEFAULT_LINK)),
        socketcand: Some(
            socketcand::DEFAULT_ADDRESS
                .parse()
                .expect("the default address parses"),
        ),
        socketcan: None,
        demo: Demo::Off,
        hci: None,
        swap_drive_addresses: false,
        reversed_drive: None,
        update_keys: Vec::new(),
    };
    let mut stay = false;
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--help" | "-h" => return Ok(None),
            "--link" => options.link = Some(args.next().ok_or("--link needs a path")?.into()),
            "--no-link" => options.link = None,
            "--socketcand" => {
                let address = args.next().ok_or("--socketcand needs ADDRESS:PORT")?;
                let address = address.parse().map_err(|_| {
                    format!("--socketcand {address:?}: not ADDRESS:PORT (e.g. 127.0.0.1:29536)")
                })?;
                options.socketcand = Some(address);
            }
            "--no-socketcand" => options.socketcand = None,
            "--socketcan" => {
                options.socketcan = Some(args.next().ok_or("--socketcan needs an interface name")?);
            }
            "--flash" => options.flash_path = args.next().ok_or("--flash needs a path")?.into(),
            "--demo" => options.demo = Demo::ThenQuit,
            "--stay" => stay = true,
            "--swap-drive-addresses" => options.swap_drive_addresses = true,
            "--reverse-drive" => {
                let slave = args.next().ok_or("--reverse-drive needs 1 or 2")?;
                options.reversed_drive = match slave.as_str() {
                    "1" => Some(1),
                    "2" => Some(2),
                    other => return Err(format!("--reverse-drive {other:?}: 1 or 2")),
                };
            }
            "--update-key" => {
                let path = args.next().ok_or("--update-key needs a file")?;
                let key = simulator::read_public_key(path.as_ref())?;
                options.update_keys.push(key);
            }
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
