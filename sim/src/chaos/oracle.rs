//! The oracle: checks the rules of [`super::rules`] on what the robot does at its
//! wires and buses — what each drive's motor is told and when, the shafts' speeds,
//! the CAN frames both ways, the flash operations, the boots — against what the tester
//! made happen (the PC's frames, the pads, the pins, the faults). It is written from
//! docs/behaviour.md and docs/protocol.md, never from the firmware's code: its own
//! models of who may move the base, of the e-stop, of the update lock, of the
//! registers and of the boot slots are upper bounds of what the documents allow, so a
//! violation is something no reading of them permits.
//!
//! The world feeds it every observation at the virtual moment it happens, in time
//! order (the drives' order changes first, up to that moment), and ticks it every
//! control cycle with the shafts' speeds.

use std::collections::VecDeque;

use super::event::{PadHands, PadKind, wire};
use super::registers::{self, Registers, address};
use super::rules::{Rule, bounds};
use crate::drives::{MotorOrder, MotorOrderChange};
use base_core::drives::DriveSettings;

/// Home \[PS\] in a report's buttons (Xbox layout bits, docs/remote.md): with L2, the
/// pad switches off.
const SWITCH_OFF: u16 = 1 << 8;

/// The front button's debounce (and a little): its release reaches the controller then.
const BUTTON_DEBOUNCE_US: Us = 25_000;

/// Microseconds of virtual time since the run's start.
pub type Us = u64;

/// What broke, when, and how.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation {
    pub rule: Rule,
    pub at_us: Us,
    pub what: String,
}

/// A fault the world injected, for the rules that ask whether a reported fault
/// happened and whether the controller could reach a drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Injected {
    /// Something on the drives' line or in a drive (silence, garbling, a busy drive,
    /// power, an alarm, lost replies, failing long requests), for `slave` (0: both).
    DriveLine {
        slave: u8,
        active: bool,
    },
    /// A drive's feedback lies (stuck encoder, stale speed), or heals.
    Feedback {
        slave: u8,
        active: bool,
    },
    /// A drive turns against its command and reports it so (its direction parameter
    /// at the other value), or is set right: its feedback lies too, as above.
    ReversedMotion {
        slave: u8,
        active: bool,
    },
    Flash,
    LoadCell {
        missing: bool,
    },
    CanBus,
}

/// What the controller is doing, from the world.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Controller {
    /// Reset, booting or dark since this moment.
    Down { since: Us },
    /// Its tasks run since this moment.
    Up { since: Us },
}

/// One drive as the oracle sees it.
#[derive(Debug, Clone, Copy)]
struct Drive {
    order: MotorOrder,
    /// Since when it is excited without a break.
    excited_since: Option<Us>,
    /// The last sampled shaft speed (r/min, its own direction).
    speed_rpm: f64,
    /// Line or drive faults active now.
    faults: u32,
    /// When the last line or drive fault was injected or healed.
    fault_at: Option<Us>,
    feedback_lie: bool,
    feedback_at: Option<Us>,
    /// When its order last changed.
    order_at: Us,
    /// Its shaft turns against its command (and its feedback says so).
    reversed_motion: bool,
    /// Since when it has turned against its command at `AGAINST_RPM` or more, its order
    /// keeping one sign (+1 or -1).
    against_since: Option<(Us, f64)>,
    /// The earliest moment the check may count from: after the order changed sign, a
    /// healthy wheel on the commanded ramp needs this long to come round (from the
    /// old target, the speed it had or where the commanded ramp had got to, whichever
    /// is farther, to `AGAINST_RPM` on the new side; docs/behaviour.md: "every speed
    /// the commanded ramp passed through").
    against_from: Us,
    /// Where the commanded ramps had got to when the order last changed (r/min in the
    /// order's direction) and when: each order from the moment it came, at its rate,
    /// from where the one before had got to, never corrected by the shaft's speed, as
    /// the controller's own model has it (core/src/plausibility.rs, `Commanded`). A
    /// reversed shaft leaves that model behind: after a stop and a new order, the
    /// ramp may still be far on the old side while the shaft is near zero.
    ramp_rpm: f64,
    ramp_at: Us,
}

impl Drive {
    fn new() -> Self {
        Self {
            order: MotorOrder {
                powered: true,
                power_ons: 0,
                servo_on: false,
                alarm: 0,
                target_rpm: 0.0,
                decel_rpm_per_s: 0.0,
            },
            excited_since: None,
            speed_rpm: 0.0,
            faults: 0,
            fault_at: None,
            feedback_lie: false,
            feedback_at: None,
            order_at: 0,
            reversed_motion: false,
            against_since: None,
            against_from: 0,
            ramp_rpm: 0.0,
            ramp_at: 0,
        }
    }

    /// Where the commanded ramp is at `at`: on from `ramp_rpm` towards the order's
    /// target at its rate; zero while the drive is de-excited (the controller ramps to
    /// zero before it lets go, and sets its model standing when it sets the drives up).
    fn ramp_rpm_at(&self, at: Us) -> f64 {
        if !self.order.excited() {
            return 0.0;
        }
        let step = self.order.decel_rpm_per_s * at.saturating_sub(self.ramp_at) as f64 / 1e6;
        let target = self.order.target_rpm;
        if self.ramp_rpm < target {
            (self.ramp_rpm + step).min(target)
        } else {
            (self.ramp_rpm - step).max(target)
        }
    }

    fn moving_order(&self) -> bool {
        self.order.excited() && self.order.target_rpm != 0.0
    }

    /// Whether a fault could keep the controller's frames from this drive at any time
    /// in `since..`.
    fn unreachable_since(&self, since: Us) -> bool {
        self.faults > 0 || self.fault_at.is_some_and(|at| at + 1_000_000 >= since)
    }

    /// Whether its feedback lies or lied lately: the controller's ramps start from a
    /// wrong speed until the plausibility check trips (two 100 ms windows).
    fn feedback_lied_since(&self, since: Us) -> bool {
        self.feedback_lie || self.feedback_at.is_some_and(|at| at + 1_000_000 >= since)
    }
}

/// The robot PC's side of who may move the base: the enable and the stored velocity.
#[derive(Debug, Clone, Copy, Default)]
struct CanSource {
    /// When the last refreshing enable reached the controller.
    enable_at: Option<Us>,
    /// The stored velocity and when it arrived.
    velocity: Option<(i16, i16, Us)>,
}

/// One pad as the controller's remote side sees it.
#[derive(Debug, Clone, Copy, Default)]
struct Pad {
    connected_at: Option<Us>,
    hands: Option<PadHands>,
    /// Its dead-man was seen released since it took control, the last e-stop and the
    /// last update lock (docs/behaviour.md, "Who may move the base").
    armed: bool,
}

/// The update lock as the PC sees it (docs/protocol.md, "Firmware update").
#[derive(Debug, Clone, Default)]
struct UpdateLock {
    /// A session runs: its id and when it began.
    session: Option<(u8, Us)>,
    /// A refusal may have ended the session (several do): until a STATE reply says,
    /// the lock counts as lifted for who may drive, and no motion is held against it.
    session_uncertain: bool,
    /// The PC's last frame that keeps a session alive (its commands, any data frame).
    last_heard: Us,
    /// An image on trial since this boot.
    trial_since: Option<Us>,
}

impl UpdateLock {
    /// The lock surely holds.
    fn locked(&self) -> bool {
        (self.session.is_some() && !self.session_uncertain) || self.trial_since.is_some()
    }
}

/// The boot slots as the PC sees them: the confirmed version, and the one activated
/// but not yet confirmed.
#[derive(Debug, Clone)]
struct Images {
    confirmed: String,
    /// Activated (ACTIVATE sent): it may boot once, on trial.
    activated: Option<String>,
    /// The session that activated it, which alone may confirm it (`None`: not known
    /// to the controller either, as after a power cut: anyone may).
    activated_by: Option<u8>,
    /// CONFIRM was sent during its trial by a program that may decide (its answer
    /// may have been lost).
    confirm_sent: bool,
    /// The versions each session sends.
    sessions: Vec<(u8, String)>,
    /// Boots since the activation.
    boots_since_activation: u32,
}

impl Images {
    /// Whether a CONFIRM or ROLLBACK naming `session` may decide about the image on
    /// trial.
    fn may_decide(&self, session: u8) -> bool {
        self.activated_by.is_none_or(|owner| owner == session)
    }

    /// The chip's RTC RAM was cleared (a power cut, the reset button): the next boot
    /// cannot know who activated an image.
    fn forget_activator(&mut self) {
        self.activated_by = None;
    }
}

/// The stop the rules expect after a source's command ended or the e-stop: from the
/// fastest wheel's speed, at the gentlest deceleration allowed.
#[derive(Debug, Clone, Copy)]
struct Stop {
    rule: Rule,
    /// When the non-zero command ended.
    since: Us,
    /// Zero must be on the wire by then.
    zero_by: Us,
    /// Whether that is still to check (the line was clean).
    zero_checked: bool,
    /// Whether the wheels must stop: the source's control ended (a source in control
    /// that asks for zero ramps with its own register, however gentle).
    envelope: bool,
    /// When control ended.
    control_ended: Us,
    /// Braking starts by then at the latest.
    brakes_by: Us,
    decel_rpm_per_s: f64,
    /// The fastest shaft speed seen from the end of control to `brakes_by`.
    fastest_rpm: f64,
}

