//! Two pads at once, a BLE pad and a PlayStation pad, each behind its own remote task:
//! exactly one controls the base, the first connected (docs/behaviour.md, "Who may
//! move the base"). Their tasks are scripted here where they hand their links and
//! decoded reports to the controller, on the virtual clock, with the real controller
//! and drive link behind. (The same with the real tasks and virtual pads over
//! Bluetooth: the Classic scenario
//! `a_ble_pad_and_a_playstation_pad_connected_at_once_only_the_first_drives`.)

use base_core::gamepad::{Buttons, GamepadState};
use base_core::remote::Pad;
use embassy_time::{Duration, Instant};
use virtual_robot::robot::{ScriptedPads, VirtualRobot, wait_ms};

const BOOT_MS: u64 = 1_500;

fn held(forward: f32) -> GamepadState {
    GamepadState {
        left_y: forward,
        buttons: Buttons::RIGHT_BUMPER,
        ..GamepadState::default()
    }
}

fn released() -> GamepadState {
    GamepadState::default()
}

/// The left drive's commanded speed (r/min), 0 before any command.
fn left_rpm(robot: &VirtualRobot) -> i32 {
    robot.drives.drive(1).command.map_or(0, |c| c.speed_rpm)
}

/// Runs the firmware with the pads scripted, each report taken by the controller
/// before the script goes on.
fn run_with_two_pads<T>(robot: &VirtualRobot, script: impl AsyncFnOnce(&Pads<'_>) -> T) -> T {
    robot.run_with_pads(async |_pc, pads| script(&Pads(pads)).await)
}

struct Pads<'a>(&'a ScriptedPads<'a>);

impl Pads<'_> {
    async fn link(&self, pad: Pad, connected: bool) {
        self.0.link(pad, connected).await;
        wait_ms(1).await;
    }

    async fn report(&self, pad: Pad, state: GamepadState) {
        self.0.report(pad, state).await;
        wait_ms(1).await;
    }
}

/// The most the left wheel was commanded over `ms`, sampled every millisecond.
async fn most_rpm_over(robot: &VirtualRobot, ms: u64) -> i32 {
    let end = Instant::now() + Duration::from_millis(ms);
    let mut most = 0;
    while Instant::now() < end {
        most = most.max(left_rpm(robot).abs());
        wait_ms(1).await;
    }
    most
}

#[test]
fn the_second_pads_release_does_not_arm_the_first_pads_held_dead_man() {
    let robot = VirtualRobot::new();
    let most = run_with_two_pads(&robot, async |pads| {
        wait_ms(BOOT_MS).await;
        // Pad A (BLE) connects with its dead-man held and the stick forward: it was
        // never seen released, so it must not drive.
        pads.link(Pad::Ble, true).await;
        pads.report(Pad::Ble, held(1.0)).await;
        // Pad B (PlayStation) connects too, its dead-man up.
        pads.link(Pad::Classic, true).await;
        pads.report(Pad::Classic, released()).await;
        // A moves its stick a little, still holding the dead-man it never released.
        pads.report(Pad::Ble, held(0.9)).await;
        most_rpm_over(&robot, 500).await
    });
    assert_eq!(most, 0, "pad B's release armed pad A's held dead-man");
}

#[test]
fn the_pad_in_control_letting_go_stops_the_base_whatever_the_other_pad_holds() {
    let robot = VirtualRobot::new();
    let most = run_with_two_pads(&robot, async |pads| {
        wait_ms(BOOT_MS).await;
        // Pad A drives: released first, then held with the stick forward.
        pads.link(Pad::Ble, true).await;
        pads.report(Pad::Ble, released()).await;
        pads.report(Pad::Ble, held(1.0)).await;
        assert!(most_rpm_over(&robot, 300).await > 0, "pad A drives");
        // Pad B connects and holds its dead-man with the stick forward as well.
        pads.link(Pad::Classic, true).await;
        pads.report(Pad::Classic, released()).await;
        pads.report(Pad::Classic, held(1.0)).await;
        // A lets go: the base stops, and B's reports (a PlayStation pad streams every
        // 4 ms) must not start it again.
        pads.report(Pad::Ble, released()).await;
        wait_ms(1_000).await;
        let mut most = 0;
        for _ in 0..250 {
            pads.report(Pad::Classic, held(1.0)).await;
            wait_ms(3).await;
            most = most.max(left_rpm(&robot).abs());
        }
        most
    });
    assert_eq!(most, 0, "pad B drove after pad A, in control, let go");
}

#[test]
fn when_the_pad_in_control_leaves_the_other_takes_over_only_after_a_release() {
    let robot = VirtualRobot::new();
    let (stopped, held_after_handover, driven_after_release) =
        run_with_two_pads(&robot, async |pads| {
            wait_ms(BOOT_MS).await;
            pads.link(Pad::Classic, true).await;
            pads.report(Pad::Classic, released()).await;
            pads.report(Pad::Classic, held(1.0)).await;
            assert!(
                most_rpm_over(&robot, 300).await > 0,
                "the PlayStation pad drives"
            );
            // The BLE pad connects and holds its dead-man with the stick forward.
            pads.link(Pad::Ble, true).await;
            pads.report(Pad::Ble, released()).await;
            pads.report(Pad::Ble, held(1.0)).await;
            // The PlayStation pad's link drops: zero goes to the drives at once, as a
            // CAN stop does (at most 10 ms to the wire, docs/figures.md).
            pads.link(Pad::Classic, false).await;
            wait_ms(10).await;
            let stopped = left_rpm(&robot);
            // The BLE pad controls now, but its dead-man, held since before it took
            // over, was never seen released as the pad in control.
            pads.report(Pad::Ble, held(0.9)).await;
            let held_after_handover = most_rpm_over(&robot, 1_000).await;
            pads.report(Pad::Ble, released()).await;
            pads.report(Pad::Ble, held(1.0)).await;
            (
                stopped,
                held_after_handover,
                most_rpm_over(&robot, 300).await,
            )
        });
    assert_eq!(stopped, 0, "no zero on the wire 10 ms after the link-down");
    assert_eq!(
        held_after_handover, 0,
        "a held dead-man drove after the hand-over"
    );
    assert!(
        driven_after_release > 0,
        "released and held again, the BLE pad drives"
    );
}
