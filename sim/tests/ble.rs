//! The Bluetooth remote end to end: the firmware's BLE central (`base_runtime::ble::run`,
//! trouble-host) on the wall clock, through an HCI transport (H4 over TCP) to Google
//! Bumble's virtual controllers, where a HID-over-GATT gamepad serves the Report Map of
//! an Xbox Wireless Controller. The pad drives the virtual robot.
//!
//! Each scenario starts its own peer (sim/ble-peer/bumble_gamepad.py) and scripts the
//! pad through it. The scenarios run one at a time: they follow the wall clock, and a
//! supervision timeout of 500 ms must not depend on how busy the machine is.
//!
//! Without Bumble the scenarios are skipped with a message, except in CI (CI=true),
//! where they fail.

#[path = "ble/common.rs"]
mod common;
#[path = "ble/peer.rs"]
mod peer;

use std::time::{Duration, Instant};

use base_core::can::Mode;
use base_core::registers::{BLUETOOTH_ON_KEY, Reg};
use common::{
    bond_stored_for, last_decel, open_pairing_window, scenario, status, wheels, write_register,
};
use embassy_futures::join::join;
use embassy_futures::select::select;
use embassy_time::Timer;
use peer::Peer;
use virtual_robot::ble::{BOND_FLASH_SIZE, RemoteRobot};
use virtual_robot::robot::{Pc, controller_panics};

/// The pad's random static address (the two top bits set).
const PAD_ADDRESS: &str = "C1:11:22:33:44:55";
const OTHER_PAD_ADDRESS: &str = "C2:66:77:88:99:AA";

/// Creates pad `name`, lets it advertise, opens the pairing window and waits until the
/// pad is paired, subscribed and counted as connected.
async fn pair(peer: &mut Peer, pc: &Pc, name: &str, address: &str) {
    peer.cmd(&format!("pad {name} {address}")).await;
    pair_created(peer, pc, name).await;
}

/// [`pair`] for a pad that exists already.
async fn pair_created(peer: &mut Peer, pc: &Pc, name: &str) {
    let mark = peer.mark();
    peer.cmd(&format!("advertise {name}")).await;
    open_pairing_window(pc).await;
    peer.wait_for(mark, &["paired", name], 20_000).await;
    peer.wait_for(mark, &["subscribed", name], 10_000).await;
    status(pc, 5_000, "the paired pad is connected", |s| {
        s.flags.remote_bonded && s.flags.remote_connected
    })
    .await;
}

/// Holds the dead-man and waits until the controller hands control to the remote.
async fn take_control(peer: &mut Peer, pc: &Pc, name: &str) {
    // The dead-man counts only once seen released while the drives are ready.
    status(pc, 5_000, "the drives are set up", |s| {
        s.mode != Mode::Starting
    })
    .await;
    peer.cmd(&format!("release {name} RB")).await;
    peer.cmd(&format!("press {name} RB")).await;
    status(pc, 2_000, "the dead-man gives the remote control", |s| {
        s.flags.remote_in_control
    })
    .await;
}

#[test]
fn pairing_window_pairs_the_pad_stores_the_bond_and_decodes_its_reports() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    let started = Instant::now();
    robot.run(peer.controller(), async |pc| {
        let before = status(pc, 5_000, "the controller is up", |_| true).await;
        assert!(!before.flags.remote_bonded, "no bond on a blank flash");
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        // A report decoded through the Xbox Report Map: RB is the dead-man.
        take_control(&mut peer, pc, "pad").await;
        peer.cmd("release pad RB").await;
        status(
            pc,
            2_000,
            "releasing the dead-man ends remote control",
            |s| !s.flags.remote_in_control,
        )
        .await;
    });
    assert!(
        bond_stored_for(&robot, PAD_ADDRESS),
        "the bond is in its flash partition"
    );
    eprintln!("pairing scenario: {:?}", started.elapsed());
}

