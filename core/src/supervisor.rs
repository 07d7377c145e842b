//! The safety supervisor: the one place that decides whether the base may move, which
//! source is in control, at what speed and with what acceleration. The controller feeds
//! it events (CAN, remote, inputs, drive link) with the time; it answers with effects.
//!
//! ```text
//!                 DrivesReady                 request (excite)
//!   Starting ─────────────────▶ Standby ───────────────────────▶ Active
//!      │                          ▲  ◀──────────────────────────── │
//!      │                          │   at rest for disable_time      │
//!      │                          │   (de-excite: brakes close)     │
//!      │                          │                                 │
//!      │                          │ DrivesReady   drive lost, alarm │
//!      │                       Recovering ◀──────┐ or implausible   ▼
//!      │                          ▲              └──── confirm ── Fault (brakes close
//!      │                          │                                 at rest)
//!      │                          │ confirm
//!      │  e-stop pressed    AwaitingConfirm
//!      │  (from any state)        ▲
//!      ▼                          │ e-stop released
//!   Emergency ────────────────────┘
//! ```
//!
//! Rules that hold in every state:
//! - Only `Active` ever commands a non-zero speed; every other state commands zero.
//! - Entering `Emergency` commands zero with `estop_decel` at once and forgets every
//!   stored command (CAN velocity, remote dead-man): nothing resumes by itself.
//! - CAN drives only while the enable is fresh and a velocity frame arrived while it was;
//!   a lapse clears the stored velocity, so a returning enable alone never moves the base.
//! - A held dead-man wins over CAN, armed or not: it drops the CAN velocity and stops
//!   the base; it drives only once armed (seen released while the base could drive).
//! - While motion is locked (a firmware update runs or a new image is on trial) no
//!   source is in control: nothing is stored or armed, and whatever was goes. When the
//!   lock lifts, a dead-man seen up at that moment is armed, one held through it must
//!   be released first (as after a recovery).
//! - Every stop of a source that went away (enable lapse or withdrawal, `cmd_timeout`,
//!   dead-man release, remote link loss, a dead-man taking control from CAN) brakes
//!   with the source's own register, but never gentler than `stop_decel`.
//! - After the dead-man lets go (release or link loss), CAN velocity frames are dropped
//!   until a drive feedback measures both wheels at rest; after that a fresh frame is
//!   needed, so a PC that kept streaming cannot drive into a base that still rolls.

use crate::can::{ControlSource, Mode};
use crate::kinematics::{SafetyLimits, Twist};
use crate::time::Timestamp;

/// Which wheel a drive event is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Wheel {
    Left,
    Right,
}

/// Everything the supervisor reacts to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// CAN 0x2E4: `refresh` for byte0 = 0x40, otherwise the enable is withdrawn.
    CanEnable { refresh: bool },
    /// CAN 0x0C8, already decoded.
    CanVelocity(Twist),
    /// From the remote mapping ([`crate::remote`]): the dead-man button and the twist
    /// the sticks ask for, on every gamepad report and when a register change alters
    /// the twist of a held stick.
    Remote { dead_man: bool, twist: Twist },
    /// The gamepad link dropped (or the pad was switched off).
    RemoteLinkLost,
    /// The debounced e-stop input changed.
    Estop { pressed: bool },
    /// The debounced safety-zone input changed.
    SafetyZone { occupied: bool },
    /// A short press of the front button.
    ConfirmPressed,
    /// The drive link finished setting up both drives; they are de-excited (brakes on).
    DrivesReady,
    /// A drive stopped answering.
    DriveSilent(Wheel),
    /// A drive reported an alarm (non-zero code).
    DriveAlarm { wheel: Wheel, code: u8 },
    /// A drive's position counter and reported speed disagree
    /// ([`crate::plausibility`]): its feedback cannot be trusted.
    FeedbackImplausible(Wheel),
    /// Whether both wheels are measured at rest, from the latest drive feedback.
    AtRest(bool),
    /// A firmware update runs or a new image is on trial (`true`), or neither: motion
    /// is locked meanwhile.
    MotionLock { locked: bool },
    /// Time passed; timeouts are checked.
    Tick,
}

/// What the drives should do now: a twist (already clamped to the safety zone) and the
/// acceleration, in motor (1/min)/s, to reach it with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setpoint {
    pub twist: Twist,
    pub accel_rpm_per_s: u32,
}

/// The answer to one event. `None` fields mean "no change".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Effects {
    /// A new setpoint for both wheels, to be sent to the drives at once.
    pub setpoint: Option<Setpoint>,
    /// Excite the drives (`true`: brakes released) or de-excite them (`false`: brakes close).
    pub excite: Option<bool>,
    /// Set the drives up from scratch (share group, alarm reset, re-baseline) and report
    /// `DrivesReady` when done.
    pub setup_drives: bool,
}

/// The register values the supervisor needs, with their units in their names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Params {
    pub enable_timeout_ms: u32,
    /// 0 = a CAN velocity never goes stale by itself.
    pub cmd_timeout_ms: u32,
    pub disable_time_ms: u32,
    pub can_accel: u32,
    pub remote_accel: u32,
    pub remote_release_accel: u32,
    pub estop_decel: u32,
    /// The floor of every stop but the e-stop (`stop_decel`).
    pub stop_decel: u32,
    pub safety_limits: SafetyLimits,
}

/// Latched drive faults, cleared by a successful recovery after the confirm press.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveFaults {
    pub left_silent: bool,
    pub left_alarm: bool,
    pub right_silent: bool,
    pub right_alarm: bool,
    /// The drive's position counter and speed disagreed: its feedback lies.
    pub left_implausible: bool,
    pub right_implausible: bool,
    /// The latest non-zero alarm code either drive reported (stays after recovery, for the log).
    pub last_alarm_code: u8,
}

/// Why a drive faulted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum DriveFault {
    Silent,
    Alarm(u8),
    Implausible,
}

