"""A ROS 2 user's client of ``rfhoming node``, written with rclpy (Jazzy's wheels, Fast DDS on
loopback as tests/rclpy_node.py sets it up): nothing of rfhoming is imported here.

    python tests/rclpy_homing.py DOMAIN SECONDS NODE [--set NAME=VALUE ...] [--cancel-after N]
                                 [--nav2] [--graph-only]

It waits for NODE's services (NODE: the node's full name, e.g. /rfhoming), sets its parameters
(``--set``, through the node's parameter services, then lists them back), calls NODE/home and
prints one JSON line per message: NODE/feedback, NODE/result, /cmd_vel, /odom (its stamp: the
robot's time, and its twist) and /diagnostics; and what it did ({"called": ...}, {"cancel": ...}).
``--cancel-after N``: call NODE/cancel after N feedback messages in the homing phase. ``--nav2``:
be a stand-in for Nav2: follow geometry_msgs/PoseStamped on goal_pose by driving /cmd_vel straight
at it (turn, then go; stop within 0.05 m). It ends on NODE/result (2 s later) or after SECONDS, and
prints the graph: {"graph": {topics}, "services": [...], "nodes": [...]}. ``--graph-only``: no
homing, just the graph and the parameters, after 3 s.
"""

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

PROFILE = Path(__file__).resolve().parent.parent / "docs" / "ros2" / "fastdds-loopback.xml"


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("domain", type=int)
    p.add_argument("seconds", type=float)
    p.add_argument("node")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--cancel-after", type=int)
    p.add_argument("--nav2", action="store_true")
    p.add_argument("--graph-only", action="store_true")
    p.add_argument("--log-dir", default=os.environ.get("TMPDIR", "/tmp"))
    args = p.parse_args()
    os.environ.update(ROS_DOMAIN_ID=str(args.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="SYSTEM_DEFAULT",
                      RMW_IMPLEMENTATION="rmw_fastrtps_cpp", FASTRTPS_DEFAULT_PROFILES_FILE=str(PROFILE),
                      FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE), ROS_LOG_DIR=args.log_dir)
    import rclpy

    rclpy.init()
    client = Client(args)
    try:
        client.run(args.seconds)
    finally:
        n = client.node
        say(graph={name: types for name, types in n.get_topic_names_and_types()},
            services={name: types for name, types in n.get_service_names_and_types()},
            nodes=[f"{ns.rstrip('/')}/{name}" for name, ns in n.get_node_names_and_namespaces()])
        n.destroy_node()
        rclpy.shutdown()


def say(**line: Any) -> None:
    print(json.dumps(line), flush=True)


