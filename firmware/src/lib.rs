//! The base controller on the chip: esp-hal implementations of the library's hardware
//! traits ([`base_runtime::hw`]) and the boards that say which pin does what. No
//! decisions are made here; `main.rs` wires these to [`base_runtime::run`].
#![no_std]

pub mod battery;
pub mod board;
pub mod can;
pub mod flash;
pub mod rs485;
pub mod update;
pub mod watchdog;

/// Called by esp-backtrace's panic handler after it printed the panic, in the firmware
/// and in the on-target tests alike (both link this library): records the panic with
/// the uptime for the next boot's panic-loop decision (`board::panic_record`), then
/// resets the chip at once. The drives are then held at zero by the next boot's first
/// frames (and by their own communication timeout meanwhile), instead of running on
/// while a halted chip waits for the watchdog.
#[unsafe(no_mangle)]
fn custom_halt() -> ! {
    let uptime = esp_hal::time::Instant::now().duration_since_epoch();
    board::panic_record::record_panic(uptime.as_millis());
    esp_hal::system::software_reset()
}