impl DriveFaults {
    fn any(&self) -> bool {
        self.left_silent
            || self.left_alarm
            || self.right_silent
            || self.right_alarm
            || self.left_implausible
            || self.right_implausible
    }

    /// Sets the wheel's bit for the fault; an alarm also keeps its code.
    fn record(&mut self, wheel: Wheel, fault: DriveFault) {
        if let DriveFault::Alarm(code) = fault {
            self.last_alarm_code = code;
        }
        let (silent, alarm, implausible) = match wheel {
            Wheel::Left => (
                &mut self.left_silent,
                &mut self.left_alarm,
                &mut self.left_implausible,
            ),
            Wheel::Right => (
                &mut self.right_silent,
                &mut self.right_alarm,
                &mut self.right_implausible,
            ),
        };
        match fault {
            DriveFault::Silent => *silent = true,
            DriveFault::Alarm(_) => *alarm = true,
            DriveFault::Implausible => *implausible = true,
        }
    }
}

/// The supervisor's state. Data lives in the variant that needs it: what was last sent
/// to the drives and how to stop exist only while they are excited.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    /// After boot, until the drive link reports the drives ready.
    Starting,
    /// Drives ready and de-excited: the brakes hold the base. The last setpoint sent
    /// was zero.
    Standby,
    /// Drives excited. `setpoint` is the last one sent; `stop_accel` is how to stop
    /// when the source in control goes away (it depends on why); `at_rest_since` runs
    /// while nothing is requested and the wheels stand.
    Active {
        setpoint: Setpoint,
        stop_accel: u32,
        at_rest_since: Option<Timestamp>,
    },
    /// The e-stop is pressed. `excited_since_stop` is when zero was commanded to
    /// drives that were excited then: they are de-excited [`STOPPED_AFTER_MS`] later,
    /// when every wheel stands, whether or not feedback says so.
    Emergency {
        excited_since_stop: Option<Timestamp>,
    },
    /// The e-stop was released; a confirm press is needed. The drives' excitation as in
    /// `Emergency`.
    AwaitingConfirm {
        excited_since_stop: Option<Timestamp>,
    },
    /// Confirmed; the drive link sets the drives up again.
    Recovering,
    /// A drive fault outside an e-stop; a confirm press starts the recovery. The drive
    /// that still answers stays excited (if it was) until the base stands for
    /// `disable_time`, or [`STOPPED_AFTER_MS`] after the stop (`stopped_at`), whichever
    /// comes first.
    Fault {
        excited: bool,
        at_rest_since: Option<Timestamp>,
        stopped_at: Timestamp,
    },
}

/// After this long at `estop_decel` every wheel stands: the registers only accept an
/// `estop_decel` that stops `max_motor_vel` within it.
pub const STOPPED_AFTER_MS: u64 = crate::registers::ESTOP_POWER_CUT_MS as u64;

/// A CAN velocity stored while the enable is fresh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct CanCommand {
    twist: Twist,
    received: Timestamp,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct RemoteInput {
    /// A report arrived since boot or since the link was lost. Until then `dead_man`
    /// is a default, not an observation.
    reported: bool,
    dead_man: bool,
    twist: Twist,
    /// The dead-man must be seen released before it may take control: a pad that connects
    /// with the button held, or a button held through an e-stop, does not drive.
    armed: bool,
}

impl RemoteInput {
    const NONE: RemoteInput = RemoteInput {
        reported: false,
        dead_man: false,
        twist: Twist::ZERO,
        armed: false,
    };
}

/// What the sources and sensors last said. The state machine reads these; they change
/// only with the events that report them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Inputs {
    enable_refreshed: Option<Timestamp>,
    can_command: Option<CanCommand>,
    remote: RemoteInput,
    safety_zone: bool,
    estop_pressed: bool,
    /// The input task has told the e-stop's level since the start (it does once the
    /// level is sure, see [`Supervisor::estop_known`]).
    estop_known: bool,
    /// The same for the safety zone: until then its limit is unknown.
    zone_known: bool,
    at_rest: bool,
    /// The dead-man let go: CAN velocity is dropped until a drive feedback measures
    /// both wheels at rest (or the drives are set up from scratch).
    can_waits_for_rest: bool,
    /// A firmware update locks motion ([`Event::MotionLock`]).
    motion_locked: bool,
}

/// See the module documentation for the state diagram and the rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Supervisor {
    state: State,
    inputs: Inputs,
    /// Latched until a recovery ends; shown in the status frame in every state.
    faults: DriveFaults,
}

impl Default for Supervisor {
    fn default() -> Self {
        Self::new()
    }
}

/// Zero speed, reached with `accel_rpm_per_s`.
const fn zero_setpoint(accel_rpm_per_s: u32) -> Setpoint {
    Setpoint {
        twist: Twist::ZERO,
        accel_rpm_per_s,
    }
}

impl Supervisor {
    pub const fn new() -> Self {
        Self {
            state: State::Starting,
            inputs: Inputs {
                enable_refreshed: None,
                can_command: None,
                remote: RemoteInput::NONE,
                safety_zone: false,
                estop_pressed: false,
                estop_known: false,
                zone_known: false,
                at_rest: true,
                can_waits_for_rest: false,
                motion_locked: false,
            },
            faults: DriveFaults {
                left_silent: false,
                left_alarm: false,
                right_silent: false,
                right_alarm: false,
                left_implausible: false,
                right_implausible: false,
                last_alarm_code: 0,
            },
        }
    }

