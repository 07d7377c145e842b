//! The liveness task: feeds the hardware watchdog only while every critical task keeps
//! checking in. A task stuck in a loop or waiting forever stops the feeding, and the
//! watchdog resets the chip; the next boot reports it in the status frame.

use embassy_time::{Duration, Ticker};

use crate::hw::Watchdog;

use super::channels::Channels;

/// How often the check-ins are collected. Every critical task checks in at least every
/// 200 ms (the drive link's poll interval), so a healthy firmware feeds each period;
/// the board sets the hardware timeout to several periods (≥ 2 s).
pub const CHECK_PERIOD: Duration = Duration::from_millis(500);

pub async fn run<W: Watchdog>(mut watchdog: W, channels: &Channels) -> ! {
    let mut ticker = Ticker::every(CHECK_PERIOD);
    loop {
        ticker.next().await;
        if channels.liveness.all_checked_in() {
            watchdog.feed();
        }
    }
}
