//! Scale calibration (0x007, docs/behaviour.md, Scale): owns which step of the load-cell calibration
//! has been done. The CAN dispatcher hands it the steps together with the current
//! averaged HX711 reading; the register/flash owner stores what it returns.

use super::ScaleCalibrationCommand;

/// How far the calibration has got. No reading is kept: each step uses the averaged
/// reading of the moment it arrives, so repeating a step is always harmless.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScaleCalibrationPhase {
    #[default]
    Idle,
    /// `01` received: waiting for the empty-scale reading.
    Started,
    /// `02` done: the offset is stored; waiting for the known weight.
    Tared,
}

/// A register value to store (and persist) right away.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScaleUpdate {
    /// New full scale offset (registers 44/45, and 19 clamped): the raw reading of the
    /// empty scale, any 24-bit value.
    Offset(i32),
    /// New `scale_value` (register 20): raw counts per gram ×100.
    ScaleValue(u16),
}

/// Why a scale calibration step was rejected. Stable codes for the status frame: never
/// renumber, only append within 0x30..=0x3F.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ScaleCalibrationError {
    /// `02` or `03` without a preceding `01`.
    NotStarted = 0x30,
    /// `03` after `01` but before `02`.
    NotTared = 0x31,
    /// The load cell delivers no reading (HX711 not ready or not fitted).
    NoReading = 0x32,
    /// The empty-scale reading lies outside the HX711's 24-bit range, so it is no
    /// reading of a working load cell. Since the offset holds any 24-bit value
    /// (registers 44/45) no HX711 reading is refused: the code stays for a broken
    /// sensor path and keeps its number.
    OffsetOutOfRange = 0x33,
    /// `03` with 0 g: the slope would divide by zero.
    ZeroWeight = 0x34,
    /// The slope does not fit register 20 (1..=65535), including a zero or negative
    /// slope (weight not on the scale, or the load cell wired the wrong way round).
    ScaleValueOutOfRange = 0x35,
}

impl ScaleCalibrationError {
    /// Stable numeric code for the CAN status frame.
    pub const fn code(self) -> u8 {
        self as u8
    }
}

/// The scale calibration state machine.
///
/// ```text
///            01 (from any phase: restart)
///    ┌───────────────────────────────┐
///    │                               ▼
///  Idle ◀──── 03 ok ──── Tared ◀── 02 ok ── Started
///    ▲   → ScaleValue      │  ▲  → Offset
///    │                     └──┘ 02 ok: re-tare (→ Offset)
///    └── any rejected step: phase unchanged, nothing stored
/// ```
///
/// Decisions (the protocol leaves them open):
/// - The offset is returned for storing at `02` already: taring alone is useful, and a
///   person who never sends `03` still gets a zeroed scale.
/// - A rejected step changes nothing, so the person can fix the cause (empty the scale,
///   put the weight on, correct the grams) and send the same step again.
/// - `03` uses `current_offset`, the register value in force, not a copy taken at `02`:
///   the scale value must match the offset the weight conversion will actually use,
///   even if register 19 was written in between.
/// - An error names the first missing step: `03` before `01` is `NotStarted`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScaleCalibration {
    phase: ScaleCalibrationPhase,
}

impl ScaleCalibration {
    pub const fn new() -> Self {
        Self {
            phase: ScaleCalibrationPhase::Idle,
        }
    }

    pub fn phase(&self) -> ScaleCalibrationPhase {
        self.phase
    }

    /// Apply one step. `averaged_raw` is the averaged HX711 reading now (`None` if the
    /// load cell gives none); `current_offset` is the full offset (registers 44/45).
    pub fn step(
        &mut self,
        cmd: ScaleCalibrationCommand,
        averaged_raw: Option<i32>,
        current_offset: i32,
    ) -> Result<Option<ScaleUpdate>, ScaleCalibrationError> {
        use ScaleCalibrationCommand as Cmd;
        use ScaleCalibrationPhase as Phase;
        match (self.phase, cmd) {
            (_, Cmd::Start) => {
                self.phase = Phase::Started;
                Ok(None)
            }
            (Phase::Idle, Cmd::Tare | Cmd::KnownWeight { .. }) => {
                Err(ScaleCalibrationError::NotStarted)
            }
            (Phase::Started, Cmd::KnownWeight { .. }) => Err(ScaleCalibrationError::NotTared),
            (Phase::Started | Phase::Tared, Cmd::Tare) => {
                let raw = averaged_raw.ok_or(ScaleCalibrationError::NoReading)?;
                if !(-(1 << 23)..1 << 23).contains(&raw) {
                    return Err(ScaleCalibrationError::OffsetOutOfRange);
                }
                self.phase = Phase::Tared;
                Ok(Some(ScaleUpdate::Offset(raw)))
            }
            (Phase::Tared, Cmd::KnownWeight { grams }) => {
                if grams == 0 {
                    return Err(ScaleCalibrationError::ZeroWeight);
                }
                let raw = averaged_raw.ok_or(ScaleCalibrationError::NoReading)?;
                let scale_value = scale_value(raw, current_offset, grams)?;
                self.phase = Phase::Idle;
                Ok(Some(ScaleUpdate::ScaleValue(scale_value)))
            }
        }
    }
}

