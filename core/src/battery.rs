//! Battery state (docs/behaviour.md, Battery): filters the ADC voltage so load steps do not make the
//! reading jump, and maps a voltage to a percentage. The battery task feeds it samples;
//! frame 0x0EB reports the filtered voltage and its percentage.

use crate::time::Timestamp;

/// The two ends of the discharge curve (registers `batt_empty_mv`, `batt_full_mv`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BatteryParams {
    /// Voltage that reads 0 %.
    pub empty_mv: u16,
    /// Voltage that reads 100 %.
    pub full_mv: u16,
}

/// Resting (open-circuit) voltage of a 12 V lead-acid block against its state of
/// charge: (percent, mV).
///
/// Source: the state-of-charge / open-circuit-voltage table that deep-cycle lead-acid
/// makers publish (Trojan Battery's User's Guide, 12 V column, 10 … 100 %: 11.51 …
/// 12.73 V, i.e. 1.92 … 2.12 V per cell). It follows the acid density (cell voltage ≈
/// specific gravity + 0.84 V), which falls almost linearly with charge, so the curve is
/// nearly straight and gets slightly steeper towards empty. The 0 % point is not in the
/// table; it is extrapolated with the slope of the lowest segment (0.15 V per 10 %).
/// AGM and gel blocks rest 0.05–0.1 V higher but have the same shape, which is why only
/// the shape is used: [`percent`] stretches it between `empty_mv` and `full_mv`, so any
/// pack voltage (12 V, 24 V, …) and any chosen "empty" work.
pub const REST_CURVE: [(u8, u32); 11] = [
    (0, 11_360),
    (10, 11_510),
    (20, 11_660),
    (30, 11_810),
    (40, 11_960),
    (50, 12_100),
    (60, 12_240),
    (70, 12_370),
    (80, 12_500),
    (90, 12_620),
    (100, 12_730),
];
const CURVE_EMPTY_MV: u32 = REST_CURVE[0].1;
const CURVE_FULL_MV: u32 = REST_CURVE[REST_CURVE.len() - 1].1;

/// State of charge in percent for `voltage_mv`, on [`REST_CURVE`] stretched so that
/// `empty_mv` reads 0 % and `full_mv` reads 100 %.
///
/// Clamped to 0 … 100 and monotonic in the voltage. If the parameters are inverted or
/// equal (`full_mv <= empty_mv`, refused by register validation) the result is a step:
/// 0 % up to `empty_mv`, 100 % above it; nothing divides by zero.
///
/// The curve describes a *resting* battery. While the base drives, the terminal voltage
/// sags with the current, so the percentage reads low under load; [`BatteryFilter`]
/// keeps short load steps out of it, sustained driving is not corrected.
pub fn percent(voltage_mv: u16, params: BatteryParams) -> u8 {
    let BatteryParams { empty_mv, full_mv } = params;
    if voltage_mv <= empty_mv {
        return 0;
    }
    if voltage_mv >= full_mv {
        return 100;
    }
    // Here empty_mv < voltage_mv < full_mv. Map the voltage onto the curve's own scale,
    // in µV so the rounding stays far below one percent.
    let above_empty = u64::from(voltage_mv - empty_mv);
    let span = u64::from(full_mv - empty_mv);
    let curve_span_uv = u64::from(CURVE_FULL_MV - CURVE_EMPTY_MV) * 1000;
    let curve_uv = u64::from(CURVE_EMPTY_MV) * 1000 + above_empty * curve_span_uv / span;

    for pair in REST_CURVE.windows(2) {
        let [(p_lo, v_lo), (p_hi, v_hi)] = [pair[0], pair[1]];
        let (v_lo_uv, v_hi_uv) = (u64::from(v_lo) * 1000, u64::from(v_hi) * 1000);
        if curve_uv <= v_hi_uv {
            let step = u64::from(p_hi - p_lo);
            let seg = v_hi_uv - v_lo_uv;
            // round(p_lo + step · (curve − v_lo) / seg)
            let above = (curve_uv - v_lo_uv) * step;
            let pct = u64::from(p_lo) + (2 * above + seg) / (2 * seg);
            return pct.min(100) as u8;
        }
    }
    100
}

/// Default time constant of [`BatteryFilter`]: long against a load step (a start, a
/// turn: a few seconds), short against the discharge (hours), and four times the
/// 5 s report period so consecutive reports move smoothly.
pub const DEFAULT_TIME_CONSTANT_MS: u32 = 20_000;

/// First-order low-pass on the battery voltage, driven by the sample times.
///
/// Each update moves the output towards the sample by `1 − exp(−Δt/τ)`: the exact
/// discretisation of an RC filter for an input held since the previous sample. So the
/// response does not depend on how often or how regularly samples come: after one time
/// constant of a voltage step the output has moved 63 % of the way, whatever the spacing.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BatteryFilter {
    time_constant_ms: u32,
    state: FilterState,
}

