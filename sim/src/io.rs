//! The robot's simple inputs, outputs and sensors in memory: pins, the battery
//! voltage, the load cell and the watchdog. Each is a cloneable handle: the firmware
//! gets one clone, the test script keeps another to set inputs and read what the
//! firmware did. Times come from the virtual clock of [`crate::runtime`].

use core::convert::Infallible;
use std::cell::RefCell;
use std::rc::Rc;

use base_runtime::hw::{BatteryVoltage, LoadCell, SensorError, Watchdog};
use base_runtime::hx711;
use embassy_time::{Duration, Instant, Timer};
use embedded_hal::digital::{ErrorType, InputPin, OutputPin, PinState, StatefulOutputPin};

/// A level the firmware drove onto a [`SimPin`], and when.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LevelChange {
    pub at: Instant,
    pub level: PinState,
}

/// A high pulse the firmware drove: from a rising to the next falling edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pulse {
    pub start: Instant,
    pub length: Duration,
}

struct PinInner {
    level: PinState,
    changes: Vec<LevelChange>,
    /// While set, the outside world chatters the pin instead of holding `level`.
    chatter: Option<Chatter>,
}

/// A contact that chatters: `level` for `on` of every `period`, the other level for
/// the rest, starting at `start`. Read from the virtual clock whenever the firmware
/// samples the pin, so the pattern is exact to the tick whatever the sampling period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Chatter {
    pub level: PinState,
    pub period: Duration,
    pub on: Duration,
    pub start: Instant,
}

impl Chatter {
    fn level_at(&self, now: Instant) -> PinState {
        let period = self.period.as_ticks().max(1);
        let into_period = now.saturating_duration_since(self.start).as_ticks() % period;
        if into_period < self.on.as_ticks() {
            self.level
        } else {
            match self.level {
                PinState::High => PinState::Low,
                PinState::Low => PinState::High,
            }
        }
    }
}

/// A digital pin with one level shared by all clones: an input the test drives (a
/// button, the e-stop) or an output the firmware drives (the PC power switch).
#[derive(Clone)]
pub struct SimPin {
    inner: Rc<RefCell<PinInner>>,
}

impl SimPin {
    pub fn new(level: PinState) -> Self {
        Self {
            inner: Rc::new(RefCell::new(PinInner {
                level,
                changes: Vec::new(),
                chatter: None,
            })),
        }
    }

    /// The outside world drives the pin (a button pressed, a line pulled). Not
    /// logged: the log is what the firmware did.
    /// Ends a chatter started with [`Self::chatter`].
    pub fn set_level(&self, level: PinState) {
        let mut inner = self.inner.borrow_mut();
        inner.level = level;
        inner.chatter = None;
    }

    /// The outside world chatters the pin from now on: `level` for `on` of every
    /// `period`, starting with `level`, until the next [`Self::set_level`].
    pub fn chatter(&self, level: PinState, period: Duration, on: Duration) {
        self.inner.borrow_mut().chatter = Some(Chatter {
            level,
            period,
            on,
            start: Instant::now(),
        });
    }

    pub fn level(&self) -> PinState {
        let inner = self.inner.borrow();
        match inner.chatter {
            Some(chatter) => chatter.level_at(Instant::now()),
            None => inner.level,
        }
    }

    /// Every change of level the firmware made through `OutputPin`, oldest first.
    /// Setting the level it already has is not a change.
    pub fn changes(&self) -> Vec<LevelChange> {
        self.inner.borrow().changes.clone()
    }

    /// The completed high pulses in [`Self::changes`], oldest first; a pulse still
    /// high is not listed.
    pub fn high_pulses(&self) -> Vec<Pulse> {
        let inner = self.inner.borrow();
        let mut pulses = Vec::new();
        let mut rose_at = None;
        for change in &inner.changes {
            match change.level {
                PinState::High => rose_at = Some(change.at),
                PinState::Low => {
                    if let Some(start) = rose_at.take() {
                        pulses.push(Pulse {
                            start,
                            length: change.at - start,
                        });
                    }
                }
            }
        }
        pulses
    }

