//! The simulator's fault commands end to end, on the real binary and the wall clock: a
//! PC on socketcand drives the base while the console resets the controller
//! (`reboot`) or cuts a drive from the RS-485 line (`drive right silent on`), and the
//! console's `status` shows what the drives really do. With Bumble installed, a paired
//! gamepad on `--hci` comes back after a reboot (skipped without it, except in CI).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::sync::mpsc::{Receiver, channel};
use std::thread;
use std::time::{Duration, Instant};

use base_core::can::{Command as CanCommand, Mode, Report, Status, id};
use base_core::registers::{OPEN_PAIRING_WINDOW_KEY, Reg};
use virtual_robot::process::SimulatorProcess;
use virtual_robot::runtime::block_on_realtime;

// The Bumble gamepad peer of the BLE scenarios; this file uses part of it.
#[allow(dead_code)]
#[path = "ble/peer.rs"]
mod peer;

/// 500 mm/s on 142 mm wheels behind a 10:1 gear: 336 rpm at the motor.
const RPM_AT_500_MM_S: i32 = 336;

/// The motors as the simulated drives turn them.
#[derive(Debug, Clone, Copy)]
struct Motors {
    rpm: (i32, i32),
    /// Forward revolutions since the drives were powered.
    revolutions: (f64, f64),
}

impl Motors {
    /// The most either wheel travelled since `before`, in mm (142 mm wheels behind a
    /// 10:1 gear).
    fn travelled_mm_since(&self, before: &Motors) -> f64 {
        let mm = |revolutions: f64| revolutions.abs() / 10.0 * 2.0 * std::f64::consts::PI * 142.0;
        mm(self.revolutions.0 - before.revolutions.0)
            .max(mm(self.revolutions.1 - before.revolutions.1))
    }
}

/// A frame from the controller, with the moment the test read it.
struct Received {
    at: Instant,
    report: Report,
}

/// The simulator with its socketcand server on a free port, its console on stdin and
/// its stdout lines collected.
struct Simulator {
    process: SimulatorProcess,
    port: u16,
}

impl Simulator {
    fn start() -> Self {
        Self::start_with(&[])
    }

    fn start_with(extra_args: &[&str]) -> Self {
        let process = SimulatorProcess::launch(env!("CARGO_BIN_EXE_virtual-base-controller"))
            .args(extra_args)
            .start()
            .expect("the simulator starts");
        let port = process.socketcand().port();
        Self { process, port }
    }

    fn command(&mut self, line: &str) {
        self.process.console(line).unwrap();
    }

    /// Waits for a stdout line containing `text`.
    fn wait_for_line(&self, text: &str, timeout: Duration) -> Option<String> {
        self.process.wait_for_line(text, timeout)
    }

    /// The motors' speeds in rpm (left, right), as the simulated drives turn them now:
    /// from the console's `status`.
    fn motor_rpm(&mut self) -> (i32, i32) {
        self.command("status");
        self.read_motors().rpm
    }

    /// The motors as the next `status` the console prints shows them.
    fn read_motors(&self) -> Motors {
        let line = self
            .wait_for_line("motors L", Duration::from_secs(2))
            .expect("status prints the motors");
        // "... motors L 336 R 336 rpm  turned L 12.345 R 12.345 rev"
        let words: Vec<&str> = line.split_whitespace().collect();
        let after = |label: &str, side: usize| -> &str {
            let index = words.iter().position(|word| *word == label).unwrap();
            words[index + side]
        };
        Motors {
            rpm: (
                after("motors", 2).parse().unwrap(),
                after("motors", 4).parse().unwrap(),
            ),
            revolutions: (
                after("turned", 2).parse().unwrap(),
                after("turned", 4).parse().unwrap(),
            ),
        }
    }

    /// Polls the motors until both stand; how long that took, or `None` after `limit`.
    fn time_to_standstill(&mut self, since: Instant, limit: Duration) -> Option<Duration> {
        while since.elapsed() < limit {
            if self.motor_rpm() == (0, 0) {
                return Some(since.elapsed());
            }
            thread::sleep(Duration::from_millis(10));
        }
        None
    }
}

/// The robot PC on socketcand: sends commands, and a thread decodes every report.
struct Pc {
    stream: TcpStream,
    reports: Receiver<Received>,
}

