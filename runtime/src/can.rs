//! The CAN tasks: receive frames into the input queue, and send what the controller
//! queued. A bus-off is reported and recovered from here; the controller never waits
//! for the bus.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::Timer;
use heapless::Deque;

use base_core::can::{BULK_READ_MAX, RawFrame, id};
use base_core::controller::Input;

use crate::hw::{BusState, CanError, CanRx, CanTx};
use crate::sync::{InputSender, RawMutex};
use crate::update::UpdateLink;

/// Replies the transmit queue holds: register replies and the update task's replies.
/// A PC may send a burst of register reads at once and every reply is queued at once,
/// while the bus sends one frame per ~0.2 ms: a burst of 32 is answered in full. A
/// longer burst, or requests coming faster than the bus carries their replies, loses
/// the replies that find the queue full, counted in `can_tx_dropped` (register 43).
/// 32 frames of 16 bytes.
pub const REPLY_QUEUE: usize = 32;

/// Bulk-read replies the transmit queue holds: two whole batches
/// ([`BULK_READ_MAX`] each), 16 frames of 16 bytes.
pub const BULK_QUEUE: usize = 2 * BULK_READ_MAX as usize;

/// The frames waiting for the CAN TX task, in two classes. The periodic feedback frames
/// ([`id::FEEDBACK`]) have one slot per ID and always go first: a reply never drops
/// or delays them beyond the one frame already on its way to the wire. Replies wait in
/// a queue of their own, in order. Senders never wait: a reply that finds its queue
/// full is dropped and counted, and a feedback frame replaces an older one of its ID
/// that is still waiting (the bus was off or full of other nodes' frames for a whole
/// period), which counts as dropped too. The newer frame goes behind the others that
/// fell due, so frames that belong together leave in the order they were sent: a pose
/// time (0x0EF) never goes out after the pose of the next cycle.
///
/// The replies to bulk register reads wait apart, as whole batches, and take turns
/// with the single replies: programs that flood the bus with single reads keep the
/// reply queue full, and a batch that had to find room there would never fit, or would
/// wait behind their whole backlog. A batch that finds no room for all its replies is
/// dropped whole, so a reader never waits for a reply that will not come.
pub struct FrameQueue {
    queued: Mutex<RawMutex, RefCell<Queued>>,
    /// Set by every send; the TX task waits on it when both classes are empty.
    queued_signal: Signal<RawMutex, ()>,
}

struct Queued {
    /// At most one frame per feedback ID, in the order they fell due (a replaced
    /// frame's successor counts as falling due when it is sent).
    feedback: Deque<RawFrame, { id::FEEDBACK.len() }>,
    replies: Deque<RawFrame, REPLY_QUEUE>,
    bulk_replies: Deque<RawFrame, BULK_QUEUE>,
    /// The next reply comes from the bulk batches if both classes wait.
    bulk_turn: bool,
    dropped: u32,
}

impl Queued {
    fn push(&mut self, frame: RawFrame) {
        let pushed = if id::is_feedback(frame.id()) {
            // The newest value replaces a waiting older one (the PC should get the
            // newest), but at the back: had it kept the older one's place, a cycle
            // whose first frame already left would go out as the next cycle's frames
            // followed by its own, pairing the pose time with the wrong pose.
            let replaced = self
                .feedback
                .iter()
                .any(|waiting| waiting.id() == frame.id());
            if replaced {
                let mut kept = Deque::new();
                for waiting in self
                    .feedback
                    .iter()
                    .filter(|waiting| waiting.id() != frame.id())
                {
                    // Fewer than before: there is room.
                    let _ = kept.push_back(*waiting);
                }
                self.feedback = kept;
            }
            // One slot per feedback ID: there is always room.
            self.feedback.push_back(frame).is_ok() && !replaced
        } else {
            self.replies.push_back(frame).is_ok()
        };
        if !pushed {
            self.dropped = self.dropped.wrapping_add(1);
        }
    }

