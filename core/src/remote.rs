//! The Bluetooth remote (docs/remote.md): what the gamepad's sticks and buttons mean. The
//! controller feeds it the BLE task's link reports, the decoded gamepad states and the
//! time; it answers with the dead-man and twist for the supervisor, an odometry reset,
//! and a request to disconnect the pad. It also keeps the pairing window, which the
//! `command` register opens. No radio here.
//!
//! ```text
//!               Connected                  L2 + Home pressed, or no input for
//!   Offline ──────────────▶ Connected ──── PS_afk_time (dead-man up) ───▶ SwitchingOff
//!      ▲                        │          (disconnect requested)              │
//!      │      Disconnected      │                                              │
//!      ├────────────────────────┘                                              │
//!      └────────────────────────────── Disconnected ───────────────────────────┘
//! ```
//!
//! - Only `Connected` drives. Leaving it tells the supervisor the remote is gone, so a
//!   held dead-man brakes with `Contr_acc_high`, as on a link loss.
//! - Reports in `Offline` are dropped; reports in `SwitchingOff` repeat the disconnect
//!   request (the BLE task has not acted on it yet).
//! - Each connection starts at the speed level `PS_rel_max_vel`, and with every button
//!   up: a button already down in the first report counts as pressed. The dead-man is
//!   the exception, enforced by the supervisor: it must be seen released first.

pub mod arbiter;

pub use arbiter::{Pad, PadArbiter};

use crate::gamepad::{Buttons, GamepadState};
use crate::kinematics::Twist;
use crate::time::Timestamp;

/// The button that must be held for the remote to drive: RB \[R1\].
pub const DEAD_MAN: Buttons = Buttons::RIGHT_BUMPER;
/// Pressed while L2 is held: reset the odometry. Menu \[Options\].
pub const RESET_ODOMETRY: Buttons = Buttons::MENU;
/// Pressed while L2 is held: switch the pad off (disconnect). Home \[PS\].
pub const SWITCH_OFF: Buttons = Buttons::HOME;

/// LT \[L2\] counts as held while the trigger is pulled further than this (0.0 … 1.0).
/// BLE pads report it as an analog axis, not a button: half way is a deliberate pull
/// that a finger resting on the trigger does not reach, and it is far from both ends,
/// where pads' calibrations differ. A pad with a digital trigger reports 0.0 or 1.0.
pub const MODIFIER_THRESHOLD: f32 = 0.5;

/// A D-pad press moves the speed level by this much (mm/s).
pub const LEVEL_STEP_MM_S: u16 = 50;
/// The lowest speed level (mm/s); the highest is `PS_abs_max_vel`.
pub const MIN_LEVEL_MM_S: u16 = 50;

/// How long the pairing window stays open after the command opened it (ms): time to
/// walk to the pad and put it into pairing mode, short enough that the robot is not
/// left open to any pad in range.
pub const PAIRING_WINDOW_MS: u64 = 60_000;

/// The registers the remote depends on, with their units in their names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Params {
    /// `PS_rel_max_vel`: the speed level each connection starts with.
    pub start_level_mm_s: u16,
    /// `PS_abs_max_vel`: the highest speed level.
    pub max_level_mm_s: u16,
    /// `wheel_dist`: full right stick turns at level · 2 / `wheel_dist`, so that each
    /// wheel runs at the level's speed.
    pub wheel_distance_mm: u16,
    /// `PS_afk_time`: the pad is switched off after this long without input.
    pub afk_timeout_ms: u32,
}

/// Everything the remote reacts to.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The BLE task reports a bonded pad connected. Repeated while connected it changes
    /// nothing: only a connection after a disconnection is a new one.
    Connected,
    /// The BLE task reports the link down: lost, or closed after a switch-off request.
    Disconnected,
    /// A gamepad report: the pad's whole state, sent when anything on it changed.
    Report(GamepadState),
    /// Registers changed: the level is clamped into the new range and a held stick is
    /// mapped again, so the change applies to the running command.
    ParamsChanged,
    /// Time passed: the AFK timeout is checked.
    Tick,
}

/// What the remote tells the supervisor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Control {
    /// Whether the dead-man is held and the twist the sticks ask for.
    Drive { dead_man: bool, twist: Twist },
    /// The remote no longer counts (link down, or the pad is being switched off): the
    /// supervisor treats it as a link loss.
    Lost,
}

