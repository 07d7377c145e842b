//! The drive link task: brings the drives up, runs one ID-share transaction per
//! control cycle, and sets them up again after every loss.
//!
//! ```text
//!  boot ─▶ hold both until power_up_wait passed ─▶ set up ─▶ DrivesReady
//!          and both answer                ▲                     │
//!                                         │                     ▼
//!            setup requested ─────────────┤       cycle: one 17h per loop_end_delay,
//!                                         │       and at once on a new demand
//!  hold: zero + estop_decel to every      │                     │
//!  drive that answers, S-OFF unless  ◀────┴── N failed group cycles (a member
//!  still braking excited, poll the others     silent or reset, or the group alone
//!                                             failing): zero by unicast, reported
//! ```
//!
//! Outside the cycle the link *holds*: every drive that answers gets zero speed with
//! `estop_decel` (and the DDO operation type, so the trigger cannot start anything
//! else) and S-OFF, by unicast, once per poll interval and at once on a new demand.
//! This is also the first thing on the wire after boot, before and during the drives'
//! power-up wait: a controller that restarts while the base drives stops the wheels
//! at once, whichever drive answers. N = `failures_before_loss` (3: 150 ms at the
//! default 50 ms cycle).
//!
//! The link reports `DrivesReady` only after boot or a setup request (the controller's
//! contract): drives that come back unasked stay held until the supervisor asks.

use embassy_futures::select::{Either, select};
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};

use crate::channels::{InputSender, RawMutex};
use crate::hw::Rs485;
use crate::liveness::{CriticalTask, Liveness};
use base_core::controller::Input;
use base_core::kinematics::{MotorRpm, WheelCommand};
use base_core::modbus::{self, Frame, ReplyError, Target};
use base_core::odometry::EncoderCounts;
use base_core::registers::{Reg, Registers};
use base_core::supervisor::Wheel;

pub mod master;

use base_core::drives::DriveSettings;
use base_core::drives::reg;
use master::{Master, TransferError};

/// Runs the drive link forever.
pub async fn run<P: Rs485>(port: P, settings: DriveSettings, channels: DriveLinkEnds<'_>) -> ! {
    let mut link = DriveLink::new(port, settings, channels);
    link.run().await
}

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
}

impl DriveDemand {
    pub const fn at_rest(cycle_ms: u16, stop_decel: u32) -> Self {
        Self {
            wheels: WheelCommand {
                rpm: MotorRpm { left: 0, right: 0 },
                left_accel: 0,
                right_accel: 0,
            },
            excite: false,
            setup_requests: 0,
            cycle_ms,
            stop_decel,
        }
    }
}

/// The drive link's channel ends (see [`crate::channels::Channels`]).
pub struct DriveLinkEnds<'a> {
    pub drive_demand: &'a Signal<RawMutex, DriveDemand>,
    pub inputs: InputSender<'a>,
    pub liveness: &'a Liveness,
}

/// Why a step of the link failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum LinkError {
    Transfer(TransferError),
    Reply(ReplyError),
    /// An alarm stayed after the reset.
    Alarm,
}

impl From<TransferError> for LinkError {
    fn from(error: TransferError) -> Self {
        LinkError::Transfer(error)
    }
}

impl From<ReplyError> for LinkError {
    fn from(error: ReplyError) -> Self {
        LinkError::Reply(error)
    }
}

/// What a unicast probe found out about one drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Probe {
    Silent,
    /// It answers, but its share setup is gone: it lost power since the setup.
    Unconfigured,
    Ready,
}

const WHEELS: [Wheel; 2] = [Wheel::Left, Wheel::Right];

struct DriveLink<'a, P> {
    master: Master<P>,
    settings: DriveSettings,
    channels: DriveLinkEnds<'a>,
    demand: DriveDemand,
    /// Setup requests handled so far.
    served_setups: u32,
    /// What the drives were last told about S-ON.
    excited: bool,
    /// No speed but zero before this moment: the drives settle after S-ON.
    settled_at: Instant,
    /// The last cycle sent zero instead of the demanded speed, waiting for the settle.
    held_for_settle: bool,
    /// Last alarm code seen per wheel, so each alarm is reported once.
    alarms: [u32; 2],
    reply: Frame,
}

impl<'a, P: Rs485> DriveLink<'a, P> {
    fn new(port: P, settings: DriveSettings, channels: DriveLinkEnds<'a>) -> Self {
        Self {
            master: Master::new(port, &settings.line, settings.reply_timeout_ms),
            settings,
            channels,
            // Until the controller's first signal, which comes at once.
            demand: DriveDemand::at_rest(
                Registers::defaults().get(Reg::LoopEndDelay),
                u32::from(Registers::defaults().get(Reg::EstopDecel)),
            ),
            served_setups: 0,
            excited: false,
            settled_at: Instant::from_ticks(0),
            held_for_settle: false,
            alarms: [0; 2],
            reply: Frame::new(),
        }
    }

