"""The firmware update over CAN, end to end, with a client written from
docs/protocol.md ("Firmware update (ext)"): a healthy update is confirmed and survives
a reset, a failing image is rolled back, the update and driving exclude each other,
and bad frames on the wire get their documented answers.

Against the simulator the images are made by the `sim_image` example (64 KiB) and
signed with a throwaway key the simulator trusts; against a robot they come from
`--update-image` and `--update-bad-image`, signed with `--update-key` when given.
"""
import hashlib
import random
import struct
import threading
import time
import zlib

import pytest

import protocol as p
from harness import UpdateClient

# The simulated bus and flash take real time (about 3 s per 100 KiB): a generous bound
# for an image's start after the activation reset.
START_TIMEOUT = 30.0
# A failing image that never reaches the bus (a robot's deaf build) is rolled back by
# its own trial deadline, 120 s after its start.
ROLLBACK_TIMEOUT = 150.0


@pytest.fixture
def client(base):
    """An update client; whatever a failed scenario left behind is undone, so the
    scenarios after it can drive: a session is aborted, an image on trial rolled back."""
    client = UpdateClient(base)
    yield client
    try:
        running = client.query()
    except TimeoutError:
        return
    if running.phase == "on trial":
        client.command(p.update_rollback(client.session), p.DONE_ROLLED_BACK)
        time.sleep(5)
    elif running.phase != "idle" and running.session == client.session:
        client.command(p.update_abort(client.session), p.DONE_ABORTED)


def boot_info(base):
    return base.read_register_retrying(p.REG_BOOT_INFO).value


def wait_for_boot_info(base, expected, timeout=15.0):
    """Reads `boot_info` until it says `expected`; returns the last value read."""
    end = time.monotonic() + timeout
    while True:
        value = boot_info(base)
        if value == expected or time.monotonic() > end:
            return value
        time.sleep(0.3)


def current_status(base):
    """The next status frame sent from now on, not one queued before."""
    base.flush()
    return base.status()


def standby_from_now(base):
    """Waits for Standby in the status frames from now on (queued ones may be from
    before a reset)."""
    base.flush()
    return base.wait_for_mode("Standby", timeout=15)


def watchdog_reset(status):
    return bool(status.faults & 0x80)


class ChangingSpeeds:
    """A planner's traffic: the enable and a new speed every 20-50 ms, in the
    background, until stopped."""

    SPEEDS = (180, 240, 300, 220, 260)

    def __init__(self, base):
        self.base = base
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        frame = 0
        while not self.stop.is_set():
            self.base.send(p.enable())
            self.base.send(p.velocity(self.SPEEDS[frame % len(self.SPEEDS)], 0))
            frame += 1
            self.stop.wait(random.uniform(0.02, 0.05))
        self.base.send(p.velocity(0, 0))

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()


def positions_and_statuses(frames):
    positions = [p.parse_position(data).x_mm for _, frame_id, data in frames
                 if frame_id == p.POSITION]
    statuses = [p.parse_status(data) for _, frame_id, data in frames if frame_id == p.STATUS]
    return positions, statuses


def assert_motion_refused(base):
    """Enable and changing speeds for 1.5 s: every one refused with 0x50, the base
    stays braked in Standby and its position does not move."""
    rejected_before = current_status(base).rejected
    with ChangingSpeeds(base):
        time.sleep(0.3)
        frames = base.collect(1.2)
    positions, statuses = positions_and_statuses(frames)
    assert positions and statuses, "feedback and status go on while motion is refused"
    assert max(positions) - min(positions) <= 1, f"the base moved: {positions}"
    assert all(s.mode == "Standby" and s.brakes_applied for s in statuses), statuses
    last = statuses[-1]
    assert (last.last_reason, last.last_subject) in (
        (p.REJECT_UPDATE_IN_PROGRESS, p.VELOCITY & 0xFF),
        (p.REJECT_UPDATE_IN_PROGRESS, p.ENABLE & 0xFF)), last
    # Every frame is counted (the count wraps at 256): dozens in 1.5 s.
    assert (last.rejected - rejected_before) % 256 >= 20, (rejected_before, last)


def idle_at_rest_running_another_version(base, client, image):
    """Waits for the base to stand, checks that no session runs and that `image` is not
    the running version; returns the QUERY answer from before the update."""
    base.wait_until_at_rest()
    before = client.query()
    assert before.phase == "idle", before
    assert image.version != before.version, \
        f"the base runs {before.version} already: give an image of another (newer) version"
    return before


