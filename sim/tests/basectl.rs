//! basectl against the simulator binary, end to end over its SLCAN pseudo-terminal:
//! register round trip, both calibration wizards without a person at the keyboard,
//! and `monitor --count`. The test lives here because only this package's tests can
//! name the simulator binary (`CARGO_BIN_EXE_virtual-base-controller`); it calls
//! basectl's library functions, the same ones its `main` dispatches to.

use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use basectl::base::{Base, Error};
use basectl::bus::SlcanPort;
use basectl::calibrate::{self, Driving, OdometryPlan, Person, ScalePlan};
use basectl::monitor::{self, Until};
use basectl::registers;
use virtual_robot::process::SimulatorProcess;

/// The SLCAN link is a pseudo-terminal, and on a loaded machine (CI's two busy cores)
/// two of them served side by side from one test process stalled for seconds in the
/// kernel: the simulator read none of basectl's bytes for up to 6 s and then all at
/// once, and basectl none of its frames. Measured on this VM under two busy loops: 7
/// of 8 runs of this file failed with its tests in parallel, none of 11 with them one
/// after the other (3 of those under four busy loops). These tests are about basectl, not about pseudo-terminals
/// under load: one simulator at a time, each test holding its turn to its end.
static ONE_SIMULATOR_AT_A_TIME: Mutex<()> = Mutex::new(());

fn my_turn() -> MutexGuard<'static, ()> {
    ONE_SIMULATOR_AT_A_TIME
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
}

/// The simulator with its SLCAN port linked (the link exists once it has started).
fn start() -> SimulatorProcess {
    SimulatorProcess::start(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .expect("the simulator starts")
}

fn port(simulator: &SimulatorProcess) -> SlcanPort {
    SlcanPort::open(simulator.link().to_str().unwrap(), 500_000).expect("the SLCAN channel opens")
}

/// The person at the robot, played through the simulator's console: putting the
/// weight on the scale is `weight G` on its stdin.
struct ScriptedPerson<'a> {
    simulator: &'a mut SimulatorProcess,
    known_g: u16,
}

impl Person for ScriptedPerson<'_> {
    fn confirm(&mut self, instruction: &str) -> Result<(), Error> {
        let grams = if instruction.contains("empty") {
            0
        } else {
            self.known_g
        };
        self.simulator.console(&format!("weight {grams}"))?;
        // The controller filters the load cell's readings: let them settle on the new load.
        std::thread::sleep(Duration::from_secs(3));
        Ok(())
    }

    fn ask(&mut self, question: &str) -> Result<String, Error> {
        panic!("the test gives every value up front, yet was asked {question:?}")
    }
}

/// No person: the odometry test gives every value up front and drives by itself.
struct Nobody;

impl Person for Nobody {
    fn confirm(&mut self, instruction: &str) -> Result<(), Error> {
        panic!("nobody is there to {instruction:?}")
    }

    fn ask(&mut self, question: &str) -> Result<String, Error> {
        panic!("nobody is there to answer {question:?}")
    }
}

#[test]
fn a_register_written_with_basectl_reads_back_and_a_bad_value_is_refused_with_its_reason() {
    let _turn = my_turn();
    let simulator = start();
    let mut port = port(&simulator);
    let mut base = Base::new(&mut port, Duration::from_millis(500));
    let loop_end_delay = registers::lookup("loop_end_delay").unwrap();
    let mut out = Vec::new();
    registers::set(&mut base, loop_end_delay, 40, false, &mut out).unwrap();
    registers::get(&mut base, loop_end_delay, false, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    assert!(text.contains("loop_end_delay: 50 -> 40 ms"), "{text}");
    assert!(text.contains("loop_end_delay = 40 ms"), "{text}");

    // In range by itself, but empty above full breaks a cross-register rule.
    let batt_empty = registers::lookup("batt_empty_mv").unwrap();
    let error = registers::set(&mut base, batt_empty, 30_000, false, &mut Vec::new())
        .unwrap_err()
        .to_string();
    assert!(
        error.contains(
            "30000 is not a valid value for batt_empty_mv: it breaks the rule \
             batt_empty_mv < batt_full_mv (batt_full_mv is 25500 mV)"
        ),
        "{error}"
    );
}

#[test]
fn the_odometry_wizard_runs_end_to_end_and_stores_new_factors() {
    let _turn = my_turn();
    let simulator = start();
    let mut port = port(&simulator);
    let mut base = Base::new(&mut port, Duration::from_millis(500));
    let plan = OdometryPlan {
        driving: Driving::Automatic {
            distance_mm: 300,
            angle_mrad: 1500,
            speed_mm_s: 200,
            turn_mrad_s: 1000,
        },
        // Real moves about 10 % shorter than the odometry's, well inside 0.5 ... 1.5.
        real_mm: Some(300),
        real_cw_mrad: Some(1450),
        real_ccw_mrad: Some(1450),
    };
    let mut out = Vec::new();
    calibrate::odometry(&mut base, plan, &mut Nobody, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    for factor in ["f_cw", "f_ccw", "f_lin"] {
        let line = text
            .lines()
            .find(|line| line.trim_start().starts_with(&format!("{factor} ")))
            .unwrap();
        let [old, new] = [1, 3].map(|i| {
            line.split_whitespace()
                .nth(i)
                .unwrap()
                .parse::<u16>()
                .unwrap()
        });
        assert!(
            new < old,
            "{factor}: real shorter than measured lowers the factor: {line}"
        );
    }
}

#[test]
fn the_scale_wizard_runs_end_to_end_and_the_scale_then_reads_the_known_weight() {
    let _turn = my_turn();
    let mut simulator = start();
    let mut port = port(&simulator);
    let mut base = Base::new(&mut port, Duration::from_millis(500));
    let mut person = ScriptedPerson {
        simulator: &mut simulator,
        known_g: 2000,
    };
    let mut out = Vec::new();
    calibrate::scale(
        &mut base,
        ScalePlan {
            known_g: Some(2000),
        },
        &mut person,
        &mut out,
    )
    .unwrap();
    let text = String::from_utf8(out).unwrap();
    assert!(text.contains("weight_offset"), "{text}");
    // The full offset is shown too, from registers 44/45.
    assert!(text.contains("full offset (44/45) 20490 -> "), "{text}");
    let reading: u16 = text
        .lines()
        .last()
        .unwrap()
        .split_whitespace()
        .nth(4)
        .unwrap()
        .parse()
        .unwrap();
    assert!(reading.abs_diff(2000) <= 20, "{text}");
}

#[test]
fn monitor_stops_after_count_frames_and_decodes_each() {
    let _turn = my_turn();
    let simulator = start();
    let mut port = port(&simulator);
    let mut base = Base::new(&mut port, Duration::from_millis(500));
    let mut out = Vec::new();
    monitor::monitor(
        &mut base,
        Until {
            count: Some(80),
            seconds: None,
        },
        monitor::Style::Lines,
        &mut out,
    )
    .unwrap();
    let text = String::from_utf8(out).unwrap();
    assert_eq!(text.lines().count(), 80, "{text}");
    assert!(
        text.lines().any(|line| line.starts_with("position")),
        "{text}"
    );
    assert!(
        text.lines().any(|line| line.starts_with("status    mode")),
        "{text}"
    );
}
