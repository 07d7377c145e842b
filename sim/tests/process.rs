//! The launcher the end-to-end tests start the simulator binary with,
//! `virtual_robot::process`: it returns once the simulator is up, ends it on `quit`,
//! on drop or by killing it when it does not end in time, and leaves nothing behind in
//! the temporary directory; a simulator that cannot start is an error that gives the
//! simulator's own reason.

use std::io::Read;
use std::net::TcpStream;
use std::path::Path;
use std::time::Duration;

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use virtual_robot::process::SimulatorProcess;

const SIMULATOR: &str = env!("CARGO_BIN_EXE_virtual-base-controller");

fn running(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
}

#[test]
fn a_started_simulator_serves_its_link_and_socketcand_and_quit_removes_its_directory() {
    let simulator = SimulatorProcess::start(SIMULATOR).unwrap();
    let directory = simulator.directory().to_owned();
    assert!(directory.starts_with(std::env::temp_dir()), "{directory:?}");
    assert!(directory.join("flash.bin").exists());
    assert!(
        std::fs::read_link(simulator.link())
            .unwrap()
            .starts_with("/dev/pts"),
        "the link points at the serial port"
    );
    let mut client = TcpStream::connect(simulator.socketcand()).unwrap();
    client
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut greeting = [0; 6];
    client.read_exact(&mut greeting).unwrap();
    assert_eq!(
        &greeting, b"< hi >",
        "socketcand greets on the named address"
    );

    let pid = simulator.pid();
    let status = simulator.quit().unwrap();
    assert!(status.success(), "{status}");
    assert!(!running(pid));
    assert!(!directory.exists(), "the scratch directory is removed");
}

#[test]
fn dropping_a_running_simulator_ends_it_and_removes_its_directory() {
    let simulator = SimulatorProcess::start(SIMULATOR).unwrap();
    let directory = simulator.directory().to_owned();
    let pid = simulator.pid();
    drop(simulator);
    assert!(!running(pid), "the simulator ended");
    assert!(!directory.exists(), "the scratch directory is removed");
}

#[test]
fn a_simulator_that_does_not_end_in_time_is_killed() {
    let mut simulator = SimulatorProcess::start(SIMULATOR).unwrap();
    let pid = simulator.pid();
    // Stopped, it cannot act on quit.
    kill(Pid::from_raw(pid as i32), Signal::SIGSTOP).unwrap();
    simulator.console("quit").unwrap();
    let error = simulator
        .wait_for_exit(Duration::from_millis(500))
        .unwrap_err();
    assert_eq!(error.kind(), std::io::ErrorKind::TimedOut, "{error}");
    assert!(!running(pid), "the simulator was killed");
}

#[test]
fn a_simulator_that_refuses_its_options_is_an_error_with_its_reason() {
    let error = SimulatorProcess::launch(SIMULATOR)
        .args(["--socketcand", "nonsense"])
        .start()
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("--socketcand \"nonsense\": not ADDRESS:PORT"),
        "{error}"
    );
}

#[test]
fn without_link_or_socketcand_in_a_kept_directory_the_directory_stays() {
    let directory = tempfile::tempdir().unwrap();
    let simulator = SimulatorProcess::launch(SIMULATOR)
        .in_directory(directory.path())
        .no_link()
        .no_socketcand()
        .start()
        .unwrap();
    assert!(
        simulator
            .startup_lines()
            .iter()
            .all(|line| !line.starts_with("socketcand:") && !line.contains("linked from")),
        "{:?}",
        simulator.startup_lines()
    );
    assert!(simulator.quit().unwrap().success());
    assert!(
        directory.path().join("flash.bin").exists(),
        "the caller's directory stays"
    );
}