    fn push_batch(&mut self, frames: &[RawFrame]) {
        if BULK_QUEUE - self.bulk_replies.len() < frames.len() {
            self.dropped = self.dropped.wrapping_add(frames.len() as u32);
            return;
        }
        for frame in frames {
            // Room was checked above.
            let _ = self.bulk_replies.push_back(*frame);
        }
    }

    fn pop(&mut self) -> Option<RawFrame> {
        if let Some(frame) = self.feedback.pop_front() {
            return Some(frame);
        }
        let from_bulk =
            !self.bulk_replies.is_empty() && (self.bulk_turn || self.replies.is_empty());
        let frame = if from_bulk {
            self.bulk_replies.pop_front()
        } else {
            self.replies.pop_front()
        };
        if frame.is_some() {
            self.bulk_turn = !from_bulk;
        }
        frame
    }
}

impl FrameQueue {
    pub const fn new() -> Self {
        Self {
            queued: Mutex::new(RefCell::new(Queued {
                feedback: Deque::new(),
                replies: Deque::new(),
                bulk_replies: Deque::new(),
                bulk_turn: false,
                dropped: 0,
            })),
            queued_signal: Signal::new(),
        }
    }

    /// Queues a frame for sending without waiting, in its class by its ID.
    pub fn send(&self, frame: RawFrame) {
        self.queued.lock(|queued| queued.borrow_mut().push(frame));
        self.queued_signal.signal(());
    }

    /// Queues the replies to one bulk read together, or drops and counts them all
    /// when the bulk queue has no room for all of them.
    pub fn send_batch(&self, frames: &[RawFrame]) {
        self.queued
            .lock(|queued| queued.borrow_mut().push_batch(frames));
        self.queued_signal.signal(());
    }

    /// Frames dropped since boot: replies that found their queue full (a bulk read's
    /// batch counts each of its replies), and feedback frames replaced by a newer one
    /// before they were sent.
    pub fn dropped(&self) -> u32 {
        self.queued.lock(|queued| queued.borrow().dropped)
    }

    /// The frame to send next: feedback before replies.
    fn take(&self) -> Option<RawFrame> {
        self.queued.lock(|queued| queued.borrow_mut().pop())
    }

