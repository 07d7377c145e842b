//! `firmware`: the image on the base controller, and updates over CAN. `update` checks
//! the file offline, shows running → new and asks, saves the registers, moves the image
//! in windows the controller acknowledges (one progress line), activates it, waits
//! for the new version to run on trial, checks its health and confirms it. Before
//! activation, Ctrl-C or an error aborts the session; the running firmware is
//! untouched. After activation, an image that does not start, or is not confirmed,
//! is rolled back by the controller itself.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use base_core::can::update::{
    BeginFlags, DATA_BYTES, DataFrame, Phase, Step, UpdateCommand, UpdateError, UpdateReply,
    VersionAssembler,
};
use base_core::can::{Command, RawFrame};
use base_core::can::{ControlSource, Mode};
use base_core::update::image::{self, Chip, ImageInfo};
use base_core::update::partitions::SLOT_LEN;
use base_core::update::session::{
    DIGEST_PARTS, SUB_BLOCK, WINDOW_LEN, is_older, window_count, window_crc, window_len,
};
use base_core::update::signature::{self, PublicKey, Trust};
use serde_json::json;
use sha2::{Digest, Sha256};

use crate::base::{Base, Error};
use crate::bus::{Bus, exit};
use crate::config;
use crate::signing::key_id;

use base_core::update::PROJECT;

/// How long a reply may take: a window is erased, written and read back first.
const REPLY_TIMEOUT: Duration = Duration::from_millis(1000);
/// Attempts at one window before the update gives up.
const WINDOW_ATTEMPTS: u32 = 10;
/// How long the new image may take to start and answer.
const START_TIMEOUT: Duration = Duration::from_secs(30);

/// What an image file is.
#[derive(Debug, Clone)]
pub struct ImageFile {
    pub bytes: Vec<u8>,
    pub chip: Chip,
    pub version: String,
    /// The app descriptor's `secure_version`.
    pub security_version: u32,
    pub signed: Signed,
    pub sha256: [u8; 32],
}

/// Who signed an image file, as far as the file itself tells: whether the controller
/// trusts that key only the controller knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signed {
    No,
    /// Signed, and the signature matches the image and flags.
    By {
        key: PublicKey,
        downgrade: bool,
    },
    /// A signature block whose signature does not match: changed after signing.
    Broken,
}

impl Signed {
    fn of(bytes: &[u8]) -> Self {
        let mut whole = image::WholeImageCheck::new();
        whole.feed(bytes);
        let (Some(digest), Some(block)) = (whole.digest(), signature::block_after(&whole)) else {
            return Self::No;
        };
        match signature::check(Trust::Keys(&[block.key]), Some(&block), digest, 0, 0) {
            Ok(_) => Self::By {
                key: block.key,
                downgrade: block.allows_downgrade(),
            },
            Err(_) => Self::Broken,
        }
    }

    fn describe(&self) -> String {
        match self {
            Self::No => "unsigned".into(),
            Self::By { key, downgrade } => format!(
                "signed with key {}{}",
                key_id(key),
                if *downgrade {
                    ", allowed below the running security version"
                } else {
                    ""
                }
            ),
            Self::Broken => "signature BROKEN (changed after signing)".into(),
        }
    }
}

/// The offline check: an app image of this project, for a chip we build for, that
/// passes the bootloader's checks and fits a slot.
pub fn check_file(path: &Path) -> Result<ImageFile, Error> {
    let bytes = std::fs::read(path)
        .map_err(|error| Error::InvalidInput(format!("cannot read {}: {error}", path.display())))?;
    let refuse = |why: String| Error::InvalidInput(format!("{}: {why}", path.display()));
    if bytes.len() < image::PREFIX_LEN {
        return Err(refuse("too short for an app image".into()));
    }
    let chip_id = u16::from_le_bytes([bytes[12], bytes[13]]);
    let chip = Chip::from_id(chip_id)
        .ok_or_else(|| refuse(format!("built for an unknown chip (id {chip_id})")))?;
    let info = ImageInfo::parse(&bytes, chip, PROJECT)
        .map_err(|error| refuse(format!("not this firmware's image: {error:?}")))?;
    image::verify_whole(&bytes, SLOT_LEN as usize)
        .map_err(|error| refuse(format!("fails the bootloader's checks: {error:?}")))?;
    Ok(ImageFile {
        chip,
        version: info.version.as_str().to_owned(),
        security_version: info.security_version,
        signed: Signed::of(&bytes),
        sha256: Sha256::digest(&bytes).into(),
        bytes,
    })
}