/// Periodic frames: when the last one came and since when they are due.
#[derive(Debug, Clone, Copy, Default)]
struct Period {
    last: Option<Us>,
    due_since: Option<Us>,
    /// The longest period in force since the last frame: a frame scheduled with the
    /// old period comes on its old schedule.
    longest_us: Us,
}

/// The oracle.
pub struct Oracle {
    now: Us,
    violation: Option<Violation>,
    controller: Controller,
    /// The boot's panic-loop decision, and whether a confirm press or the key may have
    /// turned Bluetooth on since (pads drive only if it may be on; a held dead-man
    /// overrides CAN only if it surely is).
    bluetooth_surely_on: bool,
    bluetooth_may_be_on: bool,
    /// Why the running firmware's drive settings are ones it must refuse; then it
    /// never sets the drives up (docs/drives.md, "Settings the firmware refuses").
    refused_settings: Option<&'static str>,
    drives: [Drive; 2],
    can: CanSource,
    pads: [Pad; 2],
    /// The e-stop input: pressed now (or chattering), and since when it is released.
    estop_pressed: bool,
    estop_released_at: Option<Us>,
    /// The e-stop's last press.
    estop_pressed_at: Option<Us>,
    /// A command came within one input sample after the e-stop's press: the firmware
    /// may have taken it before it sampled the e-stop, and its order may reach the
    /// wire before the stop's zero.
    command_raced_estop: bool,
    /// Emergency latched: nothing moves until released and confirmed.
    emergency: bool,
    emergency_since: Us,
    zone_pressed: bool,
    zone_released_at: Option<Us>,
    /// Since when the zone input is active without a break.
    zone_since: Option<Us>,
    button_down_at: Option<Us>,
    update: UpdateLock,
    images: Images,
    registers: Registers,
    /// Register reads asked: (address, tag, when the request reached the controller).
    reads: VecDeque<(u8, u16, Us)>,
    /// Register writes: (address, value, when).
    writes: VecDeque<(u8, u16, Us)>,
    /// Flash stalls: (start, end).
    stalls: VecDeque<(Us, Us)>,
    /// Whether a source may move the base now, and the last moment one could.
    permitted: bool,
    /// Whether a source is in control with a fresh command (zero included).
    controlled: bool,
    last_permitted: Us,
    stop: Option<Stop>,
    estop_stop: Option<Stop>,
    position: Period,
    status: Period,
    last_status: Option<[u8; 8]>,
    /// The confirm press started a recovery (the drives are set up again) and no frame
    /// has shown its end yet: a status frame in a driving mode, or a position frame.
    /// Feedback is not due meanwhile; the last status frame, from before the e-stop,
    /// says nothing about it (`status_time` may be long).
    recovering: bool,
    /// The boot's first status frame is still to come.
    first_status_of_boot: bool,
    flash_fault_this_boot: bool,
    flash_fault_before: bool,
    last_pose: Option<PoseSeen>,
    /// Both wheels' forward motor revolutions, as the world last told.
    wheel_revolutions: [f64; 2],
    heading: Option<[u8; 4]>,
    /// Fault causes: when each kind last happened.
    flash_fault_injected: bool,
    load_cell_missing_at: Option<Us>,
    can_fault_at: Option<Us>,
    /// The current boot followed a panic or a watchdog reset.
    boot_after_panic: bool,
    /// The last resets and stalls, for reported drive faults.
    reset_at: Option<Us>,
    recent: VecDeque<String>,
}

/// The position frame's content that tells whether the pose moved.
/// A position frame as seen: when, its bytes, the heading frame's then, and the
/// wheels' revolutions at that moment.
type PoseSeen = (Us, [u8; 8], Option<[u8; 4]>, [f64; 2]);

fn pose_of(data: &[u8]) -> [u8; 8] {
    let mut pose = [0u8; 8];
    let len = data.len().min(8);
    pose[..len].copy_from_slice(&data[..len]);
    pose
}

impl Default for Oracle {
    fn default() -> Self {
        Self::new()
    }
}

impl Oracle {
    pub fn new() -> Self {
        Self {
            now: 0,
            violation: None,
            controller: Controller::Down { since: 0 },
            bluetooth_surely_on: true,
            bluetooth_may_be_on: true,
            refused_settings: None,
            drives: [Drive::new(), Drive::new()],
            can: CanSource::default(),
            pads: [Pad::default(); 2],
            estop_pressed: false,
            estop_released_at: None,
            estop_pressed_at: None,
            command_raced_estop: false,
            emergency: false,
            emergency_since: 0,
            zone_pressed: false,
            zone_released_at: None,
            zone_since: None,
            button_down_at: None,
            update: UpdateLock::default(),
            images: Images {
                confirmed: crate::app_flash::FACTORY_VERSION.to_owned(),
                activated: None,
                activated_by: None,
                confirm_sent: false,
                sessions: Vec::new(),
                boots_since_activation: 0,
            },
            registers: Registers::default(),
            reads: VecDeque::new(),
            writes: VecDeque::new(),
            stalls: VecDeque::new(),
            permitted: false,
            controlled: false,
            last_permitted: 0,
            stop: None,
            estop_stop: None,
            position: Period::default(),
            status: Period::default(),
            last_status: None,
            recovering: false,
            first_status_of_boot: true,
            flash_fault_this_boot: false,
            flash_fault_before: false,
            last_pose: None,
            wheel_revolutions: [0.0; 2],
            heading: None,
            flash_fault_injected: false,
            load_cell_missing_at: None,
            can_fault_at: None,
            boot_after_panic: false,
            reset_at: None,
            recent: VecDeque::new(),
        }
    }

    /// The first violation, if any.
    pub fn violation(&self) -> Option<&Violation> {
        self.violation.as_ref()
    }

    fn violate(&mut self, rule: Rule, at: Us, what: String) {
        if self.violation.is_none() {
            self.violation = Some(Violation {
                rule,
                at_us: at,
                what,
            });
        }
    }

    /// A line for the report's "what the robot did" tail.
    fn note(&mut self, at: Us, what: String) {
        if self.recent.len() == 400 {
            self.recent.pop_front();
        }
        self.recent
            .push_back(format!("{:>10.3} s  {what}", at as f64 / 1e6));
    }

    /// The robot's last observations worth a line.
    pub fn recent(&self) -> Vec<String> {
        self.recent.iter().cloned().collect()
    }

    fn up(&self) -> bool {
        matches!(self.controller, Controller::Up { .. })
    }

    fn up_since(&self) -> Option<Us> {
        match self.controller {
            Controller::Up { since } => Some(since),
            Controller::Down { .. } => None,
        }
    }

    /// The stalls' time inside `from..to`: the whole chip stood still meanwhile, so
    /// every deadline of the controller moves by it.
    fn stalled(&self, from: Us, to: Us) -> Us {
        self.stalls
            .iter()
            .map(|&(start, end)| end.min(to).saturating_sub(start.max(from)))
            .sum()
    }

    // -----------------------------------------------------------------------------
    // Who may move the base (rule 1), the e-stop's latch (rule 2), the lock (rule 3)
    // -----------------------------------------------------------------------------

    fn enable_fresh(&self, at: Us) -> bool {
        let timeout_us = u64::from(self.registers.max(address::ENABLE_TIMEOUT)) * 1_000;
        self.can
            .enable_at
            .is_some_and(|enabled| at <= enabled + timeout_us + self.stalled(enabled, at))
    }

    /// A stored velocity that is not stale (zero included).
    fn velocity_current(&self, at: Us) -> bool {
        let Some((_, _, since)) = self.can.velocity else {
            return false;
        };
        // `cmd_timeout` 0 is off; any value that may be in force counts.
        let off = self.registers.min(address::CMD_TIMEOUT) == 0;
        let timeout_us = u64::from(self.registers.max(address::CMD_TIMEOUT)) * 1_000;
        off || at <= since + timeout_us + self.stalled(since, at)
    }

    /// The pad in control: the first one connected of those connected.
    fn pad_in_control(&self) -> Option<usize> {
        (0..2)
            .filter(|&index| self.pads[index].connected_at.is_some())
            .min_by_key(|&index| self.pads[index].connected_at)
    }

    fn dead_man_held(&self) -> bool {
        self.bluetooth_surely_on
            && self
                .pad_in_control()
                .is_some_and(|index| self.pads[index].hands.is_some_and(|hands| hands.dead_man))
    }

    fn pad_drives(&self) -> bool {
        if !self.bluetooth_may_be_on {
            return false;
        }
        self.pad_in_control().is_some_and(|index| {
            let pad = self.pads[index];
            pad.armed
                && pad.hands.is_some_and(|hands| {
                    hands.dead_man && (hands.left_y != 0 || hands.right_x != 0)
                })
        })
    }

    fn estop_active(&self, at: Us) -> bool {
        self.estop_pressed
            || self
                .estop_released_at
                .is_some_and(|released| at < released + 50_000)
    }

