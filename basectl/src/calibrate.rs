//! `calibrate odometry` and `calibrate scale`: the manual's calibration frames
//! (0x008, 0x007) as guided wizards. Each step is explained, sent, and checked against
//! the status frame, so a refusal stops the wizard with its reason.

use std::io::{BufRead, Write};
use std::time::{Duration, Instant};

use base_core::calibration::{
    OdometryCalibrationCommand as Odometry, ScaleCalibrationCommand as Scale,
};
use base_core::can::{Command, Mode};
use base_core::registers::Reg;

use crate::base::{Base, Error, Pose};

/// The person at the robot: follows instructions and reads measurements off a tape.
pub trait Person {
    /// Shows `instruction` and returns once the person has done it.
    fn confirm(&mut self, instruction: &str) -> Result<(), Error>;
    /// Asks for a number; the answer is checked by the caller.
    fn ask(&mut self, question: &str) -> Result<String, Error>;
}

/// A person at this terminal (or a script piping answers into stdin).
pub struct Terminal;

impl Terminal {
    fn read_line(prompt: &str) -> Result<String, Error> {
        print!("{prompt}");
        std::io::stdout().flush()?;
        let mut answer = String::new();
        if std::io::stdin().lock().read_line(&mut answer)? == 0 {
            return Err(Error::Aborted(
                "stdin ended before the wizard was done".to_owned(),
            ));
        }
        Ok(answer.trim().to_owned())
    }
}

impl Person for Terminal {
    fn confirm(&mut self, instruction: &str) -> Result<(), Error> {
        Self::read_line(&format!("{instruction}\n  press Enter when done: ")).map(drop)
    }

    fn ask(&mut self, question: &str) -> Result<String, Error> {
        Self::read_line(&format!("{question}: "))
    }
}

/// How the base moves during an odometry step.
#[derive(Debug, Clone, Copy)]
pub enum Driving {
    /// The person drives (remote, or `basectl drive` in another terminal).
    ByHand,
    /// basectl drives until the uncalibrated odometry shows the distance or angle.
    Automatic {
        distance_mm: u16,
        angle_mrad: u16,
        speed_mm_s: i16,
        turn_mrad_s: i16,
    },
}

/// What `calibrate odometry` knows before it starts; missing measurements are asked.
#[derive(Debug, Clone, Copy)]
pub struct OdometryPlan {
    pub driving: Driving,
    pub real_mm: Option<u16>,
    pub real_cw_mrad: Option<u16>,
    pub real_ccw_mrad: Option<u16>,
}

/// Enable refresh period while basectl drives: well inside the default 500 ms timeout.
pub(crate) const ENABLE_PERIOD: Duration = Duration::from_millis(100);

#[derive(Clone, Copy)]
enum Motion {
    Forward,
    Clockwise,
    CounterClockwise,
}

