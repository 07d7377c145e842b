//! What every task and the channel hub name alike: the mutex kind of the channels and
//! the controller's input queue. A leaf module, so that the tasks import these from
//! here while the hub (`channels`) imports the tasks' types.
//!
//! The tasks share one executor, so a critical-section mutex costs almost nothing; it
//! is still the right one because the BLE task may run on another executor or
//! interrupt priority.

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::{Receiver, Sender};

use base_core::controller::Input;

pub type RawMutex = CriticalSectionRawMutex;

/// Room for bursts: a CAN burst of commands plus a drive cycle's worth of feedback.
pub const INPUT_QUEUE: usize = 32;

/// Where every task sends what the controller must hear of.
pub type InputSender<'a> = Sender<'a, RawMutex, Input, INPUT_QUEUE>;
pub type InputReceiver<'a> = Receiver<'a, RawMutex, Input, INPUT_QUEUE>;