    /// Handles one event at `now` and returns what must happen.
    pub fn step(&mut self, now: Timestamp, event: Event, params: &Params) -> Effects {
        let mut effects = Effects::default();
        self.expire_can(now, params);
        match event {
            Event::CanEnable { refresh: true } => self.inputs.enable_refreshed = Some(now),
            Event::CanEnable { refresh: false } => self.withdraw_enable(params),
            Event::CanVelocity(twist) => {
                // Stored only when it may drive: no enable, a held dead-man, a base still
                // rolling after the dead-man let go or a non-driving state all mean the
                // frame is dropped, not buffered.
                if self.enable_fresh(now, params)
                    && !self.remote_in_control()
                    && !self.inputs.can_waits_for_rest
                    && self.commands_count()
                {
                    self.inputs.can_command = Some(CanCommand {
                        twist,
                        received: now,
                    });
                }
            }
            Event::Remote { dead_man, twist } => self.remote_report(dead_man, twist, params),
            Event::RemoteLinkLost => {
                if self.remote_in_control() {
                    self.stop_with(params.remote_release_accel, params);
                    self.inputs.can_waits_for_rest = true;
                }
                self.inputs.remote = RemoteInput::NONE;
            }
            Event::Estop { pressed } => {
                self.inputs.estop_pressed = pressed;
                self.inputs.estop_known = true;
                if pressed {
                    self.enter_emergency(now, params, &mut effects);
                } else if let State::Emergency { excited_since_stop } = self.state {
                    self.state = State::AwaitingConfirm { excited_since_stop };
                }
            }
            Event::SafetyZone { occupied } => {
                self.inputs.safety_zone = occupied;
                self.inputs.zone_known = true;
            }
            Event::ConfirmPressed => {
                if matches!(
                    self.state,
                    State::AwaitingConfirm { .. } | State::Fault { .. }
                ) {
                    // Only once the stop has ended: the setup de-excites the drives,
                    // which on a wheel still braking would close its brake while it
                    // turns. A press during the stop (up to `STOPPED_AFTER_MS`) is
                    // ignored; the next one counts.
                    self.update_motion(now, params, &mut effects);
                    if !self.brakes_applied() {
                        warn!("confirm press ignored: the stop still runs");
                        return effects;
                    }
                    self.state = State::Recovering;
                    effects.setup_drives = true;
                }
            }
            Event::DrivesReady => {
                if matches!(self.state, State::Starting | State::Recovering) {
                    self.state = State::Standby;
                    // A dead-man seen up when the drives come back may take control; a
                    // pad that has not reported yet has not been seen released.
                    self.arm_if_seen_released();
                    // Set up from scratch: the drives stand, de-excited.
                    self.inputs.at_rest = true;
                    self.inputs.can_waits_for_rest = false;
                    self.faults = DriveFaults {
                        last_alarm_code: self.faults.last_alarm_code,
                        ..DriveFaults::default()
                    };
                }
            }
            Event::DriveSilent(wheel) => {
                self.drive_fault(now, wheel, DriveFault::Silent, params, &mut effects)
            }
            Event::DriveAlarm { wheel, code } => {
                self.drive_fault(now, wheel, DriveFault::Alarm(code), params, &mut effects)
            }
            Event::FeedbackImplausible(wheel) => {
                self.drive_fault(now, wheel, DriveFault::Implausible, params, &mut effects)
            }
            Event::AtRest(at_rest) => {
                self.inputs.at_rest = at_rest;
                if at_rest {
                    self.inputs.can_waits_for_rest = false;
                }
            }
            Event::MotionLock { locked } => self.motion_lock(locked, params),
            Event::Tick => {}
        }
        self.update_motion(now, params, &mut effects);
        effects
    }

    /// The data-less mode for the status frame.
    pub fn mode(&self) -> Mode {
        match self.state {
            State::Starting => Mode::Starting,
            State::Standby => Mode::Standby,
            State::Active { .. } => Mode::Active,
            State::Emergency { .. } => Mode::Emergency,
            State::AwaitingConfirm { .. } => Mode::AwaitingConfirm,
            State::Recovering => Mode::Recovering,
            State::Fault { .. } => Mode::Fault,
        }
    }

    /// Which source's command the drives are following: the remote's dead-man wins over
    /// CAN, and only a state that may drive follows anyone.
    pub fn control(&self) -> ControlSource {
        if !self.commands_count() {
            ControlSource::None
        } else if self.remote_in_control() {
            ControlSource::Remote
        } else if self.inputs.can_command.is_some() {
            ControlSource::Can
        } else {
            ControlSource::None
        }
    }

    /// Emergency mode in the manual's sense lasts until the confirm press: no feedback
    /// frames (0x0EA..0x0ED) are sent during it.
    pub fn in_emergency(&self) -> bool {
        matches!(
            self.state,
            State::Emergency { .. } | State::AwaitingConfirm { .. }
        )
    }

    pub fn enable_fresh(&self, now: Timestamp, params: &Params) -> bool {
        self.inputs
            .enable_refreshed
            .is_some_and(|at| now.millis_since(at) < u64::from(params.enable_timeout_ms))
    }

    pub fn safety_zone(&self) -> bool {
        self.inputs.safety_zone
    }

    pub fn estop_pressed(&self) -> bool {
        self.inputs.estop_pressed
    }

    /// Whether the e-stop's level is known since the start. Until then the feedback
    /// frames wait, as they do while it is pressed: at boot a contact that chatters
    /// may show one released sample, and the input task tells a released e-stop
    /// only after its release time without an active sample.
    pub fn estop_known(&self) -> bool {
        self.inputs.estop_known
    }

    /// The dead-man is held, armed or not: the remote has control and CAN velocity is
    /// ignored. Only an armed dead-man drives ([`Supervisor::remote_drives`]); a held
    /// one that is not armed keeps the base stopped.
    pub fn remote_in_control(&self) -> bool {
        self.inputs.remote.reported && self.inputs.remote.dead_man
    }

    /// The dead-man is held and armed: the sticks drive.
    pub fn remote_drives(&self) -> bool {
        self.inputs.remote.armed && self.remote_in_control()
    }

    /// The latest drive feedback measured both wheels at rest (or the drives were just
    /// set up from scratch).
    pub fn at_rest(&self) -> bool {
        self.inputs.at_rest
    }

