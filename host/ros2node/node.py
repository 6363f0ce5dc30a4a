"""``rfhoming node``: the homing run (host/homing/assembly.py, as ``rfhoming run`` builds it) as a
ROS 2 node written with rclpy. Only this module imports rclpy; the command imports it when it runs.

Why services and not an action: a ROS 2 action needs its own type, and defining one needs a
colcon build; no message wheel carries an action that fits (docs/usage.md, "rfhoming node").
So the goal is the ``tag`` parameter and ``~/home`` (std_srvs/Trigger) starts homing on it;
``~/cancel`` stops the robot before it answers; ``~/feedback`` and ``~/result`` are
diagnostic_msgs/DiagnosticStatus. No lifecycle either: each homing opens the devices and closes
them at its end (the one run assembly), so there is nothing to configure ahead.

Threads: the homing run is asyncio's, in the main thread; rclpy's executor spins in another.
A service call hands its work to the asyncio loop and waits for the answer.
"""

from __future__ import annotations

import asyncio
import logging
import math
import sys
import threading
from collections.abc import Callable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown
from std_srvs.srv import Trigger

from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Homing
from rfhoming.host.homing.loop import HomingLoop
from rfhoming.host.ros2node import progress as prog
from rfhoming.host.ros2node.tf import TagFrames
from rfhoming.host.sink import Sink
from rfhoming.protocol.errors import Error
from rfhoming.protocol.settings import tags as tag_ids

log = logging.getLogger(__name__)

PlanFor = Callable[[tuple[str, ...]], Homing]
MODES = ("cmd_vel", "nav2")
PARAMETERS: dict[str, tuple[Any, str]] = {
    "tag": ("", "the tag ~/home homes on (12 hex digits); empty: the only one in view, as rfhoming run"),
    "mode": ("cmd_vel", "cmd_vel: the loop drives the base; nav2: it hands its estimate to Nav2 on goal_pose "
                        "(read when homing starts)"),
    "stand_off_m": (0.5, "nav2 mode: each goal lies this far short of the estimate, facing it"),
    "reach_m": (0.8, "nav2 mode: homing has arrived once the robot is this near the estimate"),
    "resend_m": (0.3, "nav2 mode: a new goal once the estimate has moved this far from the last one sent"),
    "resend_s": (1.0, "nav2 mode: and at most one new goal in this many seconds of robot time"),
    "frame": ("odom", "the frame of the estimates and the tags' parent on /tf: the base's odometry frame"),
    "tag_frame_prefix": ("tag_", "each tag's TF frame is PREFIX<id>"),
}
DIAGNOSTICS_S = 1.0
ANSWER_S = 10.0  # a service call waits this long for the homing loop's answer


