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
//!      │                          │ DrivesReady      drive lost /   │
//!      │                       Recovering ◀──────┐   alarm          ▼
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
//! - The remote's dead-man wins over CAN; its release brakes with `Contr_acc_high`.

use crate::can::{ControlSource, Mode};
use crate::kinematics::{SafetyLimits, Twist};
use crate::time::Instant;

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
    /// Whether both wheels are measured at rest, from the latest drive feedback.
    AtRest(bool),
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
pub struct SupervisorParams {
    pub enable_timeout_ms: u32,
    /// 0 = a CAN velocity never goes stale by itself.
    pub cmd_timeout_ms: u32,
    pub disable_time_ms: u32,
    pub can_accel: u32,
    pub remote_accel: u32,
    pub remote_release_accel: u32,
    pub estop_decel: u32,
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
    /// The latest non-zero alarm code either drive reported (stays after recovery, for the log).
    pub last_alarm_code: u8,
}

impl DriveFaults {
    fn any(&self) -> bool {
        self.left_silent || self.left_alarm || self.right_silent || self.right_alarm
    }

    /// Sets the wheel's bit: silent without an alarm code, alarm with one.
    fn record(&mut self, wheel: Wheel, alarm: Option<u8>) {
        match (wheel, alarm) {
            (Wheel::Left, None) => self.left_silent = true,
            (Wheel::Left, Some(code)) => {
                self.left_alarm = true;
                self.last_alarm_code = code;
            }
            (Wheel::Right, None) => self.right_silent = true,
            (Wheel::Right, Some(code)) => {
                self.right_alarm = true;
                self.last_alarm_code = code;
            }
        }
    }
}

/// The supervisor's state. Data lives in the variant that needs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    /// After boot, until the drive link reports the drives ready.
    Starting,
    /// Drives ready and de-excited: the brakes hold the base.
    Standby,
    /// Drives excited. `at_rest_since` runs while nothing is requested and the wheels stand.
    Active { at_rest_since: Option<Instant> },
    /// The e-stop is pressed.
    Emergency,
    /// The e-stop was released; a confirm press is needed.
    AwaitingConfirm,
    /// Confirmed; the drive link sets the drives up again.
    Recovering,
    /// A drive fault outside an e-stop; a confirm press starts the recovery. The drive
    /// that still answers is de-excited once the base stands for `disable_time`.
    Fault { at_rest_since: Option<Instant> },
}

/// A CAN velocity stored while the enable is fresh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct CanCommand {
    twist: Twist,
    received: Instant,
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

/// See the module documentation for the state diagram and the rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Supervisor {
    state: State,
    enable_refreshed: Option<Instant>,
    can_command: Option<CanCommand>,
    remote: RemoteInput,
    safety_zone: bool,
    estop_pressed: bool,
    at_rest: bool,
    excited: bool,
    faults: DriveFaults,
    /// The last setpoint sent; a new one goes out only when it differs.
    last_setpoint: Setpoint,
    /// The acceleration for the next stop: depends on why the request went away.
    stop_accel: u32,
    control: ControlSource,
    /// When an e-stop or a drive fault commanded zero with `estop_decel`: the drives
    /// are de-excited [`STOPPED_AFTER_MS`] later, when every wheel stands.
    emergency_stop_at: Option<Instant>,
}

/// After this long at `estop_decel` every wheel stands: the registers only accept an
/// `estop_decel` that stops `max_motor_vel` within it.
pub const STOPPED_AFTER_MS: u64 = crate::registers::ESTOP_POWER_CUT_MS as u64;

impl Default for Supervisor {
    fn default() -> Self {
        Self::new()
    }
}

impl Supervisor {
    pub const fn new() -> Self {
        Self {
            state: State::Starting,
            enable_refreshed: None,
            can_command: None,
            remote: RemoteInput {
                reported: false,
                dead_man: false,
                twist: Twist::ZERO,
                armed: false,
            },
            safety_zone: false,
            estop_pressed: false,
            at_rest: true,
            excited: false,
            faults: DriveFaults {
                left_silent: false,
                left_alarm: false,
                right_silent: false,
                right_alarm: false,
                last_alarm_code: 0,
            },
            last_setpoint: Setpoint {
                twist: Twist::ZERO,
                accel_rpm_per_s: 0,
            },
            stop_accel: 0,
            control: ControlSource::None,
            emergency_stop_at: None,
        }
    }

