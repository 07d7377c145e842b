//! Odometry calibration (0x008, docs/behaviour.md, Odometry calibration): owns the running calibration phase and the
//! pending correction factors. The CAN dispatcher hands it the steps, the odometry task
//! feeds it every raw (uncorrected) increment, and `Store` gives the factors to whoever
//! owns registers 16–18 and the flash.

use super::OdometryCalibrationCommand;

/// Lowest accepted factor, ×10000 (0.5, docs/behaviour.md).
pub const FACTOR_MIN: u16 = 5_000;
/// Highest accepted factor, ×10000 (1.5, docs/behaviour.md).
pub const FACTOR_MAX: u16 = 15_000;
/// Registers 16–18 hold the factors in units of 1/10000.
const FACTOR_SCALE: f64 = 10_000.0;

/// The running calibration step and what it has accumulated so far.
///
/// Every raw value counts in the direction its step asks for, so a correctly executed
/// step always ends with a positive raw value: `Linear` counts forward distance,
/// `Clockwise` counts clockwise rotation and `CounterClockwise` counts
/// counter-clockwise rotation (the negated sum of the clockwise-positive increments).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OdometryCalibrationPhase {
    #[default]
    Idle,
    Linear {
        raw_mm: f64,
    },
    Clockwise {
        raw_mrad: f64,
    },
    CounterClockwise {
        raw_mrad: f64,
    },
}

/// Factors ×10000 (registers 16, 17, 18), each `Some` only if its step was completed
/// since the last `Store`. Every `Some` value lies in `FACTOR_MIN..=FACTOR_MAX`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CalibratedFactors {
    pub f_cw: Option<u16>,
    pub f_ccw: Option<u16>,
    pub f_lin: Option<u16>,
}

impl CalibratedFactors {
    fn is_empty(&self) -> bool {
        self.f_cw.is_none() && self.f_ccw.is_none() && self.f_lin.is_none()
    }
}

/// Why a calibration step was rejected. The codes go into the status frame's "last
/// rejection reason" and are stable: never renumber, only append within 0x20..=0x2F.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum OdometryCalibrationError {
    /// An end step (`0C`, `16`, `20`) arrived while its own start step was not running.
    EndWithoutStart = 0x20,
    /// The raw value of the step is zero or points the wrong way (driven backwards,
    /// turned the other way, not moved at all).
    ZeroRawValue = 0x21,
    /// real / raw lies outside 0.5 … 1.5: a measuring or operating mistake, not a wheel.
    FactorOutOfRange = 0x22,
    /// `Store` (`04`) with no completed step since the last store.
    NothingPending = 0x23,
}

impl OdometryCalibrationError {
    /// Stable numeric code for the CAN status frame.
    pub const fn code(self) -> u8 {
        self as u8
    }
}

/// The odometry calibration state machine.
///
/// ```text
///              StartLinear / StartClockwise / StartCounterClockwise
///          ┌──────────────────────────────────────────────┐  (any phase: restart at raw 0,
///          │                                              ▼   pending factors kept)
///        Idle ◀──────── End of the running phase ────── Linear{raw_mm}
///          ▲            Ok  → factor pending             Clockwise{raw_mrad}
///          │            Err → phase ended anyway,        CounterClockwise{raw_mrad}
///          │                  pending untouched              │   ▲
///          │                                                 └───┘ observe(): accumulate
///          │                                                       End of another phase:
///          │                                                       EndWithoutStart, phase kept
///   Store: pending → returned and cleared (phase unchanged); nothing pending → NothingPending
/// ```
///
/// Decisions (the protocol leaves them open):
/// - A rejected end of the running phase (zero raw, factor out of range) still ends the
///   phase: the measurement is unusable, and a fresh start makes sure no motion from
///   before the retry leaks into the next attempt. Pending factors are untouched.
/// - An end step of a phase that is *not* running is rejected and leaves the running
///   phase alone: a stray or mistyped frame must not destroy a measurement in progress.
/// - The range check is done on the rounded register value, so the stored factor is
///   always within `FACTOR_MIN..=FACTOR_MAX`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OdometryCalibration {
    phase: OdometryCalibrationPhase,
    pending: CalibratedFactors,
}

impl OdometryCalibration {
    pub const fn new() -> Self {
        Self {
            phase: OdometryCalibrationPhase::Idle,
            pending: CalibratedFactors {
                f_cw: None,
                f_ccw: None,
                f_lin: None,
            },
        }
    }

    /// The running step, for the status frame and for tests.
    pub fn phase(&self) -> OdometryCalibrationPhase {
        self.phase
    }

    /// Factors computed but not yet stored.
    pub fn pending(&self) -> CalibratedFactors {
        self.pending
    }