class HomingNode(Node):
    """The node: parameters, the two services, the publishers, and the homing task."""

    def __init__(self, plan_for: PlanFor, aloop: asyncio.AbstractEventLoop) -> None:
        super().__init__("rfhoming")
        self.plan_for, self.aloop = plan_for, aloop
        for name, (default, text) in PARAMETERS.items():
            self.declare_parameter(name, default, ParameterDescriptor(description=text))
        self.add_on_set_parameters_callback(self._check)
        group = ReentrantCallbackGroup()
        self.create_service(Trigger, "~/home", self._on_home, callback_group=group)
        self.create_service(Trigger, "~/cancel", self._on_cancel, callback_group=group)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.feedback = self.create_publisher(DiagnosticStatus, "~/feedback", 10)
        self.result = self.create_publisher(DiagnosticStatus, "~/result", latched)
        self.estimate = self.create_publisher(PoseWithCovarianceStamped, "~/estimate", 10)
        self.goal_pose = self.create_publisher(PoseStamped, "goal_pose", 10)
        self.diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(DIAGNOSTICS_S, self._diagnose, callback_group=group)
        self.tags = TagFrames(self)
        self.task: asyncio.Task[None] | None = None
        self.loop: HomingLoop | None = None  # the running loop, handed over by the run's sink
        self.mode = str(self.value("mode"))
        self.ending: str | None = None  # why the node itself ended the run: "in reach", "canceled"

    def value(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _check(self, parameters: list[Parameter]) -> SetParametersResult:
        """A parameter set from outside: refused, with the reason, unless it makes sense."""
        for p in parameters:
            why = _invalid(p.name, p.value)
            if why is not None:
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    # -- services (executor threads) -------------------------------------------------
    def _on_home(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self._ask(self._start())
        return response

    def _on_cancel(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self._ask(self.stop("canceled"))
        return response

    def _ask(self, work: Any) -> tuple[bool, str]:
        answer: tuple[bool, str] = asyncio.run_coroutine_threadsafe(work, self.aloop).result(ANSWER_S)
        return answer

    # -- the homing run (asyncio) ---------------------------------------------------
    async def _start(self) -> tuple[bool, str]:
        if self.task is not None and not self.task.done():
            return False, "already homing: call ~/cancel first"
        tag = str(self.value("tag"))
        try:
            plan = self.plan_for(tag_ids(tag) if tag else ())
            assembly.check(plan)
        except Error as exc:
            return False, str(exc)
        self.mode, self.ending = str(self.value("mode")), None
        self.task = asyncio.create_task(self._home(plan))
        return True, f"homing on {tag or 'the only tag in view'}, mode {self.mode}"

    async def _home(self, plan: Homing) -> None:
        sink = NodeSink(self, self.mode, prog.Resender(float(self.value("resend_m")),
                                                              float(self.value("resend_s"))))
        plan.sinks = [sink]
        try:
            outcome = await assembly.run(plan)
            arrived, reason = outcome.arrived, outcome.reason
        except asyncio.CancelledError:
            arrived, reason = self.ending == "in reach", self.ending or "canceled"
        except Error as exc:
            arrived, reason = False, str(exc)
        finally:
            self.loop = None
        status = DiagnosticStatus(level=bytes([prog.OK if arrived else prog.WARN]), name="rfhoming: homing",
                                  message="arrived" if arrived else reason, hardware_id=sink.tag,
                                  values=[KeyValue(key="arrived", value=str(arrived)),
                                          KeyValue(key="reason", value=reason),
                                          KeyValue(key="goals_sent", value=str(sink.resender.count))])
        self.result.publish(status)
        log.info("homing ended: %s", reason)

    async def stop(self, reason: str) -> tuple[bool, str]:
        """End the homing run, if one is on: its task is cancelled and awaited, so the base's
        stop (the loop's ``async with`` the base) has been sent when this returns."""
        task = self.task
        if task is None or task.done():
            return False, "not homing"
        self.ending = reason
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        return True, "stopped: the robot was told to stop"

    def in_reach(self) -> None:
        """Nav2 mode: the robot is in reach of the estimate; ends the run (called in its task)."""
        if self.task is not None and self.ending is None:
            self.ending = "in reach"
            self.task.cancel()

    # -- what the node publishes ----------------------------------------------------
    def publish(self, p: prog.Progress, tag: str) -> None:
        """Feedback, the estimate as a pose with covariance, and the tag's TF frame."""
        values = {"phase": p.phase, "tag": tag, "robot_time_s": f"{p.t:.3f}",
                  "robot": ",".join(f"{v:.3f}" for v in p.pose)}
        if p.goal is not None:
            values.update(x=f"{p.goal[0]:.3f}", y=f"{p.goal[1]:.3f}", distance_m=f"{p.distance_m:.3f}")
        values["uncertainty_m"] = "unknown" if p.uncertainty_m is None else f"{p.uncertainty_m:.3f}"
        self.feedback.publish(DiagnosticStatus(level=bytes([prog.OK]), name="rfhoming: homing", message=p.phase,
                                               hardware_id=tag,
                                               values=[KeyValue(key=k, value=v) for k, v in values.items()]))
        if p.goal is None:
            return
        stamp, frame = self.get_clock().now().to_msg(), str(self.value("frame"))
        pose = PoseWithCovarianceStamped()
        pose.header.stamp, pose.header.frame_id = stamp, frame
        pose.pose.pose.position.x, pose.pose.pose.position.y = p.goal
        pose.pose.pose.orientation.w = 1.0
        variance = 1e6 if p.uncertainty_m is None else p.uncertainty_m ** 2  # 1e6: not known
        cov = [0.0] * 36
        cov[0] = cov[7] = variance
        cov[14] = cov[21] = cov[28] = cov[35] = 1e6  # z and the orientation: not estimated
        pose.pose.covariance = cov
        self.estimate.publish(pose)
        self.tags.publish(frame, f"{self.value('tag_frame_prefix')}{tag}", p.goal)

    def send_goal(self, p: prog.Progress) -> None:
        x, y, yaw = prog.stand_off(p, float(self.value("stand_off_m")))
        goal = PoseStamped()
        goal.header.stamp, goal.header.frame_id = self.get_clock().now().to_msg(), str(self.value("frame"))
        goal.pose.position.x, goal.pose.position.y = x, y
        goal.pose.orientation.z, goal.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        self.goal_pose.publish(goal)

    def _diagnose(self) -> None:
        rows = prog.diagnostics(self.loop, self.mode)
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [DiagnosticStatus(level=bytes([level]), name=name, message=message, hardware_id="rfhoming",
                                         values=[KeyValue(key=k, value=v) for k, v in values.items()])
                        for name, level, message, values in rows]
        self.diagnostics.publish(array)


class NodeSink(Sink):
    """The run's watcher: each estimate becomes the node's feedback and TF frame; in Nav2 mode,
    once the estimate is there, the loop hands over and each firmer estimate is a new goal."""

    def __init__(self, node: HomingNode, mode: str, resender: prog.Resender) -> None:
        self.node, self.mode, self.resender = node, mode, resender
        self.loop: HomingLoop | None = None
        self.tag = ""

    def watch(self, loop: Any) -> None:
        self.loop = self.node.loop = loop

    def _on_item(self, device: str, t_host: float, item: Any) -> None:
        """Readings reach the node through the loop's estimates."""

    def _on_runlog(self, record: dict[str, Any]) -> None:
        p = prog.progress(record)
        if p is None or self.loop is None:
            return
        self.tag = _tag_of(self.loop)
        self.node.publish(p, self.tag)
        if self.mode != "nav2" or p.goal is None or p.phase != "homing":
            return
        self.loop.hand_over()
        if self.resender.due(p):
            self.node.send_goal(p)
        if p.distance_m is not None and p.distance_m <= float(self.node.value("reach_m")):
            self.node.in_reach()

    def _failed(self, kind: str, exc: Exception) -> None:
        log.warning("rfhoming node: publishing a %s failed: %r", kind, exc)

    def close(self) -> None:
        """Nothing held."""


def _tag_of(loop: HomingLoop) -> str:
    """The tag homed on: the XPLR-AOA's chosen one, else ``target``."""
    for sensor in loop.sensors:
        chosen = getattr(sensor, "chosen", None)
        if chosen:
            return "+".join(sorted(chosen))
    return "target"


def _invalid(name: str, value: Any) -> str | None:
    if name == "mode" and value not in MODES:
        return f"mode is {' or '.join(MODES)}"
    if name in ("stand_off_m", "reach_m", "resend_m", "resend_s") and not (isinstance(value, float) and math.isfinite(value)
                                                               and value >= 0):
        return f"{name} is a number >= 0 (metres or seconds, as its name says)"
    if name == "tag" and value:
        try:
            tag_ids(str(value))
        except ValueError as exc:
            return f"tag: {exc}"
    if name in ("frame", "tag_frame_prefix") and not str(value):
        return f"{name} cannot be empty"
    return None


def serve(plan_for: PlanFor, ros_args: list[str]) -> None:
    """Run the node until Ctrl-C or SIGTERM (asyncio's cancellation ends a homing run with the
    base's stop). rclpy's own signal handlers stay off: the command's are in charge."""
    rclpy.init(args=["rfhoming", "--ros-args", *ros_args] if ros_args else None,
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        asyncio.run(_serve(plan_for))
    finally:
        try_shutdown()


async def _serve(plan_for: PlanFor) -> None:
    node = HomingNode(plan_for, asyncio.get_running_loop())
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    spinning = threading.Thread(target=executor.spin, name="rclpy", daemon=True)
    spinning.start()
    print(f"rfhoming node: {node.get_fully_qualified_name()} up on ROS 2 domain {node.context.get_domain_id()}",
          file=sys.stderr, flush=True)
    try:
        await asyncio.Event().wait()  # until cancelled
    finally:
        await node.stop("node shut down")
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()  # type: ignore[no-untyped-call]  # rclpy 7.1 leaves it unannotated