    /// Waits for the frame to send next.
    async fn next(&self) -> RawFrame {
        loop {
            if let Some(frame) = self.take() {
                return frame;
            }
            self.queued_signal.wait().await;
        }
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
        // Chosen only once the previous frame has left, so that a feedback frame that
        // falls due meanwhile goes next.
        let raw = queue.next().await;
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

    fn reply(address: u8) -> RawFrame {
        RawFrame::new(id::REGISTER_READ, &[0, 0, 1, address, 0, 0]).expect("valid frame")
    }

    fn feedback(frame_id: u16, first: u8) -> RawFrame {
        RawFrame::new(frame_id, &[first; 8]).expect("valid frame")
    }

    fn drain(queue: &FrameQueue) -> Vec<RawFrame> {
        core::iter::from_fn(|| queue.take()).collect()
    }

    #[test]
    fn a_full_reply_queue_drops_and_counts_instead_of_waiting() {
        let queue = FrameQueue::new();
        for address in 0..REPLY_QUEUE as u8 + 3 {
            queue.send(reply(address));
        }
        assert_eq!(queue.dropped(), 3);
        // The first ones stay, in order.
        let sent = drain(&queue);
        assert_eq!(sent.len(), REPLY_QUEUE);
        assert_eq!(sent[0], reply(0));
        assert_eq!(sent[REPLY_QUEUE - 1], reply(REPLY_QUEUE as u8 - 1));
    }

    fn bulk_batch(tag: u8) -> [RawFrame; BULK_READ_MAX as usize] {
        core::array::from_fn(|i| {
            RawFrame::new(id::REGISTER_READ, &[0, 0, 1, i as u8, 0, tag]).expect("valid frame")
        })
    }

    #[test]
    fn a_bulk_batch_gets_in_beside_a_full_reply_queue_and_takes_turns_with_it() {
        let queue = FrameQueue::new();
        for address in 0..REPLY_QUEUE as u8 {
            queue.send(reply(address));
        }
        let batch = bulk_batch(1);
        queue.send_batch(&batch);
        assert_eq!(queue.dropped(), 0);
        let sent = drain(&queue);
        let bulk_positions: Vec<usize> = sent
            .iter()
            .enumerate()
            .filter(|(_, frame)| batch.contains(frame))
            .map(|(position, _)| position)
            .collect();
        // Reply, bulk, reply, bulk...: the batch is out after 16 frames, not 40.
        assert_eq!(bulk_positions, [1, 3, 5, 7, 9, 11, 13, 15]);
        assert_eq!(sent.len(), REPLY_QUEUE + batch.len());
        assert_eq!(sent[0], reply(0), "the single replies keep their order");
        assert_eq!(sent[2], reply(1));
    }

    #[test]
    fn a_bulk_batch_without_room_for_all_its_replies_is_dropped_whole_and_counted() {
        let queue = FrameQueue::new();
        queue.send_batch(&bulk_batch(1));
        queue.send_batch(&bulk_batch(2));
        queue.send_batch(&bulk_batch(3));
        assert_eq!(queue.dropped(), u32::from(BULK_READ_MAX));
        let sent = drain(&queue);
        assert_eq!(sent[..8], bulk_batch(1));
        assert_eq!(sent[8..], bulk_batch(2));
    }

    #[test]
    fn feedback_frames_go_before_waiting_replies_and_a_full_reply_queue_drops_none_of_them() {
        let queue = FrameQueue::new();
        for address in 0..REPLY_QUEUE as u8 + 10 {
            queue.send(reply(address));
        }
        let due = id::FEEDBACK.map(|frame_id| feedback(frame_id, 1));
        for frame in due {
            queue.send(frame);
        }
        queue.send(reply(99));
        assert_eq!(
            queue.dropped(),
            11,
            "the replies beyond the queue, no feedback"
        );
        let sent = drain(&queue);
        assert_eq!(
            sent[..due.len()],
            due,
            "every feedback frame first, in order"
        );
        assert_eq!(sent[due.len()], reply(0));
        assert_eq!(sent.len(), due.len() + REPLY_QUEUE);
    }

    #[test]
    fn a_cycle_whose_pose_time_already_left_is_replaced_whole_and_in_order() {
        let queue = FrameQueue::new();
        queue.send(feedback(id::POSE_TIME, 1));
        queue.send(feedback(id::POSITION, 1));
        queue.send(feedback(id::HEADING, 1));
        // The bus took only the pose time before the next cycle fell due.
        assert_eq!(queue.take(), Some(feedback(id::POSE_TIME, 1)));
        queue.send(feedback(id::POSE_TIME, 2));
        queue.send(feedback(id::POSITION, 2));
        queue.send(feedback(id::HEADING, 2));
        assert_eq!(queue.dropped(), 2);
        assert_eq!(
            drain(&queue),
            [
                feedback(id::POSE_TIME, 2),
                feedback(id::POSITION, 2),
                feedback(id::HEADING, 2)
            ],
            "cycle 2's pose time before cycle 2's pose"
        );
    }

    #[test]
    fn a_feedback_frame_not_yet_sent_is_replaced_by_the_next_of_its_id() {
        let queue = FrameQueue::new();
        queue.send(feedback(id::POSITION, 1));
        queue.send(feedback(id::HEADING, 1));
        queue.send(feedback(id::POSITION, 2));
        queue.send(feedback(id::HEADING, 2));
        assert_eq!(queue.dropped(), 2);
        assert_eq!(
            drain(&queue),
            [feedback(id::POSITION, 2), feedback(id::HEADING, 2)]
        );
    }
}
