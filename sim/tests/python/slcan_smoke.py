#!/usr/bin/env python3
"""Smoke test: python-can drives the simulator over SLCAN and sees the pose move.

Start the simulator first (`cargo run -p virtual-robot`), then:
    python3 sim/tests/python/slcan_smoke.py [CHANNEL]
CHANNEL defaults to the simulator's link, /tmp/virtual-base-controller.
Exits 0 when x grew by more than 150 mm while driving at 300 mm/s for 3 s.
"""

import struct
import sys
import time

import can

ENABLE, VELOCITY, POSITION = 0x2E4, 0x0C8, 0x0EC


def main() -> int:
    channel = sys.argv[1] if len(sys.argv) > 1 else "/tmp/virtual-base-controller"
    with can.Bus(interface="slcan", channel=channel, bitrate=500000, sleep_after_open=0) as bus:
        enable = can.Message(arbitration_id=ENABLE, data=[0x40, 0, 0, 0, 0, 0, 0, 0], is_extended_id=False)
        velocity = can.Message(
            arbitration_id=VELOCITY, data=struct.pack("<hhB", 300, 0, 3), is_extended_id=False
        )
        first_x = last_x = None
        frames = 0
        end = time.monotonic() + 4.0
        while time.monotonic() < end:
            bus.send(enable)
            bus.send(velocity)
            deadline = time.monotonic() + 0.05
            while (message := bus.recv(timeout=max(0.0, deadline - time.monotonic()))) is not None:
                if message.arbitration_id == POSITION and message.dlc == 8:
                    x, y = struct.unpack("<ii", bytes(message.data))
                    first_x = x if first_x is None else first_x
                    last_x = x
                    frames += 1
        # Stop: withdraw the enable.
        bus.send(can.Message(arbitration_id=ENABLE, data=[0] * 8, is_extended_id=False))
    print(f"{frames} position frames, x from {first_x} mm to {last_x} mm")
    if first_x is None or last_x - first_x <= 150:
        print("FAIL: the pose did not move")
        return 1
    print("OK: python-can drove the simulator over SLCAN")
    return 0


if __name__ == "__main__":
    sys.exit(main())