    fn drive(&self, level: PinState) {
        let mut inner = self.inner.borrow_mut();
        if inner.level != level {
            inner.level = level;
            inner.changes.push(LevelChange {
                at: Instant::now(),
                level,
            });
        }
    }
}

impl ErrorType for SimPin {
    type Error = Infallible;
}

impl InputPin for SimPin {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(self.level() == PinState::High)
    }

    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(self.level() == PinState::Low)
    }
}

impl OutputPin for SimPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.drive(PinState::Low);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.drive(PinState::High);
        Ok(())
    }
}

impl StatefulOutputPin for SimPin {
    fn is_set_high(&mut self) -> Result<bool, Infallible> {
        self.is_high()
    }

    fn is_set_low(&mut self) -> Result<bool, Infallible> {
        self.is_low()
    }
}

struct BatteryInner {
    millivolts: u16,
    failure: Option<SensorError>,
}

/// The battery voltage as the ADC task sees it, set by the test.
#[derive(Clone)]
pub struct SimBattery {
    inner: Rc<RefCell<BatteryInner>>,
}

impl SimBattery {
    pub fn new(millivolts: u16) -> Self {
        Self {
            inner: Rc::new(RefCell::new(BatteryInner {
                millivolts,
                failure: None,
            })),
        }
    }

    pub fn set_millivolts(&self, millivolts: u16) {
        self.inner.borrow_mut().millivolts = millivolts;
    }

    /// Makes every read fail with `failure` until called with `None`.
    pub fn set_failure(&self, failure: Option<SensorError>) {
        self.inner.borrow_mut().failure = failure;
    }
}

impl BatteryVoltage for SimBattery {
    async fn read_millivolts(&mut self) -> Result<u16, SensorError> {
        let inner = self.inner.borrow();
        match inner.failure {
            Some(error) => Err(error),
            None => Ok(inner.millivolts),
        }
    }
}

struct LoadCellInner {
    offset_counts: i32,
    counts_per_gram: f64,
    load_grams: f64,
    noise_counts: u32,
    /// xorshift64 state: the noise is the same on every run.
    noise_state: u64,
    missing: bool,
    /// When the converter started; conversion `k` is ready `k` sample intervals later.
    started: Instant,
    /// The last conversion read, so each is read at most once.
    last_read: Option<u64>,
}

impl LoadCellInner {
    fn noise(&mut self) -> i64 {
        if self.noise_counts == 0 {
            return 0;
        }
        let mut x = self.noise_state;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.noise_state = x;
        let span = 2 * u64::from(self.noise_counts) + 1;
        // Both fit an i64: span is at most 2^33.
        (x % span) as i64 - i64::from(self.noise_counts)
    }

    /// What the HX711 would put out for the present load: the 24-bit range clamps,
    /// and the rails are refused the way the firmware's driver refuses them.
    fn sample(&mut self) -> Result<i32, SensorError> {
        let counts = i64::from(self.offset_counts)
            + (self.load_grams * self.counts_per_gram).round() as i64
            + self.noise();
        let clamped = counts.clamp(-0x80_0000, 0x7F_FFFF);
        // Two's complement in 24 bits, as the chip shifts it out.
        hx711::decode((clamped as u32) & 0xFF_FFFF)
    }
}

/// The load cell behind its HX711 at 10 samples per second:
/// `raw = offset + grams × counts_per_gram (+ noise)`.
///
/// Reads behave like the firmware's HX711 driver: each conversion is read at most
/// once, so a read waits for the next one (every [`hx711::SAMPLE_INTERVAL`] from
/// creation); a missing chip times out after [`hx711::READY_TIMEOUT`], the driver's
/// wait; a load beyond the converter's range reads as [`SensorError::Invalid`].
#[derive(Clone)]
pub struct SimLoadCell {
    inner: Rc<RefCell<LoadCellInner>>,
}

