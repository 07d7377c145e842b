//! The whole base controller as one pure state machine: CAN frames, inputs, drive
//! feedback and sensor samples go in with the time; frames to send, wheel commands, the
//! brake, the PC switch and register changes to persist come out. The async tasks only
//! move these values between the peripherals and [`Controller::handle`].

use heapless::Vec;

use crate::battery::{self, BatteryFilter, BatteryParams};
use crate::calibration::odometry::OdometryCalibration;
use crate::calibration::scale::{ScaleCalibration, ScaleUpdate};
use crate::can::{BULK_READ_MAX, Command, FrameError, RawFrame, ReadEcho, Rejection, Report};
use crate::can::{Faults, Mode, Status, StatusFlags};
use crate::drives::AT_REST_RPM;
use crate::feedback::{FeedbackPeriods, FeedbackSchedule};
use crate::gamepad::GamepadState;
use crate::kinematics::{self, KinematicsParams, MotorRpm, SafetyLimits, Twist, WheelCommand};
use crate::odometry::{self, EncoderCounts, Odometry, OdometryParams};
use crate::plausibility::{self, Commanded, FeedbackCheck, SpeedRange};
use crate::power::{self, PowerControl, SwitchLevel};
use crate::registers::{
    BLE_OFF_AFTER_HOST_STOPS, BLUETOOTH_OFF_AFTER_PANICS, BootInfo, MOTOR_DIR_INVERT_LEFT,
    MOTOR_DIR_INVERT_RIGHT, RESTORE_DEFAULTS_KEY, Reg, RegisterError, Registers, RemoteInfo,
    WriteOutcome,
};
use crate::remote::{self, Control, Pad, PadArbiter, PairingWindow, Remote};
use crate::scale::{self, RawAverage};
use crate::supervisor::{self, Setpoint, Supervisor, Wheel};
use crate::time::Timestamp;

/// BLV R position counters: 0.01° of the motor shaft per count.
pub const COUNTS_PER_MOTOR_REV: f64 = 36_000.0;

/// HX711 samples averaged for one weight value (at 10 Hz: the last second).
pub const SCALE_AVERAGE_SAMPLES: usize = 10;

/// Everything that can happen to the controller.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Input {
    /// A standard-ID data frame from the bus (extended and RTR frames never get here).
    CanFrame(RawFrame),
    /// Debounced e-stop input (true = pressed).
    Estop(bool),
    /// Debounced safety-zone input (true = someone is in the zone).
    SafetyZone(bool),
    /// Debounced front button (true = held down).
    Button(bool),
    /// A connected pad's state from its task's decoder, sent on every report (pads
    /// report only when something changed). Only the pad in control's count
    /// ([`crate::remote::arbiter`]); [`crate::remote`] says what they mean.
    Gamepad {
        pad: Pad,
        state: GamepadState,
    },
    /// A remote task's link, sent at boot and on every change: whether its pad is
    /// bonded, and whether it is connected (link encrypted, reports flowing).
    /// `connected: false` of the pad in control is a link loss: a held dead-man brakes
    /// with `Contr_acc_high`.
    RemoteLink {
        pad: Pad,
        bonded: bool,
        connected: bool,
    },
    /// A remote task bonded a new pad: the pairing window closes, one new pad per opening.
    RemotePaired,
    /// A connected pad's kind and battery, for the PC (`remote_kind`, `remote_battery`
    /// show the pad in control's). The Classic task sends it once it knows the pad's
    /// kind and again when the battery reading changes, not on every report; the BLE
    /// task sends none (a BLE pad). A disconnect clears it.
    RemoteInfo {
        pad: Pad,
        info: RemoteInfo,
    },
    /// The radio guard refused a packet of `pad`'s link and closed it (counted as
    /// [`Rejection::RadioPacketRefused`]; the task backs off before the next attempt).
    RadioPacketRefused {
        pad: Pad,
    },
    /// The BLE task gave up its host: it stopped three times within a minute. BLE pads
    /// stay off until a confirm press or [`crate::registers::BLUETOOTH_ON_KEY`]
    /// ([`Output::bluetooth_on`]); register 36 says so.
    BleHostOff,
    /// The update task's word, sent on every change: a firmware update runs or a new
    /// image is on trial (`true`), so velocity, a refreshing enable and the gamepad's
    /// dead-man are refused; or neither.
    UpdateLock(bool),
    /// One cycle of drive feedback: raw position counters and measured motor speeds.
    DriveFeedback {
        counts: EncoderCounts,
        rpm: MotorRpm,
    },
    /// The drive link finished setting up both drives. Sent once after boot and once
    /// after each [`Output::setup_drives`] request, never on its own: a drive that lost
    /// power unasked is reported as [`Input::DriveSilent`] first.
    DrivesReady,
    DriveSilent(Wheel),
    DriveAlarm {
        wheel: Wheel,
        code: u8,
    },
    /// A Modbus reply was garbled or missing.
    ModbusError,
    /// One raw HX711 reading; the controller averages the last few.
    ScaleSample(i32),
    /// The load cell did not answer.
    ScaleMissing,
    /// A battery voltage sample in mV (after the board's divider).
    BatterySample {
        voltage_mv: u16,
    },
    /// The CAN controller went bus-off or lost received frames.
    CanBusFault,
    /// The register store was corrupt or unreadable at boot, or a write failed.
    FlashFault,
    /// The register store's page erases so far (its wear), for `flash_erases_hi`/`_lo`:
    /// sent at boot and whenever the count changed.
    FlashErases(u32),
    /// Time passed: timeouts and periodic frames are checked.
    Tick,
}

impl Input {
    /// A pad's link, report, kind or bond: what only the remote tasks send.
    pub fn is_from_a_remote_task(&self) -> bool {
        matches!(
            self,
            Input::Gamepad { .. }
                | Input::RemoteLink { .. }
                | Input::RemotePaired
                | Input::RemoteInfo { .. }
                | Input::RadioPacketRefused { .. }
        )
    }
}

/// What the shell found while booting, before the controller's first input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BootReport {
    /// The register store was corrupt or unreadable ([`crate::registers::LoadReport::flash_fault`]).
    pub flash_fault: bool,
    /// The last reset was the watchdog's (a panic resets as the watchdog does).
    pub watchdog_reset: bool,
    /// The register store's page erases so far.
    pub flash_erases: u32,
    /// The Bluetooth remote stays off: the last resets were a panic loop
    /// ([`crate::panic_loop`]).
    pub bluetooth_off_after_panics: bool,
    /// A first boot, an update's reset: register `boot_info`.
    pub boot_info: BootInfo,
}

/// Register changes the flash task must persist.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Persist {
    /// (address, new value) of each changed register.
    pub changed: Vec<(u8, u16), 4>,
    /// Every register went back to its default.
    pub defaults_restored: bool,
}

/// What one input asks the shell to do. Empty fields mean "nothing".
#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Output {
    /// Frames to transmit, in order.
    pub frames: Vec<RawFrame, 8>,
    /// The replies to one bulk register read, in address order. The shell queues them
    /// as one batch apart from the single replies, so that programs flooding the bus
    /// with single reads cannot crowd them out.
    pub bulk_replies: Vec<RawFrame, { BULK_READ_MAX as usize }>,
    /// A new command for both wheels: send it to the drives at once.
    pub wheels: Option<WheelCommand>,
    /// Excite (`true`, brakes released) or de-excite (`false`, brakes close) the drives.
    pub excite: Option<bool>,
    /// Set both drives up from scratch, then report [`Input::DrivesReady`].
    pub setup_drives: bool,
    /// Close or open the PC power switch.
    pub pc_switch: Option<SwitchLevel>,
    pub persist: Persist,
    /// Disconnect this pad, the one in control (L2 + Home, or no input for
    /// `PS_afk_time`), keeping its bond; its task then reports [`Input::RemoteLink`]
    /// with `connected: false`. Repeated while a pad asked to go keeps reporting.
    pub disconnect_remote: Option<Pad>,
    /// The pairing window opened (`true`; again for each opening command, which
    /// restarts it) or closed (`false`). It is closed at boot. While it is closed the
    /// BLE task connects only to the bonded pad and accepts no pairing request.
    pub pairing_window: Option<bool>,
    /// Bluetooth was off after a panic loop, or the BLE task gave up its host, and is
    /// turned on now (a confirm press of the front button, or
    /// [`crate::registers::BLUETOOTH_ON_KEY`]): start the remote (and forget the
    /// panics), or start the BLE host again.
    pub bluetooth_on: bool,
}

/// Counts and remembers rejected inputs for the status frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Rejections {
    count: u8,
    last_code: u8,
    last_subject: u8,
}

impl Rejections {
    fn record(&mut self, code: u8, subject: u8) {
        self.count = self.count.wrapping_add(1);
        self.last_code = code;
        self.last_subject = subject;
    }
}

/// Latched faults the shell reports; the drive faults live in the supervisor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct ShellFaults {
    flash: bool,
    scale: bool,
    can_bus: bool,
    watchdog_reset: bool,
}

pub struct Controller {
    registers: Registers,
    supervisor: Supervisor,
    odometry: Odometry,
    odometry_calibration: OdometryCalibration,
    scale_calibration: ScaleCalibration,
    power: PowerControl,
    battery: BatteryFilter,
    battery_mv: Option<u16>,
    scale: RawAverage<SCALE_AVERAGE_SAMPLES>,
    feedback: FeedbackSchedule,
    /// The supervisor's latest setpoint: what the wheels follow until the next one.
    setpoint: Setpoint,
    /// The wheel command last sent: the drives ramp towards it.
    in_force: WheelCommand,
    /// What the drives run at, from the latest measurement; the next ramp starts here.
    speed: SpeedEstimate,
    /// What the drives would run at had each followed every command since the last
    /// setup, from the moment it was sent: the commanded ramps alone, never moved to a
    /// measurement, so that a wheel turning against its command cannot drag it along.
    /// The feedback check compares each wheel's direction with it.
    commanded_speed: SpeedEstimate,
    /// How much that model's acceleration changed since the last drive feedback,
    /// summed, (r/min)/s (left, right): where its speed bent between two samples,
    /// which the feedback check allows for.
    commanded_bends: [f64; 2],
    /// Every target the drives were told since the last drive feedback (left, right),
    /// `None` if none: a target in force for a few ms between two samples still
    /// counts as commanded for the feedback check's direction test.
    told_targets: Option<[SpeedRange; 2]>,
    rejections: Rejections,
    faults: ShellFaults,
    /// Which of the connected pads controls the remote; the links for the status frame.
    pads: PadArbiter,
    remote: Remote,
    pairing: PairingWindow,
    modbus_errors: u8,
    /// When the last drive feedback arrived and the speeds it reported: for the
    /// odometry's plausibility check, and to carry the pose to the moment of each
    /// position frame.
    last_feedback: Option<(Timestamp, MotorRpm)>,
    /// Whether each drive's position counter and reported speed agree.
    feedback_check: FeedbackCheck,
    /// Register values wait for the flash (the runtime's store says so).
    persist_pending: bool,
    /// Both drives confirmed de-excited (the drive link's word).
    drive_brakes_confirmed: bool,
}

