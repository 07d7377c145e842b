//! The whole-robot simulation for long runs (`virtual_robot::chaos`): seeded runs of
//! every input at once against the firmware's real tasks on the virtual clock, the
//! safety rules checked every control cycle.
//!
//! ```text
//! cargo run -p virtual-robot --release --example chaos -- --hours 24 --seed 1
//! cargo run -p virtual-robot --release --example chaos -- --seed 7 --runs 1 --minutes 10
//! cargo run -p virtual-robot --release --example chaos -- --replay target/chaos/seed-7-rule-1.jsonl
//! ```
//!
//! Each run lasts `--minutes` (default 10) of virtual time; runs go on with the next
//! seed until `--hours` of virtual time (default 1) or `--runs` runs. A violation is
//! printed with its rule, the last events, what the robot did and the commands that
//! replay it; it is shrunk (unless `--no-shrink`) and the shrunk case written to
//! `--out` (default `target/chaos`). The exit status is 1 if any run broke a rule.
//! `--all-inputs` adds the inputs that the test run leaves out while their defects are
//! being fixed (`chaos::generate::Mix`); `--print-events` prints each run's events.

use std::path::PathBuf;
use std::process::ExitCode;

use virtual_robot::chaos::{self, Totals, case::Case, generate::Mix, shrink::Budget};

struct Options {
    seed: u64,
    hours: f64,
    runs: Option<u64>,
    minutes: u64,
    replay: Option<PathBuf>,
    shrink: bool,
    out: PathBuf,
    /// Print each seed's events (as a case file) before running it.
    print_events: bool,
    mix: Mix,
}

const USAGE: &str = "usage: chaos [--hours H] [--seed S] [--runs N] [--minutes M] [--no-shrink] [--out DIR] [--print-events] [--all-inputs] | --replay FILE";

fn options() -> Result<Options, String> {
    let mut options = Options {
        seed: 1,
        hours: 1.0,
        runs: None,
        minutes: 10,
        replay: None,
        shrink: true,
        out: PathBuf::from("target/chaos"),
        print_events: false,
        mix: Mix::WITHOUT_OPEN_DEFECTS,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().ok_or(format!("{name} needs a value"));
        let number = |text: String, name: &str| -> Result<f64, String> {
            text.parse::<f64>()
                .ok()
                .filter(|number| number.is_finite() && *number >= 0.0)
                .ok_or(format!("{name}: not a number: {text}"))
        };
        match arg.as_str() {
            "--seed" => options.seed = number(value("--seed")?, "--seed")? as u64,
            "--hours" => options.hours = number(value("--hours")?, "--hours")?,
            "--runs" => options.runs = Some(number(value("--runs")?, "--runs")? as u64),
            "--minutes" => {
                options.minutes = (number(value("--minutes")?, "--minutes")? as u64).max(1)
            }
            "--replay" => options.replay = Some(PathBuf::from(value("--replay")?)),
            "--no-shrink" => options.shrink = false,
            "--print-events" => options.print_events = true,
            "--all-inputs" => options.mix = Mix::ALL,
            "--out" => options.out = PathBuf::from(value("--out")?),
            "--help" | "-h" => return Err(USAGE.to_owned()),
            other => return Err(format!("unknown option {other}\n{USAGE}")),
        }
    }
    Ok(options)
}

fn replay(path: &PathBuf) -> ExitCode {
    let case = match std::fs::read_to_string(path)
        .map_err(|error| error.to_string())
        .and_then(|text| Case::parse(&text))
    {
        Ok(case) => case,
        Err(error) => {
            eprintln!("{}: {error}", path.display());
            return ExitCode::FAILURE;
        }
    };
    for comment in &case.comments {
        println!("# {comment}");
    }
    let outcome = chaos::run(&case.events, case.header.duration_ms);
    let mut totals = Totals::default();
    totals.add(&outcome);
    match &outcome.violation {
        Some(found) => {
            println!("{found}");
            println!("{totals}");
            ExitCode::FAILURE
        }
        None => {
            println!(
                "no rule broken in {:.1} s of virtual time",
                outcome.virtual_ms as f64 / 1000.0
            );
            println!("{totals}");
            ExitCode::SUCCESS
        }
    }
}

fn main() -> ExitCode {
    let options = match options() {
        Ok(options) => options,
        Err(message) => {
            eprintln!("{message}");
            return ExitCode::FAILURE;
        }
    };
    if let Some(path) = &options.replay {
        return replay(path);
    }
    let duration_ms = options.minutes * 60_000;
    let budget_ms = (options.hours * 3.6e6) as u64;
    let mut totals = Totals::default();
    let mut seed = options.seed;
    loop {
        let done = match options.runs {
            Some(runs) => totals.runs >= runs,
            None => totals.virtual_ms >= budget_ms,
        };
        if done {
            break;
        }
        let events = chaos::generate::generate(seed, duration_ms, options.mix);
        if options.print_events {
            let case = Case {
                comments: vec![format!("seed {seed}, {} virtual minutes", options.minutes)],
                header: chaos::case::Header {
                    duration_ms,
                    seed: Some(seed),
                    rule: None,
                },
                events: events.clone(),
            };
            print!("{}", case.to_text());
        }
        let outcome = chaos::run(&events, duration_ms);
        totals.add(&outcome);
        if let Some(found) = outcome.violation {
            let budget = options.shrink.then(Budget::default);
            let finding = chaos::investigate(
                seed,
                options.mix,
                duration_ms,
                &events,
                found,
                budget,
                Some(&options.out),
            );
            println!("{finding}");
        }
        if totals.runs.is_multiple_of(10) {
            eprintln!("{totals}");
        }
        seed += 1;
    }
    println!("{totals}");
    if totals.violations > 0 {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
