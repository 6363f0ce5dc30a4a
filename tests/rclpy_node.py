"""A ROS 2 node written with ROS 2's own client library, rclpy (Jazzy, rmw_fastrtps_cpp), as an
independent check of rfhoming's DDS side: nothing of rfhoming is imported here.

    python tests/rclpy_node.py DOMAIN SECONDS [--listen TOPIC=TYPE ...] [--drive V,W,METRES]
                                              [--robot X,Y,YAW] [--truth TOPIC]

``--listen``: subscribe (sensor-data QoS, which matches reliable and best-effort writers) and print
one JSON line per message; the first message of a topic also prints what the ROS graph says of
its publishers (type, reliability, durability). ``--drive``: publish geometry_msgs/Twist V, W on
/cmd_vel at 10 Hz until /odom (listened to) has moved METRES from its first pose, then zero three
times. ``--robot``: be a robot: a unicycle that obeys /cmd_vel (stops 0.5 s after the last), starts
at X,Y,YAW of its world, and publishes nav_msgs/Odometry on /odom (odom -> base_link, from 0, 0, 0)
and its ground truth as geometry_msgs/PoseStamped on TOPIC (``--truth``, default
/ground_truth/pose, frame ``world``) at 50 Hz of the node's clock. It prints ``{"ready": DOMAIN}``
once set up and ``{"graph": ...}`` (every topic and its types) at the end; it ends after SECONDS,
once its standard input closes (then 3 s more, for what is on its way), or once the drive is done.

Loopback only: Fast DDS with the profile docs/ros2/fastdds-loopback.xml and ROS_DOMAIN_ID=DOMAIN,
set here before rclpy starts (a user's shell would export them). ROS_AUTOMATIC_DISCOVERY_RANGE is
SYSTEM_DEFAULT, which leaves discovery to the profile: Jazzy's rmw_fastrtps adds, for LOCALHOST, an
any-address unicast locator to the profile's, so the node would announce the machine's other
addresses too (seen with tshark; docs/hardware.md, "ROS 2 on loopback, or on the network"). rclpy's wheels set
LD_LIBRARY_PATH themselves: their .pth file starts the interpreter again with it.
"""

import argparse
import json
import math
import os
import select
import sys
import time
from pathlib import Path
from typing import Any

PROFILE = Path(__file__).resolve().parent.parent / "docs" / "ros2" / "fastdds-loopback.xml"


def environment(domain: int, log_dir: str) -> None:
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="SYSTEM_DEFAULT",
                      RMW_IMPLEMENTATION="rmw_fastrtps_cpp", FASTRTPS_DEFAULT_PROFILES_FILE=str(PROFILE),
                      FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE), ROS_LOG_DIR=log_dir)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("domain", type=int)
    p.add_argument("seconds", type=float)
    p.add_argument("--listen", action="append", default=[], metavar="TOPIC=TYPE")
    p.add_argument("--drive", metavar="V,W,METRES")
    p.add_argument("--robot", metavar="X,Y,YAW")
    p.add_argument("--truth", default="/ground_truth/pose")
    p.add_argument("--log-dir", default=os.environ.get("TMPDIR", "/tmp"))
    args = p.parse_args()
    environment(args.domain, args.log_dir)

    import rclpy  # after the environment: Fast DDS reads its profile when the first participant is made

    rclpy.init()
    node = Node(args)
    try:
        node.run(args.seconds)
    finally:
        print(json.dumps({"graph": {name: types for name, types in node.node.get_topic_names_and_types()}}), flush=True)
        node.node.destroy_node()
        rclpy.shutdown()


class Node:
    def __init__(self, args: argparse.Namespace) -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped, Twist
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, qos_profile_sensor_data

        self.rclpy = rclpy
        self.node = rclpy.create_node("rfhoming_check")
        self.seen: set[str] = set()
        self.first_odom: tuple[float, float] | None = None
        self.moved = 0.0
        for pair in args.listen:
            topic, _, kind = pair.partition("=")
            self.node.create_subscription(message_type(kind), topic, lambda m, t=topic: self.heard(t, m),
                                          qos_profile_sensor_data)
        self.drive = tuple(map(float, args.drive.split(","))) if args.drive else None
        self.cmd = self.node.create_publisher(Twist, "/cmd_vel", QoSProfile(depth=10)) if self.drive else None
        self.robot = Unicycle(*map(float, args.robot.split(","))) if args.robot else None
        if self.robot is not None:
            self.node.create_subscription(Twist, "/cmd_vel", self.robot.command, QoSProfile(depth=10))
            self.odom = self.node.create_publisher(Odometry, "/odom", QoSProfile(depth=10))
            self.truth = self.node.create_publisher(PoseStamped, args.truth, QoSProfile(depth=10))
            self.node.create_timer(0.02, self.tick)
        if self.cmd is not None:
            self.node.create_timer(0.1, self.command)
        self.done = False

    def run(self, seconds: float) -> None:
        print(json.dumps({"ready": int(os.environ["ROS_DOMAIN_ID"])}), flush=True)
        end, closing = time.monotonic() + seconds, False
        while time.monotonic() < end and not self.done:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            if not closing and select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.read(1):
                closing, end = True, min(end, time.monotonic() + 3.0)
        if self.robot is not None:
            print(json.dumps({"robot": self.robot.state()}), flush=True)

    def heard(self, topic: str, message: Any) -> None:
        line = {"topic": topic, **describe(message)}
        if topic not in self.seen:
            self.seen.add(topic)
            line["publishers"] = [{"type": i.topic_type, "reliability": i.qos_profile.reliability.name,
                                   "durability": i.qos_profile.durability.name}
                                  for i in self.node.get_publishers_info_by_topic(topic)]
        print(json.dumps(line), flush=True)
        if topic == "/odom":
            xy = (line["x"], line["y"])
            self.first_odom = self.first_odom or xy
            self.moved = math.dist(self.first_odom, xy)

    def command(self) -> None:
        from geometry_msgs.msg import Twist

        assert self.drive is not None and self.cmd is not None
        v, w, metres = self.drive
        arrived = self.moved >= metres
        twist = Twist()
        twist.linear.x, twist.angular.z = (0.0, 0.0) if arrived else (v, w)
        repeats = 3 if arrived else 1
        for _ in range(repeats):
            self.cmd.publish(twist)
        if arrived:
            print(json.dumps({"driven": self.moved}), flush=True)
            self.done = True

    def tick(self) -> None:
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Odometry

        assert self.robot is not None
        now = self.node.get_clock().now()
        self.robot.advance(now.nanoseconds / 1e9)
        odom = Odometry()
        odom.header.stamp, odom.header.frame_id, odom.child_frame_id = now.to_msg(), "odom", "base_link"
        odom.pose.pose.position.x, odom.pose.pose.position.y = self.robot.odom[:2]
        odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = half_angle(self.robot.odom[2])
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = self.robot.v, self.robot.w
        self.odom.publish(odom)
        truth = PoseStamped()
        truth.header.stamp, truth.header.frame_id = now.to_msg(), "world"
        truth.pose.position.x, truth.pose.position.y = self.robot.world[:2]
        truth.pose.orientation.z, truth.pose.orientation.w = half_angle(self.robot.world[2])
        self.truth.publish(truth)


