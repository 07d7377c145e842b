//! Several programs reading registers at once through the simulator's socketcand
//! server: two others read registers as fast as they can (one with the manual's
//! two-byte request, one with tagged requests of its own) while basectl reads single
//! registers, saves the configuration and loads one. Every value basectl returns,
//! saves or writes must be the register's own: replies to the others' reads come on
//! the same ID.
//!
//! It calls basectl's library functions, the ones its `main` dispatches to, each on a
//! socketcand connection of its own, as separate programs would.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use base_core::can::{RawFrame, id};
use base_core::registers::{Access, Reg, TABLE};
use basectl::base::Base;
use basectl::bus::{Bus, SocketcandBus};
use basectl::config;
use virtual_robot::process::SimulatorProcess;

/// basectl's default reply timeout.
const REPLY_TIMEOUT: Duration = Duration::from_millis(500);

/// The registers the loaded file changes (and the plain reader leaves alone, since
/// their values change under it), with their new values: all in range, no rule
/// between them and the others.
const LOADED: [(Reg, u16); 3] = [
    (Reg::PcSwitchPulse, 400),
    (Reg::GearRatio, 250),
    (Reg::PsAfkTime, 20000),
];

fn start_simulator() -> SimulatorProcess {
    let simulator = SimulatorProcess::start(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .expect("the simulator starts");
    // The drives boot within the first second; let the controller reach standby.
    thread::sleep(Duration::from_millis(1500));
    simulator
}

fn connect(simulator: &SimulatorProcess) -> SocketcandBus {
    SocketcandBus::open(&simulator.socketcand().to_string()).expect("socketcand connects")
}

/// The read-write registers and their defaults: what a fresh simulator holds.
fn defaults() -> BTreeMap<u8, u16> {
    TABLE
        .iter()
        .filter(|info| info.access == Access::ReadWrite)
        .map(|info| (info.address, info.default))
        .collect()
}

/// Another program reading registers as fast as it can: each request 1 ms after the
/// reply to the previous one (or after 10 ms without one), cycling through every
/// register. `tag_base`: `None` sends the manual's `01 addr`; `Some` a tag per request.
fn hammer(
    mut bus: SocketcandBus,
    tag_base: Option<u16>,
    stop: Arc<AtomicBool>,
    reads: Arc<AtomicU64>,
) -> thread::JoinHandle<()> {
    thread::spawn(move || {
        let addresses: Vec<u8> = TABLE.iter().map(|info| info.address).collect();
        let mut tag = tag_base.unwrap_or(0);
        for &address in addresses.iter().cycle() {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            let request = match tag_base {
                None => vec![0x01, address],
                Some(_) => {
                    tag = tag.wrapping_add(1).max(1);
                    let [msb, lsb] = tag.to_be_bytes();
                    vec![0x01, address, msb, lsb]
                }
            };
            let frame = RawFrame::new(id::REGISTER_READ, &request).expect("a valid frame");
            bus.send(&frame).expect("the hammer sends");
            let deadline = Instant::now() + Duration::from_millis(10);
            while let Some(frame) = bus
                .receive(deadline.saturating_duration_since(Instant::now()))
                .expect("the hammer receives")
            {
                if frame.id() == id::REGISTER_READ && frame.data().first() != Some(&0x01) {
                    break;
                }
            }
            reads.fetch_add(1, Ordering::Relaxed);
            // A program's own pace: with none, two programs that each take the next
            // reply as theirs set each other off faster than any controller answers,
            // and nobody gets a reply through (measured: ~6000 requests/s, and reads
            // failing after 15 attempts on a loaded machine).
            thread::sleep(Duration::from_millis(1));
        }
    })
}

/// The saved file's values by address.
fn saved_values(path: &Path) -> BTreeMap<u8, u16> {
    let text = std::fs::read_to_string(path).expect("the saved file");
    let document: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    document["registers"]
        .as_array()
        .expect("a register list")
        .iter()
        .map(|entry| {
            (
                u8::try_from(entry["address"].as_u64().unwrap()).unwrap(),
                u16::try_from(entry["value"].as_u64().unwrap()).unwrap(),
            )
        })
        .collect()
}

/// `saved` with the values of `changes` put in.
fn with_changes(saved: &Path, target: &Path, changes: &[(Reg, u16)]) {
    let text = std::fs::read_to_string(saved).unwrap();
    let mut document: serde_json::Value = serde_json::from_str(&text).unwrap();
    for entry in document["registers"].as_array_mut().unwrap() {
        let address = u8::try_from(entry["address"].as_u64().unwrap()).unwrap();
        if let Some((_, value)) = changes.iter().find(|(reg, _)| reg.address() == address) {
            entry["value"] = (*value).into();
        }
    }
    std::fs::write(target, serde_json::to_string_pretty(&document).unwrap()).unwrap();
}

/// The registers whose values differ from `expected`, as `name: expected -> got`.
fn wrong_values(expected: &BTreeMap<u8, u16>, got: &BTreeMap<u8, u16>) -> Vec<String> {
    expected
        .iter()
        .filter(|(address, value)| got.get(address) != Some(value))
        .map(|(address, value)| {
            let name = base_core::registers::info(*address).unwrap().name;
            format!("{name}: {value} -> {:?}", got.get(address))
        })
        .collect()
}

#[test]
fn with_two_other_programs_reading_registers_flat_out_basectl_reads_saves_and_loads_only_its_own_values()
 {
    let simulator = start_simulator();
    let directory = simulator.directory().to_owned();
    let stop = Arc::new(AtomicBool::new(false));
    let reads = Arc::new(AtomicU64::new(0));
    let hammers = [None, Some(0x8000)].map(|tag_base| {
        hammer(
            connect(&simulator),
            tag_base,
            Arc::clone(&stop),
            Arc::clone(&reads),
        )
    });
    let started = Instant::now();

    // A plain reader: `basectl reg get` in a loop over the registers nobody writes.
    let plain = {
        let mut bus = connect(&simulator);
        let expected: Vec<(u8, u16)> = defaults()
            .into_iter()
            .filter(|(address, _)| !LOADED.iter().any(|(reg, _)| reg.address() == *address))
            .collect();
        let stop = Arc::clone(&stop);
        thread::spawn(move || {
            let mut base = Base::new(&mut bus, REPLY_TIMEOUT);
            let mut wrong = Vec::new();
            let mut failed = Vec::new();
            let mut done = 0;
            for &(address, value) in expected.iter().cycle() {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                match base.read_register(address) {
                    Ok(read) if read == value => {}
                    Ok(read) => wrong.push(format!("register {address}: {read}, is {value}")),
                    Err(error) => failed.push(format!("register {address}: {error}")),
                }
                done += 1;
            }
            (done, wrong, failed)
        })
    };

    // `config save` three times, `config load` of a changed file, a save of that,
    // and a load of the first file again.
    let mut bus = connect(&simulator);
    let mut base = Base::new(&mut bus, REPLY_TIMEOUT);
    let mut out = Vec::new();
    let mut problems = Vec::new();
    let first = directory.join("first.json");
    for run in 0..3 {
        match config::save(&mut base, &first, &mut out) {
            Ok(()) => problems.extend(
                wrong_values(&defaults(), &saved_values(&first))
                    .into_iter()
                    .map(|wrong| format!("save {run} saved {wrong}")),
            ),
            Err(error) => problems.push(format!("save {run}: {error}")),
        }
    }
    let changed = directory.join("changed.json");
    let mut loaded = defaults();
    for (reg, value) in LOADED {
        loaded.insert(reg.address(), value);
    }
    let mut loads = Vec::new();
    if first.exists() {
        with_changes(&first, &changed, &LOADED);
        for (file, values) in [(&changed, loaded.clone()), (&first, defaults())] {
            if let Err(error) = config::load(&mut base, file, false, &mut out) {
                problems.push(format!("load {}: {error}", file.display()));
            }
            let check = directory.join("check.json");
            match config::save(&mut base, &check, &mut out) {
                Ok(()) => loads.push((values, saved_values(&check))),
                Err(error) => problems.push(format!("save after load: {error}")),
            }
        }
    }
    // The plain reader goes on for a while after basectl's configuration runs.
    while started.elapsed() < Duration::from_secs(5) {
        thread::sleep(Duration::from_millis(50));
    }
    stop.store(true, Ordering::Relaxed);
    let (plain_reads, plain_wrong, plain_failed) = plain.join().expect("the plain reader");
    for hammer in hammers {
        hammer.join().expect("a hammer");
    }
    let seconds = started.elapsed().as_secs_f64();
    let others_per_second = reads.load(Ordering::Relaxed) as f64 / seconds;
    // The save after each load saved what the load wrote.
    for (written, saved) in &loads {
        problems.extend(
            wrong_values(written, saved)
                .into_iter()
                .map(|wrong| format!("after a load: {wrong}")),
        );
    }

    // The robot holds what the last load wrote: read without anyone else on the bus.
    let mut quiet_bus = connect(&simulator);
    let mut quiet = Base::new(&mut quiet_bus, REPLY_TIMEOUT);
    let now: BTreeMap<u8, u16> = defaults()
        .keys()
        .map(|&address| (address, quiet.read_register(address).unwrap()))
        .collect();
    problems.extend(
        wrong_values(&defaults(), &now)
            .into_iter()
            .map(|wrong| format!("at the end the robot holds {wrong}")),
    );

    eprintln!(
        "other programs: {others_per_second:.0} register reads/s for {seconds:.1} s; plain \
         reader: {plain_reads} reads"
    );
    assert!(
        others_per_second > 200.0,
        "the other programs read only {others_per_second:.0} registers/s"
    );
    assert!(
        plain_wrong.is_empty(),
        "the plain reader got {} wrong values of {plain_reads}: {:?}",
        plain_wrong.len(),
        &plain_wrong[..plain_wrong.len().min(10)]
    );
    assert!(
        plain_failed.is_empty(),
        "{} of {plain_reads} plain reads failed: {:?}",
        plain_failed.len(),
        &plain_failed[..plain_failed.len().min(10)]
    );
    assert!(problems.is_empty(), "{problems:#?}");
    assert!(
        plain_reads > 50,
        "the plain reader read {plain_reads} times"
    );
}
