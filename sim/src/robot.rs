//! The whole virtual robot: every simulated part wired to the firmware's real tasks.
//!
//! ```
//! use virtual_robot::robot::{VirtualRobot, wait_ms};
//!
//! let robot = VirtualRobot::new();
//! let position = robot.run(async |pc| {
//!     wait_ms(1_500).await; // the drives boot and are set up
//!     pc.drive(300, 0, 1_000).await; // enable + 300 mm/s every 50 ms
//!     pc.position()
//! });
//! assert!(position.is_some_and(|(x, _)| x > 200));
//! ```
//!
//! [`VirtualRobot::run`] boots the firmware (`base_runtime::run`) on the
//! virtual clock and runs the test script beside it; when the script returns, the
//! controller loses power. The drives, flash, pins and sensors outlive a run, so a
//! second `run` is a reboot of the controller alone.

use std::sync::{Arc, Mutex, PoisonError};

use base_core::can::{Command, RawFrame, Report, Status, id};
use base_core::controller::Input;
use base_core::gamepad::GamepadState;
use base_core::panic_loop::{Bluetooth, PanicHistory};
use base_core::registers::UpdateReset;
use base_core::remote::Pad;
use base_core::time::Timestamp;
use base_core::update::otadata::Slot;
use base_core::update::partitions;
use base_runtime::channels::Channels;
use base_runtime::sync::InputSender;
use base_runtime::update::{UpdateConfig, UpdateFlash};
use base_runtime::{Hardware, Settings};
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Timer};
use embedded_hal::digital::PinState;

use crate::can::{CanPeer, CanRxPort, CanTxPort, VirtualCan};
use crate::drives::{DrivesConfig, DrivesHandle, DrivesPort};
use crate::flash::RamFlash;
use crate::io::{SimBattery, SimLoadCell, SimPin, SimWatchdog};
use crate::runtime::{block_on, now};

/// The register store's partition: 4 pages of 4 KiB, as on the chip.
pub const FLASH_SIZE: u32 = 4 * 4096;
/// The board's hardware watchdog timeout.
pub const WATCHDOG_TIMEOUT: Duration = Duration::from_secs(2);

/// The virtual robot's hardware as the firmware's tasks take it.
pub type SimHardware = Hardware<
    CanRxPort,
    CanTxPort,
    DrivesPort,
    RamFlash,
    SimPin,
    SimPin,
    SimPin,
    SimPin,
    SimBattery,
    SimLoadCell,
    SimWatchdog,
>;

pub struct VirtualRobot {
    pub settings: Settings,
    pub drives: DrivesHandle,
    pub flash: RamFlash,
    /// E-stop loop: high = closed = released (the inputs are active low).
    pub estop: SimPin,
    pub safety_zone: SimPin,
    pub button: SimPin,
    pub pc_switch: SimPin,
    pub battery: SimBattery,
    pub load_cell: SimLoadCell,
    pub watchdog: SimWatchdog,
    /// Whether the next boot reports a watchdog reset.
    pub reset_by_watchdog: bool,
    /// The chip's RAM that survives a reset: the panic handler's record.
    pub rtc_ram: RtcRam,
    /// From power-on (the start of [`Self::run`]) until the firmware runs, as a chip's
    /// bootloader and start-up take about 0.3 s. The line is silent meanwhile. Zero by
    /// default.
    pub boot_time: Duration,
}

impl Default for VirtualRobot {
    fn default() -> Self {
        Self::new()
    }
}

impl VirtualRobot {
    /// A robot on the defaults: drives commissioned as docs/drives.md says (115200 8E1,
    /// 0.5 ms transmission waiting time) powered on now, a blank flash, all inputs
    /// released, a 24.5 V battery and an empty scale.
    pub fn new() -> Self {
        Self::with_drives(DrivesConfig::commissioned())
    }

    pub fn with_drives(config: DrivesConfig) -> Self {
        // Each boot takes its own end of the line from the handle.
        let (_, drives) = DrivesPort::new(config);
        Self {
            settings: Settings::DEFAULT,
            drives,
            flash: RamFlash::new(FLASH_SIZE as usize),
            estop: SimPin::new(PinState::High),
            safety_zone: SimPin::new(PinState::High),
            button: SimPin::new(PinState::High),
            pc_switch: SimPin::new(PinState::Low),
            battery: SimBattery::new(24_500),
            load_cell: SimLoadCell::new(8_000, 100.0),
            watchdog: SimWatchdog::new(WATCHDOG_TIMEOUT),
            reset_by_watchdog: false,
            rtc_ram: RtcRam::default(),
            boot_time: Duration::from_ticks(0),
        }
    }