    /// Handles one event at `now` and returns what must happen.
    pub fn step(&mut self, now: Instant, event: Event, params: &SupervisorParams) -> Effects {
        let mut effects = Effects::default();
        self.expire_can(now, params);
        match event {
            Event::CanEnable { refresh: true } => self.enable_refreshed = Some(now),
            Event::CanEnable { refresh: false } => self.withdraw_enable(params),
            Event::CanVelocity(twist) => {
                // Stored only when it may drive: no enable, remote in control or a
                // non-driving state all mean the frame is dropped, not buffered.
                if self.enable_fresh(now, params) && !self.remote_in_control() && self.may_drive() {
                    self.can_command = Some(CanCommand {
                        twist,
                        received: now,
                    });
                }
            }
            Event::Remote { dead_man, twist } => self.remote_report(dead_man, twist, params),
            Event::RemoteLinkLost => {
                if self.remote_in_control() {
                    self.stop_accel = params.remote_release_accel;
                }
                self.remote = RemoteInput {
                    reported: false,
                    dead_man: false,
                    twist: Twist::ZERO,
                    armed: false,
                };
            }
            Event::Estop { pressed } => {
                self.estop_pressed = pressed;
                if pressed {
                    self.enter_emergency(now, params, &mut effects);
                } else if self.state == State::Emergency {
                    self.state = State::AwaitingConfirm;
                }
            }
            Event::SafetyZone { occupied } => self.safety_zone = occupied,
            Event::ConfirmPressed => {
                if matches!(self.state, State::AwaitingConfirm | State::Fault { .. }) {
                    self.state = State::Recovering;
                    effects.setup_drives = true;
                    // The setup leaves the drives de-excited: say so, so nothing
                    // re-excites them from an old request.
                    if self.excited {
                        self.excited = false;
                        effects.excite = Some(false);
                    }
                }
            }
            Event::DrivesReady => {
                if matches!(self.state, State::Starting | State::Recovering) {
                    self.state = State::Standby;
                    self.excited = false;
                    // A dead-man seen up when the drives come back may take control; a
                    // pad that has not reported yet has not been seen released.
                    self.remote.armed = self.remote.reported && !self.remote.dead_man;
                    self.faults = DriveFaults {
                        last_alarm_code: self.faults.last_alarm_code,
                        ..DriveFaults::default()
                    };
                    self.last_setpoint = Setpoint {
                        twist: Twist::ZERO,
                        accel_rpm_per_s: 0,
                    };
                }
            }
            Event::DriveSilent(wheel) => self.drive_fault(now, wheel, None, params, &mut effects),
            Event::DriveAlarm { wheel, code } => {
                self.drive_fault(now, wheel, Some(code), params, &mut effects)
            }
            Event::AtRest(at_rest) => self.at_rest = at_rest,
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
            State::Emergency => Mode::Emergency,
            State::AwaitingConfirm => Mode::AwaitingConfirm,
            State::Recovering => Mode::Recovering,
            State::Fault { .. } => Mode::Fault,
        }
    }

    /// Which source's command the drives are following.
    pub fn control(&self) -> ControlSource {
        self.control
    }

    /// Emergency mode in the manual's sense lasts until the confirm press: no feedback
    /// frames (0x0EA..0x0ED) are sent during it.
    pub fn in_emergency(&self) -> bool {
        matches!(self.state, State::Emergency | State::AwaitingConfirm)
    }

    pub fn enable_fresh(&self, now: Instant, params: &SupervisorParams) -> bool {
        self.enable_refreshed
            .is_some_and(|at| now.millis_since(at) < u64::from(params.enable_timeout_ms))
    }

    pub fn safety_zone(&self) -> bool {
        self.safety_zone
    }

    pub fn estop_pressed(&self) -> bool {
        self.estop_pressed
    }

    pub fn remote_in_control(&self) -> bool {
        self.remote.armed && self.remote.dead_man
    }

    /// The drives were last told to de-excite (S-OFF): their brakes hold the base.
    /// What was commanded, never an assumption about the drives' power.
    pub fn brakes_applied(&self) -> bool {
        !self.excited
    }

    pub fn faults(&self) -> DriveFaults {
        self.faults
    }

    fn may_drive(&self) -> bool {
        matches!(self.state, State::Standby | State::Active { .. })
    }

