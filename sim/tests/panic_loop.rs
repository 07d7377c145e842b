//! No reboot loop, on the virtual clock: the firmware's tasks with the Bluetooth remote
//! (trouble-host on the simulator's scripted controller, `virtual_robot::fake_hci`),
//! booted again and again on one robot whose RTC RAM survives each reset, as the
//! chip's does. The controller panics where the test says (on the chip: a packet that
//! crashes the Bluetooth stack, every boot, while the attacker stays in range).
//!
//! The fake controller connects the pad it advertises as soon as the host asks, so with
//! the pairing window open a running remote task shows up in its counts at once; a
//! remote that never started sent it no HCI command at all.

use base_core::can::Command;
use base_core::panic_loop::SHORT_LIFE_MS;
use base_core::registers::{BLUETOOTH_ON_KEY, OPEN_PAIRING_WINDOW_KEY, Reg};
use embassy_time::{Duration, Instant};
use virtual_robot::ble::RemoteRobot;
use virtual_robot::fake_hci::{FakeHandle, fake_controller};
use virtual_robot::robot::{Pc, controller_panics, wait_ms};

/// One boot that panics `uptime_ms` after it started.
fn boot_and_panic_after(robot: &RemoteRobot, uptime_ms: u64) {
    let (controller, _fake) = fake_controller();
    robot.robot.until_panic(|| {
        robot.run_virtual(controller, async |_pc| {
            wait_ms(uptime_ms).await;
            controller_panics()
        })
    });
}

fn write_register(pc: &Pc, reg: Reg, value: u16) {
    pc.command(Command::RegisterWrite {
        address: reg as u8,
        value,
    });
}

/// `bluetooth_off` (36) as the robot PC reads it.
async fn bluetooth_off(pc: &Pc) -> Option<u16> {
    pc.read_register(Reg::BluetoothOff as u8).await
}

/// Waits up to `timeout_ms` until the remote task connected the fake's pad.
async fn pad_connected(fake: &FakeHandle, timeout_ms: u64) -> bool {
    let end = Instant::now() + Duration::from_millis(timeout_ms);
    while Instant::now() < end {
        if fake.stats().connections > 0 {
            return true;
        }
        wait_ms(10).await;
    }
    false
}

/// The PC drives forward for 1.5 s; whether both wheels turned forward.
async fn can_drives_the_base(robot: &RemoteRobot, pc: &Pc) -> bool {
    pc.drive(300, 0, 1_500).await;
    let turning = [1, 2].map(|drive| robot.robot.drives.drive(drive).forward_rpm());
    pc.drive(0, 0, 1_000).await;
    turning.iter().all(|rpm| *rpm > 10.0)
}

#[test]
fn three_panics_soon_after_boot_switch_bluetooth_off_and_the_key_turns_it_on_without_a_reboot() {
    let robot = RemoteRobot::new();
    // Every boot died within 0.12 to 0.2 s while the attacker was in range.
    for uptime_ms in [120, 200, 150] {
        boot_and_panic_after(&robot, uptime_ms);
    }
    let (controller, fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(2_000).await; // the drives are set up
        assert_eq!(bluetooth_off(pc).await, Some(1));
        // A running remote would now scan and connect the fake's pad.
        write_register(pc, Reg::Command, OPEN_PAIRING_WINDOW_KEY);
        assert!(can_drives_the_base(&robot, pc).await, "CAN drives the base");
        assert!(!pad_connected(&fake, 2_000).await);
        assert_eq!(fake.stats().commands, 0, "nothing touched the radio");
        write_register(pc, Reg::Command, BLUETOOTH_ON_KEY);
        assert!(
            pad_connected(&fake, 3_000).await,
            "the remote starts, and sees the pairing window still open"
        );
        assert_eq!(bluetooth_off(pc).await, Some(0));
        assert!(
            can_drives_the_base(&robot, pc).await,
            "and CAN still drives"
        );
    });
    assert_eq!(
        robot.robot.rtc_ram.short_panics(),
        0,
        "turned on: forgotten"
    );
    let (controller, fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(500).await;
        assert_eq!(bluetooth_off(pc).await, Some(0));
        write_register(pc, Reg::Command, OPEN_PAIRING_WINDOW_KEY);
        assert!(pad_connected(&fake, 3_000).await, "on at the next boot");
    });
}

#[test]
fn a_confirm_press_turns_bluetooth_on_after_a_panic_loop() {
    let robot = RemoteRobot::new();
    for _ in 0..3 {
        boot_and_panic_after(&robot, 100);
    }
    let (controller, fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(2_000).await;
        write_register(pc, Reg::Command, OPEN_PAIRING_WINDOW_KEY);
        assert!(!pad_connected(&fake, 1_000).await);
        robot.robot.press_button(200).await;
        assert!(pad_connected(&fake, 3_000).await);
        assert_eq!(bluetooth_off(pc).await, Some(0));
    });
}

#[test]
fn a_panic_after_30_s_of_uptime_does_not_count() {
    let robot = RemoteRobot::new();
    // The third ran 30 s: it starts the count over, and the fourth is the first again.
    for uptime_ms in [100, 100, SHORT_LIFE_MS, 100, 100] {
        boot_and_panic_after(&robot, uptime_ms);
    }
    assert_eq!(robot.robot.rtc_ram.short_panics(), 2);
    let (controller, _fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(500).await;
        assert_eq!(bluetooth_off(pc).await, Some(0));
    });
    // One short of 30 s still counts.
    for uptime_ms in [100, 100, SHORT_LIFE_MS - 1] {
        boot_and_panic_after(&robot, uptime_ms);
    }
    let (controller, _fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(500).await;
        assert_eq!(bluetooth_off(pc).await, Some(1));
    });
}

#[test]
fn a_power_on_forgets_the_panics() {
    let robot = RemoteRobot::new();
    for _ in 0..3 {
        boot_and_panic_after(&robot, 100);
    }
    robot.robot.rtc_ram.power_on();
    let (controller, fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(500).await;
        assert_eq!(bluetooth_off(pc).await, Some(0));
        write_register(pc, Reg::Command, OPEN_PAIRING_WINDOW_KEY);
        assert!(pad_connected(&fake, 3_000).await);
    });
}

#[test]
fn a_reset_that_is_no_panic_forgets_the_panics() {
    let robot = RemoteRobot::new();
    for _ in 0..2 {
        boot_and_panic_after(&robot, 100);
    }
    // A boot that ends without a panic: the reset button, a watchdog, flashing.
    let (controller, _fake) = fake_controller();
    robot.run_virtual(controller, async |_pc| wait_ms(100).await);
    boot_and_panic_after(&robot, 100);
    let (controller, _fake) = fake_controller();
    robot.run_virtual(controller, async |pc| {
        wait_ms(500).await;
        assert_eq!(bluetooth_off(pc).await, Some(0), "two and one are no loop");
    });
}
