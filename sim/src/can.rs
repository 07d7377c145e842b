//! A virtual CAN bus between the firmware's CAN controller ([`CanRxPort`],
//! [`CanTxPort`]) and the robot PC ([`CanPeer`]), which the test script plays.
//!
//! Frames the firmware sends take their time on the wire (500 kbit/s, see
//! [`frame_time`]), so a transmit queue can fill. The PC has two ways to send: a test
//! script's [`CanPeer::send`] arrives at once, because the script decides when it was
//! sent; [`CanPeer::transmit`], which the simulator's PC programs use, takes its bus
//! time like the firmware's frames. Both kinds of timed frame share one wire, one frame
//! after the other, so a PC streaming data slows the firmware's frames down and the
//! other way round (in the order they were offered: the bus arbitrates between frames
//! waiting at the same moment by ID, which the simulator does not model). Faults are
//! injected from the PC's side: bus-off, receive overrun and bus errors, error-passive.
//! Everything shares one thread and the clock of [`crate::runtime`].

use core::future::poll_fn;
use core::task::Poll;
use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;

use base_runtime::hw::{BusState, CanError, CanRx, CanTx};
use embassy_sync::waitqueue::WakerRegistration;
use embassy_time::{Duration, Instant, Timer};
use embedded_can::{Frame, Id, StandardId};

/// The bus speed of the robot's CAN.
pub const BITRATE_BPS: u32 = 500_000;

/// Bus-off recovery: the controller must see 128 × 11 recessive bits before it may
/// take part again.
pub const RECOVERY_BITS: u32 = 128 * 11;

/// A frame on the virtual bus: the SLCAN codec's frame type, so that frames cross the
/// simulator's serial port without conversion.
pub use slcan::Frame as SimFrame;

/// How long `frame` occupies the bus at [`BITRATE_BPS`], rounded up to whole µs.
pub fn frame_time(frame: &SimFrame) -> Duration {
    bit_time(frame.wire_bits())
}

/// How long bus-off recovery takes: [`RECOVERY_BITS`] at [`BITRATE_BPS`].
pub fn recovery_time() -> Duration {
    bit_time(RECOVERY_BITS)
}

fn bit_time(bits: u32) -> Duration {
    Duration::from_micros((u64::from(bits) * 1_000_000).div_ceil(u64::from(BITRATE_BPS)))
}

/// A frame on the bus, stamped with the time its last bit left the wire (when the
/// receivers have it); a frame a test script sent with [`CanPeer::send`], with the time
/// it sent it (those take no bus time, see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SentFrame {
    pub at: Instant,
    pub frame: SimFrame,
}

struct Bus {
    /// What the firmware's next `receive` calls return, in order: frames that passed
    /// the filter, and injected errors where they happened in the stream.
    to_firmware: VecDeque<Result<SimFrame, CanError>>,
    firmware_waiting: WakerRegistration,
    /// Frames the firmware sent that the PC has not received yet.
    to_peer: VecDeque<SimFrame>,
    peer_waiting: WakerRegistration,
    /// Every frame the firmware sent, until the test takes them.
    sent: Vec<SentFrame>,
    /// Every frame the PC sent, filtered out or not: all of them occupy the bus.
    sent_by_pc: Vec<SentFrame>,
    /// The receive acceptance filter; `None` accepts everything.
    filter: Option<Vec<Id>>,
    filtered_out: u32,
    lost_while_bus_off: u32,
    bus_off: bool,
    error_passive: bool,
    recoveries: u32,
    /// When the last frame given bus time leaves the wire: the next one starts then at
    /// the earliest.
    busy_until: Instant,
}

impl Bus {
    /// Gives `frame`, ready to go at `ready`, the wire after every frame before it;
    /// returns when its last bit has left.
    fn occupy(&mut self, frame: &SimFrame, ready: Instant) -> Instant {
        let start = ready.max(self.busy_until);
        self.busy_until = start + frame_time(frame);
        self.busy_until
    }

    fn deliver_to_firmware(&mut self, frame: SimFrame) {
        // A bus-off controller takes no part in the bus, so it receives nothing either.
        if self.bus_off {
            self.lost_while_bus_off += 1;
            return;
        }
        if let Some(filter) = &self.filter
            && !filter.contains(&frame.id())
        {
            self.filtered_out += 1;
            return;
        }
        self.to_firmware.push_back(Ok(frame));
        self.firmware_waiting.wake();
    }
}

type Shared = Rc<RefCell<Bus>>;

/// Builds the bus.
pub struct VirtualCan;

impl VirtualCan {
    /// The firmware's two halves and the PC's end of one bus. The receive port accepts
    /// every frame until [`CanRxPort::accept_only`] sets a filter.
    #[allow(
        clippy::new_ret_no_self,
        reason = "the bus is only ever used through its three ends"
    )]
    pub fn new() -> (CanRxPort, CanTxPort, CanPeer) {
        let bus = Rc::new(RefCell::new(Bus {
            to_firmware: VecDeque::new(),
            firmware_waiting: WakerRegistration::new(),
            to_peer: VecDeque::new(),
            peer_waiting: WakerRegistration::new(),
            sent: Vec::new(),
            sent_by_pc: Vec::new(),
            filter: None,
            filtered_out: 0,
            lost_while_bus_off: 0,
            bus_off: false,
            error_passive: false,
            recoveries: 0,
            busy_until: Instant::from_ticks(0),
        }));
        (
            CanRxPort { bus: bus.clone() },
            CanTxPort { bus: bus.clone() },
            CanPeer { bus },
        )
    }
}

