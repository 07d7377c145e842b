//! The PC's frames on their way to the wire. Each of the PC's nodes (the SLCAN adapter,
//! each socketcand client, the SocketCAN interface) has a queue of its own, and the
//! wire takes one frame from each node that has one, in turn. A node may have at most
//! [`NODE_TRANSMIT_QUEUE`] frames waiting: a socketcand client or the SocketCAN reader
//! holds a [`CreditToken`] for each, and its thread waits for a token before it hands
//! over the next frame (so a program that sends faster than the bus carries its frames
//! stops being read, and TCP holds it back); the hub stops reading the serial port
//! while the SLCAN queue is full.
//!
//! So a program that floods the bus slows down only itself: the frames of the others
//! wait behind one frame of it, not behind its backlog. A real CAN interface has one
//! transmit queue for all the programs of its PC, and a full one refuses their frames
//! (Linux: `ENOBUFS`); the simulator serves each program in turn instead of dropping
//! what does not fit.

use core::future::poll_fn;
use core::task::Poll;
use std::cell::RefCell;
use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, PoisonError};

use embassy_sync::waitqueue::WakerRegistration;

/// Frames one PC node may have waiting for the wire: a firmware update's 24 frames of
/// credit and its commands fit.
pub const NODE_TRANSMIT_QUEUE: usize = 32;

/// How many more frames a node may hand over; shared by the node's reader thread,
/// which takes, and the wire, which gives back when a frame has left.
#[derive(Debug)]
pub struct NodeCredit {
    free: Mutex<usize>,
    freed: Condvar,
}

impl NodeCredit {
    pub fn new(frames: usize) -> Arc<Self> {
        Arc::new(Self {
            free: Mutex::new(frames),
            freed: Condvar::new(),
        })
    }

    /// Waits until the node may hand over one more frame. For the node's own thread,
    /// never for the hub.
    pub fn take(self: &Arc<Self>) -> CreditToken {
        let mut free = self.free.lock().unwrap_or_else(PoisonError::into_inner);
        while *free == 0 {
            free = self
                .freed
                .wait(free)
                .unwrap_or_else(PoisonError::into_inner);
        }
        *free -= 1;
        CreditToken(Arc::clone(self))
    }
}

/// One frame's place in its node's queue, given back when dropped: after the frame has
/// left the wire, or with the frame when it is lost on the way.
#[derive(Debug)]
pub struct CreditToken(Arc<NodeCredit>);

impl Drop for CreditToken {
    fn drop(&mut self) {
        let mut free = self.0.free.lock().unwrap_or_else(PoisonError::into_inner);
        *free += 1;
        self.0.freed.notify_one();
    }
}

/// Each node's frames in order, the nodes in turn.
pub struct WireQueues<N, T> {
    /// The nodes with frames waiting; the front one goes next.
    nodes: RefCell<VecDeque<(N, VecDeque<T>)>>,
    waiting: RefCell<WakerRegistration>,
}

impl<N: Copy + PartialEq, T> WireQueues<N, T> {
    pub fn new() -> Self {
        Self {
            nodes: RefCell::new(VecDeque::new()),
            waiting: RefCell::new(WakerRegistration::new()),
        }
    }

    /// Queues `item` behind the other frames of `node`.
    pub fn push(&self, node: N, item: T) {
        let mut nodes = self.nodes.borrow_mut();
        match nodes.iter_mut().find(|(waiting, _)| *waiting == node) {
            Some((_, items)) => items.push_back(item),
            None => nodes.push_back((node, VecDeque::from([item]))),
        }
        self.waiting.borrow_mut().wake();
    }

    /// How many frames of `node` wait.
    pub fn waiting(&self, node: N) -> usize {
        self.nodes
            .borrow()
            .iter()
            .find(|(waiting, _)| *waiting == node)
            .map_or(0, |(_, items)| items.len())
    }

    /// The next frame for the wire, if any: the oldest of the node whose turn it is.
    pub fn pop(&self) -> Option<(N, T)> {
        let mut nodes = self.nodes.borrow_mut();
        let (node, mut items) = nodes.pop_front()?;
        let item = items.pop_front()?;
        if !items.is_empty() {
            nodes.push_back((node, items));
        }
        Some((node, item))
    }

    /// Waits for the next frame for the wire.
    pub async fn next(&self) -> (N, T) {
        poll_fn(|cx| match self.pop() {
            Some(next) => Poll::Ready(next),
            None => {
                self.waiting.borrow_mut().register(cx.waker());
                Poll::Pending
            }
        })
        .await
    }
}

impl<N: Copy + PartialEq, T> Default for WireQueues<N, T> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::thread;
    use std::time::Duration;

    #[test]
    fn a_node_with_a_backlog_takes_turns_with_a_node_that_sends_one_frame() {
        let queues = WireQueues::new();
        for frame in 0..10 {
            queues.push('a', frame);
        }
        queues.push('b', 100);
        queues.push('c', 200);
        queues.push('b', 101);
        let order: Vec<(char, i32)> = core::iter::from_fn(|| queues.pop()).collect();
        assert_eq!(
            order[..6],
            [
                ('a', 0),
                ('b', 100),
                ('c', 200),
                ('a', 1),
                ('b', 101),
                ('a', 2)
            ]
        );
        assert_eq!(order.len(), 13);
        assert_eq!(queues.waiting('a'), 0);
    }

    #[test]
    fn a_node_without_credit_waits_until_one_of_its_frames_has_left() {
        let credit = NodeCredit::new(2);
        let first = credit.take();
        let _second = credit.take();
        let waiting = Arc::clone(&credit);
        let third = thread::spawn(move || {
            let _token = waiting.take();
        });
        thread::sleep(Duration::from_millis(50));
        assert!(
            !third.is_finished(),
            "a third frame was taken without credit"
        );
        drop(first);
        third
            .join()
            .expect("the third frame is taken once the first has left");
    }
}
