//! The load cell (docs/behaviour.md, Scale): averaging of raw HX711 samples and their conversion to
//! grams with registers 19 (`weight_offset`) and 20 (`scale_value`). The scale task
//! pushes samples; the feedback sender (0x0EA) and the scale calibration read the average.

/// Weight in grams for frame 0x0EA: (raw − offset) / (scale_value / 100), rounded to
/// the nearest gram. `weight_offset` is the full offset (registers 44/45).
///
/// Below zero (an empty scale drifting under its offset) reads 0, above 65535 g
/// saturates at 65535, as the contract's frame table says. `scale_value` 0 is refused by
/// the register table; should it ever reach this function it is treated as the limit of
/// an ever smaller divisor: any load saturates, no load reads 0. That reports "off
/// scale" rather than a plausible-looking weight, and never divides by zero.
pub fn weight_grams(raw: i32, weight_offset: i32, scale_value: u16) -> u16 {
    // i64: a 32-bit difference times 100 cannot overflow.
    let counts = i64::from(raw) - i64::from(weight_offset);
    if counts <= 0 {
        return 0;
    }
    if scale_value == 0 {
        return u16::MAX;
    }
    let scale_value = i64::from(scale_value);
    let grams = (counts * 100 + scale_value / 2) / scale_value;
    u16::try_from(grams).unwrap_or(u16::MAX)
}

/// Moving average over the last `N` raw samples.
///
/// The HX711 is noisy by a few counts; the average is what both the weight frame and
/// the calibration use. The sum is kept in `i64`, so any `i32` samples (not only the
/// HX711's 24 bits) can be averaged without overflow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RawAverage<const N: usize> {
    samples: [i32; N],
    /// Where the next sample goes (the oldest one once the window is full).
    next: usize,
    len: usize,
    sum: i64,
}

impl<const N: usize> RawAverage<N> {
    pub const fn new() -> Self {
        const { assert!(N > 0, "RawAverage needs a window of at least one sample") };
        Self {
            samples: [0; N],
            next: 0,
            len: 0,
            sum: 0,
        }
    }

    /// Add a sample, dropping the oldest once `N` are held.
    pub fn push(&mut self, sample: i32) {
        if self.len == N {
            self.sum -= i64::from(self.samples[self.next]);
        } else {
            self.len += 1;
        }
        self.samples[self.next] = sample;
        self.sum += i64::from(sample);
        self.next = (self.next + 1) % N;
    }

    /// Mean of the samples held, rounded to the nearest count (halves upwards); `None`
    /// before the first sample. A partly filled window is averaged over what it holds,
    /// so a reading exists right after boot.
    pub fn average(&self) -> Option<i32> {
        if self.len == 0 {
            return None;
        }
        let n = self.len as i64;
        // floor((sum + n/2) / n), done in halves so odd n rounds correctly too.
        let mean = (2 * self.sum + n).div_euclid(2 * n);
        // The mean of i32 values lies between their min and max, so it fits.
        i32::try_from(mean).ok()
    }

    /// Forget all samples, e.g. after the load cell stopped answering.
    pub fn clear(&mut self) {
        *self = Self::new();
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn is_full(&self) -> bool {
        self.len == N
    }
}

impl<const N: usize> Default for RawAverage<N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn default_registers_convert_19_counts_per_gram() {
        // weight_offset 20490, scale_value 1900 (register defaults)
        assert_eq!(weight_grams(20_490 + 19_000, 20_490, 1900), 1000);
        assert_eq!(weight_grams(20_490 + 19, 20_490, 1900), 1);
        assert_eq!(weight_grams(20_490, 20_490, 1900), 0);
    }

    #[test]
    fn offsets_beyond_16_bits_convert_too() {
        // An empty scale reading 80 000 or -15 000, 19 counts per gram.
        assert_eq!(weight_grams(80_000, 80_000, 1900), 0);
        assert_eq!(weight_grams(80_000 + 19_000, 80_000, 1900), 1000);
        assert_eq!(weight_grams(-15_000 + 1_900, -15_000, 1900), 100);
    }

    #[test]
    fn weight_is_rounded_to_the_nearest_gram() {
        // 28 counts / 19 = 1.47 g → 1; 29 / 19 = 1.53 g → 2
        assert_eq!(weight_grams(20_490 + 28, 20_490, 1900), 1);
        assert_eq!(weight_grams(20_490 + 29, 20_490, 1900), 2);
    }