/// The answer to one event. Empty fields mean "nothing".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Effects {
    pub control: Option<Control>,
    /// L2 + Menu: set the pose to zero.
    pub reset_odometry: bool,
    /// Ask the BLE task to disconnect the pad (it keeps the bond).
    pub disconnect: bool,
}

/// One connection of a pad.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Session {
    /// Full stick is this speed (mm/s).
    level_mm_s: u16,
    /// The latest report of this connection; `None` until the first.
    last: Option<GamepadState>,
    /// The latest report, or the connection before the first: AFK counts from here.
    last_input: Timestamp,
}

#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    /// No pad connected.
    Offline,
    /// A bonded pad is connected and its reports count.
    Connected(Session),
    /// The disconnect was requested; the BLE task has not reported the link down yet.
    SwitchingOff,
}

/// See the module documentation for the state diagram and the rules.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Remote {
    state: State,
}

impl Default for Remote {
    fn default() -> Self {
        Self::new()
    }
}

impl Remote {
    pub const fn new() -> Self {
        Self {
            state: State::Offline,
        }
    }

    /// Handles one event at `now` and returns what must happen.
    pub fn step(&mut self, now: Timestamp, event: Event, params: &Params) -> Effects {
        let mut effects = Effects::default();
        self.state = match (self.state, event) {
            (_, Event::Disconnected) => {
                effects.control = Some(Control::Lost);
                State::Offline
            }
            (State::Offline, Event::Connected) => State::Connected(Session {
                level_mm_s: clamp_level(params.start_level_mm_s, params),
                last: None,
                last_input: now,
            }),
            (State::Offline, Event::Report(_)) => {
                warn!("gamepad report without a connection dropped");
                State::Offline
            }
            (State::Connected(session), Event::Report(pad)) => {
                session.report(now, pad, params, &mut effects)
            }
            (State::Connected(session), Event::ParamsChanged) => {
                State::Connected(session.params_changed(params, &mut effects))
            }
            (State::Connected(session), Event::Tick) => {
                let held = session.last.is_some_and(dead_man_held);
                let idle_ms = now.millis_since(session.last_input);
                if !held && idle_ms >= u64::from(params.afk_timeout_ms) {
                    info!("gamepad idle for {=u64} ms: switching it off", idle_ms);
                    switch_off(&mut effects)
                } else {
                    State::Connected(session)
                }
            }
            (State::SwitchingOff, Event::Report(_)) => {
                effects.disconnect = true;
                State::SwitchingOff
            }
            (state @ (State::Connected(_) | State::SwitchingOff), Event::Connected)
            | (
                state @ (State::Offline | State::SwitchingOff),
                Event::ParamsChanged | Event::Tick,
            ) => state,
        };
        effects
    }
}

impl Session {
    fn report(
        mut self,
        now: Timestamp,
        pad: GamepadState,
        params: &Params,
        effects: &mut Effects,
    ) -> State {
        let before = self.last.unwrap_or_default();
        let pressed =
            |button: Buttons| pad.buttons.contains(button) && !before.buttons.contains(button);
        // `>` is false for NaN: a garbled trigger is not a held modifier.
        let modifier = pad.left_trigger > MODIFIER_THRESHOLD;
        if modifier && pressed(SWITCH_OFF) {
            // Nothing else in this report counts: the pad is on its way out.
            return switch_off(effects);
        }
        effects.reset_odometry = modifier && pressed(RESET_ODOMETRY);

        let up = pad.dpad.up && !before.dpad.up;
        let down = pad.dpad.down && !before.dpad.down;
        let level = clamp_level(self.level_mm_s, params);
        // Up and down in the same report (a garbled hat) cancel out.
        let level = match (up, down) {
            (true, false) => level.saturating_add(LEVEL_STEP_MM_S),
            (false, true) => level.saturating_sub(LEVEL_STEP_MM_S),
            _ => level,
        };
        self.level_mm_s = clamp_level(level, params);
        self.last = Some(pad);
        self.last_input = now;
        effects.control = Some(drive(pad, self.level_mm_s, params));
        State::Connected(self)
    }

    fn params_changed(mut self, params: &Params, effects: &mut Effects) -> Session {
        self.level_mm_s = clamp_level(self.level_mm_s, params);
        // Only a held dead-man drives; a released one is mapped again with the next report.
        if let Some(pad) = self.last.filter(|pad| dead_man_held(*pad)) {
            effects.control = Some(drive(pad, self.level_mm_s, params));
        }
        self
    }
}