    /// The drives were last told to de-excite (S-OFF), so their brakes hold the base:
    /// what was commanded, never an assumption about the drives' power.
    pub fn brakes_applied(&self) -> bool {
        match self.state {
            State::Active { .. } => false,
            State::Fault { excited, .. } => !excited,
            State::Emergency { excited_since_stop }
            | State::AwaitingConfirm { excited_since_stop } => excited_since_stop.is_none(),
            State::Starting | State::Standby | State::Recovering => true,
        }
    }

    pub fn faults(&self) -> DriveFaults {
        self.faults
    }

    fn may_drive(&self) -> bool {
        matches!(self.state, State::Standby | State::Active { .. })
    }

    /// Motion is locked by a firmware update (the update task's word).
    pub fn motion_locked(&self) -> bool {
        self.inputs.motion_locked
    }

    /// The sources' commands count: the state may drive, the e-stop's and the zone's
    /// levels are known, and no update locks motion. (A drive fault still counts during
    /// a lock: that is what `may_drive` is for.)
    fn commands_count(&self) -> bool {
        let inputs = &self.inputs;
        self.may_drive() && inputs.estop_known && inputs.zone_known && !inputs.motion_locked
    }

    /// Arms the dead-man if the latest report showed it up and commands count now: the
    /// rule when the drives come back and when a lock lifts. A pad that has not reported
    /// yet has not been seen released.
    fn arm_if_seen_released(&mut self) {
        let counts = self.commands_count();
        let remote = &mut self.inputs.remote;
        remote.armed = counts && remote.reported && !remote.dead_man;
    }

    /// A lock forgets the stored CAN velocity and disarms the dead-man: nothing from
    /// before an update may drive after it. Its lift arms only a dead-man seen up.
    fn motion_lock(&mut self, locked: bool, params: &Params) {
        if locked == self.inputs.motion_locked {
            return;
        }
        self.inputs.motion_locked = locked;
        if locked {
            if self.inputs.can_command.take().is_some() {
                self.stop_with(params.can_accel, params);
            }
            self.inputs.remote.armed = false;
        } else {
            self.arm_if_seen_released();
        }
    }

    /// The source in control went away: the next stop uses `accel`, or `stop_decel`
    /// when that brakes harder. Only an excited base has anything to stop.
    fn stop_with(&mut self, accel: u32, params: &Params) {
        if let State::Active { stop_accel, .. } = &mut self.state {
            *stop_accel = accel.max(params.stop_decel);
        }
    }

    fn withdraw_enable(&mut self, params: &Params) {
        self.inputs.enable_refreshed = None;
        if self.inputs.can_command.take().is_some() {
            self.stop_with(params.can_accel, params);
        }
    }

    /// Drops the stored CAN velocity when its enable lapsed or (with `cmd_timeout`) when
    /// it went stale, so a returning enable never resumes an old command.
    fn expire_can(&mut self, now: Timestamp, params: &Params) {
        if !self.enable_fresh(now, params) {
            self.withdraw_enable(params);
        }
        if let Some(command) = self.inputs.can_command {
            let stale = params.cmd_timeout_ms != 0
                && now.millis_since(command.received) >= u64::from(params.cmd_timeout_ms);
            if stale {
                self.inputs.can_command = None;
                self.stop_with(params.can_accel, params);
            }
        }
    }

    fn remote_report(&mut self, dead_man: bool, twist: Twist, params: &Params) {
        let was_in_control = self.remote_in_control();
        let counts = self.commands_count();
        let remote = &mut self.inputs.remote;
        if !dead_man && counts {
            remote.armed = true;
        }
        remote.reported = true;
        remote.dead_man = dead_man;
        remote.twist = twist;
        if self.remote_in_control() && !was_in_control {
            // The remote takes over, armed or not; CAN must send a fresh velocity after
            // the release. A CAN drive it interrupts stops as if its enable lapsed (an
            // armed dead-man drives with its own twist instead).
            if self.inputs.can_command.take().is_some() {
                self.stop_with(params.can_accel, params);
            }
        }
        if was_in_control && !self.remote_in_control() {
            self.stop_with(params.remote_release_accel, params);
            self.inputs.can_waits_for_rest = true;
        }
    }

    fn enter_emergency(&mut self, now: Timestamp, params: &Params, effects: &mut Effects) {
        self.state = State::Emergency {
            excited_since_stop: (!self.brakes_applied()).then_some(now),
        };
        self.inputs.can_command = None;
        self.inputs.remote.armed = false;
        // Always sent, even if the last setpoint was already zero: the e-stop edge must put
        // zero on the wire at once, with the e-stop deceleration.
        effects.setpoint = Some(zero_setpoint(params.estop_decel));
    }

    fn drive_fault(
        &mut self,
        now: Timestamp,
        wheel: Wheel,
        fault: DriveFault,
        params: &Params,
        effects: &mut Effects,
    ) {
        // While (re)starting nothing moves, so a drive that does not answer or keeps an
        // alarm is no reason to stop; but the PC must see why the base does not get
        // ready, so the fault bit is set and the drives' readiness clears it.
        if matches!(self.state, State::Starting | State::Recovering) {
            self.faults.record(wheel, fault);
            return;
        }
        // Every fault latches, the second one too (both drives off: both reported).
        if matches!(self.state, State::Fault { .. }) {
            self.faults.record(wheel, fault);
            return;
        }
        // In an emergency the drives lose power by design (and often raise an
        // undervoltage alarm on the way down): not a fault.
        if !self.may_drive() {
            return;
        }
        self.faults.record(wheel, fault);
        debug_assert!(self.faults.any());
        self.state = State::Fault {
            excited: matches!(self.state, State::Active { .. }),
            at_rest_since: None,
            stopped_at: now,
        };
        self.inputs.can_command = None;
        self.inputs.remote.armed = false;
        effects.setpoint = Some(zero_setpoint(params.estop_decel));
    }

