//! The simulator: the firmware's real tasks on the virtual robot, on the wall clock,
//! for PC software to talk to live. The PC reaches the CAN bus through an SLCAN
//! serial port (a pseudo-terminal) and through a socketcand server on TCP, any number
//! of programs at once; a console on stdin plays the robot's inputs; a status line
//! shows what the controller does.

pub mod console;
pub mod serial;
pub mod socketcan;
pub mod socketcand;
pub mod status;
pub mod wire_queue;

use std::cell::RefCell;
use std::io::{self, BufRead, IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;

use base_core::can::Mode;
use base_core::registers::UpdateReset;
use base_core::update::trial::{self, ResetRecord};
use base_runtime::update::ResetRequest;
use base_runtime::{Hardware, channels::Channels};
use embassy_futures::select::{Either, Either3, Either4, select, select3, select4};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use embedded_hal::digital::PinState;

use crate::app_flash::{self, Behaviour};
use crate::can::{BITRATE_BPS, CanPeer, VirtualCan};
use crate::drives::DrivesConfig;
use crate::file_flash::FileFlash;
use crate::flash::FlashTiming;
use crate::robot::{FLASH_SIZE, Pc, VirtualRobot, wait_ms};
use crate::runtime::{QueueReceiver, block_on_realtime, cross_thread_queue, now};
use crate::slcan;
use console::{ConsoleCommand, HELP, parse_console_line};
use serial::{PortEvent, SerialPort, StableLink};
use socketcand::{Client, Event};
use status::{NetworkCounters, SlcanCounters, Telemetry, status_line};

/// How often the status line is redrawn.
const STATUS_PERIOD_MS: u64 = 250;

/// What to run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Options {
    /// The file that holds the register store's flash.
    pub flash_path: PathBuf,
    /// A symbolic link to the serial port at a fixed path, if wanted.
    pub link: Option<PathBuf>,
    /// Where the socketcand server listens, if at all.
    pub socketcand: Option<SocketAddr>,
    /// A SocketCAN interface to join, if any.
    pub socketcan: Option<String>,
    pub demo: Demo,
    /// The Bluetooth controller for the remote (`--hci`), if any.
    pub hci: Option<crate::ble::HciSpec>,
    /// The drives' address switches swapped (`--swap-drive-addresses`): slave 1 on the
    /// right wheel, for the wheel commissioning check.
    pub swap_drive_addresses: bool,
    /// The drive with this address has its direction parameter at the other value
    /// (`--reverse-drive SLAVE`): it turns against its command, for the feedback
    /// check and the wheel commissioning check to find.
    pub reversed_drive: Option<u8>,
    /// The public keys the firmware trusts for updates (`--update-key FILE`); none: a
    /// development build, which activates unsigned images.
    pub update_keys: Vec<base_core::update::signature::PublicKey>,
}

impl Options {
    /// Which images an update may activate, as a build with these keys would.
    pub fn trust(&self) -> base_core::update::signature::Trust<'_> {
        base_core::update::signature::Trust::of_keys(&self.update_keys)
    }
}

/// The public key in a PEM file (`basectl firmware keygen`'s `.pub`, or openssl's
/// `pkey -pubout` of an ed25519 key).
pub fn read_public_key(path: &std::path::Path) -> Result<[u8; 32], String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    ed25519_compact::PublicKey::from_pem(&text)
        .and_then(|key| key.validate().map(|()| *key))
        .map_err(|e| format!("{}: not an ed25519 public key in PEM: {e}", path.display()))
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

/// The last line the simulator prints at start-up, once the flash file, the serial
/// port and its link, the SocketCAN interface and the socketcand server are all set
/// up. [`crate::process::SimulatorProcess`] waits for it.
pub const STARTED: &str = "type help for the console commands";

