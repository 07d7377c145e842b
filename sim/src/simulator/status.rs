//! What the simulator shows: the controller's latest reports, taken from the frames it
//! sent, and the one-line status drawn from them and from the robot's inputs.

use std::cell::Cell;

use base_core::can::{ControlSource, RawFrame, Report, Status};
use embassy_time::Instant;
use embedded_hal::digital::PinState;

use crate::can::SentFrame;
use crate::drives::DrivesConfig;
use crate::robot::VirtualRobot;

/// The newest of each report the controller sent.
#[derive(Debug, Default, Clone, Copy)]
pub struct Telemetry {
    pub position_mm: Option<(i32, i32)>,
    pub heading_mrad: Option<i32>,
    /// Percent and mV.
    pub battery: Option<(u8, u16)>,
    pub weight_g: Option<u16>,
    pub status: Option<Status>,
}

impl Telemetry {
    pub fn absorb(&mut self, sent: impl IntoIterator<Item = SentFrame>) {
        for sent in sent {
            let Some(raw) = RawFrame::from_frame(&sent.frame) else {
                continue;
            };
            match Report::decode(raw.id(), raw.data()) {
                Ok(Some(Report::Position { x_mm, y_mm })) => self.position_mm = Some((x_mm, y_mm)),
                Ok(Some(Report::Heading { heading_mrad })) => {
                    self.heading_mrad = Some(heading_mrad);
                }
                Ok(Some(Report::Battery {
                    percent,
                    voltage_mv,
                })) => self.battery = Some((percent, voltage_mv)),
                Ok(Some(Report::Weight { grams })) => self.weight_g = Some(grams),
                Ok(Some(Report::Status(status))) => self.status = Some(status),
                // Register replies are the PC's business, not the status line's.
                Ok(Some(Report::RegisterValue { .. } | Report::RegisterReadError { .. }))
                | Ok(None)
                | Err(_) => {}
            }
        }
    }
}

/// Traffic through the SLCAN port.
#[derive(Debug, Default)]
pub struct SlcanCounters {
    pub open: Cell<bool>,
    /// Frames the PC sent onto the bus.
    pub frames_in: Cell<u32>,
    /// Frames passed to the PC.
    pub frames_out: Cell<u32>,
    /// Frames lost because the PC did not read them.
    pub frames_dropped: Cell<u32>,
}

/// One line: time, mode and control source, pose, motor speeds, battery, weight,
/// inputs, PC power and SLCAN traffic.
pub fn status_line(
    now: Instant,
    telemetry: &Telemetry,
    robot: &VirtualRobot,
    slcan: &SlcanCounters,
) -> String {
    let mode = telemetry
        .status
        .map_or("-".to_owned(), |status| format!("{:?}", status.mode));
    let control = match telemetry.status.map(|status| status.control) {
        Some(ControlSource::Can) => "CAN",
        Some(ControlSource::Remote) => "remote",
        Some(ControlSource::None) | None => "none",
    };
    let (x, y) = telemetry.position_mm.unwrap_or_default();
    let heading = telemetry.heading_mrad.unwrap_or_default();
    // The simulator builds its robot on the default drives: slave 1 left, 2 right.
    let [left, right] = DrivesConfig::default().slaves.map(|slave| {
        let drive = robot.drives.drive(slave.address);
        drive.forward_rpm().round() as i32
    });
    let battery = telemetry
        .battery
        .map_or("-".to_owned(), |(percent, millivolts)| {
            format!("{millivolts} mV {percent}%")
        });
    let weight = telemetry
        .weight_g
        .map_or("-".to_owned(), |grams| format!("{grams} g"));
    let estop = pressed(robot.estop.level(), "PRESSED", "off");
    let zone = pressed(robot.safety_zone.level(), "OCCUPIED", "clear");
    let pc_power = match robot.pc_switch.level() {
        PinState::High => "on",
        PinState::Low => "off",
    };
    let channel = if slcan.open.get() { "open" } else { "closed" };
    let mut line = format!(
        "{:7.1} s  {mode:<15} ctl {control:<6} x {x:6} y {y:6} mm  hdg {heading:6} mrad  \
         motors L {left:5} R {right:5} rpm  batt {battery}  load {weight}  \
         e-stop {estop}  zone {zone}  PC {pc_power}  slcan {channel} in {} out {}",
        now.as_millis() as f64 / 1000.0,
        slcan.frames_in.get(),
        slcan.frames_out.get(),
    );
    if slcan.frames_dropped.get() > 0 {
        line.push_str(&format!(" dropped {}", slcan.frames_dropped.get()));
    }
    line
}

/// The inputs are active low: low means pressed (e-stop) or occupied (zone).
fn pressed(level: PinState, low: &'static str, high: &'static str) -> &'static str {
    match level {
        PinState::Low => low,
        PinState::High => high,
    }
}