impl Controller {
    /// A controller starting at `now` with the registers the flash task loaded.
    pub fn new(now: Timestamp, registers: Registers) -> Self {
        Self {
            registers,
            supervisor: Supervisor::new(),
            odometry: Odometry::new(),
            odometry_calibration: OdometryCalibration::new(),
            scale_calibration: ScaleCalibration::new(),
            power: PowerControl::new(),
            battery: BatteryFilter::default(),
            battery_mv: None,
            scale: RawAverage::new(),
            feedback: FeedbackSchedule::new(now),
            setpoint: Setpoint {
                twist: Twist::ZERO,
                accel_rpm_per_s: 0,
            },
            in_force: STANDING,
            speed: SpeedEstimate::standing(now),
            commanded_speed: SpeedEstimate::standing(now),
            commanded_bends: [0.0; 2],
            told_targets: None,
            rejections: Rejections::default(),
            faults: ShellFaults::default(),
            pads: PadArbiter::new(),
            remote: Remote::new(),
            pairing: PairingWindow::Closed,
            modbus_errors: 0,
            last_feedback: None,
            feedback_check: FeedbackCheck::new(),
            persist_pending: false,
            drive_brakes_confirmed: false,
        }
    }

    /// A controller starting at `now`, with what the shell found while booting: the
    /// first status frame carries every boot fault at once.
    pub fn boot(now: Timestamp, registers: Registers, report: &BootReport) -> Self {
        let mut controller = Self::new(now, registers);
        controller.faults.flash = report.flash_fault;
        controller.faults.watchdog_reset = report.watchdog_reset;
        controller.set_flash_erases(report.flash_erases);
        if report.bluetooth_off_after_panics {
            controller
                .registers
                .set_counter(Reg::BluetoothOff, BLUETOOTH_OFF_AFTER_PANICS);
        }
        controller
            .registers
            .set_counter(Reg::BootInfo, report.boot_info.to_bits());
        controller
    }

    /// Bluetooth is off after a panic loop, until a confirm press or its key: no remote
    /// task runs.
    fn bluetooth_off_after_panics(&self) -> bool {
        self.registers.get(Reg::BluetoothOff) == BLUETOOTH_OFF_AFTER_PANICS
    }

    /// Turns the Bluetooth remote on if a panic loop switched it off at boot, or the
    /// BLE task gave up its host.
    fn turn_bluetooth_on(&mut self, out: &mut Output) {
        if self.registers.get(Reg::BluetoothOff) != 0 {
            info!("Bluetooth on again");
            self.registers.set_counter(Reg::BluetoothOff, 0);
            out.bluetooth_on = true;
        }
    }

    fn set_flash_erases(&mut self, erases: u32) {
        self.registers
            .set_counter(Reg::FlashErasesHi, (erases >> 16) as u16);
        self.registers
            .set_counter(Reg::FlashErasesLo, erases as u16);
    }

    /// The runtime's word on whether register values still wait for the flash (it
    /// writes only at standstill), for the status frame.
    pub fn set_persist_pending(&mut self, pending: bool) {
        self.persist_pending = pending;
    }

    /// The drive link's word on whether both drives confirmed they are de-excited
    /// ([`crate::drives::link::DriveLink::brakes_confirmed`]).
    pub fn set_drive_brakes_confirmed(&mut self, confirmed: bool) {
        self.drive_brakes_confirmed = confirmed;
    }

    /// What an update's BEGIN needs to know: the base stands braked and nobody
    /// controls it.
    pub fn update_gate(&self, now: Timestamp) -> crate::update::session::MotionGate {
        crate::update::session::MotionGate {
            at_standstill: self.at_standstill(now),
            brakes_applied: self.brakes_applied(),
            control_active: self.supervisor.enable_fresh(now, &self.supervisor_params())
                || self.supervisor.remote_in_control(),
        }
    }

    /// The brakes hold the base: the supervisor commanded S-OFF and both drives
    /// confirmed it (a silent drive counts as turning until its own communication
    /// timeout has surely tripped). The status frame says this, and flash is written
    /// only then: nothing may stall the loop while a wheel may still turn.
    pub fn brakes_applied(&self) -> bool {
        self.supervisor.brakes_applied() && self.drive_brakes_confirmed
    }

    pub fn registers(&self) -> &Registers {
        &self.registers
    }

    pub fn supervisor(&self) -> &Supervisor {
        &self.supervisor
    }

    pub fn odometry(&self) -> &Odometry {
        &self.odometry
    }

    /// When the next position frame goes out; the drive link reads the drives half a
    /// cycle before it, so each frame carries one fresh reading.
    pub fn position_due_at(&self) -> Timestamp {
        self.feedback.odometry_due_at()
    }

    /// Handles one input at `now`. Periodic frames that are due go out with whatever
    /// the input caused, so the shell may feed frames and ticks in any mix.
    pub fn handle(&mut self, now: Timestamp, input: Input) -> Output {
        let mut out = Output::default();
        if self.bluetooth_off_after_panics() && input.is_from_a_remote_task() {
            // The remote tasks do not run while Bluetooth is off; should anything
            // still come from them, no pad may connect or drive.
            warn!("remote input while Bluetooth is off dropped");
            self.periodic_frames(now, &mut out);
            return out;
        }
        match input {
            Input::CanFrame(frame) => self.can_frame(now, frame, &mut out),
            Input::Estop(pressed) => {
                self.supervise(now, supervisor::Event::Estop { pressed }, &mut out)
            }
            Input::SafetyZone(occupied) => {
                self.supervise(now, supervisor::Event::SafetyZone { occupied }, &mut out)
            }
            Input::Button(pressed) => {
                let event = if pressed {
                    power::Event::ButtonPressed
                } else {
                    power::Event::ButtonReleased
                };
                self.power_event(now, event, &mut out);
            }
            Input::Gamepad { pad, state } => {
                // The other pad's buttons neither arm, hold nor release anything.
                if self.pads.admit_report(pad, &state) {
                    self.remote_step(now, remote::Event::Report(state), None, &mut out);
                }
            }
            Input::RemoteLink {
                pad,
                bonded,
                connected,
            } => {
                let handover = self.pads.link(pad, bonded, connected);
                if handover.lost {
                    self.remote_step(now, remote::Event::Disconnected, None, &mut out);
                }
                if handover.gained {
                    self.remote_step(now, remote::Event::Connected, None, &mut out);
                    if handover.dead_man_held {
                        // Pressed while the pad waited, it is not reported again; the
                        // dead-man alone (sticks centred, its other buttons dropped as
                        // before) is the new connection's first report: held, not
                        // armed, it takes control from CAN and stops the base.
                        let dead_man_alone = GamepadState {
                            buttons: remote::DEAD_MAN,
                            ..GamepadState::default()
                        };
                        self.remote_step(
                            now,
                            remote::Event::Report(dead_man_alone),
                            None,
                            &mut out,
                        );
                    }
                }
                self.registers.set_remote_info(self.pads.info());
            }
            Input::RemotePaired => {
                if self.pairing.close() {
                    out.pairing_window = Some(false);
                } else {
                    // The BLE task must not pair without the window; nothing here can
                    // undo a bond, but the log shows it.
                    warn!("a gamepad was paired while the pairing window was closed");
                }
            }
            Input::RemoteInfo { pad, info } => {
                self.pads.set_info(pad, info);
                self.registers.set_remote_info(self.pads.info());
            }
            Input::RadioPacketRefused { pad } => {
                // Subject: 1 a BLE pad, 2 a PlayStation pad (as `remote_kind` counts).
                let subject = match pad {
                    Pad::Ble => 1,
                    Pad::Classic => 2,
                };
                self.rejections
                    .record(Rejection::RadioPacketRefused.code(), subject);
            }
            Input::BleHostOff => {
                // A panic loop's "all off" says more, and stays.
                if self.registers.get(Reg::BluetoothOff) == 0 {
                    warn!("the BLE host stays stopped: BLE pads off until turned on");
                    self.registers
                        .set_counter(Reg::BluetoothOff, BLE_OFF_AFTER_HOST_STOPS);
                }
            }
            Input::UpdateLock(locked) => {
                self.supervise(now, supervisor::Event::MotionLock { locked }, &mut out)
            }
            Input::DriveFeedback { counts, rpm } => self.drive_feedback(now, counts, rpm, &mut out),
            Input::DrivesReady => {
                // The counters restarted with the drives' power: the next sample is a
                // baseline. Set up from scratch (only a starting or recovering base asked
                // for it), the drives stand and were told nothing yet; one that comes
                // unasked changes nothing about what the wheels do.
                self.odometry.rebaseline();
                self.feedback_check.restart();
                if matches!(self.supervisor.mode(), Mode::Starting | Mode::Recovering) {
                    self.in_force = STANDING;
                    self.speed = SpeedEstimate::standing(now);
                    self.commanded_speed = SpeedEstimate::standing(now);
                    self.commanded_bends = [0.0; 2];
                    self.told_targets = None;
                }
                self.supervise(now, supervisor::Event::DrivesReady, &mut out);
            }
            Input::DriveSilent(wheel) => {
                self.supervise(now, supervisor::Event::DriveSilent(wheel), &mut out)
            }
            Input::DriveAlarm { wheel, code } => {
                self.supervise(now, supervisor::Event::DriveAlarm { wheel, code }, &mut out)
            }
            Input::ModbusError => self.modbus_errors = self.modbus_errors.wrapping_add(1),
            Input::ScaleSample(raw) => {
                self.faults.scale = false;
                self.scale.push(raw);
            }
            Input::ScaleMissing => self.faults.scale = true,
            Input::BatterySample { voltage_mv } => {
                self.battery_mv = Some(self.battery.update(now, voltage_mv));
            }
            Input::CanBusFault => self.faults.can_bus = true,
            Input::FlashFault => self.faults.flash = true,
            Input::FlashErases(erases) => self.set_flash_erases(erases),
            Input::Tick => {
                if self.pairing.expire(now) {
                    info!("pairing window closed: time is up");
                    out.pairing_window = Some(false);
                }
                self.remote_step(
                    now,
                    remote::Event::Tick,
                    Some(supervisor::Event::Tick),
                    &mut out,
                );
                self.power_event(now, power::Event::Tick, &mut out);
            }
        }
        self.periodic_frames(now, &mut out);
        out
    }