/// The firmware's receive half. Its queue is unbounded: frames are lost to an overrun
/// only when the test injects one.
pub struct CanRxPort {
    bus: Shared,
}

impl CanRxPort {
    /// Accepts only frames with these identifiers, as the board's acceptance filter
    /// does; others are dropped before they reach the queue. A standard and an
    /// extended ID with the same number are different identifiers.
    pub fn accept_only(&mut self, ids: impl IntoIterator<Item = Id>) {
        self.bus.borrow_mut().filter = Some(ids.into_iter().collect());
    }

    /// [`Self::accept_only`] for 11-bit identifiers such as `can::id::COMMANDS`.
    ///
    /// # Panics
    /// If an identifier is wider than 11 bits: no standard frame could carry it, so the
    /// filter would be wrong, not just strict.
    pub fn accept_only_standard(&mut self, ids: &[u16]) {
        self.accept_only(ids.iter().map(|&id| {
            let Some(id) = StandardId::new(id) else {
                panic!("{id:#x} is not an 11-bit CAN identifier");
            };
            Id::Standard(id)
        }));
    }

    /// Removes the filter.
    pub fn accept_all(&mut self) {
        self.bus.borrow_mut().filter = None;
    }
}

impl CanRx for CanRxPort {
    type Frame = SimFrame;

    async fn receive(&mut self) -> Result<SimFrame, CanError> {
        poll_fn(|cx| {
            let mut bus = self.bus.borrow_mut();
            match bus.to_firmware.pop_front() {
                Some(item) => Poll::Ready(item),
                None => {
                    bus.firmware_waiting.register(cx.waker());
                    Poll::Pending
                }
            }
        })
        .await
    }
}

/// The firmware's transmit half: one frame at a time, each for its [`frame_time`].
pub struct CanTxPort {
    bus: Shared,
}

impl CanTx for CanTxPort {
    type Frame = SimFrame;

    /// Occupies the bus for the frame's [`frame_time`], after any frame already on it or
    /// waiting for it, then hands the frame to the PC. A controller that is or goes
    /// bus-off in that time fails with [`CanError::BusOff`] and the frame is lost.
    async fn transmit(&mut self, frame: &SimFrame) -> Result<(), CanError> {
        if self.bus.borrow().bus_off {
            return Err(CanError::BusOff);
        }
        let sent = self.bus.borrow_mut().occupy(frame, Instant::now());
        Timer::at(sent).await;
        let mut bus = self.bus.borrow_mut();
        if bus.bus_off {
            return Err(CanError::BusOff);
        }
        bus.sent.push(SentFrame {
            at: Instant::now(),
            frame: *frame,
        });
        bus.to_peer.push_back(*frame);
        bus.peer_waiting.wake();
        Ok(())
    }

    fn state(&mut self) -> BusState {
        let bus = self.bus.borrow();
        if bus.bus_off {
            BusState::Off
        } else if bus.error_passive {
            BusState::Passive
        } else {
            BusState::Active
        }
    }

    /// Takes [`recovery_time`] when bus-off and counts the recovery; returns at once
    /// otherwise, as a controller that is on the bus has nothing to recover from.
    async fn recover(&mut self) {
        if !self.bus.borrow().bus_off {
            return;
        }
        Timer::after(recovery_time()).await;
        let mut bus = self.bus.borrow_mut();
        bus.bus_off = false;
        bus.recoveries += 1;
    }
}

/// The robot PC's end of the bus, and the test's handle on its faults. Clones share
/// the bus.
#[derive(Clone)]
pub struct CanPeer {
    bus: Shared,
}

impl CanPeer {
    /// Sends a standard data frame to the firmware; it arrives at once.
    ///
    /// # Panics
    /// If `id` is wider than 11 bits or `data` longer than 8 bytes: such a frame cannot
    /// exist, so the test is wrong. Use [`Self::send_frame`] for any other frame.
    pub fn send(&self, id: u16, data: &[u8]) {
        let Some(frame) = SimFrame::standard(id, data) else {
            panic!(
                "no standard CAN frame has ID {id:#x} and {} bytes",
                data.len()
            );
        };
        self.send_frame(frame);
    }

    /// Sends any frame (extended, remote) to the firmware; it arrives at once unless
    /// the acceptance filter drops it or the firmware's controller is bus-off.
    pub fn send_frame(&self, frame: SimFrame) {
        let mut bus = self.bus.borrow_mut();
        bus.sent_by_pc.push(SentFrame {
            at: Instant::now(),
            frame,
        });
        bus.deliver_to_firmware(frame);
    }

