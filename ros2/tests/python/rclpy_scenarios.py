"""base-ros2 as a ROS 2 user sees it: rclpy on Fast DDS (ROS 2 Jazzy's default
middleware, from the PyPI wheels .ci/install-ros2 installs), with the simulator as the
base. Run by ros2/tests/rclpy.rs inside a network namespace of its own:

    python rclpy_scenarios.py SOCKETCAND_HOST SOCKETCAND_PORT

Each scenario prints `PASS name: detail` or `FAIL name: detail`; the last line is
`SCENARIOS passed=N failed=M`. Measurements print `FIGURE ...` lines. The peer asks the
harness for what only it can do with a line on stdout and waits for a line on stdin:
`ESTOP?` (press the e-stop on the simulator's console), `SIGTERM?` (end base-ros2).
"""

import math
import random
import sys
import threading
import time
import traceback

import can
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Log, Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from sensor_msgs.msg import BatteryState, JointState
from std_srvs.srv import Trigger

NODE = "/base_ros2"
# The base's feedback period (register loop_end_delay, default 50 ms).
CYCLE_S = 0.05
# The twist comes from the speed the drives measured (0x0F0): in steady driving within
# 1 % of the speed at which the base's own poses move, however late the frames arrive.
# (From pose differences it could only be exact to the poses' rounding, 1 mm / 50 ms =
# 0.02 m/s.) That speed is the command's within 2 %: the default calibration factors
# (f_lin 1.0071) and the whole r/min the drives turn at.
LINEAR_TOLERANCE = 0.003
ANGULAR_TOLERANCE = 0.005
CALIBRATED = 0.02
# /odom's stamps are the poses' moments on the controller's clock, mapped to ROS time.
STAMP_SPREAD_S = 0.002


class Failed(Exception):
    pass


def check(condition, what):
    if not condition:
        raise Failed(what)


def yaw(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def percentile(values, p):
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(p / 100.0 * (len(ordered) - 1))))]


class BusWatch:
    """Every frame on the bus with its arrival time, from a socketcand client."""

    def __init__(self, host, port):
        self.bus = can.Bus(interface="socketcand", host=host, port=int(port), channel="can0")
        self.lock = threading.Lock()
        self.velocities = []   # (time, linear mm/s, rotation mrad/s)
        # (time, x mm, y mm, heading mrad, pose time ms or None, wall-clock time)
        self.poses = []
        self._position = None
        self._pose_time = None
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while self.running:
            message = self.bus.recv(0.05)
            if message is None:
                continue
            now = time.monotonic()
            data = bytes(message.data)
            with self.lock:
                if message.arbitration_id == 0x0C8 and len(data) >= 5:
                    self.velocities.append((now, int.from_bytes(data[0:2], "little", signed=True),
                                            int.from_bytes(data[2:4], "little", signed=True)))
                elif message.arbitration_id == 0x0EF and len(data) == 4:
                    self._pose_time = int.from_bytes(data, "little")
                elif message.arbitration_id == 0x0EC and len(data) == 8:
                    self._position = (int.from_bytes(data[0:4], "little", signed=True),
                                      int.from_bytes(data[4:8], "little", signed=True))
                elif message.arbitration_id == 0x0ED and len(data) == 4 and self._position:
                    heading = int.from_bytes(data[0:4], "little", signed=True)
                    self.poses.append((now, *self._position, heading, self._pose_time,
                                       time.time()))
                    self._position = None
                    self._pose_time = None

    def close(self):
        self.running = False
        self.thread.join()
        self.bus.shutdown()


