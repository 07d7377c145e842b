//! ESP32-C3 (ESP32-C3-DevKitM-1 / DevKitC-02 and compatible modules).
//!
//! Kept free: GPIO11–17 (SPI flash), GPIO18/19 (USB Serial/JTAG: flashing, the defmt
//! log and probe-rs). GPIO20/21, UART0's pins, carry the drives' UART instead: the
//! log goes over USB. The C3 has few pins, so two strapping pins carry CAN, both in
//! the level their strap wants at reset: GPIO2 (must be high) is TWAI TX, which the
//! transceiver's TXD pull-up holds high; GPIO8 (high for download mode) is TWAI RX,
//! which the transceiver drives recessive-high while the bus idles. The status LED
//! sits on GPIO9 (the BOOT strap, high for a normal boot) wired active low from 3.3 V,
//! which keeps the strap high.

use esp_hal::analog::adc::{Adc, AdcCalCurve, AdcConfig, Attenuation};
use esp_hal::peripherals::{ADC1, FLASH, GPIO0, Peripherals};
use esp_hal::rtc_cntl::SocResetReason;
use esp_storage::FlashStorage;

use super::{BATTERY_DIVIDER, Board};
use crate::battery::BatteryAdc;

pub const CHIP: &str = "ESP32-C3";

/// GPIO0 is ADC1 channel 0. The curve calibration yields mV at the pin.
pub type Battery = BatteryAdc<GPIO0<'static>, AdcCalCurve<ADC1<'static>>>;

pub fn take(p: Peripherals) -> Board {
    let mut adc_config = AdcConfig::new();
    let battery_pin = adc_config.enable_pin_with_cal(p.GPIO0, Attenuation::_11dB);
    let battery = BatteryAdc::new(
        Adc::new(p.ADC1, adc_config),
        battery_pin,
        |millivolts| millivolts,
        BATTERY_DIVIDER,
    );
    Board {
        twai: p.TWAI0,
        can_tx: p.GPIO2.into(),
        can_rx: p.GPIO8.into(),
        drives_uart: p.UART1,
        drives_tx: p.GPIO21.into(),
        drives_rx: p.GPIO20.into(),
        drives_de: p.GPIO10.into(),
        hx711_dout: p.GPIO1.into(),
        hx711_sck: p.GPIO3.into(),
        battery,
        estop: p.GPIO4.into(),
        safety_zone: p.GPIO5.into(),
        button: p.GPIO6.into(),
        pc_switch: p.GPIO7.into(),
        status_led: p.GPIO9.into(),
        bt: p.BT,
        flash: flash_storage(p.FLASH),
        rtc: p.RTC_TIMER,
        timg0: p.TIMG0,
        scheduler_interrupt: p.FROM_CPU_INTR0,
    }
}

/// The flash: one core, nothing to park.
pub fn flash_storage(flash: FLASH<'_>) -> FlashStorage<'_> {
    FlashStorage::new(flash)
}

/// Whether a watchdog (any of the chip's four) caused the last reset.
pub fn reset_by_watchdog(reason: Option<SocResetReason>) -> bool {
    use SocResetReason::*;
    matches!(
        reason,
        Some(
            CoreMwdt0
                | CoreMwdt1
                | CoreRtcWdt
                | Cpu0Mwdt0
                | Cpu0Mwdt1
                | Cpu0RtcWdt
                | SysRtcWdt
                | SysSuperWdt
        )
    )
}

/// A software reset: the panic handler's (the firmware does not reset itself otherwise).
pub fn reset_by_software(reason: Option<SocResetReason>) -> bool {
    use SocResetReason::*;
    matches!(reason, Some(CoreSw | Cpu0Sw))
}