fn switch_off(effects: &mut Effects) -> State {
    effects.control = Some(Control::Lost);
    effects.disconnect = true;
    State::SwitchingOff
}

fn dead_man_held(pad: GamepadState) -> bool {
    pad.buttons.contains(DEAD_MAN)
}

/// The level within `MIN_LEVEL_MM_S ..= PS_abs_max_vel`; if the registers ever allowed
/// a maximum below the minimum, the minimum wins (the slower one).
fn clamp_level(level_mm_s: u16, params: &Params) -> u16 {
    level_mm_s.min(params.max_level_mm_s).max(MIN_LEVEL_MM_S)
}

fn drive(pad: GamepadState, level_mm_s: u16, params: &Params) -> Control {
    Control::Drive {
        dead_man: dead_man_held(pad),
        twist: stick_twist(
            pad.left_y,
            pad.right_x,
            level_mm_s,
            params.wheel_distance_mm,
        ),
    }
}

/// The twist the sticks ask for at a speed level: left stick forward (+1) is
/// `level_mm_s` forward, right stick right (+1) is `level · 2 / wheel_dist` clockwise,
/// positive as on CAN (docs/behaviour.md, Conventions), which runs the left wheel forward and the right
/// one backward at the level's speed.
fn stick_twist(left_y: f32, right_x: f32, level_mm_s: u16, wheel_distance_mm: u16) -> Twist {
    let level = f32::from(level_mm_s);
    let full_turn_mrad_s = level * 2000.0 / f32::from(wheel_distance_mm);
    Twist {
        linear_mm_s: libm::roundf(stick(left_y) * level) as i32,
        rotation_mrad_s: libm::roundf(stick(right_x) * full_turn_mrad_s) as i32,
    }
}