    /// Arbitrates the sources, clamps to the safety zone and runs the brake timer.
    fn update_motion(&mut self, now: Timestamp, params: &Params, effects: &mut Effects) {
        let (setpoint, stop_accel, at_rest_since) = match self.state {
            State::Fault {
                excited,
                at_rest_since,
                stopped_at,
            } => {
                let since = self.standstill_since(now, excited, false, at_rest_since);
                let stopped = now.millis_since(stopped_at) >= STOPPED_AFTER_MS;
                self.state = if excited && (stopped || brake_due(now, since, params)) {
                    effects.excite = Some(false);
                    State::Fault {
                        excited: false,
                        at_rest_since: None,
                        stopped_at,
                    }
                } else {
                    State::Fault {
                        excited,
                        at_rest_since: since,
                        stopped_at,
                    }
                };
                return;
            }
            // After an e-stop every wheel stands once `estop_decel` had its time: the
            // brakes close even if no feedback says so.
            State::Emergency {
                excited_since_stop: Some(at),
            }
            | State::AwaitingConfirm {
                excited_since_stop: Some(at),
            } if now.millis_since(at) >= STOPPED_AFTER_MS => {
                effects.excite = Some(false);
                self.state = match self.state {
                    State::Emergency { .. } => State::Emergency {
                        excited_since_stop: None,
                    },
                    _ => State::AwaitingConfirm {
                        excited_since_stop: None,
                    },
                };
                return;
            }
            // The strongest stop until a source's loss says which one applies.
            State::Standby => (zero_setpoint(0), params.estop_decel, None),
            State::Active {
                setpoint,
                stop_accel,
                at_rest_since,
            } => (setpoint, stop_accel, at_rest_since),
            State::Starting
            | State::Emergency { .. }
            | State::AwaitingConfirm { .. }
            | State::Recovering => {
                return;
            }
        };

        let (twist, accel) = match (self.control(), self.inputs.can_command) {
            (ControlSource::Remote, _) if self.inputs.remote.armed => {
                (self.inputs.remote.twist, params.remote_accel)
            }
            // Held but not armed: it has control, and stops the base.
            (ControlSource::Remote, _) => (Twist::ZERO, stop_accel),
            (ControlSource::Can, Some(command)) => (command.twist, params.can_accel),
            (ControlSource::Can | ControlSource::None, _) => (Twist::ZERO, stop_accel),
        };
        let twist = if self.inputs.safety_zone {
            twist.clamped(params.safety_limits)
        } else {
            twist
        };
        let requested = twist != Twist::ZERO;
        if requested {
            // The wheels may turn from now on: a standstill measured before this says
            // nothing about them, only the next measurement does (with `disable_time`
            // 0 the brakes would close on the old one).
            self.inputs.at_rest = false;
        }
        if self.state == State::Standby {
            if !requested {
                return;
            }
            effects.excite = Some(true);
        }

        // A stop that brakes harder than the ramp running to the same zero (a source
        // went away while it asked for zero) is sent too.
        let harder_stop = twist == Twist::ZERO && accel > setpoint.accel_rpm_per_s;
        let setpoint = if twist == setpoint.twist && !harder_stop {
            setpoint
        } else {
            let new = Setpoint {
                twist,
                accel_rpm_per_s: accel,
            };
            effects.setpoint = Some(new);
            new
        };

        let since = self.standstill_since(now, true, requested, at_rest_since);
        self.state = if brake_due(now, since, params) {
            effects.excite = Some(false);
            State::Standby
        } else {
            State::Active {
                setpoint,
                stop_accel,
                at_rest_since: since,
            }
        };
    }

    /// When the standstill that lets the brakes close began: none while the drives are
    /// de-excited, something is requested or the wheels are measured moving.
    fn standstill_since(
        &self,
        now: Timestamp,
        excited: bool,
        requested: bool,
        at_rest_since: Option<Timestamp>,
    ) -> Option<Timestamp> {
        if !excited || requested || !self.inputs.at_rest {
            return None;
        }
        Some(at_rest_since.unwrap_or(now))
    }
}

/// The base has stood for `disable_time`: the drives may be de-excited.
fn brake_due(now: Timestamp, standstill_since: Option<Timestamp>, params: &Params) -> bool {
    standstill_since
        .is_some_and(|since| now.millis_since(since) >= u64::from(params.disable_time_ms))
}

#[cfg(test)]
mod tests {
    use super::*;

    const PARAMS: Params = Params {
        enable_timeout_ms: 500,
        cmd_timeout_ms: 0,
        disable_time_ms: 300,
        can_accel: 700,
        remote_accel: 350,
        remote_release_accel: 500,
        estop_decel: 4500,
        stop_decel: 600,
        safety_limits: SafetyLimits {
            linear_mm_s: 200,
            rotation_mrad_s: 100,
        },
    };

    const FORWARD: Twist = Twist {
        linear_mm_s: 500,
        rotation_mrad_s: 0,
    };

    fn at(ms: u64) -> Timestamp {
        Timestamp::from_millis(ms)
    }

    fn ready() -> Supervisor {
        let mut supervisor = Supervisor::new();
        supervisor.step(at(0), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(0), Event::SafetyZone { occupied: false }, &PARAMS);
        supervisor.step(at(0), Event::DrivesReady, &PARAMS);
        supervisor
    }

    /// Drives ready, the dead-man seen released at 0 ms and held at 10 ms: the remote
    /// drives forward.
    fn remote_driving_forward() -> Supervisor {
        let mut supervisor = ready();
        let released = Event::Remote {
            dead_man: false,
            twist: Twist::ZERO,
        };
        supervisor.step(at(0), released, &PARAMS);
        let held = Event::Remote {
            dead_man: true,
            twist: FORWARD,
        };
        supervisor.step(at(10), held, &PARAMS);
        supervisor
    }

    fn setpoint(twist: Twist, accel_rpm_per_s: u32) -> Option<Setpoint> {
        Some(Setpoint {
            twist,
            accel_rpm_per_s,
        })
    }

