//! The simulator: the firmware's real tasks on the virtual robot, on the wall clock,
//! for PC software to talk to live. The PC reaches the CAN bus through an SLCAN
//! serial port (a pseudo-terminal); a console on stdin plays the robot's inputs; a
//! status line shows what the controller does.

pub mod console;
pub mod serial;
pub mod status;

use std::cell::RefCell;
use std::io::{self, BufRead, IsTerminal, Write};
use std::path::PathBuf;

use base_controller::app::{self, Hardware, channels::Channels};
use base_controller::can::Mode;
use embassy_futures::select::{Either, Either4, select, select4};
use embassy_time::{Instant, Timer};
use embedded_hal::digital::PinState;

use crate::can::{BITRATE_BPS, CanPeer, VirtualCan};
use crate::file_flash::FileFlash;
use crate::robot::{FLASH_SIZE, Pc, VirtualRobot, wait_ms};
use crate::runtime::{QueueReceiver, block_on_realtime, cross_thread_queue, now};
use crate::slcan;
use console::{ConsoleCommand, HELP, parse_console_line};
use serial::{SerialPort, StableLink};
use status::{SlcanCounters, Telemetry, status_line};

/// How often the status line is redrawn.
const STATUS_PERIOD_MS: u64 = 250;

/// What to run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Options {
    /// The file that holds the register store's flash.
    pub flash_path: PathBuf,
    /// A symbolic link to the serial port at a fixed path, if wanted.
    pub link: Option<PathBuf>,
    pub demo: Demo,
    /// The Bluetooth controller for the remote (`--hci`), if any.
    pub hci: Option<crate::ble::HciSpec>,
}

/// Whether the simulator drives a path by itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Demo {
    Off,
    /// Drive the demo path, then quit.
    ThenQuit,
    /// Drive the demo path, then keep running for the PC and the console.
    ThenStay,
}

/// The flash file when none is named: in the user's cache directory
/// (`$XDG_CACHE_HOME` or `~/.cache`), else under `./target/`.
pub fn default_flash_path() -> PathBuf {
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .filter(|path| !path.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|home| PathBuf::from(home).join(".cache")));
    match cache {
        Some(cache) => cache.join("virtual-base-controller").join("flash.bin"),
        None => PathBuf::from("target").join("virtual-base-controller-flash.bin"),
    }
}

/// The default symbolic link to the serial port.
pub const DEFAULT_LINK: &str = "/tmp/virtual-base-controller";

/// Runs the simulator until `quit` (or the end of the demo). Fails only at start-up:
/// the flash file or the serial port could not be set up.
pub fn run(options: &Options) -> io::Result<()> {
    let robot = VirtualRobot::new();
    let flash = FileFlash::open(&options.flash_path, FLASH_SIZE as usize)?;
    let port = SerialPort::open()?;
    let link = options
        .link
        .as_deref()
        .map(|link| StableLink::create(link, port.path()))
        .transpose()?;
    let output = Output {
        status_on_terminal: io::stderr().is_terminal(),
    };
    output.message(&format!("SLCAN serial port: {}", port.path().display()));
    if let Some(link) = &link {
        output.message(&format!("  linked from:     {}", link.path().display()));
    }
    output.message(&format!(
        "registers kept in: {}",
        options.flash_path.display()
    ));
    output.message("type help for the console commands");

    let remote = (options.hci.as_ref())
        .map(|spec| crate::ble::LiveRemote::open(spec, &options.flash_path))
        .transpose()?;
    let console_lines = read_stdin_lines()?;
    let (can_rx, can_tx, peer) = VirtualCan::new();
    let hardware = Hardware {
        can_rx,
        can_tx,
        drives: robot.drives.port(),
        flash,
        flash_range: 0..FLASH_SIZE,
        estop: robot.estop.clone(),
        safety_zone: robot.safety_zone.clone(),
        button: robot.button.clone(),
        pc_switch: robot.pc_switch.clone(),
        battery: robot.battery.clone(),
        load_cell: robot.load_cell.clone(),
        watchdog: robot.watchdog.clone(),
        reset_by_watchdog: false,
    };
    let channels = Channels::new();
    let view = View {
        robot: &robot,
        peer: &peer,
        telemetry: RefCell::default(),
        slcan: SlcanCounters::default(),
        output,
    };
    block_on_realtime(async {
        let ending = select(
            serve_console(&console_lines, &view),
            demo(options.demo, &view),
        );
        match select4(
            embassy_futures::join::join(
                app::run(hardware, robot.settings, &channels),
                crate::ble::run_live_remote(remote, &channels),
            ),
            bridge_slcan(&port, &view),
            show_status(&view),
            ending,
        )
        .await
        {
            Either4::First((never, ())) | Either4::Second(never) | Either4::Third(never) => never,
            Either4::Fourth(_) => {}
        }
    });
    view.output.finish_status();
    Ok(())
}