    /// Boots the controller and runs `script` beside it, with the robot PC's end of
    /// the CAN bus; returns what the script returns.
    pub fn run<T>(&self, script: impl AsyncFnOnce(&Pc) -> T) -> T {
        let (hardware, pc) = self.boot();
        let channels = Channels::new();
        let firmware = async {
            Timer::after(self.boot_time).await;
            base_runtime::run(hardware, self.settings, &channels).await
        };
        block_on(async {
            match select(firmware, script(&pc)).await {
                Either::First(never) => never,
                Either::Second(result) => result,
            }
        })
    }

    /// [`Self::run`] with the firmware update task beside the firmware, as the chip runs
    /// it, on a blank app flash of its own (the update task answers QUERY; a run that
    /// writes an image needs the simulator's bootloader model instead).
    pub fn run_with_update<T>(&self, script: impl AsyncFnOnce(&Pc) -> T) -> T {
        let (hardware, pc) = self.boot();
        let channels = Channels::new();
        let app_flash = RamFlash::new(partitions::FLASH_SIZE as usize);
        let mut update_flash = UpdateFlash::new(app_flash, Slot::Ota0);
        let config = UpdateConfig {
            chip: crate::app_flash::SIM_CHIP,
            project: base_runtime::update::PROJECT,
            version: crate::app_flash::FACTORY_VERSION,
            security_version: 0,
            trust: base_core::update::signature::Trust::Development,
            trial_deadline_ms: base_runtime::update::TRIAL_DEADLINE_MS,
        };
        let firmware = async {
            Timer::after(self.boot_time).await;
            let started = base_runtime::update::arm(&mut update_flash).await;
            channels.update.lock_at_start(&started);
            // Blank otadata: the image starts confirmed, no trial to own.
            let update = base_runtime::update::run(
                &mut update_flash,
                started,
                None,
                &config,
                &channels.update,
                &channels.can_tx,
            );
            match select(
                base_runtime::run(hardware, self.settings, &channels),
                update,
            )
            .await
            {
                Either::First(never) => never,
                Either::Second(reset) => panic!("the update task asked for a reset: {reset:?}"),
            }
        };
        block_on(async {
            match select(firmware, script(&pc)).await {
                Either::First(never) => never,
                Either::Second(result) => result,
            }
        })
    }

    /// [`Self::run`] with pads scripted beside the PC: the script gets [`ScriptedPads`],
    /// which hand links and decoded reports to the controller where the remote tasks do
    /// (no radio, no HID decoding: what comes before that is the Bluetooth scenarios').
    pub fn run_with_pads<T>(&self, script: impl AsyncFnOnce(&Pc, &ScriptedPads<'_>) -> T) -> T {
        let (hardware, pc) = self.boot();
        let channels = Channels::new();
        let pads = ScriptedPads {
            inputs: channels.remote_ends().inputs,
        };
        let firmware = async {
            Timer::after(self.boot_time).await;
            base_runtime::run(hardware, self.settings, &channels).await
        };
        block_on(async {
            match select(firmware, script(&pc, &pads)).await {
                Either::First(never) => never,
                Either::Second(result) => result,
            }
        })
    }

    /// The hardware of one boot, and the robot PC's end of its CAN bus: for runs that
    /// add tasks beside the firmware's (the Bluetooth remote, see [`crate::ble`]).
    pub fn boot(&self) -> (SimHardware, Pc) {
        let (can_rx, can_tx, peer) = VirtualCan::new();
        let hardware = Hardware {
            can_rx,
            can_tx,
            drives: self.drives.port(),
            flash: self.flash.clone(),
            flash_range: 0..FLASH_SIZE,
            estop: self.estop.clone(),
            safety_zone: self.safety_zone.clone(),
            button: self.button.clone(),
            pc_switch: self.pc_switch.clone(),
            battery: self.battery.clone(),
            load_cell: self.load_cell.clone(),
            watchdog: self.watchdog.clone(),
            reset_by_watchdog: self.reset_by_watchdog,
            bluetooth: self.rtc_ram.boot(),
            update_reset: UpdateReset::None,
        };
        (hardware, Pc { peer })
    }

    pub fn press_estop(&self) {
        self.estop.set_level(PinState::Low);
    }

    pub fn release_estop(&self) {
        self.estop.set_level(PinState::High);
    }

    pub fn set_safety_zone(&self, occupied: bool) {
        self.safety_zone.set_level(if occupied {
            PinState::Low
        } else {
            PinState::High
        });
    }

    /// Runs `boot` (a run of this robot whose script ends in [`controller_panics`]) and
    /// takes the panic as the chip's panic handler does: recorded in [`Self::rtc_ram`]
    /// with the uptime, then the reset. Any other panic (a failed assertion in the
    /// script) is passed on.
    pub fn until_panic(&self, boot: impl FnOnce()) {
        let booted = now();
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(boot)) {
            Ok(()) => panic!("the run ended without the controller's panic"),
            Err(payload) if payload.is::<ControllerPanic>() => {
                let uptime = now() - booted;
                self.rtc_ram
                    .record_panic(Timestamp::from_millis(uptime.as_millis()));
            }
            Err(payload) => std::panic::resume_unwind(payload),
        }
    }