class Peer(Node):
    def __init__(self):
        super().__init__("ros2_scenarios")
        default = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
        self.cmd_vel = self.create_publisher(Twist, "/cmd_vel", 10)
        self.odoms = []      # (arrival monotonic, Odometry)
        self.joints = []     # (arrival monotonic, JointState)
        self.diagnostics = []
        self.batteries = []
        self.logs = []
        # Nav2's controller and robot_localization read /odom as a reliable,
        # volatile keep-last-10 subscriber (rclcpp's default).
        self.create_subscription(Odometry, "/odom", self._odom, default)
        self.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append,
                                 default)
        self.create_subscription(BatteryState, "/battery_state", self.batteries.append, default)
        self.create_subscription(JointState, "/joint_states",
                                 lambda message: self.joints.append((time.monotonic(), message)),
                                 default)
        # /rosout as `ros2 topic echo /rosout` reads it.
        rosout_qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                history=HistoryPolicy.KEEP_LAST)
        self.create_subscription(Log, "/rosout", self.logs.append, rosout_qos)
        self.reset = self.create_client(Trigger, "/reset_odometry")

    def _odom(self, message):
        self.odoms.append((time.monotonic(), message))

    def spin_for(self, seconds):
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            rclpy.spin_once(self, timeout_sec=min(left, 0.005))

    def wait_for(self, predicate, seconds, what):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self, timeout_sec=0.01)
            if predicate():
                return
        raise Failed(f"not within {seconds} s: {what}")

    def odom(self):
        return self.odoms[-1][1] if self.odoms else None

    def drive(self, linear_x, angular_z, seconds, rate_hz=20.0):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            twist = Twist()
            twist.linear.x = float(linear_x)
            twist.angular.z = float(angular_z)
            self.cmd_vel.publish(twist)
            self.spin_for(1.0 / rate_hz)

    def call(self, client, request, seconds=5.0):
        check(client.wait_for_service(timeout_sec=10.0), f"service {client.srv_name} is offered")
        future = client.call_async(request)
        rclpy.spin_until_future_complete(self, future, timeout_sec=seconds)
        check(future.done(), f"{client.srv_name} answered within {seconds} s")
        return future.result()

    def reset_odometry(self):
        """Calls the reset service; the first /odom after its answer."""
        response = self.call(self.reset, Trigger.Request())
        check(response.success, f"reset_odometry succeeded: {response.message!r}")
        count = len(self.odoms)
        self.wait_for(lambda: len(self.odoms) > count, 2, "an /odom after the reset")
        return self.odoms[count][1]

    def standing(self, seconds=0.3):
        """The pose has not changed over the last `seconds` of /odom."""
        if not self.odoms or self.odoms[-1][0] - self.odoms[0][0] < seconds:
            return False
        last = self.odoms[-1][1].pose.pose
        for arrived, message in reversed(self.odoms):
            pose = message.pose.pose
            if (pose.position.x, pose.position.y, pose.orientation.z) != \
                    (last.position.x, last.position.y, last.orientation.z):
                return False
            if arrived < self.odoms[-1][0] - seconds:
                return True
        return True

    def stopped(self):
        """Waits until the base stands: the pose unchanged for 0.3 s."""
        self.wait_for(self.standing, 5, "the base stops")


def ask(line):
    print(line, flush=True)
    sys.stdin.readline()


# ---- The scenarios ----

def graph_and_types(peer):
    def found():
        return ("base_ros2", "/") in peer.get_node_names_and_namespaces()
    peer.wait_for(found, 20, "base_ros2 in the graph")
    topics = dict(peer.get_topic_names_and_types())
    expected = {
        "/cmd_vel": "geometry_msgs/msg/Twist",
        "/odom": "nav_msgs/msg/Odometry",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/battery_state": "sensor_msgs/msg/BatteryState",
        "/joint_states": "sensor_msgs/msg/JointState",
        "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
        "/rosout": "rcl_interfaces/msg/Log",
    }
    def all_there():
        topics.update(dict(peer.get_topic_names_and_types()))
        return all(kind in topics.get(name, []) for name, kind in expected.items())
    peer.wait_for(all_there, 10, f"the topics and types {expected}; seen {topics}")
    services = dict(peer.get_service_names_and_types_by_node("base_ros2", "/"))
    check(services.get("/reset_odometry") == ["std_srvs/srv/Trigger"],
          f"the reset service is std_srvs/srv/Trigger: {services}")
    for name in ("get_parameters", "list_parameters", "set_parameters", "describe_parameters"):
        check(f"{NODE}/{name}" in services, f"{NODE}/{name} is offered: {sorted(services)}")
    hashes = {str(info.topic_type_hash) for info in peer.get_publishers_info_by_topic("/odom")}
    return f"{len(expected)} topics, the reset and parameter services; /odom type hash {hashes}"


