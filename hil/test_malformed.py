"""Frames that are not the protocol: rejected and counted, or ignored, never acted on."""
import time

import protocol as p


def rejected_after(base, send):
    before = base.status().rejected
    send()
    time.sleep(0.2)
    return (base.status().rejected - before) % 256


def test_a_velocity_frame_without_its_marker_is_rejected_and_does_not_move_the_base(base):
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        start = base.position()
        count = rejected_after(base, lambda: base.send_raw(p.VELOCITY, bytes([0xF4, 0x01, 0, 0, 0x04])))
        time.sleep(0.5)
        assert base.position().x_mm == start.x_mm
    assert count == 1


def test_a_short_velocity_frame_is_rejected(base):
    assert rejected_after(base, lambda: base.send_raw(p.VELOCITY, bytes([0xF4, 0x01]))) == 1


def test_extended_and_remote_frames_are_ignored_without_counting(base):
    def send():
        base.send_raw(p.VELOCITY, bytes([0xF4, 0x01, 0, 0, 0x03]), extended=True)
        base.send_raw(p.ENABLE, bytes(8), remote=True)

    assert rejected_after(base, send) == 0


def test_an_unknown_id_is_ignored_without_counting(base):
    assert rejected_after(base, lambda: base.send_raw(0x123, bytes([1, 2, 3]))) == 0
