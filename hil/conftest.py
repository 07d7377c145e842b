"""How the HIL suite reaches a base controller.

    pytest hil                                   # against the simulator (CI)
    pytest hil --can-interface socketcan --can-channel can0    # against a robot

Against the simulator the suite starts `virtual-base-controller` itself, talks SLCAN
to it, and presses its buttons through its console. Against a robot it asks the
person at the robot to press them (run pytest with `-s` so the prompts show).
"""
import os
import pathlib
import re
import struct
import subprocess
import tempfile
import time

from dataclasses import dataclass

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
    parser.addoption("--update-image", default=None, metavar="NEXT.bin",
                     help="robot only: a firmware image newer than the one the robot runs, "
                          "for the update scenarios (the simulator's are made by sim_image)")
    parser.addoption("--update-key", default=None, metavar="KEY",
                     help="robot only: the secret key (PEM) of a robot built with "
                          "BASE_UPDATE_KEY=KEY.pub; the update images are signed with it "
                          "(the simulator gets a throwaway key of its own)")
    parser.addoption("--update-bad-image", default=None, metavar="BAD.bin",
                     help="robot only: a newer image that fails on the robot (panics at "
                          "start, or fails the health check), for the rollback scenario")


class Simulator:
    """The simulator as a subprocess: its SLCAN port and its console."""

    def __init__(self, workdir, update_key):
        self.update_key = update_key
        self.link = workdir / "slcan"
        self.flash = workdir / "flash.bin"
        self.log = open(workdir / "simulator.log", "w")
        self.process = None

    def start(self):
        if self.link.exists():
            self.link.unlink()
        self.process = subprocess.Popen(
            [str(SIMULATOR), "--link", str(self.link), "--flash", str(self.flash),
             "--socketcand", "127.0.0.1:0", "--update-key", f"{self.update_key}.pub"],
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

    def reset_controller(self, while_driving=True):
        # The controller alone restarts; the SLCAN port and the drives stay as they are.
        self.simulator.command("reboot")

    def reboot(self):
        self.base.close()
        self.simulator.stop()
        self.simulator.start()
        self.base.attach(self.simulator.open_bus())


# `cargo build -p virtual-robot --examples` makes it: it writes the simulator's images.
SIM_IMAGE = ROOT / "target" / "debug" / "examples" / "sim_image"
# Small images keep each update scenario within seconds on the simulator.
SIM_IMAGE_KIB = 64


# basectl signs the images (`firmware sign`) and makes the simulator's key (`keygen`).
BASECTL = ROOT / "target" / "debug" / "basectl"


def basectl(*args):
    if not BASECTL.exists():
        subprocess.run(["cargo", "build", "-q", "-p", "basectl"], cwd=ROOT, check=True)
    subprocess.run([str(BASECTL), *map(str, args)], check=True, capture_output=True)


def sign(path, key):
    """The image file at `path` signed with the secret key `key`, as bytes."""
    signed = path.with_suffix(".signed.bin")
    basectl("firmware", "sign", "--key", key, path, signed)
    return signed.read_bytes()


@dataclass
class Image:
    version: str
    data: bytes
    # The image as built, before it was signed.
    unsigned: bytes = None


def image_version(data):
    """The version in an ESP app image's descriptor: the descriptor (magic 0xABCD5432)
    opens the first segment, after the 24-byte image and 8-byte segment headers, and
    holds the version, NUL-terminated, at its byte 16."""
    if len(data) < 80 or struct.unpack_from("<I", data, 32)[0] != 0xABCD5432:
        raise ValueError("not an ESP app image with an app descriptor")
    return data[48:80].split(b"\0")[0].decode()


def next_version(running):
    """A release above `running` (`0.1.0` → `0.1.1`): the controller refuses the same
    version and a downgrade."""
    match = re.fullmatch(r"(\d+)\.(\d+)\.(\d+)([-+].*)?", running)
    if match is None:
        raise ValueError(f"the running version {running!r} is not major.minor.patch")
    major, minor, patch = (int(number) for number in match.groups()[:3])
    return f"{major}.{minor}.{patch + 1}"


class SimulatorImages:
    """Images the simulator's virtual firmware runs: the version chooses what it does."""

    def __init__(self, workdir, key):
        self.workdir = workdir
        self.key = key

    def _make(self, version):
        if not SIM_IMAGE.exists():
            pytest.fail(f"{SIM_IMAGE} is missing: build it with "
                        "`cargo build -p virtual-robot --examples`")
        path = self.workdir / f"{version}.bin"
        subprocess.run([str(SIM_IMAGE), version, str(path), str(SIM_IMAGE_KIB)],
                       check=True, capture_output=True)
        return Image(version, sign(path, self.key), unsigned=path.read_bytes())

    def healthy(self, client):
        return self._make(next_version(client.query().version))

    def failing(self, client):
        # Panics at start after arming its trial: the bootloader model rolls it back.
        return self._make(next_version(client.query().version) + "-sim-panic")


class RobotImages:
    """Images given on the command line; a scenario without its image is skipped."""

    def __init__(self, config):
        self.config = config

    def _load(self, option, file, what):
        path = self.config.getoption(option)
        if path is None:
            pytest.skip(f"needs {what}: pass {option} {file}")
        path = pathlib.Path(path)
        data = path.read_bytes()
        key = self.config.getoption("--update-key")
        if key is None:
            return Image(image_version(data), data, unsigned=data)
        return Image(image_version(data), sign(path, key), unsigned=data)

    def healthy(self, client):
        return self._load("--update-image", "NEXT.bin", "a firmware image newer than the robot's")

    def failing(self, client):
        return self._load("--update-bad-image", "BAD.bin",
                          "a newer image that fails on the robot (panics or fails the "
                          "health check)")


@pytest.fixture(scope="session")
def update_images(request, tmp_path_factory, simulator_key):
    """`healthy(client)` and `failing(client)`: the update scenarios' images for the
    base `client` reaches, signed with the owner's key when there is one (a robot's come
    from the options: skipped, before any frame is sent, when the option is missing)."""
    if request.config.getoption("--can-interface") is not None:
        return RobotImages(request.config)
    return SimulatorImages(tmp_path_factory.mktemp("images"), simulator_key)


@pytest.fixture(scope="session")
def simulator_key(tmp_path_factory):
    """A throwaway owner's key for the simulator, which trusts it (`--update-key`): the
    suite runs against a controller that takes only signed images, as a robot should."""
    key = tmp_path_factory.mktemp("keys") / "owner.key"
    basectl("firmware", "keygen", key)
    return key


@pytest.fixture(scope="session")
def connection(request, simulator_key):
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
        simulator = Simulator(pathlib.Path(workdir), simulator_key)
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
