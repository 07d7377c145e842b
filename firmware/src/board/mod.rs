//! The boards: every pin and peripheral choice, one file per chip, and the wiring
//! conventions the three share. Nothing outside `board/` names a GPIO number or a
//! chip-specific type; the chip is picked by the Cargo feature the build aliases set.
//!
//! The manual's pin pictures are lost, so the pins are ours, chosen per chip to keep
//! clear of the flash, strapping and USB pins; docs/flashing.md shows them as a table.

#[cfg(not(any(feature = "esp32", feature = "esp32c3", feature = "esp32c6")))]
compile_error!(
    "pick the chip: build with one of the aliases in .cargo/config.toml (e.g. `cargo build-esp32c3`)"
);

#[cfg_attr(feature = "esp32", path = "esp32.rs")]
#[cfg_attr(feature = "esp32c3", path = "esp32c3.rs")]
#[cfg_attr(feature = "esp32c6", path = "esp32c6.rs")]
mod chip;
pub mod panic_record;

pub use chip::{Battery, CHIP, flash_storage, reset_by_software, reset_by_watchdog, take};

use base_core::battery::VoltageDivider;
use base_runtime::{ActiveLevel, InputSettings};
use esp_hal::gpio::{AnyPin, Pull};
use esp_hal::peripherals::{BT, FROM_CPU_INTR0, RTC_TIMER, TIMG0, TWAI0, UART1};
use esp_storage::FlashStorage;

/// The board with its pins and peripherals sorted by job. [`take`] fills it from the
/// chip's peripherals.
pub struct Board {
    /// CAN: the TWAI controller and the transceiver's TXD/RXD.
    pub twai: TWAI0<'static>,
    pub can_tx: AnyPin<'static>,
    pub can_rx: AnyPin<'static>,
    /// RS-485 to the drives: the UART and the transceiver's DI, RO and DE (with /RE
    /// tied to DE, so the receiver is off while we send and we never read our echo).
    pub drives_uart: UART1<'static>,
    pub drives_tx: AnyPin<'static>,
    pub drives_rx: AnyPin<'static>,
    pub drives_de: AnyPin<'static>,
    /// The load cell's HX711.
    pub hx711_dout: AnyPin<'static>,
    pub hx711_sck: AnyPin<'static>,
    pub battery: Battery,
    pub estop: AnyPin<'static>,
    pub safety_zone: AnyPin<'static>,
    pub button: AnyPin<'static>,
    /// Closes the PC's power switch while high (an optocoupler or relay across the
    /// PC's front-panel switch pins).
    pub pc_switch: AnyPin<'static>,
    /// Blinks while the watchdog is fed (see `watchdog.rs`).
    pub status_led: AnyPin<'static>,
    /// The radio, for the Bluetooth remote.
    pub bt: BT<'static>,
    /// The flash, set up for this chip's cores.
    pub flash: FlashStorage<'static>,
    /// The RTC block, for its watchdog.
    pub rtc: RTC_TIMER<'static>,
    /// esp-rtos's time base and its scheduler interrupt.
    pub timg0: TIMG0<'static>,
    pub scheduler_interrupt: FROM_CPU_INTR0<'static>,
}

/// How the inputs are wired, on every board. E-stop and safety zone are fail-safe:
/// the e-stop loop is normally closed to 3.3 V and the safety scanner's output is
/// high while the zone is clear, so a pull-down makes a cut wire read as pressed or
/// occupied. The front button is a normally open contact to ground with a pull-up;
/// a cut wire reads as not pressed, which is safe for a button. The internal pulls
/// (~45 kΩ) are weak: on the robot, add 4.7 kΩ pulls next to the connectors.
pub const INPUTS: InputSettings = InputSettings {
    estop_active: ActiveLevel::Low,
    safety_zone_active: ActiveLevel::Low,
    button_active: ActiveLevel::Low,
    ..InputSettings::DEFAULT
};
pub const ESTOP_PULL: Pull = Pull::Down;
pub const SAFETY_ZONE_PULL: Pull = Pull::Down;
pub const BUTTON_PULL: Pull = Pull::Up;

/// The battery divider, the same on every board: 120 kΩ over 10 kΩ puts a fully
/// charged 24 V lead-acid pack (29 V) at 2.2 V on the pin, inside every chip's ADC
/// range at 11 dB attenuation.
pub const BATTERY_DIVIDER: VoltageDivider = VoltageDivider {
    top_ohms: 120_000,
    bottom_ohms: 10_000,
};
