//! The CAN tasks: receive frames into the input queue, and send what the controller
//! queued. A bus-off is reported and recovered from here; the controller never waits
//! for the bus.

use core::cell::Cell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::channel::Channel;
use embassy_time::Timer;

use base_core::can::RawFrame;
use base_core::controller::Input;

use crate::channels::{InputSender, RawMutex};
use crate::hw::{BusState, CanError, CanRx, CanTx};
use crate::update::UpdateLink;

/// Frames the transmit queue holds. A PC may send a burst of register reads at once,
/// and every reply is queued at once, while the bus sends one frame per ~0.2 ms: the
/// queue holds a burst of 24 replies plus one of each periodic frame (position,
/// heading, battery, weight, status), with three to spare. A longer burst loses
/// replies, counted in `can_tx_dropped` (register 43). 32 frames of 16 bytes.
pub const CAN_TX_QUEUE: usize = 32;

/// The frames waiting for the CAN TX task, in order. Senders never wait: a full queue
/// drops the frame and counts it.
pub struct FrameQueue {
    frames: Channel<RawMutex, RawFrame, CAN_TX_QUEUE>,
    dropped: Mutex<RawMutex, Cell<u32>>,
}

impl FrameQueue {
    pub const fn new() -> Self {
        Self {
            frames: Channel::new(),
            dropped: Mutex::new(Cell::new(0)),
        }
    }

    /// Queues a frame for sending without waiting; a full queue drops it.
    pub fn send(&self, frame: RawFrame) {
        if self.frames.try_send(frame).is_err() {
            self.dropped
                .lock(|dropped| dropped.set(dropped.get().wrapping_add(1)));
        }
    }

    /// Frames dropped because the queue was full.
    pub fn dropped(&self) -> u32 {
        self.dropped.lock(Cell::get)
    }
}

impl Default for FrameQueue {
    fn default() -> Self {
        Self::new()
    }
}

/// After a receive error, wait this long before the next attempt, so a controller
/// that keeps failing cannot starve the other tasks.
const ERROR_BACKOFF_MS: u64 = 10;

pub async fn run_rx<R: CanRx>(mut rx: R, inputs: InputSender<'_>, update: &UpdateLink) -> ! {
    loop {
        match rx.receive().await {
            Ok(frame) => {
                // Extended and remote frames are not part of the protocol.
                match RawFrame::from_frame(&frame) {
                    Some(raw) if UpdateLink::takes(raw.id()) => update.offer(raw),
                    Some(raw) => inputs.send(Input::CanFrame(raw)).await,
                    None => {}
                }
            }
            Err(error) => {
                if matches!(error, CanError::Overrun | CanError::BusOff) {
                    inputs.send(Input::CanBusFault).await;
                }
                Timer::after_millis(ERROR_BACKOFF_MS).await;
            }
        }
    }
}

pub async fn run_tx<T: CanTx>(mut tx: T, queue: &FrameQueue, inputs: InputSender<'_>) -> ! {
    loop {
        let raw = queue.frames.receive().await;
        if tx.state() == BusState::Off {
            recover(&mut tx, inputs).await;
        }
        let Some(frame) = raw.to_frame::<T::Frame>() else {
            continue;
        };
        if let Err(CanError::BusOff) = tx.transmit(&frame).await {
            // This frame is lost with the bus; the next period sends fresh values.
            recover(&mut tx, inputs).await;
        }
    }
}

async fn recover<T: CanTx>(tx: &mut T, inputs: InputSender<'_>) {
    warn!("CAN bus-off: recovering");
    inputs.send(Input::CanBusFault).await;
    tx.recover().await;
    info!("CAN back on the bus");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_queue_drops_and_counts_instead_of_waiting() {
        let queue = FrameQueue::new();
        let frame = RawFrame::new(0x0EC, &[0; 8]).expect("valid frame");
        for _ in 0..CAN_TX_QUEUE + 3 {
            queue.send(frame);
        }
        assert_eq!(queue.dropped(), 3);
    }
}
