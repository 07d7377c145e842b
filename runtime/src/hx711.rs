//! The HX711 load-cell ADC, bit-banged on two pins: DOUT (low = a conversion is ready)
//! and PD_SCK (the clock the driver drives). The scale task reads it through
//! [`LoadCell`]; the chip shell hands over the two pins and a blocking delay.
//!
//! Timing (HX711 datasheet, "Serial Interface"): each PD_SCK pulse shifts out one bit,
//! MSB first, valid at most 0.1 µs after the rising edge. The high time must be
//! 0.2–50 µs, because a clock held high for more than 60 µs powers the chip down; the
//! low time must be at least 0.2 µs and has no upper limit. After the 24 data bits,
//! 1–3 more pulses choose channel and gain of the *next* conversion ([`Gain`]).

use embassy_time::{Duration, Instant, Timer};
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{InputPin, OutputPin};

use crate::hw::{LoadCell, SensorError};

/// Time between two conversions with the RATE pin low (10 samples per second).
pub const SAMPLE_INTERVAL: Duration = Duration::from_millis(100);

/// Longest wait for DOUT to go low before a read gives up with
/// [`SensorError::Timeout`]. Two sample intervals: a read that starts just after a
/// sample was taken waits almost a full interval, and the internal oscillator that
/// paces the conversions is not exact. A missing or unpowered chip (DOUT pulled high)
/// is reported after this time.
pub const READY_TIMEOUT: Duration = Duration::from_millis(200);

/// How often DOUT is checked while waiting. A sample waits at most this long to be
/// read, which is nothing next to the 100 ms between samples; the cost is one pin read
/// per millisecond.
const READY_POLL: Duration = Duration::from_millis(1);

/// PD_SCK high time. Five times the datasheet minimum (0.2 µs) and ten times the data
/// delay after the rising edge (0.1 µs), so a coarse chip delay still meets both, and
/// far from the 50 µs maximum.
const SCK_HIGH_NS: u32 = 1_000;

/// PD_SCK low time between pulses; the datasheet minimum is 0.2 µs.
const SCK_LOW_NS: u32 = 1_000;

/// How long [`Hx711::power_down`] holds PD_SCK high: past the 60 µs after which the
/// chip is guaranteed to be down.
const POWER_DOWN_US: u32 = 80;

/// Bits of one conversion.
const DATA_BITS: u32 = 24;

/// The positive rail: the input is above the range (or a signal wire is broken).
const SATURATED_HIGH: u32 = 0x7F_FFFF;

/// The negative rail.
const SATURATED_LOW: u32 = 0x80_0000;

/// Channel and gain of the conversion after the current read, chosen by the number of
/// PD_SCK pulses that follow the 24 data bits.
///
/// The load cell is wired to channel A; gain 128 gives its full-scale input of ±20 mV,
/// which suits a bridge at 5 V excitation. It is also what the chip uses after power-up
/// or reset, so the first read after [`Hx711::power_up`] is always at this gain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Gain {
    /// Channel A, gain 128 (±20 mV full scale): 25 pulses.
    #[default]
    ChannelA128,
    /// Channel B, gain 32 (±80 mV full scale): 26 pulses.
    ChannelB32,
    /// Channel A, gain 64 (±40 mV full scale): 27 pulses.
    ChannelA64,
}

impl Gain {
    /// Pulses after the 24 data bits that select this setting.
    pub const fn extra_pulses(self) -> u32 {
        match self {
            Gain::ChannelA128 => 1,
            Gain::ChannelB32 => 2,
            Gain::ChannelA64 => 3,
        }
    }
}

/// Turns the 24 bits from the chip (MSB first, two's complement, in the low 24 bits of
/// `word`) into a signed value.
///
/// The two rails, 0x7FFFFF and 0x800000, are [`SensorError::Invalid`]: the chip
/// clamps there when the input is out of range, which means an overloaded cell or a
/// broken bridge wire. Neither is a weight, and passing the rail on would read as the
/// largest possible load (or none) and drag the moving average with it; the scale task
/// skips an invalid sample and keeps its last average instead.
pub const fn decode(word: u32) -> Result<i32, SensorError> {
    match word & 0xFF_FFFF {
        SATURATED_HIGH | SATURATED_LOW => Err(SensorError::Invalid),
        // Moving bit 23 to bit 31 and shifting back arithmetically copies the sign bit.
        bits => Ok((bits << 8).cast_signed() >> 8),
    }
}

