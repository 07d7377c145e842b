//! Simulated pins and sensors: they do what they say, on the virtual clock.

use base_runtime::hw::{BatteryVoltage, LoadCell, SensorError, Watchdog};
use base_runtime::hx711::{READY_TIMEOUT, SAMPLE_INTERVAL};
use embassy_time::{Duration, Timer};
use embedded_hal::digital::{InputPin, OutputPin, PinState, StatefulOutputPin};
use virtual_robot::io::{LevelChange, Pulse, SimBattery, SimLoadCell, SimPin, SimWatchdog};
use virtual_robot::runtime::{block_on, now};

fn ms(millis: u64) -> Duration {
    Duration::from_millis(millis)
}

#[test]
fn an_input_pin_reads_the_level_the_test_sets() {
    let button = SimPin::new(PinState::High);
    let mut firmware_side = button.clone();
    assert!(firmware_side.is_high().unwrap());
    button.set_level(PinState::Low);
    assert!(firmware_side.is_low().unwrap());
    assert!(!firmware_side.is_high().unwrap());
    // The test drove it, not the firmware: nothing logged.
    assert_eq!(button.changes(), vec![]);
}

#[test]
fn output_changes_are_logged_with_their_times() {
    let switch = SimPin::new(PinState::Low);
    let mut firmware_side = switch.clone();
    let start = now();
    block_on(async {
        Timer::after_millis(10).await;
        firmware_side.set_high().unwrap();
        // Already high: not a change.
        firmware_side.set_high().unwrap();
        Timer::after_millis(300).await;
        firmware_side.set_low().unwrap();
    });
    assert_eq!(
        switch.changes(),
        vec![
            LevelChange {
                at: start + ms(10),
                level: PinState::High
            },
            LevelChange {
                at: start + ms(310),
                level: PinState::Low
            },
        ]
    );
    assert_eq!(switch.level(), PinState::Low);
}

#[test]
fn high_pulses_report_their_length() {
    let switch = SimPin::new(PinState::Low);
    let mut firmware_side = switch.clone();
    let start = now();
    block_on(async {
        firmware_side.set_high().unwrap();
        Timer::after_millis(500).await;
        firmware_side.set_low().unwrap();
        Timer::after_millis(100).await;
        firmware_side.set_high().unwrap();
        Timer::after_millis(5000).await;
        firmware_side.set_low().unwrap();
        Timer::after_millis(10).await;
        // Still high at the end: not a completed pulse.
        firmware_side.set_high().unwrap();
    });
    assert_eq!(
        switch.high_pulses(),
        vec![
            Pulse {
                start,
                length: ms(500)
            },
            Pulse {
                start: start + ms(600),
                length: ms(5000)
            },
        ]
    );
}

#[test]
fn a_stateful_output_reports_and_toggles_its_level() {
    let mut led = SimPin::new(PinState::Low);
    assert!(led.is_set_low().unwrap());
    led.toggle().unwrap();
    assert!(led.is_set_high().unwrap());
    led.toggle().unwrap();
    assert!(led.is_set_low().unwrap());
    assert_eq!(led.changes().len(), 2);
}

#[test]
fn the_battery_reads_what_the_test_sets() {
    let battery = SimBattery::new(25_200);
    let mut firmware_side = battery.clone();
    assert_eq!(block_on(firmware_side.read_millivolts()), Ok(25_200));
    battery.set_millivolts(23_100);
    assert_eq!(block_on(firmware_side.read_millivolts()), Ok(23_100));
}

#[test]
fn a_failing_battery_reading_reports_its_error_until_cleared() {
    let battery = SimBattery::new(25_200);
    let mut firmware_side = battery.clone();
    battery.set_failure(Some(SensorError::Invalid));
    assert_eq!(
        block_on(firmware_side.read_millivolts()),
        Err(SensorError::Invalid)
    );
    battery.set_failure(None);
    assert_eq!(block_on(firmware_side.read_millivolts()), Ok(25_200));
}

#[test]
fn the_load_cell_reads_offset_plus_grams_times_gain() {
    let cell = SimLoadCell::new(8_000, 21.5);
    let mut firmware_side = cell.clone();
    assert_eq!(block_on(firmware_side.read_raw()), Ok(8_000));
    cell.set_load_grams(1_000.0);
    assert_eq!(block_on(firmware_side.read_raw()), Ok(8_000 + 21_500));
    // Negative counts per gram (a cell mounted the other way) go below the offset.
    let reversed = SimLoadCell::new(-100, -2.0);
    reversed.set_load_grams(50.0);
    assert_eq!(block_on(reversed.clone().read_raw()), Ok(-200));
}

