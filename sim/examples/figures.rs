//! The figures the README quotes, measured on the virtual robot in one run (virtual
//! time; Modbus bytes timed at the configured baud rate, 8E1; CAN frames at 500 kbit/s
//! with the stuff bits the virtual bus counts):
//!
//! - latency: CAN velocity frame → both drives have the new speed (the base is
//!   driving), e-stop edge → zero speed on the wire, pad report → both drives have the
//!   new speed and dead-man release → zero on the wire, each at many phases of the
//!   control cycle (`virtual_robot::latency`);
//! - the periods of the feedback frames while driving, and their jitter;
//! - the Modbus bytes of a control cycle and how busy they keep the RS-485 line, at
//!   115200 and at 230400 baud;
//! - CAN frames per second by ID and the bus load, in standby and while driving;
//! - the fail-safe figures: reset run-on, a failing group frame, a stuck encoder, a
//!   wheel turning against its command;
//! - a firmware update's transfer of 600 KB over socketcand and over SLCAN, against the
//!   simulator binary on the wall clock (build it first: `cargo build -p virtual-robot`).
//!
//! Run with `cargo run -p virtual-robot --example figures`; `-- update` prints only the
//! update's figures.

use std::collections::{BTreeMap, BTreeSet};

use base_core::can::{Command, id};
use base_core::registers::Reg;
use embassy_futures::join::join;
use embassy_time::{Duration, Instant};
use virtual_robot::can::{BITRATE_BPS, SentFrame};
use virtual_robot::drives::{DrivesConfig, DrivesHandle, FeedbackFault, FrameRecord, Reversal};
use virtual_robot::latency::{PAD_REPORT_INTERVAL_MS, can_latencies, pad_latencies};
use virtual_robot::robot::{Pc, VirtualRobot, wait_ms};

/// Until the drives are set up and the sensors have a first reading.
const BOOT_MS: u64 = 1_500;
/// Standby: the controller reports, the PC sends nothing.
const STANDBY_MS: u64 = 10_000;
/// Driving before the measurement starts, so the base is at speed.
const WARM_UP_MS: u64 = 2_000;
/// Steady driving: a dozen periods of the slowest feedback frame (`volt_time`, 5 s).
const DRIVING_MS: u64 = 60_000;
/// The robot PC's velocity period; it sends the enable with every second velocity.
const VELOCITY_PERIOD_MS: u64 = 50;
const DRIVING_SPEED_MM_S: i16 = 300;
/// The faster line the drives support, for the headroom comparison.
const FAST_BAUD: u32 = 230_400;
/// Modbus RTU ends a frame with 3.5 character times of silence; the next frame may
/// start only after it.
const FRAME_GAP_CHARS: f64 = 3.5;

fn main() {
    // `figures update`: only the update's figures, which take a minute on the wall clock.
    if std::env::args().nth(1).as_deref() == Some("update") {
        report_update();
        return;
    }
    let (velocity, estop) = can_latencies(&VirtualRobot::new());
    report_latency(
        "CAN velocity frame → both drives have the new speed",
        &velocity,
    );
    report_latency("e-stop edge → zero speed on the wire", &estop);
    let (report, release) = pad_latencies(&VirtualRobot::new());
    report_latency(
        &format!(
            "pad report → both drives have the new speed (the pad reports every {PAD_REPORT_INTERVAL_MS} ms)"
        ),
        &report,
    );
    report_latency("dead-man release → zero speed on the wire", &release);
    let (velocity, estop) = can_latencies(&robot_at_baud(FAST_BAUD));
    report_latency(
        "at 230400 baud: CAN velocity frame → both drives have the new speed",
        &velocity,
    );
    report_latency(
        "at 230400 baud: e-stop edge → zero speed on the wire",
        &estop,
    );
    report_command_limit(DrivesConfig::commissioned().baud);
    report_command_limit(FAST_BAUD);
    report_emergency_zero_limit(DrivesConfig::commissioned().baud);
    report_emergency_zero_limit(FAST_BAUD);

    println!();
    report_fail_safe();
    report_stuck_encoder();
    report_wrong_direction();

    let recording = record_buses(&VirtualRobot::new());
    println!();
    report_feedback_periods(&recording);
    println!();
    let cycle_ms = f64::from(Reg::LoopEndDelay.info().default);
    report_line(&recording, cycle_ms);
    report_line(&record_buses(&robot_at_baud(FAST_BAUD)), cycle_ms);
    println!();
    report_can(&recording);
    println!();
    report_update();
}

/// The image the update figures move: 600 KB, about a C3 firmware.
const UPDATE_IMAGE_BYTES: usize = 600_000;

