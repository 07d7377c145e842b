//! Every channel between the tasks, in one place. Each line says who sends, who
//! receives, and why that primitive.
//!
//! The tasks share one executor, so a critical-section mutex costs almost nothing;
//! it is still the right one because the BLE task (issue 5) may run on another
//! executor or interrupt priority.

use core::cell::{Cell, RefCell};

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use heapless::Vec;

use crate::can::RawFrame;
use crate::controller::{Input, Persist};
use crate::kinematics::{MotorRpm, WheelCommand};

pub type RawMutex = CriticalSectionRawMutex;

/// Room for bursts: a CAN burst of commands plus a drive cycle's worth of feedback.
pub const INPUT_QUEUE: usize = 32;
/// Two status periods' worth of reports at the default periods.
pub const CAN_TX_QUEUE: usize = 16;

pub struct Channels {
    /// CAN RX, drive link, sensors, inputs, remote → controller. A queue because every
    /// event counts and order matters (an e-stop edge must not be overtaken). Senders
    /// await room; the controller only computes, so it drains faster than anyone fills.
    pub inputs: Channel<RawMutex, Input, INPUT_QUEUE>,
    /// Controller → CAN TX. A queue of frames in order. The controller never waits on
    /// it: when the bus is slow or off and the queue is full, the frame is dropped and
    /// counted in [`Channels::can_tx_dropped`], because control must go on.
    pub can_tx: Channel<RawMutex, RawFrame, CAN_TX_QUEUE>,
    /// Controller → drive link. A signal (latest value wins), because the demand is a
    /// state, not an event: only the newest setpoint matters, and the link must never
    /// work through stale ones.
    pub drive_demand: Signal<RawMutex, DriveDemand>,
    /// Controller → register store. Coalescing dirty marks, because flash writes are
    /// slow (an erase takes tens of ms) and the controller must never wait for them,
    /// yet no change may be lost: a value written twice is stored once, with its
    /// latest value.
    pub pending_writes: PendingWrites,
    /// Critical tasks → liveness task: check-in marks behind the watchdog.
    pub liveness: Liveness,
    /// Controller → Bluetooth remote task. A signal (latest value wins): the request is
    /// a state (is the pairing window open, how many disconnects were asked for), and
    /// the remote task acts on the newest.
    pub remote_requests: Signal<RawMutex, RemoteRequest>,
    can_tx_dropped: Mutex<RawMutex, Cell<u32>>,
}

impl Channels {
    pub const fn new() -> Self {
        Self {
            inputs: Channel::new(),
            can_tx: Channel::new(),
            drive_demand: Signal::new(),
            pending_writes: PendingWrites::new(),
            liveness: Liveness::new(),
            remote_requests: Signal::new(),
            can_tx_dropped: Mutex::new(Cell::new(0)),
        }
    }

    /// Queues a frame for sending without waiting; a full queue drops it.
    pub fn send_frame(&self, frame: RawFrame) {
        if self.can_tx.try_send(frame).is_err() {
            self.can_tx_dropped
                .lock(|dropped| dropped.set(dropped.get().wrapping_add(1)));
        }
    }

    /// Frames dropped because the CAN TX queue was full.
    pub fn can_tx_dropped(&self) -> u32 {
        self.can_tx_dropped.lock(Cell::get)
    }
}

/// What the controller asks of the Bluetooth remote task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RemoteRequest {
    /// A new pad may be paired (and replace the bonded one) while this is true.
    pub pairing_open: bool,
    /// Counts the controller's requests to switch the pad off; a change means "drop the
    /// link now" (a counter, so two requests in a row are not merged into one state).
    pub disconnects: u16,
}

impl Default for Channels {
    fn default() -> Self {
        Self::new()
    }
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

/// Register values the store has yet to write.
pub struct PendingWrites {
    state: Mutex<RawMutex, RefCell<Dirty>>,
    wake: Signal<RawMutex, ()>,
}

/// Registers live at addresses below 64, so one bit each marks a pending value.
struct Dirty {
    restore_defaults: bool,
    marks: u64,
    values: [u16; 64],
}

/// Everything pending at one moment, in the order the store must apply it.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PendingBatch {
    /// Erase every stored value first.
    pub restore_defaults: bool,
    /// Then store these (address, value) pairs.
    pub writes: Vec<(u8, u16), 64>,
}

impl PendingWrites {
    pub const fn new() -> Self {
        Self {
            state: Mutex::new(RefCell::new(Dirty {
                restore_defaults: false,
                marks: 0,
                values: [0; 64],
            })),
            wake: Signal::new(),
        }
    }

