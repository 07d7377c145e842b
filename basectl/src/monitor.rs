//! `monitor`: every report of the base controller, decoded: a live view that is
//! redrawn in place (on a terminal), one line per frame (`--scroll`, or when the
//! output is no terminal), or one JSON object per frame (`--json`).

use std::io::Write;
use std::time::{Duration, Instant};

use base_core::can::{Faults, Report, Status, StatusFlags};

use crate::base::{Base, Error};
use crate::rejection;

/// When `monitor` stops; with neither it runs until Ctrl-C.
#[derive(Debug, Clone, Copy, Default)]
pub struct Until {
    pub count: Option<u64>,
    pub seconds: Option<u64>,
}

/// How `monitor` prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Style {
    /// One line per report.
    #[default]
    Lines,
    /// One JSON object per report and line.
    Json,
    /// The newest report of each kind, redrawn in place at most 10 times a second.
    Live,
}

/// How often the live view is redrawn at most.
const LIVE_PERIOD: Duration = Duration::from_millis(100);

/// The newest report of each kind, for the live view.
#[derive(Default)]
struct Latest {
    /// Kind → (when, line), in a fixed order.
    lines: [(Option<Instant>, String); 9],
    frames: u64,
}

impl Latest {
    fn absorb(&mut self, report: &Report) {
        let slot = match report {
            Report::Status(_) => 0,
            Report::Position { .. } => 1,
            Report::Heading { .. } => 2,
            Report::Battery { .. } => 3,
            Report::Weight { .. } => 4,
            Report::RegisterValue { .. } => 5,
            Report::RegisterReadError { .. } => 6,
            Report::PoseTime { .. } => 7,
            Report::MeasuredSpeed { .. } => 8,
        };
        self.lines[slot] = (Some(Instant::now()), describe(report));
        self.frames += 1;
    }

    fn draw(&self, out: &mut dyn Write) -> std::io::Result<()> {
        let mut text = String::from("\x1b[H\x1b[J");
        text.push_str(&format!(
            "basectl monitor: {} reports (Ctrl-C quits; --scroll for one line each)\n\n",
            self.frames
        ));
        for (at, line) in &self.lines {
            if let Some(at) = at {
                text.push_str(&format!(
                    "{line}   ({:.1} s ago)\n",
                    at.elapsed().as_secs_f64()
                ));
            }
        }
        out.write_all(text.as_bytes())?;
        out.flush()
    }
}

pub fn monitor(
    base: &mut Base,
    until: Until,
    style: Style,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let deadline = until
        .seconds
        .map(|seconds| Instant::now() + Duration::from_secs(seconds));
    let mut printed = 0;
    let mut quiet_since = Instant::now();
    let mut latest = Latest::default();
    let mut next_draw = Instant::now();
    while until.count.is_none_or(|count| printed < count) {
        let most = match style {
            Style::Live => LIVE_PERIOD,
            Style::Lines | Style::Json => Duration::from_secs(1),
        };
        let wait = match deadline {
            Some(deadline) if Instant::now() >= deadline => break,
            Some(deadline) => deadline.saturating_duration_since(Instant::now()).min(most),
            None => most,
        };
        if style == Style::Live && Instant::now() >= next_draw {
            latest.draw(out)?;
            next_draw = Instant::now() + LIVE_PERIOD;
        }
        match base.next_report(wait)? {
            Some(report) => {
                match style {
                    Style::Lines => writeln!(out, "{}", describe(&report))?,
                    Style::Json => writeln!(out, "{}", report_json(&report))?,
                    Style::Live => latest.absorb(&report),
                }
                out.flush()?;
                printed += 1;
                quiet_since = Instant::now();
            }
            // The status frame alone comes every second in every mode: silence this
            // long means no controller, unless the person turned status_time off.
            None if quiet_since.elapsed() > Duration::from_secs(5) => {
                writeln!(
                    out,
                    "no frame from the base controller for 5 s (is it connected? bit rate?)"
                )?;
                quiet_since = Instant::now();
            }
            None => {}
        }
    }
    Ok(())
}

