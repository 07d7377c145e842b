"""Registers over CAN: read, write, refusal, and persistence across a reboot."""
import time

import protocol as p


def test_a_register_reads_its_value(base):
    reply = base.read_register(p.REG_REGMAP_VERSION)
    assert reply.value is not None and reply.value >= 1


def test_a_written_register_reads_back_and_survives_a_reboot(base, operator):
    original = base.read_register(p.REG_BATT_FULL_MV).value
    changed = 25_600 if original != 25_600 else 25_700
    base.write_register(p.REG_BATT_FULL_MV, changed)
    time.sleep(0.3)
    assert base.read_register(p.REG_BATT_FULL_MV).value == changed
    operator.reboot()
    assert base.read_register(p.REG_BATT_FULL_MV, timeout=15).value == changed
    base.write_register(p.REG_BATT_FULL_MV, original)
    time.sleep(0.3)
    assert base.read_register(p.REG_BATT_FULL_MV).value == original


def test_an_out_of_range_write_changes_nothing_and_is_counted(base):
    before = base.status()
    original = base.read_register(p.REG_LOOP_END_DELAY).value
    base.write_register(p.REG_LOOP_END_DELAY, 5)  # below 10 ms
    time.sleep(0.2)
    after = base.status()
    assert base.read_register(p.REG_LOOP_END_DELAY).value == original
    assert after.rejected == (before.rejected + 1) % 256
    assert after.last_subject == p.REG_LOOP_END_DELAY


def test_reading_an_unknown_register_is_refused_with_its_address(base):
    reply = base.read_register(200)
    assert reply.refused_address == 200