/// What checking a signed 600 KB image costs on this machine: the bootloader's checks
/// with the SHA-256 over every byte (made window by window while the image arrives),
/// and the ed25519 verification FINISH adds for a build that trusts a key (the
/// median of 50).
fn report_signature_check() {
    use base_core::update::image::WholeImageCheck;
    use base_core::update::signature::{self, Trust};
    let secret = [7; 32];
    let image = virtual_robot::app_flash::sim_image("9.9.9", UPDATE_IMAGE_BYTES - 400);
    let (len, block) = signature::sign(&image, &secret, 0).expect("a valid image");
    let mut signed = image[..len].to_vec();
    signed.extend_from_slice(&block.to_bytes());
    let keys = [signature::public_key(&secret)];
    let started = std::time::Instant::now();
    let mut whole = WholeImageCheck::new();
    signed.chunks(4096).for_each(|window| whole.feed(window));
    whole.finish().expect("the image passes");
    let image_check = started.elapsed();
    let digest = *whole.digest().expect("checked");
    let block = signature::block_after(&whole);
    let mut verifications: Vec<std::time::Duration> = (0..50)
        .map(|_| {
            let started = std::time::Instant::now();
            signature::check(Trust::Keys(&keys), block.as_ref(), &digest, 0, 0)
                .expect("signed by the key");
            started.elapsed()
        })
        .collect();
    verifications.sort();
    println!(
        "signature check of a 600 KB image on the virtual robot: {:.1} ms \
         (SHA-256 and the bootloader's checks {:.1} ms, over the transfer; \
         the ed25519 verification at FINISH {:.2} ms)",
        (image_check + verifications[25]).as_secs_f64() * 1e3,
        image_check.as_secs_f64() * 1e3,
        verifications[25].as_secs_f64() * 1e3,
    );
}

/// How long the transfer of a 600 KB image takes (BEGIN to the last window written,
/// then ABORT: the simulator keeps its firmware), over socketcand and over SLCAN, and
/// what share of the bus limit that is: 7 image bytes per frame at the frame rate of
/// the virtual bus (8-byte frames with worst-case stuffing at 500 kbit/s). Every frame
/// takes its bus time both ways, and the flash its typical erase and program times,
/// stalling the controller as the chip does.
fn report_update() {
    report_signature_check();
    let Some(binary) = std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.parent()?.join("virtual-base-controller")))
        .filter(|path| path.exists())
    else {
        println!(
            "firmware update: not measured (build the simulator: cargo build -p virtual-robot)"
        );
        return;
    };
    let simulator = match virtual_robot::process::SimulatorProcess::start(&binary) {
        Ok(simulator) => simulator,
        Err(error) => {
            println!("firmware update: not measured ({error})");
            return;
        }
    };
    let _ = simulator.wait_for_line("boot: firmware", std::time::Duration::from_secs(10));
    let image = virtual_robot::app_flash::sim_image("9.9.9", UPDATE_IMAGE_BYTES - 400);
    let data_frame =
        virtual_robot::can::SimFrame::standard(id::UPDATE_DATA, &[0; 8]).expect("8 bytes");
    let frame_s = virtual_robot::can::frame_time(&data_frame).as_micros() as f64 / 1e6;
    let limit_s = image.len().div_ceil(7) as f64 * frame_s;
    let open = |slcan: bool| -> Result<Box<dyn basectl::bus::Bus>, String> {
        let bus: Box<dyn basectl::bus::Bus> = if slcan {
            let link = simulator.link().to_string_lossy().into_owned();
            Box::new(basectl::bus::SlcanPort::open(&link, BITRATE_BPS).map_err(|e| e.to_string())?)
        } else {
            let address = simulator.socketcand().to_string();
            Box::new(basectl::bus::SocketcandBus::open(&address).map_err(|e| e.to_string())?)
        };
        Ok(bus)
    };
    // One connection at a time, each run its own session: a connection not read while
    // the other transfers fills with the other's frames.
    for (name, slcan, session) in [("SLCAN", true, 41), ("socketcand", false, 42)] {
        let measured =
            open(slcan).and_then(|mut bus| transfer_seconds(bus.as_mut(), session, &image));
        match measured {
            Ok(seconds) => println!(
                "firmware update, 600 KB over {name}: {seconds:.1} s ({:.0} % of the bus limit of \
                 {limit_s:.1} s)",
                100.0 * limit_s / seconds
            ),
            Err(error) => println!("firmware update over {name}: not measured ({error})"),
        }
    }
    let address = simulator.socketcand().to_string();
    let listen = |until: &dyn Fn() -> bool| -> Result<Vec<f64>, String> {
        let mut bus = basectl::bus::SocketcandBus::open(&address).map_err(|e| e.to_string())?;
        position_periods_ms(&mut bus, until)
    };
    let started = std::time::Instant::now();
    let at_rest = listen(&|| started.elapsed() > std::time::Duration::from_secs(10));
    let transferring = std::sync::atomic::AtomicBool::new(true);
    let during = std::thread::scope(|scope| {
        let transfer = scope.spawn(|| {
            let result = basectl::bus::SocketcandBus::open(&address)
                .map_err(|e| e.to_string())
                .and_then(|mut bus| transfer_seconds(&mut bus, 43, &image));
            transferring.store(false, std::sync::atomic::Ordering::Relaxed);
            result
        });
        let periods = listen(&|| !transferring.load(std::sync::atomic::Ordering::Relaxed));
        transfer
            .join()
            .map_err(|_| "the transfer panicked".to_string())
            .and_then(|transfer| transfer)
            .and(periods)
    });
    match (at_rest, during) {
        (Ok(at_rest), Ok(during)) => {
            for (label, periods) in [("at rest", &at_rest), ("during an update", &during)] {
                let mean = periods.iter().sum::<f64>() / periods.len().max(1) as f64;
                let max = periods.iter().copied().fold(0.0, f64::max);
                println!(
                    "control cycle {label} (0x0EC position frame period at the PC, {} \
                     periods): mean {mean:.1} ms, max {max:.1} ms",
                    periods.len()
                );
            }
        }
        (Err(error), _) | (_, Err(error)) => {
            println!("control cycle during an update: not measured ({error})")
        }
    }
}