/// round((raw − offset) / grams · 100), if it fits register 20.
fn scale_value(raw: i32, offset: i32, grams: u16) -> Result<u16, ScaleCalibrationError> {
    // i64: a 32-bit raw minus a 32-bit offset, times 100, cannot overflow.
    let counts_x100 = (i64::from(raw) - i64::from(offset)) * 100;
    if counts_x100 <= 0 {
        return Err(ScaleCalibrationError::ScaleValueOutOfRange);
    }
    let grams = i64::from(grams);
    let rounded = (counts_x100 + grams / 2) / grams;
    match u16::try_from(rounded) {
        Ok(value) if value >= 1 => Ok(value),
        _ => Err(ScaleCalibrationError::ScaleValueOutOfRange),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ScaleCalibrationCommand as Cmd;
    use ScaleCalibrationError as E;

    #[test]
    fn full_flow_stores_offset_at_tare_and_scale_value_at_known_weight() {
        let mut cal = ScaleCalibration::new();
        assert_eq!(cal.step(Cmd::Start, Some(20_000), 20_490), Ok(None));
        assert_eq!(
            cal.step(Cmd::Tare, Some(20_480), 20_490),
            Ok(Some(ScaleUpdate::Offset(20_480)))
        );
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Tared);
        // 500 g of 19.00 counts/g on top of the new offset.
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 500 }, Some(29_980), 20_480),
            Ok(Some(ScaleUpdate::ScaleValue(1900)))
        );
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Idle);
    }

    #[test]
    fn scale_value_is_rounded_to_the_nearest_hundredth_count_per_gram() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(1000), 0).unwrap();
        // 1000 counts over 3 g: 333.33 counts/g → 33333.3 → 33333
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 3 }, Some(2000), 1000),
            Ok(Some(ScaleUpdate::ScaleValue(33_333)))
        );
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(1000), 0).unwrap();
        // 1003 counts over 6 g: 16716.67 → 16717 (rounded up, not truncated)
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 6 }, Some(2003), 1000),
            Ok(Some(ScaleUpdate::ScaleValue(16_717)))
        );
    }

    #[test]
    fn known_weight_uses_the_offset_in_force() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        // Register 19 was rewritten to 21 000 between the steps.
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 100 }, Some(22_000), 21_000),
            Ok(Some(ScaleUpdate::ScaleValue(1000)))
        );
    }

    #[test]
    fn tare_can_be_repeated_before_the_known_weight() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        assert_eq!(
            cal.step(Cmd::Tare, Some(20_100), 20_000),
            Ok(Some(ScaleUpdate::Offset(20_100)))
        );
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Tared);
    }

    #[test]
    fn start_restarts_from_any_phase() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        assert_eq!(cal.step(Cmd::Start, None, 20_000), Ok(None));
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 100 }, Some(22_000), 20_000),
            Err(E::NotTared)
        );
    }

    #[test]
    fn tare_before_start_is_rejected() {
        let mut cal = ScaleCalibration::new();
        assert_eq!(cal.step(Cmd::Tare, Some(20_000), 0), Err(E::NotStarted));
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Idle);
    }

    #[test]
    fn known_weight_before_tare_is_rejected() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 500 }, Some(30_000), 20_000),
            Err(E::NotTared)
        );
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Started);
    }

    #[test]
    fn known_weight_before_start_names_the_missing_start() {
        let mut cal = ScaleCalibration::new();
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 500 }, Some(30_000), 20_000),
            Err(E::NotStarted)
        );
    }

    #[test]
    fn known_weight_after_a_completed_calibration_needs_a_new_start() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        cal.step(Cmd::KnownWeight { grams: 100 }, Some(21_900), 20_000)
            .unwrap();
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 100 }, Some(21_900), 20_000),
            Err(E::NotStarted)
        );
    }

    #[test]
    fn tare_without_a_reading_is_rejected_and_can_be_retried() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        assert_eq!(cal.step(Cmd::Tare, None, 0), Err(E::NoReading));
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Started);
        assert_eq!(
            cal.step(Cmd::Tare, Some(100), 0),
            Ok(Some(ScaleUpdate::Offset(100)))
        );
    }

    #[test]
    fn known_weight_without_a_reading_is_rejected() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 500 }, None, 20_000),
            Err(E::NoReading)
        );
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Tared);
    }

    #[test]
    fn every_24_bit_empty_reading_tares() {
        for raw in [
            80_000, -15_000, 65_536, -1, 0, 65_535, 8_388_607, -8_388_608,
        ] {
            let mut cal = ScaleCalibration::new();
            cal.step(Cmd::Start, None, 0).unwrap();
            assert_eq!(
                cal.step(Cmd::Tare, Some(raw), 0),
                Ok(Some(ScaleUpdate::Offset(raw))),
                "raw {raw}"
            );
            assert_eq!(cal.phase(), ScaleCalibrationPhase::Tared);
        }
        // 500 g of 19 counts/g on an offset of -15 000.
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(-15_000), 0).unwrap();
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 500 }, Some(-5_500), -15_000),
            Ok(Some(ScaleUpdate::ScaleValue(1900)))
        );
    }

    #[test]
    fn a_reading_beyond_24_bits_is_no_hx711_reading_and_is_refused() {
        for raw in [8_388_608, -8_388_609, i32::MAX, i32::MIN] {
            let mut cal = ScaleCalibration::new();
            cal.step(Cmd::Start, None, 0).unwrap();
            assert_eq!(
                cal.step(Cmd::Tare, Some(raw), 0),
                Err(E::OffsetOutOfRange),
                "raw {raw}"
            );
            assert_eq!(cal.phase(), ScaleCalibrationPhase::Started);
        }
    }

    #[test]
    fn zero_grams_is_rejected() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        assert_eq!(
            cal.step(Cmd::KnownWeight { grams: 0 }, Some(30_000), 20_000),
            Err(E::ZeroWeight)
        );
        assert_eq!(cal.phase(), ScaleCalibrationPhase::Tared);
    }

    #[test]
    fn scale_value_not_fitting_its_register_is_rejected() {
        let cases = [
            // (raw, grams): too steep: 1_000_000 counts on 1 g → 100_000_000
            (1_020_000, 1),
            // 655.36 counts/g → 65536, one past the register
            (20_000 + 65_536, 100),
            // no load difference at all
            (20_000, 100),
            // lighter than empty: weight not on the scale or load cell reversed
            (19_000, 100),
            // 1 count over 1000 g rounds to 0
            (20_001, 1000),
        ];
        for (raw, grams) in cases {
            let mut cal = ScaleCalibration::new();
            cal.step(Cmd::Start, None, 0).unwrap();
            cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
            assert_eq!(
                cal.step(Cmd::KnownWeight { grams }, Some(raw), 20_000),
                Err(E::ScaleValueOutOfRange),
                "raw {raw}, {grams} g"
            );
            assert_eq!(cal.phase(), ScaleCalibrationPhase::Tared);
        }
    }

    #[test]
    fn largest_fitting_scale_value_is_accepted() {
        let mut cal = ScaleCalibration::new();
        cal.step(Cmd::Start, None, 0).unwrap();
        cal.step(Cmd::Tare, Some(20_000), 0).unwrap();
        assert_eq!(
            cal.step(
                Cmd::KnownWeight { grams: 100 },
                Some(20_000 + 65_535),
                20_000
            ),
            Ok(Some(ScaleUpdate::ScaleValue(65_535)))
        );
    }

    #[test]
    fn error_codes_are_stable() {
        assert_eq!(E::NotStarted.code(), 0x30);
        assert_eq!(E::NotTared.code(), 0x31);
        assert_eq!(E::NoReading.code(), 0x32);
        assert_eq!(E::OffsetOutOfRange.code(), 0x33);
        assert_eq!(E::ZeroWeight.code(), 0x34);
        assert_eq!(E::ScaleValueOutOfRange.code(), 0x35);
    }
}
