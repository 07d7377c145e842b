"""Odometry calibration over CAN, end to end: the factor is computed and stored."""
import time

import protocol as p


def test_odometry_calibration_stores_the_linear_factor_from_the_reported_distance(base):
    original = base.read_register(p.REG_F_LIN).value
    with base.enabled():
        base.wait_for_mode("Standby", timeout=15)
        start = base.position()
        base.send(p.odometry_calibration(0x01))
        base.send(p.velocity(300, 0))
        time.sleep(1.5)
        base.send(p.velocity(0, 0))
        time.sleep(1.5)
        driven = base.position().x_mm - start.x_mm
        # Claim the base really drove 2 % more than it reported.
        raw_mm = driven / (original / 10_000)
        base.send(p.odometry_calibration(0x0C, round(raw_mm * 1.02)))
        base.send(p.odometry_calibration(0x04))
        time.sleep(0.3)
    stored = base.read_register(p.REG_F_LIN).value
    base.write_register(p.REG_F_LIN, original)
    time.sleep(0.3)
    assert abs(stored - 10_200) <= 60  # 0.6 %: the report's 1 mm resolution


def test_a_calibration_end_without_its_start_is_refused(base):
    before = base.status().rejected
    base.send(p.odometry_calibration(0x16, 6284))
    time.sleep(0.2)
    status = base.status()
    assert status.rejected == (before + 1) % 256
    assert status.last_subject == 0x08
