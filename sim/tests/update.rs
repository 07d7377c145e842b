//! Firmware updates end to end: basectl's `firmware` functions against the simulator
//! binary over socketcand, on the wall clock. The simulator boots every image through
//! the bootloader model from its app flash file; the images are synthetic, and their
//! version chooses what the virtual firmware does (`virtual_robot::app_flash`).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use base_core::can::update::{BeginFlags, Phase, UpdateCommand, UpdateError, UpdateReply};
use base_core::can::{Command, ControlSource, Mode, RawFrame, Report};
use base_core::registers::{Access, BootInfo, Reg, TABLE, UpdateReset};
use base_core::update::PROJECT;
use base_core::update::image::Chip;
use base_core::update::partitions;
use base_core::update::signature;
use basectl::base::{Base, Error};
use basectl::bus::{Bus, BusError, SocketcandBus};
use basectl::firmware::{self, UpdatePlan};
use basectl::signing;
use sha2::{Digest, Sha256};
use virtual_robot::app_flash::{self, FACTORY_VERSION, secured_image, sim_image};
use virtual_robot::process::SimulatorProcess;

const TIMEOUT: Duration = Duration::from_millis(500);
/// Images of about 100 KiB keep each scenario short; the figures use 600 KB.
const TEST_PAYLOAD: usize = 100 * 1024;

fn start() -> SimulatorProcess {
    let simulator = SimulatorProcess::start(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .expect("the simulator starts");
    simulator
        .wait_for_line("boot: firmware", Duration::from_secs(10))
        .expect("the factory image boots");
    simulator
}

fn connect(simulator: &SimulatorProcess) -> SocketcandBus {
    SocketcandBus::open(&simulator.socketcand().to_string()).expect("socketcand connects")
}

fn image_file(simulator: &SimulatorProcess, version: &str) -> PathBuf {
    let path = simulator.directory().join(format!("{version}.bin"));
    std::fs::write(&path, sim_image(version, TEST_PAYLOAD)).unwrap();
    path
}

fn plan(file: PathBuf) -> UpdatePlan {
    UpdatePlan {
        registers_file: Some(file.with_extension("registers.json")),
        file,
        yes: true,
        force: false,
        allow_downgrade: false,
        json: true,
    }
}

/// Waits until the base stands in Standby (drives set up after a boot).
fn standby(bus: &mut dyn Bus) {
    let mut base = Base::new(bus, TIMEOUT);
    let deadline = Instant::now() + Duration::from_secs(15);
    let mut last = None;
    while Instant::now() < deadline {
        match base.next_status() {
            Ok(status) if status.mode == Mode::Standby => return,
            other => last = Some(format!("{other:?}")),
        }
    }
    panic!("the base did not reach Standby: {last:?}");
}

/// `boot_info`'s update reset and the status frame's watchdog_reset bit, once the base
/// stands after its boot.
fn boot_cause(bus: &mut dyn Bus) -> (UpdateReset, bool) {
    standby(bus);
    let mut base = Base::new(bus, TIMEOUT);
    let bits = base.read_register(Reg::BootInfo.address()).unwrap();
    let status = base.next_status().unwrap();
    let info = BootInfo::from_bits(bits).expect("bits the firmware sets");
    (info.update_reset, status.faults.watchdog_reset)
}

fn app_flash_bytes(simulator: &SimulatorProcess) -> Vec<u8> {
    let path = virtual_robot::simulator::app_flash_path(&simulator.directory().join("flash.bin"));
    std::fs::read(path).unwrap()
}

fn region(bytes: &[u8], partition: partitions::Partition) -> &[u8] {
    &bytes[partition.offset as usize..partition.end() as usize]
}

#[test]
fn a_healthy_update_runs_the_new_version_and_is_confirmed() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let file = image_file(&simulator, "0.2.0");
    let mut out = Vec::new();
    firmware::update(&mut bus, &plan(file.clone()), TIMEOUT, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    let report: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    assert_eq!(report["outcome"], "confirmed", "{text}");
    assert_eq!(report["to"], "0.2.0");
    assert!(file.with_extension("registers.json").exists());
    simulator
        .wait_for_line(
            "boot: firmware 0.2.0 from Ota1, on trial",
            Duration::from_secs(1),
        )
        .expect("the new image booted on trial");
    let running = firmware::query(&mut bus, TIMEOUT).unwrap();
    assert_eq!(
        (running.version.as_str(), running.phase, running.slot),
        ("0.2.0", Phase::Idle, 1)
    );
    assert_eq!(
        boot_cause(&mut bus),
        (UpdateReset::Activation, false),
        "the activation's reset is reported as such, not as a watchdog reset"
    );
    // Confirmed: a reset boots it again, not the factory image.
    let mut simulator = simulator;
    simulator.console("reboot").unwrap();
    simulator
        .wait_for_line("boot: firmware 0.2.0 from Ota1", Duration::from_secs(10))
        .expect("the confirmed image boots again");
    assert_eq!(boot_cause(&mut bus), (UpdateReset::None, false));
}

#[test]
fn an_image_that_panics_at_boot_is_rolled_back_and_reported() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let file = image_file(&simulator, "0.2.0-sim-panic");
    let mut out = Vec::new();
    let error = firmware::update(&mut bus, &plan(file), TIMEOUT, &mut out).unwrap_err();
    assert!(error.to_string().contains("did not start"), "{error}");
    let text = String::from_utf8(out).unwrap();
    assert!(text.contains("\"outcome\":\"rolled back\""), "{text}");
    let running = firmware::query(&mut bus, TIMEOUT).unwrap();
    assert_eq!(
        (running.version.as_str(), running.phase, running.slot),
        (FACTORY_VERSION, Phase::Idle, 0)
    );
    assert_eq!(
        boot_cause(&mut bus),
        (UpdateReset::FailedTrial, false),
        "the trial's panic is reported as a failed trial, not as a watchdog reset"
    );
}