pub fn odometry(
    base: &mut Base,
    plan: OdometryPlan,
    person: &mut dyn Person,
    out: &mut dyn Write,
) -> Result<(), Error> {
    const FACTORS: [Reg; 3] = [Reg::FCw, Reg::FCcw, Reg::FLin];
    writeln!(
        out,
        "Odometry calibration: three measured moves, then the factors are stored."
    )?;
    let old = base.read_registers(FACTORS)?;
    let steps = [
        (
            Motion::Forward,
            Odometry::StartLinear,
            "step 1/3: drive straight forward (2 m or more is best)",
            "real distance driven, mm",
            plan.real_mm,
        ),
        (
            Motion::Clockwise,
            Odometry::StartClockwise,
            "step 2/3: turn on the spot clockwise (one full turn = 6283 mrad)",
            "real clockwise angle, mrad",
            plan.real_cw_mrad,
        ),
        (
            Motion::CounterClockwise,
            Odometry::StartCounterClockwise,
            "step 3/3: turn on the spot counter-clockwise",
            "real counter-clockwise angle, mrad",
            plan.real_ccw_mrad,
        ),
    ];
    for (motion, start, explanation, question, known) in steps {
        writeln!(out, "{explanation}")?;
        base.send_checked(Command::OdometryCalibration(start), "the step's start")?;
        let moved = match plan.driving {
            Driving::ByHand => {
                let before = current_pose(base)?;
                person.confirm("  drive now")?;
                let after = current_pose(base)?;
                difference(motion, before, after)
            }
            Driving::Automatic {
                distance_mm,
                angle_mrad,
                speed_mm_s,
                turn_mrad_s,
            } => {
                let (target, linear, rotation) = match motion {
                    Motion::Forward => (distance_mm, speed_mm_s, 0),
                    Motion::Clockwise => (angle_mrad, 0, turn_mrad_s),
                    Motion::CounterClockwise => (angle_mrad, 0, -turn_mrad_s),
                };
                drive_until(base, motion, i64::from(target), linear, rotation)?
            }
        };
        writeln!(out, "  the uncalibrated odometry measured {moved}")?;
        let real = match known {
            Some(real) => real,
            None => ask_u16(person, &format!("  {question}"))?,
        };
        let end = match motion {
            Motion::Forward => Odometry::EndLinear { real_mm: real },
            Motion::Clockwise => Odometry::EndClockwise { real_mrad: real },
            Motion::CounterClockwise => Odometry::EndCounterClockwise { real_mrad: real },
        };
        base.send_checked(
            Command::OdometryCalibration(end),
            &format!("the real value {real}"),
        )?;
        writeln!(out, "  accepted: real {real}")?;
    }
    base.send_checked(
        Command::OdometryCalibration(Odometry::Store),
        "storing the factors",
    )?;
    let new = base.read_registers(FACTORS)?;
    writeln!(out, "stored (1/10000):")?;
    for ((register, old), new) in FACTORS.iter().zip(old).zip(new) {
        writeln!(out, "  {} {old} -> {new}", register.info().name)?;
    }
    Ok(())
}

fn ask_u16(person: &mut dyn Person, question: &str) -> Result<u16, Error> {
    let answer = person.ask(question)?;
    answer.parse().map_err(|_| {
        Error::InvalidInput(format!(
            "{answer:?} is not a whole number 1..=65535 ({question})"
        ))
    })
}

/// The pose of the next complete odometry report: the heading frame follows the
/// position frame every `loop_end_delay` (50 ms by default).
pub(crate) fn current_pose(base: &mut Base) -> Result<Pose, Error> {
    base.wait_for("a heading frame 0x0ED", Duration::from_secs(2), |report| {
        matches!(report, base_core::can::Report::Heading { .. }).then_some(())
    })?;
    Ok(base.pose().unwrap_or_default())
}

/// How far the pose moved in the motion's direction: mm forward, mrad of turn.
fn difference(motion: Motion, before: Pose, after: Pose) -> i64 {
    match motion {
        Motion::Forward => {
            let dx = f64::from(after.x_mm - before.x_mm);
            let dy = f64::from(after.y_mm - before.y_mm);
            dx.hypot(dy).round() as i64
        }
        Motion::Clockwise => i64::from(after.heading_mrad) - i64::from(before.heading_mrad),
        Motion::CounterClockwise => i64::from(before.heading_mrad) - i64::from(after.heading_mrad),
    }
}

/// Drives (enable every 100 ms, velocity with it) until the odometry shows `target`,
/// then stops and waits for standstill. Returns what the odometry measured.
fn drive_until(
    base: &mut Base,
    motion: Motion,
    target: i64,
    linear_mm_s: i16,
    rotation_mrad_s: i16,
) -> Result<i64, Error> {
    let start = current_pose(base)?;
    let speed = i64::from(
        linear_mm_s
            .unsigned_abs()
            .max(rotation_mrad_s.unsigned_abs()),
    )
    .max(1);
    // Twice the time at full speed, plus the ramps: a base that needs longer is stuck.
    let limit = Duration::from_millis(u64::try_from(target * 2000 / speed).unwrap_or(0) + 5000);
    let started = Instant::now();
    while difference(motion, start, current_pose(base)?) < target {
        if started.elapsed() > limit {
            stop(base)?;
            let mode = base.status().map_or(Mode::Starting, |status| status.mode);
            return Err(Error::Aborted(format!(
                "the base did not get there within {} s (mode {mode:?}: e-stop, or remote in control?)",
                limit.as_secs()
            )));
        }
        base.send(Command::Enable { refresh: true })?;
        base.send(Command::Velocity {
            linear_mm_s,
            rotation_mrad_s,
        })?;
        pause(base, ENABLE_PERIOD)?;
    }
    stop(base)?;
    Ok(difference(motion, start, current_pose(base)?))
}

