"""How the HIL suite reaches a base controller.

    pytest hil                                   # against the simulator (CI)
    pytest hil --can-interface socketcan --can-channel can0    # against a robot

Against the simulator the suite starts `virtual-base-controller` itself, talks SLCAN
to it, and presses its buttons through its console. Against a robot it asks the
person at the robot to press them (run pytest with `-s` so the prompts show).
"""
import os
import pathlib
import subprocess
import tempfile
import time

import can
import pytest

from harness import BaseController, HumanOperator

ROOT = pathlib.Path(__file__).resolve().parent.parent
# The simulator binary: `cargo build -p virtual-robot` makes it; HIL_SIMULATOR points
# elsewhere (another checkout, a release build).
SIMULATOR = pathlib.Path(os.environ.get(
    "HIL_SIMULATOR", ROOT / "target" / "debug" / "virtual-base-controller"))


def pytest_addoption(parser):
    parser.addoption("--can-interface", default=None,
                     help="python-can interface of a real robot (socketcan, slcan, pcan, …); "
                          "without it the suite runs against the simulator")
    parser.addoption("--can-channel", default="can0", help="the interface's channel")
    parser.addoption("--can-bitrate", default=500000, type=int)


class Simulator:
    """The simulator as a subprocess: its SLCAN port and its console."""

    def __init__(self, workdir):
        self.link = workdir / "slcan"
        self.flash = workdir / "flash.bin"
        self.log = open(workdir / "simulator.log", "w")
        self.process = None

    def start(self):
        if self.link.exists():
            self.link.unlink()
        self.process = subprocess.Popen(
            [str(SIMULATOR), "--link", str(self.link), "--flash", str(self.flash),
             "--socketcand", "127.0.0.1:0"],
            stdin=subprocess.PIPE, stdout=self.log, stderr=subprocess.STDOUT, text=True)
        for _ in range(100):
            if self.link.exists():
                return
            time.sleep(0.05)
        raise RuntimeError(f"the simulator made no port at {self.link}")

    def command(self, line):
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()

    def stop(self):
        if self.process and self.process.poll() is None:
            self.command("quit")
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()

    def open_bus(self):
        return can.Bus(interface="slcan", channel=str(self.link), bitrate=500000,
                       sleep_after_open=0)


class SimulatorOperator:
    """Presses the simulator's buttons through its console."""

    def __init__(self, simulator, base):
        self.simulator = simulator
        self.base = base

    def press_estop(self):
        self.simulator.command("estop on")

    def release_estop(self):
        self.simulator.command("estop off")

    def confirm(self):
        self.simulator.command("button press 200")

    def reset_controller(self):
        # The controller alone restarts; the SLCAN port and the drives stay as they are.
        self.simulator.command("reboot")

    def reboot(self):
        self.base.close()
        self.simulator.stop()
        self.simulator.start()
        self.base.attach(self.simulator.open_bus())


@pytest.fixture(scope="session")
def connection(request):
    interface = request.config.getoption("--can-interface")
    if interface is not None:
        bus = can.Bus(interface=interface, channel=request.config.getoption("--can-channel"),
                      bitrate=request.config.getoption("--can-bitrate"))
        base = BaseController(bus)
        yield base, HumanOperator()
        base.close()
        return
    if not SIMULATOR.exists():
        subprocess.run(["cargo", "build", "-q", "-p", "virtual-robot",
                        "--bin", "virtual-base-controller"], cwd=ROOT, check=True)
    with tempfile.TemporaryDirectory(prefix="hil-") as workdir:
        simulator = Simulator(pathlib.Path(workdir))
        simulator.start()
        base = BaseController(simulator.open_bus())
        yield base, SimulatorOperator(simulator, base)
        base.close()
        simulator.stop()


@pytest.fixture
def base(connection):
    base, _ = connection
    base.flush()
    return base


@pytest.fixture
def operator(connection):
    return connection[1]