    /// The motor speeds the drives are estimated to run at now (as sent to each drive,
    /// inversion applied): the latest measurement, moved along the commanded ramp since.
    /// The next wheel command ramps from here. Limited to ±`max_motor_vel`: no command
    /// is ever faster, so a reading beyond it is garbage, and believing it would stretch
    /// the other wheel's share of a stop without bound.
    pub fn estimated_rpm(&self, now: Timestamp) -> MotorRpm {
        let limit = i32::from(self.registers.get(Reg::MaxMotorVel));
        let rpm = self.speed.advanced(now, &self.in_force).rpm();
        MotorRpm {
            left: rpm.left.clamp(-limit, limit),
            right: rpm.right.clamp(-limit, limit),
        }
    }

    /// The base stands: zero is commanded, the latest feedback measured both wheels at
    /// rest, and the commanded ramp has run down since (a measurement from before a
    /// stop, or from the setup before any feedback, says nothing about now). Only then
    /// are motion registers and restore-defaults accepted.
    pub fn at_standstill(&self, now: Timestamp) -> bool {
        let standing = -AT_REST_RPM..=AT_REST_RPM;
        let estimate = self.estimated_rpm(now);
        self.in_force.rpm == MotorRpm::ZERO
            && self.supervisor.at_rest()
            && standing.contains(&estimate.left)
            && standing.contains(&estimate.right)
    }

    /// The CAN frames the transmit queue dropped since boot, for `can_tx_dropped`
    /// (saturating at 65535). The shell sets it before each input.
    pub fn set_can_tx_dropped(&mut self, dropped: u32) {
        let value = u16::try_from(dropped).unwrap_or(u16::MAX);
        self.registers.set_counter(Reg::CanTxDropped, value);
    }

    /// The status frame as it would be sent now.
    pub fn status(&self, now: Timestamp) -> Status {
        let supervisor = &self.supervisor;
        let drive = supervisor.faults();
        Status {
            mode: supervisor.mode(),
            control: supervisor.control(),
            persist_pending: self.persist_pending,
            flags: StatusFlags {
                enable_fresh: supervisor.enable_fresh(now, &self.supervisor_params()),
                pc_on: self.power.pc_on(now, &power_params(&self.registers)),
                safety_zone: supervisor.safety_zone(),
                remote_bonded: self.pads.bonded(),
                remote_connected: self.pads.connected(),
                remote_in_control: supervisor.remote_in_control(),
                estop_pressed: supervisor.estop_pressed(),
                brakes_applied: self.brakes_applied(),
            },
            faults: Faults {
                left_drive_silent: drive.left_silent,
                left_drive_alarm: drive.left_alarm,
                right_drive_silent: drive.right_silent,
                right_drive_alarm: drive.right_alarm,
                flash: self.faults.flash,
                scale: self.faults.scale,
                can_bus: self.faults.can_bus,
                watchdog_reset: self.faults.watchdog_reset,
            },
            rejected_count: self.rejections.count,
            last_rejection: self.rejections.last_code,
            last_rejection_subject: self.rejections.last_subject,
            drive_alarm: drive.last_alarm_code,
            modbus_errors: self.modbus_errors,
        }
    }

    fn can_frame(&mut self, now: Timestamp, frame: RawFrame, out: &mut Output) {
        let command = match Command::decode(frame.id(), frame.data()) {
            Ok(Some(command)) => command,
            Ok(None) => return,
            Err(error) => {
                self.reject_frame(frame.id(), error);
                return;
            }
        };
        let moves = matches!(
            command,
            Command::Enable { refresh: true } | Command::Velocity { .. }
        );
        if moves && self.supervisor.motion_locked() {
            self.rejections.record(
                Rejection::UpdateInProgress.code(),
                frame_subject(frame.id()),
            );
            return;
        }
        match command {
            Command::Enable { refresh } => {
                self.supervise(now, supervisor::Event::CanEnable { refresh }, out)
            }
            Command::Velocity {
                linear_mm_s,
                rotation_mrad_s,
            } => {
                let twist = Twist {
                    linear_mm_s: i32::from(linear_mm_s),
                    rotation_mrad_s: i32::from(rotation_mrad_s),
                };
                self.supervise(now, supervisor::Event::CanVelocity(twist), out);
            }
            Command::RegisterWrite { address, value } => {
                self.write_register(now, address, value, out);
            }
            Command::RegisterRead { address, tag } => {
                let report = self.read_reply(address, tag);
                if let Report::RegisterReadError { reason, .. } = report {
                    self.rejections.record(reason, address);
                }
                push_frame(out, report.encode());
            }
            Command::RegisterBulkRead { first, count, tag } => {
                // An address without a register inside the range gets its refusal and
                // is not counted as a rejection: the PC asked for a range, and the
                // table's gaps are not its mistake.
                for address in (first..=u8::MAX).take(usize::from(count)) {
                    let pushed = out
                        .bulk_replies
                        .push(self.read_reply(address, tag).encode());
                    debug_assert!(pushed.is_ok(), "the codec bounds a bulk read");
                }
            }
            Command::ResetOdometry => self.odometry.reset(),
            Command::Heartbeat => self.power_event(now, power::Event::Heartbeat, out),
            Command::ScaleCalibration(step) => {
                let offset = self.registers.weight_offset();
                match self
                    .scale_calibration
                    .step(step, self.scale.average(), offset)
                {
                    Ok(Some(ScaleUpdate::Offset(value))) => {
                        let outcome = self.registers.set_weight_offset(value);
                        self.register_written(now, Reg::WeightOffset as u8, outcome, out);
                    }
                    Ok(Some(ScaleUpdate::ScaleValue(value))) => {
                        self.write_register(now, Reg::ScaleValue as u8, value, out)
                    }
                    Ok(None) => {}
                    Err(error) => self
                        .rejections
                        .record(error.code(), frame_subject(frame.id())),
                }
            }
            Command::OdometryCalibration(step) => match self.odometry_calibration.step(step) {
                Ok(Some(factors)) => {
                    for (reg, value) in [
                        (Reg::FCw, factors.f_cw),
                        (Reg::FCcw, factors.f_ccw),
                        (Reg::FLin, factors.f_lin),
                    ] {
                        if let Some(value) = value {
                            self.write_register(now, reg as u8, value, out);
                        }
                    }
                }
                Ok(None) => {}
                Err(error) => self
                    .rejections
                    .record(error.code(), frame_subject(frame.id())),
            },
        }
    }

    fn reject_frame(&mut self, id: u16, error: FrameError) {
        self.rejections.record(error.code(), frame_subject(id));
    }

    /// The reply to a read of `address` with `tag`. Every reply says which read it
    /// answers: with several programs on the bus, a reply without it could be taken
    /// for another register's value.
    fn read_reply(&self, address: u8, tag: u16) -> Report {
        match self.registers.read(address) {
            Ok(value) => Report::RegisterValue {
                value,
                echo: Some(ReadEcho { address, tag }),
            },
            Err(error) => Report::RegisterReadError {
                address,
                reason: error.code(),
                tag: Some(tag),
            },
        }
    }

    /// Validates and applies a register write; a change is handed to the flash task and
    /// takes effect at once, because every parameter struct is built from the registers
    /// at the moment it is used, and a supervisor step applies it to the running command.
    /// A new value for a motion register, and restore-defaults, are refused with
    /// `NotAtRest` unless the base stands: a geometry, direction or limit that changes
    /// under a moving base turns a straight drive into a spin. So is a new value for a
    /// register that shapes the stop ([`Reg::shapes_stop`]): a stop must not be
    /// stretched by a write while the base moves.
    fn write_register(&mut self, now: Timestamp, address: u8, value: u16, out: &mut Output) {
        let changes_motion = match Reg::from_address(address) {
            Some(Reg::Command) => value == RESTORE_DEFAULTS_KEY,
            Some(reg) => {
                reg.needs_standstill()
                    && reg.info().accepts(value)
                    && self.registers.get(reg) != value
            }
            None => false,
        };
        if changes_motion && !self.at_standstill(now) {
            self.reject_register(address, RegisterError::NotAtRest);
            return;
        }
        let outcome = self.registers.write(address, value);
        self.register_written(now, address, outcome, out);
    }

    /// Acts on the outcome of a register write to `address`.
    fn register_written(
        &mut self,
        now: Timestamp,
        address: u8,
        outcome: Result<WriteOutcome, RegisterError>,
        out: &mut Output,
    ) {
        if matches!(
            outcome,
            Ok(WriteOutcome::Changed { .. } | WriteOutcome::DefaultsRestored)
        ) {
            // Without a step a lowered max_motor_vel (or a new gear ratio, radius,
            // motor_dir or safety limit) would wait for the next change of the twist,
            // which never comes while the PC repeats the same velocity or the gamepad's
            // stick is held still. The remote maps a held stick again first (a new
            // wheel_dist or speed-level limit changes its twist).
            self.remote_step(
                now,
                remote::Event::ParamsChanged,
                Some(supervisor::Event::Tick),
                out,
            );
        }
        match outcome {
            Ok(WriteOutcome::Changed { address, value }) => {
                // Four slots cover the largest batch (the three odometry factors).
                let pushed = out.persist.changed.push((address, value));
                debug_assert!(pushed.is_ok(), "more register changes than Persist holds");
            }
            Ok(WriteOutcome::OffsetChanged) => {
                // Three slots of four: the offset comes alone (a write of 19, 44 or 45,
                // or a tare).
                for change in self.registers.weight_offset_records() {
                    let pushed = out.persist.changed.push(change);
                    debug_assert!(pushed.is_ok(), "more register changes than Persist holds");
                }
            }
            Ok(WriteOutcome::Unchanged) => {}
            Ok(WriteOutcome::DefaultsRestored) => out.persist.defaults_restored = true,
            Ok(WriteOutcome::PairingWindowRequested) => {
                info!("pairing window open");
                self.pairing.open(now);
                out.pairing_window = Some(true);
            }
            Ok(WriteOutcome::BluetoothOnRequested) => self.turn_bluetooth_on(out),
            Err(error) => self.reject_register(address, error),
        }
    }