    async fn run(&mut self) -> ! {
        let powered_up =
            Instant::now() + Duration::from_millis(u64::from(self.settings.power_up_wait_ms));
        // Each round serves boot or one setup request.
        loop {
            self.served_setups = self.demand.setup_requests;
            self.hold_until_both_answer(powered_up).await;
            if let Err(error) = self.set_up().await {
                warn!("drive setup failed: {}", error);
                self.pause().await;
                continue;
            }
            info!("drives set up");
            self.report(Input::DrivesReady).await;
            self.cycle().await;
            if !self.setup_requested() {
                self.hold_until_setup_requested().await;
            }
        }
    }

    fn slave(&self, wheel: Wheel) -> u8 {
        match wheel {
            Wheel::Left => self.settings.left_slave,
            Wheel::Right => self.settings.right_slave,
        }
    }

    fn refresh_demand(&mut self) {
        if let Some(demand) = self.channels.drive_demand.try_take() {
            self.demand = demand;
        }
    }

    fn setup_requested(&self) -> bool {
        self.demand.setup_requests != self.served_setups
    }

    async fn report(&self, input: Input) {
        self.channels.inputs.send(input).await;
    }

    /// Waits one poll interval, or less if a new demand comes, checking in.
    async fn pause(&mut self) {
        self.channels.liveness.check_in(CriticalTask::DriveLink);
        let poll = Duration::from_millis(u64::from(self.settings.poll_interval_ms));
        if let Either::Second(demand) =
            select(Timer::after(poll), self.channels.drive_demand.wait()).await
        {
            self.demand = demand;
        }
        self.refresh_demand();
    }

    /// Holds every drive that answers (see the module documentation) until the
    /// power-up wait has passed and both answer. The wait is a commissioning setting
    /// and may be longer than the watchdog's timeout: the link checks in every round.
    /// After the wait, a drive silent for `failures_before_loss` rounds in a row is
    /// reported once, so the status frame says why the base does not get ready
    /// (unpowered, unplugged, wrong address or baud rate).
    async fn hold_until_both_answer(&mut self, powered_up: Instant) {
        let mut silent_rounds = [0u8; WHEELS.len()];
        loop {
            let answering = self.hold_round().await;
            if Instant::now() >= powered_up {
                if answering.iter().all(|&answers| answers) {
                    return;
                }
                for (index, wheel) in WHEELS.into_iter().enumerate() {
                    if answering[index] {
                        silent_rounds[index] = 0;
                        continue;
                    }
                    silent_rounds[index] = silent_rounds[index].saturating_add(1);
                    if silent_rounds[index] == self.settings.failures_before_loss {
                        warn!("{} drive does not answer", wheel);
                        self.report(Input::DriveSilent(wheel)).await;
                    }
                }
            }
            self.pause().await;
        }
    }

    /// One hold round over both drives; returns which answered.
    async fn hold_round(&mut self) -> [bool; 2] {
        let mut answering = [false; 2];
        for (index, wheel) in WHEELS.into_iter().enumerate() {
            answering[index] = match self.hold_one(wheel).await {
                Ok(()) => true,
                Err(LinkError::Transfer(_)) => false,
                Err(_) => {
                    // It answered, but not as asked: counted, and held again next round.
                    self.report(Input::ModbusError).await;
                    true
                }
            };
        }
        if !self.demand.excite {
            self.excited = false;
        }
        answering
    }

    /// Zero speed with the stop deceleration to one drive by unicast, and S-OFF unless
    /// the controller still wants it excited (braking to a stop after a fault, its
    /// brakes close once the base stands). Stops at the first write that gets no reply.
    async fn hold_one(&mut self, wheel: Wheel) -> Result<(), LinkError> {
        let slave = self.slave(wheel);
        let decel = self.settings.accel_unit.field(self.demand.stop_decel);
        // Operation type, position (unused in continuous operation), speed, rates.
        let fields = [self.settings.operation_type, 0, 0, decel, decel];
        self.write(slave, reg::DDO_OPERATION_TYPE, &fields).await?;
        self.write(slave, reg::DDO_TRIGGER, &[1]).await?;
        if !(self.excited && self.demand.excite) {
            self.write(slave, reg::DRIVER_INPUT_COMMAND, &[0]).await?;
        }
        Ok(())
    }

    /// Reads the share control block of one drive.
    async fn probe(&mut self, wheel: Wheel) -> Probe {
        let slave = self.slave(wheel);
        let request = modbus::read_items(slave, reg::SHARE_CONTROL, 3);
        if self.transact(&request, Target::Unicast).await.is_err() {
            return Probe::Silent;
        }
        match modbus::parse_read(&self.reply, slave, 3) {
            Ok(values) if values[..] == self.share_control(wheel) => Probe::Ready,
            Ok(_) => Probe::Unconfigured,
            Err(_) => {
                self.report(Input::ModbusError).await;
                Probe::Silent
            }
        }
    }