    fn withdraw_enable(&mut self, params: &SupervisorParams) {
        self.enable_refreshed = None;
        if self.can_command.take().is_some() {
            self.stop_accel = params.can_accel;
        }
    }

    /// Drops the stored CAN velocity when its enable lapsed or (with `cmd_timeout`) when
    /// it went stale, so a returning enable never resumes an old command.
    fn expire_can(&mut self, now: Instant, params: &SupervisorParams) {
        if !self.enable_fresh(now, params) {
            self.enable_refreshed = None;
            if self.can_command.take().is_some() {
                self.stop_accel = params.can_accel;
            }
        }
        if let Some(command) = self.can_command {
            let stale = params.cmd_timeout_ms != 0
                && now.millis_since(command.received) >= u64::from(params.cmd_timeout_ms);
            if stale {
                self.can_command = None;
                self.stop_accel = params.can_accel;
            }
        }
    }

    fn remote_report(&mut self, dead_man: bool, twist: Twist, params: &SupervisorParams) {
        let was_in_control = self.remote_in_control();
        if !dead_man && self.may_drive() {
            self.remote.armed = true;
        }
        self.remote.reported = true;
        self.remote.dead_man = dead_man;
        self.remote.twist = twist;
        if self.remote_in_control() && !was_in_control {
            // The remote takes over; CAN must send a fresh velocity after the release.
            self.can_command = None;
        }
        if was_in_control && !self.remote_in_control() {
            self.stop_accel = params.remote_release_accel;
        }
    }

    fn enter_emergency(&mut self, now: Instant, params: &SupervisorParams, effects: &mut Effects) {
        self.state = State::Emergency;
        self.can_command = None;
        self.remote.armed = false;
        self.stop_accel = params.estop_decel;
        self.emergency_stop_at = Some(now);
        // Always sent, even if the last setpoint was already zero: the e-stop edge must put
        // zero on the wire at once, with the e-stop deceleration.
        self.send_zero(params.estop_decel, effects);
    }

    fn drive_fault(
        &mut self,
        now: Instant,
        wheel: Wheel,
        alarm: Option<u8>,
        params: &SupervisorParams,
        effects: &mut Effects,
    ) {
        // While (re)starting nothing moves, so a drive that does not answer or keeps an
        // alarm is no reason to stop; but the PC must see why the base does not get
        // ready, so the fault bit is set and the drives' readiness clears it.
        if matches!(self.state, State::Starting | State::Recovering) {
            self.faults.record(wheel, alarm);
            return;
        }
        // Every fault latches, the second one too (both drives off: both reported).
        if matches!(self.state, State::Fault { .. }) {
            self.faults.record(wheel, alarm);
            return;
        }
        // In an emergency the drives lose power by design (and often raise an
        // undervoltage alarm on the way down): not a fault.
        if !self.may_drive() {
            return;
        }
        self.faults.record(wheel, alarm);
        debug_assert!(self.faults.any());
        self.state = State::Fault {
            at_rest_since: None,
        };
        self.can_command = None;
        self.remote.armed = false;
        self.stop_accel = params.estop_decel;
        self.emergency_stop_at = Some(now);
        self.send_zero(params.estop_decel, effects);
    }

    fn send_zero(&mut self, accel: u32, effects: &mut Effects) {
        let zero = Setpoint {
            twist: Twist::ZERO,
            accel_rpm_per_s: accel,
        };
        self.last_setpoint = zero;
        self.control = ControlSource::None;
        effects.setpoint = Some(zero);
    }