    /// Feed one raw (uncorrected) odometry increment: distance in mm (+ forward),
    /// rotation in mrad (+ clockwise). Only the running phase accumulates, and only the
    /// quantity it calibrates.
    pub fn observe(&mut self, raw_distance_mm: f64, raw_rotation_mrad: f64) {
        // A NaN would poison the whole sum and only surface at the end step as a
        // confusing rejection; odometry never produces one, so dropping it costs nothing.
        if !raw_distance_mm.is_finite() || !raw_rotation_mrad.is_finite() {
            return;
        }
        match &mut self.phase {
            OdometryCalibrationPhase::Idle => {}
            OdometryCalibrationPhase::Linear { raw_mm } => *raw_mm += raw_distance_mm,
            OdometryCalibrationPhase::Clockwise { raw_mrad } => *raw_mrad += raw_rotation_mrad,
            OdometryCalibrationPhase::CounterClockwise { raw_mrad } => {
                *raw_mrad -= raw_rotation_mrad
            }
        }
    }

    /// Apply one step. `Ok(Some(_))` only for `Store`: the caller writes the `Some`
    /// factors to registers 16–18 and flash.
    pub fn step(
        &mut self,
        cmd: OdometryCalibrationCommand,
    ) -> Result<Option<CalibratedFactors>, OdometryCalibrationError> {
        use OdometryCalibrationCommand as Cmd;
        use OdometryCalibrationPhase as Phase;
        match cmd {
            Cmd::StartLinear => {
                self.phase = Phase::Linear { raw_mm: 0.0 };
                Ok(None)
            }
            Cmd::StartClockwise => {
                self.phase = Phase::Clockwise { raw_mrad: 0.0 };
                Ok(None)
            }
            Cmd::StartCounterClockwise => {
                self.phase = Phase::CounterClockwise { raw_mrad: 0.0 };
                Ok(None)
            }
            Cmd::EndLinear { real_mm } => {
                let Phase::Linear { raw_mm } = self.phase else {
                    return Err(OdometryCalibrationError::EndWithoutStart);
                };
                self.phase = Phase::Idle;
                self.pending.f_lin = Some(factor(real_mm, raw_mm)?);
                Ok(None)
            }
            Cmd::EndClockwise { real_mrad } => {
                let Phase::Clockwise { raw_mrad } = self.phase else {
                    return Err(OdometryCalibrationError::EndWithoutStart);
                };
                self.phase = Phase::Idle;
                self.pending.f_cw = Some(factor(real_mrad, raw_mrad)?);
                Ok(None)
            }
            Cmd::EndCounterClockwise { real_mrad } => {
                let Phase::CounterClockwise { raw_mrad } = self.phase else {
                    return Err(OdometryCalibrationError::EndWithoutStart);
                };
                self.phase = Phase::Idle;
                self.pending.f_ccw = Some(factor(real_mrad, raw_mrad)?);
                Ok(None)
            }
            Cmd::Store => {
                if self.pending.is_empty() {
                    return Err(OdometryCalibrationError::NothingPending);
                }
                Ok(Some(core::mem::take(&mut self.pending)))
            }
        }
    }
}