    fn zone_active(&self, at: Us) -> bool {
        self.zone_pressed
            || self
                .zone_released_at
                .is_some_and(|released| at < released + 100_000)
    }

    fn moving_velocity(&self) -> bool {
        self.can
            .velocity
            .is_some_and(|(linear, rotation, _)| linear != 0 || rotation != 0)
    }

    /// A source in control has a fresh non-zero command: a wheel may be told to turn.
    fn permission(&self, at: Us) -> bool {
        if !self.up() || self.emergency || self.estop_active(at) || self.update.locked() {
            return false;
        }
        let can = !self.dead_man_held()
            && self.enable_fresh(at)
            && self.velocity_current(at)
            && self.moving_velocity();
        can || self.pad_drives()
    }

    /// A source is in control with a fresh command, zero included: the base follows
    /// its ramps. When this ends, the base stops at `stop_decel` or harder.
    fn control(&self, at: Us) -> bool {
        if !self.up() || self.emergency || self.estop_active(at) || self.update.locked() {
            return false;
        }
        let can = !self.dead_man_held() && self.enable_fresh(at) && self.velocity_current(at);
        let pad = self.bluetooth_may_be_on
            && self.pad_in_control().is_some_and(|index| {
                let pad = self.pads[index];
                pad.armed && pad.hands.is_some_and(|hands| hands.dead_man)
            });
        can || pad
    }

    /// The next moment a timeout changes the CAN source on its own.
    fn next_lapse(&self) -> Option<Us> {
        let enable = self.can.enable_at.map(|enabled| {
            let timeout_us = u64::from(self.registers.max(address::ENABLE_TIMEOUT)) * 1_000;
            enabled + timeout_us + self.stalled(enabled, self.now) + 1
        });
        let velocity = self.can.velocity.and_then(|(_, _, since)| {
            (self.registers.min(address::CMD_TIMEOUT) != 0).then(|| {
                let timeout_us = u64::from(self.registers.max(address::CMD_TIMEOUT)) * 1_000;
                since + timeout_us + self.stalled(since, self.now) + 1
            })
        });
        let estop = self.estop_released_at.map(|released| released + 50_000);
        let zero_due = |stop: &Option<Stop>| {
            stop.as_ref()
                .filter(|stop| stop.zero_checked)
                .map(|stop| stop.zero_by + 1)
        };
        [
            enable,
            velocity,
            estop,
            zero_due(&self.stop),
            zero_due(&self.estop_stop),
        ]
        .into_iter()
        .flatten()
        .filter(|&at| at > self.now)
        .min()
    }

    /// Brings the time-driven parts up to `to`: lapses, and the stops' deadlines.
    fn advance_to(&mut self, to: Us) {
        while let Some(next) = self.next_lapse().filter(|&at| at <= to) {
            self.now = next;
            if !self.enable_fresh(next) && self.can.enable_at.is_some() {
                self.can.enable_at = None;
                self.can.velocity = None;
            }
            self.update_permission(next);
            self.check_zero(next);
        }
        self.now = self.now.max(to);
        self.update_permission(to);
    }

    /// Records the start or end of permission and control, and the stop that must
    /// follow an end.
    fn update_permission(&mut self, at: Us) {
        let permitted = self.permission(at);
        let controlled = permitted || self.control(at);
        if permitted {
            self.last_permitted = at;
            self.stop = None;
        } else if self.permitted {
            // The non-zero command ended: zero on the wire.
            let stalls = self.stalled(self.last_permitted, at);
            let unreachable = self.unreachable(at);
            self.stop = Some(Stop {
                rule: Rule::OneSourceMoves,
                since: at,
                zero_by: at + bounds::ZERO_AFTER_END_US + stalls,
                zero_checked: !unreachable,
                envelope: false,
                control_ended: at,
                brakes_by: at,
                decel_rpm_per_s: self.gentlest_stop(),
                fastest_rpm: 0.0,
            });
        }
        if !controlled && self.controlled {
            // The source's control ended: the wheels stop.
            let stalls = self.stalled(self.last_permitted, at);
            let unreachable = self.unreachable(at);
            let fastest = self.fastest_rpm();
            let decel = self.gentlest_stop();
            let stop = self.stop.get_or_insert(Stop {
                rule: Rule::OneSourceMoves,
                since: at,
                zero_by: at,
                zero_checked: false,
                envelope: false,
                control_ended: at,
                brakes_by: at,
                decel_rpm_per_s: decel,
                fastest_rpm: 0.0,
            });
            if !stop.envelope {
                stop.envelope = true;
                stop.control_ended = at;
                stop.brakes_by = at
                    + bounds::ZERO_AFTER_END_US
                    + stalls
                    + if unreachable {
                        bounds::UNREACHABLE_US
                    } else {
                        0
                    };
                stop.decel_rpm_per_s = decel;
                stop.fastest_rpm = fastest;
            }
        }
        self.permitted = permitted;
        self.controlled = controlled;
    }

    /// Whether the controller may be unable to reach a drive from `at` on: a line or
    /// drive fault, or the controller is down or has not set the drives up again yet.
    fn unreachable(&self, at: Us) -> bool {
        let settled = self.up_since().is_some_and(|since| at >= since + 2_000_000);
        !settled
            || self
                .drives
                .iter()
                .any(|drive| drive.unreachable_since(at) || drive.feedback_lied_since(at))
    }

    /// The gentlest deceleration a stop may use: `stop_decel`'s floor, or the
    /// e-stop's if a fault's stop may be gentler (a small `max_motor_vel` allows it).
    fn gentlest_stop(&self) -> f64 {
        bounds::STOP_DECEL_FLOOR.min(f64::from(self.registers.min(address::ESTOP_DECEL))) * 0.97
    }

    fn fastest_rpm(&self) -> f64 {
        self.drives
            .iter()
            .map(|drive| drive.speed_rpm.abs())
            .fold(0.0, f64::max)
    }

    // -----------------------------------------------------------------------------
    // Observations
    // -----------------------------------------------------------------------------

    /// The drives' order changes up to now, oldest first.
    pub fn orders(&mut self, changes: &[MotorOrderChange]) {
        for change in changes {
            let at = change.at.as_micros();
            self.advance_to(at);
            let index = usize::from(change.slave.saturating_sub(1)).min(1);
            self.order(at, index, change);
        }
    }