    /// Marks what the controller changed. Never waits.
    pub fn record(&self, persist: &Persist) {
        if !persist.defaults_restored && persist.changed.is_empty() {
            return;
        }
        self.state.lock(|state| {
            let mut state = state.borrow_mut();
            if persist.defaults_restored {
                // Later writes go on top of the defaults; earlier ones are void.
                state.restore_defaults = true;
                state.marks = 0;
            }
            for &(address, value) in &persist.changed {
                let slot = usize::from(address);
                debug_assert!(slot < 64, "register address {address} out of the map");
                if slot < 64 {
                    state.marks |= 1 << slot;
                    state.values[slot] = value;
                }
            }
        });
        self.wake.signal(());
    }

    /// Waits until something is pending and takes all of it.
    pub async fn take(&self) -> PendingBatch {
        loop {
            let batch = self.state.lock(|state| {
                let mut state = state.borrow_mut();
                let mut batch = PendingBatch {
                    restore_defaults: core::mem::take(&mut state.restore_defaults),
                    writes: Vec::new(),
                };
                let mut marks = core::mem::take(&mut state.marks);
                while marks != 0 {
                    let slot = marks.trailing_zeros() as usize;
                    marks &= marks - 1;
                    // 64 slots fit a 64-entry batch.
                    let _ = batch.writes.push((slot as u8, state.values[slot]));
                }
                batch
            });
            if batch.restore_defaults || !batch.writes.is_empty() {
                return batch;
            }
            self.wake.wait().await;
        }
    }
}

impl Default for PendingWrites {
    fn default() -> Self {
        Self::new()
    }
}

/// The tasks whose silence means the firmware hangs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CriticalTask {
    Controller = 0,
    DriveLink = 1,
    Inputs = 2,
}

impl CriticalTask {
    pub const ALL: [CriticalTask; 3] = [Self::Controller, Self::DriveLink, Self::Inputs];
    const fn bit(self) -> u8 {
        1 << self as u8
    }
}

/// Check-in marks: each critical task marks itself on every loop; the liveness task
/// feeds the watchdog only when all marks are set, then clears them.
pub struct Liveness {
    marks: Mutex<RawMutex, Cell<u8>>,
}

impl Liveness {
    pub const fn new() -> Self {
        Self {
            marks: Mutex::new(Cell::new(0)),
        }
    }

    pub fn check_in(&self, task: CriticalTask) {
        self.marks.lock(|marks| marks.set(marks.get() | task.bit()));
    }

    /// True if every critical task checked in since the last call; clears the marks.
    pub fn all_checked_in(&self) -> bool {
        let all = CriticalTask::ALL
            .iter()
            .fold(0, |bits, task| bits | task.bit());
        self.marks.lock(|marks| marks.replace(0)) & all == all
    }
}

impl Default for Liveness {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_futures::block_on;

    fn persist(changed: &[(u8, u16)], defaults_restored: bool) -> Persist {
        Persist {
            changed: Vec::from_slice(changed).expect("fits"),
            defaults_restored,
        }
    }

    #[test]
    fn repeated_writes_coalesce_to_the_latest_value_in_address_order() {
        let pending = PendingWrites::new();
        pending.record(&persist(&[(11, 500), (3, 7)], false));
        pending.record(&persist(&[(11, 900)], false));
        let batch = block_on(pending.take());
        assert!(!batch.restore_defaults);
        assert_eq!(batch.writes[..], [(3, 7), (11, 900)]);
    }

    #[test]
    fn a_restore_voids_earlier_writes_and_keeps_later_ones() {
        let pending = PendingWrites::new();
        pending.record(&persist(&[(11, 500)], false));
        pending.record(&persist(&[], true));
        pending.record(&persist(&[(12, 2_000)], false));
        let batch = block_on(pending.take());
        assert!(batch.restore_defaults);
        assert_eq!(batch.writes[..], [(12, 2_000)]);
    }

    #[test]
    fn nothing_recorded_means_nothing_to_take() {
        let pending = PendingWrites::new();
        pending.record(&persist(&[], false));
        let mut take = core::pin::pin!(pending.take());
        let waker = core::task::Waker::noop();
        let poll = take
            .as_mut()
            .poll(&mut core::task::Context::from_waker(waker));
        assert!(poll.is_pending());
    }

    #[test]
    fn the_watchdog_is_fed_only_when_every_critical_task_checked_in() {
        let liveness = Liveness::new();
        liveness.check_in(CriticalTask::Controller);
        liveness.check_in(CriticalTask::Inputs);
        assert!(!liveness.all_checked_in(), "the drive link is missing");
        for task in CriticalTask::ALL {
            liveness.check_in(task);
        }
        assert!(liveness.all_checked_in());
        assert!(!liveness.all_checked_in(), "the marks were cleared");
    }

    #[test]
    fn a_full_can_queue_drops_and_counts_instead_of_waiting() {
        let channels = Channels::new();
        let frame = RawFrame::new(0x0EC, &[0; 8]).expect("valid frame");
        for _ in 0..CAN_TX_QUEUE + 3 {
            channels.send_frame(frame);
        }
        assert_eq!(channels.can_tx_dropped(), 3);
    }
}
