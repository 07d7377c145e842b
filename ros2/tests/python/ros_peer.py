"""A ROS 2 peer of base-ros2 on Cyclone DDS (the DDS behind rmw_cyclonedds), for the
tests in ros2/tests/dds.rs: it publishes /cmd_vel and reads /odom,
/tf, /battery_state and /diagnostics with ROS 2's type and topic names on the wire.

    python3 ros_peer.py scenarios   # the end-to-end checks; prints PASS lines
    python3 ros_peer.py stamped     # /cmd_vel as TwistStamped (base-ros2 --stamped)
    python3 ros_peer.py latency N HOST PORT   # /cmd_vel -> 0x0C8 on the bus, N times

In `scenarios`, the peer prints `ESTOP?` when it wants the e-stop pressed on the
simulator's console and waits for a line on stdin. ROS_DOMAIN_ID picks the domain.
Any failed check ends it with exit code 1 and says what was expected."""

import math
import os
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros_types import (
    BatteryState, DiagnosticArray, Header, Odometry, TFMessage, Time, Twist, TwistStamped,
    Vector3, yaw)

# ROS 2's default QoS: reliable, volatile, keep the last 10.
QOS = Qos(Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
          Policy.Durability.Volatile, Policy.History.KeepLast(10))


class Failed(Exception):
    pass


def check(condition, what):
    if not condition:
        raise Failed(what)
    print(f"PASS {what}", flush=True)


