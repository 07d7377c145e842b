//! The PlayStation pads end to end: the firmware's Classic host (`base-bluetooth`, in
//! `base_runtime::classic`) and its BLE host share one HCI transport (H4 over TCP)
//! through the HCI splitter, to Google Bumble's virtual controllers, where a virtual
//! DualShock 4 or DualSense (sim/ble-peer/classic_pads.py) streams its reports over
//! Bluetooth Classic. The pad drives the virtual robot.
//!
//! As the BLE scenarios: each starts its own peer, one at a time on the wall clock;
//! without Bumble they are skipped with a message, except in CI (CI=true).

#[path = "ble/common.rs"]
mod common;
#[path = "ble/peer.rs"]
mod peer;

use std::time::{Duration, Instant};

use base_core::can::Mode;
use base_core::registers::{Charge, Reg, RemoteBattery, RemoteInfo, RemoteKind};
use common::{
    bond_stored_for, drives_ready, last_decel, open_pairing_window, scenario, status, wheels,
    write_register,
};
use embassy_time::Timer;
use peer::Peer;
use virtual_robot::ble::RemoteRobot;
use virtual_robot::robot::Pc;

/// The pads' public addresses (Sony's prefix).
const PAD_ADDRESS: &str = "A4:AE:12:00:00:01";
const STRANGER_ADDRESS: &str = "A4:AE:12:00:00:02";
/// A BLE pad's random static address (the scenarios with a BLE pad beside a
/// PlayStation pad).
const BLE_PAD_ADDRESS: &str = "C1:11:22:33:44:55";

/// Creates PlayStation pad `name` of `kind` (ds4, dualsense), puts it in pairing mode,
/// opens the pairing window and waits until it is paired, streaming full reports and
/// counted as connected. Returns how long the pairing took from the window's opening.
async fn pair(peer: &mut Peer, pc: &Pc, name: &str, kind: &str, address: &str) -> Duration {
    peer.cmd(&format!("ps {name} {kind} {address}")).await;
    let mark = peer.mark();
    peer.cmd(&format!("pairing {name}")).await;
    drives_ready(pc).await;
    let opened = Instant::now();
    open_pairing_window(pc).await;
    peer.wait_for(mark, &["paired", name], 20_000).await;
    peer.wait_for(mark, &["feature-read", name, "0x05"], 10_000)
        .await;
    status(pc, 5_000, "the paired pad is connected", |s| {
        s.flags.remote_bonded && s.flags.remote_connected
    })
    .await;
    opened.elapsed()
}

/// Holds the dead-man (R1) and waits until the controller hands control to the remote.
async fn take_control(peer: &mut Peer, pc: &Pc, name: &str) {
    drives_ready(pc).await;
    peer.cmd(&format!("release {name} R1")).await;
    Timer::after_millis(50).await;
    peer.cmd(&format!("press {name} R1")).await;
    status(pc, 2_000, "the dead-man gives the remote control", |s| {
        s.flags.remote_in_control
    })
    .await;
}

/// Switches a bonded pad on: it pages the robot until the robot answers (a real pad
/// pages for a while; the robot's page scan is on once its controller is set up).
async fn switch_on(peer: &mut Peer, name: &str) {
    for _ in 0..3 {
        let mark = peer.mark();
        peer.cmd(&format!("on {name}")).await;
        let deadline = Instant::now() + Duration::from_secs(12);
        while Instant::now() < deadline {
            if !peer
                .events_since(mark, &["encrypted", name, "1"])
                .is_empty()
            {
                return;
            }
            if !peer.events_since(mark, &["page-failed", name]).is_empty() {
                break;
            }
            Timer::after_millis(10).await;
        }
    }
    panic!("the robot never answered {name}'s page");
}