/// One report as a line of text.
pub fn describe(report: &Report) -> String {
    match *report {
        Report::Position { x_mm, y_mm } => format!("position  x {x_mm} mm  y {y_mm} mm"),
        Report::Heading { heading_mrad } => format!("heading   {heading_mrad} mrad"),
        Report::PoseTime { controller_ms } => {
            format!("pose time {controller_ms} ms on the controller's clock")
        }
        Report::MeasuredSpeed {
            linear_mm_s,
            rotation_mrad_s,
            left_wheel_crad_s,
            right_wheel_crad_s,
        } => format!(
            "measured  {linear_mm_s} mm/s  {rotation_mrad_s} mrad/s clockwise  \
             wheels {:.2} / {:.2} rad/s",
            f64::from(left_wheel_crad_s) / 100.0,
            f64::from(right_wheel_crad_s) / 100.0
        ),
        Report::Battery {
            percent,
            voltage_mv,
        } => format!("battery   {percent} %  {voltage_mv} mV"),
        Report::Weight { grams } => format!("weight    {grams} g"),
        Report::RegisterValue {
            value,
            echo: Some(echo),
        } => format!(
            "register  {} = {value} (tag 0x{:04X})",
            echo.address, echo.tag
        ),
        Report::RegisterValue { value, echo: None } => format!("register  value {value}"),
        Report::RegisterReadError {
            address, reason, ..
        } => {
            format!(
                "register  {address} refused: {}",
                rejection::describe(reason)
            )
        }
        Report::Status(status) => describe_status(&status),
    }
}

/// The names of the flags that are set.
pub fn flag_names(flags: &StatusFlags) -> Vec<&'static str> {
    set_names(&[
        (flags.enable_fresh, "enable_fresh"),
        (flags.pc_on, "pc_on"),
        (flags.safety_zone, "safety_zone"),
        (flags.remote_bonded, "remote_bonded"),
        (flags.remote_connected, "remote_connected"),
        (flags.remote_in_control, "remote_in_control"),
        (flags.estop_pressed, "estop_pressed"),
        (flags.brakes_applied, "brakes_applied"),
    ])
}

/// The names of the faults that are set.
pub fn fault_names(faults: &Faults) -> Vec<&'static str> {
    set_names(&[
        (faults.left_drive_silent, "left_drive_silent"),
        (faults.left_drive_alarm, "left_drive_alarm"),
        (faults.right_drive_silent, "right_drive_silent"),
        (faults.right_drive_alarm, "right_drive_alarm"),
        (faults.flash, "flash"),
        (faults.scale, "scale"),
        (faults.can_bus, "can_bus"),
        (faults.watchdog_reset, "watchdog_reset"),
    ])
}