/// real / raw as a register value (×10000, rounded), or why not.
fn factor(real: u16, raw: f64) -> Result<u16, OdometryCalibrationError> {
    if raw.is_nan() || raw <= 0.0 {
        return Err(OdometryCalibrationError::ZeroRawValue);
    }
    let scaled = libm::round(f64::from(real) / raw * FACTOR_SCALE);
    if (f64::from(FACTOR_MIN)..=f64::from(FACTOR_MAX)).contains(&scaled) {
        // In range, so the cast is exact.
        Ok(scaled as u16)
    } else {
        Err(OdometryCalibrationError::FactorOutOfRange)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use OdometryCalibrationCommand as Cmd;
    use OdometryCalibrationError as E;

    /// Drive `total` in `steps` equal increments, as the odometry task would.
    fn observe_in_steps(cal: &mut OdometryCalibration, distance_mm: f64, rotation_mrad: f64) {
        const STEPS: u32 = 200;
        for _ in 0..STEPS {
            cal.observe(
                distance_mm / f64::from(STEPS),
                rotation_mrad / f64::from(STEPS),
            );
        }
    }

    #[test]
    fn full_flow_computes_all_three_factors_and_store_hands_them_over() {
        let mut cal = OdometryCalibration::new();

        assert_eq!(cal.step(Cmd::StartLinear), Ok(None));
        observe_in_steps(&mut cal, 2000.0, 3.0); // a little rotation noise is ignored
        assert_eq!(cal.step(Cmd::EndLinear { real_mm: 2014 }), Ok(None));

        assert_eq!(cal.step(Cmd::StartClockwise), Ok(None));
        observe_in_steps(&mut cal, 1.0, 6320.0);
        assert_eq!(cal.step(Cmd::EndClockwise { real_mrad: 6283 }), Ok(None));

        assert_eq!(cal.step(Cmd::StartCounterClockwise), Ok(None));
        observe_in_steps(&mut cal, -1.0, -6350.0);
        assert_eq!(
            cal.step(Cmd::EndCounterClockwise { real_mrad: 6283 }),
            Ok(None)
        );
        assert_eq!(cal.phase(), OdometryCalibrationPhase::Idle);

        let stored = cal.step(Cmd::Store);
        assert_eq!(
            stored,
            Ok(Some(CalibratedFactors {
                f_lin: Some(10070), // 2014 / 2000
                f_cw: Some(9941),   // 6283 / 6320 = 0.994146
                f_ccw: Some(9894),  // 6283 / 6350 = 0.989449
            }))
        );
        assert_eq!(cal.pending(), CalibratedFactors::default());
        assert_eq!(cal.step(Cmd::Store), Err(E::NothingPending));
    }

    #[test]
    fn store_returns_only_the_steps_that_were_completed() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartClockwise).unwrap();
        cal.observe(0.0, 1000.0);
        cal.step(Cmd::EndClockwise { real_mrad: 1100 }).unwrap();
        assert_eq!(
            cal.step(Cmd::Store),
            Ok(Some(CalibratedFactors {
                f_cw: Some(11000),
                f_ccw: None,
                f_lin: None,
            }))
        );
    }

    #[test]
    fn observe_while_idle_accumulates_nothing() {
        let mut cal = OdometryCalibration::new();
        cal.observe(500.0, 500.0);
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        assert_eq!(
            cal.phase(),
            OdometryCalibrationPhase::Linear { raw_mm: 1000.0 }
        );
    }

    #[test]
    fn observe_ignores_non_finite_increments() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        cal.observe(f64::NAN, 0.0);
        cal.observe(f64::INFINITY, 0.0);
        cal.observe(5.0, f64::NAN);
        assert_eq!(
            cal.phase(),
            OdometryCalibrationPhase::Linear { raw_mm: 1000.0 }
        );
    }

    #[test]
    fn restarting_a_phase_discards_its_raw_sum_but_keeps_pending_factors() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        cal.step(Cmd::EndLinear { real_mm: 1010 }).unwrap();

        cal.step(Cmd::StartClockwise).unwrap();
        cal.observe(0.0, 9999.0);
        cal.step(Cmd::StartClockwise).unwrap();
        cal.observe(0.0, 1000.0);
        cal.step(Cmd::EndClockwise { real_mrad: 990 }).unwrap();

        assert_eq!(
            cal.pending(),
            CalibratedFactors {
                f_lin: Some(10100),
                f_cw: Some(9900),
                f_ccw: None,
            }
        );
    }

    #[test]
    fn end_without_start_is_rejected() {
        let mut cal = OdometryCalibration::new();
        assert_eq!(
            cal.step(Cmd::EndLinear { real_mm: 1000 }),
            Err(E::EndWithoutStart)
        );
        assert_eq!(
            cal.step(Cmd::EndClockwise { real_mrad: 1000 }),
            Err(E::EndWithoutStart)
        );
        assert_eq!(
            cal.step(Cmd::EndCounterClockwise { real_mrad: 1000 }),
            Err(E::EndWithoutStart)
        );
        assert_eq!(cal.pending(), CalibratedFactors::default());
    }

    #[test]
    fn end_of_another_phase_is_rejected_and_keeps_the_running_measurement() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        assert_eq!(
            cal.step(Cmd::EndClockwise { real_mrad: 1000 }),
            Err(E::EndWithoutStart)
        );
        assert_eq!(
            cal.step(Cmd::EndCounterClockwise { real_mrad: 1000 }),
            Err(E::EndWithoutStart)
        );
        assert_eq!(
            cal.phase(),
            OdometryCalibrationPhase::Linear { raw_mm: 1000.0 }
        );
        assert_eq!(cal.step(Cmd::EndLinear { real_mm: 1005 }), Ok(None));
        assert_eq!(cal.pending().f_lin, Some(10050));
    }

    #[test]
    fn end_after_an_already_ended_phase_is_rejected() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        cal.step(Cmd::EndLinear { real_mm: 1000 }).unwrap();
        assert_eq!(
            cal.step(Cmd::EndLinear { real_mm: 1000 }),
            Err(E::EndWithoutStart)
        );
    }

    #[test]
    fn linear_end_without_motion_is_a_zero_raw_value() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        assert_eq!(
            cal.step(Cmd::EndLinear { real_mm: 1000 }),
            Err(E::ZeroRawValue)
        );
    }

    #[test]
    fn linear_end_after_driving_backwards_is_a_zero_raw_value() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        observe_in_steps(&mut cal, -1000.0, 0.0);
        assert_eq!(
            cal.step(Cmd::EndLinear { real_mm: 1000 }),
            Err(E::ZeroRawValue)
        );
    }

    #[test]
    fn clockwise_end_after_turning_counter_clockwise_is_a_zero_raw_value() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartClockwise).unwrap();
        observe_in_steps(&mut cal, 0.0, -6283.0);
        assert_eq!(
            cal.step(Cmd::EndClockwise { real_mrad: 6283 }),
            Err(E::ZeroRawValue)
        );
    }

    #[test]
    fn counter_clockwise_end_after_turning_clockwise_is_a_zero_raw_value() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartCounterClockwise).unwrap();
        observe_in_steps(&mut cal, 0.0, 6283.0);
        assert_eq!(
            cal.step(Cmd::EndCounterClockwise { real_mrad: 6283 }),
            Err(E::ZeroRawValue)
        );
    }

    #[test]
    fn factors_just_outside_half_and_one_and_a_half_are_rejected() {
        for (real_mm, expected) in [
            (490, Err(E::FactorOutOfRange)),
            (1510, Err(E::FactorOutOfRange)),
            (0, Err(E::FactorOutOfRange)),
            (500, Ok(None)),
            (1500, Ok(None)),
        ] {
            let mut cal = OdometryCalibration::new();
            cal.step(Cmd::StartLinear).unwrap();
            cal.observe(1000.0, 0.0);
            assert_eq!(
                cal.step(Cmd::EndLinear { real_mm }),
                expected,
                "real {real_mm} mm over raw 1000 mm"
            );
        }
    }

    #[test]
    fn boundary_factors_are_stored_as_5000_and_15000() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartClockwise).unwrap();
        cal.observe(0.0, 1000.0);
        cal.step(Cmd::EndClockwise { real_mrad: 500 }).unwrap();
        cal.step(Cmd::StartCounterClockwise).unwrap();
        cal.observe(0.0, -1000.0);
        cal.step(Cmd::EndCounterClockwise { real_mrad: 1500 })
            .unwrap();
        assert_eq!(cal.pending().f_cw, Some(FACTOR_MIN));
        assert_eq!(cal.pending().f_ccw, Some(FACTOR_MAX));
    }

    #[test]
    fn rejected_end_ends_the_phase_and_leaves_pending_factors_untouched() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartClockwise).unwrap();
        cal.observe(0.0, 1000.0);
        cal.step(Cmd::EndClockwise { real_mrad: 1010 }).unwrap();

        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        assert_eq!(
            cal.step(Cmd::EndLinear { real_mm: 2000 }),
            Err(E::FactorOutOfRange)
        );
        assert_eq!(cal.phase(), OdometryCalibrationPhase::Idle);
        assert_eq!(
            cal.step(Cmd::EndLinear { real_mm: 1000 }),
            Err(E::EndWithoutStart)
        );
        assert_eq!(
            cal.pending(),
            CalibratedFactors {
                f_cw: Some(10100),
                f_ccw: None,
                f_lin: None,
            }
        );
    }

    #[test]
    fn store_with_nothing_pending_is_rejected() {
        let mut cal = OdometryCalibration::new();
        assert_eq!(cal.step(Cmd::Store), Err(E::NothingPending));
        // A started but unfinished step is not a result either.
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        assert_eq!(cal.step(Cmd::Store), Err(E::NothingPending));
    }

    #[test]
    fn store_does_not_interrupt_a_running_phase() {
        let mut cal = OdometryCalibration::new();
        cal.step(Cmd::StartLinear).unwrap();
        cal.observe(1000.0, 0.0);
        cal.step(Cmd::EndLinear { real_mm: 1000 }).unwrap();
        cal.step(Cmd::StartClockwise).unwrap();
        cal.observe(0.0, 300.0);
        assert!(matches!(cal.step(Cmd::Store), Ok(Some(_))));
        assert_eq!(
            cal.phase(),
            OdometryCalibrationPhase::Clockwise { raw_mrad: 300.0 }
        );
    }

    #[test]
    fn error_codes_are_stable() {
        assert_eq!(E::EndWithoutStart.code(), 0x20);
        assert_eq!(E::ZeroRawValue.code(), 0x21);
        assert_eq!(E::FactorOutOfRange.code(), 0x22);
        assert_eq!(E::NothingPending.code(), 0x23);
    }
}