    fn reject_register(&mut self, address: u8, error: RegisterError) {
        self.rejections.record(error.code(), address);
    }

    fn drive_feedback(
        &mut self,
        now: Timestamp,
        counts: EncoderCounts,
        rpm: MotorRpm,
        out: &mut Output,
    ) {
        let params = self.odometry_params();
        let elapsed_ms = self.last_feedback.map_or(0, |(at, _)| now.millis_since(at));
        self.last_feedback = Some((now, rpm));
        let max_motor_rpm = u32::from(self.registers.get(Reg::MaxMotorVel));
        let jumped = self
            .odometry
            .discontinuity(&params, counts, max_motor_rpm, elapsed_ms);
        if jumped != 0 {
            warn!(
                "drive counter discontinuity (wheel mask {=u8}): odometry re-baselined",
                jumped
            );
            // Shown like a rejection (the subject says which wheel: 1 left, 2 right, 3 both).
            self.rejections
                .record(Rejection::OdometryDiscontinuity.code(), jumped);
            self.odometry.rebaseline();
            self.feedback_check.restart();
        }
        if let Some(motion) = self.odometry.update(&params, counts) {
            self.odometry_calibration
                .observe(motion.distance_mm, motion.rotation_mrad);
        }
        self.speed = SpeedEstimate::measured(now, rpm);
        self.advance_commanded_speed(now);
        let target = self.in_force.rpm;
        let in_force = [SpeedRange::of(target.left), SpeedRange::of(target.right)];
        let targets = self.told_targets.take().map_or(in_force, |[left, right]| {
            [left.with(in_force[0]), right.with(in_force[1])]
        });
        let commanded = Commanded {
            expected: self.commanded_speed.rpm(),
            target,
            targets,
            bends_rpm_per_s: core::mem::take(&mut self.commanded_bends),
        };
        let verdict =
            self.feedback_check
                .sample(now, counts, rpm, commanded, params.counts_per_motor_rev);
        self.feedback_plausibility(now, &verdict, out);
        // Standing by the reported speed and by the counters: a stale speed register
        // must not let the brakes, the flash or a motion register through while the
        // shaft still turns.
        let at_rest = plausibility::speed_standing(rpm.left)
            && plausibility::speed_standing(rpm.right)
            && verdict.position_standing;
        self.supervise(now, supervisor::Event::AtRest(at_rest), out);
    }

    /// A drive whose counter and speed disagree, or whose counter runs against its
    /// command, latches a drive fault (zero with `estop_decel`, see the supervisor); the
    /// status frame shows why as a rejection (0x41 position stuck, 0x42 speed stale,
    /// 0x43 wrong direction; subject 1 left, 2 right).
    fn feedback_plausibility(
        &mut self,
        now: Timestamp,
        verdict: &plausibility::Verdict,
        out: &mut Output,
    ) {
        for (wheel, finding) in verdict.findings() {
            let subject = match wheel {
                Wheel::Left => 1,
                Wheel::Right => 2,
            };
            warn!(
                "drive feedback implausible (wheel {=u8}): the base stops",
                subject
            );
            self.rejections
                .record(Rejection::Feedback(finding).code(), subject);
            self.supervise(now, supervisor::Event::FeedbackImplausible(wheel), out);
        }
    }

    /// Moves the commanded model along the command in force until `now`.
    fn advance_commanded_speed(&mut self, now: Timestamp) {
        let (speed, bends) = self.commanded_speed.advanced_bending(now, &self.in_force);
        self.commanded_speed = speed;
        self.note_commanded_bends(bends);
    }

    fn note_commanded_bends(&mut self, bends: [f64; 2]) {
        self.commanded_bends[0] += bends[0];
        self.commanded_bends[1] += bends[1];
    }

    fn supervise(&mut self, now: Timestamp, event: supervisor::Event, out: &mut Output) {
        let effects = self.supervisor.step(now, event, &self.supervisor_params());
        if let Some(setpoint) = effects.setpoint {
            self.setpoint = setpoint;
        }
        // Mapped on every step, not only for a new setpoint, so that registers written
        // since then (and the safety zone's motor limit) apply to the running command
        // too. A new setpoint always goes out, even an unchanged zero (the e-stop edge).
        let zone = self.supervisor.safety_zone();
        let target = kinematics::motor_rpm(&self.kinematics_params(zone), self.setpoint.twist);
        // The ramp starts from what the wheels run at, not from the last target: a
        // command that interrupts a ramp then still brings both wheels in together.
        let start = self.estimated_rpm(now);
        let estop_decel = u32::from(self.registers.get(Reg::EstopDecel));
        // In the safety zone every slowing down brakes at least with estop_decel: a base
        // faster than the zone allows reaches its limits within 300 ms (the estop_decel
        // rule), whatever the source's own acceleration.
        let zone_brake = zone && slows_down(start, target);
        // An e-stop's or a fault's stop de-excites the drives `STOPPED_AFTER_MS` after
        // it began, which holds only if every wheel brakes with `estop_decel`. Shared
        // out by the measured speeds, a speed register frozen low (the fault itself,
        // perhaps) would give its wheel a gentle ramp: each wheel brakes with the full
        // rate.
        let hard_stop = matches!(self.supervisor.mode(), Mode::Fault | Mode::Emergency)
            && target == MotorRpm::ZERO;
        let weak_brake_in_force =
            self.in_force.left_accel.max(self.in_force.right_accel) < estop_decel;
        let a_weak_brake_in_force =
            self.in_force.left_accel.min(self.in_force.right_accel) < estop_decel;
        if effects.setpoint.is_some()
            || target != self.in_force.rpm
            || (zone_brake && weak_brake_in_force)
            || (hard_stop && a_weak_brake_in_force)
        {
            let mut accel = self.setpoint.accel_rpm_per_s;
            if zone_brake {
                accel = accel.max(estop_decel);
            }
            let mut command = kinematics::ramp(start, target, accel);
            if hard_stop {
                command.left_accel = command.left_accel.max(estop_decel);
                command.right_accel = command.right_accel.max(estop_decel);
            }
            if zone_brake {
                // The ramps share the acceleration to keep the curvature, which would
                // let the wheel with the smaller change brake gentler: in the zone,
                // braking in time wins over the curvature for that moment.
                if wheel_slows_down(start.left, target.left) {
                    command.left_accel = command.left_accel.max(estop_decel);
                }
                if wheel_slows_down(start.right, target.right) {
                    command.right_accel = command.right_accel.max(estop_decel);
                }
            }
            self.speed = self.speed.advanced(now, &self.in_force);
            self.advance_commanded_speed(now);
            let before = self.commanded_speed.slope(&self.in_force);
            let after = self.commanded_speed.slope(&command);
            self.note_commanded_bends([(after[0] - before[0]).abs(), (after[1] - before[1]).abs()]);
            self.in_force = command;
            let told = [
                SpeedRange::of(command.rpm.left),
                SpeedRange::of(command.rpm.right),
            ];
            self.told_targets = Some(self.told_targets.map_or(told, |[left, right]| {
                [left.with(told[0]), right.with(told[1])]
            }));
            out.wheels = Some(command);
        }
        if effects.excite.is_some() {
            out.excite = effects.excite;
        }
        out.setup_drives |= effects.setup_drives;
    }

    /// Runs the remote and gives the supervisor what it asks for. `otherwise` is the
    /// supervisor step the caller needs anyway (a tick); a remote event replaces it,
    /// since every step checks the timeouts, and a second step for the same input would
    /// start the wheel ramp from a command the drives were never sent.
    fn remote_step(
        &mut self,
        now: Timestamp,
        event: remote::Event,
        otherwise: Option<supervisor::Event>,
        out: &mut Output,
    ) {
        let effects = self.remote.step(now, event, &self.remote_params());
        if effects.reset_odometry {
            self.odometry.reset();
        }
        if effects.disconnect {
            out.disconnect_remote = self.pads.in_control();
        }
        let step = match effects.control {
            Some(Control::Drive { dead_man, twist }) => {
                if dead_man && self.supervisor.motion_locked() {
                    // Refused like CAN motion; the supervisor sees it held, which
                    // neither drives nor arms while locked.
                    self.rejections
                        .record(Rejection::UpdateInProgress.code(), 0);
                }
                Some(supervisor::Event::Remote { dead_man, twist })
            }
            Some(Control::Lost) => Some(supervisor::Event::RemoteLinkLost),
            None => otherwise,
        };
        if let Some(step) = step {
            self.supervise(now, step, out);
        }
    }

    fn power_event(&mut self, now: Timestamp, event: power::Event, out: &mut Output) {
        let power = self.power.step(now, event, &power_params(&self.registers));
        if power.confirm {
            self.turn_bluetooth_on(out);
            self.supervise(now, supervisor::Event::ConfirmPressed, out);
        }
        if power.switch.is_some() {
            out.pc_switch = power.switch;
        }
    }