def qos(peer):
    for topic in ("/odom", "/tf", "/diagnostics", "/battery_state", "/joint_states"):
        infos = peer.get_publishers_info_by_topic(topic)
        check(len(infos) == 1, f"one publisher of {topic}: {infos}")
        profile = infos[0].qos_profile
        # Nav2, robot_localization, tf2's listener and the diagnostic aggregator all
        # ask for reliable (or best effort) and volatile: a reliable volatile writer
        # serves them all.
        check(profile.reliability == ReliabilityPolicy.RELIABLE
              and profile.durability == DurabilityPolicy.VOLATILE,
              f"{topic} is offered reliable and volatile: {profile}")
    infos = peer.get_subscriptions_info_by_topic("/cmd_vel")
    profile = infos[0].qos_profile
    check(profile.reliability == ReliabilityPolicy.BEST_EFFORT,
          f"/cmd_vel is read best effort, so that any teleop's writer matches: {profile}")
    peer.wait_for(lambda: len(peer.odoms) >= 5 and peer.diagnostics, 5,
                  "/odom and /diagnostics reach reliable volatile readers")
    return ("/odom, /tf, /diagnostics, /battery_state, /joint_states reliable+volatile; "
            "/cmd_vel best effort")


def odom_rate_and_stamps(peer):
    start = len(peer.odoms)
    peer.spin_for(3.0)
    window = peer.odoms[start:]
    rate = (len(window) - 1) / (window[-1][0] - window[0][0])
    check(abs(rate - 20.0) < 1.0, f"/odom at 20 Hz: {rate:.2f} Hz")
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in window]
    check(all(b > a for a, b in zip(stamps, stamps[1:])), "stamps strictly increase")
    now = peer.get_clock().now().nanoseconds * 1e-9
    check(abs(now - stamps[-1]) < 0.5, f"stamps are the ROS time: {now - stamps[-1]:.3f} s old")
    last = window[-1][1]
    check(last.header.frame_id == "odom" and last.child_frame_id == "base_link",
          f"odom -> base_link: {last.header.frame_id} -> {last.child_frame_id}")
    return f"{rate:.2f} Hz, stamps increasing"


def reset_by_service(peer):
    peer.drive(0.3, 0.0, 1.0)
    peer.stopped()
    check(peer.odom().pose.pose.position.x > 0.1, "the base moved before the reset")
    first = peer.reset_odometry()
    x = first.pose.pose.position.x
    check(abs(x) < 0.002 and abs(yaw(first.pose.pose.orientation)) < 0.002,
          f"the first /odom after the answer is at zero: x {x:.4f} m")
    return "the answer comes after the reset shows in /odom"


def bus_steps(peer, since):
    """The smallest and largest x step (mm) between successive poses the base sent."""
    with peer.watch.lock:
        xs = [pose[1] for pose in peer.watch.poses if pose[0] >= since]
    steps = [b - a for a, b in zip(xs, xs[1:])]
    return (min(steps), max(steps)) if steps else None


def pose_rate(peer, since):
    """The speed (m/s forward, rad/s counter-clockwise) at which the base's poses moved
    from `since` on, over their times on the controller's clock."""
    with peer.watch.lock:
        poses = [pose for pose in peer.watch.poses if pose[0] >= since and pose[4] is not None]
    check(len(poses) >= 10, f"{len(poses)} poses with their times on the bus")
    first, last = poses[0], poses[-1]
    span_s = ((last[4] - first[4]) % 2**32) / 1000.0
    return (last[1] - first[1]) / 1000.0 / span_s, -(last[3] - first[3]) / 1000.0 / span_s


def frozen_poses(peer, since):
    """How often the base itself sent a pose equal to the one before while the
    /odom twist says it moved: seen on the bus, not through base-ros2."""
    with peer.watch.lock:
        poses = [pose[1:4] for pose in peer.watch.poses if pose[0] >= since]
    return sum(1 for a, b in zip(poses, poses[1:]) if a == b)