    fn order(&mut self, at: Us, index: usize, change: &MotorOrderChange) {
        let before = self.drives[index].order;
        let ramp = self.drives[index].ramp_rpm_at(at);
        let order = change.order;
        self.drives[index].order = order;
        self.drives[index].order_at = at;
        self.drives[index].ramp_rpm = if order.excited() { ramp } else { 0.0 };
        self.drives[index].ramp_at = at;
        // Where the commanded ramp had got to, not a stop's zero target nor a reversed
        // shaft's speed, is where the command comes round from: a PC that withdraws and
        // drives the other way a moment later turns round a ramp still far on the old
        // side, however near zero the reversed shaft already is (seed 126: the ramp at
        // 450 r/min, the shaft at 40; the controller judges by the ramp).
        let ramp_comes_round = ramp * order.target_rpm < 0.0;
        if order.target_rpm != 0.0
            && (before.target_rpm.signum() != order.target_rpm.signum() || ramp_comes_round)
        {
            let from = before
                .target_rpm
                .abs()
                .max(change.speed_rpm.abs())
                .max(ramp.abs());
            let rate = order.decel_rpm_per_s.max(1.0);
            let ramp_us = (from + bounds::AGAINST_RPM) / rate * 1e6;
            self.drives[index].against_from = at + ramp_us as Us;
        }
        self.drives[index].excited_since = match (before.excited(), order.excited()) {
            (_, false) => None,
            (false, true) => Some(at),
            (true, true) => self.drives[index].excited_since,
        };
        let side = if index == 0 { "left" } else { "right" };
        if order.excited()
            && (order.target_rpm != before.target_rpm
                || order.decel_rpm_per_s != before.decel_rpm_per_s)
        {
            self.note(
                at,
                format!(
                    "{side} drive ordered {:+.0} r/min at {:.0} (1/min)/s (shaft at {:+.0})",
                    order.target_rpm, order.decel_rpm_per_s, change.speed_rpm
                ),
            );
        } else if order.excited() != before.excited() {
            self.note(
                at,
                format!(
                    "{side} drive {} (S-ON {}, alarm {:#x}, power {})",
                    if order.excited() {
                        "excited"
                    } else {
                        "de-excited"
                    },
                    order.servo_on,
                    order.alarm,
                    order.powered
                ),
            );
        }
        // Rule 1: a firmware that refuses its drive settings holds the drives, stopped
        // and de-excited; it never excites one or orders it a speed.
        if let (Some(refused), Controller::Up { .. }) = (self.refused_settings, self.controller) {
            let moves = order.target_rpm != 0.0 && order.target_rpm != before.target_rpm;
            if order.excited() && (!before.excited() || moves) {
                self.violate(
                    Rule::OneSourceMoves,
                    at,
                    format!(
                        "the {side} drive was set going (S-ON, {:+.0} r/min) by a firmware whose drive settings must be refused: {refused}",
                        order.target_rpm,
                    ),
                );
            }
        }
        // Rule 4: the controller's S-OFF closes the brake on a turning wheel.
        if before.excited()
            && order.powered
            && order.power_ons == before.power_ons
            && order.alarm == 0
            && !order.servo_on
            && change.speed_rpm.abs() > 10.0
        {
            self.violate(
                Rule::BrakesAndFlash,
                at,
                format!(
                    "the {side} drive was de-excited (S-OFF) while its shaft turned at {:.0} r/min",
                    change.speed_rpm
                ),
            );
        }
        if !(order.excited() && order.target_rpm != 0.0) {
            return;
        }
        let target = order.target_rpm.abs();
        // Rule 1: beyond `max_motor_vel`, or beyond the zone's limit.
        let max = f64::from(self.registers.max(address::MAX_MOTOR_VEL));
        if target > max + 1.0 {
            self.violate(
                Rule::OneSourceMoves,
                at,
                format!(
                    "the {side} drive was ordered {target:.0} r/min, above max_motor_vel {max}"
                ),
            );
        }
        let zone_limit = f64::from(self.registers.max(address::SEC_MOTOR_VEL));
        let zone_settled = self
            .zone_since
            .is_some_and(|since| at >= since + bounds::COMMAND_LATENCY_US)
            && self.zone_active(at);
        if zone_settled && target > zone_limit + 1.0 {
            self.violate(
                Rule::OneSourceMoves,
                at,
                format!(
                    "the {side} drive was ordered {target:.0} r/min while someone is in the safety zone (sec_motor_vel {zone_limit})"
                ),
            );
        }
        // A new non-zero order needs a source that could ask for it just now; an order
        // that only slows the wheel down towards zero is part of a stop.
        let slowing = before.excited()
            && before.target_rpm.signum() == order.target_rpm.signum()
            && target < before.target_rpm.abs();
        // A drive reversed (its direction parameter changed) turns the command it has
        // round: nobody commanded anything new (seed 221: 35 ms after a panic).
        if slowing || change.turned_round {
            return;
        }
        let latency = bounds::COMMAND_LATENCY_US + self.stalled(self.last_permitted, at);
        if self.permitted || at <= self.last_permitted + latency {
            return;
        }
        let (rule, why) = if self.emergency || self.estop_active(at) {
            // Decided from a command the firmware took before it sampled the e-stop:
            // such an order may reach the wire until the stop's zero is due.
            if self.command_raced_estop
                && self
                    .estop_pressed_at
                    .is_some_and(|pressed| at <= pressed + bounds::ESTOP_ZERO_US)
            {
                return;
            }
            (
                Rule::EmergencyStop,
                "in an emergency (e-stop pressed, or not yet confirmed)".to_owned(),
            )
        } else if self.update.locked() {
            (
                Rule::UpdateLock,
                "while the firmware update's lock holds".to_owned(),
            )
        } else {
            (Rule::OneSourceMoves, self.why_no_source(at))
        };
        self.violate(
            rule,
            at,
            format!(
                "the {side} drive was ordered {:+.0} r/min {why}",
                order.target_rpm
            ),
        );
    }

    fn why_no_source(&self, at: Us) -> String {
        let since = (at - self.last_permitted) as f64 / 1000.0;
        let can = if self.dead_man_held() {
            "a dead-man is held (CAN ignored)".to_owned()
        } else if !self.enable_fresh(at) {
            "no fresh enable".to_owned()
        } else if self.can.velocity.is_none() {
            "no velocity since the enable".to_owned()
        } else {
            "the velocity is zero or stale".to_owned()
        };
        let pad = match self.pad_in_control() {
            None => "no pad connected".to_owned(),
            Some(index) => {
                let pad = self.pads[index];
                let name = if index == 0 { "BLE" } else { "PlayStation" };
                match pad.hands {
                    Some(hands) if hands.dead_man && !pad.armed => {
                        format!("the {name} pad's dead-man is held but was not seen released")
                    }
                    Some(hands) if hands.dead_man => format!("the {name} pad's sticks are centred"),
                    _ => format!("the {name} pad's dead-man is up"),
                }
            }
        };
        format!("with no source in control for {since:.1} ms: CAN: {can}; pad: {pad}")
    }

    /// A frame the PC put on the bus reached the controller at `at`.
    pub fn pc_frame(&mut self, at: Us, id: u16, data: &[u8]) {
        self.advance_to(at);
        if id == wire::UPDATE_DATA {
            self.update.last_heard = at;
        }
        if id == wire::UPDATE_COMMAND {
            self.update_command(at, data);
        }
        if !self.up() {
            return;
        }
        match id {
            wire::ENABLE if !data.is_empty() => {
                if data[0] == wire::ENABLE_REFRESH {
                    // Refused while the update lock holds (rejection 0x50).
                    if !self.update.locked() {
                        self.can.enable_at = Some(at);
                    }
                } else {
                    self.can.enable_at = None;
                    self.can.velocity = None;
                }
            }
            wire::VELOCITY if data.len() >= 5 && data[4] == wire::VELOCITY_MARKER => {
                self.note_command_race(at);
                let linear = i16::from_le_bytes([data[0], data[1]]);
                let rotation = i16::from_le_bytes([data[2], data[3]]);
                let taken = self.enable_fresh(at)
                    && !self.dead_man_held()
                    && !self.emergency
                    && !self.estop_active(at)
                    && !self.update.locked();
                if taken {
                    self.can.velocity = Some((linear, rotation, at));
                }
            }
            wire::REGISTER_WRITE if data.len() >= 3 => {
                let value = u16::from_be_bytes([data[1], data[2]]);
                self.registers.written(at, data[0], value);
                self.writes.push_back((data[0], value, at));
                if data[0] == address::COMMAND && value == registers::BLUETOOTH_ON {
                    self.bluetooth_may_be_on = true;
                }
            }
            wire::REGISTER_READ if data.len() >= 2 && data[0] == 0x01 => {
                let tag = if data.len() >= 4 {
                    u16::from_be_bytes([data[2], data[3]])
                } else {
                    0
                };
                self.reads.push_back((data[1], tag, at));
            }
            wire::REGISTER_READ if data.len() >= 5 && data[0] == 0x02 => {
                let (first, count) = (data[1], data[2]);
                let tag = u16::from_be_bytes([data[3], data[4]]);
                if (1..=wire::BULK_READ_MAX).contains(&count)
                    && usize::from(first) + usize::from(count) <= 256
                {
                    for address in (first..=u8::MAX).take(usize::from(count)) {
                        self.reads.push_back((address, tag, at));
                    }
                }
            }
            _ => {}
        }
        self.trim(at);
        self.update_permission(at);
    }

    fn trim(&mut self, at: Us) {
        let horizon = at.saturating_sub(5_000_000);
        while self.reads.front().is_some_and(|read| read.2 < horizon) {
            self.reads.pop_front();
        }
        while self.writes.front().is_some_and(|write| write.2 < horizon) {
            self.writes.pop_front();
        }
        let stall_horizon = at.saturating_sub(120_000_000);
        while self
            .stalls
            .front()
            .is_some_and(|stall| stall.1 < stall_horizon)
        {
            self.stalls.pop_front();
        }
    }

    fn update_command(&mut self, at: Us, data: &[u8]) {
        let Some(&opcode) = data.first() else {
            return;
        };
        let session = data.get(1).copied();
        if let Some((running, _)) = self.update.session
            && session == Some(running)
            && (2..=7).contains(&opcode)
        {
            self.update.last_heard = at;
        }
        match opcode {
            // ACTIVATE: the image may boot once, on trial, from the next boot.
            0x06 => {
                if let Some(version) = session.and_then(|session| self.session_version(session)) {
                    self.images.activated = Some(version);
                    self.images.activated_by = session.filter(|&session| session != 0);
                    self.images.confirm_sent = false;
                    self.images.boots_since_activation = 0;
                }
            }
            // CONFIRM, from the session that activated the image (one without a
            // session byte names none).
            0x08 if self.update.trial_since.is_some()
                && self.images.may_decide(session.unwrap_or(0)) =>
            {
                self.images.confirm_sent = true;
            }
            _ => {}
        }
    }

    fn session_version(&self, session: u8) -> Option<String> {
        self.images
            .sessions
            .iter()
            .rev()
            .find(|(id, _)| *id == session)
            .map(|(_, version)| version.clone())
    }

    /// An update program announces the version its session `session` sends.
    pub fn session_image(&mut self, session: u8, version: &str) {
        self.images.sessions.push((session, version.to_owned()));
    }

