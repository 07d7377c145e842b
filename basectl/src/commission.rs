//! `commission wheels`: turns each wheel alone, slowly forward, and confirms which
//! wheel turned and which way.
//!
//! Two observers, because neither sees everything. The controller's odometry (the
//! pose frames) shows what its drives report: that the drive it drives as the left
//! one turned, and turned the commanded way in its own frame (the heading turns
//! clockwise when only the left wheel rolls forward). It cannot show where that drive
//! sits: with swapped address switches, or a `motor_dir` that inverts the wrong motor,
//! every drive still does what it is told and reports it faithfully. Only a person
//! looking at the wheels sees that, so basectl asks, and from the two answers names
//! the fault: swapped addresses, or which `motor_dir` bit is wrong.
//!
//! What the pose frames do show is a drive whose reports run against its command (its
//! direction parameter differs from the one the base was set up with, a replaced
//! drive): the heading turns the wrong way, and the controller stops the base with a
//! `WrongDirection` fault once it is sure. The check names that before asking.

use std::fmt;
use std::io::Write;
use std::time::{Duration, Instant};

use base_core::can::{Command, Mode, Rejection, Status};
use base_core::plausibility::Finding;
use base_core::registers::{MOTOR_DIR_INVERT_LEFT, MOTOR_DIR_INVERT_RIGHT, Reg};

use crate::base::{Base, Error};
use crate::calibrate::{ENABLE_PERIOD, Person, current_pose, pause, stop};

/// How the wheels are turned.
#[derive(Debug, Clone, Copy)]
pub struct WheelsPlan {
    /// The turning wheel's speed at its rim, mm/s (the other stands).
    pub speed_mm_s: i16,
    /// How long each wheel turns.
    pub duration: Duration,
}

impl Default for WheelsPlan {
    /// 60 mm/s for 2 s: 12 cm of rim, plain to see, slow enough to stop by hand.
    fn default() -> Self {
        Self {
            speed_mm_s: 60,
            duration: Duration::from_secs(2),
        }
    }
}

/// A wheel, as the person at the base sees it (from behind, looking forward).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
}

impl fmt::Display for Side {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Side::Left => "left",
            Side::Right => "right",
        })
    }
}

/// What the person saw during one step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Seen {
    Turned { side: Side, forward: bool },
    Nothing,
}

impl fmt::Display for Seen {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Seen::Turned { side, forward } => {
                let way = if *forward { "forward" } else { "backward" };
                write!(f, "the {side} wheel turned {way}")
            }
            Seen::Nothing => f.write_str("no wheel turned"),
        }
    }
}

/// The question the person answers after each step.
pub const QUESTION: &str = "which wheel turned, and which way? \
    l+ left forward, l- left backward, r+ right forward, r- right backward, n none";

/// Reads an answer to [`QUESTION`].
pub fn parse_seen(answer: &str) -> Result<Seen, Error> {
    let seen = match answer.trim().to_ascii_lowercase().as_str() {
        "l+" => Seen::Turned {
            side: Side::Left,
            forward: true,
        },
        "l-" => Seen::Turned {
            side: Side::Left,
            forward: false,
        },
        "r+" => Seen::Turned {
            side: Side::Right,
            forward: true,
        },
        "r-" => Seen::Turned {
            side: Side::Right,
            forward: false,
        },
        "n" | "none" => Seen::Nothing,
        other => {
            return Err(Error::InvalidInput(format!(
                "{other:?} is none of l+ l- r+ r- n"
            )));
        }
    };
    Ok(seen)
}

/// What the two answers say about the wiring, with the fix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Diagnosis {
    /// Each command turned its own wheel forward.
    Correct,
    /// The left command turned the right wheel and the right command the left one.
    AddressesSwapped,
    /// Each command turned its own wheel, these ones backward: `motor_dir` should be
    /// `fixed_motor_dir`.
    WrongDirection {
        left_backward: bool,
        right_backward: bool,
        fixed_motor_dir: u16,
    },
    /// Anything else: a wheel that did not turn, or both commands on one wheel.
    Unexplained(String),
}

