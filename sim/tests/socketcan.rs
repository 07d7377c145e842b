//! `--socketcan IFACE`: the simulator as a node on a Linux CAN interface. The round
//! trip needs a kernel with CAN sockets and a `vcan0` that is up; where either is
//! missing that test says so and skips. The refusal test runs everywhere.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use embedded_can::Frame as _;
use socketcan::{CanFrame, CanSocket, Socket, StandardId};
use virtual_robot::process::SimulatorProcess;
use virtual_robot::simulator::socketcan::kernel_has_can;

#[test]
fn an_interface_that_cannot_be_joined_is_refused_with_the_reason() {
    // The simulator creates its flash file before it joins the interface.
    let directory = tempfile::tempdir().unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .args(["--no-link", "--no-socketcand", "--socketcan", "nosuchcan9"])
        .arg("--flash")
        .arg(directory.path().join("flash.bin"))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!output.status.success());
    let error = String::from_utf8_lossy(&output.stderr);
    let expected = match kernel_has_can() {
        Err(_) => "this kernel has no CAN sockets (AF_CAN",
        Ok(()) => "no interface nosuchcan9",
    };
    assert!(error.contains("--socketcan nosuchcan9: "), "{error}");
    assert!(error.contains(expected), "{error}");
}

#[test]
fn a_program_on_vcan0_reads_a_register_of_the_simulated_controller() {
    if let Err(reason) = kernel_has_can() {
        println!("skipped: {reason}");
        return;
    }
    let Ok(socket) = CanSocket::open("vcan0") else {
        println!(
            "skipped: no vcan0 that is up (as root: ip link add vcan0 type vcan; \
             ip link set vcan0 up)"
        );
        return;
    };
    let simulator = SimulatorProcess::launch(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .no_link()
        .no_socketcand()
        .args(["--socketcan", "vcan0"])
        .start()
        .expect("the simulator starts on vcan0");
    assert!(
        simulator
            .startup_lines()
            .iter()
            .any(|line| line.starts_with("SocketCAN:")),
        "{:?}",
        simulator.startup_lines()
    );
    let request = CanFrame::new(StandardId::new(0x004).unwrap(), &[0x01, 15]).unwrap();
    socket.write_frame(&request).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    let reply = loop {
        assert!(Instant::now() < deadline, "no register reply on vcan0");
        let Ok(frame) = socket.read_frame_timeout(Duration::from_millis(500)) else {
            continue;
        };
        if frame.id() == embedded_can::Id::Standard(StandardId::new(0x004).unwrap())
            && frame.data().first() == Some(&0x00)
        {
            break frame;
        }
    };
    assert_eq!(reply.data(), [0x00, 0x00, 50], "loop_end_delay is 50 ms");
    drop(simulator);
}