class Client:
    def __init__(self, args: argparse.Namespace) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
        from geometry_msgs.msg import PoseStamped, Twist
        from nav_msgs.msg import Odometry
        from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
        from std_srvs.srv import Trigger

        self.rclpy, self.args = rclpy, args
        self.node = rclpy.create_node("homing_client")
        n, name = self.node, args.node
        self.home = n.create_client(Trigger, f"{name}/home")
        self.cancel = n.create_client(Trigger, f"{name}/cancel")
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        n.create_subscription(DiagnosticStatus, f"{name}/feedback", self.on_feedback, 10)
        n.create_subscription(DiagnosticStatus, f"{name}/result", self.on_result, latched)
        n.create_subscription(Twist, "/cmd_vel", self.on_cmd, 10)
        n.create_subscription(Odometry, "/odom", self.on_odom, qos_profile_sensor_data)
        n.create_subscription(DiagnosticArray, "/diagnostics", self.on_diagnostics, 10)
        self.feedback_homing = 0
        self.result: Any = None
        self.pending: list[tuple[str, Any]] = []
        self.odom: Any = None
        self.goal: tuple[float, float] | None = None
        if args.nav2:
            n.create_subscription(PoseStamped, "goal_pose", self.on_goal, 10)
            self.drive = n.create_publisher(Twist, "/cmd_vel", 10)
            n.create_timer(0.05, self.steer)

    def run(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        for c in (self.home, self.cancel):
            if not c.wait_for_service(timeout_sec=60):
                say(error=f"no service {c.srv_name}")
                return
        self.parameters()
        if self.args.graph_only:
            self.spin_for(3.0)
            return
        self.call("home", self.home)
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            self.answers()
            if self.result is not None:
                self.spin_for(2.0)
                return

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            self.answers()

    def call(self, what: str, client: Any) -> None:
        from std_srvs.srv import Trigger

        say(call=what, odom_stamp=self.odom_stamp())
        self.pending.append((what, client.call_async(Trigger.Request())))

    def answers(self) -> None:
        for what, future in list(self.pending):
            if future.done():
                self.pending.remove((what, future))
                r = future.result()
                say(called=what, success=r.success, message=r.message, odom_stamp=self.odom_stamp())

    def parameters(self) -> None:
        """Set --set's through the parameter services, then list and read them back."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters

        name = self.args.node
        if self.args.set:
            setter = self.node.create_client(SetParameters, f"{name}/set_parameters")
            setter.wait_for_service(timeout_sec=30)
            request = SetParameters.Request()
            for pair in self.args.set:
                key, _, text = pair.partition("=")
                value = ParameterValue()
                try:
                    value.type, value.double_value = ParameterType.PARAMETER_DOUBLE, float(text)
                except ValueError:
                    value.type, value.string_value = ParameterType.PARAMETER_STRING, text
                request.parameters.append(Parameter(name=key, value=value))
            results = self.wait(setter.call_async(request)).results
            say(set=[{"successful": r.successful, "reason": r.reason} for r in results])
        lister = self.node.create_client(ListParameters, f"{name}/list_parameters")
        lister.wait_for_service(timeout_sec=30)
        names = list(self.wait(lister.call_async(ListParameters.Request())).result.names)
        getter = self.node.create_client(GetParameters, f"{name}/get_parameters")
        getter.wait_for_service(timeout_sec=30)
        values = self.wait(getter.call_async(GetParameters.Request(names=names))).values
        say(parameters={k: v.string_value if v.type == ParameterType.PARAMETER_STRING else
                        v.double_value if v.type == ParameterType.PARAMETER_DOUBLE else None
                        for k, v in zip(names, values)})

    def wait(self, future: Any) -> Any:
        self.rclpy.spin_until_future_complete(self.node, future, timeout_sec=30)
        return future.result()

    def odom_stamp(self) -> float | None:
        return None if self.odom is None else seconds(self.odom.header.stamp)

    def on_feedback(self, m: Any) -> None:
        values = {kv.key: kv.value for kv in m.values}
        say(**{**values, "topic": "feedback", "phase": m.message, "tag": m.hardware_id})
        if m.message == "homing" and "x" in values:
            self.feedback_homing += 1
            if self.args.cancel_after is not None and self.feedback_homing == self.args.cancel_after:
                self.call("cancel", self.cancel)

    def on_result(self, m: Any) -> None:
        self.result = m
        say(**{kv.key: kv.value for kv in m.values}, topic="result", message=m.message, tag=m.hardware_id,
            level=m.level[0] if isinstance(m.level, bytes) else m.level)

    def on_cmd(self, m: Any) -> None:
        say(topic="cmd_vel", v=m.linear.x, w=m.angular.z, odom_stamp=self.odom_stamp())

    def on_odom(self, m: Any) -> None:
        self.odom = m
        p = m.pose.pose
        say(topic="odom", stamp=seconds(m.header.stamp), x=p.position.x, y=p.position.y,
            v=m.twist.twist.linear.x, w=m.twist.twist.angular.z)

    def on_diagnostics(self, m: Any) -> None:
        say(topic="diagnostics", stamp=seconds(m.header.stamp),
            status=[{"name": s.name, "message": s.message, "values": {kv.key: kv.value for kv in s.values}}
                    for s in m.status])

    def on_goal(self, m: Any) -> None:
        self.goal = (m.pose.position.x, m.pose.position.y)
        say(topic="goal_pose", frame=m.header.frame_id, x=self.goal[0], y=self.goal[1])

    def steer(self) -> None:
        """Nav2's stand-in: straight at the goal on the robot's own odometry."""
        from geometry_msgs.msg import Twist

        if self.goal is None or self.odom is None:
            return
        p = self.odom.pose.pose
        yaw = 2 * math.atan2(p.orientation.z, p.orientation.w)
        dx, dy = self.goal[0] - p.position.x, self.goal[1] - p.position.y
        heading = math.remainder(math.atan2(dy, dx) - yaw, math.tau)
        twist = Twist()
        if math.hypot(dx, dy) > 0.05:
            twist.angular.z = max(-0.8, min(0.8, 1.5 * heading))
            twist.linear.x = 0.0 if abs(heading) > 0.3 else min(0.3, math.hypot(dx, dy))
        self.drive.publish(twist)


def seconds(stamp: Any) -> float:
    return stamp.sec + stamp.nanosec / 1e9


if __name__ == "__main__":
    sys.exit(main())