/// The HX711 on a DOUT input, a PD_SCK output and a blocking delay for the
/// sub-microsecond pulses.
///
/// PD_SCK must already be low when the driver gets it (configure the output low):
/// a clock that was high for more than 60 µs has the chip powered down, and the first
/// conversion after power-up needs the datasheet's 400 ms settling time.
pub struct Hx711<Dout, Sck, Delay> {
    dout: Dout,
    sck: Sck,
    delay: Delay,
    gain: Gain,
}

impl<Dout, Sck, Delay> Hx711<Dout, Sck, Delay>
where
    Dout: InputPin,
    Sck: OutputPin,
    Delay: DelayNs,
{
    pub fn new(dout: Dout, sck: Sck, delay: Delay, gain: Gain) -> Self {
        Self {
            dout,
            sck,
            delay,
            gain,
        }
    }

    pub fn gain(&self) -> Gain {
        self.gain
    }

    /// Chooses the gain that the pulses at the end of each read select. The chip applies it
    /// to the conversion after the next read: that read still returns a value at the
    /// old gain, and the datasheet allows 400 ms to settle after a change.
    pub fn set_gain(&mut self, gain: Gain) {
        self.gain = gain;
    }

    /// Powers the chip down (about 1 µA): PD_SCK stays high until [`Self::power_up`].
    pub fn power_down(&mut self) -> Result<(), SensorError> {
        self.sck.set_high().map_err(pin_error)?;
        // Returning before 60 µs have passed would let a quick power_up turn this into
        // an ordinary clock pulse that shifts out a data bit.
        self.delay.delay_us(POWER_DOWN_US);
        Ok(())
    }

    /// Powers the chip up again. It resets to channel A, gain 128; the first read sets
    /// the configured gain for the conversion after it.
    pub fn power_up(&mut self) -> Result<(), SensorError> {
        self.sck.set_low().map_err(pin_error)
    }

    pub fn release(self) -> (Dout, Sck, Delay) {
        (self.dout, self.sck, self.delay)
    }

    async fn wait_ready(&mut self) -> Result<(), SensorError> {
        let deadline = Instant::now() + READY_TIMEOUT;
        loop {
            if self.dout.is_low().map_err(pin_error)? {
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(SensorError::Timeout);
            }
            Timer::after(READY_POLL).await;
        }
    }

    /// Clocks out the 24 data bits and the gain pulses. Synchronous on purpose: no other
    /// task may run between the pulses, only interrupts, and those only in low phases.
    fn shift_in(&mut self) -> Result<u32, SensorError> {
        let mut word = 0;
        for _ in 0..DATA_BITS {
            word = (word << 1) | u32::from(self.pulse()?);
        }
        for _ in 0..self.gain.extra_pulses() {
            self.pulse()?;
        }
        Ok(word)
    }

    /// One PD_SCK pulse; returns DOUT as sampled during the high phase.
    ///
    /// Only the high phase runs with interrupts off. An interrupt there could stretch
    /// the pulse past 60 µs and power the chip down mid-read, while a stretched low
    /// phase is harmless. So interrupts are held off about 1 µs per pulse, instead of
    /// some 50 µs for a whole 25-27 pulse read, which would delay the CAN and UART
    /// interrupts for no gain.
    fn pulse(&mut self) -> Result<bool, SensorError> {
        let Self {
            dout, sck, delay, ..
        } = self;
        let high = critical_section::with(|_| {
            sck.set_high().map_err(pin_error)?;
            delay.delay_ns(SCK_HIGH_NS);
            let level = dout.is_high();
            // The clock goes low even when reading DOUT failed: left high, it would
            // power the chip down.
            sck.set_low().map_err(pin_error)?;
            level.map_err(pin_error)
        })?;
        self.delay.delay_ns(SCK_LOW_NS);
        Ok(high)
    }
}

impl<Dout, Sck, Delay> LoadCell for Hx711<Dout, Sck, Delay>
where
    Dout: InputPin,
    Sck: OutputPin,
    Delay: DelayNs,
{
    /// Waits up to [`READY_TIMEOUT`] for a conversion and reads it.
    ///
    /// A pin error is [`SensorError::Invalid`]: the bits cannot be trusted. If it
    /// happens mid-read the chip is left part-way through the word; a
    /// [`Hx711::power_down`] and [`Hx711::power_up`] resets it. (The chip's GPIOs
    /// cannot fail; this is for pins behind an expander.)
    async fn read_raw(&mut self) -> Result<i32, SensorError> {
        self.wait_ready().await?;
        decode(self.shift_in()?)
    }
}

fn pin_error<E: embedded_hal::digital::Error>(_: E) -> SensorError {
    SensorError::Invalid
}

