//! The sensor tasks: battery voltage once a second, and every load-cell sample.

use embassy_time::{Duration, Ticker, Timer};

use crate::hw::{BatteryVoltage, LoadCell};
use base_core::controller::Input;

use crate::sync::InputSender;

/// The battery filter's time constant is 20 s; one sample a second is plenty.
pub const BATTERY_PERIOD: Duration = Duration::from_secs(1);
/// After a missing load cell, try again this much later.
pub const SCALE_RETRY: Duration = Duration::from_secs(1);

pub async fn run_battery<V: BatteryVoltage>(mut battery: V, inputs: InputSender<'_>) -> ! {
    let mut ticker = Ticker::every(BATTERY_PERIOD);
    loop {
        // A failed conversion is skipped: the filter holds the last value, and the
        // battery frame keeps reporting it.
        if let Ok(voltage_mv) = battery.read_millivolts().await {
            inputs.send(Input::BatterySample { voltage_mv }).await;
        }
        ticker.next().await;
    }
}

/// Reads as fast as the converter delivers (10 samples/s on the HX711).
pub async fn run_scale<L: LoadCell>(mut load_cell: L, inputs: InputSender<'_>) -> ! {
    loop {
        match load_cell.read_raw().await {
            Ok(raw) => inputs.send(Input::ScaleSample(raw)).await,
            Err(_) => {
                inputs.send(Input::ScaleMissing).await;
                Timer::after(SCALE_RETRY).await;
            }
        }
    }
}