/// The periods between the position frames a PC receives until `done` says so.
fn position_periods_ms(
    bus: &mut dyn basectl::bus::Bus,
    done: &dyn Fn() -> bool,
) -> Result<Vec<f64>, String> {
    let mut last: Option<std::time::Instant> = None;
    let mut periods = Vec::new();
    while !done() {
        let Some(frame) = bus
            .receive(std::time::Duration::from_millis(100))
            .map_err(|error| error.to_string())?
        else {
            continue;
        };
        if frame.id() != id::POSITION {
            continue;
        }
        let now = std::time::Instant::now();
        if let Some(last) = last {
            periods.push((now - last).as_secs_f64() * 1000.0);
        }
        last = Some(now);
    }
    Ok(periods)
}

/// BEGIN, the digest, every window, then ABORT: the seconds from BEGIN to the last
/// window written.
fn transfer_seconds(
    bus: &mut dyn basectl::bus::Bus,
    session: u8,
    image: &[u8],
) -> Result<f64, String> {
    use base_core::can::update::{BeginFlags, UpdateCommand};
    use base_core::update::session::DIGEST_PARTS;
    use sha2::Digest;
    // BEGIN needs the base standing braked: wait for Standby after the boot.
    let mut base = basectl::base::Base::new(bus, std::time::Duration::from_millis(500));
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(15);
    while !base
        .next_status()
        .is_ok_and(|status| status.mode == base_core::can::Mode::Standby)
    {
        if std::time::Instant::now() > deadline {
            return Err("the base did not reach Standby".into());
        }
    }
    let started = std::time::Instant::now();
    let send = |bus: &mut dyn basectl::bus::Bus, command: UpdateCommand| {
        bus.send(&command.encode())
            .map_err(|error| error.to_string())
    };
    send(
        bus,
        UpdateCommand::Begin {
            session,
            size: image.len() as u32,
            flags: BeginFlags::default(),
        },
    )?;
    let digest = sha2::Sha256::digest(image);
    for part in 0..DIGEST_PARTS {
        let at = usize::from(part) * 4;
        let bytes = [digest[at], digest[at + 1], digest[at + 2], digest[at + 3]];
        send(
            bus,
            UpdateCommand::Digest {
                session,
                part,
                bytes,
            },
        )?;
    }
    let stats = basectl::firmware::transfer(bus, session, image, |_, _, _| {})
        .map_err(|error| error.to_string())?;
    let seconds = started.elapsed().as_secs_f64();
    send(bus, UpdateCommand::Abort { session })?;
    if stats.retries > 0 {
        println!("  ({} windows sent again)", stats.retries);
    }
    Ok(seconds)
}

/// A robot whose controller and drives both talk at `baud`.
fn robot_at_baud(baud: u32) -> VirtualRobot {
    let mut robot = VirtualRobot::with_drives(DrivesConfig {
        baud,
        ..DrivesConfig::commissioned()
    });
    robot.settings.drives.line.baud = baud;
    robot
}

