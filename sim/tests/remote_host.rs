//! The BLE host's life on the virtual clock: the firmware's remote task
//! (`base_runtime::ble::run`, trouble-host behind the guard) on the simulator's scripted
//! controller (`virtual_robot::fake_hci`), whose pad is bonded and serves HID over GATT
//! as an Xbox pad. What happens when the host stops (a broken transport, a malformed
//! answer from the controller), and when the guard closes links.
//!
//! Virtual time: the bounds here (200 ms to zero on the wire, 2 s until the owner is
//! back) do not depend on how busy the machine is.

use base_core::can::{Command, Mode};
use base_core::registers::{BLE_OFF_AFTER_HOST_STOPS, BLUETOOTH_ON_KEY, Reg};
use embassy_time::{Duration, Instant};
use virtual_robot::ble::RemoteRobot;
use virtual_robot::fake_hci::{AttackAt, FakeHandle, PAD_ADDRESS, XboxReport, fake_controller};
use virtual_robot::robot::{Pc, wait_ms};

/// The Xbox Wireless Controller's Report Map (BLE firmware 5), as the pad serves it.
fn xbox_report_map() -> Vec<u8> {
    include_str!("../../core/tests/data/hid/xbox-wireless-ble-fw5_045E-0B13.hex")
        .lines()
        .filter(|line| !line.starts_with('#'))
        .flat_map(str::split_whitespace)
        .map(|pair| u8::from_str_radix(pair, 16).expect("hex"))
        .collect()
}

/// A robot whose flash holds the bond of the fake's pad, and the fake, its pad serving
/// HID over GATT.
fn bonded_robot_and_pad() -> (
    RemoteRobot,
    virtual_robot::fake_hci::FakeController,
    FakeHandle,
) {
    let robot = RemoteRobot::new();
    robot.bond_ble_pad(PAD_ADDRESS);
    let (controller, fake) = fake_controller();
    fake.serve_gamepad(xbox_report_map());
    (robot, controller, fake)
}

/// Waits up to `timeout_ms` for `done`; whether it came.
async fn within(timeout_ms: u64, done: impl Fn() -> bool) -> bool {
    let end = Instant::now() + Duration::from_millis(timeout_ms);
    while Instant::now() < end {
        if done() {
            return true;
        }
        wait_ms(1).await;
    }
    done()
}

/// Waits until the task subscribed to the pad's reports and the controller counts the
/// pad connected.
async fn pad_ready(fake: &FakeHandle, pc: &Pc, timeout_ms: u64) {
    assert!(
        within(timeout_ms, || fake.subscribed()).await,
        "the pad is served within {timeout_ms} ms: {:?}",
        fake.stats()
    );
    assert!(
        pc.wait_for_status(2_000, |s| s.flags.remote_connected)
            .await
            .is_some(),
        "the pad counts as connected"
    );
}

/// An empty ATT PDU (L2CAP length 0, channel 4), as H4 for the fake.
fn empty_att_pdu() -> Vec<u8> {
    vec![0x02, 0x00, 0x20, 0x04, 0x00, 0x00, 0x00, 0x04, 0x00]
}

/// The impostor at the bonded address (no key: its encryption fails) sends an empty
/// ATT PDU on its link at `at`; the guard closes the link. Returns how long after the
/// impostor's link ended the owner's pad, back in range, is served again.
async fn owner_back_after_one_empty_att_pdu(fake: &FakeHandle, pc: &Pc, at: AttackAt) -> Duration {
    pad_ready(fake, pc, 10_000).await;
    // The owner's pad goes out of range; the impostor comes.
    fake.peer_disconnects();
    fake.impostor(true);
    fake.attack_every_link(at, [empty_att_pdu()]);
    let before = fake.stats().packets_delivered;
    assert!(
        within(5_000, || fake.stats().packets_delivered > before).await,
        "the impostor is connected and sends its packet"
    );
    // Its link ends (the guard closes it).
    within(1_000, || !fake.connected()).await;
    // The impostor leaves, the owner's pad is back.
    let left = Instant::now();
    fake.peace();
    fake.impostor(false);
    assert!(
        within(75_000, || fake.subscribed()).await,
        "{at:?}: the owner's pad is not back 75 s after the impostor left: {:?}",
        fake.stats()
    );
    left.elapsed()
}