    /// Global ID, member count and local ID of one wheel's drive.
    fn share_control(&self, wheel: Wheel) -> [u32; 3] {
        let local_id = match wheel {
            Wheel::Left => 1,
            Wheel::Right => 2,
        };
        [u32::from(self.settings.share_group), 2, local_id]
    }

    /// Sends `request` and leaves the reply in `self.reply`.
    async fn transact(&mut self, request: &[u8], target: Target) -> Result<(), TransferError> {
        let expected = modbus::expected_reply_len(request, target).unwrap_or(0);
        self.master
            .transact(request, expected, &mut self.reply)
            .await
    }

    async fn write(&mut self, slave: u8, start: u16, values: &[u32]) -> Result<(), LinkError> {
        let request = modbus::write_items(slave, start, values);
        self.transact(&request, Target::Unicast).await?;
        modbus::parse_write_echo(&self.reply, slave, start, 2 * values.len() as u16)?;
        Ok(())
    }

    async fn read_alarm(&mut self, slave: u8) -> Result<u32, LinkError> {
        let request = modbus::read_items(slave, reg::PRESENT_ALARM, 1);
        self.transact(&request, Target::Unicast).await?;
        Ok(modbus::parse_read(&self.reply, slave, 1)?[0])
    }

    /// The setup of docs/drives.md (What happens on the wire), for drives that answer.
    async fn set_up(&mut self) -> Result<(), LinkError> {
        let mut lists = [0u32; 2 * reg::SHARE_LIST_SLOTS];
        lists[..reg::SHARE_READ_LIST.len()].copy_from_slice(&reg::SHARE_READ_LIST);
        lists[reg::SHARE_LIST_SLOTS..][..reg::SHARE_WRITE_LIST.len()]
            .copy_from_slice(&reg::SHARE_WRITE_LIST);
        for wheel in WHEELS {
            let slave = self.slave(wheel);
            let result = self.set_up_one(wheel, slave, &lists).await;
            if let Err(error) = result {
                if error != LinkError::Alarm {
                    self.report(Input::ModbusError).await;
                }
                return Err(error);
            }
        }
        // The group answers as a whole: the cycle can start.
        let request = modbus::share_read(
            self.settings.share_group,
            0,
            reg::SHARE_READ_LIST.len() as u16,
            2,
        );
        self.transact(&request, Target::Share).await?;
        modbus::parse_share_reply(
            &self.reply,
            self.settings.share_group,
            modbus::READ_HOLDING,
            2,
            reg::SHARE_READ_LIST.len(),
        )?;
        self.excited = false;
        self.alarms = [0; 2];
        Ok(())
    }

    async fn set_up_one(
        &mut self,
        wheel: Wheel,
        slave: u8,
        lists: &[u32],
    ) -> Result<(), LinkError> {
        let control = self.share_control(wheel);
        self.write(slave, reg::SHARE_CONTROL, &control).await?;
        self.write(slave, reg::SHARE_LISTS, lists).await?;
        if let Some(timeout_ms) = self.settings.drive_comm_timeout_ms {
            self.write(slave, reg::COMM_TIMEOUT, &[u32::from(timeout_ms)])
                .await?;
        }
        if self.read_alarm(slave).await? != 0 {
            // The reset acts on the 0 → 1 change.
            self.write(slave, reg::ALARM_RESET, &[1]).await?;
            self.write(slave, reg::ALARM_RESET, &[0]).await?;
            let code = self.read_alarm(slave).await?;
            if code != 0 {
                warn!(
                    "{} drive alarm {=u32:#x} stays after the reset",
                    wheel, code
                );
                self.report(Input::DriveAlarm {
                    wheel,
                    code: alarm_byte(code),
                })
                .await;
                return Err(LinkError::Alarm);
            }
        }
        // Known state: de-excited, brakes holding, until the supervisor asks.
        self.write(slave, reg::DRIVER_INPUT_COMMAND, &[0]).await
    }