def forward(peer):
    peer.reset_odometry()
    start = len(peer.odoms)
    started = time.monotonic()
    peer.drive(0.3, 0.0, 2.5)
    odom = peer.odom()
    x = odom.pose.pose.position.x
    check(0.45 < x < 0.76, f"0.3 m/s for 2.5 s moves x forward: {x:.3f} m")
    check(abs(odom.pose.pose.position.y) < 0.01, f"straight: y {odom.pose.pose.position.y:.4f}")
    # Once at speed (the base accelerates within 0.5 s), every twist is the speed.
    cruise_from = peer.odoms[start][0] + 1.0
    cruise = [m.twist.twist.linear.x for t, m in peer.odoms[start:] if t > cruise_from]
    speed = pose_rate(peer, cruise_from)[0]
    check(abs(speed - 0.3) <= 0.3 * CALIBRATED, f"the poses move at 0.3 m/s: {speed:.4f}")
    worst = max(abs(v - speed) for v in cruise)
    check(worst <= LINEAR_TOLERANCE,
          f"the twist is within {LINEAR_TOLERANCE} m/s of the poses' {speed:.4f} m/s in every "
          f"/odom: worst {worst:.4f} "
          f"(the base sent {frozen_poses(peer, started + 1.0)} poses equal to the one before; "
          f"its x steps per frame were {bus_steps(peer, started + 1.0)} mm)")
    return f"x {x:.3f} m; twist within {worst:.4f} m/s of {speed:.4f} over {len(cruise)} /odom"


def on_the_controllers_clock(peer):
    """3 s at 0.3 m/s: each /odom stamped with its pose's moment on the controller's
    clock, its twist within 1 %, and the wheels' joint states beside it."""
    start, joints_start = len(peer.odoms), len(peer.joints)
    peer.drive(0.3, 0.0, 3.0)
    speed = pose_rate(peer, peer.odoms[start][0] + 1.0)[0]
    with peer.watch.lock:
        poses = list(peer.watch.poses)
    by_pose = {(x, heading): (pose_ms, wall) for _, x, _, heading, pose_ms, wall in poses
               if pose_ms is not None}
    odoms = [m for t, m in peer.odoms[start:] if t > peer.odoms[start][0] + 1.0]
    deviations, late = [], []
    for message in odoms:
        key = (round(message.pose.pose.position.x * 1000),
               round(-yaw(message.pose.pose.orientation) * 1000))
        if key not in by_pose:
            continue
        pose_ms, wall = by_pose[key]
        stamp = message.header.stamp.sec + message.header.stamp.nanosec * 1e-9
        deviations.append(stamp - pose_ms / 1000.0)
        late.append(wall - stamp)
    check(len(deviations) >= 20, f"{len(deviations)} /odom matched to their poses on the bus")
    spread = max(deviations) - min(deviations)
    check(spread <= STAMP_SPREAD_S,
          f"every stamp is its pose's time on the controller's clock plus one offset: the "
          f"offsets spread over {spread * 1000:.2f} ms")
    check(min(late) > -STAMP_SPREAD_S,
          f"no stamp is later than the pose reached the bus: {min(late) * 1000:.2f} ms")
    twist_errors = [abs(m.twist.twist.linear.x - speed) for m in odoms]
    check(max(twist_errors) <= LINEAR_TOLERANCE,
          f"the twist within 1 %: worst {max(twist_errors):.4f} m/s")
    joints = [m for _, m in peer.joints[joints_start:]]
    check(len(joints) >= 40, f"{len(joints)} /joint_states while driving")
    last = joints[-1]
    check(list(last.name) == ["left_wheel_joint", "right_wheel_joint"]
          and len(last.position) == 2 and len(last.velocity) == 2,
          f"both wheels by name, with position and velocity: {last}")
    check(all(v > 0 for v in last.velocity) and abs(last.velocity[0] - last.velocity[1]) < 1e-9,
          f"both wheels turn forward alike: {list(last.velocity)} rad/s")
    turned = last.position[0] - joints[0].position[0]
    span = (last.header.stamp.sec - joints[0].header.stamp.sec) + \
        (last.header.stamp.nanosec - joints[0].header.stamp.nanosec) * 1e-9
    check(turned > 0.9 * last.velocity[0] * span - 0.5,
          f"the left wheel turned {turned:.2f} rad in {span:.2f} s at {last.velocity[0]:.2f} rad/s")
    stamp_errors = sorted((d - min(deviations)) * 1000 for d in deviations)
    print(f"FIGURE twist_error n={len(twist_errors)} p50={percentile(twist_errors, 50):.4f} "
          f"p99={percentile(twist_errors, 99):.4f} m/s", flush=True)
    print(f"FIGURE stamp_error n={len(stamp_errors)} p50={percentile(stamp_errors, 50):.2f} "
          f"p99={percentile(stamp_errors, 99):.2f} ms", flush=True)
    return (f"{len(deviations)} stamps within {spread * 1000:.2f} ms of one offset; twist within "
            f"{max(twist_errors):.4f} m/s; {len(joints)} /joint_states")


