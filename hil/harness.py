"""The HIL harness: a CAN connection to a base controller, and the person (or
simulator) who presses its buttons. Everything a scenario does goes over CAN."""
import contextlib
import queue
import threading
import time

import can

import protocol as p


class BaseController:
    """A base controller on the other end of a python-can bus."""

    def __init__(self, bus):
        self.frames = queue.Queue()
        self.attach(bus)

    def attach(self, bus):
        """Talks over `bus` from now on (after the simulator restarted)."""
        self.bus = bus
        self._reader = can.Notifier(bus, [self._receive])

    def _receive(self, message):
        if not message.is_extended_id and not message.is_remote_frame:
            self.frames.put((time.monotonic(), message.arbitration_id, bytes(message.data)))

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

    def reset_controller(self):
        self._ask("While the wheels turn, press the base controller's reset button "
                  "(the drives keep their power)")
