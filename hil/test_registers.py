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


def test_each_reply_names_the_address_and_tag_it_answers(base):
    """Another program's untagged reads and our tagged one cross: each reply keeps the
    manual's three bytes and says which read it answers."""
    expected = {p.REG_REGMAP_VERSION: base.read_register(p.REG_REGMAP_VERSION).value,
                p.REG_LOOP_END_DELAY: base.read_register(p.REG_LOOP_END_DELAY).value}
    base.flush()
    base.send(p.register_read(p.REG_LOOP_END_DELAY))
    base.send(p.register_read(p.REG_REGMAP_VERSION, tag=0xBEEF))
    base.send(p.register_read(p.REG_LOOP_END_DELAY))
    replies = [p.parse_register_reply(base.wait_for(p.REGISTER_READ, lambda data: data[0] != 0x01))
               for _ in range(3)]
    assert [(r.address, r.tag) for r in replies] == [
        (p.REG_LOOP_END_DELAY, 0), (p.REG_REGMAP_VERSION, 0xBEEF), (p.REG_LOOP_END_DELAY, 0)]
    assert all(r.value == expected[r.address] for r in replies)


def test_a_bulk_read_answers_each_address_in_order_with_its_tag(base):
    """Registers 36 to 43 in one request: a value or a refusal for each address (37, 41
    and 42 hold no register), in address order, each with the request's tag."""
    expected = {address: base.read_register(address) for address in range(36, 44)}
    tag = p.next_tag()
    base.flush()
    base.send(p.register_bulk_read(36, 8, tag))
    replies = [p.parse_register_reply(base.wait_for(p.REGISTER_READ, lambda data: data[0] != 0x02))
               for _ in range(8)]
    assert [(r.address, r.tag) for r in replies] == [(address, tag) for address in range(36, 44)]
    assert [r.refused_address for r in replies] == [expected[a].refused_address for a in range(36, 44)]
    # The counters (43) may move between the two readings; the rest hold still.
    assert [r.value for r in replies[:7]] == [expected[a].value for a in range(36, 43)]