/// The controller's answer to QUERY.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Running {
    pub phase: Phase,
    pub session: u8,
    pub slot: u8,
    pub version: String,
    /// Only signed images activate (a controller before signed images: false).
    pub signatures_required: bool,
    pub security_version: u8,
}

impl Running {
    /// What `info` says about updates: loud for a development build.
    pub fn trust_text(&self) -> String {
        if self.signatures_required {
            format!(
                "signed images only (security version {})",
                self.security_version
            )
        } else {
            "DEVELOPMENT BUILD: updates over CAN accept unsigned images".into()
        }
    }
}

fn receive_reply(bus: &mut dyn Bus, deadline: Instant) -> Result<Option<UpdateReply>, Error> {
    loop {
        let remaining = deadline.saturating_duration_since(Instant::now());
        let Some(frame) = bus.receive(remaining)? else {
            return Ok(None);
        };
        if let Ok(Some(reply)) = UpdateReply::decode(frame.id(), frame.data()) {
            return Ok(Some(reply));
        }
    }
}

/// Asks the controller what runs and where the update stands.
pub fn query(bus: &mut dyn Bus, timeout: Duration) -> Result<Running, Error> {
    bus.send(&UpdateCommand::Query.encode())?;
    let deadline = Instant::now() + timeout;
    let mut state = None;
    let mut version = VersionAssembler::default();
    loop {
        match receive_reply(bus, deadline)? {
            None => {
                return Err(Error::NoReply {
                    awaited: "the update state (0x2EA)".into(),
                    timeout_ms: timeout.as_millis(),
                });
            }
            Some(UpdateReply::State {
                phase,
                session,
                running_slot,
                signatures_required,
                security_version,
                ..
            }) => {
                state = Some((
                    phase,
                    session,
                    running_slot,
                    signatures_required,
                    security_version,
                ));
                version.restart();
            }
            Some(UpdateReply::Version { part, text }) => {
                if let (
                    Some((phase, session, slot, signatures_required, security_version)),
                    Some(whole),
                ) = (state, version.add(part, &text))
                {
                    return Ok(Running {
                        phase,
                        session,
                        slot,
                        version: String::from_utf8_lossy(whole).into_owned(),
                        signatures_required,
                        security_version,
                    });
                }
            }
            Some(_) => {}
        }
    }
}

fn refused(step: &str, error: UpdateError, detail: u8) -> Error {
    let detail = match error {
        UpdateError::BadImage => format!(" (image check {detail})"),
        UpdateError::Untrusted => match detail {
            1 => " (the image is not signed: `basectl firmware sign`)".into(),
            2 => " (signed with a key this controller does not trust)".into(),
            _ => " (the signature does not match the image: changed after signing)".into(),
        },
        UpdateError::NotTrialOwner => " (another update session activated the image on trial: \
             only it may keep or reject it; give its id with `--session`, as that update \
             printed it, or let the trial end by itself after 120 s)"
            .into(),
        UpdateError::SecurityDowngrade => format!(
            " (below the running security version {detail}: the owner signs a downgrade with \
             `basectl firmware sign --allow-security-downgrade`)"
        ),
        _ => String::new(),
    };
    Error::Aborted(format!(
        "the base controller refused {step}: {}{detail}",
        error.name()
    ))
}