/// Runs the simulator until `quit` (or the end of the demo). Fails only at start-up:
/// the flash file or the serial port could not be set up.
pub fn run(options: &Options) -> io::Result<()> {
    let drives = if options.swap_drive_addresses {
        DrivesConfig::default().with_swapped_addresses()
    } else {
        DrivesConfig::default()
    };
    let robot = VirtualRobot::with_drives(drives);
    if let Some(slave) = options.reversed_drive {
        robot
            .drives
            .set_reversed(slave, Some(crate::drives::Reversal::Motion));
    }
    let flash = FileFlash::open(&options.flash_path, FLASH_SIZE as usize)?;
    let app_flash = FileFlash::open(
        &app_flash_path(&options.flash_path),
        base_core::update::partitions::FLASH_SIZE as usize,
    )?;
    let port = SerialPort::open()?;
    let link = options
        .link
        .as_deref()
        .map(|link| StableLink::create(link, port.path()))
        .transpose()?;
    let (network_events, network) = cross_thread_queue();
    let socketcan = options
        .socketcan
        .as_deref()
        .map(|interface| socketcan::SocketCanLink::join(interface, network_events.clone()))
        .transpose()?;
    let socketcand = options
        .socketcand
        .map(|address| {
            socketcand::serve(address, network_events).map_err(|error| {
                io::Error::new(
                    error.kind(),
                    format!("socketcand on {address}: {error} (see --socketcand, --no-socketcand)"),
                )
            })
        })
        .transpose()?;
    let signals = quit_on_signals()?;
    let output = Output {
        status_on_terminal: io::stderr().is_terminal(),
    };
    output.message(&format!("SLCAN serial port: {}", port.path().display()));
    if let Some(link) = &link {
        output.message(&format!("  linked from:     {}", link.path().display()));
    }
    if let Some(link) = &socketcan {
        output.message(&format!("SocketCAN:         {}", link.interface));
    }
    if let Some(address) = socketcand {
        output.message(&format!(
            "socketcand:        {address}, bus {}",
            socketcand::BUS_NAME
        ));
    }
    output.message(&format!(
        "registers kept in: {}",
        options.flash_path.display()
    ));
    output.message(STARTED);

    let remote = (options.hci.as_ref())
        .map(|spec| crate::ble::LiveRemote::open(spec, &options.flash_path))
        .transpose()?;
    let console_lines = read_stdin_lines()?;
    let (can_rx, can_tx, peer) = VirtualCan::new();
    let view = View {
        robot: &robot,
        peer: &peer,
        telemetry: RefCell::default(),
        slcan: SlcanCounters::default(),
        network: NetworkCounters::default(),
        output,
        reboot: Signal::new(),
    };
    block_on_realtime(async {
        let ending = select3(
            serve_console(&console_lines, &view),
            demo(options.demo, &view),
            signals.receive(),
        );
        match select4(
            controller(&view, options, (flash, app_flash), (can_rx, can_tx), remote),
            bridge(&port, &network, socketcan.as_ref(), &view),
            show_status(&view),
            ending,
        )
        .await
        {
            Either4::First(never) | Either4::Second(never) | Either4::Third(never) => never,
            Either4::Fourth(_) => {}
        }
    });
    view.output.finish_status();
    Ok(())
}

/// The file that holds the app slots and otadata: beside the register store's file.
pub fn app_flash_path(flash_path: &std::path::Path) -> PathBuf {
    let mut name = flash_path
        .file_stem()
        .map(|stem| stem.to_os_string())
        .unwrap_or_default();
    name.push("-app.bin");
    flash_path.with_file_name(name)
}

