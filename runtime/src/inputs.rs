//! The input task: samples the e-stop, the safety zone and the front button, debounces
//! them and reports each stable change.

use embassy_time::{Duration, Ticker};

use crate::hw::InputPin;
use base_core::controller::Input;
use base_core::debounce::{Debouncer, SafetyDebouncer};
use base_core::time::Timestamp;

use crate::control::core_now;
use crate::liveness::{CriticalTask, Liveness};
use crate::sync::InputSender;

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
    /// Every input is sampled this often. Short enough that a chattering e-stop or
    /// zone contact cannot hide between samples: any active phase of at least this
    /// long is seen, whatever its phase against the sampling.
    pub sample_period_us: u32,
    /// The e-stop and the safety zone are active from their first active sample on
    /// (see [`SafetyDebouncer`]) and released only after this long without one. The
    /// e-stop is left only with the confirm press anyway; the release time keeps a
    /// chattering button from offering that confirm between two bounces.
    pub estop_release_ms: u32,
    /// The zone limit holds whenever the zone input was active within this window:
    /// long enough to bridge a scanner output chattering at 50/50 ms, short enough
    /// that the base is back at full speed a moment after someone left the zone.
    pub safety_zone_release_ms: u32,
    /// Contact bounce of a push button lasts up to ~20 ms. The button is no safety
    /// input: both directions are debounced alike.
    pub button_debounce_ms: u32,
    /// E-stop loops are normally closed to 3.3 V: an open loop or a broken wire reads
    /// low through the board's pull-down, which counts as pressed.
    pub estop_active: ActiveLevel,
    pub safety_zone_active: ActiveLevel,
    pub button_active: ActiveLevel,
}

impl InputSettings {
    pub const DEFAULT: InputSettings = InputSettings {
        sample_period_us: 200,
        estop_release_ms: 50,
        safety_zone_release_ms: 100,
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

/// How one input's raw samples become its stable level.
enum Debounce {
    /// Towards the safe side: the e-stop and the safety zone.
    Safety(SafetyDebouncer),
    /// Both directions alike: the front button.
    Symmetric(Debouncer),
}

impl Debounce {
    fn update(&mut self, now: Timestamp, raw: bool) -> Option<bool> {
        match self {
            Debounce::Safety(debouncer) => debouncer.update(now, raw),
            Debounce::Symmetric(debouncer) => debouncer.update(now, raw),
        }
    }

    fn level(&self) -> bool {
        match self {
            Debounce::Safety(debouncer) => debouncer.level(),
            Debounce::Symmetric(debouncer) => debouncer.level(),
        }
    }
}

struct DebouncedInput<P> {
    pin: P,
    active: ActiveLevel,
    debounce: Debounce,
    report: fn(bool) -> Input,
    /// The controller has been told this input's level since the start.
    told: bool,
}

impl<P: InputPin> DebouncedInput<P> {
    /// A safety input, active from the start: it is told active at its first active
    /// sample, and released only after `release_ms` without one, at boot as always. One
    /// released sample proves nothing about a contact that chatters. A pin that cannot
    /// be read counts as active: the safe reading for the e-stop and the zone.
    fn safety(pin: P, active: ActiveLevel, release_ms: u32, report: fn(bool) -> Input) -> Self {
        Self {
            pin,
            active,
            debounce: Debounce::Safety(SafetyDebouncer::new(true, release_ms)),
            report,
            told: false,
        }
    }

    /// An input debounced alike in both directions, starting from its level now.
    fn symmetric(
        mut pin: P,
        active: ActiveLevel,
        debounce_ms: u32,
        report: fn(bool) -> Input,
    ) -> Self {
        let initial = read(&mut pin, active);
        Self {
            pin,
            active,
            debounce: Debounce::Symmetric(Debouncer::new(initial, debounce_ms)),
            report,
            told: true,
        }
    }

    /// The level to tell the controller after this sample, if any: a change, or the
    /// first level that is sure since the start.
    fn sample(&mut self) -> Option<Input> {
        let raw = read(&mut self.pin, self.active);
        let change = self.debounce.update(core_now(), raw);
        if !self.told && (raw || change.is_some()) {
            self.told = true;
            return Some((self.report)(self.debounce.level()));
        }
        change.map(self.report)
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
    let mut estop = DebouncedInput::safety(
        pins.estop,
        settings.estop_active,
        settings.estop_release_ms,
        Input::Estop,
    );
    let mut zone = DebouncedInput::safety(
        pins.safety_zone,
        settings.safety_zone_active,
        settings.safety_zone_release_ms,
        Input::SafetyZone,
    );
    let mut button = DebouncedInput::symmetric(
        pins.button,
        settings.button_active,
        settings.button_debounce_ms,
        Input::Button,
    );
    // The controller starts knowing nothing: each safety input's level is told once
    // it is sure (the first active sample, or the release time without one).
    let mut ticker = Ticker::every(Duration::from_micros(u64::from(
        settings.sample_period_us.max(1),
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
