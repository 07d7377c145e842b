//! The simulator binary end to end: a PC opens its SLCAN serial port, drives the robot
//! over it and reads the odometry back; registers written over CAN survive a restart.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc::{Receiver, channel};
use std::thread;
use std::time::{Duration, Instant};

use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use virtual_robot::process::SimulatorProcess;

const SIMULATOR: &str = env!("CARGO_BIN_EXE_virtual-base-controller");

/// The simulator in a scratch directory of its own.
fn start() -> SimulatorProcess {
    SimulatorProcess::start(SIMULATOR).expect("the simulator starts")
}

/// The simulator with its flash and link in `directory`, which outlives it.
fn start_in(directory: &Path) -> SimulatorProcess {
    SimulatorProcess::launch(SIMULATOR)
        .in_directory(directory)
        .start()
        .expect("the simulator starts")
}

/// Ends the simulator with `quit`; it ends cleanly.
fn quit(simulator: SimulatorProcess) {
    let status = simulator.quit().unwrap();
    assert!(status.success(), "{status}");
}

/// Opens the simulator's port as a PC program does (raw mode).
fn open_raw(simulator: &SimulatorProcess) -> File {
    let port = File::options()
        .read(true)
        .write(true)
        .open(simulator.link())
        .expect("the serial port opens");
    let mut termios = tcgetattr(&port).unwrap();
    cfmakeraw(&mut termios);
    tcsetattr(&port, SetArg::TCSANOW, &termios).unwrap();
    port
}

/// Opens the simulator's port as a PC program does and starts reading its lines.
fn connect(simulator: &SimulatorProcess) -> (File, Receiver<String>) {
    let port = open_raw(simulator);
    let mut reader = port.try_clone().unwrap();
    let (sender, lines) = channel();
    thread::spawn(move || {
        let mut line = String::new();
        let mut byte = [0];
        while reader.read_exact(&mut byte).is_ok() {
            match byte[0] {
                b'\r' | b'\x07' => {
                    line.push(char::from(byte[0]));
                    if sender.send(std::mem::take(&mut line)).is_err() {
                        return;
                    }
                }
                other => line.push(char::from(other)),
            }
        }
    });
    (port, lines)
}

/// Sends SLCAN lines, each with its CR.
fn send(port: &mut File, lines: &[&str]) {
    for line in lines {
        port.write_all(format!("{line}\r").as_bytes()).unwrap();
    }
}

/// The x of a position frame line `t0EC8XXXXXXXXYYYYYYYY\r`.
fn position_x(line: &str) -> Option<i32> {
    let data = line.strip_prefix("t0EC8")?.get(..8)?;
    let bytes: Vec<u8> = (0..4)
        .map(|i| u8::from_str_radix(&data[2 * i..2 * i + 2], 16).unwrap())
        .collect();
    Some(i32::from_le_bytes(bytes.try_into().unwrap()))
}

#[test]
fn a_pc_on_the_slcan_port_drives_the_robot_and_sees_the_position_grow() {
    let simulator = start();
    let (mut port, lines) = connect(&simulator);
    send(&mut port, &["C", "S6", "O"]);
    let opened: Vec<String> = (0..3)
        .map(|_| lines.recv_timeout(Duration::from_secs(5)).unwrap())
        .collect();
    assert_eq!(opened, ["\r", "\r", "\r"]);

    // Enable + 300 mm/s every 50 ms until the base has gone 150 mm (about 1.5 s: the
    // drives boot in the first second). The deadline is far off because on a busy
    // machine this thread's gaps can outlast the enable timeout, which stops the base
    // as it should; the position must still grow.
    let mut positions = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while positions.last().is_none_or(|&x| x <= 150) {
        assert!(
            Instant::now() < deadline,
            "x = {:?} mm after a minute of driving at 300 mm/s",
            positions.last()
        );
        send(&mut port, &["t2E484000000000000000", "t0C852C01000003"]);
        thread::sleep(Duration::from_millis(50));
        positions.extend(lines.try_iter().filter_map(|line| position_x(&line)));
    }
    assert!(positions.len() > 20, "{} position frames", positions.len());
    quit(simulator);
}

