"""A live view in Foxglove (or Lichtblick): a Foxglove WebSocket server fed by a run.

:class:`FoxgloveView` is a sink like the MCAP recorder: ``on_item`` sees every decoded device
item, ``on_runlog`` every run log record. It publishes, with foxglove-sdk's own schemas:

- ``/tf`` (odom -> base_link), ``/robot/pose`` and ``/robot/path`` from the base's odometry,
  ``/scan`` from its range scans;
- ``/rfhoming/scene``: the target estimate as a sphere (its diameter: the spread of the
  estimates it came from, e.g. S0's parallax and vector goals, at least 0.2 m), the latest
  bearings as rays from the robot (length: the range estimate, else 2 m), S3's position fix
  and anchors (:meth:`FoxgloveView.show_anchors`);
- ``/rfhoming/particles``: S2's particle cloud, ``/rfhoming/obstacles``: the occupied cells of
  the loop's occupancy grid (both when the view :meth:`FoxgloveView.watch` es the loop);
- JSON channels for plots: ``/rfhoming/aoa`` (angle events), ``/rfhoming/ble`` (BLE RSSI),
  ``/rfhoming/antennas`` (antenna sets), ``/rfhoming/measurement``, ``/rfhoming/command``,
  ``/rfhoming/estimate``.

``foxglove_layout.json`` beside this module is a layout that shows them (Foxglove: Layouts ->
Import from file). Times are the host's wall clock: a live view shows now.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from importlib.resources import files
from typing import Any

import foxglove
import numpy as np
from foxglove import channels, messages

from rfhoming.host.sink import Sink
from rfhoming.protocol.jsonable import as_dict

log = logging.getLogger(__name__)

PATH_POSES = 1000  # the path keeps the latest poses ...
PATH_STEP_M = 0.05  # ... each at least this far from the one before (a path costs O(poses) to send)
RAYS = 12  # bearings drawn at once
PATH_EVERY = 25  # odometry records per path update (0.5 s at the base's 50 Hz)
CLOUD_EVERY = 5  # estimates per particle cloud / obstacle map update
DEFAULT_PORT = 8765  # Foxglove's own default
BACKLOG = 128
"""Outgoing messages the SDK buffers per client, oldest dropped first (its default, 1024, of
paths and point clouds could hold tens of MB for one client that never reads). What a client
sends is bounded by the SDK itself: a message over 16 MiB ends that client's connection
(foxglove-sdk 0.30; ``tests/test_foxglove_view.py`` holds it to that)."""
LAYOUT = files("rfhoming.host").joinpath("foxglove_layout.json")


class FoxgloveView(Sink):
    """Starts a Foxglove WebSocket server on ``host:port`` (0 = any free port) at once."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "rfhoming") -> None:
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context,
                                            message_backlog_size=BACKLOG)
        self.address = f"ws://{host}:{self.server.port}"
        ctx = {"context": self.context}
        self.tf = channels.FrameTransformsChannel("/tf", **ctx)
        self.pose_channel = channels.PoseInFrameChannel("/robot/pose", **ctx)
        self.path_channel = channels.PosesInFrameChannel("/robot/path", **ctx)
        self.scan_channel = channels.LaserScanChannel("/scan", **ctx)
        self.scene = channels.SceneUpdateChannel("/rfhoming/scene", **ctx)
        self.particles = channels.PointCloudChannel("/rfhoming/particles", **ctx)
        self.obstacles = channels.PointCloudChannel("/rfhoming/obstacles", **ctx)
        self.json = {topic: foxglove.Channel(topic, message_encoding="json", **ctx)
                     for topic in ("/rfhoming/aoa", "/rfhoming/ble", "/rfhoming/antennas", "/rfhoming/measurement",
                                   "/rfhoming/command", "/rfhoming/estimate")}
        self.pose: tuple[float, float, float] | None = None
        self.path: deque[tuple[float, float, float]] = deque(maxlen=PATH_POSES)
        self.rays: deque[tuple[tuple[float, float], tuple[float, float]]] = deque(maxlen=RAYS)
        self._odometry = 0
        self._estimates = 0
        self.anchors: dict[str, tuple[float, float]] = {}
        self.loop: Any = None
        self.published = 0
        self.failed = 0  # items that could not be drawn (logged once)

    def _failed(self, kind: str, exc: Exception) -> None:
        """An item that cannot be drawn: counted, logged once."""
        if not self.failed:
            log.warning("Foxglove view: cannot publish a %s (%s); counting such failures", kind, exc)
        self.failed += 1

    def _on_item(self, device: str, t_host: float, item: Any) -> None:
        kind = getattr(item, "kind", None)
        if kind == "odometry":
            self._on_pose(item.x_mm / 1000, item.y_mm / 1000, item.theta_urad / 1e6)
        elif kind == "range_scan":
            self._log(self.scan_channel, messages.LaserScan(
                timestamp=self._now(), frame_id="base_link", start_angle=item.angle_min_mrad / 1000,
                end_angle=(item.angle_min_mrad + item.angle_inc_mrad * max(0, len(item.ranges_mm) - 1)) / 1000,
                ranges=[r / 1000 if r else math.inf for r in item.ranges_mm], intensities=[]))
        elif kind in ("angle", "adv_report", "antenna_set"):
            topic = {"angle": "/rfhoming/aoa", "adv_report": "/rfhoming/ble", "antenna_set": "/rfhoming/antennas"}[kind]
            self._log(self.json[topic], {"device": device, "t": t_host, **as_dict(item)})

    def _on_runlog(self, record: dict[str, Any]) -> None:
        kind = record.get("kind")
        if kind == "measurement":
            self._log(self.json["/rfhoming/measurement"], record)
            self._on_bearing(record)
        elif kind == "command":
            self._log(self.json["/rfhoming/command"], record)
        elif kind == "estimate":
            self._log(self.json["/rfhoming/estimate"], record)
            self._publish_scene(record)

    def show_anchors(self, anchors: dict[str, list[float]]) -> None:
        """Beacons at surveyed places (S3's ``[trilat.anchors]``), drawn in every scene update."""
        self.anchors = {name: (float(xy[0]), float(xy[1])) for name, xy in anchors.items()}

    def watch(self, loop: Any) -> None:
        """The homing loop, for what the run log does not hold: its controller's state (S2's
        particle cloud) and the obstacles it has mapped (its occupancy grid)."""
        self.loop = loop

    def close(self) -> None:
        self.server.stop()

    # -- drawing -------------------------------------------------------------------------
    def _on_pose(self, x: float, y: float, theta: float) -> None:
        m = messages
        self.pose = (x, y, theta)
        now = self._now()
        q = m.Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2))
        self._log(self.tf, m.FrameTransforms(transforms=[m.FrameTransform(
            timestamp=now, parent_frame_id="odom", child_frame_id="base_link",
            translation=m.Vector3(x=x, y=y, z=0.0), rotation=q)]))
        self._log(self.pose_channel, m.PoseInFrame(timestamp=now, frame_id="odom", pose=self._pose(x, y, theta)))
        if not self.path or math.dist(self.path[-1][:2], (x, y)) >= PATH_STEP_M:
            self.path.append(self.pose)
        self._odometry += 1
        if self._odometry % PATH_EVERY == 1:
            self._log(self.path_channel, m.PosesInFrame(timestamp=now, frame_id="odom",
                                                        poses=[self._pose(*p) for p in self.path]))

    def _on_bearing(self, record: dict[str, Any]) -> None:
        bearing = record.get("theta_s", record.get("theta"))
        if self.pose is None or bearing is None:
            return
        x, y, theta = self.pose
        length = record.get("distance", record.get("range")) or 2.0
        heading = theta + float(bearing)
        self.rays.append(((x, y), (x + length * math.cos(heading), y + length * math.sin(heading))))

    def _publish_scene(self, record: dict[str, Any]) -> None:
        m = messages
        now = self._now()
        entities = []
        goal = record.get("goal")
        if goal is not None:
            others = [record[k] for k in ("g_p", "g_v", "fix") if record.get(k) is not None]
            spread = max([math.dist(goal, o) for o in others] + [0.1])
            entities.append(m.SceneEntity(
                timestamp=now, frame_id="odom", id="target", spheres=[m.SpherePrimitive(
                    pose=self._pose(goal[0], goal[1], 0.0), size=m.Vector3(x=2 * spread, y=2 * spread, z=0.05),
                    color=m.Color(r=1.0, g=0.6, b=0.0, a=0.6))]))
        if record.get("fix") is not None and goal is None:
            fx, fy = record["fix"]
            entities.append(m.SceneEntity(timestamp=now, frame_id="odom", id="fix", spheres=[m.SpherePrimitive(
                pose=self._pose(fx, fy, 0.0), size=m.Vector3(x=0.2, y=0.2, z=0.05), color=m.Color(r=0.2, g=0.4, b=1.0, a=0.8))]))
        if self.rays:
            points = [m.Point3(x=px, y=py, z=0.05) for ray in self.rays for px, py in ray]
            entities.append(m.SceneEntity(timestamp=now, frame_id="odom", id="bearings", lines=[m.LinePrimitive(
                type=m.LinePrimitiveLineType.LineList, thickness=0.02, points=points,
                color=m.Color(r=0.1, g=0.8, b=0.2, a=0.8))]))
        for name, (ax, ay) in self.anchors.items():
            entities.append(m.SceneEntity(
                timestamp=now, frame_id="odom", id=f"anchor {name}",
                cubes=[m.CubePrimitive(pose=self._pose(ax, ay, 0.0), size=m.Vector3(x=0.15, y=0.15, z=0.3),
                                       color=m.Color(r=0.6, g=0.2, b=0.8, a=0.9))],
                texts=[m.TextPrimitive(pose=self._pose(ax, ay + 0.25, 0.0), billboard=True, font_size=12.0,
                                       scale_invariant=True, color=m.Color(r=1.0, g=1.0, b=1.0, a=1.0), text=name)]))
        if entities:
            self._log(self.scene, m.SceneUpdate(entities=entities))
        self._estimates += 1
        if self._estimates % CLOUD_EVERY == 1 and self.loop is not None:
            pf = getattr(self.loop.controller, "pf", None)
            if pf is not None and pf.initialised:
                self._log(self.particles, self._cloud(now, pf.x[:2].T))
            grid = self.loop.grid
            if grid is not None:
                cells = np.argwhere(grid.occupied())
                r = grid.params.resolution
                self._log(self.obstacles, self._cloud(now, [(grid.x0 + (i + 0.5) * r, grid.y0 + (j + 0.5) * r)
                                                            for i, j in cells]))

    def _cloud(self, now: Any, xy: Any) -> Any:
        """Points (x, y) in the odom frame as a point cloud of float32 pairs."""
        m = messages
        data = np.asarray(xy, dtype="<f4").reshape(-1, 2).tobytes()
        return m.PointCloud(
            timestamp=now, frame_id="odom", pose=self._pose(0.0, 0.0, 0.0), point_stride=8,
            fields=[m.PackedElementField(name="x", offset=0, type=m.PackedElementFieldNumericType.Float32),
                    m.PackedElementField(name="y", offset=4, type=m.PackedElementFieldNumericType.Float32)],
            data=data)

    # -- helpers ---------------------------------------------------------------------------
    def _pose(self, x: float, y: float, theta: float) -> Any:
        m = messages
        return m.Pose(position=m.Vector3(x=x, y=y, z=0.0),
                      orientation=m.Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)))

    def _now(self) -> Any:
        ns = time.time_ns()
        return messages.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)

    def _log(self, channel: Any, message: Any) -> None:
        channel.log(message)
        self.published += 1