    /// Arbitrates the sources, clamps to the safety zone and runs the brake timer.
    fn update_motion(&mut self, now: Instant, params: &SupervisorParams, effects: &mut Effects) {
        if let State::Fault { at_rest_since } = self.state {
            let at_rest_since = self.brake_timer(now, false, at_rest_since, params, effects);
            self.state = State::Fault { at_rest_since };
        }
        if !self.may_drive() {
            if self.last_setpoint.twist != Twist::ZERO {
                self.send_zero(self.stop_accel, effects);
            }
            self.control = ControlSource::None;
            // After an e-stop or a drive fault, every wheel stands once `estop_decel`
            // had its time: the brakes close even if no feedback says so.
            let stopped = self
                .emergency_stop_at
                .is_some_and(|at| now.millis_since(at) >= STOPPED_AFTER_MS);
            if self.excited && stopped {
                self.excited = false;
                effects.excite = Some(false);
            }
            return;
        }
        self.emergency_stop_at = None;

        let (control, twist, accel) = if self.remote_in_control() {
            (
                ControlSource::Remote,
                self.remote.twist,
                params.remote_accel,
            )
        } else if let Some(command) = self.can_command {
            (ControlSource::Can, command.twist, params.can_accel)
        } else {
            (ControlSource::None, Twist::ZERO, self.stop_accel)
        };
        let twist = if self.safety_zone {
            twist.clamped(params.safety_limits)
        } else {
            twist
        };
        self.control = control;

        let requested = twist != Twist::ZERO;
        if requested && !self.excited {
            self.excited = true;
            effects.excite = Some(true);
            self.state = State::Active {
                at_rest_since: None,
            };
        }

        if twist != self.last_setpoint.twist {
            let setpoint = Setpoint {
                twist,
                accel_rpm_per_s: accel,
            };
            self.last_setpoint = setpoint;
            effects.setpoint = Some(setpoint);
        }

        if let State::Active { at_rest_since } = self.state {
            let at_rest_since = self.brake_timer(now, requested, at_rest_since, params, effects);
            self.state = if self.excited {
                State::Active { at_rest_since }
            } else {
                State::Standby
            };
        }
    }

    /// De-excites the drives once nothing is requested and the wheels have been measured
    /// at rest for `disable_time`. Returns when the standstill began (if it runs).
    fn brake_timer(
        &mut self,
        now: Instant,
        requested: bool,
        at_rest_since: Option<Instant>,
        params: &SupervisorParams,
        effects: &mut Effects,
    ) -> Option<Instant> {
        if !self.excited || requested || !self.at_rest {
            return None;
        }
        let since = at_rest_since.unwrap_or(now);
        if now.millis_since(since) >= u64::from(params.disable_time_ms) {
            self.excited = false;
            effects.excite = Some(false);
            return None;
        }
        Some(since)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PARAMS: SupervisorParams = SupervisorParams {
        enable_timeout_ms: 500,
        cmd_timeout_ms: 0,
        disable_time_ms: 300,
        can_accel: 700,
        remote_accel: 350,
        remote_release_accel: 500,
        estop_decel: 4500,
        safety_limits: SafetyLimits {
            linear_mm_s: 200,
            rotation_mrad_s: 100,
        },
    };

    const FORWARD: Twist = Twist {
        linear_mm_s: 500,
        rotation_mrad_s: 0,
    };

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    fn ready() -> Supervisor {
        let mut supervisor = Supervisor::new();
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
        let params = SupervisorParams {
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
    fn remote_held_through_an_emergency_does_not_drive_after_recovery() {
        let mut supervisor = remote_driving_forward();
        assert!(supervisor.remote_in_control());
        supervisor.step(at(20), Event::Estop { pressed: true }, &PARAMS);
        supervisor.step(at(30), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(40), Event::ConfirmPressed, &PARAMS);
        let effects = supervisor.step(at(50), Event::DrivesReady, &PARAMS);
        assert_eq!(effects.setpoint, None);
        assert!(!supervisor.remote_in_control());
        // Released and pressed again: now it drives.
        supervisor.step(
            at(60),
            Event::Remote {
                dead_man: false,
                twist: Twist::ZERO,
            },
            &PARAMS,
        );
        let effects = supervisor.step(
            at(70),
            Event::Remote {
                dead_man: true,
                twist: FORWARD,
            },
            &PARAMS,
        );
        assert_eq!(effects.setpoint, setpoint(FORWARD, 350));
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
        assert!(!supervisor.remote_in_control());

        let mut supervisor = ready();
        supervisor.step(at(0), Event::RemoteLinkLost, &PARAMS);
        supervisor.step(at(10), Event::Estop { pressed: true }, &PARAMS);
        supervisor.step(at(20), Event::Estop { pressed: false }, &PARAMS);
        supervisor.step(at(30), Event::ConfirmPressed, &PARAMS);
        supervisor.step(at(40), Event::DrivesReady, &PARAMS);
        assert_eq!(supervisor.step(at(50), held, &PARAMS).setpoint, None);
        assert!(!supervisor.remote_in_control());
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
    fn remote_link_loss_while_held_brakes_with_contr_acc_high() {
        let mut supervisor = remote_driving_forward();
        let effects = supervisor.step(at(20), Event::RemoteLinkLost, &PARAMS);
        assert_eq!(effects.setpoint, setpoint(Twist::ZERO, 500));
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
}