/// Sends `command` and waits for its DONE `step` (or a refusal).
fn expect_done(
    bus: &mut dyn Bus,
    command: UpdateCommand,
    step: Step,
    timeout: Duration,
) -> Result<(), Error> {
    bus.send(&command.encode())?;
    let deadline = Instant::now() + timeout;
    loop {
        match receive_reply(bus, deadline)? {
            None => {
                return Err(Error::NoReply {
                    awaited: format!("{step:?} (0x2EA)"),
                    timeout_ms: timeout.as_millis(),
                });
            }
            Some(UpdateReply::Done { step: done, .. }) if done == step => return Ok(()),
            Some(UpdateReply::Refused {
                opcode,
                error,
                detail,
                session,
            }) if opcode == command.opcode() && answers(session, command.session()) => {
                return Err(refused(&format!("{step:?}"), error, detail));
            }
            Some(_) => {}
        }
    }
}

/// How the transfer went.
#[derive(Debug, Clone, Copy, Default)]
pub struct TransferStats {
    pub seconds: f64,
    pub retries: u32,
    pub frames: u64,
}

/// DIGEST 0–7: the SHA-256 of the whole file, announced for `session`.
pub fn send_digest(bus: &mut dyn Bus, session: u8, sha256: &[u8; 32]) -> Result<(), Error> {
    let (parts, _) = sha256.as_chunks::<4>();
    for (part, &bytes) in (0..DIGEST_PARTS).zip(parts) {
        bus.send(
            &UpdateCommand::Digest {
                session,
                part,
                bytes,
            }
            .encode(),
        )?;
    }
    Ok(())
}

/// Moves `image` window by window. `progress` gets (bytes written, retries).
pub fn transfer(
    bus: &mut dyn Bus,
    session: u8,
    image: &[u8],
    mut progress: impl FnMut(usize, u32, Duration),
) -> Result<TransferStats, Error> {
    let started = Instant::now();
    let size = image.len() as u32;
    let mut stats = TransferStats::default();
    for index in 0..window_count(size) {
        let start = usize::from(index) * WINDOW_LEN;
        let bytes = &image[start..start + window_len(size, index)];
        let crc = window_crc(bytes);
        let frames: Vec<RawFrame> = bytes
            .chunks(DATA_BYTES)
            .enumerate()
            .map(|(i, chunk)| {
                let mut data = [0u8; DATA_BYTES];
                data[..chunk.len()].copy_from_slice(chunk);
                DataFrame {
                    seq: i as u8,
                    bytes: data,
                }
                .encode()
            })
            .collect();
        let mut attempts = 0;
        'window: loop {
            attempts += 1;
            if attempts > WINDOW_ATTEMPTS {
                return Err(Error::Aborted(format!(
                    "window {index} failed {WINDOW_ATTEMPTS} times"
                )));
            }
            if attempts > 1 {
                stats.retries += 1;
            }
            bus.send(
                &UpdateCommand::Window {
                    session,
                    index,
                    crc,
                }
                .encode(),
            )?;
            // Frames of this attempt sent so far: a READY lets the sender go on up to
            // SUB_BLOCK frames past the frame it names, without sending any twice,
            // except after an OutOfOrder, where the READY that follows says where to
            // go back to.
            let mut sent = 0;
            let mut go_back = false;
            loop {
                let deadline = Instant::now() + REPLY_TIMEOUT;
                let reply = match receive_reply(bus, deadline)? {
                    // Lost on the way: ask for the window again.
                    None => continue 'window,
                    Some(reply) => reply,
                };
                match reply {
                    // Another session's replies (another program, or stale ones) are not ours.
                    UpdateReply::Ready {
                        session: owner,
                        window,
                        next,
                    } if owner == session && window == index => {
                        let next = usize::from(next);
                        if go_back {
                            sent = next;
                            go_back = false;
                        }
                        let end = (next + usize::from(SUB_BLOCK)).min(frames.len());
                        for frame in &frames[sent.max(next).min(end)..end] {
                            bus.send(frame)?;
                            stats.frames += 1;
                        }
                        sent = sent.max(end);
                    }
                    UpdateReply::Written {
                        session: owner,
                        window,
                    } if owner == session && window == index => break 'window,
                    // Another program's refusals (its BEGIN refused Busy) are not ours.
                    UpdateReply::Refused { session: owner, .. } if !answers(owner, session) => {}
                    UpdateReply::Refused {
                        error: UpdateError::BadCrc | UpdateError::WrongWindow,
                        ..
                    } => continue 'window,
                    UpdateReply::Refused {
                        error: UpdateError::OutOfOrder,
                        ..
                    } => go_back = true,
                    UpdateReply::Refused {
                        error: UpdateError::Duplicate,
                        ..
                    } => {}
                    UpdateReply::Refused { error, detail, .. } => {
                        return Err(refused("the image", error, detail));
                    }
                    _ => {}
                }
            }
        }
        progress(start + bytes.len(), stats.retries, started.elapsed());
    }
    stats.seconds = started.elapsed().as_secs_f64();
    Ok(stats)
}