#[test]
fn a_pad_paired_while_the_base_drives_is_stored_only_at_the_next_standstill() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the drives are set up", |s| {
            s.mode == Mode::Standby
        })
        .await;
        // The PC drives at 300 mm/s while a pad pairs: a flash erase now would stall
        // the control loop (up to 400 ms on the chip).
        let driving = async {
            loop {
                pc.enable();
                pc.velocity(300, 0);
                Timer::after_millis(50).await;
            }
        };
        let pairing = async {
            wheels(&robot, 3_000, true).await;
            pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
            wheels(&robot, 100, true).await;
            assert!(
                !bond_stored_for(&robot, PAD_ADDRESS),
                "the bond was written to flash while the wheels turned"
            );
        };
        select(driving, pairing).await;
        // The PC stops sending: the enable lapses, the base stops and the brakes close.
        status(pc, 5_000, "the brakes close at standstill", |s| {
            s.flags.brakes_applied
        })
        .await;
        let deadline = Instant::now() + Duration::from_secs(2);
        while !bond_stored_for(&robot, PAD_ADDRESS) {
            assert!(
                Instant::now() < deadline,
                "the bond is stored at the standstill"
            );
            Timer::after_millis(10).await;
        }
        status(pc, 1_000, "the pad stays connected", |s| {
            s.flags.remote_bonded && s.flags.remote_connected
        })
        .await;
    });
}

/// Pulls the left stick forward with the dead-man held: the robot drives.
async fn drive_forward(peer: &mut Peer, robot: &RemoteRobot, pc: &Pc) {
    take_control(peer, pc, "pad").await;
    peer.cmd("stick pad LY 1.0").await;
    wheels(robot, 3_000, true).await;
}

/// A value of `Contr_acc_high` no other rule uses, to recognise its braking: above
/// `stop_decel` (2000), the floor of every stop but the e-stop, so the register itself
/// is in force.
const RELEASE_BRAKING: u16 = 2777;

#[test]
fn dead_man_and_stick_turn_the_wheels_and_release_stops_them() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        drive_forward(&mut peer, &robot, pc).await;
        peer.cmd("release pad RB").await;
        wheels(&robot, 3_000, false).await;
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
    });
}

#[test]
fn link_loss_with_the_dead_man_held_stops_with_contr_acc_high() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        drive_forward(&mut peer, &robot, pc).await;
        let lost_at = Instant::now();
        // The dead-man stays held: only the link goes.
        peer.cmd("lose pad").await;
        status(pc, 3_000, "the lost link is reported", |s| {
            !s.flags.remote_connected && !s.flags.remote_in_control
        })
        .await;
        wheels(&robot, 3_000, false).await;
        let stopped_after = lost_at.elapsed();
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
        // The 500 ms supervision timeout plus the ramp down from full stick.
        assert!(stopped_after < Duration::from_secs(3), "{stopped_after:?}");
        eprintln!("link loss to standstill: {stopped_after:?}");
    });
}

#[test]
fn a_dropped_pad_reconnects_encrypted_without_pairing() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        peer.cmd("disconnect pad").await;
        status(pc, 3_000, "the drop is reported", |s| {
            !s.flags.remote_connected
        })
        .await;
        let mark = peer.mark();
        peer.cmd("advertise pad").await;
        peer.wait_for(mark, &["encrypted", "pad", "1"], 10_000)
            .await;
        peer.wait_for(mark, &["subscribed", "pad"], 10_000).await;
        status(pc, 3_000, "the pad is back", |s| s.flags.remote_connected).await;
        assert!(
            peer.events_since(mark, &["pairing-started"]).is_empty(),
            "a bonded pad is not paired again"
        );
        take_control(&mut peer, pc, "pad").await;
    });
}

#[test]
fn a_reboot_reconnects_with_the_bond_from_flash() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
    });
    // The chip lost power: the pad sees its link time out and advertises again.
    let mark = peer.mark();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the bond came back from flash", |s| {
            s.flags.remote_bonded
        })
        .await;
        peer.wait_for(0, &["disconnected", "pad"], 5_000).await;
        peer.cmd("advertise pad").await;
        peer.wait_for(mark, &["encrypted", "pad", "1"], 10_000)
            .await;
        peer.wait_for(mark, &["subscribed", "pad"], 10_000).await;
        status(pc, 3_000, "the pad is back", |s| s.flags.remote_connected).await;
        assert!(peer.events_since(mark, &["pairing-started"]).is_empty());
        take_control(&mut peer, pc, "pad").await;
    });
}

