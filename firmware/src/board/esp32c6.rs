//! ESP32-C6 (ESP32-C6-DevKitC-1 and compatible modules).
//!
//! Kept free: GPIO24–30 (SPI flash), GPIO12/13 (USB Serial/JTAG: flashing, the defmt
//! log and probe-rs), GPIO16/17 (UART0), and the strapping pins GPIO4, 5, 8, 9 and 15.

use esp_hal::analog::adc::{Adc, AdcCalCurve, AdcConfig, Attenuation};
use esp_hal::peripherals::{ADC1, FLASH, GPIO0, Peripherals};
use esp_hal::rtc_cntl::SocResetReason;
use esp_storage::FlashStorage;

use super::{BATTERY_DIVIDER, Board};
use crate::battery::BatteryAdc;

pub const CHIP: &str = "ESP32-C6";

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
        can_tx: p.GPIO22.into(),
        can_rx: p.GPIO23.into(),
        drives_uart: p.UART1,
        drives_tx: p.GPIO10.into(),
        drives_rx: p.GPIO11.into(),
        drives_de: p.GPIO3.into(),
        hx711_dout: p.GPIO1.into(),
        hx711_sck: p.GPIO2.into(),
        battery,
        estop: p.GPIO18.into(),
        safety_zone: p.GPIO19.into(),
        button: p.GPIO20.into(),
        pc_switch: p.GPIO21.into(),
        status_led: p.GPIO6.into(),
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
