"""The HIL harness: a CAN connection to a base controller, and the person (or
simulator) who presses its buttons. Everything a scenario does goes over CAN."""
import contextlib
import hashlib
import queue
import random
import threading
import time
import zlib

from dataclasses import dataclass

import can

import protocol as p


class BaseController:
    """A base controller on the other end of a python-can bus."""

    def __init__(self, bus):
        self.frames = queue.Queue()
        # The firmware update's replies (0x2EA): a queue of their own.
        self.update_replies = queue.Queue()
        self.attach(bus)

    def attach(self, bus):
        """Talks over `bus` from now on (after the simulator restarted)."""
        self.bus = bus
        self._reader = can.Notifier(bus, [self._receive])

    def _receive(self, message):
        if message.is_extended_id or message.is_remote_frame:
            return
        if message.arbitration_id != p.UPDATE_REPLY:
            self.frames.put((time.monotonic(), message.arbitration_id, bytes(message.data)))
        else:
            try:
                reply = p.parse_update_reply(message.data)
            except (ValueError, IndexError):
                # Kept, so that a scenario waiting for a reply names what came instead.
                reply = p.UpdateReply("garbled", text=bytes(message.data))
            self.update_replies.put(reply)

    def close(self):
        self._reader.stop()
        self.bus.shutdown()

    def send(self, frame):
        arbitration_id, data = frame
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

    def send_raw(self, arbitration_id, data, extended=False, remote=False):
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data,
                                  is_extended_id=extended, is_remote_frame=remote,
                                  dlc=len(data)))

    def flush(self):
        while not self.frames.empty():
            self.frames.get_nowait()

    def collect(self, seconds):
        """Every frame received during the next `seconds`: [(time, id, data)]."""
        self.flush()
        end = time.monotonic() + seconds
        collected = []
        while (left := end - time.monotonic()) > 0:
            try:
                collected.append(self.frames.get(timeout=left))
            except queue.Empty:
                break
        return collected

    def wait_for(self, arbitration_id, predicate=lambda data: True, timeout=2.0):
        """The data of the next frame with this ID that satisfies `predicate`."""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            try:
                _, frame_id, data = self.frames.get(timeout=left)
            except queue.Empty:
                break
            if frame_id == arbitration_id and predicate(data):
                return data
        raise TimeoutError(f"no frame 0x{arbitration_id:03X} within {timeout} s")

    def status(self, timeout=3.0):
        return p.parse_status(self.wait_for(p.STATUS, timeout=timeout))

    def wait_for_mode(self, mode, timeout=10.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            status = self.status(timeout=max(0.1, end - time.monotonic()))
            if status.mode == mode:
                return status
        raise TimeoutError(f"mode {mode} not reached within {timeout} s")

    def wait_until_at_rest(self, timeout=15.0):
        """The status of a base that stands in Standby with its brakes applied and
        nobody in control: what a firmware update's BEGIN needs."""
        end = time.monotonic() + timeout
        status = None
        while time.monotonic() < end:
            status = self.status(timeout=max(0.1, end - time.monotonic()))
            if (status.mode == "Standby" and status.brakes_applied
                    and not status.enable_fresh and status.source == "none"):
                return status
        raise TimeoutError(f"the base is not at rest within {timeout} s: {status}")

    def read_register_retrying(self, address, timeout=10.0):
        """A register read that tries again while the controller restarts."""
        end = time.monotonic() + timeout
        while True:
            try:
                return self.read_register(address)
            except TimeoutError:
                if time.monotonic() > end:
                    raise

    def read_register(self, address, timeout=1.0):
        """Takes only the reply that echoes this read's address and tag: other programs
        on the bus may read registers at the same moment."""
        tag = p.next_tag()
        self.flush()
        self.send(p.register_read(address, tag))
        return p.parse_register_reply(
            self.wait_for(p.REGISTER_READ, p.reply_to(address, tag), timeout=timeout))

    def write_register(self, address, value):
        self.send(p.register_write(address, value))

    def position(self, timeout=1.0):
        self.flush()
        return p.parse_position(self.wait_for(p.POSITION, timeout=timeout))

    @contextlib.contextmanager
    def enabled(self, period=0.1):
        """Sends the enable (and the PC heartbeat) every `period` s while inside."""
        stop = threading.Event()

        def refresh():
            while not stop.is_set():
                self.send(p.enable())
                self.send(p.heartbeat())
                stop.wait(period)

        sender = threading.Thread(target=refresh, daemon=True)
        sender.start()
        try:
            yield self
        finally:
            stop.set()
            sender.join()


@dataclass
class Running:
    """What QUERY answers: the update's phase and the running image."""
    phase: str
    session: int
    slot: int
    windows: int
    version: str
    signatures_required: bool = False
    security_version: int = 0


class UpdateRefused(AssertionError):
    def __init__(self, what, reply):
        super().__init__(f"{what}: {reply}")
        self.reply = reply


class UpdateClient:
    """A firmware update client written from docs/protocol.md ("Firmware update
    (ext)"): commands on 0x2E8, data on 0x2EC, replies on 0x2EA, a random session."""

    # The docs: no reply within about a second, send the WINDOW again.
    REPLY_TIMEOUT = 1.0
    WINDOW_ATTEMPTS = 5

    def __init__(self, base, session=None):
        self.base = base
        self.session = session or random.randint(1, 255)
        self.resent_windows = 0

    def send(self, frame):
        self.base.send(frame)

    def answers(self, refused):
        """Whether a REFUSED is this client's: it names this session, or none (a
        command without a session, or firmware from before refusals named it)."""
        return refused.session in (self.session, 0)

    def flush(self):
        while not self.base.update_replies.empty():
            self.base.update_replies.get_nowait()

    def wait_reply(self, accept, timeout, what):
        """The next reply `accept` takes; the others are skipped (and named when
        nothing comes)."""
        end = time.monotonic() + timeout
        skipped = []
        while (left := end - time.monotonic()) > 0:
            try:
                reply = self.base.update_replies.get(timeout=left)
            except queue.Empty:
                break
            if accept(reply):
                return reply
            skipped.append(str(reply))
        raise TimeoutError(f"no {what} within {timeout} s (other replies: {skipped})")

    def command(self, frame, step, timeout=2.0):
        """Sends a command; returns its DONE `step` or the REFUSED naming its opcode
        (`step` None: a command that only a REFUSED answers, as WINDOW without a
        session)."""
        opcode = frame[1][0]
        self.flush()
        self.send(frame)
        return self.wait_reply(
            lambda r: (r.kind == "done" and r.step == step)
            or (r.kind == "refused" and r.opcode == opcode and self.answers(r)),
            timeout, f"DONE {step} or REFUSED for opcode {opcode:#04x}")

    def expect_done(self, frame, step, timeout=2.0):
        reply = self.command(frame, step, timeout)
        if reply.kind != "done":
            raise UpdateRefused(f"command {frame[1].hex()} refused", reply)
        return reply

    def query(self, timeout=1.0):
        self.flush()
        self.send(p.update_query())
        end = time.monotonic() + timeout
        state, parts = None, {}
        while state is None or len(parts) < 6:
            reply = self.wait_reply(lambda r: r.kind in ("state", "version"),
                                    max(0.01, end - time.monotonic()), "STATE and VERSION 0-5")
            if reply.kind == "state":
                state = reply
            elif reply.part < 6:
                parts[reply.part] = reply.text
        text = b"".join(parts[part] for part in range(6)).split(b"\0")[0]
        return Running(phase=p.PHASES[state.phase], session=state.session, slot=state.slot,
                       windows=state.windows, version=text.decode(),
                       signatures_required=state.signatures_required,
                       security_version=state.security_version)

    def wait_for_running(self, version, phase, timeout=30.0):
        """Polls QUERY until `version` runs in `phase` (across the controller's reset)."""
        end = time.monotonic() + timeout
        last = None
        while time.monotonic() < end:
            try:
                last = self.query(timeout=0.5)
                if (last.version, last.phase) == (version, phase):
                    return last
            except TimeoutError as silent:
                last = silent
            time.sleep(0.2)
        raise TimeoutError(f"firmware {version} not {phase} within {timeout} s; last: {last}")

    def begin(self, size, flags=0):
        return self.command(p.update_begin(self.session, size, flags), p.DONE_BEGUN)

    def send_digest(self, image):
        digest = hashlib.sha256(image).digest()
        for part in range(p.DIGEST_PARTS):
            self.send(p.update_digest(self.session, part, digest))

    def send_frames(self, frames):
        for frame in frames:
            self.send(frame)

    def send_window(self, index, window, crc=None):
        """One attempt at a window: WINDOW, then the frames each READY asks for, until
        WRITTEN or REFUSED (returned), or None when the controller falls silent."""
        frames = p.window_frames(window)
        self.flush()
        self.send(p.update_window(self.session, index,
                                  zlib.crc32(window) if crc is None else crc))
        # READY n: every frame before n arrived; send on up to frame n + 23, each once.
        sent = 0
        while True:
            try:
                reply = self.wait_reply(
                    lambda r: r.kind in ("ready", "written", "refused"),
                    self.REPLY_TIMEOUT, f"READY/WRITTEN for window {index}")
            except TimeoutError:
                return None
            if reply.kind == "ready" and (reply.session, reply.window) == (self.session, index):
                end = reply.next + p.FRAMES_PER_READY
                self.send_frames(frames[max(sent, reply.next):end])
                sent = max(sent, end)
            elif reply.kind == "written" and (reply.session, reply.window) == (self.session, index):
                return reply
            elif reply.kind == "refused" and self.answers(reply):
                return reply

    def transfer(self, image, flags=0):
        """BEGIN, DIGEST, every window (sent again after BadCrc, WrongWindow or
        silence, as the docs say) and FINISH. Returns the seconds it took."""
        started = time.monotonic()
        begun = self.begin(len(image), flags)
        if begun.kind != "done":
            raise UpdateRefused("BEGIN refused", begun)
        self.send_digest(image)
        for index in range(p.window_count(len(image))):
            window = p.window_bytes(image, index)
            for attempt in range(self.WINDOW_ATTEMPTS):
                reply = self.send_window(index, window)
                if reply is not None and reply.kind == "written":
                    break
                if reply is not None and p.UPDATE_ERRORS.get(reply.error) not in (
                        "BadCrc", "WrongWindow"):
                    raise UpdateRefused(f"window {index} refused", reply)
                self.resent_windows += 1
            else:
                raise AssertionError(f"window {index} failed {self.WINDOW_ATTEMPTS} times")
        self.expect_done(p.update_finish(self.session), p.DONE_FINISHED)
        return time.monotonic() - started

    def abort(self):
        return self.expect_done(p.update_abort(self.session), p.DONE_ABORTED)


class HumanOperator:
    """A person at the robot: the suite asks, they act and press Enter."""

    def _ask(self, what):
        input(f"\n>>> {what}, then press Enter ")

    def press_estop(self):
        self._ask("Press the e-stop")

    def release_estop(self):
        self._ask("Release the e-stop (do not press the front button yet)")

    def confirm(self):
        self._ask("Press the front button once, briefly")

    def reboot(self):
        self._ask("Power-cycle the base controller and wait 5 s")

    def reset_controller(self, while_driving=True):
        if while_driving:
            self._ask("While the wheels turn, press the base controller's reset button "
                      "(the drives keep their power)")
        else:
            self._ask("Press the base controller's reset button (the drives keep their "
                      "power) and wait 5 s")