    #[test]
    fn weight_below_zero_reads_zero() {
        assert_eq!(weight_grams(20_000, 20_490, 1900), 0);
        assert_eq!(weight_grams(i32::MIN, 65_535, 1), 0);
        assert_eq!(weight_grams(-8_388_608, 8_388_607, 1), 0);
    }

    #[test]
    fn weight_saturates_at_65535_grams() {
        assert_eq!(weight_grams(8_388_607, 0, 100), u16::MAX);
        assert_eq!(weight_grams(i32::MAX, 0, 1), u16::MAX);
        assert_eq!(weight_grams(65_535, 0, 100), 65_535);
    }

    #[test]
    fn zero_scale_value_saturates_a_load_and_never_divides_by_zero() {
        assert_eq!(weight_grams(30_000, 20_490, 0), u16::MAX);
        assert_eq!(weight_grams(20_490, 20_490, 0), 0);
        assert_eq!(weight_grams(10_000, 20_490, 0), 0);
    }

    #[test]
    fn average_is_none_before_the_first_sample() {
        let avg = RawAverage::<4>::new();
        assert_eq!(avg.average(), None);
        assert!(avg.is_empty());
    }

    #[test]
    fn average_of_a_partly_filled_window_uses_what_it_holds() {
        let mut avg = RawAverage::<4>::new();
        avg.push(10);
        avg.push(20);
        assert_eq!(avg.average(), Some(15));
        assert_eq!(avg.len(), 2);
        assert!(!avg.is_full());
    }

    #[test]
    fn average_drops_the_oldest_sample_once_full() {
        let mut avg = RawAverage::<3>::new();
        for s in [100, 200, 300, 400] {
            avg.push(s);
        }
        assert_eq!(avg.average(), Some(300));
        assert!(avg.is_full());
    }

    #[test]
    fn average_rounds_to_nearest_also_below_zero() {
        let mut avg = RawAverage::<2>::new();
        avg.push(1);
        avg.push(2);
        assert_eq!(avg.average(), Some(2)); // 1.5 → 2
        avg.push(-2);
        avg.push(-3);
        assert_eq!(avg.average(), Some(-2)); // -2.5 → -2 (halves upwards)
        let mut avg = RawAverage::<3>::new();
        for s in [-1, -1, 0] {
            avg.push(s);
        }
        assert_eq!(avg.average(), Some(-1)); // -0.67 → -1
    }

    #[test]
    fn clear_forgets_all_samples() {
        let mut avg = RawAverage::<3>::new();
        avg.push(5);
        avg.clear();
        assert_eq!(avg.average(), None);
        avg.push(7);
        assert_eq!(avg.average(), Some(7));
    }

    #[test]
    fn full_scale_24_bit_samples_do_not_overflow() {
        let mut avg = RawAverage::<64>::new();
        for _ in 0..64 {
            avg.push(8_388_607);
        }
        assert_eq!(avg.average(), Some(8_388_607));
        for _ in 0..64 {
            avg.push(-8_388_608);
        }
        assert_eq!(avg.average(), Some(-8_388_608));
    }

    proptest! {
        #[test]
        fn average_matches_the_mean_of_the_last_n_samples(
            samples in proptest::collection::vec(any::<i32>(), 1..40),
        ) {
            let mut avg = RawAverage::<8>::new();
            for &s in &samples {
                avg.push(s);
            }
            let window = &samples[samples.len().saturating_sub(8)..];
            let sum: i128 = window.iter().map(|&s| i128::from(s)).sum();
            let mean = sum as f64 / window.len() as f64;
            let got = f64::from(avg.average().unwrap());
            prop_assert!((got - mean).abs() <= 0.5, "got {got}, mean {mean}");
        }

        #[test]
        fn weight_never_decreases_as_the_load_grows(
            raw in -9_000_000i32..9_000_000,
            extra in 0i32..100_000,
            offset in -8_388_608i32..8_388_608,
            scale_value: u16,
        ) {
            prop_assert!(
                weight_grams(raw, offset, scale_value)
                    <= weight_grams(raw + extra, offset, scale_value)
            );
        }
    }
}
