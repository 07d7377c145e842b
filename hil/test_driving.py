"""Driving over CAN: enable and velocity, odometry, the enable lapse."""
import time

import protocol as p


def drive(base, linear, rotation, seconds):
    base.send(p.velocity(linear, rotation))
    time.sleep(seconds)


def test_enable_and_velocity_move_the_base_forward_and_the_pose_follows(base):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        base.send(p.reset_odometry())
        time.sleep(0.2)
        start = base.position()
        drive(base, 300, 0, 2.0)
        moved = base.position()
        drive(base, 0, 0, 1.0)
    # 300 mm/s for 2 s, less the ramps and the brake release: clearly forward, straight.
    assert 300 < moved.x_mm - start.x_mm < 700
    assert abs(moved.y_mm - start.y_mm) < 20


def test_a_clockwise_command_turns_the_heading_positive(base):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        base.send(p.reset_odometry())
        time.sleep(0.2)
        drive(base, 0, 500, 1.5)
        base.flush()
        heading = p.parse_heading(base.wait_for(p.HEADING))
        drive(base, 0, 0, 1.0)
    assert heading > 200


def test_reset_odometry_sets_the_pose_to_zero(base):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        drive(base, 200, 0, 1.0)
        drive(base, 0, 0, 1.0)
        base.send(p.reset_odometry())
        time.sleep(0.2)
        position = base.position()
    assert (position.x_mm, position.y_mm) == (0, 0)


def test_the_base_stops_when_the_enable_lapses_and_stays_still_after_a_new_enable(base):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        drive(base, 300, 0, 1.0)
    # No more enables: it lapses after enable_timeout (500 ms) and the base brakes.
    time.sleep(1.5)
    stopped = base.position()
    time.sleep(0.5)
    assert base.position().x_mm == stopped.x_mm
    assert not base.status().enable_fresh
    # A fresh enable alone does not bring the old velocity back.
    with base.enabled():
        time.sleep(1.0)
        assert base.position().x_mm == stopped.x_mm


def test_a_controller_reset_while_driving_stops_the_base_and_it_boots_to_standby(base, operator):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        base.send(p.reset_odometry())
        drive(base, 300, 0, 1.5)
        before = base.position()
        assert before.x_mm > 200
        # The controller resets alone; the drives keep their power and their last
        # speed until the new boot holds them at zero. The enable goes on, as from a PC
        # that did not notice; the velocity is not sent again.
        base.flush()
        operator.reset_controller()
        base.wait_for_mode("Starting", timeout=5)
        base.wait_for_mode("Standby", timeout=15)
        # A fresh pose, and the base stands: nothing brings the old velocity back.
        stopped = base.position()
        assert abs(stopped.x_mm) < 100 and abs(stopped.y_mm) < 100, (before, stopped)
        time.sleep(1.0)
        assert base.position() == stopped
