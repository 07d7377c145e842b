//! Registers that shape a stop (`estop_decel`, `stop_decel`, `enable_timeout`,
//! `cmd_timeout`, `Contr_acc_high`) written while the base moves are refused like the
//! motion registers (NotAtRest, 0x14), so no write can stretch a stop that is under
//! way or due. Before, they took effect at once: an `estop_decel` of 100 written at
//! 500 mm/s made the next e-stop roll for seconds.

use base_core::can::Command;
use base_core::registers::Reg;
use virtual_robot::robot::{Pc, VirtualRobot, wait_ms};

const BOOT_MS: u64 = 1_500;

fn wheel_mm(revolutions: f64) -> f64 {
    revolutions / 10.0 * 2.0 * std::f64::consts::PI * 142.0
}

fn write(pc: &Pc, reg: Reg, value: u16) {
    pc.command(Command::RegisterWrite {
        address: reg.address(),
        value,
    });
}

/// `estop_decel` 100 written at 500 mm/s, then the e-stop: the stop keeps 4500
/// (1/min)/s, 336 r/min to zero in 75 ms (about 20 mm, plus sampling and one
/// transaction). With the write in force it would roll 3.4 s, over 800 mm.
#[test]
fn an_estop_decel_written_while_driving_is_refused_and_the_estop_stops_as_before() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_000).await;
        write(pc, Reg::EstopDecel, 100);
        pc.drive(500, 0, 200).await;
        let refused = pc
            .wait_for_status(1_100, |status| {
                (status.last_rejection, status.last_rejection_subject)
                    == (0x14, Reg::EstopDecel.address())
            })
            .await;
        assert!(refused.is_some(), "the refusal is in the status frame");
        pc.drive(500, 0, 200).await;
        let before = robot.drives.drive(1).forward_revolutions();
        robot.press_estop();
        wait_ms(1_000).await;
        let rolled = wheel_mm(robot.drives.drive(1).forward_revolutions() - before);
        assert!(rolled <= 40.0, "rolled {rolled:.0} mm after the e-stop");
        assert_eq!(
            robot.drives.drive(1).command.map(|c| c.decel_rpm_per_s),
            Some(4_500)
        );
        assert_eq!(
            pc.read_register(Reg::EstopDecel.address()).await,
            Some(4_500)
        );
    });
}

/// `enable_timeout` 5000 written while driving, then the PC falls silent: the enable
/// still lapses after the 500 ms in force when the drive began.
#[test]
fn an_enable_timeout_raised_while_driving_does_not_let_a_silent_pc_drive_on() {
    let robot = VirtualRobot::new();
    let stood_after_ms = robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        pc.drive(500, 0, 1_000).await;
        write(pc, Reg::EnableTimeout, 5_000);
        pc.drive(500, 0, 100).await;
        // The PC stops sending: no enable, no velocity.
        let mut stood_after_ms = None;
        for t in 0..3_000u64 {
            wait_ms(1).await;
            if robot.drives.drive(1).forward_rpm().abs() < 0.5 {
                stood_after_ms = Some(t);
                break;
            }
        }
        stood_after_ms
    });
    let stood_after_ms = stood_after_ms.expect("the base stopped");
    // 500 ms enable_timeout, then 336 r/min braked with stop_decel (2000): 168 ms.
    assert!(
        stood_after_ms <= 800,
        "stood {stood_after_ms} ms after the last enable"
    );
}

/// Every stop-shaping register is refused while moving and accepted once the base
/// stands, with the value in force and read back.
#[test]
fn every_stop_shaping_register_is_refused_while_moving_and_accepted_at_rest() {
    let robot = VirtualRobot::new();
    robot.run(async |pc| {
        wait_ms(BOOT_MS).await;
        let writes = [
            (Reg::EnableTimeout, 1_000),
            (Reg::CmdTimeout, 300),
            (Reg::EstopDecel, 3_000),
            (Reg::StopDecel, 2_500),
            (Reg::ContrAccHigh, 800),
        ];
        pc.drive(300, 0, 1_000).await;
        for (reg, value) in writes {
            let default = reg.info().default;
            write(pc, reg, value);
            pc.drive(300, 0, 100).await;
            assert_eq!(
                pc.read_register(reg.address()).await,
                Some(default),
                "{reg:?} refused while driving"
            );
        }
        pc.enable();
        pc.velocity(0, 0);
        wait_ms(1_000).await;
        for (reg, value) in writes {
            write(pc, reg, value);
            wait_ms(20).await;
            assert_eq!(
                pc.read_register(reg.address()).await,
                Some(value),
                "{reg:?} accepted at rest"
            );
        }
    });
}