#[test]
fn a_closed_channel_refuses_frames_and_malformed_lines_get_bel() {
    let simulator = start();
    let (mut port, lines) = connect(&simulator);
    send(&mut port, &["t0050", "t0EC9", "S6", "O", "t0050"]);
    let replies: Vec<String> = (0..5)
        .map(|_| lines.recv_timeout(Duration::from_secs(5)).unwrap())
        .collect();
    assert_eq!(replies, ["\x07", "\x07", "\r", "\r", "z\r"]);
    quit(simulator);
}

#[test]
fn a_register_written_over_slcan_is_still_there_after_a_restart() {
    let directory = tempfile::tempdir().unwrap();
    let simulator = start_in(directory.path());
    let (mut port, lines) = connect(&simulator);
    // Register 9, sec_lin_vel, to 321 mm/s (0x0141).
    send(&mut port, &["O", "t0033090141"]);
    // The store writes the flash once both drives confirmed their brakes (the virtual
    // drives answer 1 s after power-on), then within a moment; give it two seconds.
    thread::sleep(Duration::from_secs(2));
    drop(lines);
    drop(port);
    quit(simulator);

    let simulator = start_in(directory.path());
    let (mut port, lines) = connect(&simulator);
    send(&mut port, &["O", "t00420109"]);
    let deadline = Instant::now() + Duration::from_secs(5);
    let reply = loop {
        let line = lines
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .expect("a register reply arrives");
        if line.starts_with("t0046") {
            break line;
        }
    };
    // 00 value MSB LSB, then the address read (9) and the request's tag (none: 0).
    assert_eq!(reply, "t0046000141090000\r");
    quit(simulator);
}

#[test]
fn a_pc_that_leaves_without_closing_the_channel_leaves_nothing_queued_for_the_next() {
    let simulator = start();
    // A program that opens the channel, reads until the controller's frames flow, then
    // stops reading for a second and dies without sending C: the frames of that second
    // wait unread in the port when it goes.
    let mut port = open_raw(&simulator);
    send(&mut port, &["C", "S6", "O"]);
    let mut received = Vec::new();
    let mut byte = [0];
    while !received.windows(2).any(|pair| pair == b"\rt") {
        port.read_exact(&mut byte).unwrap();
        received.push(byte[0]);
    }
    thread::sleep(Duration::from_secs(1));
    drop(port);
    // Long enough for the controller to send dozens more frames.
    thread::sleep(Duration::from_secs(1));
    let (mut port, lines) = connect(&simulator);
    send(&mut port, &["V"]);
    assert_eq!(
        lines.recv_timeout(Duration::from_secs(2)).unwrap(),
        "V0101\r",
        "the next program's first line is the answer to its own command"
    );
    assert!(lines.recv_timeout(Duration::from_millis(500)).is_err());
    quit(simulator);
}

#[test]
fn a_second_simulator_on_the_same_link_is_refused_and_names_the_first() {
    let first = start();
    let second = Command::new(SIMULATOR)
        .arg("--link")
        .arg(first.link())
        .arg("--flash")
        .arg(first.directory().join("flash2.bin"))
        .args(["--no-socketcand"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!second.status.success());
    let error = String::from_utf8_lossy(&second.stderr);
    assert!(
        error.contains(&format!("another simulator (pid {})", first.pid())),
        "{error}"
    );
    // The first one's link still points at its port.
    assert!(
        std::fs::read_link(first.link())
            .unwrap()
            .starts_with("/dev/pts")
    );
    quit(first);
}

#[test]
fn sigterm_and_ctrl_c_remove_the_link_and_its_lock() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    for signal in [Signal::SIGTERM, Signal::SIGINT] {
        let mut simulator = start();
        let lock = simulator.directory().join("slcan.lock");
        assert!(lock.exists());
        kill(Pid::from_raw(simulator.pid() as i32), signal).unwrap();
        let status = simulator.wait_for_exit(Duration::from_secs(10)).unwrap();
        assert!(status.success(), "{signal}: {status}");
        assert!(
            std::fs::symlink_metadata(simulator.link()).is_err(),
            "{signal}: the link is gone"
        );
        assert!(!lock.exists(), "{signal}: the lock file is gone");
    }
}