/// The fail-safe figures of the drive link: how far the wheels run on after a
/// controller reset at 500 mm/s (with both drives answering, and with the right drive
/// silent from the reset on), and how long a group frame may fail before both drives
/// get zero by unicast.
fn report_fail_safe() {
    let wheel_mm = |revolutions: f64| revolutions / 10.0 * 2.0 * std::f64::consts::PI * 142.0;
    // The reset falls at ten moments 5 ms apart across one 50 ms control cycle: the
    // run-on depends on what the line carries at that moment.
    let reset_run_on_after_boot = |silent: Option<u8>, phase_ms: u64, boot_ms: u64| {
        let mut robot = VirtualRobot::new();
        robot.boot_time = Duration::from_millis(boot_ms);
        robot.run(async |pc| {
            wait_ms(BOOT_MS).await;
            pc.drive(500, 0, 2_000).await;
            wait_ms(phase_ms).await;
        });
        if let Some(slave) = silent {
            robot.drives.set_silent(slave, true);
        }
        let before = [1, 2].map(|slave| robot.drives.drive(slave).forward_revolutions());
        robot.run(async |_pc| wait_ms(3_000).await);
        // [answering drives (the most of them), the silent drive]
        let mut run_on = [0.0_f64; 2];
        for (slave, before) in [1, 2].into_iter().zip(before) {
            let mm = wheel_mm(robot.drives.drive(slave).forward_revolutions() - before).abs();
            let index = usize::from(Some(slave) == silent);
            run_on[index] = run_on[index].max(mm);
        }
        run_on
    };
    let reset_run_on =
        |silent: Option<u8>, phase_ms: u64| reset_run_on_after_boot(silent, phase_ms, 0);
    let phases = || (0..10).map(|k| k * 5);
    let range = |values: Vec<f64>| {
        let min = values.iter().copied().fold(f64::INFINITY, f64::min);
        let max = values.iter().copied().fold(0.0, f64::max);
        (min, max)
    };
    let (min, max) = range(phases().map(|phase| reset_run_on(None, phase)[0]).collect());
    println!(
        "reset run-on, both drives answering: {max:.0} mm (worst of 10 reset moments; best {min:.0} mm)"
    );
    let silent_runs: Vec<[f64; 2]> = phases().map(|phase| reset_run_on(Some(2), phase)).collect();
    let (min, max) = range(silent_runs.iter().map(|run| run[0]).collect());
    let (_, silent) = range(silent_runs.iter().map(|run| run[1]).collect());
    println!(
        "reset run-on, one drive silent: {max:.0} mm (worst of 10 reset moments; best {min:.0} mm)"
    );
    println!("  (the silent drive itself, stopped by its communication timeout: {silent:.0} mm)");
    // The same with a chip's boot time: nothing on the line for 300 ms.
    let (_, max) = range(
        phases()
            .map(|phase| reset_run_on_after_boot(None, phase, 300)[0])
            .collect(),
    );
    println!("reset run-on with a 300 ms boot, both drives answering: {max:.0} mm");
    let runs: Vec<[f64; 2]> = phases()
        .map(|phase| reset_run_on_after_boot(Some(2), phase, 300))
        .collect();
    let (_, max) = range(runs.iter().map(|run| run[0].max(run[1])).collect());
    println!("reset run-on with a 300 ms boot, one drive silent: {max:.0} mm");

    // The link cannot hear the drives: from 500 mm/s, at five moments of a cycle.
    let stopped_after = |fault: &dyn Fn(&VirtualRobot), phase_ms: u64| {
        let robot = VirtualRobot::new();
        robot.run(async |pc| {
            wait_ms(BOOT_MS).await;
            pc.drive(500, 0, 2_000).await;
            wait_ms(phase_ms).await;
            let before = [1, 2].map(|slave| robot.drives.drive(slave).forward_revolutions());
            fault(&robot);
            pc.drive(500, 0, 3_000).await;
            [1, 2]
                .into_iter()
                .zip(before)
                .map(|(slave, before)| {
                    wheel_mm(robot.drives.drive(slave).forward_revolutions() - before).abs()
                })
                .fold(0.0_f64, f64::max)
        })
    };
    let worst = |fault: &dyn Fn(&VirtualRobot)| {
        (0..5)
            .map(|k| stopped_after(fault, k * 10))
            .fold(0.0_f64, f64::max)
    };
    println!(
        "replies lost while driving -> both wheels stopped: {:.0} mm",
        worst(&|robot| robot.drives.lose_replies(true))
    );
    println!(
        "a drive answering exceptions -> both wheels stopped: {:.0} mm",
        worst(&|robot| robot.drives.set_busy(1, true))
    );

    let robot = VirtualRobot::new();
    let zero_after = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(300, 0, 1_000).await;
        // Long frames fail (the group's command write), the short read and unicast
        // frames pass; the PC then changes its speed, which needs the write.
        robot.drives.fail_requests_longer_than(Some(40));
        pc.drive(300, 0, 300).await;
        let failing = Instant::now();
        pc.drive(200, 0, 1_000).await;
        let zero = [1, 2].map(|slave| {
            let drive = robot.drives.drive(slave);
            assert_eq!(drive.command.expect("commanded").speed_rpm, 0);
            drive.last_new_speed_at.expect("speed")
        });
        zero.into_iter().max().expect("two drives") - failing
    });
    println!(
        "group command write failing -> zero on the wire: {:.0} ms (from the first command that needs it)",
        ms(zero_after)
    );

    let control_gap = |writes: bool| {
        let robot = VirtualRobot::new();
        robot.flash.set_erase_stall(Duration::from_millis(400));
        robot.run(async |pc| {
            wait_ms(BOOT_MS).await;
            pc.drive(300, 0, 1_000).await;
            let from = Instant::now();
            // Register writes while driving, enough records for several page erases.
            for round in 0..2_000u16 {
                pc.enable();
                pc.velocity(300, 0);
                if writes {
                    pc.command(Command::RegisterWrite {
                        address: 11,
                        value: 300 + round % 2,
                    });
                }
                wait_ms(2).await;
            }
            let to = Instant::now();
            let cycles: Vec<Instant> = robot
                .drives
                .requests()
                .into_iter()
                .filter(|request| {
                    // The motion part of each cycle's feedback read.
                    request.bytes[..4] == [15, 0x03, 0, 0] && (from..to).contains(&request.at)
                })
                .map(|request| request.at)
                .collect();
            cycles
                .windows(2)
                .map(|pair| pair[1] - pair[0])
                .max()
                .expect("cycles")
        })
    };
    println!(
        "control latency while a 400 ms flash erase is pending: max {:.0} ms (without register writes: max {:.0} ms; the time between two control cycles while driving)",
        ms(control_gap(true)),
        ms(control_gap(false))
    );
}