impl fmt::Display for Diagnosis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Diagnosis::Correct => f.write_str("both wheels are wired and set up right"),
            Diagnosis::AddressesSwapped => f.write_str(
                "the drive addresses are swapped: the drive the controller drives as the \
                 left wheel (slave 1) sits on the right wheel. Swap the drives' address \
                 switches (or their cables), then run this check again",
            ),
            Diagnosis::WrongDirection {
                left_backward,
                right_backward,
                fixed_motor_dir,
            } => {
                let wheels = match (left_backward, right_backward) {
                    (true, true) => "both wheels turn",
                    (true, false) => "the left wheel turns",
                    _ => "the right wheel turns",
                };
                write!(
                    f,
                    "{wheels} backward when told forward: motor_dir is wrong; set it to \
                     {fixed_motor_dir} (basectl reg set motor_dir {fixed_motor_dir}) and \
                     run this check again"
                )
            }
            Diagnosis::Unexplained(what) => write!(f, "{what}: check the drives' wiring"),
        }
    }
}

/// Names the fault from what the person saw when the left wheel alone was told to
/// turn forward, then the right one; `motor_dir` is the register's value now.
pub fn diagnose(left_command: Seen, right_command: Seen, motor_dir: u16) -> Diagnosis {
    use Side::{Left, Right};
    match (left_command, right_command) {
        (
            Seen::Turned {
                side: Left,
                forward: left_forward,
            },
            Seen::Turned {
                side: Right,
                forward: right_forward,
            },
        ) => {
            if left_forward && right_forward {
                return Diagnosis::Correct;
            }
            let mut fixed_motor_dir = motor_dir;
            if !left_forward {
                fixed_motor_dir ^= MOTOR_DIR_INVERT_LEFT;
            }
            if !right_forward {
                fixed_motor_dir ^= MOTOR_DIR_INVERT_RIGHT;
            }
            Diagnosis::WrongDirection {
                left_backward: !left_forward,
                right_backward: !right_forward,
                fixed_motor_dir,
            }
        }
        (Seen::Turned { side: Right, .. }, Seen::Turned { side: Left, .. }) => {
            Diagnosis::AddressesSwapped
        }
        (Seen::Nothing, _) => {
            Diagnosis::Unexplained("told to turn the left wheel, no wheel turned".to_owned())
        }
        (_, Seen::Nothing) => {
            Diagnosis::Unexplained("told to turn the right wheel, no wheel turned".to_owned())
        }
        (Seen::Turned { side: first, .. }, Seen::Turned { .. }) => {
            Diagnosis::Unexplained(format!("both commands turned the {first} wheel"))
        }
    }
}

