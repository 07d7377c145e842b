//! The drive link as a state machine: which Modbus request goes to the drives next,
//! what each reply means, and when the drives count as lost. It never touches the
//! line: the runtime's drive link task sends each [`Request`], feeds the reply (or why
//! none came) back as an [`Event`], waits as long as [`Next::WaitUntil`] says, and
//! passes the [`Effects::reports`] on to the controller.
//!
//! ```text
//!             boot, a setup request, a failed setup
//!                           │
//!                           ▼
//!   ┌──────────────▶ Holding(ForSetup) ◀─── poll_interval or a demand ───┐
//!   │                  │           │                                     │
//!   │   round done, the power-up   └── otherwise ──▶ HoldPause(ForSetup) ─┘
//!   │   wait passed, both answered                          ▲
//!   │                  ▼                                    │ failed
//!   │     SettingUp(left, then right) ──────────────────────┤
//!   │                  │ done                               │ failed
//!   │                  ▼                                    │
//!   │            CheckingGroup ─────────────────────────────┘
//!   │                  │ the group answers: DrivesReady
//!   │                  ▼
//!   │   ┌───────▶ CycleWait ── S-ON or S-OFF due ──▶ Exciting(left, right)
//!   │   │   ▲  │  │                                     │ done, or failed
//!   │   │   │  │  ├── an emergency zero ──▶ BroadcastingZero (one 10h to address 0)
//!   │   │   │  │  │                                       │ sent
//!   │   │   │  │  └── a command the drives do not have ──▶ Writing (one 10h)
//!   │   │   │  │                                          │ done, or failed
//!   │   │   │  └── the read's moment came ──▶ Reading(Motion), then Reading(Alarms)
//!   │   │   │                                     │ answered, or failed
//!   │   └───┴─────────────────────────────────────┘ (fewer than N failed in a row)
//!   │
//!   ├── a setup request, in CycleWait
//!   │
//!   │   N failed reads, or N failed writes (S-ON and S-OFF included), in a row:
//!   │   StoppingBlind(zero ×3, silent) ──▶ Probing(left, right)
//!   │                                             ──▶ Holding(UntilSetupRequested)
//!   │                                                         │        ▲
//!   │                                                         ▼        │ poll_interval
//!   └──────────── a setup request ◀─────────────── HoldPause(UntilSetupRequested)
//! ```
//!
//! Rules that hold in every state:
//! - Outside the cycle the link *holds*: every drive that answers gets, by unicast,
//!   zero speed with `stop_decel` (with the DDO operation type, so the trigger cannot
//!   start anything else), the trigger, and S-OFF unless the controller still wants it
//!   excited (braking to a stop after a fault: its brakes close once the base stands).
//!   A drive that does not answer is skipped; one that answers garbled is counted
//!   ([`Input::ModbusError`]) and held again next round.
//! - The first request after boot is such a hold: a controller that restarts while the
//!   base drives stops the wheels at once, before and during the drives' power-up wait,
//!   whichever drive answers.
//! - Only `Writing` sends a non-zero speed, and only while excited and after
//!   `excite_settle_ms` has passed since S-ON.
//! - The cycle splits the line's work: the feedback read goes out once per
//!   `loop_end_delay` on a fixed schedule that commands never move, in two short FC
//!   03h to the group (both positions and speeds, then both alarms), and a command
//!   (FC 10h to the group: both wheels' speed, rates and trigger) goes out at the next
//!   free moment whenever the controller wants something the drives do not have yet.
//!   A newer demand replaces one that was not sent; one that was acknowledged is not
//!   sent again. No transaction is long, so nothing urgent waits long behind one.
//! - An emergency zero (zero for both wheels braked at least with `estop_decel`)
//!   goes out first, by one 29-byte broadcast that needs no reply (speed 0, the
//!   stronger wheel's rate, the trigger); the acknowledged group write follows.
//! - N = `failures_before_loss` failed reads, or failed writes, in a row (the group
//!   silent, a member silent or reset, or the group frames alone failing while each
//!   drive answers unicast) end the cycle (a failed write is tried again after the
//!   next read, so it never starves the feedback). Nothing a drive says can be
//!   trusted then, so the stop needs no reply: zero by broadcast, then silence until
//!   every drive's communication timeout has surely tripped. Then each drive is probed and the lost ones are reported ([`Input::DriveSilent`]; both when both
//!   answer alone, because the commands cannot reach the wheels).
//! - In the cycle the link steps at least every third of the drives' communication
//!   timeout. A longer gap means the chip stalled (a flash erase, which waits for both
//!   brakes confirmed): if both drives were confirmed de-excited, an alarm 85h in the
//!   first alarm read sent after it is the link's own doing and is reset (0x0180: 1,
//!   then 0) and counted as a Modbus error instead of reported. Any other alarm, or an
//!   85h that stays, is reported.
//! - [`Input::DrivesReady`] comes only after boot or a setup request (the controller's
//!   contract): drives that come back unasked stay held until the controller asks.
//! - A request is answered before anything else moves the machine: a demand that
//!   comes while a request is out is kept and acts from the next request on.

use heapless::Vec;

use super::{DriveSettings, reg};
use crate::controller::Input;
use crate::kinematics::{MotorRpm, WheelCommand};
use crate::modbus::{self, Frame, ReplyError, Target, TransferError};
use crate::odometry::EncoderCounts;
use crate::registers::{Reg, Registers};
use crate::supervisor::Wheel;
use crate::time::Timestamp;

/// What the controller wants from the drives right now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveDemand {
    /// Motor speeds and accelerations for both wheels.
    pub wheels: WheelCommand,
    /// Drives excited (S-ON, brakes released).
    pub excite: bool,
    /// How many times the controller asked for a fresh setup; the link sets the drives
    /// up again whenever this grows past what it served.
    pub setup_requests: u32,
    /// The control cycle (`loop_end_delay`), ms.
    pub cycle_ms: u16,
    /// `estop_decel`, (r/min)/s: how a held drive brakes to zero.
    pub stop_decel: u32,
    /// When the controller sends its next position frame: the link times its feedback
    /// read half a cycle before each one, so that every frame carries exactly one
    /// fresh read whatever the commands in between do. `None`: any phase.
    pub feedback_due_at: Option<Timestamp>,
}

impl DriveDemand {
    pub const fn at_rest(cycle_ms: u16, stop_decel: u32) -> Self {
        Self {
            wheels: WheelCommand {
                rpm: MotorRpm::ZERO,
                left_accel: 0,
                right_accel: 0,
            },
            excite: false,
            setup_requests: 0,
            cycle_ms,
            stop_decel,
            feedback_due_at: None,
        }
    }
}