#[test]
fn one_empty_att_pdu_from_an_impostor_costs_the_owner_at_most_2_s() {
    for at in [
        AttackAt::Connect,
        AttackAt::EncryptionRequested,
        AttackAt::Encrypted,
    ] {
        let (robot, controller, fake) = bonded_robot_and_pad();
        let back = robot.run_virtual(controller, async |pc| {
            owner_back_after_one_empty_att_pdu(&fake, pc, at).await
        });
        eprintln!(
            "empty ATT PDU at {at:?}: owner served again {} ms after the impostor left",
            back.as_millis()
        );
        assert!(
            back <= Duration::from_secs(2),
            "{at:?}: {} ms",
            back.as_millis()
        );
        assert_eq!(fake.stats().resets, 1, "{at:?}: the host never restarted");
    }
}

/// The speed both drives were last commanded, in r/min (None before any command).
/// The bonded pad itself sends an empty ATT PDU on every link once encrypted: the
/// guard closes each. It is reached again at most once a second (it was reconnected
/// 33 times in 10 s), each closed link counts as rejection 0x60 on CAN, and once it
/// behaves it is served within 2 s.
#[test]
fn a_bonded_pad_whose_packets_the_guard_keeps_refusing_is_backed_off_and_counted() {
    let (robot, controller, fake) = bonded_robot_and_pad();
    robot.run_virtual(controller, async |pc| {
        pad_ready(&fake, pc, 10_000).await;
        fake.attack_every_link(AttackAt::Encrypted, [empty_att_pdu()]);
        fake.peer_disconnects();
        let connections = fake.stats().connections;
        wait_ms(10_000).await;
        let reconnects = fake.stats().connections - connections;
        eprintln!("a pad refused on every link: {reconnects} connections in 10 s");
        assert!(
            (1..=11).contains(&reconnects),
            "at most one attempt a second: {reconnects} in 10 s, {:?}",
            fake.stats()
        );
        let status = pc
            .wait_for_status(2_000, |s| s.last_rejection == 0x60)
            .await
            .expect("the refused packets show as rejection 0x60 RadioPacketRefused");
        assert_eq!(status.last_rejection_subject, 1, "a BLE pad");
        assert!(
            u32::from(status.rejected_count) + 1 >= reconnects,
            "{status:?}"
        );
        fake.peace();
        let behaved = Instant::now();
        assert!(
            within(5_000, || fake.subscribed()).await,
            "{:?}",
            fake.stats()
        );
        assert!(
            behaved.elapsed() <= Duration::from_secs(2),
            "served again {} ms after it behaved",
            behaved.elapsed().as_millis()
        );
    });
}

fn commanded_rpm(robot: &RemoteRobot) -> [Option<i32>; 2] {
    [1, 2].map(|slave| {
        robot
            .robot
            .drives
            .drive(slave)
            .command
            .map(|command| command.speed_rpm)
    })
}

/// The pad holds the dead-man with the stick forward until both wheels are commanded
/// forward.
async fn drive_forward(robot: &RemoteRobot, fake: &FakeHandle, pc: &Pc) {
    // The dead-man counts only once seen released while the drives are ready.
    assert!(
        pc.wait_for_status(5_000, |s| s.mode != Mode::Starting)
            .await
            .is_some(),
        "the drives are set up"
    );
    fake.notify(XboxReport::default());
    wait_ms(50).await;
    fake.notify(XboxReport {
        left_y: 0x8000,
        buttons: XboxReport::RB,
    });
    assert!(
        pc.wait_for_status(2_000, |s| s.flags.remote_in_control)
            .await
            .is_some(),
        "the dead-man gives the remote control"
    );
    fake.notify(XboxReport {
        left_y: XboxReport::FULL_FORWARD,
        buttons: XboxReport::RB,
    });
    assert!(
        within(2_000, || commanded_rpm(robot)
            .iter()
            .all(|rpm| rpm.is_some_and(|rpm| rpm != 0)))
        .await,
        "the wheels are commanded forward: {:?}",
        commanded_rpm(robot)
    );
}

