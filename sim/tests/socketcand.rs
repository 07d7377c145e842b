//! The simulator's socketcand server end to end: python-can programs share the bus
//! through it, and a client that stops reading is dropped without holding up the bus
//! or the other clients.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::os::fd::AsFd;
use std::process::Command;
use std::thread;
use std::time::{Duration, Instant};

use virtual_robot::process::SimulatorProcess;

/// The simulator with its socketcand server on a free port; its stdout lines are
/// collected for the tests to look at.
fn start() -> SimulatorProcess {
    SimulatorProcess::start(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .expect("the simulator starts")
}

/// A socketcand client by hand: connects and goes through the handshake.
fn connect(port: u16) -> TcpStream {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut expect = |send: Option<&str>, reply: &str| {
        if let Some(send) = send {
            stream.write_all(send.as_bytes()).unwrap();
        }
        let mut buffer = vec![0; reply.len()];
        stream.read_exact(&mut buffer).unwrap();
        assert_eq!(String::from_utf8(buffer).unwrap(), reply);
    };
    expect(None, "< hi >");
    expect(Some("< open can0 >"), "< ok >");
    expect(Some("< rawmode >"), "< ok >");
    stream
}

#[test]
fn python_can_programs_share_the_bus_and_none_loses_a_frame_or_a_reply() {
    let simulator = start();
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/python/socketcand_clients.py"
    );
    let output = Command::new("python3")
        .arg(script)
        .args(["127.0.0.1", &simulator.socketcand().port().to_string(), "4"])
        .output()
        .expect("python3 runs (CI installs python-can, see .ci/run)");
    let text = String::from_utf8_lossy(&output.stdout);
    let errors = String::from_utf8_lossy(&output.stderr);
    assert!(
        output.status.success(),
        "{text}\n{errors}\n(needs python-can: pip install python-can)"
    );
    assert!(text.contains("OK: 4 python-can clients"), "{text}");
}

#[test]
fn a_client_that_stops_reading_is_dropped_and_the_others_get_every_frame() {
    let simulator = start();
    // The slow client reads nothing after its handshake, through a small receive
    // buffer so that its backlog reaches the server's queue soon.
    let slow = connect(simulator.socketcand().port());
    nix::sys::socket::setsockopt(&slow.as_fd(), nix::sys::socket::sockopt::RcvBuf, &2048).unwrap();
    let mut sender = connect(simulator.socketcand().port());
    let mut listener = connect(simulator.socketcand().port());
    // Frames start flowing a moment after the handshake.
    thread::sleep(Duration::from_millis(200));

    const FRAMES: usize = 20_000;
    let counter = thread::spawn(move || {
        let mut reader = BufReader::new(listener.try_clone().unwrap());
        let mut seen = 0;
        let mut next = 0;
        let mut message = Vec::new();
        while seen < FRAMES {
            message.clear();
            if reader.read_until(b'>', &mut message).unwrap_or(0) == 0 {
                break;
            }
            let text = String::from_utf8_lossy(&message);
            if let Some(rest) = text.trim().strip_prefix("< frame 7F0 ") {
                // "SECS.USECS DATA >": the data is the frame's number, big-endian.
                let data = rest.split_whitespace().nth(1).unwrap();
                let number = usize::from_str_radix(data, 16).unwrap();
                assert_eq!(number, next, "frames arrive in order, none missing");
                next += 1;
                seen += 1;
            }
        }
        listener.write_all(b"< send 004 2 1 f >").unwrap();
        (seen, reader)
    });
    // About the most a 500 kbit/s bus carries: 40 frames every 5 ms.
    for chunk in (0..FRAMES).collect::<Vec<_>>().chunks(40) {
        let mut burst = String::new();
        for &number in chunk {
            let [high, low] = (number as u16).to_be_bytes();
            burst.push_str(&format!("< send 7F0 2 {high:x} {low:x} >"));
        }
        sender.write_all(burst.as_bytes()).unwrap();
        thread::sleep(Duration::from_millis(5));
    }
    let (seen, mut reader) = counter.join().unwrap();
    assert_eq!(seen, FRAMES, "the listening client got every frame");
    // And the bus still answers it: register 15's reply.
    let mut message = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        assert!(Instant::now() < deadline, "no register reply");
        message.clear();
        reader.read_until(b'>', &mut message).unwrap();
        let text = String::from_utf8_lossy(&message);
        if text.contains("< frame 004 ") {
            // The value 50, then the address 15 and tag 0 (the request had none).
            assert!(text.trim().ends_with(" 0000320F0000 >"), "{text}");
            break;
        }
    }
    let dropped = simulator
        .wait_for_line("dropped", Duration::from_secs(5))
        .expect("the simulator logs the slow client's drop");
    assert!(dropped.contains("client 1"), "{dropped}");
    drop(slow);
}