impl Pc {
    fn connect(port: u16) -> Self {
        let mut stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        for (send, reply) in [
            (None, "< hi >"),
            (Some("< open can0 >"), "< ok >"),
            (Some("< rawmode >"), "< ok >"),
        ] {
            if let Some(send) = send {
                stream.write_all(send.as_bytes()).unwrap();
            }
            let mut buffer = vec![0; reply.len()];
            stream.read_exact(&mut buffer).unwrap();
            assert_eq!(String::from_utf8(buffer).unwrap(), reply);
        }
        stream.set_read_timeout(None).unwrap();
        let (sender, reports) = channel();
        let mut reader = BufReader::new(stream.try_clone().unwrap());
        thread::spawn(move || {
            let mut message = Vec::new();
            loop {
                message.clear();
                if reader.read_until(b'>', &mut message).unwrap_or(0) == 0 {
                    return;
                }
                // "< frame 0EE 12.345678 0102030405060708 >"
                let text = String::from_utf8_lossy(&message);
                let words: Vec<&str> = text.split_whitespace().collect();
                let ["<", "frame", frame_id, _time, rest @ ..] = words.as_slice() else {
                    continue;
                };
                let Ok(frame_id) = u16::from_str_radix(frame_id, 16) else {
                    continue;
                };
                let hex = match rest {
                    [">"] => "",
                    [data, ">"] => data,
                    _ => continue,
                };
                let data: Vec<u8> = (0..hex.len() / 2)
                    .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
                    .collect();
                if let Ok(Some(report)) = Report::decode(frame_id, &data) {
                    let received = Received {
                        at: Instant::now(),
                        report,
                    };
                    if sender.send(received).is_err() {
                        return;
                    }
                }
            }
        });
        Self { stream, reports }
    }

    fn command(&mut self, command: CanCommand) {
        let frame = command.encode();
        self.send(frame.id(), frame.data());
    }

    fn send(&mut self, frame_id: u16, data: &[u8]) {
        let bytes: Vec<String> = data.iter().map(|byte| format!("{byte:x}")).collect();
        let message = format!("< send {frame_id:03X} {} {} >", data.len(), bytes.join(" "));
        self.stream.write_all(message.as_bytes()).unwrap();
    }

    /// The enable (with refresh) and a velocity, as the PC sends them every 50 ms.
    fn drive(&mut self, linear_mm_s: i16) {
        self.send(id::ENABLE, &[0x40, 0, 0, 0, 0, 0, 0, 0]);
        let [low, high] = linear_mm_s.to_le_bytes();
        self.send(id::VELOCITY, &[low, high, 0, 0, 0x03]);
    }

    /// Every report that arrived since the last call.
    fn take(&self) -> Vec<Received> {
        self.reports.try_iter().collect()
    }

    /// Waits for the first report that `pick` takes; the ones before are dropped.
    fn wait_for<T>(&self, timeout: Duration, pick: impl Fn(Received) -> Option<T>) -> Option<T> {
        let deadline = Instant::now() + timeout;
        loop {
            let received = self
                .reports
                .recv_timeout(deadline.saturating_duration_since(Instant::now()))
                .ok()?;
            if let Some(found) = pick(received) {
                return Some(found);
            }
        }
    }

    /// Waits for a status frame that satisfies `check`.
    fn wait_for_status(
        &self,
        timeout: Duration,
        check: impl Fn(&Status) -> bool,
    ) -> Option<(Instant, Status)> {
        self.wait_for(timeout, |received| match received.report {
            Report::Status(status) if check(&status) => Some((received.at, status)),
            _ => None,
        })
    }

    /// Waits for the next position report.
    fn next_position(&self, timeout: Duration) -> Option<(i32, i32)> {
        self.wait_for(timeout, |received| match received.report {
            Report::Position { x_mm, y_mm } => Some((x_mm, y_mm)),
            _ => None,
        })
    }
}

/// Sends enable + 500 mm/s every 50 ms until both motors turn at speed (the drives
/// boot and are set up first); returns the last position the controller reported.
fn drive_at_500(simulator: &mut Simulator, pc: &mut Pc) -> (i32, i32) {
    let deadline = Instant::now() + Duration::from_secs(15);
    let mut position = None;
    loop {
        assert!(Instant::now() < deadline, "the base never reached 500 mm/s");
        pc.drive(500);
        thread::sleep(Duration::from_millis(50));
        for received in pc.take() {
            if let Report::Position { x_mm, y_mm } = received.report {
                position = Some((x_mm, y_mm));
            }
        }
        let (left, right) = simulator.motor_rpm();
        if left > RPM_AT_500_MM_S - 6 && right > RPM_AT_500_MM_S - 6 {
            return position.expect("position frames arrive while driving");
        }
    }
}

/// Sends enable + `linear_mm_s` every 50 ms for `time`; returns the last x reported.
fn keep_driving(pc: &mut Pc, linear_mm_s: i16, time: Duration) -> i32 {
    let end = Instant::now() + time;
    let mut x = None;
    while Instant::now() < end {
        pc.drive(linear_mm_s);
        thread::sleep(Duration::from_millis(50));
        for received in pc.take() {
            if let Report::Position { x_mm, .. } = received.report {
                x = Some(x_mm);
            }
        }
    }
    x.expect("position frames arrive while driving")
}