/// Runs the check; `Ok` only when both wheels turned as told. A wrong wiring ends in
/// [`Error::Aborted`] with the [`Diagnosis`].
pub fn wheels(
    base: &mut Base,
    plan: WheelsPlan,
    person: &mut dyn Person,
    out: &mut dyn Write,
) -> Result<(), Error> {
    if plan.speed_mm_s < 2 {
        return Err(Error::InvalidInput(format!(
            "speed {} mm/s: at least 2",
            plan.speed_mm_s
        )));
    }
    let [wheel_dist, motor_dir] = base.read_registers([Reg::WheelDist, Reg::MotorDir])?;
    ready_to_drive(base)?;
    writeln!(
        out,
        "Wheel check: each wheel turns alone, forward at {} mm/s for {:.1} s.",
        plan.speed_mm_s,
        plan.duration.as_secs_f64()
    )?;
    person.confirm(
        "Jack the base up so the wheels turn freely (or give it 0.3 m of room), and keep \
         the e-stop at hand",
    )?;
    let mut seen = [Seen::Nothing; 2];
    for (index, side) in [Side::Left, Side::Right].into_iter().enumerate() {
        writeln!(out, "step {}/2: the {side} wheel alone, forward", index + 1)?;
        let turned_mrad = turn_alone(base, side, plan, wheel_dist)?;
        // Only the left wheel forward turns the base clockwise (+), only the right
        // one counter-clockwise.
        let expected_sign = match side {
            Side::Left => 1,
            Side::Right => -1,
        };
        let expected_mrad = f64::from(plan.speed_mm_s) * plan.duration.as_secs_f64()
            / f64::from(wheel_dist)
            * 1000.0;
        if turned_mrad * expected_sign < (expected_mrad / 3.0) as i64 {
            let status = base.status();
            if let Some(against) = against_its_command(side, turned_mrad, expected_mrad, status) {
                return Err(Error::Aborted(against));
            }
            let mode = status.map_or(Mode::Starting, |status| status.mode);
            return Err(Error::Aborted(format!(
                "the controller did not see its {side} drive turn forward (heading changed \
                 {turned_mrad} mrad, about {}{expected_mrad:.0} expected; mode {mode:?})",
                if expected_sign < 0 { "-" } else { "+" }
            )));
        }
        writeln!(
            out,
            "  the controller saw its {side} drive turn forward (heading {turned_mrad:+} mrad)"
        )?;
        seen[index] = parse_seen(&person.ask(&format!("  {QUESTION}"))?)?;
        writeln!(out, "  you saw: {}", seen[index])?;
    }
    let diagnosis = diagnose(seen[0], seen[1], motor_dir);
    match diagnosis {
        Diagnosis::Correct => {
            writeln!(out, "{diagnosis}")?;
            Ok(())
        }
        _ => Err(Error::Aborted(diagnosis.to_string())),
    }
}

/// The fault when the controller's `side` drive ran against its command: the heading
/// turned at least a third of `expected_mrad` the wrong way, or the controller stopped
/// the base because that wheel turned against its command. `None` otherwise.
pub fn against_its_command(
    side: Side,
    turned_mrad: i64,
    expected_mrad: f64,
    status: Option<Status>,
) -> Option<String> {
    let (expected_sign, subject) = match side {
        Side::Left => (1, 1),
        Side::Right => (-1, 2),
    };
    let wrong_direction = Rejection::Feedback(Finding::WrongDirection).code();
    let stopped = status.is_some_and(|status| {
        status.mode == Mode::Fault
            && status.last_rejection == wrong_direction
            && status.last_rejection_subject == subject
    });
    let backward = turned_mrad * expected_sign <= -((expected_mrad / 3.0) as i64);
    if !(stopped || backward) {
        return None;
    }
    let reaction = if stopped {
        ", and the controller stopped the base (WrongDirection, a drive fault)"
    } else {
        ""
    };
    Some(format!(
        "the controller saw its {side} drive turn backward when told forward (heading \
         changed {turned_mrad:+} mrad){reaction}: that drive's position runs against its \
         command, so its direction parameter differs from the one this base was set up \
         with (a replaced drive?). Set it as on the drive it replaced (MEXE02), press the \
         front button to confirm, and run this check again"
    ))
}

/// The base must be able to drive, without a person in the safety zone (its limits
/// would turn the standing wheel too) and without the remote in control.
fn ready_to_drive(base: &mut Base) -> Result<(), Error> {
    let status = base.next_status()?;
    if !matches!(status.mode, Mode::Standby | Mode::Active) {
        return Err(Error::Aborted(format!(
            "the base cannot drive now (mode {:?}): release the e-stop, confirm, and try again",
            status.mode
        )));
    }
    if status.flags.safety_zone {
        return Err(Error::Aborted(
            "someone is in the safety zone: its limits would turn both wheels".to_owned(),
        ));
    }
    if status.flags.remote_in_control {
        return Err(Error::Aborted(
            "the remote is in control: release its dead-man".to_owned(),
        ));
    }
    Ok(())
}