/// The controller: the firmware's tasks on the robot's hardware, booted again from
/// scratch at every console `reboot`, at every reset an update asks for, and after a
/// panic. Each boot goes through the bootloader model: the slot otadata names starts,
/// and its image's version says what the virtual firmware does (`app_flash`). A reboot drops the running firmware where it
/// stands, as a reset does to the chip: the drives, the flash, the inputs and the
/// sensors stay as they are (the drives keep their last command until the new boot
/// stops them), and the controller's CAN node restarts on the same bus, so the
/// simulator's SLCAN port, socketcand clients and SocketCAN interface stay connected.
async fn controller(
    view: &View<'_>,
    options: &Options,
    (flash, app_flash): (FileFlash, FileFlash),
    first_can: (crate::can::CanRxPort, crate::can::CanTxPort),
    mut remote: Option<crate::ble::LiveRemote>,
) -> ! {
    let robot = view.robot;
    let mut first_can = Some(first_can);
    let mut reset_by_watchdog = false;
    // The chip's reset-cause record in RTC RAM, empty after the power-on.
    let mut reset_record = ResetRecord::Empty;
    let mut app = app_flash;
    if app_flash::install_factory_image(&mut app).await {
        view.output.message(&format!(
            "app flash blank: firmware {} written to ota_0",
            app_flash::FACTORY_VERSION
        ));
    }
    // From here on the flash takes the chip's time, and the chip stands still meanwhile
    // (the factory image above is the USB flash's work, not the controller's).
    app.set_timing(FlashTiming::TYPICAL);
    flash.set_timing(FlashTiming::TYPICAL);
    loop {
        let (can_rx, can_tx) = match first_can.take() {
            Some(ports) => ports,
            None => view.peer.reset_controller(),
        };
        let Some(booted) = app_flash::boot(&mut app).await else {
            view.output.message(
                "boot: no slot holds an image that loads: the controller stays dark \
                 (remove the app flash file to start from the factory image)",
            );
            let reset = view.reboot.wait().await;
            reset_by_watchdog = reset != Reset::Button;
            reset_record = reset.record_after(reset_record);
            continue;
        };
        let booted_at = now();
        // As the chip's boot does, first thing: the panic-loop decision.
        let bluetooth = robot.rtc_ram.boot();
        let channels = Channels::new();
        let mut update_flash = base_runtime::update::UpdateFlash::new(app.clone(), booted.slot);
        let started = base_runtime::update::arm(&mut update_flash).await;
        base_runtime::update::report_start(&started);
        channels.update.lock_at_start(&started);
        let role = started.role();
        // As the chip's boot does: an update's reset before this boot is reported as
        // such (`boot_info`), not as a watchdog reset.
        let boot = trial::boot_cause(reset_record, &started.start, started.written, booted.slot);
        reset_record = boot.keep;
        let behaviour = Behaviour::of(&booted.version);
        view.output.message(&format!(
            "boot: firmware {} from {:?}{}",
            booted.version,
            booted.slot,
            if role.on_trial() { ", on trial" } else { "" }
        ));
        if behaviour == Behaviour::PanicsAtBoot {
            view.output.message(&format!(
                "firmware {} panicked at boot: the watchdog resets the chip",
                booted.version
            ));
            Timer::after_millis(200).await;
            // As the chip's panic handler does: the panic counts towards a panic loop.
            robot
                .rtc_ram
                .record_panic(base_core::time::Timestamp::from_millis(
                    (now() - booted_at).as_millis(),
                ));
            reset_by_watchdog = true;
            continue;
        }
        let can_rx = app_flash::DeafToConfirm {
            rx: can_rx,
            deaf: behaviour == Behaviour::NeverConfirms,
        };
        let hardware = Hardware {
            can_rx,
            can_tx,
            drives: robot.drives.port(),
            flash: flash.clone(),
            flash_range: 0..FLASH_SIZE,
            estop: robot.estop.clone(),
            safety_zone: robot.safety_zone.clone(),
            button: robot.button.clone(),
            pc_switch: robot.pc_switch.clone(),
            battery: robot.battery.clone(),
            load_cell: robot.load_cell.clone(),
            watchdog: robot.watchdog.clone(),
            reset_by_watchdog: reset_by_watchdog && boot.cause == UpdateReset::None,
            bluetooth,
            update_reset: boot.cause,
        };
        let firmware = embassy_futures::join::join(
            base_runtime::run(hardware, robot.settings, &channels),
            crate::ble::run_live_remote(remote.take(), bluetooth, &robot.rtc_ram, &channels),
        );
        let config = base_runtime::update::UpdateConfig {
            chip: app_flash::SIM_CHIP,
            project: base_runtime::update::PROJECT,
            version: &booted.version,
            security_version: booted.security_version,
            trust: options.trust(),
            trial_deadline_ms: base_runtime::update::TRIAL_DEADLINE_MS,
        };
        let update = base_runtime::update::run(
            &mut update_flash,
            started,
            boot.trial_owner,
            &config,
            &channels.update,
            &channels.can_tx,
        );
        // The firmware (and its end of the HCI connection) is dropped at the end of
        // this statement: the chip is reset.
        let reset = match select3(firmware, update, view.reboot.wait()).await {
            Either3::First((never, ())) => never,
            Either3::Second(request) => {
                view.output
                    .message(&format!("update: {request:?}: the controller resets"));
                Reset::Update(request)
            }
            Either3::Third(reset) => reset,
        };
        // As the chip's panic handler does, before its reset.
        if reset == Reset::Panic {
            let uptime = (now() - booted_at).as_millis();
            robot
                .rtc_ram
                .record_panic(base_core::time::Timestamp::from_millis(uptime));
            view.output.message(&format!(
                "panic: the controller panicked {uptime} ms after its boot and resets; \
                 panics in a row soon after boot: {} (at {} Bluetooth stays off)",
                robot.rtc_ram.short_panics(),
                base_core::panic_loop::LOOP_PANICS
            ));
        }
        reset_by_watchdog = matches!(reset, Reset::Watchdog | Reset::Panic);
        reset_record = reset.record_after(reset_record);
        view.output.message(match reset {
            Reset::Watchdog | Reset::Panic => {
                "reboot: the controller restarts as after a watchdog reset (the status frame \
                 reports watchdog_reset); the drives keep running until it stops them"
            }
            Reset::Button => {
                "reboot: the controller restarts as after a reset or brown-out; the drives \
                 keep running until it stops them"
            }
            Reset::Update(_) => {
                "reboot: the controller restarts into the image otadata names (a software \
                 reset, not reported as watchdog_reset); the drives keep running until it \
                 stops them"
            }
        });
        // The radio restarts with the chip: a new host on the HCI transport.
        if let Some(spec) = &options.hci {
            remote = match crate::ble::LiveRemote::open(spec, &options.flash_path) {
                Ok(remote) => Some(remote),
                Err(error) => {
                    view.output.message(&format!(
                        "reboot: {error}; the controller runs without the remote"
                    ));
                    None
                }
            };
        }
    }
}