/// Pulls the left stick forward with the dead-man held: the robot drives.
async fn drive_forward(peer: &mut Peer, robot: &RemoteRobot, pc: &Pc, name: &str) {
    take_control(peer, pc, name).await;
    peer.cmd(&format!("stick {name} LY 1.0")).await;
    wheels(robot, 3_000, true).await;
}

/// When the drives were last told to stand still (zero speed on the wire), waiting
/// up to `timeout_ms` for it.
async fn zero_on_the_wire(robot: &RemoteRobot, timeout_ms: u64) -> Instant {
    let deadline = Instant::now() + Duration::from_millis(timeout_ms);
    loop {
        let commanded = robot.robot.drives.drive(1).command;
        if commanded.is_some_and(|command| command.speed_rpm == 0) {
            return Instant::now();
        }
        assert!(
            Instant::now() < deadline,
            "no zero speed on the wire within {timeout_ms} ms: {commanded:?}"
        );
        Timer::after_millis(1).await;
    }
}

/// A value of `Contr_acc_high` no other rule uses, to recognise its braking.
const RELEASE_BRAKING: u16 = 2777;

#[test]
fn a_dualshock4_pairs_in_the_window_drives_with_r1_held_and_release_stops() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        let before = status(pc, 5_000, "the controller is up", |_| true).await;
        assert!(!before.flags.remote_bonded, "no bond on a blank flash");
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        let took = pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        eprintln!("classic pairing (window opened to connected): {took:?}");
        take_control(&mut peer, pc, "pad").await;
        // Stick forward → the first non-zero speed on the wire: the peer's command, the
        // next report (every 4 ms), the splitter, the host, the controller's cycle.
        let pushed_at = Instant::now();
        peer.cmd("stick pad LY 1.0").await;
        let deadline = pushed_at + Duration::from_secs(2);
        while robot
            .robot
            .drives
            .drive(1)
            .command
            .is_none_or(|c| c.speed_rpm == 0)
        {
            assert!(
                Instant::now() < deadline,
                "the stick never reached the drives"
            );
            Timer::after_millis(1).await;
        }
        eprintln!(
            "classic stick to speed on the wire: {:?}",
            pushed_at.elapsed()
        );
        wheels(&robot, 3_000, true).await;
        peer.cmd("release pad R1").await;
        wheels(&robot, 3_000, false).await;
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
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
        "the link key is in the bonds partition"
    );
}

#[test]
fn link_loss_with_r1_held_stops_within_the_supervision_timeout() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        drive_forward(&mut peer, &robot, pc, "pad").await;
        let mark = peer.mark();
        let lost_at = Instant::now();
        // Out of range: the dead-man stays held, nothing passes any more. The pad's
        // stream stops with the link, so the silence watchdog may see it first.
        peer.cmd("lose pad").await;
        let zero = zero_on_the_wire(&robot, 2_000).await;
        let stopped_after = zero - lost_at;
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
        status(pc, 2_000, "the lost link is reported", |s| {
            !s.flags.remote_connected && !s.flags.remote_in_control
        })
        .await;
        // The supervision timeout the host set as central is the one played out.
        let lost = peer.wait_for(mark, &["lost", "pad"], 3_000).await;
        assert_eq!(lost.words[2], "500", "supervision timeout in ms");
        assert!(
            stopped_after < Duration::from_millis(600),
            "{stopped_after:?}"
        );
        eprintln!("classic link loss to zero on the wire: {stopped_after:?}");
    });
}

#[test]
fn a_silent_pad_stops_the_base_within_the_report_watchdog() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        drive_forward(&mut peer, &robot, pc, "pad").await;
        let mark = peer.mark();
        let silent_at = Instant::now();
        // The link stays up; the reports stop (a hung pad).
        peer.cmd("silent pad").await;
        let zero = zero_on_the_wire(&robot, 2_000).await;
        let stopped_after = zero - silent_at;
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
        // 100 ms of silence, a 10 ms tick, the controller's cycle.
        assert!(
            stopped_after < Duration::from_millis(250),
            "{stopped_after:?}"
        );
        eprintln!("classic report silence to zero on the wire: {stopped_after:?}");
        // The silent link is dropped.
        peer.wait_for(mark, &["disconnected", "pad"], 3_000).await;
        status(pc, 2_000, "the link is reported down", |s| {
            !s.flags.remote_connected
        })
        .await;
    });
}