/// Turns one wheel alone and returns how far the controller's heading turned, mrad.
///
/// Left = lin + rot·wheel_dist/2, right = lin − rot·wheel_dist/2: with lin = v/2 and
/// rot = v/wheel_dist one wheel runs at v and the other stands.
fn turn_alone(
    base: &mut Base,
    side: Side,
    plan: WheelsPlan,
    wheel_dist_mm: u16,
) -> Result<i64, Error> {
    let linear_mm_s = plan.speed_mm_s / 2;
    let rotation = (f64::from(2 * linear_mm_s) * 1000.0 / f64::from(wheel_dist_mm)).round();
    let rotation_mrad_s = match side {
        Side::Left => rotation,
        Side::Right => -rotation,
    } as i16;
    let before = current_pose(base)?;
    let started = Instant::now();
    while started.elapsed() < plan.duration {
        base.send(Command::Enable { refresh: true })?;
        base.send(Command::Velocity {
            linear_mm_s,
            rotation_mrad_s,
        })?;
        pause(base, ENABLE_PERIOD)?;
    }
    stop(base)?;
    let after = current_pose(base)?;
    Ok(i64::from(after.heading_mrad) - i64::from(before.heading_mrad))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn turned(side: Side, forward: bool) -> Seen {
        Seen::Turned { side, forward }
    }

    /// A drive running against its command is named from the heading alone, or from
    /// the controller's WrongDirection fault on that wheel; a wheel that merely turned
    /// too little is not.
    #[test]
    fn a_drive_against_its_command_is_named_from_the_heading_or_the_fault() {
        let fault = |subject: u8| Status {
            mode: Mode::Fault,
            last_rejection: 0x43,
            last_rejection_subject: subject,
            ..Status::default()
        };
        let named = |side, turned, status| {
            against_its_command(side, turned, 240.0, status)
                .is_some_and(|text| text.contains("direction parameter"))
        };
        assert!(named(Side::Left, -200, None));
        assert!(named(Side::Right, 200, None));
        assert!(named(Side::Left, -20, Some(fault(1))));
        assert!(named(Side::Right, 10, Some(fault(2))));
        assert!(
            !named(Side::Left, -20, Some(fault(2))),
            "the other wheel's fault"
        );
        assert!(!named(Side::Left, 30, None), "too little, not backward");
        assert!(
            !named(Side::Right, -240, None),
            "forward for the right wheel"
        );
    }

    #[test]
    fn answers_parse_and_anything_else_is_refused() {
        assert_eq!(parse_seen(" L+ ").unwrap(), turned(Side::Left, true));
        assert_eq!(parse_seen("r-").unwrap(), turned(Side::Right, false));
        assert_eq!(parse_seen("none").unwrap(), Seen::Nothing);
        assert!(parse_seen("left").is_err());
    }

    /// Every wiring a base can have, and what the person then sees: left command
    /// first, right command second (the right motor mirrored, motor_dir 2).
    #[test]
    fn each_wiring_fault_gets_its_own_diagnosis() {
        use Side::{Left, Right};
        let cases = [
            (turned(Left, true), turned(Right, true), Diagnosis::Correct),
            // Swapped address switches: slave 1 on the mirrored right motor.
            (
                turned(Right, false),
                turned(Left, false),
                Diagnosis::AddressesSwapped,
            ),
            (
                turned(Left, false),
                turned(Right, true),
                Diagnosis::WrongDirection {
                    left_backward: true,
                    right_backward: false,
                    fixed_motor_dir: 3,
                },
            ),
            (
                turned(Left, true),
                turned(Right, false),
                Diagnosis::WrongDirection {
                    left_backward: false,
                    right_backward: true,
                    fixed_motor_dir: 0,
                },
            ),
            (
                turned(Left, false),
                turned(Right, false),
                Diagnosis::WrongDirection {
                    left_backward: true,
                    right_backward: true,
                    fixed_motor_dir: 1,
                },
            ),
        ];
        for (left, right, expected) in cases {
            assert_eq!(diagnose(left, right, 2), expected, "{left} / {right}");
        }
        assert!(matches!(
            diagnose(Seen::Nothing, turned(Right, true), 2),
            Diagnosis::Unexplained(_)
        ));
        assert!(matches!(
            diagnose(turned(Left, true), turned(Left, true), 2),
            Diagnosis::Unexplained(_)
        ));
    }
}
