//! The input task: samples the e-stop, the safety zone and the front button, debounces
//! them and reports each stable change.

use embassy_time::{Duration, Ticker};

use crate::hw::InputPin;
use base_core::controller::Input;
use base_core::debounce::Debouncer;

use crate::channels::InputSender;
use crate::control::core_now;
use crate::liveness::{CriticalTask, Liveness};

/// Which pin level means "active" (pressed, occupied).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ActiveLevel {
    High,
    Low,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputSettings {
    pub sample_period_ms: u32,
    /// Short, because it adds to the stop latency; two agreeing samples still ignore a
    /// spike on the wire.
    pub estop_debounce_ms: u32,
    pub safety_zone_debounce_ms: u32,
    /// Contact bounce of a push button lasts up to ~20 ms.
    pub button_debounce_ms: u32,
    /// E-stop loops are normally closed to 3.3 V: an open loop or a broken wire reads
    /// low through the board's pull-down, which counts as pressed.
    pub estop_active: ActiveLevel,
    pub safety_zone_active: ActiveLevel,
    pub button_active: ActiveLevel,
}

impl InputSettings {
    pub const DEFAULT: InputSettings = InputSettings {
        sample_period_ms: 1,
        estop_debounce_ms: 1,
        safety_zone_debounce_ms: 10,
        button_debounce_ms: 20,
        estop_active: ActiveLevel::Low,
        safety_zone_active: ActiveLevel::Low,
        button_active: ActiveLevel::Low,
    };
}

pub struct InputPins<E, Z, B> {
    pub estop: E,
    pub safety_zone: Z,
    pub button: B,
}

struct DebouncedInput<P> {
    pin: P,
    active: ActiveLevel,
    debouncer: Debouncer,
    report: fn(bool) -> Input,
}

impl<P: InputPin> DebouncedInput<P> {
    /// Starts from the level the pin shows now. A pin that cannot be read counts as
    /// active: the safe reading for the e-stop and the zone.
    fn new(mut pin: P, active: ActiveLevel, debounce_ms: u32, report: fn(bool) -> Input) -> Self {
        let initial = read(&mut pin, active);
        Self {
            pin,
            active,
            debouncer: Debouncer::new(initial, debounce_ms),
            report,
        }
    }

    fn sample(&mut self) -> Option<Input> {
        let raw = read(&mut self.pin, self.active);
        self.debouncer.update(core_now(), raw).map(self.report)
    }

    fn current(&self) -> Input {
        (self.report)(self.debouncer.level())
    }
}

fn read<P: InputPin>(pin: &mut P, active: ActiveLevel) -> bool {
    match active {
        ActiveLevel::High => pin.is_high().unwrap_or(true),
        ActiveLevel::Low => pin.is_low().unwrap_or(true),
    }
}

pub async fn run<E: InputPin, Z: InputPin, B: InputPin>(
    pins: InputPins<E, Z, B>,
    settings: InputSettings,
    inputs: InputSender<'_>,
    liveness: &Liveness,
) -> ! {
    let mut estop = DebouncedInput::new(
        pins.estop,
        settings.estop_active,
        settings.estop_debounce_ms,
        Input::Estop,
    );
    let mut zone = DebouncedInput::new(
        pins.safety_zone,
        settings.safety_zone_active,
        settings.safety_zone_debounce_ms,
        Input::SafetyZone,
    );
    let mut button = DebouncedInput::new(
        pins.button,
        settings.button_active,
        settings.button_debounce_ms,
        Input::Button,
    );
    // The controller starts knowing nothing: tell it the levels at boot.
    inputs.send(estop.current()).await;
    inputs.send(zone.current()).await;
    let mut ticker = Ticker::every(Duration::from_millis(u64::from(
        settings.sample_period_ms.max(1),
    )));
    loop {
        ticker.next().await;
        liveness.check_in(CriticalTask::Inputs);
        for change in [estop.sample(), zone.sample(), button.sample()]
            .into_iter()
            .flatten()
        {
            inputs.send(change).await;
        }
    }
}