fn set_names(pairs: &[(bool, &'static str)]) -> Vec<&'static str> {
    pairs
        .iter()
        .filter(|(on, _)| *on)
        .map(|(_, name)| *name)
        .collect()
}

fn describe_status(status: &Status) -> String {
    let joined = |names: Vec<&str>| {
        if names.is_empty() {
            "-".to_owned()
        } else {
            names.join(",")
        }
    };
    let flag_names = joined(flag_names(&status.flags));
    let fault_names = joined(fault_names(&status.faults));
    let last = match rejection::name(status.last_rejection) {
        Some(name) => format!("{name} on 0x{:02X}", status.last_rejection_subject),
        None if status.last_rejection == 0 => "none".to_owned(),
        None => format!(
            "0x{:02X} on 0x{:02X}",
            status.last_rejection, status.last_rejection_subject
        ),
    };
    format!(
        "status    mode {:?}  source {:?}  flags {flag_names}  faults {fault_names}  rejected {} (last {last})  drive alarm 0x{:02X}  modbus errors {}",
        status.mode,
        status.control,
        status.rejected_count,
        status.drive_alarm,
        status.modbus_errors
    )
}

/// One report as a JSON object, with a `"report"` field naming its kind.
pub fn report_json(report: &Report) -> serde_json::Value {
    use serde_json::json;
    match *report {
        Report::Position { x_mm, y_mm } => {
            json!({"report": "position", "x_mm": x_mm, "y_mm": y_mm})
        }
        Report::Heading { heading_mrad } => {
            json!({"report": "heading", "heading_mrad": heading_mrad})
        }
        Report::PoseTime { controller_ms } => {
            json!({"report": "pose_time", "controller_ms": controller_ms})
        }
        Report::MeasuredSpeed {
            linear_mm_s,
            rotation_mrad_s,
            left_wheel_crad_s,
            right_wheel_crad_s,
        } => json!({
            "report": "measured_speed",
            "linear_mm_s": linear_mm_s,
            "rotation_mrad_s": rotation_mrad_s,
            "left_wheel_rad_s": f64::from(left_wheel_crad_s) / 100.0,
            "right_wheel_rad_s": f64::from(right_wheel_crad_s) / 100.0,
        }),
        Report::Battery {
            percent,
            voltage_mv,
        } => {
            json!({"report": "battery", "percent": percent, "voltage_mv": voltage_mv})
        }
        Report::Weight { grams } => json!({"report": "weight", "grams": grams}),
        Report::RegisterValue { value, echo } => json!({
            "report": "register_value",
            "value": value,
            "address": echo.map(|echo| echo.address),
            "tag": echo.map(|echo| echo.tag),
        }),
        Report::RegisterReadError {
            address,
            reason,
            tag,
        } => json!({
            "report": "register_read_error",
            "address": address,
            "reason": rejection::name(reason),
            "reason_code": reason,
            "tag": tag,
        }),
        Report::Status(status) => json!({
            "report": "status",
            "mode": format!("{:?}", status.mode),
            "control": format!("{:?}", status.control),
            "flags": flag_names(&status.flags),
            "faults": fault_names(&status.faults),
            "rejected_count": status.rejected_count,
            "last_rejection": rejection::name(status.last_rejection),
            "last_rejection_code": status.last_rejection,
            "last_rejection_subject": status.last_rejection_subject,
            "drive_alarm": status.drive_alarm,
            "modbus_errors": status.modbus_errors,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_status_frame_names_mode_flags_faults_and_the_last_rejection() {
        // The protocol document's example frame.
        let bytes = [0x24, 0x8D, 0xA6, 0xC8, 0x02, 0xC8, 0x84, 0x07];
        let Ok(Some(report)) = Report::decode(0x0EE, &bytes) else {
            panic!("decodes")
        };
        let line = describe(&report);
        assert!(line.contains("mode AwaitingConfirm"), "{line}");
        assert!(line.contains("source Remote"), "{line}");
        assert!(
            line.contains("enable_fresh,safety_zone,remote_bonded,brakes_applied"),
            "{line}"
        );
        assert!(
            line.contains("left_drive_alarm,right_drive_silent,scale,watchdog_reset"),
            "{line}"
        );
        assert!(
            line.contains("rejected 200 (last BadVelocityMarker on 0xC8)"),
            "{line}"
        );
    }

    #[test]
    fn the_live_view_redraws_in_place_with_the_newest_report_of_each_kind() {
        let mut latest = Latest::default();
        latest.absorb(&Report::Position { x_mm: 1, y_mm: 2 });
        latest.absorb(&Report::Position { x_mm: 10, y_mm: 20 });
        latest.absorb(&Report::Battery {
            percent: 80,
            voltage_mv: 24_000,
        });
        let mut text = Vec::new();
        latest.draw(&mut text).unwrap();
        let text = String::from_utf8(text).unwrap();
        assert!(
            text.starts_with("\x1b[H\x1b[J"),
            "cursor home, clear: {text:?}"
        );
        assert!(text.contains("3 reports"), "{text}");
        assert!(text.contains("position  x 10 mm  y 20 mm"), "{text}");
        assert!(!text.contains("x 1 mm"), "only the newest: {text}");
        assert!(text.contains("battery   80 %  24000 mV"), "{text}");
    }

    #[test]
    fn a_position_frame_reads_in_millimetres() {
        let report = Report::Position {
            x_mm: 1000,
            y_mm: -2,
        };
        assert_eq!(describe(&report), "position  x 1000 mm  y -2 mm");
    }
}