/// How far the farther wheel rolls from `fault` on until both stand, while the PC asks
/// for 500 mm/s; with `driving_ms`, the fault comes after driving that long, else at
/// rest.
fn rolled_after(driving_ms: Option<u64>, fault: impl FnOnce(&DrivesHandle)) -> f64 {
    let wheel_mm = |revolutions: f64| revolutions / 10.0 * 2.0 * std::f64::consts::PI * 142.0;
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        if let Some(driving_ms) = driving_ms {
            pc.drive(500, 0, driving_ms).await;
        }
        let before = [1, 2].map(|slave| robot.drives.drive(slave).forward_revolutions());
        fault(&robot.drives);
        pc.drive(500, 0, 2_000).await;
        let stood = [1, 2]
            .iter()
            .all(|&slave| robot.drives.drive(slave).forward_rpm().abs() < 0.5);
        assert!(stood, "both wheels stopped");
        [1, 2]
            .into_iter()
            .zip(before)
            .map(|(slave, before)| {
                wheel_mm(robot.drives.drive(slave).forward_revolutions() - before).abs()
            })
            .fold(0.0, f64::max)
    })
}

/// The worst and the best of some distances.
fn worst_and_best(rolled: &[f64]) -> (f64, f64) {
    let worst = rolled.iter().copied().fold(0.0, f64::max);
    let best = rolled.iter().copied().fold(f64::INFINITY, f64::min);
    (worst, best)
}

/// The left encoder sticks at 500 mm/s (its counter stands, its speed stays true) at
/// ten moments 5 ms apart across a 50 ms feedback cycle, while the PC keeps asking for
/// 500 mm/s: how far the farther wheel rolls from the fault until both stand.
fn report_stuck_encoder() {
    let rolled: Vec<f64> = (0..10u64)
        .map(|k| {
            rolled_after(Some(2_000 + k * 5), |drives| {
                drives.set_feedback_fault(1, Some(FeedbackFault::StuckPosition))
            })
        })
        .collect();
    let (worst, best) = worst_and_best(&rolled);
    println!(
        "stuck encoder -> both wheels stopped: {worst:.0} mm (worst of 10 moments; best {best:.0} mm)"
    );
}

/// A drive whose direction parameter is at the other value: from rest the left drive
/// turns against its command as the PC asks for 500 mm/s; and at 500 mm/s the left
/// drive's reports turn round (position and speed against the command, the shaft
/// still as commanded) at ten moments 5 ms apart across a feedback cycle. How far the
/// farther wheel rolls until both stand.
fn report_wrong_direction() {
    let from_rest = rolled_after(None, |drives| {
        drives.set_reversed(1, Some(Reversal::Motion))
    });
    println!("a wheel turning against its command -> both wheels stopped:");
    println!("  from rest, the left drive reversed: {from_rest:.0} mm");
    let rolled: Vec<f64> = (0..10u64)
        .map(|k| {
            rolled_after(Some(2_000 + k * 5), |drives| {
                drives.set_reversed(1, Some(Reversal::Feedback))
            })
        })
        .collect();
    let (worst, best) = worst_and_best(&rolled);
    println!(
        "  at 500 mm/s, the left drive's reports turning round: {worst:.0} mm (worst of 10 moments; best {best:.0} mm)"
    );
}

