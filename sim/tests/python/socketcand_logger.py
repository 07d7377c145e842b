#!/usr/bin/env python3
"""A python-can logger on the simulator's socketcand server, beside other programs.

    python3 sim/tests/python/socketcand_logger.py HOST PORT SECONDS

Logs every frame for SECONDS and exits 0 if the controller's status frame (0x0EE,
once a second) came at least once every 1.5 s throughout, so that no stretch of the
bus went missing.
"""

import sys
import time

import can

STATUS = 0x0EE


def main() -> int:
    host, port, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    frames, status_times = 0, []
    with can.Bus(interface="socketcand", host=host, port=port, channel="can0") as bus:
        end = time.monotonic() + seconds
        while (now := time.monotonic()) < end:
            message = bus.recv(timeout=end - now)
            if message is None:
                continue
            frames += 1
            if message.arbitration_id == STATUS:
                status_times.append(time.monotonic())
    gaps = [b - a for a, b in zip(status_times, status_times[1:])]
    longest = max(gaps, default=float("inf"))
    print(f"logger: {frames} frames, {len(status_times)} status frames, "
          f"longest gap {longest:.2f} s")
    if len(status_times) < seconds - 2 or longest > 1.5:
        print("FAIL: the logger missed part of the bus")
        return 1
    print("OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