    #[test]
    fn nothing_drives_before_the_drives_are_ready() {
        let mut supervisor = Supervisor::new();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        let effects = supervisor.step(at(1), Event::CanVelocity(FORWARD), &PARAMS);
        assert_eq!(effects, Effects::default());
        assert_eq!(supervisor.mode(), Mode::Starting);
    }

    #[test]
    fn enabled_velocity_excites_and_drives_with_can_accel() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        let effects = supervisor.step(at(1), Event::CanVelocity(FORWARD), &PARAMS);
        assert_eq!(effects.setpoint, setpoint(FORWARD, 700));
        assert_eq!(effects.excite, Some(true));
        assert_eq!(supervisor.control(), ControlSource::Can);
        assert_eq!(supervisor.mode(), Mode::Active);
    }

    #[test]
    fn cmd_timeout_stops_a_stale_velocity_when_enabled() {
        let params = Params {
            cmd_timeout_ms: 200,
            ..PARAMS
        };
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &params);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &params);
        supervisor.step(at(150), Event::CanEnable { refresh: true }, &params);
        assert_eq!(
            supervisor.step(at(199), Event::Tick, &params).setpoint,
            None
        );
        let effects = supervisor.step(at(200), Event::Tick, &params);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 700));
    }

    #[test]
    fn withdrawn_enable_stops_at_once() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &PARAMS);
        let effects = supervisor.step(at(10), Event::CanEnable { refresh: false }, &PARAMS);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 700));
    }

    #[test]
    fn an_enable_withdrawn_while_a_gentle_zero_velocity_ramps_down_brakes_with_stop_decel() {
        // The PC asked for zero with a gentle `CAN_accel`; its enable then goes: the
        // stop brakes with `stop_decel`, not on along the gentle ramp to the same zero.
        let params = Params {
            can_accel: 100,
            ..PARAMS
        };
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &params);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &params);
        let effects = supervisor.step(at(10), Event::CanVelocity(Twist::ZERO), &params);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 100));
        let effects = supervisor.step(at(20), Event::CanEnable { refresh: false }, &params);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 600));
        // A stop already as hard is not sent again.
        let effects = supervisor.step(at(30), Event::Tick, &params);
        assert_eq!(effects.setpoint, None);
    }

    #[test]
    fn remote_held_through_an_emergency_does_not_drive_after_recovery() {
        let mut supervisor = remote_driving_forward();
        assert!(supervisor.remote_in_control());
        assert!(supervisor.remote_drives());
        supervisor.step(at(20), Event::Estop { pressed: true }, &PARAMS);
        supervisor.step(at(30), Event::Estop { pressed: false }, &PARAMS);
        // The confirm press counts once the stop has ended.
        supervisor.step(at(20 + STOPPED_AFTER_MS), Event::ConfirmPressed, &PARAMS);
        let effects = supervisor.step(at(350), Event::DrivesReady, &PARAMS);
        assert_eq!(effects.setpoint, None);
        assert!(!supervisor.remote_drives());
        assert_eq!(supervisor.control(), ControlSource::Remote);
        // Released and pressed again: now it drives.
        supervisor.step(
            at(360),
            Event::Remote {
                dead_man: false,
                twist: Twist::ZERO,
            },
            &PARAMS,
        );
        let effects = supervisor.step(
            at(370),
            Event::Remote {
                dead_man: true,
                twist: FORWARD,
            },
            &PARAMS,
        );
        assert_eq!(effects.setpoint, setpoint(FORWARD, 350));
        assert!(supervisor.remote_drives());
    }

    /// A pad that only reports, its dead-man up, has no control: a CAN drive goes on,
    /// neither stopped nor made to wait for rest.
    #[test]
    fn a_pad_reporting_its_dead_man_up_leaves_a_can_drive_alone() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &PARAMS);
        for ms in [10, 20, 30] {
            let released = Event::Remote {
                dead_man: false,
                twist: Twist::ZERO,
            };
            let effects = supervisor.step(at(ms), released, &PARAMS);
            assert_eq!(effects.setpoint, None, "at {ms} ms");
        }
        assert_eq!(supervisor.control(), ControlSource::Can);
        let slower = Twist {
            linear_mm_s: 200,
            rotation_mrad_s: 0,
        };
        supervisor.step(at(40), Event::CanEnable { refresh: true }, &PARAMS);
        let effects = supervisor.step(at(40), Event::CanVelocity(slower), &PARAMS);
        assert_eq!(effects.setpoint, setpoint(slower, PARAMS.can_accel));
    }

    /// What the status frame's e-stop flag shows, and what the feedback frames and
    /// the commands wait for: the safety inputs' levels as last told, unknown until
    /// then. At boot nothing drives before the input task told both the e-stop's and
    /// the zone's level, even with the drives ready.
    #[test]
    fn nothing_drives_until_the_estop_and_the_zone_are_told() {
        let drives_forward = |supervisor: &mut Supervisor, ms: u64| {
            supervisor.step(at(ms), Event::CanEnable { refresh: true }, &PARAMS);
            let effects = supervisor.step(at(ms), Event::CanVelocity(FORWARD), &PARAMS);
            effects.setpoint == setpoint(FORWARD, PARAMS.can_accel)
        };
        let mut supervisor = Supervisor::new();
        supervisor.step(at(0), Event::DrivesReady, &PARAMS);
        assert!(!supervisor.estop_known());
        assert!(!drives_forward(&mut supervisor, 0));
        supervisor.step(at(10), Event::Estop { pressed: false }, &PARAMS);
        assert!(supervisor.estop_known());
        assert!(
            !drives_forward(&mut supervisor, 20),
            "the zone is not told yet"
        );
        supervisor.step(at(30), Event::SafetyZone { occupied: false }, &PARAMS);
        assert!(drives_forward(&mut supervisor, 40));

        // The other way round: the zone told first.
        let mut supervisor = Supervisor::new();
        supervisor.step(at(0), Event::DrivesReady, &PARAMS);
        supervisor.step(at(10), Event::SafetyZone { occupied: false }, &PARAMS);
        assert!(
            !drives_forward(&mut supervisor, 20),
            "the e-stop is not told yet"
        );
        supervisor.step(at(30), Event::Estop { pressed: false }, &PARAMS);
        assert!(drives_forward(&mut supervisor, 40));
    }

    #[test]
    fn the_estop_flag_is_the_level_last_told() {
        let mut supervisor = ready();
        assert!(!supervisor.estop_pressed());
        supervisor.step(at(30), Event::Estop { pressed: true }, &PARAMS);
        assert!(supervisor.estop_pressed());
        supervisor.step(at(40), Event::Estop { pressed: false }, &PARAMS);
        assert!(!supervisor.estop_pressed());
        assert!(supervisor.estop_known());
    }

    #[test]
    fn a_motion_lock_neither_arms_nor_drives_and_its_lift_arms_only_a_dead_man_seen_up() {
        let lock = |locked| Event::MotionLock { locked };
        let released = Event::Remote {
            dead_man: false,
            twist: Twist::ZERO,
        };
        let held = Event::Remote {
            dead_man: true,
            twist: FORWARD,
        };
        // Locked: a release does not arm, a held dead-man does not drive, CAN is not
        // stored.
        let mut supervisor = ready();
        supervisor.step(at(0), lock(true), &PARAMS);
        supervisor.step(at(10), released, &PARAMS);
        assert_eq!(supervisor.step(at(20), held, &PARAMS), Effects::default());
        supervisor.step(at(30), Event::CanEnable { refresh: true }, &PARAMS);
        supervisor.step(at(30), released, &PARAMS);
        assert_eq!(
            supervisor.step(at(40), Event::CanVelocity(FORWARD), &PARAMS),
            Effects::default()
        );
        assert_eq!(supervisor.control(), ControlSource::None);
        // Held through the lift: no motion until released after it.
        supervisor.step(at(50), held, &PARAMS);
        supervisor.step(at(60), lock(false), &PARAMS);
        assert_eq!(
            supervisor.step(at(70), held, &PARAMS).setpoint,
            None,
            "a dead-man held through the lock drove"
        );
        supervisor.step(at(80), released, &PARAMS);
        assert_eq!(
            supervisor.step(at(90), held, &PARAMS).setpoint,
            setpoint(FORWARD, 350)
        );
        // Seen up when the lock lifts: armed, it drives when pressed.
        let mut supervisor = ready();
        supervisor.step(at(0), lock(true), &PARAMS);
        supervisor.step(at(10), released, &PARAMS);
        supervisor.step(at(20), lock(false), &PARAMS);
        assert_eq!(
            supervisor.step(at(30), held, &PARAMS).setpoint,
            setpoint(FORWARD, 350)
        );
    }

    #[test]
    fn a_motion_lock_stops_a_can_drive_and_disarms_the_dead_man() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &PARAMS);
        let effects = supervisor.step(at(10), Event::MotionLock { locked: true }, &PARAMS);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 700));
        // An armed, released pad is disarmed by the lock and re-armed at the lift only
        // because it is still seen up then.
        let mut supervisor = remote_driving_forward();
        supervisor.step(
            at(20),
            Event::Remote {
                dead_man: false,
                twist: Twist::ZERO,
            },
            &PARAMS,
        );
        supervisor.step(at(30), Event::MotionLock { locked: true }, &PARAMS);
        assert!(!supervisor.inputs.remote.armed);
    }

    #[test]
    fn a_pad_whose_first_report_holds_the_dead_man_does_not_drive() {
        // At boot, and after a link loss followed by a recovery: no report since, so
        // the dead-man was never seen released.
        let held = Event::Remote {
            dead_man: true,
            twist: FORWARD,
        };
        let mut supervisor = ready();
        assert_eq!(supervisor.step(at(10), held, &PARAMS).setpoint, None);
        assert!(!supervisor.remote_drives());
        assert_eq!(supervisor.control(), ControlSource::Remote);

        let mut supervisor = ready();
        supervisor.step(at(0), Event::RemoteLinkLost, &PARAMS);
        supervisor.step(at(10), Event::Estop { pressed: true }, &PARAMS);
        supervisor.step(at(20), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(30), Event::ConfirmPressed, &PARAMS);
        supervisor.step(at(40), Event::DrivesReady, &PARAMS);
        assert_eq!(supervisor.step(at(50), held, &PARAMS).setpoint, None);
        assert!(!supervisor.remote_drives());
    }

    #[test]
    fn a_dead_man_seen_released_before_the_drives_are_ready_drives_at_once() {
        let mut supervisor = Supervisor::new();
        supervisor.step(
            at(0),
            Event::Remote {
                dead_man: false,
                twist: Twist::ZERO,
            },
            &PARAMS,
        );
        supervisor.step(at(10), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(10), Event::SafetyZone { occupied: false }, &PARAMS);
        supervisor.step(at(10), Event::DrivesReady, &PARAMS);
        let effects = supervisor.step(
            at(20),
            Event::Remote {
                dead_man: true,
                twist: FORWARD,
            },
            &PARAMS,
        );
        assert_eq!(effects.setpoint, setpoint(FORWARD, 350));
    }

    #[test]
    fn remote_link_loss_while_held_brakes_with_contr_acc_high_or_stop_decel() {
        let mut supervisor = remote_driving_forward();
        let params = Params {
            stop_decel: 400,
            ..PARAMS
        };
        let effects = supervisor.step(at(20), Event::RemoteLinkLost, &params);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 500));
        assert_eq!(supervisor.control(), ControlSource::None);
        // stop_decel above Contr_acc_high: the floor applies.
        let mut supervisor = remote_driving_forward();
        let effects = supervisor.step(at(20), Event::RemoteLinkLost, &PARAMS);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 600));
        assert_eq!(supervisor.control(), ControlSource::None);
    }

    #[test]
    fn confirm_is_ignored_while_the_estop_is_still_pressed() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::Estop { pressed: true }, &PARAMS);
        let effects = supervisor.step(at(10), Event::ConfirmPressed, &PARAMS);
        assert!(!effects.setup_drives);
        assert_eq!(supervisor.mode(), Mode::Emergency);
    }

    #[test]
    fn a_drive_silent_while_starting_is_shown_without_leaving_starting_and_cleared_when_ready() {
        let mut supervisor = Supervisor::new();
        let effects = supervisor.step(at(300), Event::DriveSilent(Wheel::Right), &PARAMS);
        assert!(supervisor.faults().right_silent);
        assert!(!supervisor.faults().left_silent);
        assert_eq!(supervisor.mode(), Mode::Starting);
        assert_eq!(effects, Effects::default());
        supervisor.step(at(900), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(900), Event::SafetyZone { occupied: false }, &PARAMS);
        supervisor.step(at(900), Event::DrivesReady, &PARAMS);
        assert_eq!(supervisor.faults(), DriveFaults::default());
        assert_eq!(supervisor.mode(), Mode::Standby);
    }

    #[test]
    fn drives_losing_power_in_an_emergency_is_not_a_fault() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::Estop { pressed: true }, &PARAMS);
        supervisor.step(at(300), Event::DriveSilent(Wheel::Left), &PARAMS);
        supervisor.step(
            at(300),
            Event::DriveAlarm {
                wheel: Wheel::Right,
                code: 0x42,
            },
            &PARAMS,
        );
        assert_eq!(supervisor.faults(), DriveFaults::default());
        assert_eq!(supervisor.mode(), Mode::Emergency);
    }

    #[test]
    fn a_recovery_clears_the_latched_drive_faults_but_keeps_the_alarm_code() {
        let mut supervisor = ready();
        supervisor.step(
            at(0),
            Event::DriveAlarm {
                wheel: Wheel::Right,
                code: 0x84,
            },
            &PARAMS,
        );
        assert!(supervisor.faults().right_alarm);
        assert_eq!(supervisor.mode(), Mode::Fault);
        assert!(
            supervisor
                .step(at(10), Event::ConfirmPressed, &PARAMS)
                .setup_drives
        );
        supervisor.step(at(20), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(20), Event::SafetyZone { occupied: false }, &PARAMS);
        supervisor.step(at(20), Event::DrivesReady, &PARAMS);
        assert_eq!(
            supervisor.faults(),
            DriveFaults {
                last_alarm_code: 0x84,
                ..DriveFaults::default()
            }
        );
        assert_eq!(supervisor.mode(), Mode::Standby);
    }

    #[test]
    fn implausible_feedback_while_driving_stops_with_estop_decel_and_latches_until_recovery() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &PARAMS);
        supervisor.step(at(10), Event::AtRest(false), &PARAMS);
        let effects = supervisor.step(at(20), Event::FeedbackImplausible(Wheel::Left), &PARAMS);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 4500));
        assert_eq!(supervisor.mode(), Mode::Fault);
        assert!(supervisor.faults().left_implausible);
        assert!(!supervisor.faults().right_implausible);
        // The PC keeps asking: nothing drives.
        supervisor.step(at(30), Event::CanEnable { refresh: true }, &PARAMS);
        let effects = supervisor.step(at(30), Event::CanVelocity(FORWARD), &PARAMS);
        assert_eq!(effects.setpoint, None);
        assert_eq!(supervisor.mode(), Mode::Fault);
        supervisor.step(at(1_000), Event::ConfirmPressed, &PARAMS);
        supervisor.step(at(1_500), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(1_500), Event::SafetyZone { occupied: false }, &PARAMS);
        supervisor.step(at(1_500), Event::DrivesReady, &PARAMS);
        assert_eq!(supervisor.mode(), Mode::Standby);
        assert!(!supervisor.faults().left_implausible);
    }

    #[test]
    fn brakes_wait_for_measured_standstill_not_just_a_zero_command() {
        let mut supervisor = ready();
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &PARAMS);
        supervisor.step(at(0), Event::CanVelocity(FORWARD), &PARAMS);
        supervisor.step(at(10), Event::AtRest(false), &PARAMS);
        supervisor.step(at(20), Event::CanVelocity(Twist::ZERO), &PARAMS);
        // Still rolling long after disable_time: the brakes must not close on a moving base.
        assert_eq!(supervisor.step(at(1000), Event::Tick, &PARAMS).excite, None);
        supervisor.step(at(1100), Event::AtRest(true), &PARAMS);
        assert_eq!(supervisor.step(at(1399), Event::Tick, &PARAMS).excite, None);
        assert_eq!(
            supervisor.step(at(1400), Event::Tick, &PARAMS).excite,
            Some(false)
        );
        assert_eq!(supervisor.mode(), Mode::Standby);
    }

    /// Found by the whole-robot tester (`brake-at-once-seed-30-rule-4`): with
    /// `disable_time` 0, a zero that followed a start within one feedback cycle
    /// de-excited the drives at once on a standstill measured before the start, while
    /// the shaft turned at 15 r/min. Only a standstill measured after the last motion
    /// command lets the brakes close.
    #[test]
    fn a_standstill_measured_before_a_start_does_not_close_the_brakes_after_it() {
        let params = Params {
            disable_time_ms: 0,
            ..PARAMS
        };
        let mut supervisor = ready();
        supervisor.step(at(0), Event::AtRest(true), &params);
        supervisor.step(at(0), Event::CanEnable { refresh: true }, &params);
        supervisor.step(at(5), Event::CanVelocity(FORWARD), &params);
        let effects = supervisor.step(at(11), Event::CanVelocity(Twist::ZERO), &params);
        assert_eq!(effects.excite, None, "de-excited 6 ms after the start");
        assert_eq!(supervisor.step(at(30), Event::Tick, &params).excite, None);
        // Measured standing after the zero: the brakes close at once.
        assert_eq!(
            supervisor.step(at(60), Event::AtRest(true), &params).excite,
            Some(false)
        );
    }
}