    /// Presses the front button for `hold_ms`, then releases it.
    pub async fn press_button(&self, hold_ms: u64) {
        self.button.set_level(PinState::Low);
        wait_ms(hold_ms).await;
        self.button.set_level(PinState::High);
    }
}

/// Pads scripted at the remote tasks' end of the controller's input queue: a link
/// report or a decoded report goes in as the BLE task or the PlayStation pad's task
/// would send it ([`VirtualRobot::run_with_pads`]).
pub struct ScriptedPads<'a> {
    inputs: InputSender<'a>,
}

impl ScriptedPads<'_> {
    /// `pad`'s task reports its pad bonded and connected, or its link down.
    pub async fn link(&self, pad: Pad, connected: bool) {
        self.send(Input::RemoteLink {
            pad,
            bonded: true,
            connected,
        })
        .await;
    }

    /// `pad`'s task hands on a decoded report.
    pub async fn report(&self, pad: Pad, state: GamepadState) {
        self.send(Input::Gamepad { pad, state }).await;
    }

    /// Queues `input` as a remote task does (waiting for room, as they do).
    pub async fn send(&self, input: Input) {
        self.inputs.send(input).await;
    }
}

/// The two words of the chip's RTC RAM that survive a reset but not a power-on, where
/// the panic handler leaves its [`PanicHistory`] for the next boot (the firmware's
/// `board::panic_record`). Shared by every boot of one robot, as the chip's RAM is.
#[derive(Debug, Clone)]
pub struct RtcRam(Arc<Mutex<[u32; 2]>>);

impl Default for RtcRam {
    /// Fresh from a power-on: noise, no history.
    fn default() -> Self {
        let ram = RtcRam(Arc::new(Mutex::new([0; 2])));
        ram.power_on();
        ram
    }
}

impl RtcRam {
    fn update<T>(&self, change: impl FnOnce(&mut PanicHistory) -> T) -> T {
        let mut words = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let mut history = PanicHistory::decode(*words);
        let result = change(&mut history);
        *words = history.encode();
        result
    }

    /// The boot's decision on Bluetooth, as the firmware's start makes it.
    pub fn boot(&self) -> Bluetooth {
        self.update(PanicHistory::at_boot)
    }

    /// The panic handler's record: the controller panicked `uptime` after its boot.
    pub fn record_panic(&self, uptime: Timestamp) {
        self.update(|history| history.on_panic(uptime));
    }

    /// Bluetooth was turned on by hand: the panics are forgotten.
    pub fn turned_on(&self) {
        self.update(PanicHistory::turned_on);
    }

    /// Panics in a row, each soon after its boot, so far.
    pub fn short_panics(&self) -> u8 {
        self.update(|history| history.short_panics())
    }

    /// The power was off: the RAM holds whatever it powers up with.
    pub fn power_on(&self) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = [0x5A5A_A5A5, 0x0003_FFFC];
    }
}