#[test]
fn the_bonded_pad_reconnects_by_its_page_also_after_a_reboot_without_pairing() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        // Switched off and on: the pad pages the robot.
        peer.cmd("off pad").await;
        status(pc, 3_000, "the switch-off is reported", |s| {
            !s.flags.remote_connected
        })
        .await;
        let mark = peer.mark();
        let on_at = Instant::now();
        peer.cmd("on pad").await;
        peer.wait_for(mark, &["encrypted", "pad", "1"], 10_000)
            .await;
        status(pc, 5_000, "the pad is back", |s| s.flags.remote_connected).await;
        eprintln!(
            "classic reconnect (pad on to connected): {:?}",
            on_at.elapsed()
        );
        assert!(
            peer.events_since(mark, &["paired"]).is_empty(),
            "a bonded pad is not paired again"
        );
        // The ESP32's dual-mode vendor event after the authentication by link key went
        // to the robot (the splitter hands vendor events to the BLE host, which ignores
        // them); the Classic link runs on and the pad drives.
        assert!(
            !peer.events_since(mark, &["vendor-legacy-auth"]).is_empty(),
            "the controller reported the legacy authentication"
        );
        take_control(&mut peer, pc, "pad").await;
        // At rest before the power goes, so that the next boot finds the drives well.
        peer.cmd("release pad R1").await;
        status(pc, 5_000, "the brakes close", |s| s.flags.brakes_applied).await;
    });
    // The chip lost power; it boots with the key from flash.
    let mark = peer.mark();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the bond came back from flash", |s| {
            s.flags.remote_bonded
        })
        .await;
        peer.wait_for(0, &["disconnected", "pad"], 5_000).await;
        switch_on(&mut peer, "pad").await;
        status(pc, 5_000, "the pad is back", |s| s.flags.remote_connected).await;
        assert!(peer.events_since(mark, &["paired"]).is_empty());
        take_control(&mut peer, pc, "pad").await;
    });
}

#[test]
fn a_stranger_outside_the_window_and_an_impostor_at_the_bonded_address_are_refused() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        peer.cmd("off pad").await;
        status(pc, 3_000, "the switch-off is reported", |s| {
            !s.flags.remote_connected
        })
        .await;
        // A pad nobody paired pages the robot: rejected at once, by its address.
        peer.cmd(&format!("ps stranger ds4 {STRANGER_ADDRESS}"))
            .await;
        let mark = peer.mark();
        peer.cmd("on stranger 00:B0:75:00:00:01").await;
        peer.wait_for(mark, &["page-failed", "stranger"], 10_000)
            .await;
        assert!(
            peer.events_since(mark, &["connected", "stranger"])
                .is_empty()
        );
        // The bonded address without the key (an impostor, or a pad reset): the link
        // comes up, fails to authenticate, is dropped and never paired.
        peer.cmd("forget pad").await;
        let mark = peer.mark();
        peer.cmd("on pad").await;
        peer.wait_for(mark, &["classic-key-mismatch"], 10_000).await;
        peer.wait_for(mark, &["disconnected", "pad"], 10_000).await;
        Timer::after_millis(500).await;
        assert!(
            peer.events_since(mark, &["paired"]).is_empty(),
            "no pairing outside the window"
        );
        assert!(
            peer.events_since(mark, &["encrypted", "pad", "1"])
                .is_empty()
        );
        let now = status(pc, 1_000, "the controller answers", |_| true).await;
        assert!(!now.flags.remote_connected && now.flags.remote_bonded);
    });
}