/// Also: only the session that activated the image may send it back. Another program
/// (a second basectl without `--session`) is refused and the image stays on trial; the
/// session the failed update named in its error decides.
#[test]
fn a_rollback_the_pc_asks_for_is_reported_as_a_failed_trial() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    // Deaf to CONFIRM: basectl's confirm goes unanswered and the image stays on trial.
    let file = image_file(&simulator, "0.2.0-sim-noconfirm");
    let mut out = Vec::new();
    let error = firmware::update(&mut bus, &plan(file), TIMEOUT, &mut out).unwrap_err();
    let error = error.to_string();
    let session: u8 = error
        .split("rollback --session ")
        .nth(1)
        .map(|rest| {
            rest.chars()
                .take_while(char::is_ascii_digit)
                .collect::<String>()
        })
        .and_then(|number| number.parse().ok())
        .unwrap_or_else(|| panic!("the error names the session: {error}"));
    assert_eq!(
        boot_cause(&mut bus),
        (UpdateReset::Activation, false),
        "on trial after the activation's reset"
    );
    let stranger = firmware::rollback(&mut bus, None, TIMEOUT, &mut Vec::new()).unwrap_err();
    assert!(stranger.to_string().contains("NotTrialOwner"), "{stranger}");
    let other_session = session.wrapping_add(1).max(1);
    let stranger = firmware::rollback(&mut bus, Some(other_session), TIMEOUT, &mut Vec::new());
    assert!(stranger.is_err(), "another session's rollback is refused");
    let running = firmware::query(&mut bus, TIMEOUT).unwrap();
    assert_eq!(
        (running.version.as_str(), running.phase),
        ("0.2.0-sim-noconfirm", Phase::OnTrial),
        "still on trial after the strangers' rollbacks"
    );
    firmware::rollback(&mut bus, Some(session), TIMEOUT, &mut Vec::new()).unwrap();
    simulator
        .wait_for_line(
            &format!("boot: firmware {FACTORY_VERSION} from Ota0"),
            Duration::from_secs(10),
        )
        .expect("the previous image boots");
    assert_eq!(
        boot_cause(&mut bus),
        (UpdateReset::FailedTrial, false),
        "the rejection's reset is reported as a failed trial, not as a watchdog reset"
    );
}