/// The wire's limit for a new command: its write (FC 10h to the share group, both
/// drives' items) on the line, and the C3.5 after which the drives act on it.
fn report_command_limit(baud: u32) {
    let items = base_core::drives::reg::SHARE_WRITE_LIST.len();
    // Address, function, start, count, byte count; 4 bytes per item and drive; CRC.
    let bytes = 7 + 2 * 4 * items + 2;
    let char_ms = virtual_robot::runtime::char_time(baud, 11).as_micros() as f64 / 1000.0;
    let on_wire = bytes as f64 * char_ms;
    println!(
        "limit at {baud} baud: the command write ({bytes} bytes) takes {on_wire:.1} ms on the \
         wire, the drives apply it {:.1} ms after its first byte",
        on_wire + FRAME_GAP_CHARS * char_ms
    );
}

/// The e-stop's limit: the emergency zero by broadcast (FC 10h to address 0, the DDO
/// speed, both rates, torque limit and trigger) on the line, and the drives' C3.5.
fn report_emergency_zero_limit(baud: u32) {
    // Address, function, start, count, byte count; five 4-byte items; CRC.
    let bytes = 7 + 5 * 4 + 2;
    let char_ms = virtual_robot::runtime::char_time(baud, 11).as_micros() as f64 / 1000.0;
    let on_wire = bytes as f64 * char_ms;
    println!(
        "limit at {baud} baud: the emergency zero ({bytes} bytes, broadcast) takes {on_wire:.1} ms \
         on the wire, the drives apply it {:.1} ms after its first byte",
        on_wire + FRAME_GAP_CHARS * char_ms
    );
}

fn report_latency(what: &str, samples: &[Duration]) {
    let min = samples.iter().copied().min().expect("samples");
    let max = samples.iter().copied().max().expect("samples");
    let mean = samples.iter().map(|&d| ms(d)).sum::<f64>() / samples.len() as f64;
    println!(
        "{what}: min {:.1} ms, mean {mean:.1} ms, max {:.1} ms ({} samples)",
        ms(min),
        ms(max),
        samples.len()
    );
}

/// A stretch of virtual time, start included, end excluded.
#[derive(Debug, Clone, Copy)]
struct Window {
    start: Instant,
    end: Instant,
}

impl Window {
    /// Waits `duration_ms` and returns the time it waited.
    async fn lasting(duration_ms: u64) -> Window {
        let start = Instant::now();
        wait_ms(duration_ms).await;
        Window {
            start,
            end: Instant::now(),
        }
    }

    fn contains(&self, at: Instant) -> bool {
        (self.start..self.end).contains(&at)
    }

    fn seconds(&self) -> f64 {
        ms(self.end - self.start) / 1000.0
    }
}

/// What one robot put on its buses in standby and then while driving steadily.
struct BusRecording {
    standby: Window,
    driving: Window,
    from_controller: Vec<SentFrame>,
    from_pc: Vec<SentFrame>,
    line_baud: u32,
    requests: Vec<FrameRecord>,
    replies: Vec<FrameRecord>,
}

fn record_buses(robot: &VirtualRobot) -> BusRecording {
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        let standby = Window::lasting(STANDBY_MS).await;
        let (_, driving) = join(drive_as_the_pc_does(pc, WARM_UP_MS + DRIVING_MS), async {
            wait_ms(WARM_UP_MS).await;
            Window::lasting(DRIVING_MS).await
        })
        .await;
        let requests = robot.drives.requests();
        assert!(
            requests
                .first()
                .is_some_and(|first| first.at < driving.start),
            "the drives' log must reach back before the driving window"
        );
        BusRecording {
            standby,
            driving,
            from_controller: pc.peer.sent(),
            from_pc: pc.peer.sent_by_pc(),
            line_baud: robot.settings.drives.line.baud,
            requests,
            replies: robot.drives.replies(),
        }
    })
}

/// The robot PC while driving: a velocity every 50 ms and the enable with every second
/// one (every 100 ms, well inside `enable_timeout`).
async fn drive_as_the_pc_does(pc: &Pc, duration_ms: u64) {
    let end = Instant::now() + Duration::from_millis(duration_ms);
    let mut with_enable = true;
    while Instant::now() < end {
        if with_enable {
            pc.enable();
        }
        with_enable = !with_enable;
        pc.velocity(DRIVING_SPEED_MM_S, 0);
        wait_ms(VELOCITY_PERIOD_MS).await;
    }
}