/// Ctrl-C, SIGTERM and SIGHUP end the simulator as `quit` does, so that its link and
/// lock file go away and the flash file is complete.
fn quit_on_signals() -> io::Result<QueueReceiver<i32>> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])?;
    let (sender, received) = cross_thread_queue();
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            let mut signals = signals.forever();
            if let Some(signal) = signals.next() {
                sender.send(signal);
            }
            // A second signal while the first one's shutdown hangs: leave at once.
            if signals.next().is_some() {
                std::process::exit(130);
            }
        })?;
    Ok(received)
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
    network: NetworkCounters,
    output: Output,
    /// The console asked for a reboot.
    reboot: Signal<NoopRawMutex, Reset>,
}

/// How the console resets the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reset {
    /// The reset button or a brown-out.
    Button,
    /// A watchdog bite.
    Watchdog,
    /// A panic: recorded for the next boot's panic-loop decision, then the reset (the
    /// status frame shows it as watchdog_reset, as the chip's does).
    Panic,
    /// The update asked for it: an image activated, rejected or rolled back (a software
    /// reset, which the status frame does not report as a watchdog reset).
    Update(ResetRequest),
}

impl Reset {
    /// The reset-cause record in RTC RAM after this reset (`before`: what it held): the
    /// update writes its cause just before its reset; the reset button or a brown-out
    /// clears RTC RAM as a power-on does; a watchdog reset or a panic keeps it.
    fn record_after(self, before: ResetRecord) -> ResetRecord {
        match self {
            Reset::Update(request) => request.record(),
            Reset::Button => ResetRecord::Empty,
            Reset::Watchdog | Reset::Panic => before,
        }
    }
}