#[test]
fn a_reboot_while_driving_stops_the_wheels_at_once_and_the_controller_answers_again() {
    let mut simulator = Simulator::start();
    let mut pc = Pc::connect(simulator.port);
    drive_at_500(&mut simulator, &mut pc);
    let x_before = keep_driving(&mut pc, 500, Duration::from_secs(1));
    assert!(x_before > 400, "x = {x_before} mm before the reboot");

    // The controller resets; the PC stops sending (it may not even notice). The
    // console reads the motors and resets the controller in one go.
    simulator.command("status\nreboot");
    let rebooted_at = Instant::now();
    let at_reboot = simulator.read_motors();
    assert!(
        at_reboot.rpm.0 > 300 && at_reboot.rpm.1 > 300,
        "{at_reboot:?}"
    );
    simulator
        .wait_for_line("reboot:", Duration::from_secs(2))
        .expect("the console confirms the reboot");
    let stood_after = simulator
        .time_to_standstill(rebooted_at, Duration::from_secs(1))
        .expect("both wheels stand within 1 s of the reboot");
    simulator.command("status");
    let stood = simulator.read_motors();
    // The new boot holds every answering drive at zero from its first frame (about
    // 30 mm from 500 mm/s). Left to themselves the drives stop on their own
    // communication timeout (300 ms: measured 149 mm); without the reset the enable
    // lapse stops them (measured 270 mm).
    let run_on = stood.travelled_mm_since(&at_reboot);
    eprintln!("wheels stood {stood_after:?} and {run_on:.0} mm after the reboot");
    assert!(run_on < 80.0, "run-on after the reboot: {run_on:.0} mm");
    thread::sleep(Duration::from_secs(1));
    simulator.command("status");
    let still = simulator.read_motors();
    assert_eq!(still.rpm, (0, 0), "the wheels stay still");
    assert!(
        still.travelled_mm_since(&stood) < 1.0,
        "{stood:?} → {still:?}"
    );

    // A fresh boot: it starts (the old controller was Active and never goes back to
    // Starting), then sets the drives up and stands by.
    pc.wait_for_status(Duration::from_secs(3), |status| {
        status.mode == Mode::Starting
    })
    .expect("the rebooted controller reports Starting");
    let (_, standby) = pc
        .wait_for_status(Duration::from_secs(10), |status| {
            status.mode == Mode::Standby
        })
        .expect("the rebooted controller sets the drives up and stands by");
    // No abnormal reset reported (the bit is latched, so it would still show): a
    // reset or brown-out looks like a power-on to the firmware.
    assert!(!standby.faults.watchdog_reset, "{standby:?}");
    // Its pose starts from zero, and the wheels that ran on before it took its first
    // sample are no motion.
    let (x_after, y_after) = pc
        .next_position(Duration::from_secs(2))
        .expect("position frames after the reboot");
    assert!(
        x_after.abs() < 50 && y_after.abs() < 50,
        "pose after the reboot: ({x_after}, {y_after}), before: x = {x_before}"
    );
    // It answers a register read (register 15, loop_end_delay, 50 ms).
    pc.take();
    pc.send(id::REGISTER_READ, &[1, 15]);
    let deadline = Instant::now() + Duration::from_secs(2);
    let reply = loop {
        let received = pc
            .reports
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .expect("a register reply after the reboot");
        if let Report::RegisterValue { .. } = received.report {
            break received.report;
        }
    };
    assert!(
        matches!(reply, Report::RegisterValue { value: 50, .. }),
        "{reply:?}"
    );
    // And it drives again on the PC's commands.
    let (x_start, _) = pc.next_position(Duration::from_secs(2)).unwrap();
    let (x_driven, _) = drive_at_500(&mut simulator, &mut pc);
    assert!(x_driven > x_start + 50, "{x_start} → {x_driven} mm");

    // `reboot watchdog` resets it as a watchdog bite does, and the status says so.
    simulator.command("reboot watchdog");
    let rebooted_at = Instant::now();
    simulator
        .time_to_standstill(rebooted_at, Duration::from_secs(1))
        .expect("both wheels stand within 1 s of the watchdog reset");
    // The new boot's first status frame (mode Starting) names the reset; the store,
    // written with the defaults at the first boot, is no fault.
    let (_, status) = pc
        .wait_for_status(Duration::from_secs(3), |status| {
            status.mode == Mode::Starting
        })
        .expect("the rebooted controller's first status frame");
    assert!(
        status.faults.watchdog_reset && !status.faults.flash,
        "the first status frame after the reset names it: {status:?}"
    );
}