impl SimLoadCell {
    /// An unloaded, noise-free cell whose converter starts now.
    pub fn new(offset_counts: i32, counts_per_gram: f64) -> Self {
        Self {
            inner: Rc::new(RefCell::new(LoadCellInner {
                offset_counts,
                counts_per_gram,
                load_grams: 0.0,
                noise_counts: 0,
                noise_state: 0x9E37_79B9_7F4A_7C15,
                missing: false,
                started: Instant::now(),
                last_read: None,
            })),
        }
    }

    pub fn set_load_grams(&self, grams: f64) {
        self.inner.borrow_mut().load_grams = grams;
    }

    /// Adds noise of up to ± `counts` to every reading; 0 turns it off.
    pub fn set_noise(&self, counts: u32) {
        self.inner.borrow_mut().noise_counts = counts;
    }

    /// Unplugs the HX711 (DOUT stays high) or plugs it back.
    pub fn set_missing(&self, missing: bool) {
        self.inner.borrow_mut().missing = missing;
    }
}

impl LoadCell for SimLoadCell {
    async fn read_raw(&mut self) -> Result<i32, SensorError> {
        if self.inner.borrow().missing {
            Timer::after(hx711::READY_TIMEOUT).await;
            return Err(SensorError::Timeout);
        }
        let (conversion, ready_at) = {
            let inner = self.inner.borrow();
            let interval = hx711::SAMPLE_INTERVAL.as_ticks();
            let latest = (Instant::now() - inner.started).as_ticks() / interval;
            // Conversion 0 is the start itself, not a sample.
            let next = match inner.last_read {
                Some(last) => latest.max(last + 1),
                None => latest.max(1),
            };
            (next, inner.started + Duration::from_ticks(next * interval))
        };
        Timer::at(ready_at).await;
        let mut inner = self.inner.borrow_mut();
        inner.last_read = Some(conversion);
        inner.sample()
    }
}

struct WatchdogInner {
    timeout: Duration,
    last_feed: Instant,
    feeds: u32,
    bitten_at: Option<Instant>,
}

impl WatchdogInner {
    /// Records the bite if the timeout ran out since the last feed. A real watchdog
    /// resets the chip at that moment; this one notes when, and the test decides.
    fn check(&mut self, now: Instant) {
        let due = self.last_feed + self.timeout;
        if self.bitten_at.is_none() && now >= due {
            self.bitten_at = Some(due);
        }
    }
}

/// The hardware watchdog: it bites `timeout` after the last feed (or after creation,
/// when it was armed). A feed at that very instant is too late, as on a chip whose
/// counter reached its limit.
#[derive(Clone)]
pub struct SimWatchdog {
    inner: Rc<RefCell<WatchdogInner>>,
}

impl SimWatchdog {
    /// A watchdog armed now.
    pub fn new(timeout: Duration) -> Self {
        Self {
            inner: Rc::new(RefCell::new(WatchdogInner {
                timeout,
                last_feed: Instant::now(),
                feeds: 0,
                bitten_at: None,
            })),
        }
    }

    /// When it first bit, if it did by now.
    pub fn bitten_at(&self) -> Option<Instant> {
        let mut inner = self.inner.borrow_mut();
        inner.check(Instant::now());
        inner.bitten_at
    }

    pub fn has_bitten(&self) -> bool {
        self.bitten_at().is_some()
    }

    pub fn feeds(&self) -> u32 {
        self.inner.borrow().feeds
    }
}

impl Watchdog for SimWatchdog {
    fn feed(&mut self) {
        let mut inner = self.inner.borrow_mut();
        let now = Instant::now();
        inner.check(now);
        inner.last_feed = now;
        inner.feeds += 1;
    }
}