#[test]
fn a_stranger_is_ignored_outside_the_pairing_window() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        peer.cmd("disconnect pad").await;
        status(pc, 3_000, "the drop is reported", |s| {
            !s.flags.remote_connected
        })
        .await;
        let mark = peer.mark();
        peer.cmd(&format!("pad stranger {OTHER_PAD_ADDRESS}")).await;
        peer.cmd("advertise stranger").await;
        // The robot looks for its own pad only; when that one is back, the stranger
        // has been advertising all along.
        peer.cmd("advertise pad").await;
        peer.wait_for(mark, &["subscribed", "pad"], 10_000).await;
        assert!(
            peer.events_since(mark, &["connected", "stranger"])
                .is_empty()
        );
        assert!(peer.events_since(mark, &["central-scan", "on"]).is_empty());
    });
}

/// Counts the robot's connection attempts over `window_ms` from now.
async fn connect_attempts(peer: &Peer, window_ms: u64) -> usize {
    let mark = peer.mark();
    Timer::after_millis(window_ms).await;
    peer.events_since(mark, &["central-connect"]).len()
}

#[test]
fn an_impostor_at_the_bonded_address_is_refused_and_the_robot_backs_off() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        let bond = robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32);
        peer.cmd("remove pad").await;
        status(pc, 3_000, "the pad is gone", |s| !s.flags.remote_connected).await;
        let mark = peer.mark();
        peer.cmd(&format!("pad impostor {PAD_ADDRESS}")).await;
        peer.cmd("advertise impostor").await;
        peer.wait_for(mark, &["connected", "impostor"], 10_000)
            .await;
        peer.wait_for(mark, &["disconnected", "impostor"], 10_000)
            .await;
        let attempts = connect_attempts(&peer, 3_000).await;
        // Refused, not raced: the robot never even asks to pair.
        let pairings = peer.events_since(mark, &["central-pairing-request"]).len();
        assert_eq!(pairings, 0, "pairing requests outside the window");
        assert!(peer.events_since(mark, &["pairing-started"]).is_empty());
        assert!(
            peer.events_since(mark, &["subscribed", "impostor"])
                .is_empty()
        );
        assert!(attempts <= 3, "{attempts} connection attempts in 3 s");
        assert!(!pc.status().expect("status").flags.remote_connected);
        assert_eq!(bond, robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32));
    });
}

#[test]
fn a_pad_that_forgot_its_bond_is_not_paired_outside_the_window() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        peer.cmd("disconnect pad").await;
        peer.cmd("forget pad").await;
        status(pc, 3_000, "the drop is reported", |s| {
            !s.flags.remote_connected
        })
        .await;
        let mark = peer.mark();
        peer.cmd("advertise pad").await;
        peer.wait_for(mark, &["connected", "pad"], 10_000).await;
        peer.wait_for(mark, &["disconnected", "pad"], 10_000).await;
        let attempts = connect_attempts(&peer, 3_000).await;
        // Refused, not raced: the robot never even asks to pair.
        let pairings = peer.events_since(mark, &["central-pairing-request"]).len();
        assert_eq!(pairings, 0, "pairing requests outside the window");
        assert!(peer.events_since(mark, &["pairing-started"]).is_empty());
        assert!(attempts <= 3, "{attempts} connection attempts in 3 s");
    });
}

#[test]
fn a_new_pad_replaces_the_bond_inside_the_window() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    let mark = robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        peer.cmd("remove pad").await;
        status(pc, 3_000, "the pad is gone", |s| !s.flags.remote_connected).await;
        pair(&mut peer, pc, "new", OTHER_PAD_ADDRESS).await;
        // Marked before the power goes: the pad may hear the link drop before the
        // next line of this test runs.
        peer.mark()
    });
    assert!(bond_stored_for(&robot, OTHER_PAD_ADDRESS));
    robot.run(peer.controller(), async |pc| {
        peer.wait_for(mark, &["disconnected", "new"], 5_000).await;
        peer.cmd("advertise new").await;
        peer.wait_for(mark, &["subscribed", "new"], 10_000).await;
        status(pc, 3_000, "the new pad is back", |s| {
            s.flags.remote_connected
        })
        .await;
        assert!(peer.events_since(mark, &["pairing-started"]).is_empty());
    });
}

#[test]
fn a_pad_left_idle_is_switched_off() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        // The shortest AFK time the register takes.
        write_register(pc, Reg::PsAfkTime, 5_000);
        let mark = peer.mark();
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        // The pad has been idle since it paired, at the latest.
        let paired = peer.wait_for(mark, &["paired", "pad"], 0).await;
        let off = peer.wait_for(mark, &["disconnected", "pad"], 10_000).await;
        let idle = off.at - paired.at;
        assert!(
            idle >= Duration::from_millis(5_000),
            "switched off after {idle:?}"
        );
        // Remote user terminated connection: the robot closed the link.
        assert_eq!(off.words[2], "19");
    });
}