#[test]
fn a_silent_drive_stops_the_base_and_a_confirm_recovers_once_it_answers() {
    let mut simulator = Simulator::start();
    let mut pc = Pc::connect(simulator.port);
    drive_at_500(&mut simulator, &mut pc);

    // The right drive's wire breaks while the PC goes on driving.
    simulator.command("drive right silent on");
    let cut_at = Instant::now();
    let mut reported = None;
    let mut stood = None;
    while cut_at.elapsed() < Duration::from_secs(3) && (reported.is_none() || stood.is_none()) {
        pc.drive(500);
        thread::sleep(Duration::from_millis(50));
        for received in pc.take() {
            if let Report::Status(status) = received.report
                && status.faults.right_drive_silent
                && reported.is_none()
            {
                reported = Some((received.at - cut_at, status));
            }
        }
        if stood.is_none() && simulator.motor_rpm() == (0, 0) {
            stood = Some(cut_at.elapsed());
        }
    }
    let (reported_after, status) = reported.expect("the status frame names the silent drive");
    assert_eq!(status.mode, Mode::Fault, "{status:?}");
    assert!(!status.faults.left_drive_silent, "{status:?}");
    // The left wheel is stopped by the controller, the unheard right one by its own
    // communication timeout (which the controller set up): the base stands.
    let stood = stood.expect("both wheels stand within 3 s of the cut");
    eprintln!("fault reported after {reported_after:?}, wheels stood after {stood:?}");
    assert!(
        stood < Duration::from_millis(1_500),
        "stood after {stood:?}"
    );

    // Reconnected, the drive answers again, but the fault holds the base until the
    // confirm press, whatever the PC sends.
    simulator.command("drive right silent off");
    let end = Instant::now() + Duration::from_secs(2);
    while Instant::now() < end {
        pc.drive(500);
        thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(
        simulator.motor_rpm(),
        (0, 0),
        "no motion before the confirm"
    );
    let (_, status) = pc
        .wait_for_status(Duration::from_secs(2), |_| true)
        .expect("status frames go on");
    assert_eq!(status.mode, Mode::Fault, "{status:?}");

    // The recovery (docs/behaviour.md, drive faults): a brief press of the front
    // button once the drive answers, then the PC's next commands drive the base.
    simulator.command("button press");
    let (_, status) = pc
        .wait_for_status(Duration::from_secs(5), |status| {
            status.mode == Mode::Standby
        })
        .expect("the confirm brings the base back to Standby");
    assert!(!status.faults.right_drive_silent, "{status:?}");
    drive_at_500(&mut simulator, &mut pc);
}

#[test]
fn after_a_reboot_the_paired_remote_reconnects_encrypted_with_the_bond_from_flash() {
    if !peer::bumble_available() {
        return;
    }
    let mut pad = peer::Peer::start();
    let virtual_robot::ble::HciSpec::Tcp(hci) = pad.hci.clone();
    let hci = format!("tcp:{hci}");
    let mut simulator = Simulator::start_with(&["--hci", &hci]);
    let mut pc = Pc::connect(simulator.port);
    // The bond goes to flash only once both drives confirmed their brakes, which the
    // setup does: pair a base that is up, as a user would.
    pc.wait_for_status(Duration::from_secs(5), |status| {
        status.mode != Mode::Starting
    })
    .expect("the drives are set up");
    block_on_realtime(async {
        pad.cmd("pad pad C1:11:22:33:44:55").await;
        pad.cmd("advertise pad").await;
    });
    pc.command(CanCommand::RegisterWrite {
        address: Reg::Command as u8,
        value: OPEN_PAIRING_WINDOW_KEY,
    });
    block_on_realtime(async {
        pad.wait_for(0, &["paired", "pad"], 20_000).await;
        pad.wait_for(0, &["subscribed", "pad"], 10_000).await;
    });
    pc.wait_for_status(Duration::from_secs(5), |status| {
        status.flags.remote_bonded && status.flags.remote_connected
    })
    .expect("the paired pad is connected");

    // The chip resets: its radio goes with it, the pad sees the link drop, and the new
    // boot's host connects to the HCI transport afresh.
    let mark = pad.mark();
    simulator.command("reboot");
    pc.wait_for_status(Duration::from_secs(3), |status| {
        status.mode == Mode::Starting
    })
    .expect("the rebooted controller reports Starting");
    block_on_realtime(async {
        pad.wait_for(mark, &["host-connected", "2"], 5_000).await;
        pad.wait_for(mark, &["disconnected", "pad"], 5_000).await;
        pad.cmd("advertise pad").await;
        pad.wait_for(mark, &["encrypted", "pad", "1"], 10_000).await;
        pad.wait_for(mark, &["subscribed", "pad"], 10_000).await;
    });
    assert!(
        pad.events_since(mark, &["pairing-started"]).is_empty(),
        "the bond came back from the flash file: no new pairing"
    );
    pc.wait_for_status(Duration::from_secs(3), |status| {
        status.flags.remote_bonded && status.flags.remote_connected
    })
    .expect("the pad is back after the reboot");
}