/// Whether a refusal naming `refused` answers a command of `session`: it names that
/// session, or none (a controller from before refusals named the session sends none).
fn answers(refused: u8, session: u8) -> bool {
    refused == session || refused == 0
}

/// A session id for this run: different for each program and run.
fn session_id() -> u8 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |time| time.subsec_nanos());
    let mixed = nanos ^ std::process::id().wrapping_mul(2_654_435_761);
    (mixed % 255) as u8 + 1
}

/// `firmware update`'s options.
#[derive(Debug, Clone)]
pub struct UpdatePlan {
    pub file: PathBuf,
    pub yes: bool,
    pub force: bool,
    pub allow_downgrade: bool,
    /// Where the registers are saved first (default: beside the image).
    pub registers_file: Option<PathBuf>,
    pub json: bool,
}

/// Waits for the new image to answer QUERY on trial; `Ok(None)` when the old one
/// answers instead (the new one did not start and was rolled back).
fn wait_for_trial(bus: &mut dyn Bus, new: &str, old: &str) -> Result<Option<Running>, Error> {
    let deadline = Instant::now() + START_TIMEOUT;
    while Instant::now() < deadline {
        if let Ok(running) = query(bus, Duration::from_millis(500)) {
            if running.version == new && running.phase == Phase::OnTrial {
                return Ok(Some(running));
            }
            if running.version == old && running.phase == Phase::Idle {
                // The reset may still be ahead: only a second answer counts.
                std::thread::sleep(Duration::from_millis(1500));
                if let Ok(again) = query(bus, Duration::from_millis(500))
                    && again.version == old
                    && again.phase == Phase::Idle
                {
                    return Ok(None);
                }
            }
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    Err(Error::NoReply {
        awaited: format!("firmware {new} on trial"),
        timeout_ms: START_TIMEOUT.as_millis(),
    })
}

/// The new image's health: it reports status in Standby, no drive is silent or in
/// alarm, and the flash is fine (unless it was not before the update either: a
/// blank register store is no fault of the new image).
fn health_check(
    bus: &mut dyn Bus,
    reply_timeout: Duration,
    flash_fault_before: bool,
) -> Result<(), String> {
    let mut base = Base::new(bus, reply_timeout);
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut last = String::from("no status frame");
    while Instant::now() < deadline {
        let status = base.next_status().map_err(|error| error.to_string())?;
        let faults = status.faults;
        let drive_fault = faults.left_drive_silent
            || faults.left_drive_alarm
            || faults.right_drive_silent
            || faults.right_drive_alarm;
        if status.mode == Mode::Standby && !drive_fault && (!faults.flash || flash_fault_before) {
            return Ok(());
        }
        last = format!("mode {:?}, faults {faults:?}", status.mode);
    }
    Err(last)
}

/// Why a controller that requires signatures will refuse `file` at FINISH, known
/// before a byte is sent; `None` when it may pass (only the controller knows its keys).
fn untrusted_here(file: &ImageFile, running: &Running) -> Option<String> {
    if !running.signatures_required {
        return None;
    }
    match file.signed {
        Signed::No => Some(
            "it takes only signed images: sign it with `basectl firmware sign --key KEY IN OUT`"
                .into(),
        ),
        Signed::Broken => {
            Some("its signature does not match the image: it was changed after signing".into())
        }
        Signed::By { downgrade, .. } => {
            let floor = u32::from(running.security_version);
            (file.security_version < floor && !downgrade).then(|| {
                format!(
                    "its security version {} is below the running {}: only an image the owner \
                     signed with --allow-security-downgrade goes below",
                    file.security_version, running.security_version
                )
            })
        }
    }
}

pub fn update(
    bus: &mut dyn Bus,
    plan: &UpdatePlan,
    reply_timeout: Duration,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let file = check_file(&plan.file)?;
    let running = query(bus, reply_timeout * 2)?;
    match running.phase {
        Phase::Idle => {}
        Phase::OnTrial => {
            return Err(Error::Aborted(format!(
                "firmware {} runs on trial: `basectl firmware confirm` or `rollback` first",
                running.version
            )));
        }
        _ => {
            return Err(Error::Aborted(
                "another update session runs (`basectl firmware abort` ends it)".into(),
            ));
        }
    }
    if let Some(why) = untrusted_here(&file, &running) {
        return Err(Error::InvalidInput(format!(
            "{}: the controller would refuse it: {why}",
            plan.file.display()
        )));
    }
    if is_older(&file.version, &running.version) && !plan.allow_downgrade {
        return Err(Error::InvalidInput(format!(
            "{} is older than the running {}: --allow-downgrade",
            file.version, running.version
        )));
    }
    if file.version == running.version && !plan.force {
        return Err(Error::InvalidInput(format!(
            "{} runs already: --force to write it again",
            file.version
        )));
    }
    if !plan.json {
        writeln!(
            out,
            "firmware {} (slot {}) -> {} ({}, {} KiB, {})",
            running.version,
            running.slot,
            file.version,
            file.chip.name(),
            file.bytes.len() / 1024,
            file.signed.describe()
        )?;
        if !running.signatures_required {
            writeln!(out, "warning: {}", running.trust_text())?;
        }
    }
    if !plan.yes && !ask_yes("update now? [y/N] ")? {
        return Err(Error::Aborted("not updated".into()));
    }
    let flash_fault_before = {
        // A driving base is left alone: no withdrawn enable, no session.
        let mut base = Base::new(bus, reply_timeout);
        let status = base.next_status()?;
        if status.mode == Mode::Active || status.control != ControlSource::None {
            return Err(Error::Aborted(format!(
                "the base is driving (mode {:?}, control {:?}): stop it, then update",
                status.mode, status.control
            )));
        }
        status.faults.flash
    };
    let registers_file = plan.registers_file.clone().unwrap_or_else(|| {
        plan.file
            .with_file_name(format!("registers-before-{}.json", file.version))
    });
    {
        let mut base = Base::new(bus, reply_timeout);
        let mut sink = Vec::new();
        config::save(&mut base, &registers_file, &mut sink)?;
        // Nobody drives through us while the update runs.
        base.send(Command::Enable { refresh: false })?;
    }
    if !plan.json {
        writeln!(out, "registers saved to {}", registers_file.display())?;
    }

    let session = session_id();
    let flags = BeginFlags {
        force: plan.force,
        allow_downgrade: plan.allow_downgrade,
    };
    expect_done(
        bus,
        UpdateCommand::Begin {
            session,
            size: file.bytes.len() as u32,
            flags,
        },
        Step::Begun,
        reply_timeout * 2,
    )?;
    // From here until activation, any way out ends the session.
    let mut abort_on_exit = abort_registration(session);
    send_digest(bus, session, &file.sha256)?;
    let total = file.bytes.len();
    let show_progress = !plan.json;
    let result = transfer(bus, session, &file.bytes, |done, retries, elapsed| {
        if show_progress {
            let rate = done as f64 / 1024.0 / elapsed.as_secs_f64().max(1e-3);
            let eta = (total - done) as f64 / 1024.0 / rate.max(1e-3);
            eprint!(
                "\r{:>5} / {} KiB  {:>5.1} KiB/s  ETA {:>3.0} s  retries {retries}   ",
                done / 1024,
                total / 1024,
                rate,
                eta
            );
        }
    });
    if show_progress {
        eprintln!();
    }
    let stats = match result {
        Ok(stats) => stats,
        Err(error) => {
            let _ = bus.send(&UpdateCommand::Abort { session }.encode());
            return Err(error);
        }
    };
    let finished = expect_done(
        bus,
        UpdateCommand::Finish { session },
        Step::Finished,
        reply_timeout * 2,
    );
    if let Err(error) = finished {
        let _ = bus.send(&UpdateCommand::Abort { session }.encode());
        return Err(error);
    }
    expect_done(
        bus,
        UpdateCommand::Activate { session },
        Step::Activated,
        reply_timeout * 4,
    )?;
    // Activated: the controller resets; an abort has nothing left to end.
    abort_on_exit.disarm();
    if !plan.json {
        writeln!(
            out,
            "written in {:.1} s ({:.1} KiB/s, {} retries); activated by session {session}, \
             waiting for {} to start",
            stats.seconds,
            total as f64 / 1024.0 / stats.seconds.max(1e-3),
            stats.retries,
            file.version
        )?;
        // Should this program end before it decides, the session is what lets a person
        // decide instead of waiting for the trial's deadline.
        writeln!(
            out,
            "(if this program ends first: `basectl firmware confirm --session {session}` \
             keeps it, `rollback --session {session}` rejects it)"
        )?;
    }
    let report = |out: &mut dyn Write, outcome: &str, version: &str| -> Result<(), Error> {
        if plan.json {
            let object = json!({
                "from": running.version,
                "to": file.version,
                "outcome": outcome,
                "running": version,
                "seconds": stats.seconds,
                "kib_per_s": total as f64 / 1024.0 / stats.seconds.max(1e-3),
                "retries": stats.retries,
                "session": session,
                "registers_saved_to": registers_file.display().to_string(),
            });
            writeln!(out, "{object}")?;
        } else {
            writeln!(out, "{outcome}: firmware {version} runs")?;
        }
        Ok(())
    };
    let trial = wait_for_trial(bus, &file.version, &running.version)
        .map_err(|error| still_on_trial(error, session))?;
    if trial.is_none() {
        report(out, "rolled back", &running.version)?;
        return Err(Error::Aborted(format!(
            "firmware {} did not start; the controller went back to {}",
            file.version, running.version
        )));
    }
    if let Err(why) = health_check(bus, reply_timeout, flash_fault_before) {
        let _ = bus.send(&UpdateCommand::Rollback { session }.encode());
        return Err(Error::Aborted(format!(
            "firmware {} failed its health check ({why}); rolled back",
            file.version
        )));
    }
    expect_done(
        bus,
        UpdateCommand::Confirm { session },
        Step::Confirmed,
        reply_timeout * 4,
    )
    .map_err(|error| still_on_trial(error, session))?;
    report(out, "confirmed", &file.version)
}

/// An error after the activation, before the confirm: the image may be on trial, and
/// only this program's session may decide about it; the error says how a person does.
fn still_on_trial(error: Error, session: u8) -> Error {
    Error::Aborted(format!(
        "{error}; the new image may still be on trial: `basectl firmware confirm --session \
         {session}` keeps it, `basectl firmware rollback --session {session}` rejects it, \
         and nobody's decision within 120 s rejects it"
    ))
}

/// On Ctrl-C or SIGTERM before activation: an ABORT through a second connection when
/// the bus allows one (socketcand); otherwise the session ends after 10 s of silence.
struct AbortOnExit {
    armed: Arc<AtomicBool>,
    _registration: Option<exit::Registration>,
}

impl AbortOnExit {
    /// After activation there is no session left to end.
    fn disarm(&mut self) {
        self.armed.store(false, Ordering::SeqCst);
    }
}

fn abort_registration(session: u8) -> AbortOnExit {
    let armed = Arc::new(AtomicBool::new(true));
    let target = ABORT_TARGET.lock().ok().and_then(|target| target.clone());
    let still_armed = armed.clone();
    let registration = target.map(|(interface, channel, bitrate)| {
        exit::register(Box::new(move || {
            if !still_armed.load(Ordering::SeqCst) {
                return;
            }
            if let Ok(mut bus) = crate::bus::open(interface, &channel, bitrate) {
                let _ = bus.send(&UpdateCommand::Abort { session }.encode());
            }
        }))
    });
    AbortOnExit {
        armed,
        _registration: registration,
    }
}

/// Asks a yes/no question on the terminal.
fn ask_yes(question: &str) -> Result<bool, Error> {
    use std::io::BufRead;
    eprint!("{question}");
    std::io::stderr().flush()?;
    let mut answer = String::new();
    std::io::stdin().lock().read_line(&mut answer)?;
    Ok(matches!(answer.trim(), "y" | "Y" | "yes"))
}

/// The bus a Ctrl-C abort is sent through: set by the command line.
pub static ABORT_TARGET: std::sync::Mutex<Option<(crate::bus::Interface, String, u32)>> =
    std::sync::Mutex::new(None);

pub fn info(
    bus: &mut dyn Bus,
    timeout: Duration,
    json_output: bool,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let running = query(bus, timeout * 2)?;
    if json_output {
        writeln!(
            out,
            "{}",
            json!({
                "version": running.version,
                "slot": running.slot,
                "phase": format!("{:?}", running.phase),
                "on_trial": running.phase == Phase::OnTrial,
                "signatures_required": running.signatures_required,
                "security_version": running.security_version,
            })
        )?;
    } else {
        writeln!(out, "firmware   {}", running.version)?;
        writeln!(out, "slot       ota_{}", running.slot)?;
        writeln!(out, "update     {:?}", running.phase)?;
        writeln!(out, "updates    {}", running.trust_text())?;
    }
    Ok(())
}

pub fn check(path: &Path, json_output: bool, out: &mut dyn Write) -> Result<(), Error> {
    let file = check_file(path)?;
    let digest: String = file.sha256.iter().map(|b| format!("{b:02x}")).collect();
    if json_output {
        writeln!(
            out,
            "{}",
            json!({
                "version": file.version,
                "chip": file.chip.name(),
                "bytes": file.bytes.len(),
                "sha256": digest,
                "security_version": file.security_version,
                "signed_by": match file.signed {
                    Signed::By { key, .. } => Some(key.iter().map(|b| format!("{b:02x}")).collect::<String>()),
                    _ => None,
                },
                "signature_broken": file.signed == Signed::Broken,
                "ok": file.signed != Signed::Broken,
            })
        )?;
    } else {
        writeln!(
            out,
            "{}: firmware {} for {}, security version {}, {} bytes, sha256 {digest}, {}: {}",
            path.display(),
            file.version,
            file.chip.name(),
            file.security_version,
            file.bytes.len(),
            file.signed.describe(),
            if file.signed == Signed::Broken {
                "REFUSED"
            } else {
                "ok"
            }
        )?;
    }
    if file.signed == Signed::Broken {
        return Err(Error::InvalidInput(format!(
            "{}: the signature does not match the image",
            path.display()
        )));
    }
    Ok(())
}

/// Keeps the image on trial. `session`: the update session that activated it, which
/// alone may decide (`None` for a trial whose session the controller does not know).
pub fn confirm(
    bus: &mut dyn Bus,
    session: Option<u8>,
    timeout: Duration,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let session = session.unwrap_or(0);
    expect_done(
        bus,
        UpdateCommand::Confirm { session },
        Step::Confirmed,
        timeout * 4,
    )?;
    writeln!(out, "confirmed")?;
    Ok(())
}

/// Rejects the image on trial; `session` as for [`confirm`].
pub fn rollback(
    bus: &mut dyn Bus,
    session: Option<u8>,
    timeout: Duration,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let session = session.unwrap_or(0);
    expect_done(
        bus,
        UpdateCommand::Rollback { session },
        Step::RolledBack,
        timeout * 4,
    )?;
    writeln!(
        out,
        "rolled back: the controller restarts the previous firmware"
    )?;
    Ok(())
}

pub fn abort(bus: &mut dyn Bus, timeout: Duration, out: &mut dyn Write) -> Result<(), Error> {
    let running = query(bus, timeout * 2)?;
    if matches!(running.phase, Phase::Idle | Phase::OnTrial) {
        writeln!(out, "no update session runs")?;
        return Ok(());
    }
    expect_done(
        bus,
        UpdateCommand::Abort {
            session: running.session,
        },
        Step::Aborted,
        timeout * 2,
    )?;
    writeln!(out, "aborted")?;
    Ok(())
}