def stale_stop(peer):
    peer.drive(0.3, 0.0, 1.0)
    last_command = time.monotonic()
    peer.wait_for(peer.standing, 3, "the base stops without /cmd_vel")
    stopped_after = time.monotonic() - last_command - 0.3
    x = peer.odom().pose.pose.position.x
    peer.spin_for(0.5)
    moved = peer.odom().pose.pose.position.x - x
    check(abs(moved) < 0.001, f"and stays: moved {moved * 1000:.1f} mm")
    return f"stopped {stopped_after:.2f} s after the last /cmd_vel (time-out 0.5 s)"


def counter_clockwise(peer):
    peer.stopped()
    before = yaw(peer.odom().pose.pose.orientation)
    start = len(peer.odoms)
    peer.drive(0.0, 0.5, 2.0)
    turned = yaw(peer.odom().pose.pose.orientation) - before
    check(0.6 < turned < 1.05, f"angular.z +0.5 for 2 s turns yaw positive: {turned:.3f} rad")
    cruise_from = peer.odoms[start][0] + 1.0
    cruise = [m.twist.twist.angular.z for t, m in peer.odoms[start:] if t > cruise_from]
    rate = pose_rate(peer, cruise_from)[1]
    check(abs(rate - 0.5) <= 0.5 * CALIBRATED, f"the poses turn at 0.5 rad/s: {rate:.4f}")
    worst = max(abs(w - rate) for w in cruise)
    check(worst <= ANGULAR_TOLERANCE,
          f"angular.z twist within {ANGULAR_TOLERANCE} of the poses' {rate:.4f}: worst {worst:.4f}")
    return f"turned {turned:.3f} rad; twist within {worst:.4f} rad/s of {rate:.4f}"


def zero_twist_at_goal(peer):
    peer.drive(0.3, 0.0, 1.0)
    # Nav2 at the goal: zero twists, still fresh.
    peer.drive(0.0, 0.0, 1.5)
    odom = peer.odom()
    check(abs(odom.twist.twist.linear.x) < 1e-6, f"zero twist stops the base: "
                                                f"{odom.twist.twist.linear.x:.4f} m/s")
    x = odom.pose.pose.position.x
    peer.drive(0.0, 0.0, 0.5)
    moved = peer.odom().pose.pose.position.x - x
    check(abs(moved) < 0.001, f"and it stays while zeros keep coming: {moved * 1000:.1f} mm")
    return "a fresh zero twist holds the base"