#[test]
fn load_cell_reads_come_one_per_sample_interval() {
    let mut cell = SimLoadCell::new(0, 1.0);
    let start = now();
    let times = block_on(async {
        let mut times = Vec::new();
        for _ in 0..3 {
            cell.read_raw().await.unwrap();
            times.push(now() - start);
        }
        times
    });
    assert_eq!(
        times,
        [SAMPLE_INTERVAL, SAMPLE_INTERVAL * 2, SAMPLE_INTERVAL * 3]
    );
}

#[test]
fn a_load_cell_read_after_a_pause_gets_the_latest_sample_at_once() {
    let mut cell = SimLoadCell::new(0, 1.0);
    let start = now();
    block_on(async {
        cell.read_raw().await.unwrap();
        Timer::after_millis(250).await;
        cell.read_raw().await.unwrap();
        // The 300 ms conversion, waited for.
        cell.read_raw().await.unwrap();
    });
    assert_eq!(now() - start, ms(400));
}

#[test]
fn a_missing_load_cell_times_out_like_the_driver() {
    let cell = SimLoadCell::new(0, 1.0);
    let mut firmware_side = cell.clone();
    cell.set_missing(true);
    let start = now();
    assert_eq!(
        block_on(firmware_side.read_raw()),
        Err(SensorError::Timeout)
    );
    assert_eq!(now() - start, READY_TIMEOUT);
    cell.set_missing(false);
    assert_eq!(block_on(firmware_side.read_raw()), Ok(0));
}

#[test]
fn an_overloaded_load_cell_reads_invalid_like_the_driver() {
    let cell = SimLoadCell::new(0, 1_000.0);
    let mut firmware_side = cell.clone();
    cell.set_load_grams(8_388.606);
    assert_eq!(block_on(firmware_side.read_raw()), Ok(0x7F_FFFE));
    cell.set_load_grams(10_000.0);
    assert_eq!(
        block_on(firmware_side.read_raw()),
        Err(SensorError::Invalid)
    );
    cell.set_load_grams(-10_000.0);
    assert_eq!(
        block_on(firmware_side.read_raw()),
        Err(SensorError::Invalid)
    );
}

#[test]
fn load_cell_noise_stays_within_its_amplitude_and_repeats() {
    let read_noisy = || {
        let mut cell = SimLoadCell::new(1_000, 1.0);
        cell.set_noise(5);
        block_on(async {
            let mut values = Vec::new();
            for _ in 0..50 {
                values.push(cell.read_raw().await.unwrap());
            }
            values
        })
    };
    let values = read_noisy();
    assert!(
        values.iter().all(|v| (995..=1_005).contains(v)),
        "{values:?}"
    );
    // Noise, not a constant offset.
    assert!(values.iter().any(|v| *v != values[0]));
    assert_eq!(read_noisy(), values);
}

#[test]
fn a_fed_watchdog_does_not_bite() {
    let watchdog = SimWatchdog::new(ms(1_000));
    let mut firmware_side = watchdog.clone();
    block_on(async {
        for _ in 0..10 {
            Timer::after_millis(900).await;
            firmware_side.feed();
        }
        Timer::after_millis(999).await;
    });
    assert!(!watchdog.has_bitten());
    assert_eq!(watchdog.feeds(), 10);
}

#[test]
fn a_starved_watchdog_bites_one_timeout_after_the_last_feed() {
    let watchdog = SimWatchdog::new(ms(1_000));
    let mut firmware_side = watchdog.clone();
    let start = now();
    block_on(async {
        Timer::after_millis(500).await;
        firmware_side.feed();
        Timer::after_millis(3_000).await;
    });
    assert_eq!(watchdog.bitten_at(), Some(start + ms(1_500)));
    assert_eq!(watchdog.feeds(), 1);
}

#[test]
fn a_late_feed_does_not_undo_the_bite() {
    let watchdog = SimWatchdog::new(ms(1_000));
    let mut firmware_side = watchdog.clone();
    let start = now();
    block_on(async {
        Timer::after_millis(1_200).await;
        firmware_side.feed();
        Timer::after_millis(100).await;
    });
    assert_eq!(watchdog.bitten_at(), Some(start + ms(1_000)));
}

#[test]
fn a_feed_exactly_at_the_timeout_is_too_late() {
    let watchdog = SimWatchdog::new(ms(1_000));
    let mut firmware_side = watchdog.clone();
    block_on(Timer::after_millis(1_000));
    firmware_side.feed();
    assert!(watchdog.has_bitten());
}