class Peer:
    def __init__(self, stamped=False):
        domain = int(os.environ.get("ROS_DOMAIN_ID", "0"))
        self.participant = DomainParticipant(domain)
        p = self.participant
        self.stamped = stamped
        self.cmd_vel = DataWriter(
            p, Topic(p, "rt/cmd_vel", TwistStamped if stamped else Twist), qos=QOS)
        self.types = {"odom": Odometry, "tf": TFMessage, "battery": BatteryState,
                      "diagnostics": DiagnosticArray}
        topics = {"odom": "rt/odom", "tf": "rt/tf", "battery": "rt/battery_state",
                  "diagnostics": "rt/diagnostics"}
        self.readers = {name: DataReader(p, Topic(p, topics[name], kind), qos=QOS)
                        for name, kind in self.types.items()}
        self.last = {name: None for name in self.readers}
        self.count = {name: 0 for name in self.readers}
        self.diagnostics = []

    def pump(self):
        for name, reader in self.readers.items():
            for sample in reader.take(N=100):
                if not isinstance(sample, self.types[name]):
                    continue  # an invalid sample (instance state change)
                self.last[name] = sample
                self.count[name] += 1
                if name == "diagnostics":
                    self.diagnostics.append(sample)

    def drive(self, linear_x, angular_z, seconds, rate_hz=20.0, stamp_age=None):
        """Publishes one Twist `rate_hz` times a second for `seconds`; stamped
        `stamp_age` seconds in the past if given (else the stamp is left unset)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            twist = Twist(linear=Vector3(x=linear_x), angular=Vector3(z=angular_z))
            if self.stamped:
                header = Header(frame_id="base_link")
                if stamp_age is not None:
                    ns = time.time_ns() - int(stamp_age * 1e9)
                    header.stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
                twist = TwistStamped(header=header, twist=twist)
            self.cmd_vel.write(twist)
            self.wait(1.0 / rate_hz)

    def wait(self, seconds):
        end = time.monotonic() + seconds
        while True:
            self.pump()
            left = end - time.monotonic()
            if left <= 0:
                return
            time.sleep(min(left, 0.01))

    def wait_for(self, predicate, seconds, what):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pump()
            if predicate():
                return
            time.sleep(0.01)
        raise Failed(f"within {seconds} s: {what}")

    def odom(self):
        return self.last["odom"]


def scenarios():
    peer = Peer()
    peer.wait_for(lambda: peer.odom() is not None, 20, "/odom arrives (discovery)")
    first = peer.odom()
    check(first.header.frame_id == "odom" and first.child_frame_id == "base_link",
          f"/odom frames are odom -> base_link (got {first.header.frame_id!r} -> "
          f"{first.child_frame_id!r})")
    # A fresh simulator starts at zero (the reset is a service, tested with rclpy in
    # ros2/tests/rclpy.rs).
    check(abs(first.pose.pose.position.x) < 1e-3 and abs(yaw(first.pose.pose.orientation)) < 1e-3,
          "/odom starts at zero")

    # Forward, 0.3 m/s for 2 s.
    peer.drive(0.3, 0.0, 2.0)
    odom = peer.odom()
    x = odom.pose.pose.position.x
    y = odom.pose.pose.position.y
    check(x > 0.2, f"driving forward (linear.x 0.3 m/s for 2 s) moves /odom x forward in "
                   f"metres: x = {x:.3f} m")
    check(x < 0.7, f"... and not more than the commanded 0.6 m: x = {x:.3f} m")
    check(abs(y) < 0.02, f"... straight: y = {y:.4f} m")
    v = odom.twist.twist.linear.x
    check(0.15 < v < 0.4, f"/odom twist linear.x is the forward speed: {v:.3f} m/s")
    check(peer.count["tf"] > 0, "odom -> base_link arrives on /tf")
    tf = peer.last["tf"].transforms[0]
    check(tf.header.frame_id == "odom" and tf.child_frame_id == "base_link"
          and abs(tf.transform.translation.x - x) < 0.1,
          f"/tf carries the same pose (x {tf.transform.translation.x:.3f} m)")

    # Stale /cmd_vel: stop publishing, the base must stop by itself.
    peer.wait(1.5)
    stopped = peer.odom()
    peer.wait(0.5)
    moved = peer.odom().pose.pose.position.x - stopped.pose.pose.position.x
    v = peer.odom().twist.twist.linear.x
    check(abs(v) < 0.01 and abs(moved) < 0.005,
          f"a stale /cmd_vel stops the base: twist {v:.4f} m/s, moved {moved * 1000:.1f} mm "
          f"in 0.5 s")

    # Counter-clockwise in ROS: angular.z > 0 -> yaw grows positive.
    yaw_before = yaw(peer.odom().pose.pose.orientation)
    peer.drive(0.0, 0.5, 2.0)
    odom = peer.odom()
    turned = yaw(odom.pose.pose.orientation) - yaw_before
    check(turned > 0.3, f"a counter-clockwise turn (angular.z +0.5 rad/s for 2 s) turns /odom "
                        f"yaw positive: {turned:.3f} rad")
    check(turned < 1.1, f"... by at most the commanded 1 rad: {turned:.3f} rad")
    w = odom.twist.twist.angular.z
    check(0.25 < w < 0.7, f"/odom twist angular.z is positive counter-clockwise: {w:.3f} rad/s")
    peer.wait(1.5)

    # A NaN /cmd_vel is refused and counted.
    peer.cmd_vel.write(Twist(linear=Vector3(x=math.nan)))
    peer.wait_for(lambda: any(value.key == "cmd_vel_not_finite" and value.value == "1"
                              for array in peer.diagnostics[-1:]
                              for status in array.status for value in status.values),
                  4, "/diagnostics counts the NaN /cmd_vel (cmd_vel_not_finite 1)")
    print("PASS a NaN /cmd_vel is refused and counted in /diagnostics", flush=True)
    latest = peer.diagnostics[-1].status[0]
    values = {value.key: value.value for value in latest.values}
    # A fresh simulator's blank flash is a latched flash fault: a warning, not an error.
    check(latest.level < 2 and values.get("mode") == "Standby"
          and values.get("estop_pressed") == "no",
          f"/diagnostics before the e-stop: level {latest.level}, {latest.message!r}")

    # The running image's whole version, from the update's QUERY the node sends each 5 s.
    def image_version():
        for array in peer.diagnostics[-1:]:
            for status in array.status:
                values = {value.key: value.value for value in status.values}
                if values.get("firmware_image", "unknown").count(".") >= 2:
                    return values["firmware_image"]
        return None
    peer.wait_for(image_version, 7, "/diagnostics names the firmware image's version")
    print(f"PASS /diagnostics names the firmware image: {image_version()}", flush=True)

    battery = peer.last["battery"]
    peer.wait_for(lambda: peer.last["battery"] is not None, 7, "/battery_state arrives")
    battery = peer.last["battery"]
    check(battery.voltage > 1.0 and 0.0 <= battery.percentage <= 1.0,
          f"/battery_state in volts and 0..1: {battery.voltage:.2f} V, "
          f"{battery.percentage:.2f}")

    # The e-stop, pressed on the simulator's console.
    print("ESTOP?", flush=True)
    sys.stdin.readline()
    def estop_shown():
        for array in peer.diagnostics[-1:]:
            for status in array.status:
                values = {value.key: value.value for value in status.values}
                if (status.level == 2 and "e-stop pressed" in status.message
                        and values.get("mode") == "Emergency"
                        and values.get("estop_pressed") == "yes"):
                    return True
        return False
    peer.wait_for(estop_shown, 4, "/diagnostics shows ERROR 'Emergency: e-stop pressed'")
    print(f"PASS /diagnostics shows the e-stop: {peer.diagnostics[-1].status[0].message!r}",
          flush=True)
    print("DONE", flush=True)


def stamped():
    """base-ros2 --stamped: geometry_msgs/TwistStamped on /cmd_vel drives as Twist does."""
    peer = Peer(stamped=True)
    peer.wait_for(lambda: peer.odom() is not None, 20, "/odom arrives (discovery)")
    start = peer.odom().pose.pose.position.x
    peer.drive(0.3, -0.2, 1.5)
    odom = peer.odom()
    moved = odom.pose.pose.position.x - start
    check(moved > 0.15, f"a TwistStamped forward moves /odom x: {moved:.3f} m")
    w = odom.twist.twist.angular.z
    check(w < -0.1, f"a TwistStamped clockwise turn (angular.z -0.2) is a negative yaw rate: "
                    f"{w:.3f} rad/s")
    # Stamped 2 s ago, older than cmd_vel_timeout (0.5 s): dropped, so the base stops
    # within the timeout and its ramp, and stays.
    peer.drive(0.3, 0.0, 1.5, stamp_age=2.0)
    x = peer.odom().pose.pose.position.x
    peer.drive(0.3, 0.0, 1.0, stamp_age=2.0)
    moved = peer.odom().pose.pose.position.x - x
    check(abs(moved) < 0.005, f"TwistStamped 2 s old do not drive: {moved * 1000:.1f} mm")
    # A fresh stamp drives again.
    x = peer.odom().pose.pose.position.x
    peer.drive(0.3, 0.0, 1.0, stamp_age=0.0)
    moved = peer.odom().pose.pose.position.x - x
    check(moved > 0.1, f"a freshly stamped TwistStamped drives: {moved:.3f} m")
    print("DONE", flush=True)


def latency(count, host, port):
    """/cmd_vel published -> its 0x0C8 frame seen on the bus by a socketcand client,
    `count` times, each a new speed so each frame is matched to its command."""
    import can
    bus = can.Bus(interface="socketcand", host=host, port=int(port), channel="can0")
    peer = Peer()
    # Discovery: drive until the bridge's first 0x0C8 shows up.
    end = time.monotonic() + 20
    while True:
        peer.cmd_vel.write(Twist(linear=Vector3(x=0.001)))
        message = bus.recv(0.05)
        if message is not None and message.arbitration_id == 0x0C8:
            break
        if time.monotonic() > end:
            raise Failed("no 0x0C8 within 20 s of publishing /cmd_vel")
    delays = []
    for i in range(count):
        speed_mm = 10 + (i % 200)  # 10..209 mm/s, never the previous value
        sent = time.monotonic_ns()
        peer.cmd_vel.write(Twist(linear=Vector3(x=speed_mm / 1000.0)))
        deadline = time.monotonic() + 0.5
        while True:
            message = bus.recv(max(0.0, deadline - time.monotonic()))
            if message is None:
                raise Failed(f"command {i} ({speed_mm} mm/s) not on the bus within 0.5 s")
            if message.arbitration_id == 0x0C8 and \
                    int.from_bytes(message.data[0:2], "little", signed=True) == speed_mm:
                delays.append((time.monotonic_ns() - sent) / 1e6)
                break
        time.sleep(0.02)  # 50 Hz, like a fast teleop or Nav2's controller
    bus.shutdown()
    delays.sort()
    def pct(p):
        return delays[min(len(delays) - 1, int(round(p / 100.0 * (len(delays) - 1))))]
    print(f"LATENCY n={len(delays)} p50={pct(50):.2f} p99={pct(99):.2f} "
          f"max={delays[-1]:.2f} min={delays[0]:.2f} ms", flush=True)


if __name__ == "__main__":
    try:
        if sys.argv[1] == "scenarios":
            scenarios()
        elif sys.argv[1] == "stamped":
            stamped()
        elif sys.argv[1] == "latency":
            latency(int(sys.argv[2]), sys.argv[3], sys.argv[4])
        else:
            raise SystemExit(f"unknown mode {sys.argv[1]!r}")
    except Failed as failure:
        print(f"FAIL {failure}", flush=True)
        sys.exit(1)