/// The feedback frames' periods, from the times their last bit left the bus: each
/// interval's deviation from the register's period.
fn report_feedback_periods(recording: &BusRecording) {
    let window = recording.driving;
    println!(
        "Feedback periods while driving ({:.0} s), from the time each frame left the bus:",
        window.seconds()
    );
    println!(
        "  {:<7}{:<16}{:>9}{:>12}{:>10}{:>10}{:>10}{:>11}",
        "ID", "register", "set", "mean", "min dev", "max dev", "std dev", "intervals"
    );
    for (frame_id, period) in [
        (id::POSITION, Reg::LoopEndDelay),
        (id::BATTERY, Reg::VoltTime),
        (id::WEIGHT, Reg::WeightTime),
        (id::STATUS, Reg::StatusTime),
    ] {
        let set_ms = f64::from(period.info().default);
        let times: Vec<Instant> = recording
            .from_controller
            .iter()
            .filter(|sent| sent.frame.standard_id() == Some(frame_id) && window.contains(sent.at))
            .map(|sent| sent.at)
            .collect();
        let intervals: Vec<f64> = times.windows(2).map(|pair| ms(pair[1] - pair[0])).collect();
        let count = intervals.len() as f64;
        let mean = intervals.iter().sum::<f64>() / count;
        let variance = intervals.iter().map(|i| (i - mean).powi(2)).sum::<f64>() / count;
        let deviation_us = |interval: f64| (interval - set_ms) * 1000.0;
        let min_dev = intervals
            .iter()
            .copied()
            .map(deviation_us)
            .fold(f64::MAX, f64::min);
        let max_dev = intervals
            .iter()
            .copied()
            .map(deviation_us)
            .fold(f64::MIN, f64::max);
        println!(
            "  {frame_id:#05X}  {:<16}{:>6} ms{:>9.3} ms{:>+7.0} µs{:>+7.0} µs{:>7.0} µs{:>11}",
            period.info().name,
            set_ms,
            mean,
            min_dev,
            max_dev,
            variance.sqrt() * 1000.0,
            intervals.len()
        );
    }
}

/// One request on the RS-485 line and the reply it drew (none for a broadcast).
struct Transaction<'a> {
    request: &'a FrameRecord,
    reply: Option<&'a FrameRecord>,
}

impl Transaction<'_> {
    fn function_code(&self) -> u8 {
        self.request.bytes.get(1).copied().unwrap_or_default()
    }

    /// The request's first register (a share read's part, a command write's items).
    fn start_register(&self) -> u16 {
        match self.request.bytes.get(2..4) {
            Some(&[high, low]) => u16::from_be_bytes([high, low]),
            _ => 0,
        }
    }

    /// How long one byte took on the line, from the request's own timing.
    fn char_time_ms(&self) -> f64 {
        ms(self.request.at - self.request.started) / self.request.bytes.len() as f64
    }

    /// From the request's first byte to the silence after the last frame, which the
    /// line needs before it can carry the next one.
    fn busy_ms(&self) -> f64 {
        let last = self.reply.unwrap_or(self.request);
        ms(last.at - self.request.started) + FRAME_GAP_CHARS * self.char_time_ms()
    }
}

/// The driving window's requests, each with the first reply that started after it
/// ended and before the next request.
fn transactions(recording: &BusRecording) -> Vec<Transaction<'_>> {
    let requests: Vec<&FrameRecord> = recording
        .requests
        .iter()
        .filter(|request| recording.driving.contains(request.started))
        .collect();
    requests
        .iter()
        .enumerate()
        .map(|(index, &request)| {
            let next = requests.get(index + 1).map(|next| next.started);
            let reply = recording.replies.iter().find(|reply| {
                reply.started >= request.at && next.is_none_or(|next| reply.started < next)
            });
            Transaction { request, reply }
        })
        .collect()
}