def reset_while_driving(peer):
    """Twelve resets while driving at 0.3 m/s: no /odom carries a velocity spike."""
    start = len(peer.odoms)
    end_drive = time.monotonic() + 0.8
    resets = 0
    while resets < 12:
        twist = Twist()
        twist.linear.x = 0.3
        peer.cmd_vel.publish(twist)
        if time.monotonic() > end_drive:
            future = peer.reset.call_async(Trigger.Request())
            deadline = time.monotonic() + 3
            while not future.done() and time.monotonic() < deadline:
                peer.cmd_vel.publish(twist)
                peer.spin_for(0.05)
            check(future.done() and future.result().success, f"reset {resets} answered")
            resets += 1
            end_drive = time.monotonic() + random.uniform(0.1, 0.4)
        peer.spin_for(0.05)
    window = [m for t, m in peer.odoms[start:] if t > peer.odoms[start][0] + 0.8]
    speed = sorted(m.twist.twist.linear.x for m in window)[len(window) // 2]
    check(abs(speed - 0.3) <= 0.3 * CALIBRATED, f"the base drives at 0.3 m/s: {speed:.4f}")
    worst_v = max(abs(m.twist.twist.linear.x - speed) for m in window)
    worst_w = max(abs(m.twist.twist.angular.z) for m in window)
    check(worst_v <= LINEAR_TOLERANCE and worst_w <= ANGULAR_TOLERANCE,
          f"no velocity spike across 12 resets: worst {worst_v:.4f} m/s off, "
          f"{worst_w:.4f} rad/s")
    return f"12 resets at 0.3 m/s, {len(window)} /odom, twist never off by more than {worst_v:.4f}"


def stream_50hz(peer):
    """A 50 Hz stream of changing speeds for 5 s: no fault, no jump in /odom."""
    start = len(peer.odoms)
    diagnostics_before = len(peer.diagnostics)
    t0 = time.monotonic()
    while (elapsed := time.monotonic() - t0) < 5.0:
        twist = Twist()
        twist.linear.x = 0.25 + 0.2 * math.sin(2 * math.pi * elapsed / 1.7)
        twist.angular.z = 0.4 * math.sin(2 * math.pi * elapsed / 2.3)
        peer.cmd_vel.publish(twist)
        peer.spin_for(0.02)
    peer.stopped()
    modes = {value.value for array in peer.diagnostics[diagnostics_before:]
             for status in array.status for value in status.values if value.key == "mode"}
    check("Fault" not in modes, f"the base did not fault: modes {sorted(modes)}")
    window = [m for _, m in peer.odoms[start:]]
    jumps = []
    for a, b in zip(window, window[1:]):
        dt = (b.header.stamp.sec - a.header.stamp.sec) + \
            (b.header.stamp.nanosec - a.header.stamp.nanosec) * 1e-9
        step = math.hypot(b.pose.pose.position.x - a.pose.pose.position.x,
                          b.pose.pose.position.y - a.pose.pose.position.y)
        if step > 0.5 * max(dt, CYCLE_S) + 0.005:
            jumps.append((round(step, 4), round(dt, 3)))
    check(not jumps, f"no jump in /odom: {jumps[:5]}")
    check(max(abs(m.twist.twist.linear.x) for m in window) < 0.5,
          f"no twist beyond the commanded 0.45 m/s (the base sent {frozen_poses(peer, t0)} "
          f"poses equal to the one before while driving)")
    return f"{len(window)} /odom, modes {sorted(modes)}"


def rosout(peer):
    peer.wait_for(lambda: any(log.name == "base_ros2" for log in peer.logs), 5,
                  "a /rosout line of base_ros2")
    lines = [log.msg for log in peer.logs if log.name == "base_ros2"]
    check(any("odometry reset" in line for line in lines),
          f"the reset is logged on /rosout: {lines[-5:]}")
    return f"{len(lines)} lines, e.g. {lines[-1]!r}"


def parameters(peer):
    get = peer.create_client(GetParameters, f"{NODE}/get_parameters")
    request = GetParameters.Request()
    request.names = ["cmd_vel_timeout", "odom_frame", "hardware_id", "publish_tf"]
    values = peer.call(get, request).values
    check([v.type for v in values] == [ParameterType.PARAMETER_DOUBLE,
                                       ParameterType.PARAMETER_STRING,
                                       ParameterType.PARAMETER_STRING,
                                       ParameterType.PARAMETER_BOOL],
          f"the parameter types: {values}")
    # The harness passed `-p cmd_vel_timeout:=0.5 -p hardware_id:=sim_base` and a
    # parameters file with odom_frame: odom.
    check(values[0].double_value == 0.5 and values[1].string_value == "odom"
          and values[2].string_value == "sim_base" and values[3].bool_value,
          f"the values from --ros-args -p and --params-file: {values}")
    listing = peer.call(peer.create_client(ListParameters, f"{NODE}/list_parameters"),
                        ListParameters.Request()).result.names
    check("command_rate" in listing and "pose_covariance" in listing,
          f"list_parameters names the node's parameters: {listing}")
    change = SetParameters.Request()
    change.parameters = [Parameter(name="cmd_vel_timeout", value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=2.0))]
    result = peer.call(peer.create_client(SetParameters, f"{NODE}/set_parameters"),
                       change).results[0]
    check(not result.successful and "read-only" in result.reason,
          f"a change while running is refused with a reason: {result}")
    return f"{len(listing)} parameters; changing one is refused: {result.reason!r}"