    fn periodic_frames(&mut self, now: Timestamp, out: &mut Output) {
        let periods = FeedbackPeriods {
            odometry_ms: u32::from(self.registers.get(Reg::LoopEndDelay)),
            battery_ms: u32::from(self.registers.get(Reg::VoltTime)),
            weight_ms: u32::from(self.registers.get(Reg::WeightTime)),
            status_ms: u32::from(self.registers.get(Reg::StatusTime)),
        };
        let quiet = self.supervisor.in_emergency() || !self.supervisor.estop_known();
        let due = self.feedback.poll(now, &periods, quiet);
        if due.odometry {
            // The pose at this frame's moment: the last reading carried on by the speeds
            // it reported, so that frames one cycle apart hold poses one cycle apart
            // whenever the reading itself was taken (on a loaded host a read may even
            // land just after its frame). A reading older than two cycles (a silent
            // drive) is reported as it is.
            let fresh_rpm = self
                .last_feedback
                .filter(|(at, _)| now.millis_since(*at) <= 2 * u64::from(periods.odometry_ms));
            let params = self.odometry_params();
            let pose = match fresh_rpm {
                Some((at, rpm)) => self.odometry.pose_ahead(&params, rpm, now.millis_since(at)),
                None => self.odometry.pose(),
            };
            // The pose's moment on this clock (ext), ahead of the pose: a PC divides
            // pose differences by these, not by arrival times a busy bus or PC stretches.
            push_frame(
                out,
                Report::PoseTime {
                    // Wraps after 49.7 days; a PC takes differences.
                    controller_ms: now.as_millis() as u32,
                }
                .encode(),
            );
            // The speed the pose moves at (ext), between its time and the pose: a PC
            // takes the twist from it, exact to the drives' resolution, instead of
            // from pose differences (1 mm and 1 mrad of rounding per pose). Only from
            // a fresh reading: a silent drive's last speed is not the base's.
            if let Some((_, rpm)) = fresh_rpm {
                push_frame(out, measured_speed_report(&params, rpm).encode());
            }
            push_frame(
                out,
                Report::Position {
                    x_mm: pose.x_mm,
                    y_mm: pose.y_mm,
                }
                .encode(),
            );
            push_frame(
                out,
                Report::Heading {
                    heading_mrad: pose.heading_mrad,
                }
                .encode(),
            );
        }
        if due.battery
            && let Some(voltage_mv) = self.battery_mv
        {
            let params = BatteryParams {
                empty_mv: self.registers.get(Reg::BattEmptyMv),
                full_mv: self.registers.get(Reg::BattFullMv),
            };
            let percent = battery::percent(voltage_mv, params);
            push_frame(
                out,
                Report::Battery {
                    percent,
                    voltage_mv,
                }
                .encode(),
            );
        }
        if due.weight
            && let Some(raw) = self.scale.average()
        {
            let grams = scale::weight_grams(
                raw,
                self.registers.weight_offset(),
                self.registers.get(Reg::ScaleValue),
            );
            push_frame(out, Report::Weight { grams }.encode());
        }
        if due.status {
            push_frame(out, Report::Status(self.status(now)).encode());
        }
    }

    fn supervisor_params(&self) -> supervisor::Params {
        let r = &self.registers;
        supervisor::Params {
            enable_timeout_ms: u32::from(r.get(Reg::EnableTimeout)),
            cmd_timeout_ms: u32::from(r.get(Reg::CmdTimeout)),
            disable_time_ms: u32::from(r.get(Reg::DisableTime)),
            can_accel: u32::from(r.get(Reg::CanAccel)),
            remote_accel: u32::from(r.get(Reg::ContrAccNorm)),
            remote_release_accel: u32::from(r.get(Reg::ContrAccHigh)),
            estop_decel: u32::from(r.get(Reg::EstopDecel)),
            stop_decel: u32::from(r.get(Reg::StopDecel)),
            safety_limits: SafetyLimits {
                linear_mm_s: r.get(Reg::SecLinVel),
                rotation_mrad_s: r.get(Reg::SecTurnVel),
            },
        }
    }

    fn remote_params(&self) -> remote::Params {
        let r = &self.registers;
        remote::Params {
            start_level_mm_s: r.get(Reg::PsRelMaxVel),
            max_level_mm_s: r.get(Reg::PsAbsMaxVel),
            wheel_distance_mm: r.get(Reg::WheelDist),
            afk_timeout_ms: u32::from(r.get(Reg::PsAfkTime)),
        }
    }

    /// The kinematics the registers describe. In the safety zone the motor limit is
    /// `sec_motor_vel` too: it holds in motor r/min, so a wrong radius or gear ratio
    /// cannot defeat the zone's limits the way it defeats the twist clamp.
    fn kinematics_params(&self, safety_zone: bool) -> KinematicsParams {
        let g = Geometry::of(&self.registers);
        let mut max_motor_rpm = self.registers.get(Reg::MaxMotorVel);
        if safety_zone {
            max_motor_rpm = max_motor_rpm.min(self.registers.get(Reg::SecMotorVel));
        }
        KinematicsParams {
            left_radius_mm: g.left_radius_mm as f32,
            right_radius_mm: g.right_radius_mm as f32,
            wheel_distance_mm: g.wheel_distance_mm as f32,
            gear_ratio: g.gear_ratio as f32,
            max_motor_rpm: f32::from(max_motor_rpm),
            invert_left: g.invert_left,
            invert_right: g.invert_right,
        }
    }

    fn odometry_params(&self) -> OdometryParams {
        let r = &self.registers;
        let g = Geometry::of(r);
        OdometryParams {
            left_radius_mm: g.left_radius_mm,
            right_radius_mm: g.right_radius_mm,
            wheel_distance_mm: g.wheel_distance_mm,
            gear_ratio: g.gear_ratio,
            counts_per_motor_rev: COUNTS_PER_MOTOR_REV,
            invert_left: g.invert_left,
            invert_right: g.invert_right,
            f_lin: f64::from(r.get(Reg::FLin)) / 10_000.0,
            f_cw: f64::from(r.get(Reg::FCw)) / 10_000.0,
            f_ccw: f64::from(r.get(Reg::FCcw)) / 10_000.0,
        }
    }
}

/// The base's geometry in the registers' units decoded to physical ones, once for
/// both directions: twist → wheels (kinematics) and wheels → pose (odometry).
struct Geometry {
    left_radius_mm: f64,
    right_radius_mm: f64,
    wheel_distance_mm: f64,
    /// Motor turns per wheel turn (`gear_ratio` is ×100).
    gear_ratio: f64,
    invert_left: bool,
    invert_right: bool,
}

impl Geometry {
    fn of(r: &Registers) -> Self {
        let motor_dir = r.get(Reg::MotorDir);
        Self {
            left_radius_mm: f64::from(r.get(Reg::RadL)),
            right_radius_mm: f64::from(r.get(Reg::RadR)),
            wheel_distance_mm: f64::from(r.get(Reg::WheelDist)),
            gear_ratio: f64::from(r.get(Reg::GearRatio)) / 100.0,
            invert_left: motor_dir & MOTOR_DIR_INVERT_LEFT != 0,
            invert_right: motor_dir & MOTOR_DIR_INVERT_RIGHT != 0,
        }
    }
}

/// The drives after setup: standing, nothing commanded.
const STANDING: WheelCommand = WheelCommand {
    rpm: MotorRpm::ZERO,
    left_accel: 0,
    right_accel: 0,
};

/// What the drives run at: the latest measured motor speeds and when they were
/// measured. Between two measurements each drive is taken to ramp linearly towards the
/// command in force at its commanded rate, as the drives do.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct SpeedEstimate {
    left: f32,
    right: f32,
    at: Timestamp,
}

impl SpeedEstimate {
    fn standing(now: Timestamp) -> Self {
        Self {
            left: 0.0,
            right: 0.0,
            at: now,
        }
    }

    fn measured(now: Timestamp, rpm: MotorRpm) -> Self {
        Self {
            left: rpm.left as f32,
            right: rpm.right as f32,
            at: now,
        }
    }

    /// Moved along `command` until `now`.
    fn advanced(self, now: Timestamp, command: &WheelCommand) -> Self {
        let seconds = now.millis_since(self.at) as f32 / 1000.0;
        let toward = |speed: f32, target: i32, accel: u32| {
            let target = target as f32;
            let step = accel as f32 * seconds;
            if speed < target {
                (speed + step).min(target)
            } else {
                (speed - step).max(target)
            }
        };
        Self {
            left: toward(self.left, command.rpm.left, command.left_accel),
            right: toward(self.right, command.rpm.right, command.right_accel),
            at: now,
        }
    }

    /// Each motor's acceleration now, following `command`, (r/min)/s: towards the
    /// target at its rate, or none once there.
    fn slope(self, command: &WheelCommand) -> [f64; 2] {
        let slope = |speed: f32, target: i32, accel: u32| {
            let towards = target as f32 - speed;
            if towards == 0.0 {
                0.0
            } else {
                f64::from(towards.signum()) * f64::from(accel)
            }
        };
        [
            slope(self.left, command.rpm.left, command.left_accel),
            slope(self.right, command.rpm.right, command.right_accel),
        ]
    }

    /// Moved along `command` until `now`, with how much each motor's acceleration
    /// changed meanwhile ((r/min)/s; left, right): a ramp that reached its target.
    fn advanced_bending(self, now: Timestamp, command: &WheelCommand) -> (Self, [f64; 2]) {
        let advanced = self.advanced(now, command);
        let before = self.slope(command);
        let after = advanced.slope(command);
        let bends = [(after[0] - before[0]).abs(), (after[1] - before[1]).abs()];
        (advanced, bends)
    }

    /// Rounded to whole r/min (`as` saturates a garbage measurement at the i32 range).
    fn rpm(self) -> MotorRpm {
        MotorRpm {
            left: libm::roundf(self.left) as i32,
            right: libm::roundf(self.right) as i32,
        }
    }
}

/// Some wheel must slow down to go from `start` to `target`.
fn slows_down(start: MotorRpm, target: MotorRpm) -> bool {
    wheel_slows_down(start.left, target.left) || wheel_slows_down(start.right, target.right)
}

/// A wheel must slow down: it is faster than its target, or must reverse, by more than
/// the measurement noise.
fn wheel_slows_down(start: i32, target: i32) -> bool {
    let (start, target) = (i64::from(start), i64::from(target));
    let reverses = start.signum() * target.signum() < 0;
    let faster = start.abs() > target.abs() + i64::from(AT_REST_RPM);
    start.abs() > i64::from(AT_REST_RPM) && (reverses || faster)
}

fn power_params(r: &Registers) -> power::Params {
    power::Params {
        start_pc_ms: u32::from(r.get(Reg::StartPc)),
        shutdown_pc_ms: u32::from(r.get(Reg::ShutdownPc)),
        heartbeat_timeout_ms: u32::from(r.get(Reg::HeartbeatTime)),
        boot_grace_ms: u32::from(r.get(Reg::PcBootGrace)) * 1000,
        switch_pulse_ms: u32::from(r.get(Reg::PcSwitchPulse)),
    }
}