/// Bytes per control cycle by function code, and the line's busy time: frames, the
/// drives' response delay and the closing silence.
fn report_line(recording: &BusRecording, cycle_ms: f64) {
    let window = recording.driving;
    let transactions = transactions(recording);
    let cycles = window.seconds() * 1000.0 / cycle_ms;
    let per_cycle = |total: f64| total / cycles;
    let char_time = transactions.first().expect("traffic").char_time_ms();
    println!(
        "RS-485 at {} baud ({:.1} µs per byte), steady driving, per {cycle_ms:.0} ms cycle:",
        recording.line_baud,
        char_time * 1000.0
    );
    let mut by_function: BTreeMap<(u8, u16), Vec<&Transaction>> = BTreeMap::new();
    for transaction in &transactions {
        by_function
            .entry((transaction.function_code(), transaction.start_register()))
            .or_default()
            .push(transaction);
    }
    for ((function, start), group) in &by_function {
        let count = group.len() as f64;
        let mean = |measure: &dyn Fn(&Transaction) -> f64| {
            group.iter().map(|&t| measure(t)).sum::<f64>() / count
        };
        let request_bytes = mean(&|t| t.request.bytes.len() as f64);
        let reply_bytes = mean(&|t| t.reply.map_or(0.0, |reply| reply.bytes.len() as f64));
        let response_delay = mean(&|t| {
            t.reply
                .map_or(0.0, |reply| ms(reply.started - t.request.at))
        });
        println!(
            "  FC {function:02X}h from {start:04X}h, {:.2} per cycle: request {request_bytes:.0} B ({:.2} ms) + response \
             delay {response_delay:.2} ms + reply {reply_bytes:.0} B ({:.2} ms) + gap {:.2} ms",
            per_cycle(count),
            request_bytes * char_time,
            reply_bytes * char_time,
            FRAME_GAP_CHARS * char_time,
        );
    }
    let bytes: usize = transactions
        .iter()
        .map(|t| t.request.bytes.len() + t.reply.map_or(0, |reply| reply.bytes.len()))
        .sum();
    let busy_ms: f64 = transactions.iter().map(Transaction::busy_ms).sum();
    println!(
        "  total {:.1} B per cycle, line busy {:.2} ms per cycle = {:.1} % utilisation",
        per_cycle(bytes as f64),
        per_cycle(busy_ms),
        100.0 * busy_ms / (window.seconds() * 1000.0)
    );
    // What the drives' communication timeout (0x138A) sees: the longest time without
    // a frame on the line, from the end of one frame to the start of the next.
    let mut frames: Vec<&FrameRecord> = recording
        .requests
        .iter()
        .chain(&recording.replies)
        .filter(|frame| window.contains(frame.started))
        .collect();
    frames.sort_by_key(|frame| frame.started);
    let longest_silence = frames
        .windows(2)
        .map(|pair| pair[1].started - pair[0].at)
        .max()
        .expect("frames");
    println!(
        "  longest silence on the line: {:.1} ms (the drives' communication timeout: {} ms)",
        ms(longest_silence),
        base_core::drives::DriveSettings::DEFAULT.drive_comm_timeout_ms
    );
}

/// Frames per second by ID and direction, and the share of the bus's bits they take.
fn report_can(recording: &BusRecording) {
    let windows = [
        ("standby", recording.standby),
        ("driving", recording.driving),
    ];
    let directions = [
        ("PC → BC", &recording.from_pc),
        ("BC → PC", &recording.from_controller),
    ];
    println!(
        "CAN at {} kbit/s, frames per second; standby: the PC is silent, driving: it sends\n\
         the velocity every 50 ms and the enable every 100 ms (bits: on the wire, stuffed):",
        BITRATE_BPS / 1000
    );
    println!(
        "  {:<7}{:<9}{:>5}{:>9}{:>9}",
        "ID", "from", "bits", windows[0].0, windows[1].0
    );
    let mut totals = [(0usize, 0u64); 2];
    for (direction, frames) in directions {
        let ids: BTreeSet<u16> = frames
            .iter()
            .filter_map(|sent| sent.frame.standard_id())
            .collect();
        for frame_id in ids {
            let wire_bits = frames
                .iter()
                .filter(|sent| sent.frame.standard_id() == Some(frame_id))
                .map(|sent| sent.frame.wire_bits())
                .max()
                .unwrap_or_default();
            let mut row = format!("  {frame_id:#05X}  {direction:<9}{wire_bits:>5}");
            for ((_, window), total) in windows.iter().zip(&mut totals) {
                let in_window: Vec<&SentFrame> = frames
                    .iter()
                    .filter(|sent| {
                        sent.frame.standard_id() == Some(frame_id) && window.contains(sent.at)
                    })
                    .collect();
                total.0 += in_window.len();
                total.1 += in_window
                    .iter()
                    .map(|sent| u64::from(sent.frame.wire_bits()))
                    .sum::<u64>();
                row += &format!("{:>9.1}", in_window.len() as f64 / window.seconds());
            }
            println!("{row}");
        }
    }
    let [standby, driving] = [0, 1].map(|index| {
        let (frames, bits) = totals[index];
        let seconds = windows[index].1.seconds();
        (
            frames as f64 / seconds,
            100.0 * bits as f64 / (f64::from(BITRATE_BPS) * seconds),
        )
    });
    println!("  {:<21}{:>9.1}{:>9.1}", "total", standby.0, driving.0);
    println!("  {:<21}{:>8.2}%{:>8.2}%", "bus load", standby.1, driving.1);
}

fn ms(duration: Duration) -> f64 {
    duration.as_micros() as f64 / 1000.0
}
