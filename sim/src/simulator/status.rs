//! What the simulator shows: the controller's latest reports, taken from the frames it
//! sent, and the one-line status drawn from them and from the robot's inputs.

use std::cell::Cell;

use base_core::can::{ControlSource, Mode, RawFrame, Report, Status};
use embassy_time::Instant;
use embedded_hal::digital::PinState;

use crate::can::SentFrame;
use crate::drives::{DriveView, DrivesConfig, Mounting};
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
                // Register replies, pose times and measured speeds are the PC's
                // business, not the status line's.
                Ok(Some(
                    Report::RegisterValue { .. }
                    | Report::RegisterReadError { .. }
                    | Report::PoseTime { .. }
                    | Report::MeasuredSpeed { .. },
                ))
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

/// The socketcand clients and their traffic.
#[derive(Debug, Default)]
pub struct NetworkCounters {
    /// Clients connected in raw mode now.
    pub clients: Cell<u32>,
    /// Frames the clients sent onto the bus.
    pub frames_in: Cell<u32>,
    /// Frames queued for clients (one frame to three clients counts three).
    pub frames_out: Cell<u32>,
    /// Clients disconnected because they stopped reading.
    pub dropped_clients: Cell<u32>,
    /// Frames the SocketCAN interface did not take in time.
    pub socketcan_lost: Cell<u32>,
}

/// The width the live status line fits in: an 80-column terminal, less the cursor.
pub const STATUS_WIDTH: usize = 79;

/// The live status line, at most [`STATUS_WIDTH`] characters: time, mode, control
/// source, alarms (only while there are any), pose (x, y mm, heading mrad), motor
/// speeds (rpm), battery, and the PC's links (`slcan` while its channel is open,
/// `tcp N` for socketcand clients, `LOST` once anything was dropped).
/// [`status_report`] has everything, for the `status` command.
pub fn status_line(
    now: Instant,
    telemetry: &Telemetry,
    robot: &VirtualRobot,
    slcan: &SlcanCounters,
    network: &NetworkCounters,
) -> String {
    let mode = telemetry.status.map_or("-", |status| match status.mode {
        Mode::Starting => "Starting",
        Mode::Standby => "Standby",
        Mode::Active => "Active",
        Mode::Emergency => "Emergency",
        Mode::AwaitingConfirm => "Confirm?",
        Mode::Recovering => "Recovering",
        Mode::Fault => "Fault",
    });
    let (x, y) = telemetry.position_mm.unwrap_or_default();
    let heading = telemetry.heading_mrad.unwrap_or_default();
    let [left, right] = motor_rpm(robot);
    let mut line = format!(
        "{:6.1}s {mode:<10} {:<6}",
        now.as_millis() as f64 / 1000.0,
        control(telemetry)
    );
    if robot.estop.level() == PinState::Low {
        line.push_str(" ESTOP");
    }
    if robot.safety_zone.level() == PinState::Low {
        line.push_str(" ZONE");
    }
    if robot.pc_switch.level() == PinState::Low {
        line.push_str(" PC-off");
    }
    line.push_str(&format!(" x{x:6} y{y:6} h{heading:5} L{left:4} R{right:4}"));
    if let Some((_, millivolts)) = telemetry.battery {
        line.push_str(&format!(" {:.1}V", f64::from(millivolts) / 1000.0));
    }
    if slcan.open.get() {
        line.push_str(" slcan");
    }
    if network.clients.get() > 0 {
        line.push_str(&format!(" tcp {}", network.clients.get()));
    }
    if slcan.frames_dropped.get() > 0
        || network.dropped_clients.get() > 0
        || network.socketcan_lost.get() > 0
    {
        line.push_str(" LOST");
    }
    // ASCII only, so cutting at a byte is cutting at a character.
    line.truncate(STATUS_WIDTH);
    line
}