/// The payload of the virtual controller's panic ([`controller_panics`]).
#[derive(Debug)]
pub struct ControllerPanic;

/// The controller panics here, as a firmware task would (on the chip: a bug, or a
/// packet that crashes the Bluetooth stack); see [`VirtualRobot::until_panic`].
pub fn controller_panics() -> ! {
    std::panic::panic_any(ControllerPanic)
}

/// Waits `ms` of virtual time.
pub async fn wait_ms(ms: u64) {
    Timer::after_millis(ms).await;
}

/// The robot PC: sends commands and reads what the controller reported.
pub struct Pc {
    pub peer: CanPeer,
}

impl Pc {
    pub fn command(&self, command: Command) {
        self.send(command.encode());
    }

    pub fn send(&self, frame: RawFrame) {
        self.peer.send(frame.id(), frame.data());
    }

    pub fn enable(&self) {
        self.command(Command::Enable { refresh: true });
    }

    pub fn velocity(&self, linear_mm_s: i16, rotation_mrad_s: i16) {
        self.command(Command::Velocity {
            linear_mm_s,
            rotation_mrad_s,
        });
    }

    /// Sends the enable and the same velocity every `period_ms` for `duration_ms`, as
    /// the robot PC does while driving.
    pub async fn drive(&self, linear_mm_s: i16, rotation_mrad_s: i16, duration_ms: u64) {
        const PERIOD_MS: u64 = 50;
        let end = Instant::now() + Duration::from_millis(duration_ms);
        while Instant::now() < end {
            self.enable();
            self.velocity(linear_mm_s, rotation_mrad_s);
            wait_ms(PERIOD_MS).await;
        }
    }

    /// Every report the controller sent so far with this ID, decoded, with its time.
    pub fn reports(&self, frame_id: u16) -> Vec<(Instant, Report)> {
        self.peer
            .sent_with_id(frame_id)
            .into_iter()
            .filter_map(|sent| {
                let raw = RawFrame::from_frame(&sent.frame)?;
                let report = Report::decode(raw.id(), raw.data()).ok()??;
                Some((sent.at, report))
            })
            .collect()
    }

    /// Reads a register over CAN as the manual's untagged request and waits 50 ms for
    /// the first value reply after it (`None`: refused or no reply).
    pub async fn read_register(&self, address: u8) -> Option<u16> {
        let before = self.reports(id::REGISTER_READ).len();
        self.command(Command::RegisterRead { address, tag: 0 });
        wait_ms(50).await;
        self.reports(id::REGISTER_READ)
            .into_iter()
            .skip(before)
            .find_map(|(_, report)| match report {
                Report::RegisterValue { value, .. } => Some(value),
                _ => None,
            })
    }

    /// The newest report with this ID that `pick` accepts.
    fn last<T>(&self, frame_id: u16, pick: impl Fn(Report) -> Option<T>) -> Option<T> {
        self.reports(frame_id)
            .into_iter()
            .rev()
            .find_map(|(_, report)| pick(report))
    }

    /// The last position (x, y) in mm.
    pub fn position(&self) -> Option<(i32, i32)> {
        self.last(id::POSITION, |report| match report {
            Report::Position { x_mm, y_mm } => Some((x_mm, y_mm)),
            _ => None,
        })
    }

    /// The last heading in mrad.
    pub fn heading(&self) -> Option<i32> {
        self.last(id::HEADING, |report| match report {
            Report::Heading { heading_mrad } => Some(heading_mrad),
            _ => None,
        })
    }

    /// The last status frame.
    pub fn status(&self) -> Option<Status> {
        self.last(id::STATUS, |report| match report {
            Report::Status(status) => Some(status),
            _ => None,
        })
    }

    /// Waits (up to `timeout_ms`) for a status frame that satisfies `check`.
    pub async fn wait_for_status(
        &self,
        timeout_ms: u64,
        check: impl Fn(&Status) -> bool,
    ) -> Option<Status> {
        let end = Instant::now() + Duration::from_millis(timeout_ms);
        while Instant::now() < end {
            if let Some(status) = self.status().filter(|status| check(status)) {
                return Some(status);
            }
            wait_ms(10).await;
        }
        None
    }
}
