//! The firmware on the virtual robot, driving a short path by itself: what the robot
//! PC would send, and what the base controller reports back. Runs in virtual time, so
//! it finishes at once. `cargo run -p virtual-robot --example demo`
//!
//! The live simulator with an SLCAN endpoint for real PC software: `cargo run -p virtual-robot`.

use base_core::can::Mode;
use embassy_time::Instant;
use virtual_robot::robot::{Pc, VirtualRobot, wait_ms};

fn main() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(1_500).await;
        show(pc, "drives set up");
        for (what, linear, rotation, ms) in [
            ("forward 400 mm/s", 400, 0, 2_000),
            ("turn clockwise 800 mrad/s", 0, 800, 1_963),
            ("forward 400 mm/s", 400, 0, 1_000),
            ("arc 300 mm/s, 300 mrad/s", 300, 300, 2_000),
            ("stop", 0, 0, 1_000),
        ] {
            pc.drive(linear, rotation, ms).await;
            show(pc, what);
        }
        robot.press_estop();
        wait_ms(500).await;
        println!("e-stop pressed: the drives stopped, no feedback frames until the confirm press");
        robot.release_estop();
        robot.press_button(200).await;
        let status = pc
            .wait_for_status(3_000, |status| status.mode == Mode::Standby)
            .await;
        println!(
            "confirm pressed: back in {:?}",
            status.map(|status| status.mode)
        );
    });
}

fn show(pc: &Pc, what: &str) {
    let t = Instant::now().as_millis() as f64 / 1000.0;
    let (x, y) = pc.position().unwrap_or_default();
    let heading = pc.heading().unwrap_or_default();
    let mode = pc.status().map(|status| status.mode);
    println!("{t:6.2} s  {what:<28} x {x:5} mm  y {y:5} mm  heading {heading:5} mrad  {mode:?}");
}
