//! A deterministic executor on a virtual clock, and the `embassy-time` driver behind it.
//!
//! [`block_on`] polls one future (the firmware's joined tasks plus the test script).
//! When the future is waiting and no waker fired, nothing can happen until the next
//! timer, so the clock jumps straight there. Bytes on a virtual wire, wheel motion and
//! timeouts all follow this clock, which makes every run reproducible.
//!
//! The clock is per thread: `cargo test` runs tests on parallel threads, and each gets
//! its own time starting at zero.
//!
//! [`block_on_realtime`] runs the same tasks on the wall clock instead, for the
//! simulator that a PC talks to live: it sleeps until the next timer or until another
//! thread (a serial port reader, stdin) wakes it through a [`cross_thread_queue`].

use core::future::Future;
use core::pin::pin;
use core::task::{Context, Poll, Waker};
use std::cell::RefCell;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::Wake;
use std::thread::{self, Thread};

use embassy_time::{Duration, Instant};
use embassy_time_driver::Driver;

struct Alarm {
    at: u64,
    waker: Waker,
}

#[derive(Default)]
struct Clock {
    /// Ticks on the virtual clock; in real-time mode, the ticks when it started.
    now: u64,
    alarms: Vec<Alarm>,
    /// Set while [`block_on_realtime`] runs: the wall-clock instant at which the clock
    /// read `now`. Time then flows with the wall clock from there.
    wall_origin: Option<std::time::Instant>,
}

impl Clock {
    fn now(&self) -> u64 {
        match self.wall_origin {
            Some(origin) => self.now + wall_ticks(origin.elapsed()),
            None => self.now,
        }
    }

    /// How long the wall clock has to run until the earliest alarm, in real-time mode.
    fn wall_time_to_next_alarm(&self) -> Option<std::time::Duration> {
        let next = self.alarms.iter().map(|alarm| alarm.at).min()?;
        let ticks = next.saturating_sub(self.now());
        Some(std::time::Duration::from_micros(
            Duration::from_ticks(ticks).as_micros(),
        ))
    }
}

fn wall_ticks(elapsed: std::time::Duration) -> u64 {
    let ticks = elapsed.as_nanos() * u128::from(embassy_time::TICK_HZ) / 1_000_000_000;
    u64::try_from(ticks).unwrap_or(u64::MAX)
}

thread_local! {
    static CLOCK: RefCell<Clock> = RefCell::new(Clock::default());
}

struct VirtualClock;

impl Driver for VirtualClock {
    fn now(&self) -> u64 {
        CLOCK.with(|clock| clock.borrow().now())
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        CLOCK.with(|clock| {
            let mut clock = clock.borrow_mut();
            if at <= clock.now() {
                waker.wake_by_ref();
                return;
            }
            // A timer future re-registers on every poll: keep one entry per waker.
            match clock
                .alarms
                .iter_mut()
                .find(|alarm| alarm.waker.will_wake(waker))
            {
                Some(alarm) => alarm.at = alarm.at.min(at),
                None => clock.alarms.push(Alarm {
                    at,
                    waker: waker.clone(),
                }),
            }
        })
    }
}

embassy_time_driver::time_driver_impl!(static DRIVER: VirtualClock = VirtualClock);

/// Jumps the clock to the earliest alarm and wakes everything due then. Returns false
/// if no alarm is pending.
fn advance_to_next_alarm() -> bool {
    let due: Vec<Waker> = CLOCK.with(|clock| {
        let mut clock = clock.borrow_mut();
        let Some(next) = clock.alarms.iter().map(|alarm| alarm.at).min() else {
            return Vec::new();
        };
        clock.now = clock.now.max(next);
        let now = clock.now;
        let (due, later) = clock.alarms.drain(..).partition(|alarm| alarm.at <= now);
        clock.alarms = later;
        due.into_iter().map(|alarm| alarm.waker).collect()
    });
    let any = !due.is_empty();
    due.into_iter().for_each(Waker::wake);
    any
}