    /// A frame the controller put on the bus, complete at `at`.
    pub fn bc_frame(&mut self, at: Us, id: u16, data: &[u8]) {
        self.advance_to(at);
        match id {
            wire::STATUS if data.len() == 8 => self.status_frame(at, data),
            wire::POSITION => self.position_frame(at, data),
            wire::HEADING if data.len() >= 4 => {
                self.heading = Some([data[0], data[1], data[2], data[3]]);
            }
            wire::UPDATE_REPLY => self.update_reply(at, data),
            wire::REGISTER_READ if data.len() == 6 && data[0] == 0x00 => {
                let value = u16::from_be_bytes([data[1], data[2]]);
                let address = data[3];
                let tag = u16::from_be_bytes([data[4], data[5]]);
                self.read_reply(address, tag, value);
            }
            _ => {}
        }
        if matches!(
            id,
            wire::WEIGHT
                | wire::BATTERY
                | wire::POSITION
                | wire::HEADING
                | wire::POSE_TIME
                | wire::MEASURED_SPEED
        ) && self.estop_pressed
            && self.estop_since_press(at) > 10_000 + bounds::FRAME_QUEUE_US
        {
            self.violate(
                Rule::EmergencyStop,
                at,
                format!("feedback frame {id:#05x} sent while the e-stop was pressed"),
            );
        }
        self.update_permission(at);
    }

    fn estop_since_press(&self, at: Us) -> Us {
        at.saturating_sub(self.emergency_since)
    }

    fn read_reply(&mut self, address: u8, tag: u16, value: u16) {
        let Some(index) = self
            .reads
            .iter()
            .position(|&(asked, asked_tag, _)| asked == address && asked_tag == tag)
        else {
            return;
        };
        let (_, _, asked_at) = self.reads.remove(index).unwrap_or_default();
        let writes_after: Vec<u16> = self
            .writes
            .iter()
            .filter(|&&(written, _, at)| written == address && at > asked_at)
            .map(|&(_, value, _)| value)
            .collect();
        self.registers.read(asked_at, address, value, &writes_after);
    }

    fn status_frame(&mut self, at: Us, data: &[u8]) {
        let status: [u8; 8] = data.try_into().unwrap_or_default();
        let mode = status[0] & 0x0F;
        let flags = status[1];
        let faults = status[2];
        let built = at.saturating_sub(bounds::FRAME_QUEUE_US);
        // Rule 4: brakes applied while a drive is excited.
        if flags & 0x80 != 0 {
            for (index, drive) in self.drives.into_iter().enumerate() {
                if drive
                    .excited_since
                    .is_some_and(|since| since + bounds::FRAME_QUEUE_US < at)
                {
                    let side = if index == 0 { "left" } else { "right" };
                    self.violate(
                        Rule::BrakesAndFlash,
                        at,
                        format!(
                            "the status frame says brakes_applied while the {side} drive has been excited for {:.1} ms",
                            (at - drive.excited_since.unwrap_or(at)) as f64 / 1000.0
                        ),
                    );
                }
            }
        }
        // Rule 5: what a reboot brought back, once this boot's first frame says
        // whether the store reported a fault.
        if faults & 0x10 != 0 {
            self.flash_fault_this_boot = true;
            self.registers.flash_unreliable();
        }
        if self.first_status_of_boot {
            self.first_status_of_boot = false;
            let excused = faults & 0x10 != 0 || self.flash_fault_before;
            for lost in self.registers.check_after_boot(excused) {
                self.violate(
                    Rule::StoreAndBoot,
                    at,
                    format!(
                        "after the reboot register {} reads {}, which no one wrote (expected one of {:?}), and no flash fault is reported",
                        lost.address, lost.read, lost.expected
                    ),
                );
            }
        } else if self.registers.awaiting_boot_check() {
            let excused = faults & 0x10 != 0 || self.flash_fault_before;
            for lost in self.registers.check_after_boot(excused) {
                self.violate(
                    Rule::StoreAndBoot,
                    at,
                    format!(
                        "after the reboot register {} reads {}, which no one wrote (expected one of {:?}), and no flash fault is reported",
                        lost.address, lost.read, lost.expected
                    ),
                );
            }
        }
        if status[0] & 0x80 == 0 {
            self.registers.persisted(built);
        }
        // Rule 6: every fault reported is one that happened.
        let before = self.last_status.map_or(0, |last| last[2]);
        let rising = faults & !before;
        let before_mode = self.last_status.map(|last| last[0] & 0x0F);
        let starting = matches!(mode, 0 | 5);
        if rising != 0 {
            self.check_reported_faults(at, rising, starting);
        }
        if mode == 6 && before_mode != Some(6) && !self.drive_fault_recent(at, None) {
            self.violate(
                Rule::FeedbackAndFaults,
                at,
                "the status frame reports mode Fault with no drive fault injected".to_owned(),
            );
        }
        let reason = status[4];
        if matches!(reason, 0x41 | 0x42)
            && self
                .last_status
                .is_none_or(|last| last[4] != reason || last[3] != status[3])
            && !self.drive_fault_recent(at, None)
        {
            self.violate(
                Rule::FeedbackAndFaults,
                at,
                format!("the status frame reports implausible feedback ({reason:#04x}) from drives whose feedback is true"),
            );
        }
        if self
            .last_status
            .is_none_or(|last| last[0] != status[0] || last[2] != status[2])
        {
            self.note(
                at,
                format!(
                    "status: mode {mode}, source {}, flags {flags:#04x}, faults {faults:#04x}, rejection {:#04x}/{:#04x}",
                    (status[0] >> 4) & 0x07,
                    status[4],
                    status[5]
                ),
            );
        }
        if matches!(mode, 1 | 2 | 6) {
            self.recovering = false;
        }
        self.last_status = Some(status);
        self.period(at, PeriodKind::Status);
    }

    fn check_reported_faults(&mut self, at: Us, rising: u8, starting: bool) {
        let names = [
            "left_drive_silent",
            "left_drive_alarm",
            "right_drive_silent",
            "right_drive_alarm",
            "flash",
            "scale",
            "can_bus",
            "watchdog_reset",
        ];
        for (bit, name) in names.iter().enumerate() {
            if rising & (1 << bit) == 0 {
                continue;
            }
            let happened = match bit {
                // A fault on either drive's line may show on both: the link probes each
                // drive alone, and a group frame that keeps failing reports both
                // silent; its deliberate silence trips 85h in both (docs/drives.md).
                0..=3 => starting || self.drive_fault_recent(at, None),
                4 => self.flash_fault_injected,
                5 => self.load_cell_missing_at.is_some(),
                6 => self.can_fault_at.is_some(),
                _ => self.boot_after_panic,
            };
            if !happened {
                self.violate(
                    Rule::FeedbackAndFaults,
                    at,
                    format!(
                        "the status frame reports {name} though nothing that causes it happened"
                    ),
                );
            }
        }
    }

    /// Whether a drive fault, a line fault, a reset or a long stall could explain a
    /// reported drive fault now (for `drive`, or either).
    fn drive_fault_recent(&self, at: Us, drive: Option<usize>) -> bool {
        // A status frame shows what happened since the frame before it, which may be
        // long ago: `status_time` 0 stops the frames, and a latched fault shows in the
        // first one after.
        let since_last_status = self.status.last.map_or(0, |last| at.saturating_sub(last));
        let window = bounds::FAULT_CAUSE_US + self.status_period_us().max(since_last_status);
        let recent = |when: Option<Us>| when.is_some_and(|when| when + window >= at);
        let drives: Vec<&Drive> = match drive {
            Some(index) => vec![&self.drives[index]],
            None => self.drives.iter().collect(),
        };
        let drive_side = drives.iter().any(|drive| {
            drive.faults > 0
                || drive.feedback_lie
                || recent(drive.fault_at)
                || recent(drive.feedback_at)
        });
        let stall = self
            .stalls
            .iter()
            .any(|&(start, end)| end - start >= 100_000 && end + window >= at);
        drive_side || recent(self.reset_at) || stall
    }

    fn status_period_us(&self) -> Us {
        u64::from(self.registers.max(address::STATUS_TIME)) * 1_000
    }

    /// Both wheels' forward motor revolutions now (for the next position frame).
    pub fn wheels(&mut self, revolutions: [f64; 2]) {
        self.wheel_revolutions = revolutions;
    }

    fn position_frame(&mut self, at: Us, data: &[u8]) {
        self.recovering = false;
        // Rule 6: every pose is fresh: wheels that turned half a motor revolution
        // (4.5 mm at the default radius and gear) since the last frame move it.
        let pose = pose_of(data);
        let wheels = self.wheel_revolutions;
        if let Some((previous_at, previous, previous_heading, previous_wheels)) = self.last_pose {
            let turned = (0..2)
                .map(|index| (wheels[index] - previous_wheels[index]).abs())
                .fold(0.0, f64::max);
            let geometry_default = [
                address::RAD_R,
                address::RAD_L,
                address::WHEEL_DIST,
                address::GEAR_RATIO,
                address::MOTOR_DIR,
            ]
            .into_iter()
            .all(|register| self.registers.surely_default(register));
            let clean = !self.drives.iter().any(|drive| {
                drive.unreachable_since(previous_at) || drive.feedback_lied_since(previous_at)
            });
            let gap = at - previous_at;
            if turned >= 0.5
                && geometry_default
                && clean
                && gap <= 200_000
                && self.stalled(previous_at, at) == 0
                && previous == pose
                && previous_heading == self.heading
            {
                self.violate(
                    Rule::FeedbackAndFaults,
                    at,
                    format!(
                        "the pose repeated ({:.1} ms after the last one) while a wheel turned {turned:.2} motor revolutions",
                        gap as f64 / 1000.0
                    ),
                );
            }
        }
        self.last_pose = Some((at, pose, self.heading, wheels));
        self.period(at, PeriodKind::Position);
    }