#[test]
fn a_reset_in_the_middle_of_the_transfer_keeps_the_old_version_and_the_rerun_succeeds() {
    let mut simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let file = image_file(&simulator, "0.2.0");
    let address = simulator.socketcand().to_string();
    let update_plan = plan(file);
    let first = std::thread::spawn({
        let update_plan = update_plan.clone();
        move || {
            let mut bus = SocketcandBus::open(&address).unwrap();
            firmware::update(&mut bus, &update_plan, TIMEOUT, &mut Vec::new())
        }
    });
    // Well into the transfer: a few windows are written.
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let running = firmware::query(&mut bus, TIMEOUT).unwrap();
        if running.phase != Phase::Idle {
            break;
        }
        assert!(Instant::now() < deadline, "the transfer did not start");
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_millis(500));
    simulator.console("reboot").unwrap();
    assert!(
        first.join().unwrap().is_err(),
        "the interrupted update reports failure"
    );
    // A fresh connection: the server drops a client that stops reading while the
    // image streams past (this one slept).
    drop(bus);
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let running = firmware::query(&mut bus, TIMEOUT).unwrap();
    assert_eq!(
        (running.version.as_str(), running.phase),
        (FACTORY_VERSION, Phase::Idle)
    );
    firmware::update(&mut bus, &update_plan, TIMEOUT, &mut Vec::new()).unwrap();
    assert_eq!(firmware::query(&mut bus, TIMEOUT).unwrap().version, "0.2.0");
}