/// Removes the alarms of an executor's waker when that executor returns (or unwinds):
/// the future they would wake is gone. Left in this thread's clock, they would keep
/// the waker alive for ever (a leak that libFuzzer's leak check reports on every input
/// of the fuzz targets that run the robot) and make a later [`block_on`] jump the clock
/// to a time nothing waits for.
struct ForgetAlarmsOf(Waker);

impl Drop for ForgetAlarmsOf {
    fn drop(&mut self) {
        CLOCK.with(|clock| {
            clock
                .borrow_mut()
                .alarms
                .retain(|alarm| !alarm.waker.will_wake(&self.0));
        });
    }
}

struct Flag(AtomicBool);

impl Wake for Flag {
    fn wake(self: Arc<Self>) {
        self.0.store(true, Ordering::SeqCst);
    }
    fn wake_by_ref(self: &Arc<Self>) {
        self.0.store(true, Ordering::SeqCst);
    }
}

/// Runs `future` to completion on the virtual clock.
///
/// # Panics
/// If the future waits with no timer pending: nothing could ever wake it.
pub fn block_on<F: Future>(future: F) -> F::Output {
    let mut future = pin!(future);
    let woken = Arc::new(Flag(AtomicBool::new(true)));
    let waker = Waker::from(woken.clone());
    let _forget = ForgetAlarmsOf(waker.clone());
    let mut cx = Context::from_waker(&waker);
    loop {
        if woken.0.swap(false, Ordering::SeqCst) {
            if let Poll::Ready(output) = future.as_mut().poll(&mut cx) {
                return output;
            }
        } else if !advance_to_next_alarm() {
            panic!("deadlock: every task waits and no timer is pending");
        }
    }
}

/// Wakes everything whose alarm is due on the wall clock. Returns false if nothing was.
fn wake_due_alarms() -> bool {
    let due: Vec<Waker> = CLOCK.with(|clock| {
        let mut clock = clock.borrow_mut();
        let now = clock.now();
        let (due, later) = clock.alarms.drain(..).partition(|alarm| alarm.at <= now);
        clock.alarms = later;
        due.into_iter().map(|alarm| alarm.waker).collect()
    });
    let any = !due.is_empty();
    due.into_iter().for_each(Waker::wake);
    any
}

/// Wakes the real-time executor's thread from any thread.
struct ThreadWake {
    woken: AtomicBool,
    thread: Thread,
}

impl Wake for ThreadWake {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }
    fn wake_by_ref(self: &Arc<Self>) {
        self.woken.store(true, Ordering::SeqCst);
        self.thread.unpark();
    }
}

/// Puts the thread's clock back on virtual time, continuing from where the wall clock
/// left it, however [`block_on_realtime`] ends (a panicking task included).
struct BackToVirtualTime;

impl Drop for BackToVirtualTime {
    fn drop(&mut self) {
        CLOCK.with(|clock| {
            let mut clock = clock.borrow_mut();
            clock.now = clock.now();
            clock.wall_origin = None;
        });
    }
}

/// Runs `future` to completion with this thread's clock following the wall clock.
///
/// Between polls the thread sleeps until the next timer is due or a waker fires; the
/// wakers may be fired from other threads (see [`cross_thread_queue`]). Waiting with no
/// timer pending is not a deadlock here: the outside world may still wake the future.
pub fn block_on_realtime<F: Future>(future: F) -> F::Output {
    CLOCK.with(|clock| clock.borrow_mut().wall_origin = Some(std::time::Instant::now()));
    let _restore = BackToVirtualTime;
    let mut future = pin!(future);
    let wake = Arc::new(ThreadWake {
        woken: AtomicBool::new(true),
        thread: thread::current(),
    });
    let waker = Waker::from(wake.clone());
    let _forget = ForgetAlarmsOf(waker.clone());
    let mut cx = Context::from_waker(&waker);
    loop {
        if wake.woken.swap(false, Ordering::SeqCst) {
            if let Poll::Ready(output) = future.as_mut().poll(&mut cx) {
                return output;
            }
        } else if !wake_due_alarms() {
            // A wake from another thread between the check above and here leaves an
            // unpark token, so the park returns at once and nothing is missed.
            match CLOCK.with(|clock| clock.borrow().wall_time_to_next_alarm()) {
                Some(wait) => thread::park_timeout(wait),
                None => thread::park(),
            }
        }
    }
}

