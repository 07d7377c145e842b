"""The command path at a planner's rate: a speed that changes every 20 ms never trips
the drives' communication timeout, never faults the base, and every position frame
carries a fresh measurement (no repeat, no jump)."""
import threading
import time

import protocol as p

# A planner's output: a new speed in every frame.
SPEEDS = (200, 260, 300, 240)
PERIOD = 0.02


def stream_changing_speeds(base, seconds):
    """Sends the enable and a new speed every 20 ms for `seconds` in the background;
    returns the thread."""
    def send():
        end = time.monotonic() + seconds
        frame = 0
        while time.monotonic() < end:
            base.send(p.enable())
            base.send(p.velocity(SPEEDS[frame % len(SPEEDS)], 0))
            frame += 1
            time.sleep(PERIOD)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    return sender


def test_speeds_changing_every_20_ms_keep_the_positions_fresh_and_the_drives_happy(base):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        base.send(p.reset_odometry())
        time.sleep(0.2)
        sender = stream_changing_speeds(base, 6.0)
        # Up to speed first, then five seconds of frames.
        time.sleep(1.0)
        frames = base.collect(4.5)
        sender.join()
        base.send(p.velocity(0, 0))
        # Long after the last frame the drives still hear the controller: the base
        # drives again at once, and no drive raised its communication timeout.
        time.sleep(1.5)
        before = base.position()
        base.send(p.velocity(200, 0))
        time.sleep(1.0)
        moved = base.position().x_mm - before.x_mm
        base.send(p.velocity(0, 0))
        after = base.status()

    positions = [p.parse_position(data).x_mm for _, frame_id, data in frames
                 if frame_id == p.POSITION]
    statuses = [p.parse_status(data) for _, frame_id, data in frames if frame_id == p.STATUS]
    assert len(positions) > 60, f"{len(positions)} position frames in 4.5 s"
    steps = [b - a for a, b in zip(positions, positions[1:])]
    # At 200..300 mm/s every 50 ms frame moves 10..15 mm: a repeat is a stale frame, a
    # step beyond 22 mm one that swallowed another's motion.
    assert all(step > 0 for step in steps), f"repeated positions: {steps}"
    assert max(steps) <= 22, f"jumps: {steps}"
    assert statuses and all(status.mode == "Active" for status in statuses)
    assert all(status.drive_alarm == 0 for status in statuses)
    assert after.mode != "Fault" and after.drive_alarm == 0
    assert moved > 100, f"{moved} mm in 1 s at 200 mm/s after the stream"


def test_the_e_stop_stops_the_base_within_what_estop_decel_allows(base, operator):
    """The e-stop's zero goes to both drives by one short broadcast within 8 ms of the
    edge, with `estop_decel`: from 300 mm/s (about 200 r/min at the motor) 4500
    (r/min)/s stops the wheels in 45 ms, about 7 mm, plus 2.4 mm for the 8 ms. The
    e-stop circuit cuts the drives' power about 300 ms after the press: a zero that
    never came, or a drive braking with its own slow ramp, rolls up to 90 mm."""
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        base.send(p.reset_odometry())
        time.sleep(0.2)
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            base.send(p.velocity(300, 0))
            time.sleep(PERIOD)
        # The last pose before the press is at most one 50 ms frame old: 15 mm.
        before = base.position()
        operator.press_estop()
        base.wait_for_mode("Emergency", timeout=5)
        time.sleep(1.0)
        operator.release_estop()
        base.wait_for_mode("AwaitingConfirm", timeout=5)
        operator.confirm()
        base.wait_for_mode("Standby", timeout=15)
        after = base.position()
        status = base.status()
    rolled = after.x_mm - before.x_mm
    assert 0 <= rolled <= 40, f"rolled {rolled} mm after the e-stop from 300 mm/s"
    assert status.drive_alarm == 0