    fn update_reply(&mut self, at: Us, data: &[u8]) {
        let held_before = self.update.locked();
        match data {
            // DONE: begun, aborted, confirmed.
            [0x85, session, step, ..] => match step {
                1 => {
                    self.update.session = Some((*session, at));
                    self.update.session_uncertain = false;
                    self.update.last_heard = at;
                    self.lock_begins();
                    self.note(at, format!("update session {session} begun: motion locked"));
                }
                4 => {
                    if self
                        .update
                        .session
                        .is_some_and(|(running, _)| running == *session)
                    {
                        self.update.session = None;
                        self.note(at, format!("update session {session} aborted"));
                    }
                }
                5 if self.update.trial_since.take().is_some() => {
                    if !self.images.may_decide(*session) {
                        self.violate(
                            Rule::UpdateLock,
                            at,
                            format!(
                                "session {session}'s CONFIRM kept the image session {} activated",
                                self.images.activated_by.unwrap_or(0)
                            ),
                        );
                    }
                    if let Some(version) = self.images.activated.take() {
                        self.images.confirmed = version;
                    }
                    self.note(at, "image on trial confirmed".to_owned());
                }
                _ => {}
            },
            // REFUSED TimedOut: the session ended.
            [0xFF, _, 18, ..] => {
                if self.update.session.take().is_some() {
                    self.update.session_uncertain = false;
                    self.note(at, "update session timed out".to_owned());
                }
            }
            // Other refusals may end it (a bad image, a digest mismatch, a failed write).
            [0xFF, ..] => {
                if self.update.session.is_some() && !self.update.session_uncertain {
                    self.update.session_uncertain = true;
                }
            }
            // STATE: idle means no session; a session's phase beyond its bound is a
            // lock that outlived it.
            [0x81, phase, ..] => {
                if *phase == 0 && self.update.session.take().is_some() {
                    self.update.session_uncertain = false;
                }
                if (1..=3).contains(phase) && self.update.session.is_some() {
                    self.update.session_uncertain = false;
                }
                if (1..=3).contains(phase)
                    && self.update.session.is_some()
                    && at > self.update.last_heard + bounds::SESSION_SILENCE_US + 1_000_000
                {
                    self.violate(
                        Rule::UpdateLock,
                        at,
                        format!(
                            "the update session still runs (phase {phase}) {:.1} s after its PC's last frame",
                            (at - self.update.last_heard) as f64 / 1e6
                        ),
                    );
                }
            }
            _ => {}
        }
        if held_before && !self.update.locked() {
            self.lock_lifted();
        }
    }

    fn lock_begins(&mut self) {
        self.can.velocity = None;
        self.can.enable_at = None;
        for pad in &mut self.pads {
            pad.armed = false;
        }
    }

    /// The lock held and does no more. Only then: a reply that ends a session the
    /// oracle already took as ended (a refusal left it uncertain, then STATE says idle)
    /// lifts nothing, and must not take away an arming the pad earned since.
    fn lock_lifted(&mut self) {
        // A dead-man seen up when the lock lifts is armed; one held through it is not.
        for pad in &mut self.pads {
            pad.armed = pad.hands.is_some_and(|hands| !hands.dead_man);
        }
    }

    /// A pad's task handed the controller a link change or a report.
    pub fn pad_link(&mut self, at: Us, pad: PadKind, connected: bool) {
        self.advance_to(at);
        let index = pad.index();
        let in_control_before = self.pad_in_control();
        if connected {
            if self.pads[index].connected_at.is_none() {
                self.pads[index] = Pad {
                    connected_at: Some(at),
                    hands: None,
                    armed: false,
                };
            }
        } else {
            self.pads[index] = Pad::default();
        }
        let in_control = self.pad_in_control();
        if in_control != in_control_before
            && let Some(taker) = in_control
        {
            // A new pad in control is a new connection: its dead-man must be seen
            // released first, and the controller knows nothing of its hands yet.
            self.pads[taker].armed = false;
            self.pads[taker].hands = None;
        }
        self.note(
            at,
            format!(
                "{pad:?} pad {}",
                if connected { "connected" } else { "dropped" }
            ),
        );
        self.update_permission(at);
    }

    pub fn pad_report(&mut self, at: Us, pad: PadKind, hands: PadHands) {
        self.advance_to(at);
        let index = pad.index();
        if self.pads[index].connected_at.is_none() || !self.up() {
            return;
        }
        // The other pad's reports are dropped: the controller knows nothing of them.
        if self.pad_in_control() != Some(index) {
            return;
        }
        self.note_command_race(at);
        // L2 + Home switches the pad off: nothing else in that report counts, and the
        // pad is gone as on a link loss (docs/remote.md).
        let home_before = self.pads[index]
            .hands
            .is_some_and(|before| before.buttons & SWITCH_OFF != 0);
        if hands.l2 && hands.buttons & SWITCH_OFF != 0 && !home_before {
            self.pad_link(at, pad, false);
            return;
        }
        let in_control = true;
        let held_before = self.dead_man_held();
        self.pads[index].hands = Some(hands);
        if in_control && !hands.dead_man && !self.update.locked() {
            self.pads[index].armed = true;
        }
        if in_control && hands.dead_man && !held_before {
            // A held dead-man takes control from CAN: its velocity is dropped.
            self.can.velocity = None;
        }
        self.update_permission(at);
    }

    /// A command arriving at `at` may reach the firmware before it sampled the e-stop
    /// pressed just before.
    fn note_command_race(&mut self, at: Us) {
        if self
            .estop_pressed_at
            .is_some_and(|pressed| at < pressed + bounds::INPUT_SAMPLE_US)
        {
            self.command_raced_estop = true;
        }
    }

    /// The e-stop contact changed (or starts chattering, which counts as pressed).
    /// A release is dated at the contact's last pressed moment (a chatter's last
    /// pulse).
    pub fn estop(&mut self, at: Us, pressed: bool) {
        self.estop_until(at, pressed, at);
    }

    /// The e-stop contact rests released from `at`, its last pressed moment being
    /// `last_pressed` (a chatter's last pulse ended then).
    pub fn estop_until(&mut self, at: Us, pressed: bool, last_pressed: Us) {
        self.advance_to(at);
        if pressed {
            if !self.estop_pressed {
                self.note(at, "e-stop pressed".to_owned());
                self.estop_pressed_at = Some(at);
                self.command_raced_estop = false;
            }
            self.estop_pressed = true;
            self.estop_released_at = None;
            if self.up() {
                self.enter_emergency(at);
            }
        } else if self.estop_pressed {
            self.estop_pressed = false;
            // The firmware's last pressed sample may be up to one sample period earlier.
            self.estop_released_at = Some(last_pressed.min(at).saturating_sub(1_000));
            self.note(at, "e-stop released".to_owned());
        }
        self.update_permission(at);
    }

    fn enter_emergency(&mut self, at: Us) {
        if !self.emergency {
            self.emergency = true;
            self.emergency_since = at;
            let unreachable = self.unreachable(at);
            let stalls = self.stalled(at.saturating_sub(100_000), at);
            self.estop_stop = Some(Stop {
                rule: Rule::EmergencyStop,
                since: at,
                zero_by: at + bounds::ESTOP_ZERO_US + stalls,
                zero_checked: !unreachable,
                envelope: true,
                control_ended: at,
                brakes_by: at
                    + bounds::ESTOP_ZERO_US
                    + stalls
                    + if unreachable {
                        bounds::UNREACHABLE_US
                    } else {
                        0
                    },
                decel_rpm_per_s: f64::from(self.registers.min(address::ESTOP_DECEL)) * 0.97,
                fastest_rpm: self.fastest_rpm(),
            });
        }
        self.can.velocity = None;
        for pad in &mut self.pads {
            pad.armed = false;
        }
    }

    pub fn zone(&mut self, at: Us, occupied: bool) {
        self.zone_until(at, occupied, at);
    }

    /// The zone input rests clear from `at`, its last active moment being
    /// `last_active`.
    pub fn zone_until(&mut self, at: Us, occupied: bool, last_active: Us) {
        self.advance_to(at);
        if occupied {
            if !self.zone_active(at) {
                self.zone_since = Some(at);
            }
            self.zone_pressed = true;
            self.zone_released_at = None;
        } else if self.zone_pressed {
            self.zone_pressed = false;
            // The firmware's last active sample may be up to one sample period earlier.
            self.zone_released_at = Some(last_active.min(at).saturating_sub(1_000));
        }
    }

    /// The front button pressed or released. A brief press with the e-stop released
    /// confirms an emergency (and turns Bluetooth on after a panic loop).
    pub fn button(&mut self, at: Us, down: bool) {
        self.advance_to(at);
        if down {
            self.button_down_at = Some(at);
            return;
        }
        let Some(pressed) = self.button_down_at.take() else {
            return;
        };
        let start_pc_us = u64::from(self.registers.max(address::START_PC)) * 1_000;
        if at - pressed < start_pc_us {
            self.bluetooth_may_be_on = true;
            // The controller sees the release after its 20 ms debounce: the e-stop
            // must be released (debounced) by then.
            if self.emergency && !self.estop_active(at + BUTTON_DEBOUNCE_US) {
                self.emergency = false;
                self.estop_stop = None;
                self.recovering = true;
                self.note(at, "emergency confirmed".to_owned());
            }
        }
        self.update_permission(at);
    }