#[test]
fn l2_and_home_switch_the_pad_off() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        let mark = peer.mark();
        peer.cmd("trigger pad LT 1.0").await;
        peer.cmd("press pad XBOX").await;
        let off = peer.wait_for(mark, &["disconnected", "pad"], 3_000).await;
        // Remote user terminated connection: the robot closed the link.
        assert_eq!(off.words[2], "19");
        // The robot does not keep a pad it switched off from coming back: this one
        // advertises again at once, and its next link is a new connection.
        peer.wait_for(mark, &["encrypted", "pad", "1"], 10_000)
            .await;
    });
}

/// Every supervision timeout the robot's controller was asked for since `mark`, ms.
fn supervision_timeouts(peer: &Peer, mark: usize) -> Vec<String> {
    peer.events_since(mark, &["central-params"])
        .into_iter()
        .chain(peer.events_since(mark, &["central-connect"]))
        .map(|line| line.words.last().cloned().unwrap_or_default())
        .collect()
}

#[test]
fn our_supervision_timeout_holds_through_pairing_and_encryption() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        peer.cmd(&format!("pad pad {PAD_ADDRESS}")).await;
        // The pad asks for a 6 s supervision timeout as soon as it is connected: while
        // pairing now, while encrypting after the reconnect below.
        peer.cmd("greedy pad 6000").await;
        pair_created(&mut peer, pc, "pad").await;
        // The request while pairing may go unanswered for the same reason as the one
        // on the reconnect below (trouble-host 0.8 drops it when it comes before the
        // link is handed over; seen in most runs since the tests pair after the drives'
        // setup). Answered or not, the pad's 6 s must never be granted.
        let pairing_answered = Instant::now();
        while peer.events_since(0, &["central-params"]).is_empty()
            && pairing_answered.elapsed() < Duration::from_secs(2)
        {
            Timer::after_millis(20).await;
        }
        peer.cmd("disconnect pad").await;
        let mark = peer.mark();
        peer.cmd("advertise pad").await;
        peer.wait_for(mark, &["subscribed", "pad"], 10_000).await;
        // The request during the bonded encryption is answered with ours too, but now
        // and then it goes unanswered: trouble-host 0.8 drops a parameter request that
        // arrives before `Central::connect` has handed the new connection to our task
        // (its connection is still "connecting", and the event finds no connected
        // link). The link then keeps the 500 ms it was made with. Either way the pad's
        // 6 s must never be granted, which is what stops the base on a dead link.
        let answered = Instant::now();
        while peer.events_since(mark, &["central-params"]).is_empty()
            && answered.elapsed() < Duration::from_secs(5)
        {
            Timer::after_millis(20).await;
        }
        if peer.events_since(mark, &["central-params"]).is_empty() {
            eprintln!("the pad's parameter request on the reconnect went unanswered");
        }
        let timeouts = supervision_timeouts(&peer, 0);
        // At least the two connections we made, each with our 500 ms.
        assert!(timeouts.len() >= 2, "{timeouts:?}");
        assert!(timeouts.iter().all(|t| t == "500"), "{timeouts:?}");
    });
}

#[test]
fn a_pad_that_fails_to_pair_inside_the_window_is_retried_with_a_back_off() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        peer.cmd(&format!("pad pad {PAD_ADDRESS}")).await;
        peer.cmd("refuse pad").await;
        peer.cmd("advertise pad").await;
        let mark = peer.mark();
        open_pairing_window(pc).await;
        peer.wait_for(mark, &["pairing-refused", "pad"], 10_000)
            .await;
        let attempts = connect_attempts(&peer, 3_000).await;
        assert!(attempts <= 3, "{attempts} connection attempts in 3 s");
        assert!(!pc.status().expect("status").flags.remote_bonded);
    });
}