/// Everything the drive link reacts to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event<'a> {
    /// The controller's new demand.
    Demand(DriveDemand),
    /// The reply to the request of the last [`Next::Send`]: its bytes, or why none came.
    Reply(Result<&'a [u8], TransferError>),
    /// The moment of the last [`Next::WaitUntil`] came.
    Timer,
}

/// One Modbus request and how to read its reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Request {
    pub frame: Frame,
    /// The length of a complete normal reply, so the master knows when it is done.
    pub expected_len: usize,
}

impl Request {
    fn new(frame: Frame, target: Target) -> Self {
        // 0: a broadcast, which draws no reply (the master then waits for nothing).
        let expected_len = modbus::expected_reply_len(&frame, target).unwrap_or(0);
        Self {
            frame,
            expected_len,
        }
    }
}

/// What the runtime does next.
// No heap in the firmware to box the frame in; one `Next` lives in the task at a time.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Next {
    /// Send this request, then step its [`Event::Reply`].
    Send(Request),
    /// Wait until this moment ([`Event::Timer`]) or a new demand ([`Event::Demand`]).
    WaitUntil(Timestamp),
}

/// What a step asks for. The most a step reports is a feedback and two alarms.
pub type Reports = Vec<Input, 4>;

/// What must happen now.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Effects {
    /// `None`: carry on with the request that is out, or the wait.
    pub next: Option<Next>,
    /// For the controller, in this order.
    pub reports: Reports,
}

/// Why the link holds the drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Hold {
    /// Boot, a setup request or a failed setup: the drives are set up once the
    /// power-up wait has passed and both answer (and never with settings the
    /// firmware refuses).
    ForSetup,
    /// After a loss, until the controller asks for a setup.
    UntilSetupRequested,
}

/// The three writes that hold one drive, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HoldWrite {
    /// Operation type, position, zero speed, `stop_decel` twice.
    ZeroSpeed,
    Trigger,
    ServoOff,
}

/// The blind stop, in order. Broadcasts (address 0) reach every drive that hears
/// the line and draw no reply, so they act even when no reply gets back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BlindStep {
    /// Zero speed with `stop_decel` and the trigger, in one broadcast; the n-th of
    /// [`BLIND_REPEATS`].
    Zero(u8),
    /// Nothing on the line, so that every drive's communication timeout trips
    /// (alarm 85h: de-excited, brake applied) whatever it made of the frames above.
    Silent,
}

/// How often each blind broadcast goes out: a frame lost to noise is not the end.
pub const BLIND_REPEATS: u8 = 3;
/// Silence beyond the drives' communication timeout before the link talks again.
pub const SILENCE_MARGIN_MS: u64 = 100;

/// The setup of one drive, in order (docs/drives.md, What happens on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SetupStep {
    ShareControl,
    ShareLists,
    CommTimeout,
    ReadAlarm,
    /// The reset acts on the 0 → 1 change.
    AlarmResetOn,
    AlarmResetOff,
    ReadAlarmAfterReset,
    ServoOff,
}

/// One pass over both drives while holding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HoldRound {
    pub wheel: Wheel,
    pub write: HoldWrite,
    /// Which drives answered so far in this round.
    pub answering: [bool; 2],
    /// Rounds in a row each drive stayed silent after the power-up wait (`ForSetup`).
    pub silent_rounds: [u8; 2],
}

/// What the running cycle keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cycle {
    /// When the next feedback read is due. It advances by whole periods from the read
    /// before, whatever the commands in between do.
    pub read_at: Timestamp,
    /// Failed motion reads (positions and speeds) in a row.
    pub read_failures: u8,
    /// Failed alarm reads in a row.
    pub alarm_read_failures: u8,
    /// The motion read passed and the alarm read, the rest of this period's feedback,
    /// goes next.
    pub alarms_due: bool,
    /// The zero of an emergency stop went out by broadcast; the acknowledged group
    /// write follows. Cleared by the next non-zero command the drives acknowledge.
    pub zero_broadcast: bool,
    /// Per wheel: alarm 85h that the controller's own silence at rest caused (a flash
    /// erase stalls the chip longer than the drives' timeout) is reset before anything
    /// else goes to that drive.
    pub timeout_alarm_resets: [bool; 2],
    /// Failed writes (command, S-ON or S-OFF) in a row.
    pub write_failures: u8,
    /// A write went out while the read was due: the read goes next, so commands at
    /// any rate delay it by one write at most.
    pub read_deferred: bool,
    /// A write that failed is tried again only from this moment on, so a failing
    /// write never starves the feedback read.
    pub write_retry_at: Timestamp,
    /// No speed but zero before this moment: the drives settle after S-ON.
    pub settled_at: Timestamp,
    /// The command both drives acknowledged last; `None` before the first.
    pub written: Option<WheelCommand>,
    /// The last alarm code per wheel, so each alarm is reported once.
    pub alarms: [u32; 2],
}