    /// A fault the world injected (or healed).
    pub fn injected(&mut self, at: Us, fault: Injected) {
        self.advance_to(at);
        match fault {
            Injected::DriveLine { slave, active } => {
                for (index, drive) in self.drives.iter_mut().enumerate() {
                    if slave == 0 || usize::from(slave) == index + 1 {
                        drive.fault_at = Some(at);
                        if active {
                            drive.faults += 1;
                        } else {
                            drive.faults = drive.faults.saturating_sub(1);
                        }
                    }
                }
            }
            Injected::Feedback { slave, active } => {
                let index = usize::from(slave.saturating_sub(1)).min(1);
                self.drives[index].feedback_lie = active;
                self.drives[index].feedback_at = Some(at);
            }
            Injected::ReversedMotion { slave, active } => {
                let index = usize::from(slave.saturating_sub(1)).min(1);
                self.drives[index].feedback_lie = active;
                self.drives[index].feedback_at = Some(at);
                // The command did not change, only the direction the shaft takes it in:
                // the order (already turned round, the drives log it first) and the
                // commanded ramp are in the shaft's direction, so the ramp turns round too.
                if self.drives[index].reversed_motion != active {
                    let ramp = self.drives[index].ramp_rpm_at(at);
                    self.drives[index].ramp_rpm = -ramp;
                    self.drives[index].ramp_at = at;
                }
                self.drives[index].reversed_motion = active;
                self.drives[index].against_since = None;
            }
            Injected::Flash => self.flash_fault_injected = true,
            Injected::LoadCell { missing } => {
                if missing {
                    self.load_cell_missing_at = Some(at);
                }
            }
            Injected::CanBus => self.can_fault_at = Some(at),
        }
        self.update_permission(at);
    }

    /// The whole chip stood still from `start` to `end` (a flash erase or program).
    pub fn stall(&mut self, start: Us, end: Us) {
        if end > start {
            self.stalls.push_back((start, end));
        }
    }

    /// The firmware wrote or erased flash at `at` (boot-time writes not included).
    pub fn flash_written(&mut self, at: Us, what: &str) {
        self.advance_to(at);
        for (index, drive) in self.drives.into_iter().enumerate() {
            if drive.order.excited() {
                let side = if index == 0 { "left" } else { "right" };
                self.violate(
                    Rule::BrakesAndFlash,
                    at,
                    format!("{what} while the {side} drive is excited"),
                );
            }
        }
    }

    /// The controller stopped (reset, power cut, panic): nothing it knew survives.
    pub fn controller_down(&mut self, at: Us, panic: bool) {
        self.advance_to(at);
        // A stop whose zero the controller had not sent yet when it went down: the
        // drives run on their last order until their own communication timeout stops
        // them, as for drives it cannot reach (seeds 227 and 356: the enable lapsed
        // 2 ms before a reset).
        if let Some(stop) = &mut self.stop
            && at < stop.brakes_by
        {
            stop.zero_checked = false;
            stop.brakes_by = stop.brakes_by.max(at + bounds::UNREACHABLE_US);
        }
        self.controller = Controller::Down { since: at };
        self.reset_at = Some(at);
        self.boot_after_panic = panic;
        self.can = CanSource::default();
        self.pads = [Pad::default(); 2];
        self.update.session = None;
        self.update.trial_since = None;
        self.emergency = false;
        self.estop_stop = None;
        self.flash_fault_before = self.flash_fault_this_boot;
        self.flash_fault_this_boot = false;
        self.registers.rebooted();
        self.reads.clear();
        self.position = Period::default();
        self.status = Period::default();
        self.last_status = None;
        self.last_pose = None;
        self.first_status_of_boot = true;
        self.note(
            at,
            format!("controller down{}", if panic { " (panic)" } else { "" }),
        );
        self.update_permission(at);
    }

    /// The reset that just happened cleared the chip's RTC RAM (a power cut, the reset
    /// button), and with it the record of who activated an image.
    pub fn rtc_cleared(&mut self, at: Us) {
        self.advance_to(at);
        self.images.forget_activator();
    }

    /// The bootloader chose an image (`None`: nothing loads).
    pub fn booted(&mut self, at: Us, version: Option<&str>) {
        self.advance_to(at);
        let Some(version) = version else {
            self.violate(
                Rule::StoreAndBoot,
                at,
                "no slot holds an image the bootloader loads: the controller stays dark".to_owned(),
            );
            return;
        };
        self.note(at, format!("boot: firmware {version}"));
        if super::programs::untrusted(version) {
            self.violate(
                Rule::StoreAndBoot,
                at,
                format!("the bootloader started firmware {version}, which no key the controller trusts signed"),
            );
            return;
        }
        let activated = self.images.activated.clone();
        let on_trial = activated.as_deref() == Some(version)
            && self.images.boots_since_activation == 0
            && version != self.images.confirmed;
        if activated.is_some() {
            self.images.boots_since_activation += 1;
        }
        if on_trial {
            self.update.trial_since = Some(at);
            return;
        }
        let confirmed_maybe = self.images.confirm_sent && activated.as_deref() == Some(version);
        if version == self.images.confirmed || confirmed_maybe {
            if confirmed_maybe {
                self.images.confirmed = version.to_owned();
            }
            self.images.activated = None;
            self.images.confirm_sent = false;
            return;
        }
        self.violate(
            Rule::StoreAndBoot,
            at,
            format!(
                "the bootloader started firmware {version}; only the confirmed {} or, once, the activated {} may boot",
                self.images.confirmed,
                activated.as_deref().unwrap_or("(none)")
            ),
        );
    }

    /// The firmware's tasks run from `at`. `bluetooth_on`: the boot's panic-loop
    /// decision; `estop`: the contact is pressed now; `drives`: the settings its
    /// firmware was built with.
    pub fn controller_up(
        &mut self,
        at: Us,
        bluetooth_on: bool,
        estop: bool,
        drives: &DriveSettings,
    ) {
        self.advance_to(at);
        self.controller = Controller::Up { since: at };
        self.refused_settings = refused(drives);
        self.bluetooth_surely_on = bluetooth_on;
        self.bluetooth_may_be_on = bluetooth_on;
        if estop {
            // The reset's run-on is the stop that the controller going down started.
            self.enter_emergency(at);
            self.estop_stop = None;
        }
        self.update_permission(at);
    }

    /// The firmware panicked where no fault injected a panic.
    pub fn panicked(&mut self, at: Us, message: &str) {
        self.violate(
            Rule::FeedbackAndFaults,
            at,
            format!("the controller panicked: {message}"),
        );
    }

    /// The watchdog bit: a task stopped checking in.
    pub fn watchdog_bit(&mut self, at: Us) {
        self.violate(
            Rule::FeedbackAndFaults,
            at,
            "the watchdog bit: a critical task stopped checking in for 2 s".to_owned(),
        );
    }

    /// Every control cycle: the shafts' speeds now (r/min, each drive's own
    /// direction), and the checks that run on time rather than on events.
    pub fn tick(&mut self, at: Us, speeds_rpm: [f64; 2]) {
        self.advance_to(at);
        for (drive, speed) in self.drives.iter_mut().zip(speeds_rpm) {
            drive.speed_rpm = speed;
        }
        if std::env::var_os("CHAOS_DEBUG").is_some() {
            eprintln!(
                "tick {:.3} speeds {:?} orders {:?}",
                at as f64 / 1e6,
                speeds_rpm,
                self.drives
                    .iter()
                    .map(|d| (
                        d.order.target_rpm,
                        d.order.decel_rpm_per_s,
                        d.order.excited()
                    ))
                    .collect::<Vec<_>>()
            );
        }
        if let Some(stop) = self.stop {
            self.check_stop(at, stop, false);
        }
        if let Some(stop) = self.estop_stop {
            self.check_stop(at, stop, true);
        }
        self.check_periods(at);
        self.check_update_bounds(at);
        self.check_against(at);
    }

    /// Rule 6: a drive turning against its command is found (`WrongDirection`) and
    /// stopped: its wheel may not keep turning against a command of one sign for
    /// [`bounds::AGAINST_FOUND_US`] (two 100 ms windows, the cycle that acts on them,
    /// and as much again for slack).
    fn check_against(&mut self, at: Us) {
        let settled = self.up_since().is_some_and(|since| at >= since + 2_000_000);
        for index in 0..2 {
            let drive = &mut self.drives[index];
            // The order is the shaft's: a reversed drive's shaft turns as ordered,
            // against its command.
            let sign = drive.order.target_rpm.signum();
            let against = settled
                && drive.reversed_motion
                && drive.faults == 0
                && drive.order.excited()
                && drive.order.target_rpm.abs() >= bounds::AGAINST_RPM
                && drive.speed_rpm.abs() >= bounds::AGAINST_RPM
                && drive.speed_rpm.signum() == sign;
            drive.against_since = match drive.against_since {
                Some((since, was)) if against && was == sign => Some((since, was)),
                _ if against => Some((at, sign)),
                _ => None,
            };
            let Some((since, _)) = drive.against_since else {
                continue;
            };
            if at > since.max(drive.against_from) + bounds::AGAINST_FOUND_US {
                let side = if index == 0 { "left" } else { "right" };
                let speed = drive.speed_rpm;
                self.violate(
                    Rule::FeedbackAndFaults,
                    at,
                    format!(
                        "the {side} drive has turned against its command ({speed:+.0} r/min) for {:.0} ms, not found (WrongDirection) nor stopped",
                        (at - since) as f64 / 1000.0
                    ),
                );
            }
        }
    }

