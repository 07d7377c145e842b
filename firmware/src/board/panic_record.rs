//! The panic record: the [`PanicHistory`] the panic handler leaves for the next boot,
//! in two words of RTC fast RAM, which survive every reset but a power-on. The same on
//! every chip: esp-hal places `persistent` statics where each keeps its RTC fast RAM
//! (the ESP32-C6's LP RAM) and zeroes them only after a power-on; the history's own
//! magic and check words (`PanicHistory::decode`) reject zeros, noise and a record
//! torn by a reset in the middle of a write alike, and start with an empty history.

use base_core::panic_loop::{Bluetooth, PanicHistory};
use base_core::time::Timestamp;

#[esp_hal::ram(unstable(rtc_fast, persistent))]
static mut RECORD: [u32; 2] = [0; 2];

fn load() -> PanicHistory {
    // SAFETY: a plain two-word read of our own static; the writers below and the panic
    // handler write whole records, and a torn one fails the check words.
    PanicHistory::decode(unsafe { (&raw const RECORD).read_volatile() })
}

fn store(history: &PanicHistory) {
    // SAFETY: as in `load`.
    unsafe { (&raw mut RECORD).write_volatile(history.encode()) }
}

/// The panic handler's entry: a panic `uptime_ms` after this boot.
pub fn record_panic(uptime_ms: u64) {
    let mut history = load();
    history.on_panic(Timestamp::from_millis(uptime_ms));
    store(&history);
}

/// The boot's decision on Bluetooth. `reset_by_panic`: the reset reason is the panic
/// handler's software reset; after any other reset the record is not trusted.
pub fn at_boot(reset_by_panic: bool) -> Bluetooth {
    let mut history = if reset_by_panic {
        load()
    } else {
        PanicHistory::default()
    };
    let decision = history.at_boot();
    store(&history);
    decision
}

/// Bluetooth was turned on by hand: the panics are forgotten.
pub fn turned_on() {
    let mut history = load();
    history.turned_on();
    store(&history);
}