#[test]
fn a_dualsense_pairs_and_drives_and_l2_with_ps_switches_it_off() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        let mark = peer.mark();
        pair(&mut peer, pc, "pad", "dualsense", PAD_ADDRESS).await;
        // Its light bar (at other offsets than the DualShock 4's) shows the base ready.
        light_bar(&peer, mark, "pad", GREEN, 2_000).await;
        let kind = pc.read_register(Reg::RemoteKind.address()).await;
        assert_eq!(kind, Some(RemoteKind::DualSense.code()));
        drive_forward(&mut peer, &robot, pc, "pad").await;
        peer.cmd("release pad R1").await;
        peer.cmd("stick pad LY 0").await;
        wheels(&robot, 3_000, false).await;
        let mark = peer.mark();
        peer.cmd("trigger pad L2 1.0").await;
        Timer::after_millis(50).await;
        peer.cmd("press pad PS").await;
        peer.wait_for(mark, &["disconnected", "pad"], 3_000).await;
        status(pc, 2_000, "the switch-off is reported", |s| {
            s.flags.remote_bonded && !s.flags.remote_connected
        })
        .await;
    });
}

#[test]
fn a_ble_pad_and_a_playstation_pad_bonded_in_turn_both_drive() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        // The BLE pad first (HID over GATT, its dead-man RB).
        peer.cmd(&format!("pad xbox {BLE_PAD_ADDRESS}")).await;
        let mark = peer.mark();
        peer.cmd("advertise xbox").await;
        open_pairing_window(pc).await;
        peer.wait_for(mark, &["paired", "xbox"], 20_000).await;
        peer.wait_for(mark, &["subscribed", "xbox"], 10_000).await;
        status(pc, 5_000, "the BLE pad is connected", |s| {
            s.flags.remote_connected
        })
        .await;
        peer.cmd("disconnect xbox").await;
        status(pc, 3_000, "the BLE pad is off", |s| {
            !s.flags.remote_connected
        })
        .await;
        // Then the PlayStation pad, in the next window.
        pair(&mut peer, pc, "ps", "ds4", PAD_ADDRESS).await;
        drive_forward(&mut peer, &robot, pc, "ps").await;
        peer.cmd("release ps R1").await;
        wheels(&robot, 3_000, false).await;
        peer.cmd("off ps").await;
        status(pc, 3_000, "the PlayStation pad is off", |s| {
            !s.flags.remote_connected
        })
        .await;
        // Each kind keeps its bond: the BLE pad comes back and drives too.
        let mark = peer.mark();
        peer.cmd("advertise xbox").await;
        peer.wait_for(mark, &["subscribed", "xbox"], 10_000).await;
        status(pc, 3_000, "the BLE pad is back", |s| {
            s.flags.remote_connected
        })
        .await;
        drives_ready(pc).await;
        peer.cmd("release xbox RB").await;
        peer.cmd("press xbox RB").await;
        status(pc, 2_000, "the BLE pad's dead-man gives it control", |s| {
            s.flags.remote_in_control
        })
        .await;
    });
    assert!(bond_stored_for(&robot, PAD_ADDRESS));
}

/// Waits up to 2 s until register `remote_kind` reads `kind`.
async fn remote_kind_becomes(pc: &Pc, kind: RemoteKind, what: &str) {
    let deadline = Instant::now() + Duration::from_secs(2);
    loop {
        let read = pc.read_register(Reg::RemoteKind.address()).await;
        if read == Some(kind.code()) {
            return;
        }
        assert!(Instant::now() < deadline, "{what}: read {read:?}");
        Timer::after_millis(20).await;
    }
}

