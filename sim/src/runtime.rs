//! A deterministic executor on a virtual clock, and the `embassy-time` driver behind it.
//!
//! [`block_on`] polls one future (the firmware's joined tasks plus the test script).
//! When the future is waiting and no waker fired, nothing can happen until the next
//! timer, so the clock jumps straight there. Bytes on a virtual wire, wheel motion and
//! timeouts all follow this clock, which makes every run reproducible.
//!
//! The clock is per thread: `cargo test` runs tests on parallel threads, and each gets
//! its own time starting at zero.

use core::future::Future;
use core::pin::pin;
use core::task::{Context, Poll, Waker};
use std::cell::RefCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::Wake;

use embassy_time::{Duration, Instant};
use embassy_time_driver::Driver;

struct Alarm {
    at: u64,
    waker: Waker,
}

#[derive(Default)]
struct Clock {
    now: u64,
    alarms: Vec<Alarm>,
}

thread_local! {
    static CLOCK: RefCell<Clock> = RefCell::new(Clock::default());
}

struct VirtualClock;

impl Driver for VirtualClock {
    fn now(&self) -> u64 {
        CLOCK.with(|clock| clock.borrow().now)
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        CLOCK.with(|clock| {
            let mut clock = clock.borrow_mut();
            if at <= clock.now {
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

/// Virtual time since this thread's clock started.
pub fn now() -> Instant {
    Instant::now()
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
    fn one_character_at_115200_8e1_takes_96_us() {
        assert_eq!(char_time(115_200, 11), Duration::from_micros(96));
    }
}