impl View<'_> {
    /// Takes the frames the controller sent since the last call into the telemetry.
    /// Also keeps the bus's logs of sent frames from growing while the simulator runs.
    fn refresh(&self) -> Telemetry {
        let mut telemetry = self.telemetry.borrow_mut();
        telemetry.absorb(self.peer.take_sent());
        self.peer.forget_sent_by_pc();
        *telemetry
    }

    fn status_report(&self) -> String {
        status::status_report(
            now(),
            &self.refresh(),
            self.robot,
            &self.slcan,
            &self.network,
        )
    }

    fn status_line(&self) -> String {
        status_line(
            now(),
            &self.refresh(),
            self.robot,
            &self.slcan,
            &self.network,
        )
    }
}

/// The bus as the PC's programs see it: the SLCAN adapter, the socketcand clients
/// and the SocketCAN interface are nodes beside the controller. Every frame one of
/// them sends takes its time on the wire (shared with the controller's frames), then
/// reaches the controller and every other node (not itself, as on a real bus); every
/// frame the controller sends reaches them all. The nodes' frames take the wire in
/// turn ([`wire_queue`]).
async fn bridge(
    port: &SerialPort,
    network: &QueueReceiver<Event>,
    socketcan: Option<&socketcan::SocketCanLink>,
    view: &View<'_>,
) -> ! {
    let to_wire = ToWire::new();
    let on_wire = OnWire::new();
    match select(
        serve_nodes(port, network, socketcan, view, (&to_wire, &on_wire)),
        put_on_wire(view.peer, &to_wire, &on_wire),
    )
    .await
    {
        Either::First(never) | Either::Second(never) => never,
    }
}

/// Who sent a frame on the PC's side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PcNode {
    Slcan,
    /// A socketcand client, or the SocketCAN interface ([`socketcan::NODE`]).
    Network(u64),
}

/// A PC frame waiting for the wire: the time its node had it, and for a network node
/// its place in the node's queue, given back once the frame has left.
type Waiting = (
    crate::can::SimFrame,
    Instant,
    Option<wire_queue::CreditToken>,
);

/// The frames of the PC's nodes on their way to the wire, each node in turn.
type ToWire = wire_queue::WireQueues<PcNode, Waiting>;

/// Frames of the PC's nodes that have left the wire, for the other nodes.
type OnWire = embassy_sync::channel::Channel<
    NoopRawMutex,
    (crate::can::SimFrame, PcNode),
    { wire_queue::NODE_TRANSMIT_QUEUE },
>;

/// The PC's frames, one after the other, each for its bus time (in turn with the
/// controller's), then handed back for the other nodes.
async fn put_on_wire(peer: &CanPeer, to_wire: &ToWire, on_wire: &OnWire) -> ! {
    loop {
        let (sender, (frame, queued, credit)) = to_wire.next().await;
        peer.transmit(frame, queued).await;
        drop(credit);
        on_wire.send((frame, sender)).await;
    }
}