thread_local! {
    /// How much longer than asked the real-time stalls so far slept: the host's sleep
    /// overshoots by tens of µs, which many short stalls (one per flash page) would add
    /// up, so the next stall is shorter by it.
    static OVERSLEPT: RefCell<std::time::Duration> = const { RefCell::new(std::time::Duration::ZERO) };
}

/// The whole chip stalls for `duration`: the virtual clock jumps ahead while nothing
/// runs (as when esp-storage masks interrupts during a flash erase). Timers that came
/// due meanwhile fire late. In real-time mode the thread sleeps instead, and a run of
/// stalls takes their sum however coarse the host's sleep is.
pub fn stall(duration: Duration) {
    let realtime = CLOCK.with(|clock| clock.borrow().wall_origin.is_some());
    if realtime {
        let asked = std::time::Duration::from_micros(duration.as_micros());
        OVERSLEPT.with(|overslept| {
            let mut overslept = overslept.borrow_mut();
            let sleep = asked.saturating_sub(*overslept);
            let started = std::time::Instant::now();
            if !sleep.is_zero() {
                thread::sleep(sleep);
            }
            *overslept = (*overslept + started.elapsed()).saturating_sub(asked);
        });
    } else {
        CLOCK.with(|clock| clock.borrow_mut().now += duration.as_ticks());
    }
}

/// Time since this thread's clock started: virtual, or wall-clock time in
/// [`block_on_realtime`].
pub fn now() -> Instant {
    Instant::now()
}

struct QueueState<T> {
    items: VecDeque<T>,
    receiver_waiting: Option<Waker>,
    senders: usize,
}

type SharedQueue<T> = Arc<Mutex<QueueState<T>>>;

fn lock<T>(queue: &SharedQueue<T>) -> std::sync::MutexGuard<'_, QueueState<T>> {
    // The state stays consistent at every step, so a panic elsewhere leaves it usable.
    queue.lock().unwrap_or_else(PoisonError::into_inner)
}

/// An unbounded queue from plain threads (blocking readers of a terminal or stdin) to
/// a task on the real-time executor, whose wait it ends.
pub fn cross_thread_queue<T>() -> (QueueSender<T>, QueueReceiver<T>) {
    let queue = Arc::new(Mutex::new(QueueState {
        items: VecDeque::new(),
        receiver_waiting: None,
        senders: 1,
    }));
    (
        QueueSender {
            queue: queue.clone(),
        },
        QueueReceiver { queue },
    )
}

/// The sending end of a [`cross_thread_queue`]; clones send into the same queue.
pub struct QueueSender<T> {
    queue: SharedQueue<T>,
}

impl<T> QueueSender<T> {
    pub fn send(&self, item: T) {
        let mut state = lock(&self.queue);
        state.items.push_back(item);
        if let Some(waker) = state.receiver_waiting.take() {
            waker.wake();
        }
    }
}

impl<T> Clone for QueueSender<T> {
    fn clone(&self) -> Self {
        lock(&self.queue).senders += 1;
        Self {
            queue: self.queue.clone(),
        }
    }
}

impl<T> Drop for QueueSender<T> {
    fn drop(&mut self) {
        let mut state = lock(&self.queue);
        state.senders -= 1;
        if state.senders == 0
            && let Some(waker) = state.receiver_waiting.take()
        {
            waker.wake();
        }
    }
}

/// The receiving end of a [`cross_thread_queue`], for one task.
pub struct QueueReceiver<T> {
    queue: SharedQueue<T>,
}