def estop_in_diagnostics(peer):
    ask("ESTOP?")
    def shown():
        for array in peer.diagnostics[-1:]:
            for status in array.status:
                values = {value.key: value.value for value in status.values}
                # rclpy gives the byte `level` as bytes.
                if ord(status.level) == 2 and values.get("estop_pressed") == "yes" \
                        and values.get("mode") == "Emergency":
                    return True
        return False
    try:
        peer.wait_for(shown, 4, "/diagnostics shows ERROR, Emergency, estop_pressed yes")
    except Failed as failure:
        last = peer.diagnostics[-1].status[0] if peer.diagnostics else None
        raise Failed(f"{failure}; last seen: {last}")
    return repr(peer.diagnostics[-1].status[0].message)


def sigterm_leaves_graph(peer):
    ask("SIGTERM?")
    start = time.monotonic()
    peer.wait_for(lambda: ("base_ros2", "/") not in peer.get_node_names_and_namespaces(), 5,
                  "base_ros2 leaves the graph after SIGTERM")
    return f"gone {time.monotonic() - start:.2f} s after base-ros2 ended"


# ---- The measurements ----

def measure(peer, watch):
    """/cmd_vel -> its 0x0C8 on the bus, and the position frame (0x0EC, 0x0ED) ->
    its /odom, at 50 Hz with a new speed each time, 400 samples."""
    peer.reset_odometry()
    command_delays = []
    for i in range(400):
        speed = 100 + (i % 100)
        twist = Twist()
        twist.linear.x = speed / 1000.0
        sent = time.monotonic()
        peer.cmd_vel.publish(twist)
        deadline = sent + 0.5
        while time.monotonic() < deadline:
            rclpy.spin_once(peer, timeout_sec=0.001)
            with watch.lock:
                seen = [t for t, linear, _ in watch.velocities if t >= sent and linear == speed]
            if seen:
                command_delays.append((seen[0] - sent) * 1000)
                break
        peer.spin_for(max(0.0, 0.02 - (time.monotonic() - sent)))
    peer.stopped()
    with watch.lock:
        poses = list(watch.poses)
    odom_delays = []
    by_pose = {}
    for t, x, y, heading, *_ in poses:
        by_pose.setdefault((x, y, heading), t)
    for arrived, message in peer.odoms:
        key = (round(message.pose.pose.position.x * 1000),
               round(-message.pose.pose.position.y * 1000),
               round(-yaw(message.pose.pose.orientation) * 1000))
        sent = by_pose.pop(key, None)
        if sent is not None and arrived >= sent:
            odom_delays.append((arrived - sent) * 1000)
    check(len(command_delays) >= 390, f"{len(command_delays)} of 400 commands seen on the bus")
    check(len(odom_delays) >= 100, f"{len(odom_delays)} poses matched to /odom")
    print(f"FIGURE cmd_vel->bus n={len(command_delays)} p50={percentile(command_delays, 50):.2f} "
          f"p99={percentile(command_delays, 99):.2f} ms", flush=True)
    print(f"FIGURE position->odom n={len(odom_delays)} p50={percentile(odom_delays, 50):.2f} "
          f"p99={percentile(odom_delays, 99):.2f} ms", flush=True)
    return "figures printed"


SCENARIOS = [graph_and_types, qos, odom_rate_and_stamps, reset_by_service, forward,
             on_the_controllers_clock, stale_stop,
             counter_clockwise, zero_twist_at_goal, reset_while_driving, stream_50hz, rosout,
             parameters]


def main():
    host, port = sys.argv[1], sys.argv[2]
    rclpy.init()
    peer = Peer()
    watch = BusWatch(host, port)
    peer.watch = watch
    passed = failed = 0

    def run(scenario, *args):
        nonlocal passed, failed
        try:
            detail = scenario(peer, *args)
            print(f"PASS {scenario.__name__}: {detail}", flush=True)
            passed += 1
        except Failed as failure:
            print(f"FAIL {scenario.__name__}: {failure}", flush=True)
            failed += 1
        except Exception:  # a scenario's own bug: counted, and the rest still run
            print(f"FAIL {scenario.__name__}: {traceback.format_exc()}", flush=True)
            failed += 1
        # Whatever the scenario left: stop driving before the next.
        peer.spin_for(0.7)

    run(graph_and_types)
    for scenario in SCENARIOS[1:]:
        run(scenario)
    run(measure, watch)
    run(estop_in_diagnostics)
    run(sigterm_leaves_graph)
    watch.close()
    print(f"SCENARIOS passed={passed} failed={failed}", flush=True)
    peer.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