/// No wheel turns for `ms`: the drives' commanded speed stays zero throughout.
async fn still_for(robot: &RemoteRobot, ms: u64, why: &str) {
    let end = Instant::now() + Duration::from_millis(ms);
    while Instant::now() < end {
        for slave in [1, 2] {
            let commanded = robot.robot.drives.drive(slave).command;
            assert!(
                commanded.is_none_or(|c| c.speed_rpm == 0),
                "{why}: drive {slave} commanded {commanded:?}"
            );
        }
        Timer::after_millis(5).await;
    }
}

#[test]
fn a_ble_pad_and_a_playstation_pad_connected_at_once_only_the_first_drives() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        // The PlayStation pad connects first: it is the pad in control.
        pair(&mut peer, pc, "ps", "ds4", PAD_ADDRESS).await;
        remote_kind_becomes(pc, RemoteKind::DualShock4, "the PlayStation pad").await;
        // The BLE pad is paired in the next window and stays connected beside it.
        peer.cmd(&format!("pad xbox {BLE_PAD_ADDRESS}")).await;
        let mark = peer.mark();
        peer.cmd("advertise xbox").await;
        open_pairing_window(pc).await;
        peer.wait_for(mark, &["subscribed", "xbox"], 20_000).await;
        remote_kind_becomes(pc, RemoteKind::DualShock4, "the pad in control shows").await;
        // The BLE pad's dead-man and stick do nothing.
        peer.cmd("release xbox RB").await;
        peer.cmd("press xbox RB").await;
        peer.cmd("stick xbox LY 1.0").await;
        still_for(&robot, 500, "the second pad drove").await;
        let now = status(pc, 2_000, "a fresh status", |_| true).await;
        assert!(!now.flags.remote_in_control, "the second pad took control");
        // The PlayStation pad drives; its release stops the base, whatever the BLE pad
        // still holds.
        drive_forward(&mut peer, &robot, pc, "ps").await;
        peer.cmd("release ps R1").await;
        wheels(&robot, 3_000, false).await;
        still_for(&robot, 1_000, "the second pad drove after the first let go").await;
        // The PlayStation pad is switched off: the BLE pad takes control, but its
        // dead-man, held since before, must be released first.
        peer.cmd("off ps").await;
        remote_kind_becomes(pc, RemoteKind::BlePad, "the BLE pad in control").await;
        peer.cmd("stick xbox LY 0.9").await;
        still_for(&robot, 500, "a dead-man held through the hand-over drove").await;
        peer.cmd("release xbox RB").await;
        peer.cmd("press xbox RB").await;
        wheels(&robot, 3_000, true).await;
    });
}

#[test]
fn a_streaming_pad_left_idle_is_switched_off() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        // The shortest AFK time the register takes.
        write_register(pc, Reg::PsAfkTime, 5_000);
        let mark = peer.mark();
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        // The pad streams all the time, but nothing changes: that is no input.
        let streaming = peer.wait_for(mark, &["streaming", "pad"], 0).await;
        let off = peer.wait_for(mark, &["disconnected", "pad"], 10_000).await;
        let idle = off.at - streaming.at;
        assert!(
            (Duration::from_millis(5_000)..Duration::from_millis(7_000)).contains(&idle),
            "switched off after {idle:?}"
        );
        // Remote user terminated connection: the robot closed the link.
        assert_eq!(off.words[2], "19");
    });
}

#[test]
fn a_pad_stuck_on_the_short_report_still_drives_and_is_asked_again() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        // A clone that answers feature report 0x05 but never leaves the short report.
        peer.cmd(&format!("ps pad ds4 {PAD_ADDRESS}")).await;
        peer.cmd("short pad").await;
        let mark = peer.mark();
        peer.cmd("pairing pad").await;
        open_pairing_window(pc).await;
        peer.wait_for(mark, &["paired", "pad"], 20_000).await;
        status(pc, 5_000, "the paired pad is connected", |s| {
            s.flags.remote_connected
        })
        .await;
        // The short report carries sticks and buttons: it drives.
        drive_forward(&mut peer, &robot, pc, "pad").await;
        peer.cmd("release pad R1").await;
        wheels(&robot, 3_000, false).await;
        // Asked again, once a second, a bounded number of times.
        Timer::after_millis(1_500).await;
        let asked = peer
            .events_since(mark, &["feature-read", "pad", "0x05"])
            .len();
        assert!((2..=5).contains(&asked), "asked {asked} times");
        assert_eq!(peer.cmd("state pad").await, "connected short");
    });
}