    /// Runs the control cycle until the drives are lost or a setup is requested.
    async fn cycle(&mut self) {
        let mut failures = 0u8;
        let mut next = Instant::now();
        loop {
            self.channels.liveness.check_in(CriticalTask::DriveLink);
            self.refresh_demand();
            if self.setup_requested() {
                return;
            }
            match self.exchange().await {
                Ok(()) => failures = 0,
                Err(_) => {
                    self.report(Input::ModbusError).await;
                    failures += 1;
                    if failures >= self.settings.failures_before_loss {
                        // No command reached the drives for N cycles: zero by unicast
                        // first, then find out why, and hold until the recovery.
                        self.hold_round().await;
                        if !self.find_lost_drives().await {
                            // Each drive answers alone, but the group frame keeps
                            // failing (a marginal line fails long frames first): the
                            // PC's commands cannot reach the wheels. Both are reported.
                            warn!("the share group fails while both drives answer alone");
                            for wheel in WHEELS {
                                self.report(Input::DriveSilent(wheel)).await;
                            }
                        }
                        return;
                    }
                }
            }
            let period = Duration::from_millis(u64::from(self.cycle_period_ms()));
            next = (next + period).max(Instant::now());
            let mut wake = next;
            // A speed held back for the brake release goes out as soon as it may.
            if self.excited && self.held_for_settle {
                wake = wake.min(self.settled_at.max(Instant::now()));
            }
            // A new demand goes out at once, not at the next cycle.
            if let Either::Second(demand) =
                select(Timer::at(wake), self.channels.drive_demand.wait()).await
            {
                self.demand = demand;
            }
        }
    }

    /// One cycle: S-ON changes first, then one 17h transaction that writes both
    /// wheels' command and reads both positions, speeds and alarms.
    async fn exchange(&mut self) -> Result<(), LinkError> {
        if self.demand.excite != self.excited {
            let word = if self.demand.excite { reg::S_ON } else { 0 };
            for wheel in WHEELS {
                let slave = self.slave(wheel);
                self.write(slave, reg::DRIVER_INPUT_COMMAND, &[word])
                    .await?;
            }
            self.excited = self.demand.excite;
            if self.excited {
                self.settled_at = Instant::now()
                    + Duration::from_millis(u64::from(self.settings.excite_settle_ms));
            }
        }
        let command = self.demand.wheels;
        let rpm = if self.excited && Instant::now() >= self.settled_at {
            command.rpm
        } else {
            MotorRpm::ZERO
        };
        self.held_for_settle = self.excited && rpm != command.rpm;
        let unit = self.settings.accel_unit;
        let member = |speed: i32, accel: u32| {
            let accel = unit.field(accel);
            // Signed speeds go on the wire as two's complement.
            [self.settings.operation_type, speed as u32, accel, accel, 1]
        };
        let left = member(rpm.left, command.left_accel);
        let right = member(rpm.right, command.right_accel);
        let request = modbus::share_read_write(
            self.settings.share_group,
            0,
            reg::SHARE_READ_LIST.len() as u16,
            0,
            &[&left, &right],
        );
        self.transact(&request, Target::Share).await?;
        let share = modbus::parse_share_reply(
            &self.reply,
            self.settings.share_group,
            modbus::READ_WRITE_MULTIPLE,
            2,
            reg::SHARE_READ_LIST.len(),
        )?;
        let (left, right) = (share.member(0), share.member(1));
        self.report(Input::DriveFeedback {
            counts: EncoderCounts {
                left: left[0] as i32,
                right: right[0] as i32,
            },
            rpm: MotorRpm {
                left: left[1] as i32,
                right: right[1] as i32,
            },
        })
        .await;
        for (index, (wheel, code)) in WHEELS.into_iter().zip([left[2], right[2]]).enumerate() {
            if code != 0 && self.alarms[index] == 0 {
                self.report(Input::DriveAlarm {
                    wheel,
                    code: alarm_byte(code),
                })
                .await;
            }
            self.alarms[index] = code;
        }
        Ok(())
    }

    /// After repeated failures: asks each drive on its own. Reports and returns true
    /// if one is silent or lost its setup; false if both are fine (a burst of noise).
    async fn find_lost_drives(&mut self) -> bool {
        let mut lost = false;
        for wheel in WHEELS {
            if self.probe(wheel).await != Probe::Ready {
                warn!("{} drive lost", wheel);
                lost = true;
                self.report(Input::DriveSilent(wheel)).await;
            }
        }
        lost
    }

    /// After a loss: holds every drive that answers until a setup is requested.
    async fn hold_until_setup_requested(&mut self) {
        while !self.setup_requested() {
            self.hold_round().await;
            self.pause().await;
        }
    }

    /// The time between two cycle frames: `loop_end_delay`, but at most a third of the
    /// drives' communication timeout, so that a long cycle can never trip it.
    fn cycle_period_ms(&self) -> u32 {
        let cycle = u32::from(self.demand.cycle_ms.max(1));
        match self.settings.drive_comm_timeout_ms {
            Some(timeout) if timeout > 0 => cycle.min((u32::from(timeout) / 3).max(1)),
            _ => cycle,
        }
    }
}

/// Oriental alarm codes are one byte (e.g. 84h); the register is 32 bits wide.
fn alarm_byte(code: u32) -> u8 {
    u8::try_from(code).unwrap_or(u8::MAX)
}
