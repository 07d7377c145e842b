//! The battery voltage: one ADC1 reading, turned into millivolts at the pin by the
//! board's conversion, then through the divider into millivolts at the battery.

use base_core::battery::VoltageDivider;
use base_runtime::hw::{BatteryVoltage, SensorError};
use esp_hal::Blocking;
use esp_hal::analog::adc::{Adc, AdcCalScheme, AdcChannel, AdcPin};
use esp_hal::peripherals::ADC1;

pub struct BatteryAdc<Pin, Calibration> {
    adc: Adc<'static, ADC1<'static>, Blocking>,
    pin: AdcPin<Pin, ADC1<'static>, Calibration>,
    /// The board's reading → mV at the pin (identity where the calibration scheme
    /// already yields mV).
    pin_millivolts: fn(u16) -> u16,
    divider: VoltageDivider,
}

impl<Pin, Calibration> BatteryAdc<Pin, Calibration> {
    pub fn new(
        adc: Adc<'static, ADC1<'static>, Blocking>,
        pin: AdcPin<Pin, ADC1<'static>, Calibration>,
        pin_millivolts: fn(u16) -> u16,
        divider: VoltageDivider,
    ) -> Self {
        Self {
            adc,
            pin,
            pin_millivolts,
            divider,
        }
    }
}

impl<Pin, Calibration> BatteryVoltage for BatteryAdc<Pin, Calibration>
where
    Pin: AdcChannel,
    Calibration: AdcCalScheme<ADC1<'static>>,
{
    async fn read_millivolts(&mut self) -> Result<u16, SensorError> {
        // A one-shot conversion takes tens of µs: shorter than an await would be worth.
        let reading =
            nb::block!(self.adc.read_oneshot(&mut self.pin)).map_err(|()| SensorError::Invalid)?;
        Ok(self.divider.battery_mv((self.pin_millivolts)(reading)))
    }
}
