//! Latency figures of the running firmware on the virtual robot (virtual time, Modbus
//! bytes timed at the configured 115200 baud, 8E1):
//!
//! - CAN velocity frame → both drives have the new speed (the base is driving);
//! - e-stop edge → zero speed on the wire.
//!
//! Each is measured at many phases of the control cycle. Run with
//! `cargo run -p virtual-robot --example latency`.

use embassy_time::{Duration, Instant, Timer};
use virtual_robot::robot::{VirtualRobot, wait_ms};

/// Phases spread over one 50 ms control cycle.
const TRIALS: u64 = 50;

fn main() {
    let robot = VirtualRobot::new();
    let (velocity, estop) = robot.run(async |pc| {
        wait_ms(1_500).await;
        pc.drive(300, 0, 500).await;
        let mut velocity = Vec::new();
        for trial in 0..TRIALS {
            let speed = if trial % 2 == 0 { 400 } else { 300 };
            pc.enable();
            let sent = Instant::now();
            pc.velocity(speed, 0);
            // Longer than a cycle, and 1 ms more each trial: the next command lands
            // at a new phase of the drive link's own 50 ms cycle, sometimes while its
            // transaction is on the wire.
            Timer::after(Duration::from_millis(50) + Duration::from_micros(trial * 1_000)).await;
            let applied =
                [1, 2].map(|slave| robot.drives.drive(slave).last_new_speed_at.expect("speed"));
            velocity.push(applied.into_iter().max().expect("two drives") - sent);
        }

        let mut estop = Vec::new();
        for trial in 0..TRIALS / 2 {
            pc.drive(300, 0, 300).await;
            Timer::after(Duration::from_micros(trial * 2_000)).await;
            let pressed = Instant::now();
            robot.press_estop();
            wait_ms(60).await;
            let stopped =
                [1, 2].map(|slave| robot.drives.drive(slave).last_new_speed_at.expect("speed"));
            estop.push(stopped.into_iter().max().expect("two drives") - pressed);
            robot.release_estop();
            wait_ms(100).await;
            robot.press_button(200).await;
            wait_ms(800).await;
        }
        (velocity, estop)
    });
    report(
        "CAN velocity frame → both drives have the new speed",
        &velocity,
    );
    report("e-stop edge → zero speed on the wire", &estop);
}

fn report(what: &str, samples: &[Duration]) {
    let ms = |d: Duration| d.as_micros() as f64 / 1000.0;
    let min = samples.iter().copied().min().expect("samples");
    let max = samples.iter().copied().max().expect("samples");
    let mean = samples.iter().map(|&d| ms(d)).sum::<f64>() / samples.len() as f64;
    println!(
        "{what}: min {:.1} ms, mean {mean:.1} ms, max {:.1} ms ({} samples)",
        ms(min),
        ms(max),
        samples.len()
    );
}
