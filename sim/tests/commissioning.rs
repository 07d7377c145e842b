//! `basectl commission wheels` against the simulator binary, end to end over its SLCAN
//! pseudo-terminal. The person at the base is played by the test: after each step it
//! looks at the wheels through the simulator's `status` command, which reports how far
//! each wheel really turned, by the side it sits on (not by its drive's address).
//! With the drives' address switches swapped (`--swap-drive-addresses`) the check
//! must name the swap; the controller alone cannot see it. With a drive whose
//! direction parameter is at the other value (`--reverse-drive`) the controller sees
//! it turn against its command, and the check names that before asking.

use std::time::Duration;

use basectl::base::{Base, Error};
use basectl::bus::SlcanPort;
use basectl::calibrate::Person;
use basectl::commission::{self, WheelsPlan};
use virtual_robot::process::SimulatorProcess;

fn port(simulator: &SimulatorProcess) -> SlcanPort {
    SlcanPort::open(simulator.link().to_str().unwrap(), 500_000).expect("the SLCAN channel opens")
}

/// Looks at the wheels: the simulator's `status` report says how many forward
/// revolutions each motor turned ("turned L 1.234 R -0.567 rev"); the answer is the
/// wheel that moved since the last look, and which way.
struct Watcher<'a> {
    simulator: &'a mut SimulatorProcess,
    last: [f64; 2],
}

impl Watcher<'_> {
    fn look(&mut self) -> [f64; 2] {
        self.simulator.console("status").expect("console");
        let line = self
            .simulator
            .wait_for_line("turned L", Duration::from_secs(5))
            .expect("a status report");
        let turned = line.split("turned L").nth(1).expect("turned L");
        let numbers: Vec<f64> = turned
            .split_whitespace()
            .filter_map(|word| word.parse().ok())
            .collect();
        [numbers[0], numbers[1]]
    }
}

impl Person for Watcher<'_> {
    fn confirm(&mut self, _instruction: &str) -> Result<(), Error> {
        self.last = self.look();
        Ok(())
    }

    fn ask(&mut self, _question: &str) -> Result<String, Error> {
        let now = self.look();
        let moved = [now[0] - self.last[0], now[1] - self.last[1]];
        self.last = now;
        let (side, turned) = if moved[0].abs() >= moved[1].abs() {
            ("l", moved[0])
        } else {
            ("r", moved[1])
        };
        // 60 mm/s for 2 s is 1.3 motor revolutions; a standing wheel turns none.
        Ok(if turned.abs() < 0.2 {
            "n".to_owned()
        } else if turned > 0.0 {
            format!("{side}+")
        } else {
            format!("{side}-")
        })
    }
}

fn check_wheels(simulator: &mut SimulatorProcess) -> (Result<(), Error>, String) {
    let mut port = port(simulator);
    let mut base = Base::new(&mut port, Duration::from_millis(500));
    let mut watcher = Watcher {
        simulator,
        last: [0.0; 2],
    };
    let mut out = Vec::new();
    let result = commission::wheels(&mut base, WheelsPlan::default(), &mut watcher, &mut out);
    (result, String::from_utf8(out).unwrap())
}

#[test]
fn a_correctly_wired_base_passes_the_wheel_check() {
    let mut simulator =
        SimulatorProcess::start(env!("CARGO_BIN_EXE_virtual-base-controller")).expect("starts");
    // The drives answer 1 s after power-on.
    std::thread::sleep(Duration::from_secs(2));
    let (result, text) = check_wheels(&mut simulator);
    assert!(result.is_ok(), "{result:?}\n{text}");
    assert!(
        text.contains("you saw: the left wheel turned forward"),
        "{text}"
    );
    assert!(
        text.contains("you saw: the right wheel turned forward"),
        "{text}"
    );
    assert!(text.contains("wired and set up right"), "{text}");
}

#[test]
fn swapped_drive_addresses_are_found_by_the_wheel_check() {
    let mut simulator = SimulatorProcess::launch(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .arg("--swap-drive-addresses")
        .start()
        .expect("starts");
    std::thread::sleep(Duration::from_secs(2));
    let (result, text) = check_wheels(&mut simulator);
    // The controller saw each of its drives turn as told ...
    assert!(
        text.contains("the controller saw its left drive turn forward"),
        "{result:?}\n{text}"
    );
    // ... but the person saw the other wheel turn, backward.
    assert!(
        text.contains("you saw: the right wheel turned backward"),
        "{result:?}\n{text}"
    );
    assert!(
        text.contains("you saw: the left wheel turned backward"),
        "{result:?}\n{text}"
    );
    match result {
        Err(Error::Aborted(diagnosis)) => {
            assert!(
                diagnosis.contains("drive addresses are swapped"),
                "{diagnosis}"
            )
        }
        other => panic!("expected the swap to be named, got {other:?}\n{text}"),
    }
}

#[test]
fn a_drive_turning_against_its_command_is_named_by_the_wheel_check() {
    let mut simulator = SimulatorProcess::launch(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .arg("--reverse-drive")
        .arg("1")
        .start()
        .expect("starts");
    std::thread::sleep(Duration::from_secs(2));
    let (result, text) = check_wheels(&mut simulator);
    match result {
        Err(Error::Aborted(diagnosis)) => {
            assert!(
                diagnosis.contains("the controller saw its left drive turn backward"),
                "{diagnosis}"
            );
            assert!(diagnosis.contains("direction parameter"), "{diagnosis}");
        }
        other => panic!("expected the reversed drive to be named, got {other:?}\n{text}"),
    }
    assert!(!text.contains("you saw"), "named before asking:\n{text}");
}