def test_a_healthy_update_runs_on_trial_is_confirmed_and_survives_a_reset(
        base, operator, client, update_images):
    image = update_images.healthy(client)
    before = idle_at_rest_running_another_version(base, client, image)

    seconds = client.transfer(image.data)
    client.expect_done(p.update_activate(client.session), p.DONE_ACTIVATED, timeout=5)
    trial = client.wait_for_running(image.version, "on trial", timeout=START_TIMEOUT)
    print(f"\n{len(image.data)} bytes in {seconds:.1f} s, "
          f"{client.resent_windows} windows sent again")
    assert trial.slot != before.slot, "the new image runs from the other slot"
    standby_from_now(base)
    assert boot_info(base) == p.BOOT_ACTIVATED, "the activation's reset starts the trial"
    assert not watchdog_reset(current_status(base)), "an activation is no watchdog reset"
    # While the image is on trial, nothing drives the base and no update begins.
    assert_motion_refused(base)
    again = client.begin(len(image.data))
    assert (again.kind, again.error) == ("refused", p.ERROR_CODES["OnTrial"]), str(again)

    # Only the session that activated the image decides about its trial.
    stranger = UpdateClient(base, session=client.session % 255 + 1)
    for command, opcode in ((p.update_confirm(stranger.session), p.OP_CONFIRM),
                            (p.update_rollback(stranger.session), p.OP_ROLLBACK)):
        refused = stranger.command(command, p.DONE_CONFIRMED)
        assert (refused.kind, refused.opcode, refused.error) == (
            "refused", opcode, p.ERROR_CODES["NotTrialOwner"]), str(refused)
    assert client.query().phase == "on trial"

    client.expect_done(p.update_confirm(client.session), p.DONE_CONFIRMED, timeout=5)
    confirmed = client.query()
    assert (confirmed.version, confirmed.phase) == (image.version, "idle"), confirmed
    twice = client.command(p.update_confirm(client.session), p.DONE_CONFIRMED)
    assert (twice.kind, twice.opcode, twice.error) == (
        "refused", p.OP_CONFIRM, p.ERROR_CODES["NotOnTrial"]), str(twice)

    operator.reset_controller(while_driving=False)
    # boot_info drops its activation bit only with a new boot: the reset happened.
    assert wait_for_boot_info(base, 0) == 0, "a plain reset after the confirm"
    after = client.wait_for_running(image.version, "idle", timeout=START_TIMEOUT)
    assert after.slot == trial.slot, "the confirmed image starts again, not the old one"
    assert not watchdog_reset(standby_from_now(base))


def test_an_image_that_fails_on_the_target_is_rolled_back(base, client, update_images):
    image = update_images.failing(client)
    before = idle_at_rest_running_another_version(base, client, image)

    client.transfer(image.data)
    client.expect_done(p.update_activate(client.session), p.DONE_ACTIVATED, timeout=5)
    end = time.monotonic() + ROLLBACK_TIMEOUT
    while True:
        assert time.monotonic() < end, f"neither {image.version} on trial nor a rollback"
        try:
            running = client.query(timeout=0.5)
        except TimeoutError:
            continue
        if running.version == image.version and running.phase == "on trial":
            # It started: the health check basectl makes decides (Standby, no drive
            # fault within 10 s); an image that passes it is no failing image.
            status = health_check(base)
            assert status is not None, f"{image.version} passed the health check"
            client.expect_done(p.update_rollback(client.session), p.DONE_ROLLED_BACK, timeout=5)
            break
        if running.version == before.version and running.phase == "idle":
            # The old version: after the new one failed, or still before the reset;
            # only an answer 1.5 s later counts (as basectl does), with boot_info's
            # rollback bit below.
            time.sleep(1.5)
            again = client.query()
            if (again.version, again.phase) == (before.version, "idle"):
                break
        time.sleep(0.3)

    assert wait_for_boot_info(base, p.BOOT_ROLLED_BACK) == p.BOOT_ROLLED_BACK
    after = client.wait_for_running(before.version, "idle", timeout=START_TIMEOUT)
    assert after.slot == before.slot, "the old image runs from its own slot"
    status = standby_from_now(base)
    assert not watchdog_reset(status), "a failed trial is reported by boot_info, not as a " \
                                       "watchdog reset"


def health_check(base):
    """None when the base reaches Standby without a drive fault within 10 s, else the
    last status."""
    base.flush()
    end = time.monotonic() + 10
    status = None
    while time.monotonic() < end:
        status = base.status()
        if status.mode == "Standby" and status.faults & 0x0F == 0:
            return None
    return status