#[cfg(test)]
mod tests {
    //! A scripted HX711 behind fake pins. It shifts out a given word on the clock the
    //! driver produces and checks that clock against the datasheet's timing; the fake
    //! delay is its clock for pulse widths, while waiting for DOUT runs on a virtual
    //! `embassy-time` clock that jumps to the next timer at once.

    use super::*;
    use core::cell::{Cell, RefCell};
    use core::task::Waker;
    use std::rc::Rc;
    use std::string::String;
    use std::vec::Vec;

    use embassy_futures::block_on;
    use embedded_hal::digital::{ErrorKind, ErrorType};

    /// The `embassy-time` driver of this test binary (the library's only tests that
    /// need a clock). Per thread, because tests run on parallel threads. A timer moves
    /// the clock straight to its deadline, so a wait takes no real time and its end is
    /// exact.
    struct JumpingClock;

    thread_local! {
        static NOW: Cell<u64> = const { Cell::new(0) };
    }

    impl embassy_time_driver::Driver for JumpingClock {
        fn now(&self) -> u64 {
            NOW.with(Cell::get)
        }

        fn schedule_wake(&self, at: u64, waker: &Waker) {
            NOW.with(|now| now.set(now.get().max(at)));
            waker.wake_by_ref();
        }
    }

    embassy_time_driver::time_driver_impl!(static DRIVER: JumpingClock = JumpingClock);

    const MIN_HIGH_NS: u64 = 200;
    const MAX_HIGH_NS: u64 = 50_000;
    const POWER_DOWN_NS: u64 = 60_000;
    const MIN_LOW_NS: u64 = 200;
    const DATA_VALID_NS: u64 = 100;

    struct Chip {
        /// The finished conversion, if any; DOUT stays high until `ready_at`.
        word: Option<u32>,
        ready_at: Instant,
        sck_high: bool,
        /// Rising edges since the conversion was loaded.
        pulses: u32,
        /// Nanoseconds of fake delay so far; the clock of pulse widths.
        elapsed_ns: u64,
        last_edge_ns: Option<u64>,
        longest_high_ns: u64,
        /// Power-down/up cycles: a high phase past 60 µs, after which the chip resets.
        resets: u32,
        /// Timing rules the driver broke, in words.
        violations: Vec<String>,
        /// DOUT reads fail from this rising edge on (1-based), to test pin errors.
        fail_dout_at_pulse: Option<u32>,
    }

    impl Chip {
        /// A chip with `word` converted and ready now.
        fn new(word: u32) -> Self {
            Self {
                word: Some(word),
                ready_at: Instant::now(),
                sck_high: false,
                pulses: 0,
                elapsed_ns: 0,
                last_edge_ns: None,
                longest_high_ns: 0,
                resets: 0,
                violations: Vec::new(),
                fail_dout_at_pulse: None,
            }
        }

        fn ready(&self) -> bool {
            self.word.is_some() && Instant::now() >= self.ready_at
        }

        /// DOUT: the ready flag before the first pulse, then bit 23 down to bit 0, each
        /// from its rising edge on, then high from the 25th pulse.
        fn dout_high(&self) -> bool {
            match (self.pulses, self.word) {
                (0, _) => !self.ready(),
                (n @ 1..=24, Some(word)) => word >> (24 - n) & 1 == 1,
                _ => true,
            }
        }

        fn rising_edge(&mut self) {
            if let Some(last) = self.last_edge_ns {
                let low = self.elapsed_ns - last;
                if low < MIN_LOW_NS {
                    self.violations.push(format!("low for only {low} ns"));
                }
            }
            if self.pulses == 0 && !self.ready() {
                self.violations
                    .push("clocked before DOUT signalled ready".into());
            }
            self.pulses += 1;
            self.sck_high = true;
            self.last_edge_ns = Some(self.elapsed_ns);
        }

        fn falling_edge(&mut self) {
            let high = self.elapsed_ns - self.last_edge_ns.unwrap_or(0);
            if high > POWER_DOWN_NS {
                // The rising edge that started the power-down counted as pulse 1.
                if self.pulses > 1 {
                    self.violations.push("powered down mid-read".into());
                }
                self.pulses = 0;
                self.resets += 1;
            } else {
                self.longest_high_ns = self.longest_high_ns.max(high);
                if !(MIN_HIGH_NS..=MAX_HIGH_NS).contains(&high) {
                    self.violations.push(format!("high for {high} ns"));
                }
            }
            self.sck_high = false;
            self.last_edge_ns = Some(self.elapsed_ns);
        }
    }

