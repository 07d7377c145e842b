//! The drive link task: brings the drives up, runs one ID-share transaction per
//! control cycle, and sets them up again after every loss.
//!
//! ```text
//!  boot ─▶ wait power_up_wait ─▶ poll until both answer ─▶ set up ─▶ DrivesReady
//!                                      ▲                               │
//!            setup requested ─────────┤                               ▼
//!                                      │                 cycle: one 17h per loop_end_delay,
//!  hold: zero to drives that answer,   │                 and at once on a new demand
//!  poll the others  ◀──── lost ────────┴──── N failed cycles, a member silent or reset
//! ```
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
}

impl DriveDemand {
    pub const fn at_rest(cycle_ms: u16) -> Self {
        Self {
            wheels: WheelCommand {
                rpm: MotorRpm { left: 0, right: 0 },
                left_accel: 0,
                right_accel: 0,
            },
            excite: false,
            setup_requests: 0,
            cycle_ms,
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
            demand: DriveDemand::at_rest(Registers::defaults().get(Reg::LoopEndDelay)),
            served_setups: 0,
            excited: false,
            settled_at: Instant::from_ticks(0),
            alarms: [0; 2],
            reply: Frame::new(),
        }
    }

    async fn run(&mut self) -> ! {
        self.wait_for_power_up().await;
        // Each round serves boot or one setup request.
        loop {
            self.served_setups = self.demand.setup_requests;
            self.poll_until_both_answer().await;
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

    /// Gives the drives their power-up time, checking in every poll interval: the wait
    /// is a commissioning setting and may be longer than the watchdog's timeout.
    async fn wait_for_power_up(&mut self) {
        let powered_up =
            Instant::now() + Duration::from_millis(u64::from(self.settings.power_up_wait_ms));
        let poll = Duration::from_millis(u64::from(self.settings.poll_interval_ms));
        while Instant::now() < powered_up {
            self.channels.liveness.check_in(CriticalTask::DriveLink);
            Timer::at(powered_up.min(Instant::now() + poll)).await;
        }
    }

    /// Waits one poll interval, checking in and taking a new demand.
    async fn pause(&mut self) {
        self.channels.liveness.check_in(CriticalTask::DriveLink);
        Timer::after_millis(u64::from(self.settings.poll_interval_ms)).await;
        self.refresh_demand();
    }

    /// Polls until both drives answer. A drive silent for `failures_before_loss` polls
    /// in a row is reported once, so the status frame says why the base does not get
    /// ready (unpowered, unplugged, wrong address or baud rate).
    async fn poll_until_both_answer(&mut self) {
        let mut silent_polls = [0u8; WHEELS.len()];
        loop {
            let mut answering = 0;
            for (index, wheel) in WHEELS.into_iter().enumerate() {
                if self.probe(wheel).await != Probe::Silent {
                    answering += 1;
                    silent_polls[index] = 0;
                    continue;
                }
                silent_polls[index] = silent_polls[index].saturating_add(1);
                if silent_polls[index] == self.settings.failures_before_loss {
                    warn!("{} drive does not answer", wheel);
                    self.report(Input::DriveSilent(wheel)).await;
                }
            }
            if answering == WHEELS.len() {
                return;
            }
            self.pause().await;
        }
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
                        if self.find_lost_drives().await {
                            return;
                        }
                        failures = 0;
                    }
                }
            }
            let period = Duration::from_millis(u64::from(self.demand.cycle_ms.max(1)));
            next = (next + period).max(Instant::now());
            let mut wake = next;
            if self.excited && self.settled_at > Instant::now() {
                wake = wake.min(self.settled_at);
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

    /// After a loss: commands what the supervisor demands (zero by then) to the drives
    /// that still answer with their setup, and polls, until a setup is requested.
    async fn hold_until_setup_requested(&mut self) {
        while !self.setup_requested() {
            for wheel in WHEELS {
                if self.probe(wheel).await == Probe::Ready {
                    // Best effort: a failure shows in the next probe.
                    let _ = self.command_one(wheel).await;
                }
            }
            self.pause().await;
        }
    }

    /// Unicast speed command to one drive, outside the share group.
    async fn command_one(&mut self, wheel: Wheel) -> Result<(), LinkError> {
        let command = self.demand.wheels;
        let (rpm, accel) = match wheel {
            Wheel::Left => (command.rpm.left, command.left_accel),
            Wheel::Right => (command.rpm.right, command.right_accel),
        };
        let rpm = if self.excited { rpm } else { 0 };
        let accel = self.settings.accel_unit.field(accel);
        let slave = self.slave(wheel);
        self.write(slave, reg::DDO_SPEED, &[rpm as u32, accel, accel])
            .await?;
        self.write(slave, reg::DDO_TRIGGER, &[1]).await
    }
}

/// Oriental alarm codes are one byte (e.g. 84h); the register is 32 bits wide.
fn alarm_byte(code: u32) -> u8 {
    u8::try_from(code).unwrap_or(u8::MAX)
}