    /// Sends `frame` as a PC program does through its CAN interface: it takes its
    /// [`frame_time`] on the bus, after every frame already on it or waiting for it,
    /// and reaches the firmware when its last bit has left; returns then, with that
    /// time. `queued` is when the interface had the frame: a caller that comes late
    /// (a wall clock that overslept) loses no bus time, its frames follow each other
    /// on the wire as they would have. The firmware does not take it if the
    /// acceptance filter drops it or its controller is bus-off.
    pub async fn transmit(&self, frame: SimFrame, queued: Instant) -> Instant {
        let sent = self.bus.borrow_mut().occupy(&frame, queued);
        Timer::at(sent).await;
        let mut bus = self.bus.borrow_mut();
        bus.sent_by_pc.push(SentFrame { at: sent, frame });
        bus.deliver_to_firmware(frame);
        sent
    }

    /// Every frame the PC sent, oldest first, whether the firmware took it or not.
    pub fn sent_by_pc(&self) -> Vec<SentFrame> {
        self.bus.borrow().sent_by_pc.clone()
    }

    /// Empties the log of [`Self::sent_by_pc`]; a simulator that runs for hours calls
    /// it so that the log does not grow without bound.
    pub fn forget_sent_by_pc(&self) {
        self.bus.borrow_mut().sent_by_pc.clear();
    }

    /// The next frame from the firmware, waiting for one if none is queued.
    pub async fn receive(&self) -> SimFrame {
        poll_fn(|cx| {
            let mut bus = self.bus.borrow_mut();
            match bus.to_peer.pop_front() {
                Some(frame) => Poll::Ready(frame),
                None => {
                    bus.peer_waiting.register(cx.waker());
                    Poll::Pending
                }
            }
        })
        .await
    }

    /// The next frame from the firmware, if one is queued.
    pub fn try_receive(&self) -> Option<SimFrame> {
        self.bus.borrow_mut().to_peer.pop_front()
    }

    /// Every frame the firmware sent since the last [`Self::take_sent`], oldest first.
    /// Independent of [`Self::receive`]: a frame is both logged here and queued there.
    pub fn sent(&self) -> Vec<SentFrame> {
        self.bus.borrow().sent.clone()
    }

    /// [`Self::sent`], emptying the log.
    pub fn take_sent(&self) -> Vec<SentFrame> {
        core::mem::take(&mut self.bus.borrow_mut().sent)
    }

    /// The logged frames with standard identifier `id`, oldest first.
    pub fn sent_with_id(&self, id: u16) -> Vec<SentFrame> {
        let bus = self.bus.borrow();
        bus.sent
            .iter()
            .filter(|sent| sent.frame.standard_id() == Some(id))
            .copied()
            .collect()
    }

    /// Puts the firmware's controller bus-off, as after too many transmit errors: a
    /// transmit under way fails, every transmit fails and nothing is received until
    /// the firmware calls [`CanTx::recover`].
    pub fn force_bus_off(&self) {
        self.bus.borrow_mut().bus_off = true;
    }

    /// The controller's CAN node restarts, as when the chip resets while the bus and
    /// the PC stay up: its receive queue is emptied (frames it had not read are lost),
    /// its acceptance filter is gone and it is error-active again (a reset clears the
    /// error counters). Returns the new boot's two halves on the same bus; the PC's end
    /// and every clone of it stay connected, and frames the controller sent before the
    /// reset stay sent.
    ///
    /// The previous boot's halves must be dropped first (the firmware that held them
    /// is gone): they would share the bus with the new ones.
    pub fn reset_controller(&self) -> (CanRxPort, CanTxPort) {
        let mut bus = self.bus.borrow_mut();
        bus.to_firmware.clear();
        bus.filter = None;
        bus.bus_off = false;
        bus.error_passive = false;
        drop(bus);
        (
            CanRxPort {
                bus: self.bus.clone(),
            },
            CanTxPort {
                bus: self.bus.clone(),
            },
        )
    }

    /// Bus-off recoveries the firmware completed.
    pub fn recoveries(&self) -> u32 {
        self.bus.borrow().recoveries
    }

    /// Makes the controller report [`BusState::Passive`] (high error counters) or not.
    /// Frames still go both ways, as they do on a real error-passive node.
    pub fn set_error_passive(&self, passive: bool) {
        self.bus.borrow_mut().error_passive = passive;
    }

    /// Queues a receive error, typically [`CanError::Overrun`]. It comes out of the
    /// firmware's `receive` after the frames sent before it and before those sent
    /// after it, where the loss happened.
    pub fn inject_rx_error(&self, error: CanError) {
        let mut bus = self.bus.borrow_mut();
        bus.to_firmware.push_back(Err(error));
        bus.firmware_waiting.wake();
    }

    /// Frames the acceptance filter dropped.
    pub fn filtered_out(&self) -> u32 {
        self.bus.borrow().filtered_out
    }

    /// Frames sent to the firmware while its controller was bus-off, which it missed.
    pub fn lost_while_bus_off(&self) -> u32 {
        self.bus.borrow().lost_while_bus_off
    }
}