/// Reads stdin on its own thread, line by line, for the console.
fn read_stdin_lines() -> io::Result<QueueReceiver<String>> {
    let (sender, lines) = cross_thread_queue();
    std::thread::Builder::new()
        .name("console".into())
        .spawn(move || {
            for line in io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                sender.send(line);
            }
        })?;
    Ok(lines)
}

/// Where messages and the status line go. Messages go to stdout; the status line to
/// stderr, redrawn in place on a terminal and as plain lines otherwise.
struct Output {
    status_on_terminal: bool,
}

impl Output {
    fn message(&self, text: &str) {
        if self.status_on_terminal {
            // Clear the status line first, or the message would continue it.
            eprint!("\r\x1b[K");
        }
        println!("{text}");
    }

    fn status(&self, line: &str) {
        let mut stderr = io::stderr().lock();
        // A closed stderr leaves nothing to show the status on; the simulator goes on.
        let _ = if self.status_on_terminal {
            write!(stderr, "\r\x1b[K{line}").and_then(|()| stderr.flush())
        } else {
            writeln!(stderr, "{line}")
        };
    }

    /// Ends the redrawn line, so the shell prompt starts on a line of its own.
    fn finish_status(&self) {
        if self.status_on_terminal {
            eprintln!();
        }
    }
}

/// What the simulator's own tasks share: the robot's handles, the PC's end of the
/// bus, what the controller reported and the SLCAN traffic.
struct View<'a> {
    robot: &'a VirtualRobot,
    peer: &'a CanPeer,
    telemetry: RefCell<Telemetry>,
    slcan: SlcanCounters,
    output: Output,
}

impl View<'_> {
    /// Takes the frames the controller sent since the last call into the telemetry.
    /// Also keeps the bus's log of sent frames from growing while the simulator runs.
    fn refresh(&self) -> Telemetry {
        let mut telemetry = self.telemetry.borrow_mut();
        telemetry.absorb(self.peer.take_sent());
        *telemetry
    }

    fn status_line(&self) -> String {
        status_line(now(), &self.refresh(), self.robot, &self.slcan)
    }
}

/// The USB-CAN adapter: the PC's SLCAN lines go onto the bus, and the frames the
/// controller sends go to the PC while its channel is open.
async fn bridge_slcan(port: &SerialPort, view: &View<'_>) -> ! {
    let mut channel = slcan::Channel::new(BITRATE_BPS);
    let counters = &view.slcan;
    loop {
        match select(port.lines().receive(), view.peer.receive()).await {
            Either::First(Some(line)) => {
                let response = channel.handle_line(&line);
                port.send(response.reply);
                if let Some(refusal) = response.refusal {
                    view.output.message(&format!(
                        "slcan: refused \"{}\": {refusal}",
                        line.escape_ascii()
                    ));
                }
                if let Some(frame) = response.transmit {
                    view.peer.send_frame(frame);
                    counters.frames_in.set(counters.frames_in.get() + 1);
                }
                if channel.is_open() != counters.open.get() {
                    counters.open.set(channel.is_open());
                    let state = if channel.is_open() {
                        "opened"
                    } else {
                        "closed"
                    };
                    view.output.message(&format!("slcan: channel {state}"));
                }
            }
            Either::First(None) => {
                view.output.message(
                    "slcan: the serial port failed; the PC is cut off, the controller runs on",
                );
                core::future::pending().await
            }
            Either::Second(frame) if channel.is_open() => {
                // The adapter's millisecond counter, which wraps at 60 s.
                let timestamp_ms = channel
                    .timestamps()
                    .then(|| (now().as_millis() % 60_000) as u16);
                let counter = if port.send(::slcan::format_frame(&frame, timestamp_ms).as_bytes()) {
                    &counters.frames_out
                } else {
                    &counters.frames_dropped
                };
                counter.set(counter.get() + 1);
            }
            // A closed adapter takes no part in the bus.
            Either::Second(_) => {}
        }
    }
}