/// Waits until both drives are commanded zero; how long it took.
async fn until_zero_on_the_wire(robot: &RemoteRobot, timeout_ms: u64) -> Option<Duration> {
    let start = Instant::now();
    within(timeout_ms, || commanded_rpm(robot) == [Some(0), Some(0)])
        .await
        .then(|| start.elapsed())
}

#[test]
fn a_host_stopped_by_a_broken_transport_stops_the_wheels_within_200_ms_and_starts_again() {
    let (robot, controller, fake) = bonded_robot_and_pad();
    robot.run_virtual(controller, async |pc| {
        pad_ready(&fake, pc, 10_000).await;
        drive_forward(&robot, &fake, pc).await;
        // The transport breaks: trouble-host's runner stops. The pad still holds the
        // dead-man and sends nothing more (BLE pads report on change).
        fake.fail_next_read();
        let zero = until_zero_on_the_wire(&robot, 1_000).await;
        eprintln!(
            "host stopped: zero on the wire after {:?} ms",
            zero.map(|zero| zero.as_millis())
        );
        assert!(
            zero.is_some_and(|zero| zero <= Duration::from_millis(200)),
            "zero on the wire within 200 ms of the host stopping: {zero:?}, {:?}",
            commanded_rpm(&robot)
        );
        // A fresh host resets the controller and serves the pad again.
        assert!(
            within(5_000, || fake.stats().resets == 2 && fake.subscribed()).await,
            "the host started again and serves the pad: {:?}",
            fake.stats()
        );
    });
}

/// A host that stops three times within a minute stays off (no restart loop), the PC
/// sees it in register 36, and the key starts it again: the owner's pad is back.
#[test]
fn a_host_that_keeps_stopping_stays_off_shows_it_and_the_key_starts_it_again() {
    let (robot, controller, fake) = bonded_robot_and_pad();
    robot.run_virtual(controller, async |pc| {
        pad_ready(&fake, pc, 10_000).await;
        for start in 2..=3 {
            fake.fail_next_read();
            assert!(
                within(5_000, || fake.stats().resets == start && fake.subscribed()).await,
                "start {start}: {:?}",
                fake.stats()
            );
        }
        // The third stop within a minute: the controller is reset (the pad's link ends
        // with it) and no host starts again.
        let connections = fake.stats().connections;
        fake.fail_next_read();
        wait_ms(30_000).await;
        assert_eq!(fake.stats().resets, 4, "{:?}", fake.stats());
        assert_eq!(fake.stats().connections, connections, "no connection since");
        assert!(!fake.connected());
        assert!(
            pc.wait_for_status(100, |s| !s.flags.remote_connected)
                .await
                .is_some(),
            "the pad counts as gone"
        );
        assert_eq!(
            pc.read_register(Reg::BluetoothOff as u8).await,
            Some(BLE_OFF_AFTER_HOST_STOPS),
            "register 36 says the BLE host is off"
        );
        pc.command(Command::RegisterWrite {
            address: Reg::Command as u8,
            value: BLUETOOTH_ON_KEY,
        });
        assert!(
            within(5_000, || fake.stats().resets == 5 && fake.subscribed()).await,
            "turned on: a fresh host serves the owner's pad again: {:?}",
            fake.stats()
        );
        assert_eq!(pc.read_register(Reg::BluetoothOff as u8).await, Some(0));
    });
}