class Unicycle:
    """The robot's own kinematics: (v, w) held until the next command or 0.5 s without one."""

    TIMEOUT_S = 0.5

    def __init__(self, x: float, y: float, yaw: float) -> None:
        self.world = [x, y, yaw]
        self.odom = [0.0, 0.0, 0.0]
        self.v = self.w = 0.0
        self.t: float | None = None
        self.last_command = -math.inf
        self.commands = 0

    def command(self, twist: Any) -> None:
        self.v, self.w = twist.linear.x, twist.angular.z
        self.last_command = time.monotonic()
        self.commands += 1

    def advance(self, t: float) -> None:
        if time.monotonic() - self.last_command > self.TIMEOUT_S:
            self.v = self.w = 0.0
        dt, self.t = (0.0 if self.t is None else t - self.t), t
        for pose in (self.world, self.odom):
            heading = pose[2] + self.w * dt / 2  # midpoint rule: exact enough at 50 Hz
            pose[0] += self.v * dt * math.cos(heading)
            pose[1] += self.v * dt * math.sin(heading)
            pose[2] = math.remainder(pose[2] + self.w * dt, math.tau)

    def state(self) -> dict[str, object]:
        return {"world": self.world, "odom": self.odom, "commands": self.commands}


def half_angle(yaw: float) -> tuple[float, float]:
    return math.sin(yaw / 2), math.cos(yaw / 2)


def yaw_of(q: Any) -> float:
    return 2 * math.atan2(q.z, q.w)  # planar: roll = pitch = 0


def message_type(name: str) -> type:
    package, _, kind = name.split("/")
    module = __import__(f"{package}.msg", fromlist=[kind])
    return getattr(module, kind)


def seconds(stamp: Any) -> float:
    return stamp.sec + stamp.nanosec / 1e9


def describe(m: Any) -> dict[str, object]:
    """The fields a test checks, by message type."""
    kind = type(m).__name__
    out: dict[str, object] = {"type": f"{type(m).__module__.split('.')[0]}/msg/{kind}"}
    header = getattr(m, "header", None)
    if header is not None:
        out.update(frame=header.frame_id, stamp=seconds(header.stamp))
    if kind == "Odometry":
        p = m.pose.pose
        out.update(child=m.child_frame_id, x=p.position.x, y=p.position.y, yaw=yaw_of(p.orientation),
                   v=m.twist.twist.linear.x, w=m.twist.twist.angular.z)
    elif kind == "LaserScan":
        r = list(m.ranges)
        lo, hi = m.range_min, m.range_max
        out.update(range_min=lo, range_max=hi, angle_min=m.angle_min, angle_max=m.angle_max,
                   angle_increment=m.angle_increment, beams=len(r),
                   in_range=sum(1 for x in r if lo <= x <= hi), pos_inf=sum(1 for x in r if x == math.inf),
                   neg_inf=sum(1 for x in r if x == -math.inf), nan=sum(1 for x in r if math.isnan(x)))
    elif kind == "Twist":
        out.update(v=m.linear.x, w=m.angular.z)
    elif kind == "PointStamped":
        out.update(xyz=[m.point.x, m.point.y, m.point.z])
    elif kind in ("PoseStamped", "PoseWithCovarianceStamped"):
        pose = m.pose.pose if kind == "PoseWithCovarianceStamped" else m.pose
        q = pose.orientation
        out.update(xyz=[pose.position.x, pose.position.y, pose.position.z], orientation=[q.x, q.y, q.z, q.w])
        if kind == "PoseWithCovarianceStamped":
            out.update(covariance=[float(c) for c in m.pose.covariance])
    elif kind == "String":
        out.update(data=m.data)
    return out


if __name__ == "__main__":
    main()