async fn show_status(view: &View<'_>) -> ! {
    loop {
        Timer::after_millis(STATUS_PERIOD_MS).await;
        view.output.status(&view.status_line());
    }
}

/// Acts on the console's lines until `quit`. At the end of stdin (the simulator runs
/// in the background, or a piped script ended) the simulator goes on without it.
async fn serve_console(lines: &QueueReceiver<String>, view: &View<'_>) {
    let robot = view.robot;
    let mut stdin_open = true;
    let mut button_release_at: Option<Instant> = None;
    loop {
        let next_line = async {
            match stdin_open {
                true => lines.receive().await,
                false => core::future::pending().await,
            }
        };
        let button_release = async {
            match button_release_at {
                Some(at) => Timer::at(at).await,
                None => core::future::pending().await,
            }
        };
        let line = match select(next_line, button_release).await {
            Either::First(Some(line)) => line,
            Either::First(None) => {
                stdin_open = false;
                continue;
            }
            Either::Second(()) => {
                robot.button.set_level(PinState::High);
                button_release_at = None;
                continue;
            }
        };
        let command = match parse_console_line(&line) {
            Ok(Some(command)) => command,
            Ok(None) => continue,
            Err(error) => {
                view.output.message(&format!("console: {error}"));
                continue;
            }
        };
        match command {
            ConsoleCommand::Estop(true) => robot.press_estop(),
            ConsoleCommand::Estop(false) => robot.release_estop(),
            ConsoleCommand::SafetyZone(occupied) => robot.set_safety_zone(occupied),
            ConsoleCommand::ButtonPress { hold_ms } => {
                robot.button.set_level(PinState::Low);
                button_release_at = Some(now() + embassy_time::Duration::from_millis(hold_ms));
            }
            ConsoleCommand::BatteryMillivolts(millivolts) => {
                robot.battery.set_millivolts(millivolts);
            }
            ConsoleCommand::WeightGrams(grams) => robot.load_cell.set_load_grams(grams),
            ConsoleCommand::DrivesPower(on) => robot.drives.power(on),
            ConsoleCommand::Status => view.output.message(&view.status_line()),
            ConsoleCommand::Help => view.output.message(HELP),
            ConsoleCommand::Quit => return,
        }
    }
}

/// The path of `sim/examples/demo.rs`, on the wall clock: what the robot PC sends,
/// and the pose the controller reports back.
async fn demo(demo: Demo, view: &View<'_>) {
    if demo == Demo::Off {
        return core::future::pending().await;
    }
    let pc = Pc {
        peer: view.peer.clone(),
    };
    let show = |what: &str| {
        let telemetry = view.refresh();
        let (x, y) = telemetry.position_mm.unwrap_or_default();
        let heading = telemetry.heading_mrad.unwrap_or_default();
        let mode = telemetry
            .status
            .map_or("-".to_owned(), |status| format!("{:?}", status.mode));
        view.output.message(&format!(
            "demo {:6.2} s  {what:<28} x {x:5} mm  y {y:5} mm  heading {heading:5} mrad  {mode}",
            now().as_millis() as f64 / 1000.0
        ));
    };
    wait_ms(1_500).await;
    show("drives set up");
    for (what, linear, rotation, ms) in [
        ("forward 400 mm/s", 400, 0, 2_000),
        ("turn clockwise 800 mrad/s", 0, 800, 1_963),
        ("forward 400 mm/s", 400, 0, 1_000),
        ("arc 300 mm/s, 300 mrad/s", 300, 300, 2_000),
        ("stop", 0, 0, 1_000),
    ] {
        pc.drive(linear, rotation, ms).await;
        show(what);
    }
    view.robot.press_estop();
    wait_ms(500).await;
    show("e-stop pressed");
    view.robot.release_estop();
    view.robot.press_button(200).await;
    // The status frame comes once a second; give the recovery three.
    for _ in 0..30 {
        if view
            .refresh()
            .status
            .is_some_and(|status| status.mode == Mode::Standby)
        {
            break;
        }
        wait_ms(100).await;
    }
    show("confirm pressed");
    if demo == Demo::ThenStay {
        view.output
            .message("demo done; the simulator keeps running");
        core::future::pending().await
    }
}