/// Commands standstill and keeps the enable until the pose stops changing, so the
/// base ramps down under control, then withdraws the enable.
pub(crate) fn stop(base: &mut Base) -> Result<(), Error> {
    let mut last = current_pose(base)?;
    let mut still_since = Instant::now();
    while still_since.elapsed() < Duration::from_millis(500) {
        base.send(Command::Enable { refresh: true })?;
        base.send(Command::Velocity {
            linear_mm_s: 0,
            rotation_mrad_s: 0,
        })?;
        pause(base, ENABLE_PERIOD)?;
        let now = current_pose(base)?;
        if now != last {
            last = now;
            still_since = Instant::now();
        }
    }
    base.send(Command::Enable { refresh: false })
}

/// Reads reports for `duration`, keeping the latest pose and status current.
pub(crate) fn pause(base: &mut Base, duration: Duration) -> Result<(), Error> {
    let until = Instant::now() + duration;
    while base
        .next_report(until.saturating_duration_since(Instant::now()))?
        .is_some()
    {}
    Ok(())
}

/// The full 24-bit scale offset (registers 44 and 45), or `None` from a firmware whose
/// register map has no such registers (it refuses the read).
fn full_offset(base: &mut Base) -> Result<Option<i32>, Error> {
    match base.read_registers([Reg::WeightOffsetHi, Reg::WeightOffsetLo]) {
        Ok([high, low]) => {
            let bits = (u32::from(high) << 16) | u32::from(low);
            // 24-bit two's complement: sign-extend bit 23.
            Ok(Some(((bits << 8) as i32) >> 8))
        }
        Err(Error::ReadRefused { .. }) => Ok(None),
        Err(error) => Err(error),
    }
}

/// What `calibrate scale` knows before it starts.
#[derive(Debug, Clone, Copy)]
pub struct ScalePlan {
    pub known_g: Option<u16>,
}

pub fn scale(
    base: &mut Base,
    plan: ScalePlan,
    person: &mut dyn Person,
    out: &mut dyn Write,
) -> Result<(), Error> {
    const RESULTS: [Reg; 2] = [Reg::WeightOffset, Reg::ScaleValue];
    writeln!(
        out,
        "Scale calibration: an empty reading, then a known weight."
    )?;
    let old = base.read_registers(RESULTS)?;
    let old_full = full_offset(base)?;
    base.send_checked(
        Command::ScaleCalibration(Scale::Start),
        "the calibration's start",
    )?;
    writeln!(out, "step 1/2: the empty reading")?;
    person.confirm("  empty the scale")?;
    base.send_checked(Command::ScaleCalibration(Scale::Tare), "the empty reading")?;
    writeln!(out, "step 2/2: a known weight")?;
    let grams = match plan.known_g {
        Some(grams) => {
            person.confirm(&format!("  put {grams} g on the scale"))?;
            grams
        }
        None => ask_u16(person, "  put a known weight on the scale; its weight in g")?,
    };
    if grams == 0 {
        return Err(Error::InvalidInput(
            "the known weight must be 1..=65535 g".to_owned(),
        ));
    }
    base.send_checked(
        Command::ScaleCalibration(Scale::KnownWeight { grams }),
        &format!("the known weight {grams} g"),
    )?;
    let new = base.read_registers(RESULTS)?;
    writeln!(out, "stored:")?;
    for ((register, old), new) in RESULTS.iter().zip(old).zip(new) {
        writeln!(out, "  {} {old} -> {new}", register.info().name)?;
    }
    // weight_offset (19) reads the offset clamped to 16 bits; the full one is 44/45.
    if let (Some(old), Some(new)) = (old_full, full_offset(base)?) {
        writeln!(out, "  full offset (44/45) {old} -> {new}")?;
    }
    // The frame already on its way may predate the new calibration: take the second.
    base.next_weight()?;
    let weight = base.next_weight()?;
    writeln!(out, "the scale now reads {weight} g")?;
    Ok(())
}
