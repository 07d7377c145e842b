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
POSE_TIME = 0x0EF
MEASURED_SPEED = 0x0F0

FEEDBACK_IDS = (WEIGHT, BATTERY, POSITION, HEADING, POSE_TIME, MEASURED_SPEED)

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


def register_bulk_read(first, count, tag):
    """(ext) `02 first count tagMSB tagLSB`: `count` (1 to 8) consecutive addresses,
    each answered by its own reply with this tag, in address order."""
    return REGISTER_READ, struct.pack(">BBBH", 0x02, first, count, tag)


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


def parse_pose_time(data):
    """Milliseconds of the controller's clock (wrapping at 2**32)."""
    return struct.unpack("<I", bytes(data[:4]))[0]


def parse_measured_speed(data):
    """mm/s forward, mrad/s clockwise, and each wheel's rad/s (forward positive)."""
    linear, rotation, left, right = struct.unpack("<hhhh", bytes(data[:8]))
    return linear, rotation, left / 100, right / 100


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


# Firmware update (ext), "Firmware update (ext)" in docs/protocol.md: 11-bit IDs as all.
UPDATE_COMMAND = 0x2E8
UPDATE_DATA = 0x2EC
UPDATE_REPLY = 0x2EA

REG_BOOT_INFO = 50
BOOT_ACTIVATED = 0x02
BOOT_ROLLED_BACK = 0x04

# A window covers 4096 image bytes, 7 to a data frame; a READY n lets the PC send up to
# frame n + 23 (READY comes every 12 frames).
WINDOW_LEN = 4096
DATA_BYTES = 7
FRAMES_PER_READY = 24
DIGEST_PARTS = 8

OP_QUERY, OP_BEGIN, OP_DIGEST, OP_WINDOW, OP_FINISH = 0x01, 0x02, 0x03, 0x04, 0x05
OP_ACTIVATE, OP_ABORT, OP_CONFIRM, OP_ROLLBACK = 0x06, 0x07, 0x08, 0x09
OP_DATA = 0x00  # the opcode a REFUSED names for a data frame

BEGIN_FORCE = 0x01
BEGIN_ALLOW_DOWNGRADE = 0x02

PHASES = ["idle", "receiving", "writing", "finished", "activating", "on trial"]

DONE_BEGUN, DONE_FINISHED, DONE_ACTIVATED, DONE_ABORTED = 1, 2, 3, 4
DONE_CONFIRMED, DONE_ROLLED_BACK = 5, 6

UPDATE_ERRORS = {
    1: "Busy", 2: "NotAtRest", 3: "ControlActive", 4: "OnTrial", 5: "NoSession",
    6: "OutOfOrder", 7: "Duplicate", 8: "BadCrc", 9: "WrongWindow", 10: "BadImage",
    11: "Downgrade", 12: "SameVersion", 13: "TooLarge", 14: "DigestMismatch",
    15: "Incomplete", 16: "FlashFailed", 17: "NotOnTrial", 18: "TimedOut",
    19: "Malformed", 20: "NotFinished", 21: "Writing", 22: "Untrusted",
    23: "SecurityDowngrade", 24: "NotTrialOwner",
}
ERROR_CODES = {name: code for code, name in UPDATE_ERRORS.items()}

# Status frame byte 4 while an update holds the motion lock.
REJECT_UPDATE_IN_PROGRESS = 0x50


def update_query():
    return UPDATE_COMMAND, bytes([OP_QUERY])


def update_begin(session, size, flags=0):
    return UPDATE_COMMAND, bytes([OP_BEGIN, session]) + size.to_bytes(3, "little") + bytes([flags])


def update_digest(session, part, digest):
    return UPDATE_COMMAND, bytes([OP_DIGEST, session, part]) + digest[4 * part:4 * part + 4]


def update_window(session, index, crc):
    return UPDATE_COMMAND, struct.pack("<BBHI", OP_WINDOW, session, index, crc)


def update_data(seq, chunk):
    """One data frame: `seq` (index in the window, mod 256) and up to 7 bytes, padded."""
    return UPDATE_DATA, bytes([seq % 256]) + chunk.ljust(DATA_BYTES, b"\x00")


def update_finish(session):
    return UPDATE_COMMAND, bytes([OP_FINISH, session])


def update_activate(session):
    return UPDATE_COMMAND, bytes([OP_ACTIVATE, session])


def update_abort(session):
    return UPDATE_COMMAND, bytes([OP_ABORT, session])


def update_confirm(session):
    """`session`: the one that activated the image on trial (0: none)."""
    return UPDATE_COMMAND, bytes([OP_CONFIRM, session])


def update_rollback(session):
    return UPDATE_COMMAND, bytes([OP_ROLLBACK, session])


def window_count(size):
    return (size + WINDOW_LEN - 1) // WINDOW_LEN


def window_bytes(image, index):
    return image[index * WINDOW_LEN:(index + 1) * WINDOW_LEN]


def window_frames(window):
    """The data frames of one window, in order."""
    return [update_data(seq, window[at:at + DATA_BYTES])
            for seq, at in enumerate(range(0, len(window), DATA_BYTES))]


@dataclass
class UpdateReply:
    """One 0x2EA frame. `kind` is "state", "version", "ready", "written", "done" or
    "refused"; the other fields are those the kind carries."""
    kind: str
    session: int = None
    phase: int = None
    slot: int = None
    windows: int = None
    # STATE bytes 6 and 7: only signed images activate; the running security version
    # (0 and 0 from a firmware that sends six bytes, as it behaved).
    signatures_required: bool = None
    security_version: int = None
    part: int = None
    text: bytes = None
    window: int = None
    next: int = None
    step: int = None
    opcode: int = None
    error: int = None
    detail: int = None

    def __str__(self):
        if self.kind == "refused":
            name = UPDATE_ERRORS.get(self.error, "?")
            return (f"REFUSED(op {self.opcode:#04x}, {name}, detail {self.detail}, "
                    f"session {self.session})")
        fields = {k: v for k, v in vars(self).items() if v is not None and k != "kind"}
        return f"{self.kind.upper()}{fields}"


def parse_update_reply(data):
    data = bytes(data)
    kind = data[0]
    if kind == 0x81 and len(data) >= 6:
        return UpdateReply("state", phase=data[1], session=data[2], slot=data[3],
                           windows=int.from_bytes(data[4:6], "little"),
                           signatures_required=len(data) > 6 and bool(data[6] & 1),
                           security_version=data[7] if len(data) > 7 else 0)
    if kind == 0x82 and len(data) >= 2:
        return UpdateReply("version", part=data[1], text=data[2:8].ljust(6, b"\x00"))
    if kind == 0x83 and len(data) >= 6:
        return UpdateReply("ready", session=data[1], window=int.from_bytes(data[2:4], "little"),
                           next=int.from_bytes(data[4:6], "little"))
    if kind == 0x84 and len(data) >= 4:
        return UpdateReply("written", session=data[1],
                           window=int.from_bytes(data[2:4], "little"))
    if kind == 0x85 and len(data) >= 3:
        return UpdateReply("done", session=data[1], step=data[2])
    if kind == 0xFF and len(data) >= 4:
        # Byte 4: the session the refusal answers (0: none; absent from older firmware).
        return UpdateReply("refused", opcode=data[1], error=data[2], detail=data[3],
                           session=data[4] if len(data) > 4 else 0)
    raise ValueError(f"not an update reply: {data.hex()}")
