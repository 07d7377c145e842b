//! Every channel between the tasks, in one place. Each field says who sends, who
//! receives, and why that primitive. The message types live beside the task that
//! consumes them; each task receives only the ends it uses (the `*_ends` methods), so
//! its signature shows its place in the topology.
//!
//! The mutex kind and the controller's input queue, which every task names, live in
//! [`crate::sync`]: the tasks import them from there and the hub imports the tasks'
//! types, so no import runs both ways.

use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;

use base_core::controller::Input;
use base_core::hid::light_bar::BaseLight;

use crate::ble::{RemoteEnds, RemoteRequest};
use crate::can::FrameQueue;
use crate::control::ControlEnds;
use crate::drive_link::{DriveBrakes, DriveDemand, DriveLinkEnds};
use crate::liveness::Liveness;
use crate::store::PendingWrites;
use crate::sync::{INPUT_QUEUE, RawMutex};
use crate::update::UpdateLink;

pub struct Channels {
    /// CAN RX, drive link, sensors, inputs, remote → controller. A queue because every
    /// event counts and order matters (an e-stop edge must not be overtaken). Senders
    /// await room; the controller only computes, so it drains faster than anyone fills.
    pub inputs: Channel<RawMutex, Input, INPUT_QUEUE>,
    /// Controller and update task → CAN TX. Two classes the senders never wait on:
    /// the periodic feedback frames (one slot per ID, sent first, so that no reply
    /// traffic drops or delays them) and replies (a queue in order; when the bus is
    /// slow or off and it is full, the reply is dropped and counted, because control
    /// must go on).
    pub can_tx: FrameQueue,
    /// Controller → drive link. A signal (latest value wins), because the demand is a
    /// state, not an event: only the newest setpoint matters, and the link must never
    /// work through stale ones.
    pub drive_demand: Signal<RawMutex, DriveDemand>,
    /// Drive link → controller: both drives confirmed de-excited. A flag, because it
    /// is a state the controller reads before each input (status frame, flash gate).
    pub drive_brakes: DriveBrakes,
    /// Controller → register store. Coalescing dirty marks, because flash writes are
    /// slow (an erase takes tens of ms) and the controller must never wait for them,
    /// yet no change may be lost: a value written twice is stored once, with its
    /// latest value. Its at-rest gate also holds back the Bluetooth task's bond writes:
    /// flash is written only while the base stands.
    pub pending_writes: PendingWrites,
    /// Critical tasks → liveness task: check-in marks behind the watchdog.
    pub liveness: Liveness,
    /// Controller → Bluetooth remote task. A signal (latest value wins): the request is
    /// a state (is the pairing window open, how many disconnects were asked for), and
    /// the remote task acts on the newest.
    pub remote_requests: Signal<RawMutex, RemoteRequest>,
    /// CAN RX → update task: the update's frames, in a queue of their own so that an
    /// image transfer never delays the controller's inputs. Update task → controller:
    /// the motion lock; controller → update task: the motion gate (flags read before
    /// and set after each input, as the brakes flag).
    pub update: UpdateLink,
    /// Controller → PlayStation pad task: the base's mode as the pad's light bar shows
    /// it, published on change. A signal of its own (latest value wins) rather than a
    /// field of the remote request, which would wake the BLE task on every mode change.
    pub base_light: Signal<RawMutex, BaseLight>,
}

impl Channels {
    pub const fn new() -> Self {
        Self {
            inputs: Channel::new(),
            can_tx: FrameQueue::new(),
            drive_demand: Signal::new(),
            drive_brakes: DriveBrakes::new(),
            pending_writes: PendingWrites::new(),
            liveness: Liveness::new(),
            remote_requests: Signal::new(),
            update: UpdateLink::new(),
            base_light: Signal::new(),
        }
    }

    /// The controller task's ends: it receives every input and feeds everyone else.
    pub fn control_ends(&self) -> ControlEnds<'_> {
        ControlEnds {
            inputs: self.inputs.receiver(),
            can_tx: &self.can_tx,
            drive_demand: &self.drive_demand,
            pending_writes: &self.pending_writes,
            drive_brakes: &self.drive_brakes,
            remote_requests: &self.remote_requests,
            base_light: &self.base_light,
            liveness: &self.liveness,
            update: &self.update,
        }
    }

    /// The drive link's ends: the demand in, feedback out, and its check-in.
    pub fn drive_link_ends(&self) -> DriveLinkEnds<'_> {
        DriveLinkEnds {
            drive_demand: &self.drive_demand,
            inputs: self.inputs.sender(),
            drive_brakes: &self.drive_brakes,
            liveness: &self.liveness,
        }
    }

    /// The Bluetooth remote's ends: the controller's requests in, pad reports out.
    pub fn remote_ends(&self) -> RemoteEnds<'_> {
        RemoteEnds {
            remote_requests: &self.remote_requests,
            inputs: self.inputs.sender(),
            flash_gate: &self.pending_writes,
            base_light: &self.base_light,
        }
    }
}

impl Default for Channels {
    fn default() -> Self {
        Self::new()
    }
}
