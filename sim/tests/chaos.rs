//! The whole-robot simulation tester (`virtual_robot::chaos`, docs/tests.md "The robot
//! tests itself") on a fixed budget: a fixed list of seeds, each a few virtual minutes
//! of every input at once, the safety rules checked every control cycle; then every
//! case in `tests/chaos/` (each once a violation, shrunk) replayed. The report line
//! goes to stderr past libtest's capture, so CI's log shows it.
//!
//! A violation fails the test with its seed, rule, last events, the shrunk case and
//! the command that replays it; the case is written to `target/chaos/`.

use std::path::{Path, PathBuf};

use virtual_robot::chaos::{self, Totals, case::Case, generate::Mix, shrink::Budget};

/// Seeds and virtual minutes of the fixed budget: about 2 virtual hours, a minute or
/// two of wall time in a release-optimised test build on one busy core.
const FIRST_SEED: u64 = 1;
const SEEDS: u64 = 24;
const MINUTES: u64 = 5;

fn report(totals: &Totals) {
    use std::io::Write as _;
    // Straight to stderr, past libtest's capture of `eprintln!`: CI's log shows it.
    if totals.runs > 0 {
        let _ = writeln!(std::io::stderr(), "{totals}");
    }
}

#[test]
fn every_input_at_once_breaks_no_safety_rule_over_a_fixed_budget_of_seeds() {
    let duration_ms = MINUTES * 60_000;
    let mut totals = Totals::default();
    let mut findings = Vec::new();
    for seed in FIRST_SEED..FIRST_SEED + SEEDS {
        let (events, outcome) = chaos::run_seed(seed, duration_ms, Mix::WITHOUT_OPEN_DEFECTS);
        totals.add(&outcome);
        if let Some(found) = outcome.violation {
            let budget = Budget {
                runs: 150,
                wall: std::time::Duration::from_secs(90),
            };
            let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/chaos");
            findings.push(
                chaos::investigate(
                    seed,
                    Mix::WITHOUT_OPEN_DEFECTS,
                    duration_ms,
                    &events,
                    found,
                    Some(budget),
                    Some(&out),
                )
                .to_string(),
            );
            // One shrunk finding is enough to act on; the others show with the example.
            break;
        }
    }
    report(&totals);
    assert!(
        totals.virtual_ms >= SEEDS.min(totals.runs) * duration_ms / 2,
        "the runs ended early: {totals}"
    );
    assert!(findings.is_empty(), "{}", findings.join("\n"));
}

fn cases(under: &str) -> Vec<PathBuf> {
    let directory = Path::new(env!("CARGO_MANIFEST_DIR")).join(under);
    let mut cases: Vec<PathBuf> = std::fs::read_dir(&directory)
        .map(|entries| {
            entries
                .filter_map(|entry| entry.ok().map(|entry| entry.path()))
                .filter(|path| {
                    path.extension()
                        .is_some_and(|extension| extension == "jsonl")
                })
                .collect()
        })
        .unwrap_or_default();
    cases.sort();
    cases
}

fn replay(path: &Path) -> (Case, chaos::Outcome) {
    let text = std::fs::read_to_string(path).expect("case readable");
    let case = Case::parse(&text).unwrap_or_else(|error| panic!("{}: {error}", path.display()));
    let outcome = chaos::run(&case.events, case.header.duration_ms);
    (case, outcome)
}

#[test]
fn every_case_the_tester_once_shrunk_now_breaks_no_rule() {
    let mut totals = Totals::default();
    let mut failures = Vec::new();
    for path in cases("tests/chaos") {
        let (_, outcome) = replay(&path);
        totals.add(&outcome);
        if let Some(found) = outcome.violation {
            failures.push(format!(
                "{}:\n{found}replay: cargo run -p virtual-robot --release --example chaos -- --replay {}",
                path.display(),
                path.display()
            ));
        }
    }
    report(&totals);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The cases of defects found and not fixed yet (docs/tests.md, "What the tester
/// found"): each still breaks the rule it broke, so the oracle is shown to catch it.
/// The fix of one makes its case pass here: move it to `tests/chaos/` then. With no
/// defect open, the directory is empty (or absent) and there is nothing to check.
#[test]
fn every_open_case_still_breaks_the_rule_it_was_found_with() {
    let open = cases("tests/chaos/open");
    let mut wrong = Vec::new();
    for path in open {
        let (case, outcome) = replay(&path);
        let broken = outcome.violation.map(|found| found.rule.number());
        if broken != case.header.rule {
            wrong.push(format!(
                "{}: breaks rule {broken:?}, was found breaking rule {:?} (fixed? move it to sim/tests/chaos/)",
                path.display(),
                case.header.rule
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn a_seed_gives_the_same_events_and_the_same_run_every_time() {
    let duration_ms = 60_000;
    let first = chaos::generate::generate(3, duration_ms, Mix::ALL);
    let second = chaos::generate::generate(3, duration_ms, Mix::ALL);
    assert_eq!(first, second);
    assert!(
        first.len() > 20,
        "a minute of chaos has more than {} events",
        first.len()
    );
    let (one, two) = (
        chaos::run(&first, duration_ms),
        chaos::run(&second, duration_ms),
    );
    assert_eq!((one.virtual_ms, one.events), (two.virtual_ms, two.events));
    assert_eq!(
        one.violation.map(|found| (found.rule, found.what)),
        two.violation.map(|found| (found.rule, found.what))
    );
}
