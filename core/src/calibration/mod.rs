//! Odometry calibration (0x008) and scale calibration (0x007): the steps a person
//! walks through over CAN, turned into new register values.

pub mod odometry;
pub mod scale;

/// One step of the odometry calibration, as sent in frame 0x008.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OdometryCalibrationCommand {
    /// `01`: start accumulating raw linear distance.
    StartLinear,
    /// `0C mm_hi mm_lo`: the real distance driven since `StartLinear`.
    EndLinear { real_mm: u16 },
    /// `02`: start accumulating raw clockwise rotation.
    StartClockwise,
    /// `16 mrad_hi mrad_lo`: the real clockwise angle turned since `StartClockwise`.
    EndClockwise { real_mrad: u16 },
    /// `03`: start accumulating raw counter-clockwise rotation.
    StartCounterClockwise,
    /// `20 mrad_hi mrad_lo`: the real counter-clockwise angle since `StartCounterClockwise`.
    EndCounterClockwise { real_mrad: u16 },
    /// `04`: store the pending factors in registers 16–18 and flash.
    Store,
}

/// One step of the scale calibration, as sent in frame 0x007.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScaleCalibrationCommand {
    /// `01`: begin a calibration.
    Start,
    /// `02`: the scale is empty; its reading becomes `weight_offset`.
    Tare,
    /// `03 g_hi g_lo`: a known weight lies on the scale; derive `scale_value`.
    KnownWeight { grams: u16 },
}