/// The packets that crashed trouble-host 0.8 before the guard: (what, when the
/// attacker sends it, L2CAP channel, payload in hex). `connect`: as soon as the robot
/// connected it; `key-missing`: right after it answered the robot's bonded encryption
/// without the key.
const CRASH_TRIGGERS: [(&str, &str, u16, &str); 7] = [
    ("an empty ATT PDU", "connect", 4, "-"),
    ("Exchange MTU Request without the MTU", "connect", 4, "02"),
    ("Read Request with a 1-byte handle", "connect", 4, "0a01"),
    (
        "an Error Response without its error code",
        "connect",
        4,
        "010a0000",
    ),
    ("Write Command without a handle", "connect", 4, "52"),
    (
        "L2CAP Disconnection Request for channel 0",
        "connect",
        5,
        // Code 6, identifier 1, length 4, destination channel 0, source 0x0040.
        "0601040000004000",
    ),
    (
        "key missing, then a Security Request without MITM",
        "key-missing",
        6,
        "0b01",
    ),
];

/// Lets pad `name` send `payload` on `channel` at `when` on its next link, and waits
/// until it did and the robot closed that link.
async fn attack_once(peer: &mut Peer, name: &str, when: &str, channel: u16, payload: &str) {
    let mark = arm_attack(peer, name, when, channel, payload).await;
    attack_done(peer, mark, name).await;
}

/// Arms the pad `name` to send `payload` on `channel` at `when`; the mark to wait from.
async fn arm_attack(peer: &mut Peer, name: &str, when: &str, channel: u16, payload: &str) -> usize {
    let mark = peer.mark();
    peer.cmd(&format!("attack {name} {when} {channel} {payload}"))
        .await;
    mark
}

/// Waits until the armed attack was sent and the controller dropped the link, then
/// disarms the pad.
async fn attack_done(peer: &mut Peer, mark: usize, name: &str) {
    peer.wait_for(mark, &["attacked", name], 15_000).await;
    peer.wait_for(mark, &["disconnected", name], 5_000).await;
    peer.cmd(&format!("peace {name}")).await;
}

/// The owner's pad, away during an attack at its address, comes back: it must be
/// encrypted with the bond within 2 s of the attacker's leaving, and drive.
async fn owner_is_back_within_2_s(peer: &mut Peer, robot: &RemoteRobot, pc: &Pc, attacker: &str) {
    let mark = peer.mark();
    let attack_ended = Instant::now();
    peer.cmd(&format!("remove {attacker}")).await;
    peer.cmd("back pad").await;
    peer.cmd("advertise pad").await;
    let back = peer
        .wait_for(mark, &["encrypted", "pad", "1"], 10_000)
        .await;
    let after = back.at - attack_ended;
    eprintln!("owner encrypted again {after:?} after the attack ended");
    assert!(
        after <= Duration::from_secs(2),
        "owner back after {after:?}"
    );
    peer.wait_for(mark, &["subscribed", "pad"], 10_000).await;
    assert!(peer.events_since(mark, &["pairing-started"]).is_empty());
    drive_forward(peer, robot, pc).await;
}

#[test]
fn crash_triggers_from_an_impostor_are_refused_and_the_owner_drives_afterwards() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        let bond = robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32);
        peer.cmd("away pad").await;
        status(pc, 3_000, "the pad is gone", |s| !s.flags.remote_connected).await;
        peer.cmd(&format!("pad impostor {PAD_ADDRESS}")).await;
        peer.cmd("advertise impostor").await;
        for (what, when, channel, payload) in CRASH_TRIGGERS {
            eprintln!("impostor sends {what}");
            attack_once(&mut peer, "impostor", when, channel, payload).await;
            // The controller runs on (a panic in the host would have ended the test).
            status(pc, 1_000, "the controller still reports", |s| {
                s.flags.remote_bonded && !s.flags.remote_connected
            })
            .await;
        }
        assert!(peer.events_since(0, &["subscribed", "impostor"]).is_empty());
        assert_eq!(bond, robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32));
        owner_is_back_within_2_s(&mut peer, &robot, pc, "impostor").await;
    });
}