def test_begin_while_driving_is_refused_and_the_base_drives_on(base, client):
    base.wait_until_at_rest()
    before = client.query()
    with ChangingSpeeds(base):
        base.wait_for_mode("Active", timeout=5)
        time.sleep(0.5)
        rejected_before = current_status(base).rejected
        refused = client.begin(64 * 1024)
        window = client.command(p.update_window(client.session, 0, 0), step=None)
        client.flush()
        client.send(p.update_data(0, b"\x00" * 7))
        data = client.wait_reply(lambda r: r.kind == "refused", 1.0, "REFUSED for data")
        frames = base.collect(1.0)
    positions, statuses = positions_and_statuses(frames)

    assert (refused.kind, refused.opcode, refused.error) == (
        "refused", p.OP_BEGIN, p.ERROR_CODES["NotAtRest"]), str(refused)
    # No session: a window and a data frame have nothing to go into.
    assert (window.opcode, window.error) == (p.OP_WINDOW, p.ERROR_CODES["NoSession"]), \
        str(window)
    assert (data.opcode, data.error) == (p.OP_DATA, p.ERROR_CODES["NoSession"]), str(data)
    after = client.query()
    assert (after.phase, after.windows, after.version, after.slot) == (
        "idle", 0, before.version, before.slot), after
    # The base drove on: every position frame moved, nothing of its traffic refused.
    assert len(positions) >= 10, positions
    steps = [b - a for a, b in zip(positions, positions[1:])]
    assert all(step > 0 for step in steps), f"the base stopped: {steps}"
    assert statuses and all(s.mode == "Active" for s in statuses), statuses
    assert all(s.rejected == rejected_before for s in statuses), (rejected_before, statuses)
    base.wait_until_at_rest()


def test_motion_is_refused_during_a_session_and_abort_releases_it(base, client):
    """Also another program's BEGIN: the session is its PC's alone."""
    base.wait_until_at_rest()
    begun = client.begin(64 * 1024)
    assert begun.kind == "done", str(begun)
    assert client.query().phase == "receiving"
    # Another program's BEGIN meanwhile: Busy.
    other = UpdateClient(base, session=client.session % 255 + 1)
    busy = other.begin(64 * 1024)
    assert (busy.kind, busy.opcode, busy.error, busy.session) == (
        "refused", p.OP_BEGIN, p.ERROR_CODES["Busy"], other.session), str(busy)
    assert_motion_refused(base)

    client.abort()
    assert client.query().phase == "idle"
    with ChangingSpeeds(base):
        base.wait_for_mode("Active", timeout=5)
        first = base.position()
        time.sleep(0.5)
        moved = base.position().x_mm - first.x_mm
    assert moved > 50, f"{moved} mm in 0.5 s at 180-300 mm/s after the abort"
    base.wait_until_at_rest()


def test_a_bad_window_crc_and_stray_data_frames_get_their_documented_answers(
        base, client, update_images):
    image = update_images.healthy(client)
    base.wait_until_at_rest()
    before = client.query()
    assert p.window_count(len(image.data)) >= 2
    # Never activated: any version will do (on a robot the image may be the one the
    # healthy update left running).
    begun = client.begin(len(image.data), p.BEGIN_FORCE | p.BEGIN_ALLOW_DOWNGRADE)
    assert begun.kind == "done", str(begun)
    client.send_digest(image.data)

    # Window 0 with a wrong CRC: every frame goes, then BadCrc; the window again with
    # the right one is written.
    window = p.window_bytes(image.data, 0)
    bad = client.send_window(0, window, crc=zlib.crc32(window) ^ 0x00010000)
    assert bad is not None and (bad.kind, bad.opcode, bad.error) == (
        "refused", p.OP_WINDOW, p.ERROR_CODES["BadCrc"]), str(bad)
    assert client.query().windows == 0
    good = client.send_window(0, window)
    assert good is not None and good.kind == "written", str(good)

    # Window 1 by hand: frames 0-2, frame 2 again, then frame 5 where 3 is due.
    window = p.window_bytes(image.data, 1)
    frames = p.window_frames(window)
    client.flush()
    client.send(p.update_window(client.session, 1, zlib.crc32(window)))
    ready = client.wait_reply(lambda r: r.kind == "ready", 1.0, "READY 0")
    assert (ready.window, ready.next) == (1, 0)
    client.send_frames(frames[0:3])
    client.send(frames[2])
    duplicate = client.wait_reply(lambda r: r.kind == "refused", 1.0, "Duplicate")
    assert (duplicate.opcode, duplicate.error, duplicate.detail) == (
        p.OP_DATA, p.ERROR_CODES["Duplicate"], 2), str(duplicate)
    client.send(frames[5])
    ahead = client.wait_reply(lambda r: r.kind == "refused", 1.0, "OutOfOrder")
    assert (ahead.opcode, ahead.error, ahead.detail) == (
        p.OP_DATA, p.ERROR_CODES["OutOfOrder"], 3), str(ahead)
    resume = client.wait_reply(lambda r: r.kind == "ready", 1.0, "READY 3")
    assert (resume.window, resume.next) == (1, 3), str(resume)
    # From where READY says, the window completes and is written.
    sent = 3 + p.FRAMES_PER_READY
    client.send_frames(frames[3:sent])
    while True:
        reply = client.wait_reply(lambda r: r.kind in ("ready", "written", "refused"), 2.0,
                                  "READY/WRITTEN for window 1")
        assert reply.kind != "refused", str(reply)
        if reply.kind == "written":
            break
        end = reply.next + p.FRAMES_PER_READY
        client.send_frames(frames[max(sent, reply.next):end])
        sent = max(sent, end)
    assert client.query().windows == 2

    client.abort()
    after = client.query()
    assert (after.phase, after.version, after.slot) == ("idle", before.version, before.slot)