#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum FilterState {
    /// No sample yet: the first one is taken as it is, so the reading after boot is the
    /// battery voltage, not a climb from 0 V.
    Empty,
    Running {
        filtered_mv: f32,
        at: Timestamp,
    },
}

impl BatteryFilter {
    /// `time_constant_ms` 0 passes samples through unfiltered.
    pub const fn new(time_constant_ms: u32) -> Self {
        Self {
            time_constant_ms,
            state: FilterState::Empty,
        }
    }

    /// Feed a sample taken at `now`; returns the filtered voltage.
    pub fn update(&mut self, now: Timestamp, sample_mv: u16) -> u16 {
        let sample = f32::from(sample_mv);
        let filtered_mv = match self.state {
            FilterState::Empty => sample,
            FilterState::Running { filtered_mv, at } => {
                if self.time_constant_ms == 0 {
                    sample
                } else {
                    // A sample from the past (Δt = 0) changes nothing.
                    let dt_ms = now.millis_since(at) as f32;
                    let gain = 1.0 - libm::expf(-dt_ms / self.time_constant_ms as f32);
                    filtered_mv + gain * (sample - filtered_mv)
                }
            }
        };
        let at = match self.state {
            FilterState::Running { at, .. } if at > now => at,
            _ => now,
        };
        self.state = FilterState::Running { filtered_mv, at };
        to_mv(filtered_mv)
    }

    /// The filtered voltage, `None` before the first sample.
    pub fn value_mv(&self) -> Option<u16> {
        match self.state {
            FilterState::Empty => None,
            FilterState::Running { filtered_mv, .. } => Some(to_mv(filtered_mv)),
        }
    }

    /// Forget the history, so the next sample is taken as it is (e.g. after the
    /// battery was swapped).
    pub fn reset(&mut self) {
        self.state = FilterState::Empty;
    }
}

impl Default for BatteryFilter {
    fn default() -> Self {
        Self::new(DEFAULT_TIME_CONSTANT_MS)
    }
}

fn to_mv(value: f32) -> u16 {
    // The filter output lies between u16 samples, so the clamp only guards rounding.
    libm::roundf(value).clamp(0.0, f32::from(u16::MAX)) as u16
}

/// The resistor divider between the battery and the ADC pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VoltageDivider {
    /// From the battery to the pin, Ω.
    pub top_ohms: u32,
    /// From the pin to ground, Ω.
    pub bottom_ohms: u32,
}