#[test]
fn crash_triggers_from_a_pad_in_the_pairing_window_are_refused_and_the_owner_pairs_afterwards() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        peer.cmd(&format!("pad intruder {OTHER_PAD_ADDRESS}")).await;
        open_pairing_window(pc).await;
        // Inside the window nothing is encrypted with a bond, so there is no key to
        // miss: every trigger that comes on connection. The intruder advertises only
        // once its first attack is armed: in the window the controller connects at
        // once, and a connection before the arming would just pair.
        let mut advertising = false;
        for (what, _, channel, payload) in CRASH_TRIGGERS
            .into_iter()
            .filter(|(_, when, _, _)| *when == "connect")
        {
            eprintln!("a pad in the window sends {what}");
            let mark = arm_attack(&mut peer, "intruder", "connect", channel, payload).await;
            if !advertising {
                peer.cmd("advertise intruder").await;
                advertising = true;
            }
            attack_done(&mut peer, mark, "intruder").await;
            status(pc, 1_000, "the controller still reports", |s| {
                !s.flags.remote_bonded
            })
            .await;
        }
        assert!(peer.events_since(0, &["paired", "intruder"]).is_empty());
        peer.cmd("remove intruder").await;
        // The window is still open: the owner's pad pairs and drives.
        let mark = peer.mark();
        peer.cmd(&format!("pad pad {PAD_ADDRESS}")).await;
        peer.cmd("advertise pad").await;
        peer.wait_for(mark, &["subscribed", "pad"], 20_000).await;
        drive_forward(&mut peer, &robot, pc).await;
    });
    assert!(bond_stored_for(&robot, PAD_ADDRESS));
}

#[test]
fn security_requests_and_pairing_from_an_impostor_never_pair_and_the_bond_stays() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
        let bond = robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32);
        peer.cmd("away pad").await;
        status(pc, 3_000, "the pad is gone", |s| !s.flags.remote_connected).await;
        peer.cmd(&format!("pad impostor {PAD_ADDRESS}")).await;
        peer.cmd("advertise impostor").await;
        let mark = peer.mark();
        for (what, payload) in [
            ("Security Request, bonding + MITM + SC", "0b0d"),
            ("Security Request, MITM + SC", "0b0c"),
            ("Security Request, bonding + MITM, legacy", "0b05"),
            ("Pairing Request, legacy Just Works", "01030001100707"),
            ("Pairing Request, Secure Connections", "0103000d100707"),
        ] {
            eprintln!("impostor sends {what}");
            attack_once(&mut peer, "impostor", "connect", 6, payload).await;
        }
        assert!(peer.events_since(mark, &["pairing-started"]).is_empty());
        assert!(peer.events_since(mark, &["paired"]).is_empty());
        assert!(
            peer.events_since(mark, &["central-pairing-request"])
                .is_empty()
        );
        assert_eq!(bond, robot.bond_flash.contents(0..BOND_FLASH_SIZE as u32));
        owner_is_back_within_2_s(&mut peer, &robot, pc, "impostor").await;
    });
}

#[test]
fn after_three_panics_soon_after_boot_bluetooth_stays_off_and_the_key_brings_the_bonded_pad_back() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", PAD_ADDRESS).await;
    });
    // Three boots that each die within 0.2 s, as with the attacker in range.
    for _ in 0..3 {
        robot.robot.until_panic(|| {
            robot.run(peer.controller(), async |_pc| {
                Timer::after_millis(150).await;
                controller_panics()
            })
        });
    }
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the drives are set up", |s| {
            s.mode != Mode::Starting
        })
        .await;
        assert_eq!(pc.read_register(Reg::BluetoothOff as u8).await, Some(1));
        peer.wait_for(0, &["disconnected", "pad"], 5_000).await;
        let mark = peer.mark();
        peer.cmd("advertise pad").await;
        // The robot PC drives as always.
        let driving = async {
            pc.drive(300, 0, 1_500).await;
            pc.drive(0, 0, 500).await;
        };
        join(driving, wheels(&robot, 1_500, true)).await;
        wheels(&robot, 3_000, false).await;
        // The bonded pad advertises all along, and the radio stays untouched.
        assert!(peer.events_since(mark, &["central-scan"]).is_empty());
        assert!(peer.events_since(mark, &["central-connect"]).is_empty());
        assert!(!pc.status().expect("status").flags.remote_connected);
        write_register(pc, Reg::Command, BLUETOOTH_ON_KEY);
        peer.wait_for(mark, &["encrypted", "pad", "1"], 10_000)
            .await;
        status(pc, 3_000, "the pad is back", |s| s.flags.remote_connected).await;
        assert_eq!(pc.read_register(Reg::BluetoothOff as u8).await, Some(0));
        drive_forward(&mut peer, &robot, pc).await;
    });
    assert_eq!(robot.robot.rtc_ram.short_panics(), 0);
}