/// The status frame's "subject" of a frame rejection: the low byte of the CAN ID.
fn frame_subject(id: u16) -> u8 {
    id.to_le_bytes()[0]
}

/// 0x0F0 from the drives' reading: rounded to the wire's units, saturating at the i16
/// range (32 m/s, 32 rad/s; a wheel at 327 rad/s).
fn measured_speed_report(params: &OdometryParams, rpm: MotorRpm) -> Report {
    let speed = odometry::measured_speed(params, rpm);
    // `as` saturates, and maps the NaN of broken geometry registers to 0.
    let wire = |value: f64| libm::round(value) as i16;
    Report::MeasuredSpeed {
        linear_mm_s: wire(speed.linear_mm_s),
        rotation_mrad_s: wire(speed.rotation_rad_s * 1000.0),
        left_wheel_crad_s: wire(speed.left_wheel_rad_s * 100.0),
        right_wheel_crad_s: wire(speed.right_wheel_rad_s * 100.0),
    }
}

/// At most one register reply, the four odometry frames, battery, weight and status go
/// out per input: eight slots always suffice.
fn push_frame(out: &mut Output, frame: RawFrame) {
    let pushed = out.frames.push(frame);
    debug_assert!(pushed.is_ok(), "more frames than Output holds");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Timestamp {
        Timestamp::from_millis(ms)
    }

    fn can(command: Command) -> Input {
        Input::CanFrame(command.encode())
    }

    #[test]
    fn the_first_status_frame_after_boot_carries_every_boot_fault() {
        let report = BootReport {
            flash_fault: true,
            watchdog_reset: true,
            flash_erases: 70_000,
            bluetooth_off_after_panics: false,
            boot_info: BootInfo::default(),
        };
        let mut controller = Controller::boot(at(0), Registers::defaults(), &report);
        let out = controller.handle(at(0), Input::Tick);
        let frame = out
            .frames
            .iter()
            .find(|frame| frame.id() == crate::can::id::STATUS)
            .expect("a status frame at boot");
        let data: [u8; 8] = frame.data().try_into().expect("8 bytes");
        let status = Status::from_bytes(data).expect("a valid status frame");
        assert!(status.faults.flash && status.faults.watchdog_reset);
        let registers = controller.registers();
        assert_eq!(
            (
                registers.get(Reg::FlashErasesHi),
                registers.get(Reg::FlashErasesLo)
            ),
            (1, 4_464)
        );
    }

    #[test]
    fn the_remote_registers_follow_the_link_and_what_the_bluetooth_tasks_report() {
        use crate::hid::playstation::{Battery, BatteryState, PadKind};
        use crate::registers::{Charge, RemoteBattery, RemoteInfo, RemoteKind};
        let link = |pad, connected| Input::RemoteLink {
            pad,
            bonded: true,
            connected,
        };
        let report = |info| Input::RemoteInfo {
            pad: Pad::Classic,
            info,
        };
        let dual_shock = RemoteInfo::playstation(
            PadKind::DualShock4,
            Some(Battery {
                percent: 80,
                state: BatteryState::Charging,
            }),
        );
        let full = RemoteInfo {
            battery: Some(RemoteBattery {
                percent: 100,
                charge: Charge::Full,
            }),
            ..dual_shock
        };
        let ble_pad = RemoteInfo {
            kind: RemoteKind::BlePad,
            battery: None,
        };
        // (input) → what `remote_kind`/`remote_battery` hold afterwards
        let table = [
            (link(Pad::Ble, false), RemoteInfo::NONE),
            // The BLE task reports no kind: its pads are BLE pads.
            (link(Pad::Ble, true), ble_pad),
            (link(Pad::Ble, false), RemoteInfo::NONE),
            // A PlayStation pad tells its kind with its first full report.
            (link(Pad::Classic, true), RemoteInfo::NONE),
            (report(dual_shock), dual_shock),
            (report(full), full),
            // A lost link never leaves a stale pad or battery behind.
            (link(Pad::Classic, false), RemoteInfo::NONE),
            (link(Pad::Classic, true), RemoteInfo::NONE),
            // Two pads: the one in control shows.
            (link(Pad::Ble, true), RemoteInfo::NONE),
            (report(dual_shock), dual_shock),
            (link(Pad::Classic, false), ble_pad),
        ];
        let mut controller = Controller::new(at(0), Registers::defaults());
        for (ms, (input, expected)) in (0..).step_by(10).zip(table) {
            controller.handle(at(ms), input);
            assert_eq!(
                controller.registers().remote_info(),
                expected,
                "after {input:?}"
            );
        }
    }

    #[test]
    fn a_first_boot_and_an_update_reset_show_in_boot_info_and_not_as_faults() {
        let boot_info = BootInfo {
            first_boot: true,
            update_reset: crate::registers::UpdateReset::Activation,
        };
        let report = BootReport {
            boot_info,
            ..BootReport::default()
        };
        let controller = Controller::boot(at(0), Registers::defaults(), &report);
        assert_eq!(
            controller.registers().read(Reg::BootInfo.address()),
            Ok(boot_info.to_bits())
        );
        assert!(!controller.faults.flash && !controller.faults.watchdog_reset);
    }

    /// Drives ready, CAN enabled and driving forward at 500 mm/s since 0 ms.
    fn driving_forward() -> Controller {
        let mut controller = Controller::new(at(0), Registers::defaults());
        // The input task tells the e-stop's level at boot.
        controller.handle(at(0), Input::Estop(false));
        controller.handle(at(0), Input::SafetyZone(false));
        controller.handle(at(0), Input::DrivesReady);
        controller.handle(at(0), can(Command::Enable { refresh: true }));
        let out = controller.handle(
            at(0),
            can(Command::Velocity {
                linear_mm_s: 500,
                rotation_mrad_s: 0,
            }),
        );
        // 336 r/min per motor; the right one is mirror-mounted (motor_dir 2).
        assert_eq!(
            out.wheels.map(|command| command.rpm),
            Some(MotorRpm {
                left: 336,
                right: -336
            })
        );
        controller
    }

    #[test]
    fn an_update_lock_refuses_enable_velocity_and_the_dead_man_but_not_a_withdrawal() {
        let mut controller = Controller::new(at(0), Registers::defaults());
        controller.handle(at(0), Input::Estop(false));
        controller.handle(at(0), Input::SafetyZone(false));
        controller.handle(at(0), Input::DrivesReady);
        controller.handle(at(0), Input::UpdateLock(true));
        for command in [
            Command::Enable { refresh: true },
            Command::Velocity {
                linear_mm_s: 500,
                rotation_mrad_s: 0,
            },
        ] {
            let out = controller.handle(at(10), can(command));
            assert_eq!(out.wheels, None, "{command:?}");
            assert_eq!(out.excite, None, "{command:?}");
            let status = controller.status(at(10));
            assert_eq!(status.last_rejection, Rejection::UpdateInProgress.code());
            assert_eq!(
                status.last_rejection_subject,
                frame_subject(command.encode().id())
            );
        }
        controller.handle(
            at(10),
            Input::RemoteLink {
                pad: Pad::Ble,
                bonded: true,
                connected: true,
            },
        );
        let dead_man = Input::Gamepad {
            pad: Pad::Ble,
            state: GamepadState {
                left_y: 1.0,
                buttons: crate::gamepad::Buttons::RIGHT_BUMPER,
                ..GamepadState::default()
            },
        };
        let out = controller.handle(at(15), dead_man);
        assert_eq!((out.wheels, out.excite), (None, None));
        let status = controller.status(at(15));
        assert_eq!(status.last_rejection, Rejection::UpdateInProgress.code());
        assert_eq!(status.control, crate::can::ControlSource::None);
        assert_eq!(status.rejected_count, 3);
        // A withdrawal is never refused.
        controller.handle(at(20), can(Command::Enable { refresh: false }));
        assert_eq!(controller.status(at(20)).rejected_count, 3);
        // Unlocked, the same commands drive again (the pad's dead-man is let go first:
        // held through the lock, it would keep CAN from driving).
        controller.handle(
            at(25),
            Input::Gamepad {
                pad: Pad::Ble,
                state: GamepadState::default(),
            },
        );
        // A feedback at rest lets CAN drive after the dead-man let go.
        controller.handle(
            at(26),
            Input::DriveFeedback {
                counts: EncoderCounts { left: 0, right: 0 },
                rpm: MotorRpm::ZERO,
            },
        );
        controller.handle(at(30), Input::UpdateLock(false));
        controller.handle(at(30), can(Command::Enable { refresh: true }));
        let out = controller.handle(
            at(30),
            can(Command::Velocity {
                linear_mm_s: 500,
                rotation_mrad_s: 0,
            }),
        );
        assert!(out.wheels.is_some());
        assert!(controller.update_gate(at(30)).control_active);
    }

    /// A pad that connects during an update with its dead-man held was never seen
    /// released: when the lock lifts, holding on must not drive; a release after the
    /// lift arms it.
    #[test]
    fn a_dead_man_held_through_an_update_lock_needs_a_release_after_the_lift() {
        let pad = |state| Input::Gamepad {
            pad: Pad::Classic,
            state,
        };
        let held = |forward: f32| {
            pad(GamepadState {
                left_y: forward,
                buttons: crate::gamepad::Buttons::RIGHT_BUMPER,
                ..GamepadState::default()
            })
        };
        let mut controller = Controller::new(at(0), Registers::defaults());
        controller.handle(at(0), Input::Estop(false));
        controller.handle(at(0), Input::SafetyZone(false));
        controller.handle(at(0), Input::DrivesReady);
        controller.handle(at(0), Input::UpdateLock(true));
        controller.handle(
            at(10),
            Input::RemoteLink {
                pad: Pad::Classic,
                bonded: true,
                connected: true,
            },
        );
        let out = controller.handle(at(20), held(1.0));
        assert_eq!((out.wheels, out.excite), (None, None), "locked");
        controller.handle(at(25), Input::UpdateLock(false));
        let out = controller.handle(at(30), held(0.9));
        assert_eq!(
            (out.wheels, out.excite),
            (None, None),
            "a dead-man held through the lock drove after the lift"
        );
        controller.handle(at(40), pad(GamepadState::default()));
        let out = controller.handle(at(50), held(1.0));
        assert_eq!(
            out.excite,
            Some(true),
            "a release after the lift arms the pad"
        );
    }

    /// Found by the whole-robot simulation tester (rule 1): the waiting pad's report with
    /// its dead-man held was dropped, so when the pad in control switched off the
    /// waiting pad took control with its dead-man unknown, and CAN drove on under the
    /// held button. Its held dead-man counts from the hand-over: it takes control from
    /// CAN and stops the base, and drives only after a release.
    #[test]
    fn a_dead_man_held_on_the_waiting_pad_takes_control_from_can_at_the_hand_over() {
        use crate::can::ControlSource;
        use crate::gamepad::Buttons;
        let link = |pad, connected| Input::RemoteLink {
            pad,
            bonded: true,
            connected,
        };
        let classic = |left_y: f32, buttons| Input::Gamepad {
            pad: Pad::Classic,
            state: GamepadState {
                left_y,
                buttons,
                ..GamepadState::default()
            },
        };
        let mut controller = driving_forward();
        controller.handle(at(10), link(Pad::Ble, true));
        controller.handle(at(20), link(Pad::Classic, true));
        // Waiting: dropped, CAN drives on.
        let out = controller.handle(at(30), classic(1.0, Buttons::RIGHT_BUMPER));
        assert_eq!(
            out.wheels, None,
            "the waiting pad's dead-man changed the wheels"
        );
        // The BLE pad leaves: the PlayStation pad takes control with its dead-man held.
        let out = controller.handle(at(40), link(Pad::Ble, false));
        assert_eq!(controller.pads.in_control(), Some(Pad::Classic));
        assert_eq!(
            controller.status(at(40)).control,
            ControlSource::Remote,
            "CAN kept control under the new pad's held dead-man"
        );
        assert_eq!(out.wheels.map(|command| command.rpm), Some(MotorRpm::ZERO));
        // CAN is ignored while the dead-man is held.
        controller.handle(at(50), can(Command::Enable { refresh: true }));
        let out = controller.handle(
            at(50),
            can(Command::Velocity {
                linear_mm_s: 500,
                rotation_mrad_s: 0,
            }),
        );
        assert!(
            !out.wheels
                .is_some_and(|command| command.rpm != MotorRpm::ZERO),
            "CAN drove under the held dead-man: {out:?}"
        );
        // Held on, it does not drive: it was never seen released since it took control.
        let out = controller.handle(at(60), classic(0.9, Buttons::RIGHT_BUMPER));
        assert!(
            !out.wheels
                .is_some_and(|command| command.rpm != MotorRpm::ZERO),
            "the handed-over dead-man drove without a release: {out:?}"
        );
        // Released, then held again: it drives.
        controller.handle(at(70), classic(0.0, Buttons::default()));
        let out = controller.handle(at(80), classic(1.0, Buttons::RIGHT_BUMPER));
        assert!(
            out.wheels.is_some_and(|command| command.rpm.left > 0),
            "a release after the hand-over arms the pad: {out:?}"
        );
    }

    /// A reading's moment moves by a few ms from cycle to cycle (a command write may hold
    /// the line when the read is due); a PC takes the position frames as one cycle
    /// apart. Before, each frame held the pose of its reading, so at 500 mm/s a
    /// reading 6 ms late every other cycle made the frames step 22 and 28 mm: ±12 %
    /// of speed that was never driven.
    /// At boot a chattering e-stop may show a released sample; until the input task
    /// tells the level (after the release time without an active sample), the
    /// feedback frames wait as they do while it is pressed. The status frame goes on.
    #[test]
    fn feedback_frames_wait_until_the_estop_level_is_known() {
        let mut controller = Controller::new(at(0), Registers::defaults());
        controller.handle(at(0), Input::DrivesReady);
        let reports = |out: &Output| -> std::vec::Vec<Report> {
            out.frames
                .iter()
                .filter_map(|frame| Report::decode(frame.id(), frame.data()).ok().flatten())
                .collect()
        };
        for ms in (10..=50).step_by(10) {
            let out = controller.handle(at(ms), Input::Tick);
            let feedback: std::vec::Vec<_> = reports(&out)
                .into_iter()
                .filter(|report| !matches!(report, Report::Status(_)))
                .collect();
            assert!(feedback.is_empty(), "at {ms} ms: {feedback:?}");
        }
        controller.handle(at(55), Input::Estop(false));
        let out = controller.handle(at(100), Input::Tick);
        assert!(
            reports(&out)
                .iter()
                .any(|report| matches!(report, Report::Position { .. })),
            "{:?}",
            reports(&out)
        );
    }

    #[test]
    fn position_frames_one_cycle_apart_step_evenly_when_the_readings_jitter() {
        let mut controller = driving_forward();
        // 336 r/min with 36000 counts per revolution; the right motor is mirrored.
        let counts_at = |ms: u64| {
            let counts = (201.6 * ms as f64).round() as i32;
            EncoderCounts {
                left: counts,
                right: -counts,
            }
        };
        let rpm = MotorRpm {
            left: 336,
            right: -336,
        };
        let mut xs = std::vec::Vec::new();
        for cycle in 1..=20u64 {
            let late_ms = if cycle % 2 == 0 { 6 } else { 0 };
            let read_at = 50 * cycle - 25 + late_ms;
            controller.handle(
                at(read_at),
                Input::DriveFeedback {
                    counts: counts_at(read_at),
                    rpm,
                },
            );
            let out = controller.handle(at(50 * cycle), Input::Tick);
            for frame in &out.frames {
                if let Ok(Some(Report::Position { x_mm, .. })) =
                    Report::decode(frame.id(), frame.data())
                {
                    xs.push(x_mm);
                }
            }
        }
        assert!(xs.len() >= 18, "a position frame every cycle: {xs:?}");
        // The first reading only sets the baseline; from the third frame on, every
        // step is one cycle at 500 mm/s (x f_lin), give or take the 1 mm rounding.
        let steps: std::vec::Vec<i32> = xs[2..].windows(2).map(|w| w[1] - w[0]).collect();
        let (min, max) = (steps.iter().min().unwrap(), steps.iter().max().unwrap());
        assert!(max - min <= 1, "steps between frames: {steps:?}");
        assert!((24..=26).contains(min), "steps between frames: {steps:?}");
    }

    /// 0x0F0 (ext) carries the speed the pose moves at: between the pose's time and
    /// the pose, from the reading the pose is carried on from, and never from a
    /// reading a silent drive left behind.
    #[test]
    fn the_measured_speed_goes_between_the_pose_time_and_the_pose_while_readings_are_fresh() {
        let mut controller = driving_forward();
        let rpm = MotorRpm {
            left: 336,
            right: -336,
        };
        let reading = |ms: u64| {
            let counts = (201.6 * ms as f64).round() as i32;
            Input::DriveFeedback {
                counts: EncoderCounts {
                    left: counts,
                    right: -counts,
                },
                rpm,
            }
        };
        let odometry_frames = |out: &Output| -> std::vec::Vec<Report> {
            out.frames
                .iter()
                .filter_map(|frame| Report::decode(frame.id(), frame.data()).ok().flatten())
                .filter(|report| !matches!(report, Report::Status(_) | Report::Battery { .. }))
                .filter(|report| !matches!(report, Report::Weight { .. }))
                .collect()
        };
        controller.handle(at(25), reading(25));
        controller.handle(at(75), reading(75));
        let out = controller.handle(at(100), Input::Tick);
        let frames = odometry_frames(&out);
        let [
            Report::PoseTime { controller_ms: 100 },
            Report::MeasuredSpeed {
                linear_mm_s,
                rotation_mrad_s: 0,
                left_wheel_crad_s,
                right_wheel_crad_s,
            },
            Report::Position { .. },
            Report::Heading { .. },
        ] = frames[..]
        else {
            panic!("the cycle's frames: {frames:?}");
        };
        // The position frames step 25 mm per 50 ms cycle at this speed (see above).
        assert!((495..=505).contains(&linear_mm_s), "{linear_mm_s} mm/s");
        assert_eq!(left_wheel_crad_s, right_wheel_crad_s, "straight ahead");
        assert!(left_wheel_crad_s > 0, "forward: {left_wheel_crad_s}");
        // The drives fall silent: two cycles on, the pose stands and no speed is sent.
        controller.handle(at(150), Input::Tick);
        let out = controller.handle(at(200), Input::Tick);
        let frames = odometry_frames(&out);
        assert!(
            matches!(
                frames[..],
                [
                    Report::PoseTime { .. },
                    Report::Position { .. },
                    Report::Heading { .. }
                ]
            ),
            "a stale reading gives no speed: {frames:?}"
        );
    }

    fn write(reg: Reg, value: u16) -> Input {
        can(Command::RegisterWrite {
            address: reg.address(),
            value,
        })
    }

    #[test]
    fn a_motion_register_written_while_driving_is_refused_and_the_command_runs_on() {
        let mut controller = driving_forward();
        let out = controller.handle(at(10), write(Reg::MaxMotorVel, 100));
        assert_eq!(out.wheels, None);
        assert_eq!(out.persist, Persist::default());
        assert_eq!(controller.registers().get(Reg::MaxMotorVel), 900);
        let status = controller.status(at(10));
        assert_eq!(
            (status.last_rejection, status.last_rejection_subject),
            (RegisterError::NotAtRest.code(), Reg::MaxMotorVel.address())
        );
        // Stopped and measured at rest: the same write is accepted and persisted.
        controller.handle(at(20), can(Command::Enable { refresh: false }));
        controller.handle(
            at(400),
            Input::DriveFeedback {
                counts: EncoderCounts { left: 0, right: 0 },
                rpm: MotorRpm::ZERO,
            },
        );
        assert!(controller.at_standstill(at(400)));
        let out = controller.handle(at(410), write(Reg::MaxMotorVel, 100));
        assert_eq!(
            out.persist.changed.as_slice(),
            [(Reg::MaxMotorVel.address(), 100)]
        );
    }

    /// Found by the safety-zone property: after the setup no drive feedback had come
    /// yet, so the last measurement still said "at rest" while the wheels ran down
    /// from 336 r/min; a `max_motor_vel` write then changed the limits under them.
    #[test]
    fn a_motion_register_is_refused_while_the_commanded_ramp_still_runs_down() {
        let mut controller = driving_forward();
        // The zone stops the base with estop_decel (4500): 336 r/min need 75 ms.
        let out = controller.handle(at(1_000), Input::SafetyZone(true));
        assert_eq!(out.wheels.map(|command| command.rpm), Some(MotorRpm::ZERO));
        controller.handle(at(1_040), write(Reg::MaxMotorVel, 100));
        assert_eq!(controller.registers().get(Reg::MaxMotorVel), 900);
        assert_eq!(
            controller.status(at(1_040)).last_rejection,
            RegisterError::NotAtRest.code()
        );
        // Ramped down and measured standing since the start: accepted.
        controller.handle(
            at(1_090),
            Input::DriveFeedback {
                counts: EncoderCounts { left: 0, right: 0 },
                rpm: MotorRpm::ZERO,
            },
        );
        controller.handle(at(1_100), write(Reg::MaxMotorVel, 100));
        assert_eq!(controller.registers().get(Reg::MaxMotorVel), 100);
    }

    /// Found by the safety-zone property: a turn commanded while the zone's stop still
    /// ran split the braking between the wheels to keep the curvature, and the wheel
    /// with the smaller change braked gentler than `estop_decel`.
    #[test]
    fn in_the_zone_every_slowing_wheel_brakes_with_estop_decel_whatever_the_curvature() {
        let mut controller = driving_forward();
        let keep_driving =
            |controller: &mut Controller, ms: u64, linear_mm_s: i16, rotation_mrad_s: i16| {
                controller.handle(at(ms), can(Command::Enable { refresh: true }));
                controller.handle(
                    at(ms),
                    can(Command::Velocity {
                        linear_mm_s,
                        rotation_mrad_s,
                    }),
                )
            };
        keep_driving(&mut controller, 400, 500, 0);
        controller.handle(at(1_000), Input::SafetyZone(true));
        let start = controller.estimated_rpm(at(1_030));
        let out = keep_driving(&mut controller, 1_030, 100, 800);
        let command = out.wheels.expect("the turn is commanded");
        let wheels = [
            (start.left, command.rpm.left, command.left_accel),
            (start.right, command.rpm.right, command.right_accel),
        ];
        let changes = wheels.map(|(from, to, _)| (i64::from(to) - i64::from(from)).abs());
        assert_ne!(
            changes[0], changes[1],
            "a curve: the wheels change unequally"
        );
        for (from, to, accel) in wheels {
            if from.abs() > to.abs() || from.signum() * to.signum() < 0 {
                assert!(accel >= 4_500, "{from} -> {to} r/min at {accel} (r/min)/s");
            }
        }
    }

    /// Found by the whole-robot tester (`speed-lie-seed-1-rule-4`): the right drive's
    /// speed register frozen at a wrong, low value. A fault's stop shared
    /// `estop_decel` out by the measured speeds, so the wheel that truly ran at 336
    /// r/min got a gentle ramp, and the fault de-excited it 300 ms later while it
    /// still turned. A fault stop brakes every wheel with `estop_decel`: the speed
    /// reading may be the fault.
    #[test]
    fn a_fault_stop_brakes_every_wheel_with_estop_decel_whatever_the_speeds_read() {
        let mut controller = driving_forward();
        controller.handle(at(400), can(Command::Enable { refresh: true }));
        controller.handle(
            at(480),
            Input::DriveFeedback {
                counts: EncoderCounts { left: 0, right: 0 },
                rpm: MotorRpm {
                    left: 336,
                    right: -20,
                },
            },
        );
        let out = controller.handle(
            at(500),
            Input::DriveAlarm {
                wheel: Wheel::Left,
                code: 0x30,
            },
        );
        let command = out.wheels.expect("the fault stops the wheels");
        assert_eq!(command.rpm, MotorRpm::ZERO);
        let estop_decel = u32::from(controller.registers().get(Reg::EstopDecel));
        assert!(
            command.left_accel >= estop_decel && command.right_accel >= estop_decel,
            "left at {}, right at {} (r/min)/s; estop_decel {estop_decel}",
            command.left_accel,
            command.right_accel
        );
    }

    /// Found by the whole-robot tester (`estop-speed-lie-seed-1-rule-4`): while the
    /// right drive's speed register read 0 with the wheel at -729 r/min, and the
    /// e-stop came. Its command shared `estop_decel` out by the speeds read and gave
    /// that wheel 241 (r/min)/s (the drive link's emergency broadcast braked it hard
    /// for 9 ms, then the wheel's own command took over), and the e-stop de-excited
    /// it 300 ms later at -632 r/min. An e-stop brakes each wheel with
    /// `estop_decel`, whatever the speeds read.
    #[test]
    fn an_estop_brakes_every_wheel_with_estop_decel_whatever_the_speeds_read() {
        let mut controller = driving_forward();
        controller.handle(at(400), can(Command::Enable { refresh: true }));
        // The right wheel runs at -336 r/min; its speed register reads 0.
        controller.handle(
            at(420),
            Input::DriveFeedback {
                counts: EncoderCounts { left: 0, right: 0 },
                rpm: MotorRpm {
                    left: 336,
                    right: 0,
                },
            },
        );
        let out = controller.handle(at(430), Input::Estop(true));
        let command = out.wheels.expect("the e-stop stops the wheels");
        assert_eq!(command.rpm, MotorRpm::ZERO);
        let estop_decel = u32::from(controller.registers().get(Reg::EstopDecel));
        assert!(
            command.left_accel >= estop_decel && command.right_accel >= estop_decel,
            "left at {}, right at {} (r/min)/s; estop_decel {estop_decel}",
            command.left_accel,
            command.right_accel
        );
    }

    #[test]
    fn a_register_write_after_the_enable_lapsed_stops_the_wheels_instead_of_resending() {
        let mut controller = driving_forward();
        // enable_timeout is 500 ms and no tick came since: the write's step sees the lapse.
        let out = controller.handle(at(600), write(Reg::CanAccel, 2000));
        assert_eq!(out.wheels.map(|command| command.rpm), Some(MotorRpm::ZERO));
    }

    #[test]
    fn a_drive_reporting_i32_min_rpm_counts_as_moving_and_does_not_panic() {
        let mut controller = driving_forward();
        controller.handle(at(10), can(Command::Enable { refresh: false }));
        // A garbled but checksummed speed reading: -i32::MIN overflows, and wrapped it
        // would read as standing and close the brakes on a moving wheel.
        controller.handle(
            at(20),
            Input::DriveFeedback {
                counts: EncoderCounts { left: 0, right: 0 },
                rpm: MotorRpm {
                    left: i32::MIN,
                    right: 0,
                },
            },
        );
        let out = controller.handle(at(1_000), Input::Tick);
        assert_eq!(out.excite, None);
        assert!(!controller.supervisor().brakes_applied());
    }
    fn booted_after_a_panic_loop() -> Controller {
        let report = BootReport {
            bluetooth_off_after_panics: true,
            ..BootReport::default()
        };
        Controller::boot(at(0), Registers::defaults(), &report)
    }

    #[test]
    fn bluetooth_off_after_panics_reads_1_until_the_key_turns_it_on_once() {
        let mut controller = booted_after_a_panic_loop();
        assert_eq!(controller.registers().get(Reg::BluetoothOff), 1);
        let out = controller.handle(
            at(10),
            write(Reg::Command, crate::registers::BLUETOOTH_ON_KEY),
        );
        assert!(out.bluetooth_on);
        assert_eq!(controller.registers().get(Reg::BluetoothOff), 0);
        let again = controller.handle(
            at(20),
            write(Reg::Command, crate::registers::BLUETOOTH_ON_KEY),
        );
        assert!(!again.bluetooth_on, "on already: nothing to start");
        assert_eq!(
            controller.rejections.count, 0,
            "the key is accepted either way"
        );
    }

    #[test]
    fn a_confirm_press_turns_bluetooth_on_after_panics_and_nothing_else_does() {
        let mut controller = booted_after_a_panic_loop();
        for (ms, input) in [
            (
                10,
                write(Reg::Command, crate::registers::OPEN_PAIRING_WINDOW_KEY),
            ),
            (20, Input::DrivesReady),
            (30, Input::Tick),
        ] {
            assert!(!controller.handle(at(ms), input).bluetooth_on, "{input:?}");
        }
        controller.handle(at(100), Input::Button(true));
        let released = controller.handle(at(300), Input::Button(false));
        assert!(released.bluetooth_on);
        assert_eq!(controller.registers().get(Reg::BluetoothOff), 0);
    }

    /// The BLE task gave up its host: register 36 says so (2), a PlayStation pad still
    /// connects, and the key starts the BLE host again; a panic loop's 1 stays 1.
    #[test]
    fn a_ble_host_given_up_reads_2_leaves_classic_pads_alone_and_the_key_restarts_it() {
        let mut controller = Controller::new(at(0), Registers::defaults());
        assert!(!controller.handle(at(10), Input::BleHostOff).bluetooth_on);
        assert_eq!(controller.registers().get(Reg::BluetoothOff), 2);
        controller.handle(
            at(20),
            Input::RemoteLink {
                pad: Pad::Classic,
                bonded: true,
                connected: true,
            },
        );
        assert!(
            controller.status(at(20)).flags.remote_connected,
            "a PlayStation pad is not a BLE pad"
        );
        let out = controller.handle(
            at(30),
            write(Reg::Command, crate::registers::BLUETOOTH_ON_KEY),
        );
        assert!(out.bluetooth_on);
        assert_eq!(controller.registers().get(Reg::BluetoothOff), 0);

        let mut looped = booted_after_a_panic_loop();
        looped.handle(at(10), Input::BleHostOff);
        assert_eq!(looped.registers().get(Reg::BluetoothOff), 1);
    }

    #[test]
    fn with_bluetooth_on_the_key_and_a_confirm_press_start_nothing() {
        let mut controller = Controller::new(at(0), Registers::defaults());
        let out = controller.handle(
            at(10),
            write(Reg::Command, crate::registers::BLUETOOTH_ON_KEY),
        );
        assert!(!out.bluetooth_on);
        controller.handle(at(100), Input::Button(true));
        assert!(
            !controller
                .handle(at(300), Input::Button(false))
                .bluetooth_on
        );
    }
}