#[test]
fn reports_with_a_bad_crc_are_refused_and_stop_the_base_as_silence_does() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        status(pc, 5_000, "the controller is up", |_| true).await;
        write_register(pc, Reg::ContrAccHigh, RELEASE_BRAKING);
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        drive_forward(&mut peer, &robot, pc, "pad").await;
        let garbled_at = Instant::now();
        // The link stays and the stream goes on, but no report passes its CRC check.
        peer.cmd("garble pad").await;
        let zero = zero_on_the_wire(&robot, 2_000).await;
        let stopped_after = zero - garbled_at;
        assert_eq!(last_decel(&robot), i32::from(RELEASE_BRAKING));
        assert!(
            stopped_after < Duration::from_millis(250),
            "{stopped_after:?}"
        );
        eprintln!("classic bad-CRC stream to zero on the wire: {stopped_after:?}");
        status(pc, 2_000, "the link is reported down", |s| {
            !s.flags.remote_connected
        })
        .await;
    });
}

/// Waits for the pad's next light bar colour (`event lightbar NAME R G B`) since `mark`.
async fn light_bar(peer: &Peer, mark: usize, name: &str, rgb: [u8; 3], timeout_ms: u64) {
    let [r, g, b] = rgb.map(|value| value.to_string());
    peer.wait_for(mark, &["lightbar", name, &r, &g, &b], timeout_ms)
        .await;
}

/// Waits up to 2 s until registers `remote_kind` and `remote_battery` read `want`.
async fn remote_registers_become(pc: &Pc, want: (u16, u16), what: &str) {
    let deadline = Instant::now() + Duration::from_secs(2);
    loop {
        let read = (
            pc.read_register(Reg::RemoteKind.address()).await,
            pc.read_register(Reg::RemoteBattery.address()).await,
        );
        if read == (Some(want.0), Some(want.1)) {
            return;
        }
        assert!(Instant::now() < deadline, "{what}: read {read:?}");
        Timer::after_millis(20).await;
    }
}

const GREEN: [u8; 3] = [0, 255, 0];
const BLUE: [u8; 3] = [0, 0, 255];
const RED: [u8; 3] = [255, 0, 0];

#[test]
fn the_light_bar_is_green_when_ready_blue_with_r1_held_and_red_in_emergency() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        let mark = peer.mark();
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        light_bar(&peer, mark, "pad", GREEN, 2_000).await;
        let mark = peer.mark();
        take_control(&mut peer, pc, "pad").await;
        light_bar(&peer, mark, "pad", BLUE, 1_000).await;
        // What stops the base wins over the dead-man still held.
        let mark = peer.mark();
        let pressed = Instant::now();
        robot.robot.press_estop();
        light_bar(&peer, mark, "pad", RED, 1_000).await;
        eprintln!(
            "classic light bar (e-stop pressed → red on the pad): {:?}",
            pressed.elapsed()
        );
        // The status frame comes every `status_time` (1 s), so wait longer than that.
        status(pc, 2_000, "the e-stop is seen", |s| {
            s.mode == Mode::Emergency
        })
        .await;
        // No flood: the light is sent on change and refreshed every 5 s, so a second
        // of a steady mode with R1 held carries at most one report.
        Timer::after_millis(200).await;
        let mark = peer.mark();
        Timer::after_millis(1_000).await;
        let reports = peer.events_since(mark, &["lightbar", "pad"]).len();
        assert!(
            reports <= 1,
            "{reports} light bar reports in 1 s of a steady mode"
        );
    });
}