/// Everything the simulator knows, on a few lines: what the `status` console command
/// prints.
pub fn status_report(
    now: Instant,
    telemetry: &Telemetry,
    robot: &VirtualRobot,
    slcan: &SlcanCounters,
    network: &NetworkCounters,
) -> String {
    let mode = telemetry
        .status
        .map_or("-".to_owned(), |status| format!("{:?}", status.mode));
    let (x, y) = telemetry.position_mm.unwrap_or_default();
    let heading = telemetry.heading_mrad.unwrap_or_default();
    let [left, right] = motor_rpm(robot);
    let [turned_left, turned_right] = motor_revolutions(robot);
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
    format!(
        "time {:.1} s  mode {mode}  control {}\n\
         pose x {x} mm  y {y} mm  heading {heading} mrad  motors L {left} R {right} rpm  \
         turned L {turned_left:.3} R {turned_right:.3} rev\n\
         battery {battery}  load {weight}  e-stop {estop}  zone {zone}  PC {pc_power}\n\
         slcan {channel}: in {} out {} dropped {}\n\
         socketcand: {} clients, in {} out {}, {} dropped for not reading; \
         SocketCAN lost {}",
        now.as_millis() as f64 / 1000.0,
        control(telemetry),
        slcan.frames_in.get(),
        slcan.frames_out.get(),
        slcan.frames_dropped.get(),
        network.clients.get(),
        network.frames_in.get(),
        network.frames_out.get(),
        network.dropped_clients.get(),
        network.socketcan_lost.get(),
    )
}

fn control(telemetry: &Telemetry) -> &'static str {
    match telemetry.status.map(|status| status.control) {
        Some(ControlSource::Can) => "CAN",
        Some(ControlSource::Remote) => "remote",
        Some(ControlSource::None) | None => "none",
    }
}

/// The drives on the left and on the right wheel, as mounted: the mirrored motor is
/// the right one, whatever its address switch says.
fn drives_by_side(robot: &VirtualRobot) -> [DriveView; 2] {
    let [first, second] = DrivesConfig::default()
        .slaves
        .map(|slave| robot.drives.drive(slave.address));
    if first.mounting == Mounting::Mirrored {
        [second, first]
    } else {
        [first, second]
    }
}

/// The motors' speeds, rpm, left and right wheel.
fn motor_rpm(robot: &VirtualRobot) -> [i32; 2] {
    drives_by_side(robot).map(|drive| drive.forward_rpm().round() as i32)
}

/// The motors' positions, forward revolutions since the drives were powered, left and
/// right wheel: how far the wheels really travelled, whatever the controller knows of it.
fn motor_revolutions(robot: &VirtualRobot) -> [f64; 2] {
    drives_by_side(robot).map(|drive| drive.forward_revolutions())
}

/// The inputs are active low: low means pressed (e-stop) or occupied (zone).
fn pressed(level: PinState, low: &'static str, high: &'static str) -> &'static str {
    match level {
        PinState::Low => low,
        PinState::High => high,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_live_line_fits_80_columns_even_with_every_alarm_and_wide_numbers() {
        let robot = VirtualRobot::new();
        robot.press_estop();
        robot.set_safety_zone(true);
        let telemetry = Telemetry {
            position_mm: Some((-2_000_000_000, -2_000_000_000)),
            heading_mrad: Some(-3141),
            battery: Some((100, 65_535)),
            weight_g: Some(65_535),
            status: Some(Status {
                mode: Mode::Recovering,
                control: ControlSource::Remote,
                ..Status::default()
            }),
        };
        let slcan = SlcanCounters::default();
        slcan.open.set(true);
        let network = NetworkCounters::default();
        network.clients.set(12);
        let line = status_line(
            Instant::from_secs(99_999),
            &telemetry,
            &robot,
            &slcan,
            &network,
        );
        assert!(line.len() <= STATUS_WIDTH, "{} chars: {line}", line.len());
        assert!(line.contains("Recovering"), "{line}");
        assert!(line.contains("ESTOP ZONE"), "{line}");
    }

    #[test]
    fn a_quiet_robot_shows_pose_motors_battery_and_links() {
        let robot = VirtualRobot::new();
        let telemetry = Telemetry {
            position_mm: Some((1234, -56)),
            heading_mrad: Some(1571),
            battery: Some((80, 24_100)),
            ..Telemetry::default()
        };
        let slcan = SlcanCounters::default();
        let network = NetworkCounters::default();
        network.clients.set(2);
        let line = status_line(Instant::from_secs(12), &telemetry, &robot, &slcan, &network);
        assert!(line.len() <= STATUS_WIDTH, "{line}");
        for part in ["x  1234", "y   -56", "h 1571", "24.1V", "tcp 2"] {
            assert!(line.contains(part), "{part:?} in {line}");
        }
        assert!(!line.contains("ESTOP"), "{line}");
    }
}