    #[derive(Debug)]
    struct PinFault;

    impl embedded_hal::digital::Error for PinFault {
        fn kind(&self) -> ErrorKind {
            ErrorKind::Other
        }
    }

    struct Dout(Rc<RefCell<Chip>>);
    struct Sck(Rc<RefCell<Chip>>);
    struct Delay(Rc<RefCell<Chip>>);

    impl ErrorType for Dout {
        type Error = PinFault;
    }

    impl InputPin for Dout {
        fn is_high(&mut self) -> Result<bool, PinFault> {
            let mut chip = self.0.borrow_mut();
            if chip
                .fail_dout_at_pulse
                .is_some_and(|from| chip.pulses >= from)
            {
                return Err(PinFault);
            }
            if chip.sck_high {
                let since_edge = chip.elapsed_ns - chip.last_edge_ns.unwrap_or(0);
                if since_edge < DATA_VALID_NS {
                    chip.violations
                        .push(format!("DOUT read {since_edge} ns after the rising edge"));
                }
            }
            Ok(chip.dout_high())
        }

        fn is_low(&mut self) -> Result<bool, PinFault> {
            self.is_high().map(|high| !high)
        }
    }

    impl ErrorType for Sck {
        type Error = PinFault;
    }

    impl OutputPin for Sck {
        fn set_high(&mut self) -> Result<(), PinFault> {
            let mut chip = self.0.borrow_mut();
            if !chip.sck_high {
                chip.rising_edge();
            }
            Ok(())
        }

        fn set_low(&mut self) -> Result<(), PinFault> {
            let mut chip = self.0.borrow_mut();
            if chip.sck_high {
                chip.falling_edge();
            }
            Ok(())
        }
    }

    impl DelayNs for Delay {
        fn delay_ns(&mut self, ns: u32) {
            self.0.borrow_mut().elapsed_ns += u64::from(ns);
        }
    }

    type Driver = Hx711<Dout, Sck, Delay>;

    fn chip_with(word: u32, gain: Gain) -> (Rc<RefCell<Chip>>, Driver) {
        let chip = Rc::new(RefCell::new(Chip::new(word)));
        let driver = Hx711::new(
            Dout(chip.clone()),
            Sck(chip.clone()),
            Delay(chip.clone()),
            gain,
        );
        (chip, driver)
    }

    fn read_word(word: u32) -> Result<i32, SensorError> {
        let (chip, mut hx) = chip_with(word, Gain::ChannelA128);
        let result = block_on(hx.read_raw());
        assert_eq!(chip.borrow().violations, Vec::<String>::new());
        result
    }

    #[test]
    fn reads_24_bits_msb_first() {
        // No bit pattern here reads the same backwards or shifted by one.
        assert_eq!(read_word(0x12_3456), Ok(0x12_3456));
        assert_eq!(read_word(0x00_0001), Ok(1));
        assert_eq!(read_word(0x40_0000), Ok(0x40_0000));
    }

    #[test]
    fn negative_values_are_sign_extended() {
        assert_eq!(read_word(0xFF_FFFF), Ok(-1));
        assert_eq!(read_word(0xAB_CDEF), Ok(0xAB_CDEF - 0x100_0000));
        assert_eq!(read_word(0x80_0001), Ok(-0x7F_FFFF));
    }

    #[test]
    fn zero_and_the_values_next_to_the_rails_are_valid() {
        assert_eq!(read_word(0), Ok(0));
        assert_eq!(read_word(0x7F_FFFE), Ok(0x7F_FFFE));
    }

    #[test]
    fn saturated_readings_are_invalid() {
        assert_eq!(read_word(0x7F_FFFF), Err(SensorError::Invalid));
        assert_eq!(read_word(0x80_0000), Err(SensorError::Invalid));
    }

    #[test]
    fn a_saturated_read_still_completes_the_word_and_the_gain_pulses() {
        let (chip, mut hx) = chip_with(0x7F_FFFF, Gain::ChannelA128);
        assert_eq!(block_on(hx.read_raw()), Err(SensorError::Invalid));
        assert_eq!(chip.borrow().pulses, 25);
    }

    #[test]
    fn gain_selects_25_26_or_27_pulses() {
        for (gain, pulses) in [
            (Gain::ChannelA128, 25),
            (Gain::ChannelB32, 26),
            (Gain::ChannelA64, 27),
        ] {
            let (chip, mut hx) = chip_with(0x12_3456, gain);
            assert_eq!(block_on(hx.read_raw()), Ok(0x12_3456), "{gain:?}");
            assert_eq!(chip.borrow().pulses, pulses, "{gain:?}");
            assert!(!chip.borrow().sck_high, "{gain:?}");
        }
    }