#[test]
fn kind_and_battery_registers_follow_the_connected_pad() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        let info = |kind: RemoteKind, percent: u8, charge: Charge| {
            RemoteInfo {
                kind,
                battery: Some(RemoteBattery { percent, charge }),
            }
            .registers()
        };
        remote_registers_become(
            pc,
            info(RemoteKind::DualShock4, 85, Charge::Discharging),
            "a DualShock 4 at 85 %",
        )
        .await;
        // On a cable, charging: the battery follows the pad.
        peer.cmd("battery pad 1A").await;
        remote_registers_become(
            pc,
            info(RemoteKind::DualShock4, 100, Charge::Charging),
            "the DualShock 4 charging",
        )
        .await;
        peer.cmd("off pad").await;
        remote_registers_become(
            pc,
            (RemoteKind::None.code(), 0),
            "no remote after switch-off",
        )
        .await;
    });
}

/// Pages the robot as `name` and waits for the outcome: `true` if the robot took the
/// link (and, without the key, dropped it after the failed authentication), `false`
/// if it rejected the page at once.
async fn page_is_taken(peer: &mut Peer, name: &str) -> bool {
    let mark = peer.mark();
    peer.cmd(&format!("on {name}")).await;
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        if !peer.events_since(mark, &["page-failed", name]).is_empty() {
            return false;
        }
        if !peer.events_since(mark, &["disconnected", name]).is_empty() {
            assert!(
                !peer
                    .events_since(mark, &["classic-key-mismatch"])
                    .is_empty(),
                "a link without the key ends in the failed authentication"
            );
            return true;
        }
        Timer::after_millis(10).await;
    }
    panic!("{name}'s page had no outcome within 10 s");
}

#[test]
fn after_each_failed_authentication_the_bonded_address_is_refused_for_1_s() {
    let Some(_one) = scenario() else { return };
    let mut peer = Peer::start();
    let robot = RemoteRobot::new();
    robot.run(peer.controller(), async |pc| {
        pair(&mut peer, pc, "pad", "ds4", PAD_ADDRESS).await;
        peer.cmd("off pad").await;
        status(pc, 3_000, "the switch-off is reported", |s| {
            !s.flags.remote_connected
        })
        .await;
        // The bonded address without the key: each link fails its authentication.
        peer.cmd("forget pad").await;
        let forgotten = peer.mark();
        assert!(page_is_taken(&mut peer, "pad").await, "the first page");
        let failed = Instant::now();
        // Within the first back-off (1 s) a page is rejected at once ...
        assert!(!page_is_taken(&mut peer, "pad").await, "a page 0 s after");
        assert!(failed.elapsed() < Duration::from_millis(800));
        // ... after it, taken (and failing again) ...
        let wait = Duration::from_millis(1_300).saturating_sub(failed.elapsed());
        Timer::after_millis(wait.as_millis() as u64).await;
        assert!(page_is_taken(&mut peer, "pad").await, "a page 1.3 s after");
        let failed_again = Instant::now();
        // ... and after the second failure the bonded address is again refused for
        // 1 s only (the host's own attempts back off longer): an impostor cannot
        // keep the owner out once it stops.
        assert!(
            !page_is_taken(&mut peer, "pad").await,
            "a page 0 s after the second"
        );
        assert!(failed_again.elapsed() < Duration::from_millis(800));
        let wait = Duration::from_millis(1_300).saturating_sub(failed_again.elapsed());
        Timer::after_millis(wait.as_millis() as u64).await;
        assert!(
            page_is_taken(&mut peer, "pad").await,
            "a page 1.3 s after the second"
        );
        assert!(
            peer.events_since(forgotten, &["encrypted", "pad"])
                .is_empty(),
            "no link without the key was ever encrypted"
        );
        assert!(peer.events_since(forgotten, &["paired"]).is_empty());
    });
}