impl<T> QueueReceiver<T> {
    /// The next item, waiting for one; `None` once the queue is empty and every sender
    /// is gone (the reader thread hit the end of its input).
    pub async fn receive(&self) -> Option<T> {
        core::future::poll_fn(|cx| {
            let mut state = lock(&self.queue);
            if let Some(item) = state.items.pop_front() {
                return Poll::Ready(Some(item));
            }
            if state.senders == 0 {
                return Poll::Ready(None);
            }
            state.receiver_waiting = Some(cx.waker().clone());
            Poll::Pending
        })
        .await
    }
}

/// How long one character takes on a UART line: start bit, 8 data bits, parity (if
/// any) and stop bits, rounded up to whole microseconds.
pub fn char_time(baud: u32, bits_per_char: u32) -> Duration {
    Duration::from_micros((u64::from(bits_per_char) * 1_000_000).div_ceil(u64::from(baud)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use embassy_futures::join::join;
    use embassy_time::Timer;

    #[test]
    fn timers_complete_in_virtual_time_in_order() {
        let order = RefCell::new(Vec::new());
        let start = now();
        block_on(join(
            async {
                Timer::after_millis(300).await;
                order.borrow_mut().push((300, now()));
            },
            async {
                Timer::after_millis(100).await;
                order.borrow_mut().push((100, now()));
            },
        ));
        let order = order.into_inner();
        assert_eq!(order[0], (100, start + Duration::from_millis(100)));
        assert_eq!(order[1], (300, start + Duration::from_millis(300)));
    }

    #[test]
    fn a_finished_run_leaves_no_timer_behind_to_move_the_next_runs_clock() {
        // Ends after 1 ms with a 100 s timer still pending.
        block_on(embassy_futures::select::select(
            Timer::after_secs(100),
            Timer::after_millis(1),
        ));
        let before = now();
        let stuck = std::panic::catch_unwind(|| block_on(core::future::pending::<()>()));
        assert!(stuck.is_err(), "nothing can wake it: a deadlock");
        assert_eq!(now(), before, "no stale timer moved the clock");
    }

    #[test]
    fn an_hour_of_virtual_time_passes_at_once() {
        let start = std::time::Instant::now();
        block_on(Timer::after_secs(3600));
        assert!(start.elapsed() < std::time::Duration::from_secs(1));
        assert!(now().as_secs() >= 3600);
    }

    #[test]
    #[should_panic(expected = "deadlock")]
    fn waiting_forever_is_reported() {
        block_on(core::future::pending::<()>());
    }

    #[test]
    fn realtime_timers_follow_the_wall_clock() {
        let start = std::time::Instant::now();
        let virtual_start = now();
        block_on_realtime(Timer::after_millis(30));
        let elapsed = start.elapsed();
        assert!(
            elapsed >= std::time::Duration::from_millis(30),
            "{elapsed:?}"
        );
        assert!(
            elapsed < std::time::Duration::from_millis(500),
            "{elapsed:?}"
        );
        assert!(now() - virtual_start >= Duration::from_millis(30));
    }

    #[test]
    fn a_sender_on_another_thread_wakes_the_realtime_executor() {
        let (sender, receiver) = cross_thread_queue();
        let start = std::time::Instant::now();
        let writer = thread::spawn(move || {
            thread::sleep(std::time::Duration::from_millis(20));
            sender.send(7);
            // Dropping the last sender ends the queue after the item.
        });
        let received = block_on_realtime(async {
            let first = receiver.receive().await;
            let after_last_sender = receiver.receive().await;
            (first, after_last_sender)
        });
        writer.join().unwrap();
        assert_eq!(received, (Some(7), None));
        assert!(start.elapsed() >= std::time::Duration::from_millis(20));
    }

    #[test]
    fn virtual_time_continues_after_a_realtime_run() {
        block_on_realtime(Timer::after_millis(5));
        let after_realtime = now();
        let wall = std::time::Instant::now();
        block_on(Timer::after_secs(60));
        assert!(wall.elapsed() < std::time::Duration::from_secs(1));
        assert!(now() >= after_realtime + Duration::from_secs(60));
    }

    #[test]
    fn one_character_at_115200_8e1_takes_96_us() {
        assert_eq!(char_time(115_200, 11), Duration::from_micros(96));
    }
}