async fn serve_nodes(
    port: &SerialPort,
    network: &QueueReceiver<Event>,
    socketcan: Option<&socketcan::SocketCanLink>,
    view: &View<'_>,
    (to_wire, on_wire): (&ToWire, &OnWire),
) -> ! {
    let mut slcan = SlcanNode {
        channel: slcan::Channel::new(BITRATE_BPS),
        port,
        view,
    };
    let mut clients = Clients {
        clients: Vec::new(),
        socketcan,
        view,
    };
    let mut network_open = true;
    loop {
        let network_event = async {
            match network_open {
                true => network.receive().await,
                false => core::future::pending().await,
            }
        };
        // While the SLCAN adapter's queue is full its lines wait in the serial port,
        // as a full adapter holds up its writer.
        let slcan_room = to_wire.waiting(PcNode::Slcan) < wire_queue::NODE_TRANSMIT_QUEUE;
        let port_event = async {
            match slcan_room {
                true => port.events().receive().await,
                false => core::future::pending().await,
            }
        };
        match select4(
            port_event,
            view.peer.receive(),
            network_event,
            on_wire.receive(),
        )
        .await
        {
            Either4::First(Some(PortEvent::Line(line))) => {
                if let Some(frame) = slcan.handle_line(&line) {
                    to_wire.push(PcNode::Slcan, (frame, now(), None));
                }
            }
            Either4::First(Some(PortEvent::Closed)) => slcan.port_closed(),
            Either4::First(None) => {
                view.output.message(
                    "slcan: the serial port failed; the PC is cut off, the controller runs on",
                );
                core::future::pending().await
            }
            Either4::Second(frame) => {
                slcan.offer(&frame);
                clients.offer(&frame, None);
            }
            Either4::Third(Some(Event::Joined(client))) => clients.join(client),
            Either4::Third(Some(Event::Frame {
                client,
                frame,
                credit,
            })) => {
                view.network.frames_in.set(view.network.frames_in.get() + 1);
                to_wire.push(PcNode::Network(client), (frame, now(), Some(credit)));
            }
            Either4::Third(Some(Event::Refused { client, why })) => {
                view.output
                    .message(&format!("socketcand: client {client}: ignored: {why}"));
            }
            Either4::Third(Some(Event::Left { client, why })) if client == socketcan::NODE => {
                view.output
                    .message(&format!("socketcan: {why}; the bus runs on without it"));
            }
            Either4::Third(Some(Event::Left { client, why })) => clients.leave(client, &why),
            // No server (--no-socketcand).
            Either4::Third(None) => network_open = false,
            Either4::Fourth((frame, sender)) => offer_sent(frame, sender, &slcan, &mut clients),
        }
    }
}

/// A PC frame has left the wire: every node but its sender has it.
fn offer_sent(
    frame: crate::can::SimFrame,
    sender: PcNode,
    slcan: &SlcanNode<'_>,
    clients: &mut Clients<'_>,
) {
    match sender {
        PcNode::Slcan => clients.offer(&frame, None),
        PcNode::Network(client) => {
            slcan.offer(&frame);
            clients.offer(&frame, Some(client));
        }
    }
}

/// The SLCAN adapter on the serial port.
struct SlcanNode<'a> {
    channel: slcan::Channel,
    port: &'a SerialPort,
    view: &'a View<'a>,
}