    /// At a stop's deadline: zero on the wire for every drive the controller can reach.
    fn check_zero(&mut self, at: Us) {
        for estop in [false, true] {
            let slot = if estop { self.estop_stop } else { self.stop };
            let Some(mut stop) = slot.filter(|stop| stop.zero_checked && at > stop.zero_by) else {
                continue;
            };
            // A command write already on the half-duplex line when the e-stop came is
            // finished first: the zero then follows it by the broadcast's time
            // (docs/figures.md: "a command may also wait for the previous command's
            // write").
            if estop {
                let write_done = self
                    .drives
                    .iter()
                    .map(|drive| drive.order_at)
                    .filter(|&done| {
                        done > stop.since && done <= stop.since + bounds::COMMAND_WRITE_US
                    })
                    .max();
                if let Some(done) = write_done
                    && stop.zero_by < done + bounds::ZERO_AFTER_WRITE_US
                {
                    stop.zero_by = done + bounds::ZERO_AFTER_WRITE_US;
                    self.estop_stop = Some(stop);
                    continue;
                }
            }
            stop.zero_checked = false;
            if self.up_since().is_some_and(|since| since <= stop.since) {
                for index in 0..2 {
                    if self.drives[index].moving_order()
                        && !self.drives[index].unreachable_since(stop.since)
                    {
                        let side = if index == 0 { "left" } else { "right" };
                        let after = if estop {
                            "the e-stop"
                        } else {
                            "the last source's non-zero command ended"
                        };
                        self.violate(
                            stop.rule,
                            at,
                            format!(
                                "the {side} drive still runs towards {:+.0} r/min {:.1} ms after {after} (zero due within {:.1} ms)",
                                self.drives[index].order.target_rpm,
                                (at - stop.since) as f64 / 1000.0,
                                (stop.zero_by - stop.since) as f64 / 1000.0
                            ),
                        );
                    }
                }
            }
            if estop {
                self.estop_stop = Some(stop);
            } else {
                self.stop = Some(stop);
            }
        }
    }

    fn check_stop(&mut self, at: Us, mut stop: Stop, estop: bool) {
        let mut done = !stop.zero_checked;
        if stop.envelope {
            if at <= stop.brakes_by {
                stop.fastest_rpm = stop.fastest_rpm.max(self.fastest_rpm());
                done = false;
            } else {
                // Both wheels within the envelope of the gentlest allowed stop.
                let braking_s = (at - stop.brakes_by) as f64 / 1e6;
                let allowed = stop.fastest_rpm - stop.decel_rpm_per_s * braking_s;
                let fastest = self.fastest_rpm();
                // The slower wheel brakes with its share of the change the controller
                // measured half a cycle ago: near standstill it may creep a little
                // longer.
                let stands_by_s = stop.fastest_rpm / stop.decel_rpm_per_s;
                let creep = if braking_s < stands_by_s + 0.3 {
                    bounds::CREEP_RPM
                } else {
                    0.0
                };
                if fastest > allowed.max(0.0) + bounds::AT_REST_RPM + creep {
                    let after = if estop {
                        "the e-stop"
                    } else {
                        "the last source's control ended"
                    };
                    self.violate(
                        stop.rule,
                        at,
                        format!(
                            "a wheel turns at {fastest:.0} r/min (left {:+.0}, right {:+.0}) {:.0} ms after {after}: from {:.0} r/min a stop at {:.0} (1/min)/s stands by {:.0} ms",
                            self.drives[0].speed_rpm,
                            self.drives[1].speed_rpm,
                            (at - stop.control_ended) as f64 / 1000.0,
                            stop.fastest_rpm,
                            stop.decel_rpm_per_s,
                            (stop.brakes_by - stop.control_ended) as f64 / 1000.0
                                + stop.fastest_rpm / stop.decel_rpm_per_s * 1000.0
                        ),
                    );
                }
                done &= allowed <= 0.0 && fastest <= bounds::AT_REST_RPM && creep == 0.0;
            }
        } else {
            // Still in control (asking for zero): kept for when control ends.
            done = false;
        }
        let keep = (!done).then_some(stop);
        if estop {
            self.estop_stop = keep;
        } else {
            self.stop = keep;
        }
    }

    fn check_update_bounds(&mut self, at: Us) {
        if let Some(since) = self.update.trial_since
            && at > since + bounds::TRIAL_US + 5_000_000
        {
            self.violate(
                Rule::UpdateLock,
                at,
                format!(
                    "the image on trial still runs locked {:.1} s after its boot without CONFIRM (the trial ends after 120 s)",
                    (at - since) as f64 / 1e6
                ),
            );
        }
    }

    // -----------------------------------------------------------------------------
    // Periodic frames (rule 6)
    // -----------------------------------------------------------------------------

    fn feedback_due(&self, at: Us) -> bool {
        let settled = self.up_since().is_some_and(|since| at >= since + 3_000_000);
        let mode_ok = self
            .last_status
            .is_some_and(|status| matches!(status[0] & 0x0F, 1 | 2 | 6));
        let bus_fault = self
            .can_fault_at
            .is_some_and(|fault| at < fault + 2_000_000);
        settled
            && mode_ok
            && !bus_fault
            && !self.emergency
            && !self.recovering
            && !self.estop_active(at)
            && self
                .estop_released_at
                .is_none_or(|released| at > released + 2_000_000)
    }

    fn status_due(&self, at: Us) -> bool {
        let bus_fault = self
            .can_fault_at
            .is_some_and(|fault| at < fault + 2_000_000);
        self.up_since().is_some_and(|since| at >= since + 3_000_000)
            && self.registers.min(address::STATUS_TIME) != 0
            && !bus_fault
    }

    fn period(&mut self, at: Us, kind: PeriodKind) {
        let due = match kind {
            PeriodKind::Position => self.feedback_due(at),
            PeriodKind::Status => self.status_due(at),
        };
        let period = match kind {
            PeriodKind::Position => &mut self.position,
            PeriodKind::Status => &mut self.status,
        };
        period.last = Some(at);
        period.longest_us = 0;
        if !due {
            period.due_since = None;
        } else if period.due_since.is_none() {
            period.due_since = Some(at);
        }
    }

    fn check_periods(&mut self, at: Us) {
        for kind in [PeriodKind::Position, PeriodKind::Status] {
            let (due, nominal_us, name) = match kind {
                PeriodKind::Position => (
                    self.feedback_due(at),
                    u64::from(self.registers.max(address::LOOP_END_DELAY)) * 1_000,
                    "position frame (0x0EC)",
                ),
                PeriodKind::Status => (
                    self.status_due(at),
                    self.status_period_us(),
                    "status frame (0x0EE)",
                ),
            };
            let period = match kind {
                PeriodKind::Position => &mut self.position,
                PeriodKind::Status => &mut self.status,
            };
            if !due {
                period.due_since = None;
                continue;
            }
            period.longest_us = period.longest_us.max(nominal_us);
            let nominal_us = period.longest_us;
            let due_since = *period.due_since.get_or_insert(at);
            let last = period.last.unwrap_or(0).max(due_since);
            let allowed = nominal_us + bounds::PERIOD_SLACK_US + self.stalled(last, at);
            if at > last + allowed {
                let gap = at - last;
                self.violate(
                    Rule::FeedbackAndFaults,
                    at,
                    format!(
                        "no {name} for {:.1} ms (its period is {:.0} ms)",
                        gap as f64 / 1000.0,
                        nominal_us as f64 / 1000.0
                    ),
                );
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PeriodKind {
    Position,
    Status,
}

/// Why the firmware must refuse these drive settings, if it must: the limits of
/// docs/drives.md ("Settings the firmware refuses"), written here from the document.
fn refused(drives: &DriveSettings) -> Option<&'static str> {
    if !(100..=180).contains(&drives.drive_comm_timeout_ms) {
        Some("the drives' own timeout must be 100 to 180 ms (0 is off)")
    } else if !(1..=3).contains(&drives.failures_before_loss) {
        Some("1 to 3 failures before a drive counts as lost")
    } else if !(10..=30).contains(&drives.reply_timeout_ms) {
        Some("a reply timeout of 10 to 30 ms")
    } else if drives.line.baud < 38_400 {
        Some("at least 38400 baud")
    } else if drives.line.min_silent_interval_us > 1_750 {
        Some("a frame gap of at most 1750 µs")
    } else {
        None
    }
}
