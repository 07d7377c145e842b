"""Feedback frames: their periods, and none of them in an emergency."""
import statistics

import protocol as p


def periods(frames, arbitration_id):
    times = [t for t, frame_id, _ in frames if frame_id == arbitration_id]
    return [b - a for a, b in zip(times, times[1:])]


def test_position_and_heading_come_every_loop_end_delay(base):
    period_ms = base.read_register(p.REG_LOOP_END_DELAY).value
    frames = base.collect(3.0)
    for arbitration_id in (p.POSITION, p.HEADING):
        gaps = periods(frames, arbitration_id)
        assert len(gaps) > 3.0 / (period_ms / 1000) * 0.8
        # Mean within 10 % of the period; no gap longer than three periods.
        assert abs(statistics.mean(gaps) * 1000 - period_ms) < period_ms * 0.1
        assert max(gaps) * 1000 < 3 * period_ms


def test_each_pose_follows_its_time_and_speed_on_the_controllers_clock(base):
    """0x0EF and 0x0F0 just before every 0x0EC; the times a cycle apart on the
    controller's clock; the measured speed of a base at rest is zero."""
    period_ms = base.read_register(p.REG_LOOP_END_DELAY).value
    frames = base.collect(3.0)
    times = []
    for before, previous, frame in zip(frames, frames[1:], frames[2:]):
        if frame[1] == p.POSITION:
            order = (before[1], previous[1])
            assert order == (p.POSE_TIME, p.MEASURED_SPEED), \
                f"0x{order[0]:03X}, 0x{order[1]:03X} before a position"
            times.append(p.parse_pose_time(before[2]))
            assert p.parse_measured_speed(previous[2]) == (0, 0, 0, 0)
    gaps = [(b - a) % 2**32 for a, b in zip(times, times[1:])]
    assert len(gaps) > 3.0 / (period_ms / 1000) * 0.8
    assert all(0 < gap < 3 * period_ms for gap in gaps), gaps
    assert abs(statistics.mean(gaps) - period_ms) < period_ms * 0.1


def test_the_status_frame_comes_every_status_time(base):
    period_ms = base.read_register(p.REG_STATUS_TIME).value
    gaps = periods(base.collect(4.5), p.STATUS)
    assert len(gaps) >= 3
    assert abs(statistics.mean(gaps) * 1000 - period_ms) < period_ms * 0.1


def test_no_feedback_frames_in_an_emergency_but_status_goes_on(base, operator):
    operator.press_estop()
    base.wait_for_mode("Emergency", timeout=5)
    frames = base.collect(2.0)
    sent = {frame_id for _, frame_id, _ in frames}
    assert not sent & set(p.FEEDBACK_IDS)
    assert p.STATUS in sent
    operator.release_estop()
    base.wait_for_mode("AwaitingConfirm", timeout=5)
    operator.confirm()
    base.wait_for_mode("Standby", timeout=15)