impl SlcanNode<'_> {
    /// Answers one line; returns the frame it puts on the bus, if any.
    fn handle_line(&mut self, line: &[u8]) -> Option<crate::can::SimFrame> {
        let counters = &self.view.slcan;
        let response = self.channel.handle_line(line);
        self.port.send(response.reply);
        match response.refusal {
            // python-can sends O twice when it opens a port (once after setting the bit
            // rate, once more); the second gets BEL, as from a real adapter, and is
            // nothing to report.
            Some(slcan::Refusal::ChannelOpen) if line == b"O" => {}
            Some(refusal) => self.view.output.message(&format!(
                "slcan: refused \"{}\": {refusal}",
                line.escape_ascii()
            )),
            None => {}
        }
        if response.transmit.is_some() {
            counters.frames_in.set(counters.frames_in.get() + 1);
        }
        self.show_state();
        response.transmit
    }

    /// The last program closed the port: the channel closes, as when an adapter is
    /// unplugged, so no frames wait for the next program.
    fn port_closed(&mut self) {
        self.channel = slcan::Channel::new(BITRATE_BPS);
        self.show_state();
    }

    fn show_state(&self) {
        let counters = &self.view.slcan;
        if self.channel.is_open() != counters.open.get() {
            counters.open.set(self.channel.is_open());
            let state = if self.channel.is_open() {
                "opened"
            } else {
                "closed"
            };
            self.view.output.message(&format!("slcan: channel {state}"));
        }
    }

    /// Passes a frame from the bus to the PC while the channel is open.
    fn offer(&self, frame: &crate::can::SimFrame) {
        if !self.channel.is_open() {
            return;
        }
        let counters = &self.view.slcan;
        // The adapter's millisecond counter, which wraps at 60 s.
        let timestamp_ms = self
            .channel
            .timestamps()
            .then(|| (now().as_millis() % 60_000) as u16);
        let counter = if self
            .port
            .send(::slcan::format_frame(frame, timestamp_ms).as_bytes())
        {
            &counters.frames_out
        } else {
            &counters.frames_dropped
        };
        counter.set(counter.get() + 1);
    }
}

/// The socketcand clients in raw mode.
struct Clients<'a> {
    clients: Vec<Client>,
    /// The SocketCAN interface, a node like the clients.
    socketcan: Option<&'a socketcan::SocketCanLink>,
    view: &'a View<'a>,
}

impl Clients<'_> {
    fn join(&mut self, client: Client) {
        self.view.output.message(&format!(
            "socketcand: client {} ({}) joined",
            client.id, client.address
        ));
        self.clients.push(client);
        self.count();
    }

    fn leave(&mut self, id: u64, why: &str) {
        // A client the hub dropped already is gone from the list.
        if let Some(index) = self.clients.iter().position(|client| client.id == id) {
            self.clients.remove(index);
            self.view
                .output
                .message(&format!("socketcand: client {id} left ({why})"));
            self.count();
        }
    }

    /// Hands `frame` to every client but its sender. A client whose queue is full has
    /// stopped reading: it is disconnected, so that it holds up no one.
    fn offer(&mut self, frame: &crate::can::SimFrame, sender: Option<u64>) {
        if let Some(link) = self.socketcan
            && sender != Some(socketcan::NODE)
            && !link.offer(*frame)
        {
            let network = &self.view.network;
            network.socketcan_lost.set(network.socketcan_lost.get() + 1);
        }
        if self.clients.is_empty() {
            return;
        }
        let message = socketcand::format_frame(frame, socketcand::wall_time());
        let network = &self.view.network;
        let view = self.view;
        self.clients.retain(|client| {
            if Some(client.id) == sender {
                return true;
            }
            if client.offer(message.clone()) {
                network.frames_out.set(network.frames_out.get() + 1);
                return true;
            }
            client.disconnect();
            network
                .dropped_clients
                .set(network.dropped_clients.get() + 1);
            view.output.message(&format!(
                "socketcand: client {} ({}) dropped: it read nothing while {} frames \
                 waited",
                client.id,
                client.address,
                socketcand::CLIENT_QUEUE
            ));
            false
        });
        self.count();
    }

    fn count(&self) {
        self.view.network.clients.set(self.clients.len() as u32);
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
            ConsoleCommand::DriveSilent { wheel, silent } => {
                robot.drives.set_silent(wheel.slave(), silent)
            }
            ConsoleCommand::Reboot { by_watchdog } => view.reboot.signal(if by_watchdog {
                Reset::Watchdog
            } else {
                Reset::Button
            }),
            ConsoleCommand::Panic => view.reboot.signal(Reset::Panic),
            ConsoleCommand::Status => view.output.message(&view.status_report()),
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