/// A stick value from the decoder within −1 … 1; a NaN or infinite one (a broken
/// decoder) reads as centred, so it stops rather than drives at full speed.
fn stick(value: f32) -> f32 {
    if value.is_finite() {
        value.clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

/// The pairing window (ext): while it is open, the BLE task may bond one new pad.
/// Opened by the `command` register key [`crate::registers::OPEN_PAIRING_WINDOW_KEY`],
/// closed after [`PAIRING_WINDOW_MS`] or by the first new bond. Closed at boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PairingWindow {
    #[default]
    Closed,
    Open {
        until: Timestamp,
    },
}

impl PairingWindow {
    pub fn is_open(&self) -> bool {
        matches!(self, PairingWindow::Open { .. })
    }

    /// Opens the window for [`PAIRING_WINDOW_MS`] from `now`; an open one starts over.
    pub fn open(&mut self, now: Timestamp) {
        *self = PairingWindow::Open {
            until: now.plus_millis(PAIRING_WINDOW_MS),
        };
    }

    /// Closes the window; whether it was open.
    pub fn close(&mut self) -> bool {
        let was_open = self.is_open();
        *self = PairingWindow::Closed;
        was_open
    }

    /// Closes the window if its time is up at `now`; whether it closed.
    pub fn expire(&mut self, now: Timestamp) -> bool {
        match *self {
            PairingWindow::Open { until } if now >= until => self.close(),
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gamepad::Dpad;

    const PARAMS: Params = Params {
        start_level_mm_s: 250,
        max_level_mm_s: 1200,
        wheel_distance_mm: 250,
        afk_timeout_ms: 30_000,
    };

    fn at(ms: u64) -> Timestamp {
        Timestamp::from_millis(ms)
    }

    fn connected() -> Remote {
        let mut remote = Remote::new();
        remote.step(at(0), Event::Connected, &PARAMS);
        remote
    }

    fn held(buttons: Buttons) -> GamepadState {
        GamepadState {
            buttons,
            ..GamepadState::default()
        }
    }

    fn sticks(left_y: f32, right_x: f32) -> GamepadState {
        GamepadState {
            left_y,
            right_x,
            buttons: DEAD_MAN,
            ..GamepadState::default()
        }
    }

    fn twist(linear_mm_s: i32, rotation_mrad_s: i32) -> Twist {
        Twist {
            linear_mm_s,
            rotation_mrad_s,
        }
    }

    fn driving(linear_mm_s: i32, rotation_mrad_s: i32) -> Option<Control> {
        Some(Control::Drive {
            dead_man: true,
            twist: twist(linear_mm_s, rotation_mrad_s),
        })
    }

    fn report(remote: &mut Remote, ms: u64, pad: GamepadState) -> Effects {
        remote.step(at(ms), Event::Report(pad), &PARAMS)
    }

    #[test]
    fn full_left_stick_is_the_speed_level_forward_and_backward() {
        assert_eq!(stick_twist(1.0, 0.0, 250, 250), twist(250, 0));
        assert_eq!(stick_twist(-1.0, 0.0, 250, 250), twist(-250, 0));
        assert_eq!(stick_twist(0.5, 0.0, 1200, 250), twist(600, 0));
        // Rounded to nearest: 0.333 · 250 = 83.25.
        assert_eq!(stick_twist(0.333, 0.0, 250, 250), twist(83, 0));
    }

    #[test]
    fn right_stick_right_turns_clockwise_which_is_positive_rotation() {
        // docs/behaviour.md, Conventions: positive rotation is clockwise seen from above, so pushing the
        // stick to the right must give a positive rotation.
        let right = stick_twist(0.0, 1.0, 250, 250);
        assert!(right.rotation_mrad_s > 0);
        assert_eq!(
            stick_twist(0.0, -1.0, 250, 250).rotation_mrad_s,
            -right.rotation_mrad_s
        );
    }

    #[test]
    fn full_right_stick_turns_at_level_times_two_over_wheel_dist() {
        // 250 mm/s · 2 / 250 mm = 2 rad/s: each wheel runs at the level's 250 mm/s.
        assert_eq!(stick_twist(0.0, 1.0, 250, 250), twist(0, 2000));
        // A wider base turns slower at the same level: 250 · 2 / 500 = 1 rad/s.
        assert_eq!(stick_twist(0.0, 1.0, 250, 500), twist(0, 1000));
        // 1200 · 2 / 700 = 3.4286 rad/s; half stick 1.7143.
        assert_eq!(stick_twist(0.0, 1.0, 1200, 700), twist(0, 3429));
        assert_eq!(stick_twist(0.0, 0.5, 1200, 700), twist(0, 1714));
    }

    #[test]
    fn sticks_outside_their_range_are_clamped_and_garbage_reads_as_centred() {
        assert_eq!(stick_twist(3.0, -7.0, 250, 250), twist(250, -2000));
        assert_eq!(stick_twist(f32::NAN, f32::INFINITY, 250, 250), Twist::ZERO);
        assert_eq!(
            stick_twist(f32::NEG_INFINITY, f32::NAN, 250, 250),
            Twist::ZERO
        );
    }

    #[test]
    fn reports_drive_only_while_connected() {
        let mut remote = Remote::new();
        assert_eq!(report(&mut remote, 0, sticks(1.0, 0.0)).control, None);
        remote.step(at(10), Event::Connected, &PARAMS);
        assert_eq!(
            report(&mut remote, 20, sticks(1.0, 0.0)).control,
            driving(250, 0)
        );
        let lost = remote.step(at(30), Event::Disconnected, &PARAMS);
        assert_eq!(lost.control, Some(Control::Lost));
        assert_eq!(report(&mut remote, 40, sticks(1.0, 0.0)).control, None);
    }

    #[test]
    fn the_dead_man_is_the_right_bumper_alone() {
        let mut remote = connected();
        let released = GamepadState {
            left_y: 1.0,
            buttons: Buttons::LEFT_BUMPER.with(Buttons::A),
            right_trigger: 1.0,
            ..GamepadState::default()
        };
        assert_eq!(
            report(&mut remote, 10, released).control,
            Some(Control::Drive {
                dead_man: false,
                twist: twist(250, 0)
            })
        );
    }

    #[test]
    fn dpad_presses_step_the_level_within_50_and_ps_abs_max_vel() {
        let params = Params {
            max_level_mm_s: 400,
            ..PARAMS
        };
        let mut remote = Remote::new();
        remote.step(at(0), Event::Connected, &params);
        let mut ms = 0;
        let mut press = |remote: &mut Remote, dpad: Dpad| {
            ms += 10;
            remote.step(at(ms), Event::Report(held(Buttons::NONE)), &params);
            let pad = GamepadState {
                dpad,
                ..sticks(1.0, 0.0)
            };
            match remote.step(at(ms), Event::Report(pad), &params).control {
                Some(Control::Drive { twist, .. }) => twist.linear_mm_s,
                other => panic!("{other:?}"),
            }
        };
        let up = Dpad {
            up: true,
            ..Dpad::default()
        };
        let down = Dpad {
            down: true,
            ..Dpad::default()
        };
        let levels: Vec<i32> = [up, up, up, up].map(|d| press(&mut remote, d)).into();
        assert_eq!(levels, [300, 350, 400, 400]);
        let levels: Vec<i32> = [down; 8].map(|d| press(&mut remote, d)).into();
        assert_eq!(levels, [350, 300, 250, 200, 150, 100, 50, 50]);
    }

    #[test]
    fn a_held_dpad_steps_once_and_up_with_down_cancels() {
        let mut remote = connected();
        let up = GamepadState {
            dpad: Dpad {
                up: true,
                ..Dpad::default()
            },
            ..sticks(1.0, 0.0)
        };
        assert_eq!(report(&mut remote, 10, up).control, driving(300, 0));
        // Still held, stick moved: no second step.
        let up_half = GamepadState { left_y: 0.5, ..up };
        assert_eq!(report(&mut remote, 20, up_half).control, driving(150, 0));
        report(&mut remote, 30, sticks(1.0, 0.0));
        let both = GamepadState {
            dpad: Dpad {
                up: true,
                down: true,
                ..Dpad::default()
            },
            ..sticks(1.0, 0.0)
        };
        assert_eq!(report(&mut remote, 40, both).control, driving(300, 0));
    }

    #[test]
    fn every_connection_starts_at_ps_rel_max_vel() {
        let mut remote = connected();
        let up = GamepadState {
            dpad: Dpad {
                up: true,
                ..Dpad::default()
            },
            ..sticks(1.0, 0.0)
        };
        assert_eq!(report(&mut remote, 10, up).control, driving(300, 0));
        // Connected again while connected: the same connection.
        remote.step(at(20), Event::Connected, &PARAMS);
        assert_eq!(
            report(&mut remote, 30, sticks(1.0, 0.0)).control,
            driving(300, 0)
        );
        remote.step(at(40), Event::Disconnected, &PARAMS);
        remote.step(at(50), Event::Connected, &PARAMS);
        assert_eq!(
            report(&mut remote, 60, sticks(1.0, 0.0)).control,
            driving(250, 0)
        );
    }

    #[test]
    fn a_lowered_ps_abs_max_vel_clamps_the_level_and_the_held_stick_at_once() {
        let mut remote = connected();
        let up = GamepadState {
            dpad: Dpad {
                up: true,
                ..Dpad::default()
            },
            ..sticks(1.0, 0.5)
        };
        assert_eq!(report(&mut remote, 10, up).control, driving(300, 1200));
        let lowered = Params {
            max_level_mm_s: 200,
            wheel_distance_mm: 400,
            ..PARAMS
        };
        let effects = remote.step(at(20), Event::ParamsChanged, &lowered);
        assert_eq!(effects.control, driving(200, 500));
        // Raised again: the level stays where the clamp put it.
        let effects = remote.step(at(30), Event::ParamsChanged, &PARAMS);
        assert_eq!(effects.control, driving(200, 800));
    }

    #[test]
    fn a_register_change_maps_again_only_a_held_dead_man() {
        let mut remote = connected();
        // No report yet: nothing to map (and "released" would be a guess).
        assert_eq!(
            remote.step(at(5), Event::ParamsChanged, &PARAMS).control,
            None
        );
        let released = GamepadState {
            buttons: Buttons::NONE,
            ..sticks(1.0, 0.0)
        };
        report(&mut remote, 10, released);
        assert_eq!(
            remote.step(at(20), Event::ParamsChanged, &PARAMS).control,
            None
        );
    }

    #[test]
    fn buttons_down_in_the_first_report_of_a_connection_count_as_pressed() {
        // Pads report only changes: the first report is usually the operator's first
        // press, and must not be swallowed as a baseline.
        let mut remote = connected();
        let first = GamepadState {
            left_trigger: 1.0,
            buttons: DEAD_MAN.with(Buttons::MENU),
            dpad: Dpad {
                up: true,
                ..Dpad::default()
            },
            ..sticks(1.0, 0.0)
        };
        let effects = report(&mut remote, 10, first);
        assert!(effects.reset_odometry);
        assert_eq!(effects.control, driving(300, 0));
    }

    #[test]
    fn l2_with_menu_resets_the_odometry_menu_alone_does_not() {
        let mut remote = connected();
        assert!(!report(&mut remote, 10, held(Buttons::MENU)).reset_odometry);
        report(&mut remote, 20, held(Buttons::NONE));
        let l2 = GamepadState {
            left_trigger: 1.0,
            ..GamepadState::default()
        };
        assert!(!report(&mut remote, 30, l2).reset_odometry);
        let l2_menu = GamepadState {
            buttons: Buttons::MENU,
            ..l2
        };
        assert!(report(&mut remote, 40, l2_menu).reset_odometry);
        // Held on: one reset per press.
        assert!(
            !report(
                &mut remote,
                50,
                GamepadState {
                    left_y: 0.2,
                    ..l2_menu
                }
            )
            .reset_odometry
        );
    }

    #[test]
    fn l2_counts_as_held_only_beyond_the_threshold() {
        let mut remote = connected();
        let menu_at = |left_trigger| GamepadState {
            left_trigger,
            buttons: Buttons::MENU,
            ..GamepadState::default()
        };
        for (ms, trigger) in [(10, MODIFIER_THRESHOLD), (30, f32::NAN)] {
            assert!(
                !report(&mut remote, ms, menu_at(trigger)).reset_odometry,
                "{trigger}"
            );
            report(&mut remote, ms + 10, held(Buttons::NONE));
        }
        assert!(report(&mut remote, 50, menu_at(0.51)).reset_odometry);
    }

    #[test]
    fn l2_with_home_switches_the_pad_off_and_ends_its_control() {
        let mut remote = connected();
        report(&mut remote, 10, held(Buttons::NONE));
        assert_eq!(
            report(&mut remote, 20, sticks(1.0, 0.0)).control,
            driving(250, 0)
        );
        assert!(!report(&mut remote, 30, held(DEAD_MAN.with(Buttons::HOME))).disconnect);
        let l2_home = GamepadState {
            left_trigger: 1.0,
            buttons: DEAD_MAN,
            ..sticks(1.0, 0.0)
        };
        report(&mut remote, 40, l2_home);
        let l2_home = GamepadState {
            buttons: DEAD_MAN.with(Buttons::HOME),
            ..l2_home
        };
        let effects = report(&mut remote, 50, l2_home);
        assert_eq!(
            effects,
            Effects {
                control: Some(Control::Lost),
                reset_odometry: false,
                disconnect: true,
            }
        );
        // Until the BLE task reports the link down, reports repeat the request and
        // drive nothing.
        let effects = report(&mut remote, 60, sticks(1.0, 0.0));
        assert_eq!((effects.control, effects.disconnect), (None, true));
        remote.step(at(70), Event::Disconnected, &PARAMS);
        assert!(!report(&mut remote, 80, sticks(1.0, 0.0)).disconnect);
    }

    #[test]
    fn no_input_for_ps_afk_time_switches_the_pad_off_counting_from_the_last_report() {
        let mut remote = connected();
        assert!(!remote.step(at(29_999), Event::Tick, &PARAMS).disconnect);
        report(&mut remote, 29_999, held(Buttons::A));
        assert!(!remote.step(at(59_998), Event::Tick, &PARAMS).disconnect);
        let effects = remote.step(at(59_999), Event::Tick, &PARAMS);
        assert_eq!(
            (effects.control, effects.disconnect),
            (Some(Control::Lost), true)
        );
        // Asked once; the BLE task reports the link down next.
        assert!(!remote.step(at(70_000), Event::Tick, &PARAMS).disconnect);
    }

    #[test]
    fn a_held_dead_man_is_input_so_afk_waits_for_its_release() {
        // Pads send nothing while a button stays down: driving straight at full stick
        // for longer than PS_afk_time must not switch the pad off under the operator.
        let mut remote = connected();
        report(&mut remote, 0, sticks(1.0, 0.0));
        assert!(!remote.step(at(100_000), Event::Tick, &PARAMS).disconnect);
        report(&mut remote, 100_000, held(Buttons::NONE));
        assert!(!remote.step(at(129_999), Event::Tick, &PARAMS).disconnect);
        assert!(remote.step(at(130_000), Event::Tick, &PARAMS).disconnect);
    }

    #[test]
    fn pairing_window_opens_for_a_minute_restarts_and_closes() {
        let mut window = PairingWindow::default();
        assert!(!window.is_open());
        assert!(!window.expire(at(0)));
        window.open(at(1_000));
        assert!(!window.expire(at(60_999)));
        window.open(at(30_000));
        assert!(!window.expire(at(89_999)));
        assert!(window.expire(at(90_000)));
        assert!(!window.is_open());
        window.open(at(100_000));
        assert!(window.close());
        assert!(!window.close());
    }
}
