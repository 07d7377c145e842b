//! `log FILE`: the bus to a file while it runs. Two formats:
//!
//! - candump's log format (`(SECS.USECS) can0 0EE#248D…`, one frame a line), which
//!   `canplayer`, `cantools plot` and `cantools decode` read; every frame, decoded or
//!   not;
//! - CSV (a `.csv` file, or `--format csv`) with a time column in seconds and one
//!   column per value (pose, battery, weight, mode, counters), one row per report with
//!   the newest value of each, which PlotJuggler and spreadsheets open directly.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use base_core::can::{RawFrame, Report};

use crate::base::Error;
use crate::bus::Bus;

/// The file's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Candump,
    Csv,
}

impl Format {
    /// CSV for a `.csv` file, candump's format otherwise.
    pub fn for_path(path: &Path) -> Self {
        match path.extension().and_then(|extension| extension.to_str()) {
            Some(extension) if extension.eq_ignore_ascii_case("csv") => Format::Csv,
            _ => Format::Candump,
        }
    }
}

/// The CSV header.
pub const CSV_HEADER: &str = "time,x_mm,y_mm,heading_mrad,battery_mv,battery_percent,weight_g,\
mode,control,rejected_count,modbus_errors,pose_time_ms,measured_mm_s,measured_mrad_s,\
left_wheel_rad_s,right_wheel_rad_s";

/// One frame in candump's log format.
pub fn candump_line(frame: &RawFrame, time: Duration) -> String {
    let data: String = frame
        .data()
        .iter()
        .map(|byte| format!("{byte:02X}"))
        .collect();
    format!(
        "({}.{:06}) can0 {:03X}#{data}",
        time.as_secs(),
        time.subsec_micros(),
        frame.id()
    )
}

/// The newest value of each column.
#[derive(Default)]
pub struct Row {
    values: [Option<String>; 15],
}

impl Row {
    /// Takes a report in; false if it changes no column.
    pub fn absorb(&mut self, report: &Report) -> bool {
        let mut set = |column: usize, value: String| self.values[column] = Some(value);
        match *report {
            Report::Position { x_mm, y_mm } => {
                set(0, x_mm.to_string());
                set(1, y_mm.to_string());
            }
            Report::Heading { heading_mrad } => set(2, heading_mrad.to_string()),
            Report::PoseTime { controller_ms } => set(10, controller_ms.to_string()),
            Report::MeasuredSpeed {
                linear_mm_s,
                rotation_mrad_s,
                left_wheel_crad_s,
                right_wheel_crad_s,
            } => {
                set(11, linear_mm_s.to_string());
                set(12, rotation_mrad_s.to_string());
                set(13, format!("{:.2}", f64::from(left_wheel_crad_s) / 100.0));
                set(14, format!("{:.2}", f64::from(right_wheel_crad_s) / 100.0));
            }
            Report::Battery {
                percent,
                voltage_mv,
            } => {
                set(3, voltage_mv.to_string());
                set(4, percent.to_string());
            }
            Report::Weight { grams } => set(5, grams.to_string()),
            Report::Status(status) => {
                // Numbers, so that a plot can show them: the mode's and source's codes.
                set(6, status.mode.code().to_string());
                set(7, (status.control as u8).to_string());
                set(8, status.rejected_count.to_string());
                set(9, status.modbus_errors.to_string());
            }
            Report::RegisterValue { .. } | Report::RegisterReadError { .. } => return false,
        }
        true
    }

    pub fn line(&self, time: Duration) -> String {
        let mut line = format!("{}.{:06}", time.as_secs(), time.subsec_micros());
        for value in &self.values {
            line.push(',');
            line.push_str(value.as_deref().unwrap_or(""));
        }
        line
    }
}

fn wall_time() -> Duration {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default()
}

/// Logs until `seconds` pass or `count` frames came (neither: until Ctrl-C).
pub fn log(
    bus: &mut dyn Bus,
    path: &Path,
    format: Format,
    seconds: Option<u64>,
    count: Option<u64>,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let file = std::fs::File::create(path).map_err(|error| {
        Error::InvalidInput(format!("cannot write {}: {error}", path.display()))
    })?;
    let mut file = std::io::BufWriter::new(file);
    if format == Format::Csv {
        writeln!(file, "{CSV_HEADER}")?;
    }
    writeln!(
        out,
        "logging to {} ({format:?}); Ctrl-C stops",
        path.display()
    )?;
    let deadline = seconds.map(|seconds| Instant::now() + Duration::from_secs(seconds));
    let mut row = Row::default();
    let mut frames = 0;
    while count.is_none_or(|count| frames < count) {
        let wait = match deadline {
            Some(deadline) if Instant::now() >= deadline => break,
            Some(deadline) => deadline
                .saturating_duration_since(Instant::now())
                .min(Duration::from_millis(200)),
            None => Duration::from_millis(200),
        };
        let Some(frame) = bus.receive(wait)? else {
            // Whatever came is on disk even if the run is killed.
            file.flush()?;
            continue;
        };
        frames += 1;
        let time = wall_time();
        match format {
            Format::Candump => writeln!(file, "{}", candump_line(&frame, time))?,
            Format::Csv => {
                if let Ok(Some(report)) = Report::decode(frame.id(), frame.data())
                    && row.absorb(&report)
                {
                    writeln!(file, "{}", row.line(time))?;
                }
            }
        }
    }
    file.flush()?;
    writeln!(out, "{frames} frames logged")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_written_as_candump_logs_them() {
        let frame = RawFrame::new(0x0EE, &[0x24, 0x8D]).unwrap();
        assert_eq!(
            candump_line(&frame, Duration::from_micros(1_700_000_000_000_042)),
            "(1700000000.000042) can0 0EE#248D"
        );
    }

    #[test]
    fn csv_rows_carry_the_newest_value_of_each_column() {
        let mut row = Row::default();
        assert!(row.absorb(&Report::Position { x_mm: 5, y_mm: -3 }));
        assert_eq!(
            row.line(Duration::from_secs(2)),
            "2.000000,5,-3,,,,,,,,,,,,,"
        );
        assert!(row.absorb(&Report::Battery {
            percent: 80,
            voltage_mv: 24_000
        }));
        assert_eq!(
            row.line(Duration::from_secs(3)),
            "3.000000,5,-3,,24000,80,,,,,,,,,,"
        );
        assert!(row.absorb(&Report::PoseTime {
            controller_ms: 4_000
        }));
        assert_eq!(
            row.line(Duration::from_secs(4)),
            "4.000000,5,-3,,24000,80,,,,,,4000,,,,"
        );
        assert!(row.absorb(&Report::MeasuredSpeed {
            linear_mm_s: 300,
            rotation_mrad_s: -500,
            left_wheel_crad_s: 250,
            right_wheel_crad_s: -5,
        }));
        assert_eq!(
            row.line(Duration::from_secs(5)),
            "5.000000,5,-3,,24000,80,,,,,,4000,300,-500,2.50,-0.05"
        );
        assert!(!row.absorb(&Report::RegisterValue {
            value: 1,
            echo: None
        }));
        assert_eq!(CSV_HEADER.split(',').count(), 16);
    }

    #[test]
    fn the_format_follows_the_file_name() {
        assert_eq!(Format::for_path(Path::new("run.csv")), Format::Csv);
        assert_eq!(Format::for_path(Path::new("run.log")), Format::Candump);
    }
}