/// Sends enable and a forward velocity every 40 ms from its own connection, as a
/// robot PC does, until dropped.
struct Driver {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Driver {
    fn start(address: String) -> Self {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut bus = SocketcandBus::open(&address).unwrap();
            while !stopping.load(std::sync::atomic::Ordering::SeqCst) {
                bus.send(&Command::Enable { refresh: true }.encode())
                    .unwrap();
                bus.send(
                    &Command::Velocity {
                        linear_mm_s: 200,
                        rotation_mrad_s: 0,
                    }
                    .encode(),
                )
                .unwrap();
                std::thread::sleep(Duration::from_millis(40));
            }
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn receive_reply(bus: &mut dyn Bus, within: Duration) -> Option<UpdateReply> {
    let deadline = Instant::now() + within;
    while let Some(frame) = bus
        .receive(deadline.saturating_duration_since(Instant::now()))
        .unwrap()
    {
        if let Ok(Some(reply)) = UpdateReply::decode(frame.id(), frame.data()) {
            return Some(reply);
        }
    }
    None
}

fn x_mm(base: &mut Base) -> i32 {
    loop {
        if let Some(Report::Position { x_mm, .. }) = base.next_report(TIMEOUT).unwrap() {
            return x_mm;
        }
    }
}

#[test]
fn an_update_while_driving_is_refused_and_the_base_keeps_driving() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let driver = Driver::start(simulator.socketcand().to_string());
    std::thread::sleep(Duration::from_secs(2));
    // basectl refuses before it sends anything.
    let file = image_file(&simulator, "0.2.0");
    let error = firmware::update(&mut bus, &plan(file), TIMEOUT, &mut Vec::new()).unwrap_err();
    assert!(error.to_string().contains("driving"), "{error}");
    // A program that sends BEGIN anyway is refused by the controller.
    bus.send(
        &UpdateCommand::Begin {
            session: 9,
            size: 200_000,
            flags: BeginFlags::default(),
        }
        .encode(),
    )
    .unwrap();
    let reply = receive_reply(&mut bus, Duration::from_secs(1));
    assert!(
        matches!(
            reply,
            Some(UpdateReply::Refused {
                error: UpdateError::NotAtRest | UpdateError::ControlActive,
                ..
            })
        ),
        "{reply:?}"
    );
    let mut base = Base::new(&mut bus, TIMEOUT);
    let before = x_mm(&mut base);
    std::thread::sleep(Duration::from_secs(1));
    let status = base.next_status().unwrap();
    let after = x_mm(&mut base);
    assert_eq!(
        (status.mode, status.control),
        (Mode::Active, ControlSource::Can)
    );
    assert!(
        after - before > 100,
        "the base kept driving: {before} -> {after} mm"
    );
    drop(driver);
}

/// A bus that flips one bit in one data frame on the way out, once.
/// Damages one data frame on its way: flips a bit in it, or loses it.
struct CorruptOnce<B> {
    bus: B,
    sent_data_frames: u32,
    corrupt_at: u32,
    lose: bool,
}

impl<B: Bus> Bus for CorruptOnce<B> {
    fn send(&mut self, frame: &RawFrame) -> Result<(), BusError> {
        if frame.id() == base_core::can::id::UPDATE_DATA {
            self.sent_data_frames += 1;
            if self.sent_data_frames == self.corrupt_at {
                if self.lose {
                    return Ok(());
                }
                let mut data = frame.data().to_vec();
                data[3] ^= 0x10;
                return self.bus.send(&RawFrame::new(frame.id(), &data).unwrap());
            }
        }
        self.bus.send(frame)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<RawFrame>, BusError> {
        self.bus.receive(timeout)
    }
}

/// Updates a fresh simulator to 0.2.0 through a bus that damages one data frame inside
/// the third window (`lose`: loses it; otherwise flips a bit in it); the update is
/// confirmed and its JSON report returned.
fn update_with_one_damaged_data_frame(lose: bool) -> serde_json::Value {
    let simulator = start();
    let mut bus = CorruptOnce {
        bus: connect(&simulator),
        sent_data_frames: 0,
        corrupt_at: 2 * 586 + 100,
        lose,
    };
    standby(&mut bus);
    let file = image_file(&simulator, "0.2.0");
    let mut out = Vec::new();
    firmware::update(&mut bus, &plan(file), TIMEOUT, &mut out).unwrap();
    assert_eq!(firmware::query(&mut bus, TIMEOUT).unwrap().version, "0.2.0");
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(report["outcome"], "confirmed");
    report
}

/// basectl's bus, on which another program's BEGIN (another session id) goes out once,
/// in the middle of the transfer: the controller refuses it Busy, on the bus every
/// program reads.
struct ForeignBeginDuringTransfer<B> {
    bus: B,
    own_session: Option<u8>,
    sent_data_frames: u32,
    foreign_begins: u32,
}

impl<B: Bus> Bus for ForeignBeginDuringTransfer<B> {
    fn send(&mut self, frame: &RawFrame) -> Result<(), BusError> {
        if let Ok(Some(UpdateCommand::Begin { session, .. })) =
            UpdateCommand::decode(frame.id(), frame.data())
        {
            self.own_session = Some(session);
        }
        if frame.id() == base_core::can::id::UPDATE_DATA {
            self.sent_data_frames += 1;
            if self.sent_data_frames == 586 + 50 {
                let foreign = self.own_session.unwrap().wrapping_add(0x80).max(1);
                self.bus.send(
                    &UpdateCommand::Begin {
                        session: foreign,
                        size: 64 * 1024,
                        flags: BeginFlags::default(),
                    }
                    .encode(),
                )?;
                self.foreign_begins += 1;
            }
        }
        self.bus.send(frame)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<RawFrame>, BusError> {
        self.bus.receive(timeout)
    }
}

#[test]
fn another_programs_refused_begin_does_not_stop_a_running_update() {
    let simulator = start();
    let mut bus = ForeignBeginDuringTransfer {
        bus: connect(&simulator),
        own_session: None,
        sent_data_frames: 0,
        foreign_begins: 0,
    };
    standby(&mut bus);
    let file = image_file(&simulator, "0.2.0");
    let mut out = Vec::new();
    let result = firmware::update(&mut bus, &plan(file), TIMEOUT, &mut out);
    assert_eq!(bus.foreign_begins, 1);
    result.unwrap();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(report["outcome"], "confirmed");
    assert_eq!(firmware::query(&mut bus, TIMEOUT).unwrap().version, "0.2.0");
}

#[test]
fn a_window_corrupted_on_the_wire_is_refused_and_sent_again() {
    let report = update_with_one_damaged_data_frame(false);
    assert!(report["retries"].as_u64().unwrap() >= 1, "{report}");
}

#[test]
fn a_data_frame_lost_on_the_wire_is_sent_again_from_where_the_controller_asks() {
    let report = update_with_one_damaged_data_frame(true);
    // The next frame is out of order; the READY after it sends basectl back to the
    // lost one, inside the same window: no window is sent again.
    assert_eq!(report["retries"], 0, "{report}");
}

#[test]
fn a_wrong_chip_image_is_refused_before_anything_is_written() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let flash_before = app_flash_bytes(&simulator);
    let image = app_flash::synthetic_image(Chip::Esp32c6, PROJECT, "0.2.0", TEST_PAYLOAD);
    // basectl's offline check names the chip; the controller refuses it by itself too.
    let session = 77;
    bus.send(
        &UpdateCommand::Begin {
            session,
            size: image.len() as u32,
            flags: BeginFlags::default(),
        }
        .encode(),
    )
    .unwrap();
    firmware::send_digest(&mut bus, session, &Sha256::digest(&image).into()).unwrap();
    let error = firmware::transfer(&mut bus, session, &image, |_, _, _| {}).unwrap_err();
    assert!(error.to_string().contains("BadImage"), "{error}");
    let after = app_flash_bytes(&simulator);
    for partition in partitions::TABLE {
        if partition.offset < after.len() as u32 {
            assert_eq!(
                region(&after, partition),
                region(&flash_before, partition),
                "{} changed",
                partition.name
            );
        }
    }
    assert!(region(&after, partitions::OTA_1).iter().all(|&b| b == 0xFF));
    let running = firmware::query(&mut bus, TIMEOUT).unwrap();
    assert_eq!(
        (running.version.as_str(), running.phase),
        (FACTORY_VERSION, Phase::Idle)
    );
}

#[test]
fn basectl_checks_an_image_file_offline() {
    let directory = tempfile::tempdir().unwrap();
    let good = directory.path().join("good.bin");
    std::fs::write(&good, sim_image("0.2.0", 1000)).unwrap();
    let mut out = Vec::new();
    firmware::check(&good, false, &mut out).unwrap();
    assert!(
        String::from_utf8(out)
            .unwrap()
            .contains("firmware 0.2.0 for esp32c3")
    );
    let mut corrupt = sim_image("0.2.0", 1000);
    corrupt[600] ^= 1;
    let bad = directory.path().join("bad.bin");
    std::fs::write(&bad, corrupt).unwrap();
    let error = firmware::check(&bad, false, &mut Vec::new()).unwrap_err();
    assert!(matches!(error, Error::InvalidInput(_)), "{error}");
}

#[test]
fn an_update_over_slcan_is_confirmed_too() {
    let simulator = start();
    let mut bus =
        basectl::bus::SlcanPort::open(simulator.link().to_str().unwrap(), 500_000).unwrap();
    standby(&mut bus);
    let file = image_file(&simulator, "0.2.0");
    let mut out = Vec::new();
    firmware::update(&mut bus, &plan(file), TIMEOUT, &mut out).unwrap();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(report["outcome"], "confirmed");
    assert_eq!(firmware::query(&mut bus, TIMEOUT).unwrap().version, "0.2.0");
}

/// The update task's view of the flash reaches the inactive slot and otadata only:
/// an offset past the slot is refused without touching anything, and a window
/// written at the slot's last sector lands there and nowhere else.
#[test]
fn the_update_flash_writes_only_inside_the_inactive_slot() {
    use base_core::update::otadata::Slot;
    use base_runtime::update::{UpdateFlash, UpdateFlashError};
    use virtual_robot::flash::RamFlash;
    use virtual_robot::runtime::block_on;

    let flash = RamFlash::new(partitions::FLASH_SIZE as usize);
    // Everything outside the slots holds a pattern that must survive.
    let pattern: Vec<u8> = (0..partitions::FLASH_SIZE)
        .map(|i| (i % 251) as u8)
        .collect();
    let mut writer = flash.clone();
    block_on(async {
        use embedded_storage_async::nor_flash::NorFlash;
        writer.erase(0, partitions::FLASH_SIZE).await.unwrap();
        writer.write(0, &pattern).await.unwrap();
    });
    let before = flash.contents(0..partitions::FLASH_SIZE);
    let mut update = UpdateFlash::new(flash.clone(), Slot::Ota0);
    let last_sector = partitions::SLOT_LEN - 4096;
    block_on(async {
        assert_eq!(
            update.write_window(partitions::SLOT_LEN, &[1; 16]).await,
            Err(UpdateFlashError::OutOfBounds)
        );
        assert_eq!(
            update.write_window(100, &[1; 16]).await,
            Err(UpdateFlashError::OutOfBounds)
        );
        assert_eq!(
            update.write_window(0, &[1; 4097]).await,
            Err(UpdateFlashError::OutOfBounds)
        );
        update.write_window(last_sector, &[7; 4093]).await.unwrap();
    });
    let after = flash.contents(0..partitions::FLASH_SIZE);
    let target = partitions::OTA_1.offset + last_sector;
    for (at, (old, new)) in before.iter().zip(&after).enumerate() {
        let at = at as u32;
        if (target..target + 4096).contains(&at) {
            let expected = if at < target + 4093 { 7 } else { 0xFF };
            assert_eq!(*new, expected, "{at:#x}");
        } else {
            assert_eq!(
                old, new,
                "{at:#x} changed outside the inactive slot's sector"
            );
        }
    }
}

/// While a session runs, the e-stop and the status frame work as always, and a
/// velocity is refused with rejection 0x50.
#[test]
fn during_an_update_session_the_estop_and_status_work_and_motion_is_refused() {
    let mut simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    bus.send(
        &UpdateCommand::Begin {
            session: 5,
            size: 200_000,
            flags: BeginFlags::default(),
        }
        .encode(),
    )
    .unwrap();
    let reply = receive_reply(&mut bus, Duration::from_secs(1));
    assert!(
        matches!(reply, Some(UpdateReply::Done { session: 5, .. })),
        "{reply:?}"
    );
    bus.send(&Command::Enable { refresh: true }.encode())
        .unwrap();
    bus.send(
        &Command::Velocity {
            linear_mm_s: 200,
            rotation_mrad_s: 0,
        }
        .encode(),
    )
    .unwrap();
    simulator.console("estop on").unwrap();
    let mut base = Base::new(&mut bus, TIMEOUT);
    let deadline = Instant::now() + Duration::from_secs(5);
    let status = loop {
        let status = base.next_status().unwrap();
        if status.mode == Mode::Emergency || Instant::now() > deadline {
            break status;
        }
    };
    assert_eq!(status.mode, Mode::Emergency);
    assert!(status.flags.estop_pressed);
    assert_eq!(status.control, ControlSource::None);
    assert_eq!(
        status.last_rejection,
        base_core::can::Rejection::UpdateInProgress.code()
    );
}

/// A controller built with the owner's key (`--update-key`), and the owner's key files
/// (the secret key in `owner.key`).
fn start_with_owner_key() -> (SimulatorProcess, tempfile::TempDir) {
    let keys = tempfile::tempdir().unwrap();
    let owner = keys.path().join("owner.key");
    signing::keygen(&owner, &mut Vec::new()).unwrap();
    let simulator = SimulatorProcess::launch(env!("CARGO_BIN_EXE_virtual-base-controller"))
        .arg("--update-key")
        .arg(signing::public_key_path(&owner))
        .start()
        .expect("the simulator starts");
    simulator
        .wait_for_line("boot: firmware", Duration::from_secs(10))
        .expect("the factory image boots");
    (simulator, keys)
}

/// An image with this version and security version, signed with `key` when given.
fn signed_file(
    simulator: &SimulatorProcess,
    version: &str,
    security_version: u32,
    key: Option<&std::path::Path>,
    allow_security_downgrade: bool,
) -> PathBuf {
    let plain = simulator.directory().join(format!("{version}.bin"));
    let image = secured_image(
        app_flash::SIM_CHIP,
        PROJECT,
        version,
        security_version,
        TEST_PAYLOAD,
    );
    std::fs::write(&plain, image).unwrap();
    let Some(key) = key else {
        return plain;
    };
    let signed = simulator.directory().join(format!("{version}.signed.bin"));
    signing::sign(
        key,
        &plain,
        &signed,
        allow_security_downgrade,
        &mut Vec::new(),
    )
    .unwrap();
    signed
}

/// BEGIN, DIGEST, every window and FINISH, as a client without basectl's own checks
/// would send them: FINISH's answer.
fn finish_raw(bus: &mut dyn Bus, image: &[u8]) -> UpdateReply {
    let session = 0x3C;
    let flags = BeginFlags {
        force: true,
        allow_downgrade: true,
    };
    let size = image.len() as u32;
    bus.send(
        &UpdateCommand::Begin {
            session,
            size,
            flags,
        }
        .encode(),
    )
    .unwrap();
    firmware::send_digest(bus, session, &Sha256::digest(image).into()).unwrap();
    firmware::transfer(bus, session, image, |_, _, _| {}).expect("every window is written");
    bus.send(&UpdateCommand::Finish { session }.encode())
        .unwrap();
    loop {
        let reply = receive_reply(bus, Duration::from_secs(5)).expect("FINISH is answered");
        if let UpdateReply::Done { .. } | UpdateReply::Refused { .. } = reply {
            // A client that goes no further ends its session.
            bus.send(&UpdateCommand::Abort { session }.encode())
                .unwrap();
            return reply;
        }
    }
}

fn untrusted(error: UpdateError, detail: u8) -> UpdateReply {
    UpdateReply::Refused {
        opcode: 0x05,
        error,
        detail,
        session: 0x3C,
    }
}

#[test]
fn a_controller_with_a_key_activates_only_images_its_owner_signed() {
    let (simulator, keys) = start_with_owner_key();
    let owner = keys.path().join("owner.key");
    let stranger = keys.path().join("stranger.key");
    signing::keygen(&stranger, &mut Vec::new()).unwrap();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let running = firmware::query(&mut bus, TIMEOUT).unwrap();
    assert!(running.signatures_required);
    assert_eq!(running.security_version, 0);

    // basectl refuses an unsigned image before it sends a byte, and the controller
    // refuses it by itself too, as it does a stranger's and a forged one.
    let unsigned = signed_file(&simulator, "0.2.0", 0, None, false);
    let error =
        firmware::update(&mut bus, &plan(unsigned.clone()), TIMEOUT, &mut Vec::new()).unwrap_err();
    assert!(error.to_string().contains("only signed images"), "{error}");
    let strangers = signed_file(&simulator, "0.2.1", 0, Some(&stranger), false);
    let mut forged =
        std::fs::read(signed_file(&simulator, "0.2.2", 0, Some(&owner), false)).unwrap();
    // The block's flags, after the magic and the key: a downgrade claimed.
    let flags_at = forged.len() - signature::BLOCK_LEN + 40;
    forged[flags_at] ^= 1;
    for (name, image, refusal) in [
        (
            "unsigned",
            std::fs::read(&unsigned).unwrap(),
            untrusted(UpdateError::Untrusted, 1),
        ),
        (
            "a stranger's",
            std::fs::read(&strangers).unwrap(),
            untrusted(UpdateError::Untrusted, 2),
        ),
        ("forged", forged, untrusted(UpdateError::Untrusted, 3)),
    ] {
        standby(&mut bus);
        assert_eq!(finish_raw(&mut bus, &image), refusal, "{name}");
        let running = firmware::query(&mut bus, TIMEOUT).unwrap();
        assert_eq!(
            (running.version.as_str(), running.phase),
            (FACTORY_VERSION, Phase::Idle),
            "{name}: nothing was activated"
        );
    }

    // The owner's image raises the security version to 2.
    let raised = signed_file(&simulator, "0.3.0", 2, Some(&owner), false);
    assert_eq!(confirmed_update(&mut bus, raised), ("0.3.0".to_owned(), 2));

    // Below it, the owner's signature alone is not enough: a signed downgrade is.
    let older = signed_file(&simulator, "0.4.0", 1, Some(&owner), false);
    let error =
        firmware::update(&mut bus, &plan(older.clone()), TIMEOUT, &mut Vec::new()).unwrap_err();
    assert!(
        error.to_string().contains("security version 1 is below"),
        "{error}"
    );
    assert_eq!(
        finish_raw(&mut bus, &std::fs::read(&older).unwrap()),
        untrusted(UpdateError::SecurityDowngrade, 2)
    );
    let downgrade = signed_file(&simulator, "0.4.1", 1, Some(&owner), true);
    standby(&mut bus);
    assert_eq!(
        confirmed_update(&mut bus, downgrade),
        ("0.4.1".to_owned(), 1)
    );
}

/// `firmware update` of `file`, confirmed: the version and security version that run.
fn confirmed_update(bus: &mut dyn Bus, file: PathBuf) -> (String, u8) {
    let mut out = Vec::new();
    firmware::update(bus, &plan(file), TIMEOUT, &mut out).unwrap();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(report["outcome"], "confirmed");
    standby(bus);
    let running = firmware::query(bus, TIMEOUT).unwrap();
    (running.version, running.security_version)
}

#[test]
fn a_development_build_says_so_and_takes_an_unsigned_image() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    let mut out = Vec::new();
    firmware::info(&mut bus, TIMEOUT, false, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    assert!(
        text.contains("DEVELOPMENT BUILD: updates over CAN accept unsigned images"),
        "{text}"
    );
    let unsigned = signed_file(&simulator, "0.2.0", 0, None, false);
    assert_eq!(
        finish_raw(&mut bus, &std::fs::read(unsigned).unwrap()),
        UpdateReply::Done {
            session: 0x3C,
            step: base_core::can::update::Step::Finished
        }
    );
}

/// Every read-write register, read over CAN.
fn register_values(bus: &mut dyn Bus) -> Vec<(&'static str, u16)> {
    let mut base = Base::new(bus, TIMEOUT);
    TABLE
        .iter()
        .filter(|register| register.access == Access::ReadWrite)
        .map(|register| (register.name, base.read_register(register.address).unwrap()))
        .collect()
}

#[test]
fn every_register_away_from_its_default_survives_an_update_and_a_rollback() {
    let simulator = start();
    let mut bus = connect(&simulator);
    standby(&mut bus);
    {
        let mut base = Base::new(&mut bus, TIMEOUT);
        for register in TABLE.iter().filter(|r| r.access == Access::ReadWrite) {
            // One step from the default; a step a rule between two registers refuses
            // (the battery limits) leaves that register at its default.
            let step = [
                register.default.wrapping_add(1),
                register.default.wrapping_sub(1),
            ]
            .into_iter()
            .find(|&value| register.accepts(value));
            if let Some(value) = step {
                let _ = base.write_register(register, value);
            }
        }
    }
    let before = register_values(&mut bus);
    let defaults = TABLE
        .iter()
        .filter(|register| register.access == Access::ReadWrite)
        .filter(|register| before.contains(&(register.name, register.default)))
        .count();
    assert!(
        defaults <= 2,
        "most registers left their defaults: {before:?}"
    );
    // The store is written at standstill, 5 s after the last change.
    std::thread::sleep(Duration::from_secs(6));
    let mut out = Vec::new();
    firmware::update(
        &mut bus,
        &plan(image_file(&simulator, "0.2.0")),
        TIMEOUT,
        &mut out,
    )
    .unwrap();
    standby(&mut bus);
    assert_eq!(
        register_values(&mut bus),
        before,
        "after the update to 0.2.0"
    );
    let failing = image_file(&simulator, "0.3.0-sim-panic");
    let error = firmware::update(&mut bus, &plan(failing), TIMEOUT, &mut Vec::new()).unwrap_err();
    assert!(error.to_string().contains("did not start"), "{error}");
    standby(&mut bus);
    assert_eq!(
        firmware::query(&mut bus, TIMEOUT).unwrap().version,
        "0.2.0",
        "rolled back"
    );
    assert_eq!(register_values(&mut bus), before, "after the rollback");
}
