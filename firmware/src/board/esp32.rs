//! ESP32 (the robot's board: ESP32-DevKitC with an ESP32-WROOM-32 module, 4 MB flash).
//!
//! Kept free: GPIO6–11 (SPI flash), GPIO1/3 (UART0: flashing and the defmt log over
//! the devkit's USB bridge), the strapping pins GPIO0, 2, 5, 12 and 15, and ADC2's
//! pins for analog use (ADC2 is the radio's). The input-only pins GPIO34–39 have no
//! internal pulls, so only the battery's analog input uses one of them.
//!
//! Built with the `esp` toolchain (espup); docs/flashing.md walks through it. CI type-checks
//! and lints it without espup (`.ci/esp32-check`).

use esp_hal::analog::adc::{Adc, AdcConfig, Attenuation};
use esp_hal::peripherals::{GPIO34, Peripherals};
use esp_hal::rtc_cntl::SocResetReason;
use esp_storage::FlashStorage;

use super::{BATTERY_DIVIDER, Board};
use crate::battery::BatteryAdc;

pub const CHIP: &str = "ESP32";

/// GPIO34 is ADC1 channel 6. esp-hal has no calibration scheme for the original ESP32,
/// so the reading is raw (12 bits).
pub type Battery = BatteryAdc<GPIO34<'static>, ()>;

/// At 11 dB the ESP32's ADC spans about 0–3.1 V over 0–4095 and is close to linear
/// between 0.15 and 2.45 V, where the battery divider keeps the pin. Uncalibrated
/// parts differ by a few percent: trim with the battery registers if needed.
fn raw_to_pin_millivolts(raw: u16) -> u16 {
    (u32::from(raw) * 3_100 / 4_095) as u16
}

pub fn take(p: Peripherals) -> Board {
    let mut adc_config = AdcConfig::new();
    let battery_pin = adc_config.enable_pin(p.GPIO34, Attenuation::_11dB);
    let battery = BatteryAdc::new(
        Adc::new(p.ADC1, adc_config),
        battery_pin,
        raw_to_pin_millivolts,
        BATTERY_DIVIDER,
    );
    Board {
        twai: p.TWAI0,
        can_tx: p.GPIO25.into(),
        can_rx: p.GPIO26.into(),
        drives_uart: p.UART1,
        drives_tx: p.GPIO17.into(),
        drives_rx: p.GPIO16.into(),
        drives_de: p.GPIO4.into(),
        hx711_dout: p.GPIO19.into(),
        hx711_sck: p.GPIO18.into(),
        battery,
        estop: p.GPIO27.into(),
        safety_zone: p.GPIO32.into(),
        button: p.GPIO33.into(),
        pc_switch: p.GPIO23.into(),
        status_led: p.GPIO22.into(),
        bt: p.BT,
        // The second core is not started, but a flash write must never run while it
        // fetches from flash: park it if it ever runs.
        flash: FlashStorage::new(p.FLASH).multicore_auto_park(),
        rtc: p.RTC_TIMER,
        timg0: p.TIMG0,
        scheduler_interrupt: p.FROM_CPU_INTR0,
    }
}

/// Whether a watchdog caused the last reset.
pub fn reset_by_watchdog(reason: Option<SocResetReason>) -> bool {
    use SocResetReason::*;
    matches!(
        reason,
        Some(CoreMwdt0 | CoreMwdt1 | CoreRtcWdt | CpuMwdt0 | Cpu0RtcWdt | SysRtcWdt)
    )
}

/// A software reset: the panic handler's (the firmware does not reset itself otherwise).
pub fn reset_by_software(reason: Option<SocResetReason>) -> bool {
    use SocResetReason::*;
    matches!(reason, Some(CoreSw | Cpu0Sw))
}
