#!/usr/bin/env python3
"""Several python-can programs on the simulator's bus at once, through socketcand.

    python3 sim/tests/python/socketcand_clients.py [HOST] [PORT] [CLIENTS]

defaults 127.0.0.1 29536 3. Each client (a python-can `socketcand` bus of its own,
on a thread of its own) sends 40 frames with an ID of its own, reads register 15
(loop_end_delay) ten times, taking turns with the others so that each reply belongs
to one request, and records everything it receives. Exits 0 when every client got
every one of its replies, every frame of every other client exactly once and none of
its own (a node does not receive its own frames), and the controller's status frames.
"""

import sys
import threading
import time

import can

REGISTER_READ, STATUS = 0x004, 0x0EE
FRAMES_EACH, READS_EACH = 40, 10
OWN_ID_BASE = 0x7F0


def run_client(number, host, port, start, register_turn, results):
    received = []
    replies = 0
    with can.Bus(interface="socketcand", host=host, port=port, channel="can0") as bus:
        start.wait()

        def drain(seconds):
            end = time.monotonic() + seconds
            while (message := bus.recv(timeout=max(0.0, end - time.monotonic()))) is not None:
                received.append(message)
                if time.monotonic() >= end:
                    break

        for i in range(FRAMES_EACH):
            bus.send(can.Message(arbitration_id=OWN_ID_BASE + number, data=[number, i],
                                 is_extended_id=False))
            drain(0.005)
        for _ in range(READS_EACH):
            with register_turn:
                bus.send(can.Message(arbitration_id=REGISTER_READ, data=[0x01, 15],
                                     is_extended_id=False))
                deadline = time.monotonic() + 1.0
                while time.monotonic() < deadline:
                    message = bus.recv(timeout=max(0.0, deadline - time.monotonic()))
                    if message is None:
                        break
                    received.append(message)
                    if message.arbitration_id == REGISTER_READ and message.data[:1] == b"\x00":
                        replies += 1
                        break
        drain(1.5)
    results[number] = (received, replies)


def main() -> int:
    host = sys.argv[1] if len(sys.argv) > 1 else "127.0.0.1"
    port = int(sys.argv[2]) if len(sys.argv) > 2 else 29536
    clients = int(sys.argv[3]) if len(sys.argv) > 3 else 3
    start = threading.Barrier(clients)
    register_turn = threading.Lock()
    results = {}
    threads = [threading.Thread(target=run_client,
                                args=(n, host, port, start, register_turn, results))
               for n in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    failures = []
    for number in range(clients):
        if number not in results:
            failures.append(f"client {number} did not finish")
            continue
        received, replies = results[number]
        if replies != READS_EACH:
            failures.append(f"client {number}: {replies} of {READS_EACH} register replies")
        for other in range(clients):
            frames = [m for m in received if m.arbitration_id == OWN_ID_BASE + other]
            expected = 0 if other == number else FRAMES_EACH
            if len(frames) != expected:
                failures.append(f"client {number}: {len(frames)} frames of client {other}, "
                                f"expected {expected}")
            elif expected and [m.data[1] for m in frames] != list(range(FRAMES_EACH)):
                failures.append(f"client {number}: client {other}'s frames out of order")
        statuses = sum(1 for m in received if m.arbitration_id == STATUS)
        if statuses == 0:
            failures.append(f"client {number}: no status frame")
        print(f"client {number}: {len(received)} frames, {replies} register replies, "
              f"{statuses} status frames")
    for failure in failures:
        print("FAIL:", failure)
    if failures:
        return 1
    print(f"OK: {clients} python-can clients shared the bus through socketcand")
    return 0


if __name__ == "__main__":
    sys.exit(main())
