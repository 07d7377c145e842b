"""The CAN protocol of the base controller, written from docs/protocol.md alone.

The HIL suite speaks to the controller only through these builders and parsers, so it
checks the firmware against the written protocol, not against the firmware's own codec.
"""
import itertools
import random
import struct
from dataclasses import dataclass

ENABLE = 0x2E4
VELOCITY = 0x0C8
REGISTER_WRITE = 0x003
REGISTER_READ = 0x004
RESET_ODOMETRY = 0x005
HEARTBEAT = 0x006
SCALE_CALIBRATION = 0x007
ODOMETRY_CALIBRATION = 0x008
WEIGHT = 0x0EA
BATTERY = 0x0EB
POSITION = 0x0EC
HEADING = 0x0ED
STATUS = 0x0EE

FEEDBACK_IDS = (WEIGHT, BATTERY, POSITION, HEADING)

# Registers used by the suite (docs/registers.md).
REG_LOOP_END_DELAY = 15
REG_F_LIN = 18
REG_BATT_FULL_MV = 30
REG_STATUS_TIME = 31
REG_FW_VERSION = 38
REG_REGMAP_VERSION = 39

MODES = ["Starting", "Standby", "Active", "Emergency", "AwaitingConfirm", "Recovering", "Fault"]
SOURCES = ["none", "CAN", "remote"]


def enable(refresh=True):
    return ENABLE, bytes([0x40 if refresh else 0x00] + [0] * 7)


def velocity(linear_mm_s, rotation_mrad_s):
    return VELOCITY, struct.pack("<hhB", linear_mm_s, rotation_mrad_s, 0x03)


def register_write(address, value):
    return REGISTER_WRITE, struct.pack(">BH", address, value)


def register_read(address, tag=0):
    """`01 addr` (the manual's request) for tag 0, else `01 addr tagMSB tagLSB`: the
    reply echoes the address and the tag."""
    if tag == 0:
        return REGISTER_READ, bytes([0x01, address])
    return REGISTER_READ, struct.pack(">BBH", 0x01, address, tag)


_tags = itertools.count(random.randrange(1, 0xFFFF))


def next_tag():
    """A tag for the next read of this program: never 0 (that is no tag)."""
    return next(_tags) % 0xFFFF + 1


def reset_odometry():
    return RESET_ODOMETRY, bytes([0x01])


def heartbeat():
    return HEARTBEAT, bytes([0x01])


def odometry_calibration(step, value=None):
    """step: 1..4 (start/store) or an end code 0x0C, 0x16, 0x20 with a u16 value."""
    if value is None:
        return ODOMETRY_CALIBRATION, bytes([step])
    return ODOMETRY_CALIBRATION, struct.pack(">BH", step, value)


def scale_calibration(step, grams=None):
    if grams is None:
        return SCALE_CALIBRATION, bytes([step])
    return SCALE_CALIBRATION, struct.pack(">BH", step, grams)


@dataclass
class Position:
    x_mm: int
    y_mm: int


def parse_position(data):
    x, y = struct.unpack("<ii", bytes(data[:8]))
    return Position(x, y)


def parse_heading(data):
    return struct.unpack("<i", bytes(data[:4]))[0]


def parse_battery(data):
    percent, millivolts = struct.unpack("<BH", bytes(data[:3]))
    return percent, millivolts


def parse_weight(data):
    return struct.unpack("<H", bytes(data[:2]))[0]


@dataclass
class RegisterReply:
    value: int = None
    refused_address: int = None
    reason: int = None
    # Which read the reply answers (ext): the address read and the request's tag.
    address: int = None
    tag: int = None


def parse_register_reply(data):
    """`00 MSB LSB addr tagMSB tagLSB` (the manual's three bytes, then the echo) or
    `FF addr reason tagMSB tagLSB`."""
    if data[0] == 0x00 and len(data) == 6:
        value, address, tag = struct.unpack(">HBH", bytes(data[1:6]))
        return RegisterReply(value=value, address=address, tag=tag)
    if data[0] == 0xFF and len(data) == 5:
        address, reason, tag = struct.unpack(">BBH", bytes(data[1:5]))
        return RegisterReply(refused_address=address, reason=reason, address=address, tag=tag)
    raise ValueError(f"not a register reply: {bytes(data).hex()}")


def reply_to(address, tag):
    """A predicate on 0x004 data: the reply to our read of `address` with `tag`, not a
    request and not the reply to another program's read."""
    def answers(data):
        try:
            reply = parse_register_reply(data)
        except (ValueError, IndexError):
            return False
        return reply.address == address and reply.tag == tag
    return answers


@dataclass
class Status:
    mode: str
    source: str
    flags: int
    faults: int
    rejected: int
    last_reason: int
    last_subject: int
    drive_alarm: int
    modbus_errors: int

    @property
    def enable_fresh(self):
        return bool(self.flags & 0x01)

    @property
    def estop_pressed(self):
        return bool(self.flags & 0x40)

    @property
    def brakes_applied(self):
        return bool(self.flags & 0x80)


def parse_status(data):
    data = bytes(data)
    # bit 7 of byte 0 is "persist pending"
    mode, source = data[0] & 0x0F, (data[0] >> 4) & 0x07
    return Status(
        mode=MODES[mode],
        source=SOURCES[source],
        flags=data[1],
        faults=data[2],
        rejected=data[3],
        last_reason=data[4],
        last_subject=data[5],
        drive_alarm=data[6],
        modbus_errors=data[7],
    )