def checksum_offset(image):
    """Where the image's XOR checksum is, read as docs/protocol.md ("Writing a client")
    lays an image out: the 24-byte header (segment count at byte 1), then each segment's
    8-byte header (its length in bytes 4-7, LE) and data; the checksum is the last byte
    of the 16-byte block the segments end in, the SHA-256 the 32 bytes after it."""
    at = 24
    for _ in range(image[1]):
        at += 8 + struct.unpack_from("<I", image, at + 4)[0]
    return at | 0xF


def transfer_and_finish(client, name, data):
    """BEGIN (forced, any version), the digest and every window of `data`, then FINISH:
    FINISH's answer."""
    begun = client.begin(len(data), p.BEGIN_FORCE | p.BEGIN_ALLOW_DOWNGRADE)
    assert begun.kind == "done", f"{name}: {begun}"
    client.send_digest(data)
    for index in range(p.window_count(len(data))):
        written = client.send_window(index, p.window_bytes(data, index))
        assert written is not None and written.kind == "written", f"{name}: {written}"
    return client.command(p.update_finish(client.session), p.DONE_FINISHED)


def test_an_image_the_bootloader_would_refuse_is_refused_at_finish(
        base, client, update_images):
    image = update_images.healthy(client).data
    checksum_at = checksum_offset(image)
    bad_checksum = bytearray(image[:checksum_at + 1])
    bad_checksum[checksum_at] ^= 0x5A
    bad_checksum += hashlib.sha256(bad_checksum).digest()
    bad_digest = bytearray(image)
    bad_digest[checksum_at + 1] ^= 0x01
    cases = [
        ("truncated inside its last segment", image[:checksum_at - 16], 7),
        ("with a bad checksum", bytes(bad_checksum), 8),
        ("with a bad appended SHA-256", bytes(bad_digest), 9),
    ]
    base.wait_until_at_rest()
    before = client.query()
    for name, data, detail in cases:
        finish = transfer_and_finish(client, name, data)
        assert (finish.kind, finish.opcode, finish.error, finish.detail) == (
            "refused", p.OP_FINISH, p.ERROR_CODES["BadImage"], detail), f"{name}: {finish}"
        # The refusal ended the session: nothing to activate, the old image runs on.
        activate = client.command(p.update_activate(client.session), p.DONE_ACTIVATED)
        assert (activate.kind, activate.error) == (
            "refused", p.ERROR_CODES["NoSession"]), f"{name}: {activate}"
        after = client.query()
        assert (after.phase, after.version, after.slot) == (
            "idle", before.version, before.slot), f"{name}: {after}"


def test_only_a_signed_image_passes_finish_on_a_controller_that_requires_signatures(
        base, client, update_images):
    """The image as built, unsigned, is refused at FINISH (Untrusted, detail 1), and
    so is the signed one with its flags changed (detail 3); the signed image itself
    passes. A development build takes any image: the scenario needs a build with a key."""
    before = client.query()
    if not before.signatures_required:
        pytest.skip("the controller is a development build: it takes unsigned images")
    image = update_images.healthy(client)
    forged = bytearray(image.data)
    forged[len(forged) - 108 + 40] ^= 0x01  # the block's flags: a downgrade claimed
    cases = [("unsigned", image.unsigned, 1), ("forged", bytes(forged), 3),
             ("signed", image.data, None)]
    base.wait_until_at_rest()
    for name, data, detail in cases:
        finish = transfer_and_finish(client, name, data)
        if detail is None:
            assert finish.kind == "done", f"{name}: {finish}"
            client.command(p.update_abort(client.session), p.DONE_ABORTED)
        else:
            assert (finish.kind, finish.opcode, finish.error, finish.detail) == (
                "refused", p.OP_FINISH, p.ERROR_CODES["Untrusted"], detail), f"{name}: {finish}"
        after = client.query()
        assert (after.phase, after.version, after.slot) == (
            "idle", before.version, before.slot), f"{name}: {after}"