    #[test]
    fn the_default_gain_is_channel_a_128() {
        assert_eq!(Gain::default(), Gain::ChannelA128);
        let (chip, mut hx) = chip_with(5, Gain::default());
        block_on(hx.read_raw()).unwrap();
        assert_eq!(chip.borrow().pulses, 25);
    }

    #[test]
    fn set_gain_changes_the_pulses_of_the_next_read() {
        let (chip, mut hx) = chip_with(5, Gain::ChannelA128);
        hx.set_gain(Gain::ChannelA64);
        assert_eq!(hx.gain(), Gain::ChannelA64);
        block_on(hx.read_raw()).unwrap();
        assert_eq!(chip.borrow().pulses, 27);
    }

    #[test]
    fn clock_pulses_meet_the_datasheet_timing() {
        let (chip, mut hx) = chip_with(0xAB_CDEF, Gain::ChannelA64);
        block_on(hx.read_raw()).unwrap();
        let chip = chip.borrow();
        assert_eq!(chip.violations, Vec::<String>::new());
        assert!(chip.longest_high_ns >= MIN_HIGH_NS);
        assert!(chip.longest_high_ns <= MAX_HIGH_NS);
        assert_eq!(chip.resets, 0);
    }

    #[test]
    fn waits_for_dout_low_before_clocking() {
        let (chip, mut hx) = chip_with(0x12_3456, Gain::ChannelA128);
        let start = Instant::now();
        chip.borrow_mut().ready_at = start + Duration::from_millis(70);
        assert_eq!(block_on(hx.read_raw()), Ok(0x12_3456));
        // Polled every millisecond, so the read starts right when DOUT falls.
        assert_eq!(Instant::now() - start, Duration::from_millis(70));
        assert_eq!(chip.borrow().violations, Vec::<String>::new());
    }

    #[test]
    fn times_out_when_dout_never_goes_low() {
        let (chip, mut hx) = chip_with(0, Gain::ChannelA128);
        chip.borrow_mut().word = None;
        let start = Instant::now();
        assert_eq!(block_on(hx.read_raw()), Err(SensorError::Timeout));
        assert_eq!(Instant::now() - start, READY_TIMEOUT);
        assert_eq!(chip.borrow().pulses, 0);
    }

    #[test]
    fn a_pin_error_mid_read_is_invalid_and_leaves_the_clock_low() {
        let (chip, mut hx) = chip_with(0x12_3456, Gain::ChannelA128);
        chip.borrow_mut().fail_dout_at_pulse = Some(10);
        assert_eq!(block_on(hx.read_raw()), Err(SensorError::Invalid));
        let chip = chip.borrow();
        assert_eq!(chip.pulses, 10);
        assert!(!chip.sck_high);
    }

    #[test]
    fn a_pin_error_while_waiting_is_invalid() {
        let (chip, mut hx) = chip_with(0x12_3456, Gain::ChannelA128);
        chip.borrow_mut().fail_dout_at_pulse = Some(0);
        assert_eq!(block_on(hx.read_raw()), Err(SensorError::Invalid));
        assert_eq!(chip.borrow().pulses, 0);
    }

    #[test]
    fn power_down_holds_the_clock_high_past_60_us_and_power_up_releases_it() {
        let (chip, mut hx) = chip_with(0x12_3456, Gain::ChannelA128);
        hx.power_down().unwrap();
        assert!(chip.borrow().sck_high);
        let held_from = chip.borrow().last_edge_ns.unwrap();
        assert!(chip.borrow().elapsed_ns - held_from > POWER_DOWN_NS);
        hx.power_up().unwrap();
        {
            let chip = chip.borrow();
            assert!(!chip.sck_high);
            assert_eq!(chip.resets, 1);
            assert_eq!(chip.violations, Vec::<String>::new());
        }
        // Out of reset, the next conversion reads normally.
        assert_eq!(block_on(hx.read_raw()), Ok(0x12_3456));
        assert_eq!(chip.borrow().pulses, 25);
    }

    #[test]
    fn decode_sign_extends_and_ignores_bits_above_23() {
        assert_eq!(decode(0xFF00_0001), Ok(1));
        assert_eq!(decode(0x00FF_FFFE), Ok(-2));
        assert_eq!(decode(0x0080_0001), Ok(-8_388_607));
        assert_eq!(decode(0x007F_FFFE), Ok(8_388_606));
    }
}