impl VoltageDivider {
    /// The battery voltage that puts `pin_mv` on the pin, rounded, saturating at
    /// `u16::MAX`.
    pub const fn battery_mv(&self, pin_mv: u16) -> u16 {
        let total = self.top_ohms as u64 + self.bottom_ohms as u64;
        let bottom = self.bottom_ohms as u64;
        let battery = (pin_mv as u64 * total + bottom / 2) / bottom;
        if battery > u16::MAX as u64 {
            u16::MAX
        } else {
            battery as u16
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Two 12 V blocks in series, resting at 2 × 11.4 V when empty, 2 × 12.7 V when full.
    const PACK_24V: BatteryParams = BatteryParams {
        empty_mv: 22_800,
        full_mv: 25_400,
    };

    fn ms(ms: u64) -> Timestamp {
        Timestamp::from_millis(ms)
    }

    #[test]
    fn curve_end_points_read_0_and_100_percent() {
        assert_eq!(percent(22_800, PACK_24V), 0);
        assert_eq!(percent(25_400, PACK_24V), 100);
    }

    #[test]
    fn voltages_beyond_the_ends_are_clamped() {
        assert_eq!(percent(0, PACK_24V), 0);
        assert_eq!(percent(22_000, PACK_24V), 0);
        assert_eq!(percent(27_000, PACK_24V), 100);
        assert_eq!(percent(u16::MAX, PACK_24V), 100);
    }

    #[test]
    fn the_source_table_is_reproduced_for_a_12v_block() {
        let block = BatteryParams {
            empty_mv: 11_360,
            full_mv: 12_730,
        };
        for (pct, mv) in REST_CURVE {
            assert_eq!(percent(mv as u16, block), pct, "{mv} mV");
        }
        // Halfway between the 50 % and 60 % rows.
        assert_eq!(percent(12_170, block), 55);
    }

    #[test]
    fn middle_of_the_voltage_span_reads_below_half_because_the_curve_bends() {
        // 24.1 V is 50 % of the span; the table puts it at 46 %.
        assert_eq!(percent(24_100, PACK_24V), 46);
    }

    #[test]
    fn inverted_parameters_give_a_step_instead_of_dividing_by_zero() {
        let same = BatteryParams {
            empty_mv: 24_000,
            full_mv: 24_000,
        };
        assert_eq!(percent(23_999, same), 0);
        assert_eq!(percent(24_000, same), 0);
        assert_eq!(percent(24_001, same), 100);
        let inverted = BatteryParams {
            empty_mv: 25_000,
            full_mv: 24_000,
        };
        assert_eq!(percent(24_500, inverted), 0);
        assert_eq!(percent(25_001, inverted), 100);
    }

    proptest! {
        #[test]
        fn percent_is_monotonic_in_the_voltage(
            empty_mv: u16,
            span in 1u16..=u16::MAX,
            a: u16,
            b: u16,
        ) {
            let params = BatteryParams { empty_mv, full_mv: empty_mv.saturating_add(span) };
            let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
            prop_assert!(percent(lo, params) <= percent(hi, params));
        }

        #[test]
        fn percent_never_exceeds_100(empty_mv: u16, full_mv: u16, v: u16) {
            let params = BatteryParams { empty_mv, full_mv };
            prop_assert!(percent(v, params) <= 100);
        }
    }

    #[test]
    fn first_sample_initialises_the_filter() {
        let mut filter = BatteryFilter::default();
        assert_eq!(filter.value_mv(), None);
        assert_eq!(filter.update(ms(12_345), 24_800), 24_800);
        assert_eq!(filter.value_mv(), Some(24_800));
    }

    #[test]
    fn step_response_reaches_63_percent_after_one_time_constant() {
        let mut filter = BatteryFilter::new(20_000);
        filter.update(ms(0), 25_000);
        let mut out = 0;
        for t in (100..=20_000).step_by(100) {
            out = filter.update(ms(t), 23_000);
        }
        // 25 000 − 2000 · (1 − e⁻¹) = 23 735.8
        assert!((i32::from(out) - 23_736).abs() <= 2, "got {out}");
    }

    #[test]
    fn irregular_sample_spacing_gives_the_same_response() {
        let mut regular = BatteryFilter::new(20_000);
        let mut irregular = BatteryFilter::new(20_000);
        regular.update(ms(0), 25_000);
        irregular.update(ms(0), 25_000);
        for t in (100..=20_000).step_by(100) {
            regular.update(ms(t), 23_000);
        }
        for t in [7, 50, 51, 900, 4_000, 4_013, 11_000, 19_999, 20_000] {
            irregular.update(ms(t), 23_000);
        }
        let (a, b) = (regular.value_mv().unwrap(), irregular.value_mv().unwrap());
        assert!(a.abs_diff(b) <= 1, "regular {a}, irregular {b}");
    }

    #[test]
    fn a_two_volt_load_dip_lasting_one_second_moves_the_percentage_by_at_most_4_points() {
        let mut filter = BatteryFilter::default();
        let resting_mv = 24_800;
        filter.update(ms(0), resting_mv);
        let before = percent(resting_mv, PACK_24V);
        let mut lowest_mv = u16::MAX;
        for t in (100..=10_000).step_by(100) {
            let sample = if (2_000..3_000).contains(&t) {
                resting_mv - 2_000
            } else {
                resting_mv
            };
            lowest_mv = lowest_mv.min(filter.update(ms(t), sample));
        }
        // Unfiltered, the dip would read 0 % (22.8 V is empty).
        assert_eq!(percent(resting_mv - 2_000, PACK_24V), 0);
        // 2000 mV · (1 − e^(−1 s / 20 s)) = 97.5 mV
        assert!(resting_mv - lowest_mv <= 100, "lowest {lowest_mv} mV");
        let lowest = percent(lowest_mv, PACK_24V);
        assert!(before - lowest <= 4, "before {before} %, lowest {lowest} %");
    }

    #[test]
    fn sample_at_the_same_instant_does_not_move_the_output() {
        let mut filter = BatteryFilter::new(20_000);
        filter.update(ms(1_000), 24_000);
        assert_eq!(filter.update(ms(1_000), 20_000), 24_000);
        assert_eq!(filter.update(ms(500), 20_000), 24_000);
    }

    #[test]
    fn zero_time_constant_passes_samples_through() {
        let mut filter = BatteryFilter::new(0);
        filter.update(ms(0), 24_000);
        assert_eq!(filter.update(ms(10), 22_000), 22_000);
    }

    #[test]
    fn reset_makes_the_next_sample_the_value() {
        let mut filter = BatteryFilter::default();
        filter.update(ms(0), 24_000);
        filter.reset();
        assert_eq!(filter.update(ms(100), 26_000), 26_000);
    }

    #[test]
    fn the_divider_scales_the_pin_voltage_up_to_the_battery() {
        let divider = VoltageDivider {
            top_ohms: 120_000,
            bottom_ohms: 10_000,
        };
        assert_eq!(divider.battery_mv(0), 0);
        assert_eq!(divider.battery_mv(2_000), 26_000);
        // 1 mV on the pin is 13 mV at the battery; the result is rounded.
        assert_eq!(divider.battery_mv(1), 13);
    }

    #[test]
    fn the_divider_saturates_instead_of_wrapping() {
        let divider = VoltageDivider {
            top_ohms: 1_000_000,
            bottom_ohms: 1_000,
        };
        assert_eq!(divider.battery_mv(3_300), u16::MAX);
    }
}