impl Cycle {
    fn start(now: Timestamp) -> Self {
        Self {
            read_at: now,
            read_failures: 0,
            alarm_read_failures: 0,
            alarms_due: false,
            zero_broadcast: false,
            timeout_alarm_resets: [false; 2],
            write_failures: 0,
            read_deferred: false,
            write_retry_at: now,
            settled_at: now,
            written: None,
            alarms: [0; 2],
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum State {
    /// One hold write is out.
    Holding { hold: Hold, round: HoldRound },
    /// Between two hold rounds.
    HoldPause {
        hold: Hold,
        wake_at: Timestamp,
        silent_rounds: [u8; 2],
    },
    /// One setup write or read is out.
    SettingUp { wheel: Wheel, step: SetupStep },
    /// Both drives are set up; one share read must pass before the cycle starts.
    CheckingGroup,
    /// The S-ON (or S-OFF) write of one drive is out, before the cycle's exchange.
    Exciting {
        wheel: Wheel,
        excite: bool,
        cycle: Cycle,
    },
    /// The command write (FC 10h to the group) is out.
    Writing { cycle: Cycle, command: WheelCommand },
    /// One part of the feedback read (FC 03h to the group) is out.
    Reading { cycle: Cycle, part: ReadPart },
    /// The zero of an emergency stop is out by broadcast (no reply comes).
    BroadcastingZero { cycle: Cycle },
    /// One write of the reset of an alarm 85h that the controller's own silence at
    /// rest caused: 1 (`on`), then 0.
    ResettingTimeoutAlarm {
        wheel: Wheel,
        on: bool,
        cycle: Cycle,
    },
    /// Until the next read is due, or a new demand comes.
    CycleWait { wake_at: Timestamp, cycle: Cycle },
    /// N failed reads or writes: the drives are stopped without needing a reply, then
    /// the line stays silent until their communication timeout has surely tripped.
    StoppingBlind { step: BlindStep },
    /// After the blind stop: the share control block of one drive is being read.
    Probing { wheel: Wheel, lost: bool },
}

/// The feedback read of one period, in two short parts, so that an urgent write never
/// waits behind a long one: positions and speeds (on the read's schedule), then the
/// alarms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReadPart {
    Motion,
    Alarms,
}

impl ReadPart {
    /// The part's first item in the share read list, and how many it reads.
    fn items(self) -> (u16, usize) {
        match self {
            ReadPart::Motion => (0, 2),
            ReadPart::Alarms => (2, 1),
        }
    }
}

/// The drive link (see the module documentation).
#[derive(Debug, Clone)]
pub struct DriveLink {
    state: State,
    demand: DriveDemand,
    /// Setup requests served so far.
    served_setups: u32,
    /// What the drives were last told about S-ON, and acknowledged.
    excited: bool,
    /// Nothing is set up before the drives had this long to power up.
    powered_up_at: Timestamp,
    /// Per wheel: the drive is known de-excited, its brake holding. Only an answered
    /// S-OFF, or the silence after a blind stop that its own communication timeout
    /// cannot have survived, says so; an S-ON (answered or not) unsays it.
    brakes_confirmed: [bool; 2],
    /// When the link last stepped. In the cycle it steps at least every third of the
    /// drives' timeout; a longer gap means the chip stalled (a flash erase).
    last_step_at: Timestamp,
    /// The link was stalled beyond the drives' timeout while both were confirmed
    /// de-excited: an alarm 85h in the next alarm read sent after it is its own doing.
    stalled_at_rest: bool,
    /// The alarm read that is out was sent after such a stall.
    alarm_read_after_stall: bool,
}

impl DriveLink {
    /// The link at boot, and its first request: the hold of the left drive. Settings
    /// the firmware refuses ([`DriveSettings::check`]) keep it holding: the drives stay
    /// stopped and de-excited, and are never set up.
    pub fn boot(now: Timestamp, settings: &DriveSettings) -> (Self, Effects) {
        if let Err(refused) = settings.check() {
            error!(
                "drive settings refused, the drives stay held: {}",
                refused.reason()
            );
        }
        let defaults = Registers::defaults();
        let mut link = Self {
            state: State::CheckingGroup,
            // Until the controller's first demand, which comes at once.
            demand: DriveDemand::at_rest(
                defaults.get(Reg::LoopEndDelay),
                u32::from(defaults.get(Reg::EstopDecel)),
            ),
            served_setups: 0,
            excited: false,
            powered_up_at: now.plus_millis(u64::from(settings.power_up_wait_ms)),
            // A controller that restarts cannot know what the drives do.
            brakes_confirmed: [false; 2],
            last_step_at: now,
            stalled_at_rest: false,
            alarm_read_after_stall: false,
        };
        let mut effects = Effects::default();
        link.begin_hold(Hold::ForSetup, [0; 2], settings, &mut effects);
        (link, effects)
    }

    pub fn state(&self) -> State {
        self.state
    }

    /// Whether the drives were last told S-ON (and acknowledged it).
    pub fn excited(&self) -> bool {
        self.excited
    }

    /// Both drives confirmed de-excited (brakes holding): see `brakes_confirmed`. The
    /// status frame's `brakes_applied` and the flash wait for this.
    pub fn brakes_confirmed(&self) -> bool {
        self.brakes_confirmed == [true, true]
    }

    pub fn step(&mut self, now: Timestamp, event: Event<'_>, settings: &DriveSettings) -> Effects {
        let mut effects = Effects::default();
        let timeout_ms = comm_timeout_ms(settings);
        let in_cycle = matches!(
            self.state,
            State::CycleWait { .. }
                | State::Reading { .. }
                | State::Writing { .. }
                | State::Exciting { .. }
                | State::BroadcastingZero { .. }
                | State::ResettingTimeoutAlarm { .. }
        );
        if in_cycle && now.millis_since(self.last_step_at) >= timeout_ms && self.brakes_confirmed()
        {
            warn!("drive link stalled beyond the drives' timeout at rest");
            self.stalled_at_rest = true;
        }
        self.last_step_at = now;
        match (self.state, event) {
            (_, Event::Demand(demand)) => {
                self.demand = demand;
                match self.state {
                    State::HoldPause {
                        hold,
                        silent_rounds,
                        ..
                    } => self.begin_hold(hold, silent_rounds, settings, &mut effects),
                    // A new command goes out at once; the read keeps its schedule.
                    State::CycleWait { cycle, .. } => {
                        self.next_in_cycle(now, cycle, settings, &mut effects)
                    }
                    State::Holding { .. }
                    | State::SettingUp { .. }
                    | State::CheckingGroup
                    | State::Exciting { .. }
                    | State::Writing { .. }
                    | State::Reading { .. }
                    | State::BroadcastingZero { .. }
                    | State::ResettingTimeoutAlarm { .. }
                    | State::StoppingBlind { .. }
                    | State::Probing { .. } => {}
                }
            }
            (
                State::HoldPause {
                    hold,
                    silent_rounds,
                    ..
                },
                Event::Timer,
            ) => self.begin_hold(hold, silent_rounds, settings, &mut effects),
            (State::CycleWait { cycle, .. }, Event::Timer) => {
                self.next_in_cycle(now, cycle, settings, &mut effects)
            }
            (State::Holding { hold, round }, Event::Reply(reply)) => {
                self.on_hold_reply(now, hold, round, reply, settings, &mut effects)
            }
            (State::SettingUp { wheel, step }, Event::Reply(reply)) => {
                self.on_setup_reply(now, wheel, step, reply, settings, &mut effects)
            }
            (State::CheckingGroup, Event::Reply(reply)) => {
                self.on_group_check(now, reply, settings, &mut effects)
            }
            (
                State::Exciting {
                    wheel,
                    excite,
                    cycle,
                },
                Event::Reply(reply),
            ) => self.on_excite_reply(now, wheel, excite, cycle, reply, settings, &mut effects),
            (State::Writing { cycle, command }, Event::Reply(reply)) => {
                self.on_command_written(now, cycle, command, reply, settings, &mut effects)
            }
            (State::Reading { cycle, part }, Event::Reply(reply)) => {
                self.on_feedback(now, cycle, part, reply, settings, &mut effects)
            }
            // A broadcast draws no reply; its "reply" says the frame is out.
            (State::BroadcastingZero { cycle }, Event::Reply(_)) => {
                self.next_in_cycle(now, cycle, settings, &mut effects)
            }
            (State::ResettingTimeoutAlarm { wheel, on, cycle }, Event::Reply(reply)) => {
                self.on_timeout_alarm_reset(now, wheel, on, cycle, reply, settings, &mut effects)
            }
            (State::Probing { wheel, lost }, Event::Reply(reply)) => {
                self.on_probe(wheel, lost, reply, settings, &mut effects)
            }
            // A broadcast draws no reply; its "reply" says the frame is out.
            (State::StoppingBlind { step }, Event::Reply(_)) => {
                self.on_blind_sent(now, step, settings, &mut effects)
            }
            (State::StoppingBlind { step }, Event::Timer) => {
                self.on_blind_timer(step, settings, &mut effects)
            }
            // The runtime sends a reply only for a request and a timer only for a wait:
            // anything else changes nothing.
            (State::HoldPause { .. } | State::CycleWait { .. }, Event::Reply(_)) => {
                warn!("drive link: a reply while no request was out, ignored");
            }
            (
                State::Holding { .. }
                | State::SettingUp { .. }
                | State::CheckingGroup
                | State::Exciting { .. }
                | State::Writing { .. }
                | State::Reading { .. }
                | State::BroadcastingZero { .. }
                | State::ResettingTimeoutAlarm { .. }
                | State::Probing { .. },
                Event::Timer,
            ) => {}
        }
        effects
    }

    fn setup_requested(&self) -> bool {
        self.demand.setup_requests != self.served_setups
    }

    /// Starts a hold round with the left drive.
    fn begin_hold(
        &mut self,
        hold: Hold,
        silent_rounds: [u8; 2],
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let (hold, silent_rounds) = match hold {
            Hold::UntilSetupRequested if self.setup_requested() => (Hold::ForSetup, [0; 2]),
            _ => (hold, silent_rounds),
        };
        if hold == Hold::ForSetup {
            // This round leads to the setup that serves every request so far.
            self.served_setups = self.demand.setup_requests;
        }
        let round = HoldRound {
            wheel: Wheel::Left,
            write: HoldWrite::ZeroSpeed,
            answering: [false; 2],
            silent_rounds,
        };
        self.send_hold(hold, round, settings, effects);
    }

    fn send_hold(
        &mut self,
        hold: Hold,
        round: HoldRound,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let slave = slave(round.wheel, settings);
        let frame = match round.write {
            HoldWrite::ZeroSpeed => {
                let decel = settings.accel_unit.field(self.demand.stop_decel);
                // Operation type, position (unused in continuous operation), speed, rates.
                let fields = [settings.operation_type, 0, 0, decel, decel];
                modbus::write_items(slave, reg::DDO_OPERATION_TYPE, &fields)
            }
            HoldWrite::Trigger => modbus::write_items(slave, reg::DDO_TRIGGER, &[1]),
            HoldWrite::ServoOff => modbus::write_items(slave, reg::DRIVER_INPUT_COMMAND, &[0]),
        };
        self.state = State::Holding { hold, round };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    fn on_hold_reply(
        &mut self,
        now: Timestamp,
        hold: Hold,
        mut round: HoldRound,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let index = wheel_index(round.wheel);
        let (start, items) = match round.write {
            HoldWrite::ZeroSpeed => (reg::DDO_OPERATION_TYPE, 5),
            HoldWrite::Trigger => (reg::DDO_TRIGGER, 1),
            HoldWrite::ServoOff => (reg::DRIVER_INPUT_COMMAND, 1),
        };
        let slave = slave(round.wheel, settings);
        let next_write = match reply.map(|bytes| write_echo(bytes, slave, start, items)) {
            // Silent: the next drive.
            Err(_) => None,
            Ok(Err(_)) => {
                // It answered, but not as asked: counted, and held again next round.
                report(effects, Input::ModbusError);
                round.answering[index] = true;
                None
            }
            Ok(Ok(())) => match round.write {
                HoldWrite::ZeroSpeed => Some(HoldWrite::Trigger),
                // A drive the controller still wants excited keeps S-ON.
                HoldWrite::Trigger if !(self.excited && self.demand.excite) => {
                    Some(HoldWrite::ServoOff)
                }
                HoldWrite::Trigger => {
                    round.answering[index] = true;
                    None
                }
                HoldWrite::ServoOff => {
                    self.brakes_confirmed[index] = true;
                    round.answering[index] = true;
                    None
                }
            },
        };
        if let Some(write) = next_write {
            round.write = write;
            return self.send_hold(hold, round, settings, effects);
        }
        if round.wheel == Wheel::Left {
            round.wheel = Wheel::Right;
            round.write = HoldWrite::ZeroSpeed;
            return self.send_hold(hold, round, settings, effects);
        }
        self.end_hold_round(now, hold, round, settings, effects);
    }

    fn end_hold_round(
        &mut self,
        now: Timestamp,
        hold: Hold,
        mut round: HoldRound,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        if !self.demand.excite {
            self.excited = false;
        }
        match hold {
            Hold::ForSetup if now >= self.powered_up_at => {
                if round.answering == [true, true] && settings.check().is_ok() {
                    return self.send_setup(
                        Wheel::Left,
                        SetupStep::ShareControl,
                        settings,
                        effects,
                    );
                }
                // A drive silent for N rounds in a row is reported once, so the status
                // frame says why the base does not get ready (unpowered, unplugged,
                // wrong address or baud rate).
                for (index, wheel) in [Wheel::Left, Wheel::Right].into_iter().enumerate() {
                    if round.answering[index] {
                        round.silent_rounds[index] = 0;
                        continue;
                    }
                    round.silent_rounds[index] = round.silent_rounds[index].saturating_add(1);
                    if round.silent_rounds[index] == settings.failures_before_loss {
                        warn!("{} drive does not answer", wheel);
                        report(effects, Input::DriveSilent(wheel));
                    }
                }
                self.pause(now, hold, round.silent_rounds, settings, effects);
            }
            Hold::ForSetup | Hold::UntilSetupRequested => {
                self.pause(now, hold, round.silent_rounds, settings, effects)
            }
        }
    }

    /// Waits one poll interval, or less if a new demand comes.
    fn pause(
        &mut self,
        now: Timestamp,
        hold: Hold,
        silent_rounds: [u8; 2],
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let wake_at = now.plus_millis(u64::from(hold_pause_ms(settings)));
        self.state = State::HoldPause {
            hold,
            wake_at,
            silent_rounds,
        };
        effects.next = Some(Next::WaitUntil(wake_at));
    }

    fn send_setup(
        &mut self,
        wheel: Wheel,
        step: SetupStep,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let slave = slave(wheel, settings);
        let frame = match step {
            SetupStep::ShareControl => {
                modbus::write_items(slave, reg::SHARE_CONTROL, &share_control(wheel, settings))
            }
            SetupStep::ShareLists => modbus::write_items(slave, reg::SHARE_LISTS, &share_lists()),
            SetupStep::CommTimeout => modbus::write_items(
                slave,
                reg::COMM_TIMEOUT,
                &[u32::from(settings.drive_comm_timeout_ms)],
            ),
            SetupStep::ReadAlarm | SetupStep::ReadAlarmAfterReset => {
                modbus::read_items(slave, reg::PRESENT_ALARM, 1)
            }
            SetupStep::AlarmResetOn => modbus::write_items(slave, reg::ALARM_RESET, &[1]),
            SetupStep::AlarmResetOff => modbus::write_items(slave, reg::ALARM_RESET, &[0]),
            // Known state: de-excited, brakes holding, until the controller asks.
            SetupStep::ServoOff => modbus::write_items(slave, reg::DRIVER_INPUT_COMMAND, &[0]),
        };
        self.state = State::SettingUp { wheel, step };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    fn on_setup_reply(
        &mut self,
        now: Timestamp,
        wheel: Wheel,
        step: SetupStep,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let slave = slave(wheel, settings);
        let bytes = match reply {
            Ok(bytes) => bytes,
            Err(_) => return self.setup_failed(now, settings, effects),
        };
        let echo = |start: u16, items: usize| write_echo(bytes, slave, start, items);
        let alarm = || modbus::parse_read(bytes, slave, 1).map(|values| values[0]);
        let next = match step {
            SetupStep::ShareControl => echo(reg::SHARE_CONTROL, 3).map(|()| SetupStep::ShareLists),
            SetupStep::ShareLists => {
                echo(reg::SHARE_LISTS, 2 * reg::SHARE_LIST_SLOTS).map(|()| SetupStep::CommTimeout)
            }
            SetupStep::CommTimeout => echo(reg::COMM_TIMEOUT, 1).map(|()| SetupStep::ReadAlarm),
            SetupStep::ReadAlarm => alarm().map(|code| match code {
                0 => SetupStep::ServoOff,
                _ => SetupStep::AlarmResetOn,
            }),
            SetupStep::AlarmResetOn => echo(reg::ALARM_RESET, 1).map(|()| SetupStep::AlarmResetOff),
            SetupStep::AlarmResetOff => {
                echo(reg::ALARM_RESET, 1).map(|()| SetupStep::ReadAlarmAfterReset)
            }
            SetupStep::ReadAlarmAfterReset => match alarm() {
                Ok(0) => Ok(SetupStep::ServoOff),
                Ok(code) => {
                    warn!(
                        "{} drive alarm {=u32:#x} stays after the reset",
                        wheel, code
                    );
                    report(
                        effects,
                        Input::DriveAlarm {
                            wheel,
                            code: alarm_byte(code),
                        },
                    );
                    // The alarm is reported; the failure is not a line error.
                    return self.pause(now, Hold::ForSetup, [0; 2], settings, effects);
                }
                Err(error) => Err(error),
            },
            SetupStep::ServoOff => {
                if let Err(error) = echo(reg::DRIVER_INPUT_COMMAND, 1) {
                    warn!("{} drive setup: {}", wheel, error);
                    return self.setup_failed(now, settings, effects);
                }
                self.brakes_confirmed[wheel_index(wheel)] = true;
                return match wheel {
                    Wheel::Left => {
                        self.send_setup(Wheel::Right, SetupStep::ShareControl, settings, effects)
                    }
                    Wheel::Right => self.send_group_check(settings, effects),
                };
            }
        };
        match next {
            Ok(step) => self.send_setup(wheel, step, settings, effects),
            Err(error) => {
                warn!("{} drive setup: {}", wheel, error);
                self.setup_failed(now, settings, effects)
            }
        }
    }

    /// A setup that failed on the line is counted and tried again after a pause.
    fn setup_failed(&mut self, now: Timestamp, settings: &DriveSettings, effects: &mut Effects) {
        warn!("drive setup failed");
        report(effects, Input::ModbusError);
        self.pause(now, Hold::ForSetup, [0; 2], settings, effects);
    }

    fn send_group_check(&mut self, settings: &DriveSettings, effects: &mut Effects) {
        let frame = modbus::share_read(
            settings.share_group,
            0,
            reg::SHARE_READ_LIST.len() as u16,
            2,
        );
        self.state = State::CheckingGroup;
        effects.next = Some(Next::Send(Request::new(frame, Target::Share)));
    }

    fn on_group_check(
        &mut self,
        now: Timestamp,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let answered = reply.is_ok_and(|bytes| {
            modbus::parse_share_reply(
                bytes,
                settings.share_group,
                modbus::READ_HOLDING,
                2,
                reg::SHARE_READ_LIST.len(),
            )
            .is_ok()
        });
        if !answered {
            return self.setup_failed(now, settings, effects);
        }
        info!("drives set up");
        self.excited = false;
        report(effects, Input::DrivesReady);
        self.next_in_cycle(now, Cycle::start(now), settings, effects);
    }

    /// What the running cycle does next: a setup request ends it; otherwise a write
    /// that is due (S-ON or S-OFF first, then a command the drives do not have yet) goes
    /// out at once, then the feedback read once its moment came; else it waits.
    fn next_in_cycle(
        &mut self,
        now: Timestamp,
        mut cycle: Cycle,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        if self.setup_requested() {
            return self.begin_hold(Hold::ForSetup, [0; 2], settings, effects);
        }
        let command = self.command_now(now, &cycle);
        // An emergency stop goes out first, by one short broadcast that needs no reply:
        // it never waits behind more than the transaction on the line. Also when the
        // drives already brake to zero at a gentler rate (a stop the PC or a hand-over
        // asked for): the e-stop's rate must not wait for the feedback read.
        if self.is_emergency_stop(&command)
            && !cycle.zero_broadcast
            && cycle
                .written
                .is_some_and(|written| !self.is_emergency_stop(&written))
        {
            return self.broadcast_zero(cycle, &command, settings, effects);
        }
        if let Some(index) = cycle.timeout_alarm_resets.iter().position(|&reset| reset) {
            let wheel = [Wheel::Left, Wheel::Right][index];
            return self.send_timeout_alarm_reset(wheel, true, cycle, settings, effects);
        }
        let read_due = now >= cycle.read_at;
        let feedback_due = read_due || cycle.alarms_due;
        // A due read waits for one write at most; after a failed write it goes first,
        // so a line that fails long frames still brings the feedback and a failing
        // write is retried once per period.
        let read_first = feedback_due && (cycle.read_deferred || cycle.write_failures > 0);
        let may_write = now >= cycle.write_retry_at && !read_first;
        cycle.read_deferred |= feedback_due;
        if may_write && self.demand.excite != self.excited {
            return self.send_excite(Wheel::Left, self.demand.excite, cycle, settings, effects);
        }
        let write_pending = cycle.written != Some(command);
        if may_write && write_pending {
            return self.send_command(cycle, command, settings, effects);
        }
        if cycle.alarms_due {
            return self.send_read(cycle, ReadPart::Alarms, settings, effects);
        }
        if read_due {
            return self.send_read(cycle, ReadPart::Motion, settings, effects);
        }
        let mut wake_at = cycle.read_at;
        if write_pending || self.demand.excite != self.excited {
            wake_at = wake_at.min(cycle.write_retry_at);
        }
        // A speed held back for the brake release goes out as soon as it may.
        if self.excited && now < cycle.settled_at && self.demand.wheels.rpm != MotorRpm::ZERO {
            wake_at = wake_at.min(cycle.settled_at);
        }
        self.state = State::CycleWait { wake_at, cycle };
        effects.next = Some(Next::WaitUntil(wake_at));
    }

    /// The controller's command as the drives may have it now: zero while they are not
    /// excited or still settle after S-ON.
    fn command_now(&self, now: Timestamp, cycle: &Cycle) -> WheelCommand {
        let mut command = self.demand.wheels;
        if !(self.excited && now >= cycle.settled_at) {
            command.rpm = MotorRpm::ZERO;
        }
        command
    }

    /// Zero for both wheels braked at least with `estop_decel`: the e-stop, a drive
    /// fault, the safety zone stopping the base. A stop the PC asks for with its own
    /// (gentler) rate is an ordinary command.
    fn is_emergency_stop(&self, command: &WheelCommand) -> bool {
        command.rpm == MotorRpm::ZERO
            && command.left_accel.max(command.right_accel) >= self.demand.stop_decel
    }

    /// The emergency zero by broadcast (address 0): speed 0, both rates the stronger
    /// wheel's, torque limit 100 % (the drives' default), trigger, from the DDO speed
    /// on (29 bytes; 3.1 ms to the drives at 115200 instead of 4.3 ms for the group
    /// write). Each drive stops with that rate; the acknowledged group write with each
    /// wheel's own rate follows, so a turning base still ends up on its track.
    fn broadcast_zero(
        &mut self,
        mut cycle: Cycle,
        command: &WheelCommand,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        const BROADCAST: u8 = 0;
        let decel = settings
            .accel_unit
            .field(command.left_accel.max(command.right_accel));
        let fields = [0, decel, decel, 1_000, 1];
        let frame = modbus::write_items(BROADCAST, reg::DDO_SPEED, &fields);
        cycle.zero_broadcast = true;
        self.state = State::BroadcastingZero { cycle };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    fn send_excite(
        &mut self,
        wheel: Wheel,
        excite: bool,
        cycle: Cycle,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let word = if excite {
            // From the moment it may arrive the drive may release its brake.
            self.brakes_confirmed[wheel_index(wheel)] = false;
            reg::S_ON
        } else {
            0
        };
        let frame = modbus::write_items(slave(wheel, settings), reg::DRIVER_INPUT_COMMAND, &[word]);
        self.state = State::Exciting {
            wheel,
            excite,
            cycle,
        };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    #[allow(clippy::too_many_arguments)]
    fn on_excite_reply(
        &mut self,
        now: Timestamp,
        wheel: Wheel,
        excite: bool,
        mut cycle: Cycle,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let acknowledged = reply.is_ok_and(|bytes| {
            write_echo(bytes, slave(wheel, settings), reg::DRIVER_INPUT_COMMAND, 1).is_ok()
        });
        if !acknowledged {
            return self.write_failed(now, cycle, settings, effects);
        }
        if !excite {
            self.brakes_confirmed[wheel_index(wheel)] = true;
        }
        if wheel == Wheel::Left {
            return self.send_excite(Wheel::Right, excite, cycle, settings, effects);
        }
        self.excited = excite;
        cycle.write_failures = 0;
        if excite {
            cycle.settled_at = now.plus_millis(u64::from(settings.excite_settle_ms));
        }
        self.next_in_cycle(now, cycle, settings, effects);
    }

    /// The command write: both wheels' speed and rates, and the trigger, in one FC 10h
    /// to the group, short so that it never waits long behind anything.
    fn send_command(
        &mut self,
        cycle: Cycle,
        command: WheelCommand,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let unit = settings.accel_unit;
        let member = |speed: i32, accel: u32| {
            let accel = unit.field(accel);
            // Signed speeds go on the wire as two's complement.
            [speed as u32, accel, accel, 1]
        };
        let left = member(command.rpm.left, command.left_accel);
        let right = member(command.rpm.right, command.right_accel);
        let frame = modbus::share_write(settings.share_group, 0, &[&left, &right]);
        self.state = State::Writing { cycle, command };
        effects.next = Some(Next::Send(Request::new(frame, Target::Share)));
    }

    #[allow(clippy::too_many_arguments)]
    fn on_command_written(
        &mut self,
        now: Timestamp,
        mut cycle: Cycle,
        command: WheelCommand,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let registers = (2 * 2 * reg::SHARE_WRITE_LIST.len()) as u16;
        let acknowledged = reply.is_ok_and(|bytes| {
            modbus::parse_write_echo(bytes, settings.share_group, 0, registers).is_ok()
        });
        if !acknowledged {
            return self.write_failed(now, cycle, settings, effects);
        }
        cycle.written = Some(command);
        cycle.write_failures = 0;
        // The drives have something other than an emergency stop again: the next one
        // is broadcast.
        if !self.is_emergency_stop(&command) {
            cycle.zero_broadcast = false;
        }
        self.next_in_cycle(now, cycle, settings, effects);
    }

    /// A write that did not reach both drives is counted and tried again after the
    /// next read; N in a row end the cycle.
    fn write_failed(
        &mut self,
        now: Timestamp,
        mut cycle: Cycle,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        report(effects, Input::ModbusError);
        cycle.write_failures = cycle.write_failures.saturating_add(1);
        if cycle.write_failures >= settings.failures_before_loss {
            return self.escalate(settings, effects);
        }
        cycle.write_retry_at = cycle.read_at.max(now);
        self.next_in_cycle(now, cycle, settings, effects);
    }

    /// The read after the one due at `read_at`: whole periods on, or, when the
    /// controller says when its position frames go out, half a period before the next
    /// one (moved by at most half a period at a time, so never two reads within half a
    /// period); after a stall, at once.
    fn next_read_at(
        &self,
        now: Timestamp,
        read_at: Timestamp,
        settings: &DriveSettings,
    ) -> Timestamp {
        let period = u64::from(cycle_period_ms(self.demand.cycle_ms, settings));
        let aligned = self
            .demand
            .feedback_due_at
            .filter(|_| period == u64::from(self.demand.cycle_ms))
            .map(|due| {
                let half = period / 2;
                let earliest = read_at.as_millis() + half;
                // The reads' phase: half a period before each frame.
                let phase = (due.as_millis() + period - half) % period;
                let offset = (phase + period - earliest % period) % period;
                Timestamp::from_millis(earliest + offset)
            });
        aligned.unwrap_or(read_at.plus_millis(period)).max(now)
    }

    /// One part of the feedback read: positions and speeds, or the alarms, of both
    /// drives in one FC 03h to the group.
    fn send_read(
        &mut self,
        cycle: Cycle,
        part: ReadPart,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let (first, items) = part.items();
        if part == ReadPart::Alarms {
            // A reply to a read sent before the stall cannot show what it caused.
            self.alarm_read_after_stall = self.stalled_at_rest;
        }
        // Two share registers per item.
        let frame = modbus::share_read(settings.share_group, 2 * first, items as u16, 2);
        self.state = State::Reading { cycle, part };
        effects.next = Some(Next::Send(Request::new(frame, Target::Share)));
    }

    fn on_feedback(
        &mut self,
        now: Timestamp,
        mut cycle: Cycle,
        part: ReadPart,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        cycle.read_deferred = false;
        let (_, items) = part.items();
        let share = reply.ok().and_then(|bytes| {
            modbus::parse_share_reply(bytes, settings.share_group, modbus::READ_HOLDING, 2, items)
                .ok()
        });
        if part == ReadPart::Motion {
            cycle.read_at = self.next_read_at(now, cycle.read_at, settings);
        }
        cycle.alarms_due = part == ReadPart::Motion && share.is_some();
        let Some(share) = share else {
            report(effects, Input::ModbusError);
            let failures = match part {
                ReadPart::Motion => &mut cycle.read_failures,
                ReadPart::Alarms => &mut cycle.alarm_read_failures,
            };
            *failures = failures.saturating_add(1);
            if *failures >= settings.failures_before_loss {
                return self.escalate(settings, effects);
            }
            return self.next_in_cycle(now, cycle, settings, effects);
        };
        let (left, right) = (share.member(0), share.member(1));
        match part {
            ReadPart::Motion => {
                report(
                    effects,
                    Input::DriveFeedback {
                        counts: EncoderCounts {
                            left: left[0] as i32,
                            right: right[0] as i32,
                        },
                        rpm: MotorRpm {
                            left: left[1] as i32,
                            right: right[1] as i32,
                        },
                    },
                );
                cycle.read_failures = 0;
            }
            ReadPart::Alarms => {
                for (index, (wheel, code)) in [Wheel::Left, Wheel::Right]
                    .into_iter()
                    .zip([left[0], right[0]])
                    .enumerate()
                {
                    if code == reg::ALARM_COMM_TIMEOUT && self.alarm_read_after_stall {
                        // Our own silence at rest tripped it: reset, and counted.
                        warn!("{} drive: alarm 85h after a stall at rest, reset", wheel);
                        report(effects, Input::ModbusError);
                        cycle.timeout_alarm_resets[index] = true;
                        continue;
                    }
                    if code != 0 && cycle.alarms[index] == 0 {
                        report(
                            effects,
                            Input::DriveAlarm {
                                wheel,
                                code: alarm_byte(code),
                            },
                        );
                    }
                    cycle.alarms[index] = code;
                }
                cycle.alarm_read_failures = 0;
                // One stall excuses the alarms of the first read after it, no more:
                // an alarm that stays after the reset is reported.
                if self.alarm_read_after_stall {
                    self.stalled_at_rest = false;
                    self.alarm_read_after_stall = false;
                }
            }
        }
        self.next_in_cycle(now, cycle, settings, effects)
    }

    fn send_timeout_alarm_reset(
        &mut self,
        wheel: Wheel,
        on: bool,
        cycle: Cycle,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let frame = modbus::write_items(slave(wheel, settings), reg::ALARM_RESET, &[u32::from(on)]);
        self.state = State::ResettingTimeoutAlarm { wheel, on, cycle };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    /// The reset acts on the 0 → 1 change, so 1 then 0; a failed write counts as any
    /// failed write and the reset is tried again after the next read.
    #[allow(clippy::too_many_arguments)]
    fn on_timeout_alarm_reset(
        &mut self,
        now: Timestamp,
        wheel: Wheel,
        on: bool,
        mut cycle: Cycle,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let acknowledged = reply.is_ok_and(|bytes| {
            write_echo(bytes, slave(wheel, settings), reg::ALARM_RESET, 1).is_ok()
        });
        if !acknowledged {
            return self.write_failed(now, cycle, settings, effects);
        }
        if on {
            return self.send_timeout_alarm_reset(wheel, false, cycle, settings, effects);
        }
        cycle.timeout_alarm_resets[wheel_index(wheel)] = false;
        cycle.write_failures = 0;
        self.next_in_cycle(now, cycle, settings, effects)
    }

    /// N failed reads or writes in a row: no command reached the drives or no feedback
    /// came for that long, so nothing the drives say can be trusted. Stop them in a
    /// way that needs no reply, fall silent, then find out why.
    fn escalate(&mut self, settings: &DriveSettings, effects: &mut Effects) {
        warn!("drive link lost: blind stop, then silence");
        self.send_blind(BlindStep::Zero(1), settings, effects);
    }

    fn send_blind(&mut self, step: BlindStep, settings: &DriveSettings, effects: &mut Effects) {
        const BROADCAST: u8 = 0;
        let BlindStep::Zero(_) = step else {
            return;
        };
        let decel = settings.accel_unit.field(self.demand.stop_decel);
        // Operation type, position, speed 0, rates, torque limit 100 % (the drives' own
        // default), trigger: the trigger comes last and applies the rest in the same
        // frame.
        let fields = [settings.operation_type, 0, 0, decel, decel, 1_000, 1];
        let frame = modbus::write_items(BROADCAST, reg::DDO_OPERATION_TYPE, &fields);
        self.state = State::StoppingBlind { step };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    fn on_blind_sent(
        &mut self,
        now: Timestamp,
        step: BlindStep,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        match step {
            BlindStep::Zero(sent) if sent < BLIND_REPEATS => {
                self.send_blind(BlindStep::Zero(sent + 1), settings, effects)
            }
            // Silence now: the drives' timeout trips in every drive, the one that
            // executes nothing too, and de-excites it; a drive that took the zero
            // brakes meanwhile.
            BlindStep::Zero(_) => self.fall_silent(now, settings, effects),
            BlindStep::Silent => {}
        }
    }

    /// Nothing on the line until the drives' timeout has surely tripped.
    fn fall_silent(&mut self, now: Timestamp, settings: &DriveSettings, effects: &mut Effects) {
        self.excited = false;
        let wake_at = now.plus_millis(comm_timeout_ms(settings) + SILENCE_MARGIN_MS);
        self.state = State::StoppingBlind {
            step: BlindStep::Silent,
        };
        effects.next = Some(Next::WaitUntil(wake_at));
    }

    fn on_blind_timer(&mut self, step: BlindStep, settings: &DriveSettings, effects: &mut Effects) {
        match step {
            BlindStep::Silent => {
                // Only `fall_silent` waits here, and it waited beyond the drives'
                // timeout: every drive tripped (alarm 85h, de-excited, brake closed),
                // the one that heard nothing long before.
                self.brakes_confirmed = [true; 2];
                self.send_probe(Wheel::Left, false, settings, effects)
            }
            BlindStep::Zero(_) => {}
        }
    }

    fn send_probe(
        &mut self,
        wheel: Wheel,
        lost: bool,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let frame = modbus::read_items(slave(wheel, settings), reg::SHARE_CONTROL, 3);
        self.state = State::Probing { wheel, lost };
        effects.next = Some(Next::Send(Request::new(frame, Target::Unicast)));
    }

    /// A drive that is silent or lost its share setup (it lost power since the setup)
    /// is reported; when both answer as set up, the group frame alone fails (a marginal
    /// line fails long frames first) and both are reported.
    fn on_probe(
        &mut self,
        wheel: Wheel,
        mut lost: bool,
        reply: Result<&[u8], TransferError>,
        settings: &DriveSettings,
        effects: &mut Effects,
    ) {
        let ready = match reply.map(|bytes| modbus::parse_read(bytes, slave(wheel, settings), 3)) {
            Err(_) => false,
            Ok(Ok(values)) => values[..] == share_control(wheel, settings),
            Ok(Err(_)) => {
                report(effects, Input::ModbusError);
                false
            }
        };
        if !ready {
            warn!("{} drive lost", wheel);
            lost = true;
            report(effects, Input::DriveSilent(wheel));
        }
        if wheel == Wheel::Left {
            return self.send_probe(Wheel::Right, lost, settings, effects);
        }
        if !lost {
            warn!("the share group fails while both drives answer alone");
            report(effects, Input::DriveSilent(Wheel::Left));
            report(effects, Input::DriveSilent(Wheel::Right));
        }
        self.begin_hold(Hold::UntilSetupRequested, [0; 2], settings, effects);
    }
}

/// Checks the echo of a write of `items` 32-bit items (two registers each).
fn write_echo(bytes: &[u8], slave: u8, start: u16, items: usize) -> Result<(), ReplyError> {
    modbus::parse_write_echo(bytes, slave, start, 2 * items as u16)
}

/// Adds a report. A step reports at most three things, so the room never runs out.
fn report(effects: &mut Effects, input: Input) {
    let pushed = effects.reports.push(input);
    debug_assert!(pushed.is_ok(), "drive link: more reports than room");
}

fn slave(wheel: Wheel, settings: &DriveSettings) -> u8 {
    match wheel {
        Wheel::Left => settings.left_slave,
        Wheel::Right => settings.right_slave,
    }
}

fn wheel_index(wheel: Wheel) -> usize {
    match wheel {
        Wheel::Left => 0,
        Wheel::Right => 1,
    }
}

/// Global ID, member count and local ID of one wheel's drive.
fn share_control(wheel: Wheel, settings: &DriveSettings) -> [u32; 3] {
    let local_id = match wheel {
        Wheel::Left => 1,
        Wheel::Right => 2,
    };
    [u32::from(settings.share_group), 2, local_id]
}

/// The share read list, then the share write list, each in its 12 slots.
fn share_lists() -> [u32; 2 * reg::SHARE_LIST_SLOTS] {
    let mut lists = [0u32; 2 * reg::SHARE_LIST_SLOTS];
    lists[..reg::SHARE_READ_LIST.len()].copy_from_slice(&reg::SHARE_READ_LIST);
    lists[reg::SHARE_LIST_SLOTS..][..reg::SHARE_WRITE_LIST.len()]
        .copy_from_slice(&reg::SHARE_WRITE_LIST);
    lists
}

/// The time between two cycle frames: `loop_end_delay`, but at most a third of the
/// drives' communication timeout, so that a long cycle can never trip it.
pub fn cycle_period_ms(cycle_ms: u16, settings: &DriveSettings) -> u32 {
    u32::from(cycle_ms.max(1)).min(a_third_of_the_timeout_ms(settings))
}

/// The pause between two hold rounds: `poll_interval_ms`, but at most a third of the
/// drives' communication timeout, so that a held drive never trips it.
pub fn hold_pause_ms(settings: &DriveSettings) -> u32 {
    settings
        .poll_interval_ms
        .min(a_third_of_the_timeout_ms(settings))
}

fn a_third_of_the_timeout_ms(settings: &DriveSettings) -> u32 {
    (u32::from(settings.drive_comm_timeout_ms) / 3).max(1)
}

/// The drives' communication timeout the link sets, ms.
fn comm_timeout_ms(settings: &DriveSettings) -> u64 {
    u64::from(settings.drive_comm_timeout_ms)
}

/// Oriental alarm codes are one byte (e.g. 84h); the register is 32 bits wide.
fn alarm_byte(code: u32) -> u8 {
    u8::try_from(code).unwrap_or(u8::MAX)
}

#[cfg(test)]
mod tests;
