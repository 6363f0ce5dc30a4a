"""A live view in Foxglove (or Lichtblick): a Foxglove WebSocket server fed by a run.

:class:`FoxgloveView` is a sink like the MCAP recorder: ``on_item`` sees every decoded device
item, ``on_runlog`` every run log record. It publishes, with foxglove-sdk's own schemas:

- ``/tf`` (odom -> base_link from every odometry record; map -> odom when S3's anchors fix the
  robot), ``/tf_static`` (base_link -> aoa_link, laser, rss_link, ble_link from the config's
  ``[mounting]``, sent again every ``PATH_EVERY`` odometry records, since a viewer may join
  late and the server keeps no latched messages), ``/robot/pose`` and ``/robot/path``, and
  ``/scan`` in the ``laser`` frame;
- ``/rfhoming/scene``: the target estimate as a sphere (its diameter: the spread of the
  estimates it came from, e.g. S0's parallax and vector goals, at least 0.2 m), the latest
  bearings as rays from the robot (length: the range estimate, else 2 m), S3's position fix
  and anchors (:meth:`FoxgloveView.show_anchors`);
- ``/rfhoming/particles``: S2's particle cloud, ``/rfhoming/obstacles``: the occupied cells of
  the loop's occupancy grid (both when the view :meth:`FoxgloveView.watch` es the loop);
- JSON channels for plots, each with its JSON schema (host/foxglove_schemas.py):
  ``/rfhoming/aoa`` (angle events), ``/rfhoming/ble`` (BLE RSSI; ``address`` MSB first, as in
  the run log's measurements), ``/rfhoming/antennas``
  (antenna sets), ``/rfhoming/measurement``, ``/rfhoming/command``, ``/rfhoming/estimate``.

Scene entities have lifetimes (:data:`ENTITY_LIFETIME_S`; the anchors none: they stay), so a
stale estimate disappears. ``foxglove_layout.json`` beside this module is a layout that shows
them (Foxglove: Layouts -> Import from file).

Time: in a run (the view watches its loop) robot time, the run log's axis (0 before the
first odometry), else the host's wall clock (``listen``/``serve`` without a base). The server has the ``time`` capability and
broadcasts that clock, so the viewer's "now" is the robot's.

Clients: foxglove-sdk's server listens on a free loopback port behind
:class:`~rfhoming.host.foxglove_front.Front`, which takes both names of the protocol
(``foxglove.sdk.v1``, which the SDK alone accepts, and the spec's ``foxglove.websocket.v1``, which
Foxglove's ``FoxgloveClient`` and Lichtblick 1.21 and older offer) and stands between the SDK
and its clients, so that one that never reads cannot stall the SDK's ``stop()`` (nor Ctrl-C);
the SDK's listener takes only the front's connections (host/loopback_key.py).
The SDK's own log lines (about what a client sent, or a connection that broke) are kept out of
Python's logging: each needs the GIL from the SDK's network threads, so a client sending garbage
would make them queue for it behind the run; the front counts and logs what matters.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from importlib.resources import files
from typing import Any

import foxglove
import numpy as np
from foxglove import channels, messages
from foxglove.websocket import Capability, ServerListener

from rfhoming.host import loopback_key
from rfhoming.host.drivers.robot_base import scan_of
from rfhoming.host.drivers.rss import NodeClock
from rfhoming.host.export import frames
from rfhoming.host.foxglove_front import Front
from rfhoming.host.foxglove_schemas import SCHEMAS
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
STOP_S = 5.0  # what close() waits for the SDK's server to stop
ENTITY_LIFETIME_S = 2.0  # a scene entity not drawn again within this vanishes
LAYOUT = files("rfhoming.host").joinpath("foxglove_layout.json")


class FoxgloveView(Sink):
    """Starts a Foxglove WebSocket server on ``host:port`` (0 = any free port) at once."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "rfhoming") -> None:
        self.context = foxglove.Context()
        self._subscribed = threading.Event()
        logging.getLogger("foxglove").setLevel(logging.CRITICAL)  # the SDK logs nothing that high
        self.server = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self.context,
                                            capabilities=[Capability.Time], server_listener=_Listener(self._subscribed),
                                            message_backlog_size=BACKLOG)
        try:
            self.front = Front(self.server.port, host, port, key=self._lock())
        except BaseException:
            self._stop_server()
            raise
        self.address = f"ws://{host}:{self.front.port}"
        ctx: dict[str, Any] = {"context": self.context}
        self.tf = channels.FrameTransformsChannel("/tf", **ctx)
        self.tf_static = channels.FrameTransformsChannel("/tf_static", **ctx)
        self.pose_channel = channels.PoseInFrameChannel("/robot/pose", **ctx)
        self.path_channel = channels.PosesInFrameChannel("/robot/path", **ctx)
        self.scan_channel = channels.LaserScanChannel("/scan", **ctx)
        self.scene = channels.SceneUpdateChannel("/rfhoming/scene", **ctx)
        self.particles = channels.PointCloudChannel("/rfhoming/particles", **ctx)
        self.obstacles = channels.PointCloudChannel("/rfhoming/obstacles", **ctx)
        self.json = {topic: foxglove.Channel(topic, message_encoding="json", schema=schema, **ctx)
                     for topic, schema in SCHEMAS.items()}
        self.pose: tuple[float, float, float] | None = None
        self.path: deque[tuple[float, float, float]] = deque(maxlen=PATH_POSES)
        self.rays: deque[tuple[tuple[float, float], tuple[float, float]]] = deque(maxlen=RAYS)
        self._odometry = 0
        self._estimates = 0
        self._clock = NodeClock()
        self.robot_time: float | None = None  # of the latest odometry
        self.clock = "host"  # "robot" once it watches a run's loop (a base is there): robot time only
        self.mounts = frames.sensor_mounts(None)
        self.anchors: dict[str, tuple[float, float]] = {}
        self.loop: Any = None
        self.published = 0
        self.failed = 0  # items that could not be drawn (logged once)

    def _lock(self) -> bytes | None:
        """The SDK's listener keyed, so that only the front reaches it; where it cannot be, said
        with the reason, and the listener is left open to local programs (None)."""
        try:
            return loopback_key.lock(self.server.port)
        except loopback_key.NotLocked as why:
            log.warning("Foxglove view: the SDK's listener (127.0.0.1:%d) cannot be locked: %s; local programs can "
                        "reach it past the front's limits", self.server.port, why)
            return None

    def wait_for_viewer(self, timeout: float) -> bool:
        """Block until a client has subscribed to a channel (True) or ``timeout`` seconds pass."""
        return self._subscribed.wait(timeout)

    def _failed(self, kind: str, exc: Exception) -> None:
        """An item that cannot be drawn: counted, logged once."""
        if not self.failed:
            log.warning("Foxglove view: cannot publish a %s (%s); counting such failures", kind, exc)
        self.failed += 1

    def _on_item(self, device: str, t_host: float, item: Any) -> None:
        kind = getattr(item, "kind", None)
        if kind == "odometry":
            self.robot_time = self._clock.unwrap(item.t_us) / 1e6
            self.server.broadcast_time(self._ns())
            self._on_pose(item.x_mm / 1000, item.y_mm / 1000, item.theta_urad / 1e6)
        elif kind in ("range_scan", "range_scan_v2"):
            scan = scan_of(item)
            self._log(self.scan_channel, messages.LaserScan(
                timestamp=self._now(), frame_id=frames.LASER, start_angle=scan.angle_min, end_angle=scan.angle_max,
                ranges=[math.inf if r is None else r for r in scan.ranges], intensities=[]))
        elif kind in ("angle", "adv_report", "antenna_set"):
            if self.clock == "host":
                self.server.broadcast_time(self._ns())  # no base: the host's clock
            topic = {"angle": "/rfhoming/aoa", "adv_report": "/rfhoming/ble", "antenna_set": "/rfhoming/antennas"}[kind]
            fields = as_dict(item)
            if kind == "adv_report":  # the BLE address as everywhere else in rfhoming, not the record's bytes
                fields["address"] = ble_address(fields.pop("addr"))
            self._log(self.json[topic], {"device": device, "t": self._ns() / 1e9, **fields})

    def _on_runlog(self, record: dict[str, Any]) -> None:
        kind = record.get("kind")
        if kind == "measurement":
            self._log(self.json["/rfhoming/measurement"], record)
            self._on_bearing(record)
        elif kind == "command":
            self._log(self.json["/rfhoming/command"], record)
        elif kind == "estimate":
            self._log(self.json["/rfhoming/estimate"], record)
            if record.get("offset") is not None:  # S3: the anchors place odom in the map
                self._log(self.tf, messages.FrameTransforms(transforms=[
                    self._transform(frames.map_to_odom(record["offset"]))]))
            self._publish_scene(record)

    def show_anchors(self, anchors: dict[str, list[float]]) -> None:
        """Beacons at surveyed places (S3's ``[trilat.anchors]``), drawn in every scene update."""
        self.anchors = {name: (float(xy[0]), float(xy[1])) for name, xy in anchors.items()}

    def watch(self, loop: Any) -> None:
        """The homing loop, for what the run log does not hold: its controller's state (S2's
        particle cloud), the obstacles it has mapped (its occupancy grid) and its config's
        sensor mountings."""
        self.loop = loop
        self.clock = "robot"
        config = getattr(loop, "config", None)
        if config is not None:
            self.mounts = frames.sensor_mounts(config.mounting)

    def close(self) -> None:
        """The front first (every client gone), then the SDK's server, waited for STOP_S at most."""
        self.front.close()
        self._stop_server()

    def _stop_server(self) -> None:
        stopper = threading.Thread(target=self.server.stop, name="foxglove-stop", daemon=True)
        stopper.start()
        stopper.join(STOP_S)
        if stopper.is_alive():
            log.warning("Foxglove view: the server did not stop within %.0f s; leaving it", STOP_S)

    # -- drawing -------------------------------------------------------------------------
    def _on_pose(self, x: float, y: float, theta: float) -> None:
        m = messages
        self.pose = (x, y, theta)
        now = self._now()
        self._log(self.tf, m.FrameTransforms(transforms=[
            self._transform(frames.Transform(frames.ODOM, frames.BASE, (x, y, 0.0), theta))]))
        self._log(self.pose_channel, m.PoseInFrame(timestamp=now, frame_id="odom", pose=self._pose(x, y, theta)))
        if not self.path or math.dist(self.path[-1][:2], (x, y)) >= PATH_STEP_M:
            self.path.append(self.pose)
        self._odometry += 1
        if self._odometry % PATH_EVERY == 1:
            self._log(self.tf_static, m.FrameTransforms(transforms=[self._transform(tf) for tf in self.mounts]))
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
        life = messages.Duration.from_secs(ENTITY_LIFETIME_S)
        entities = []
        goal = record.get("goal")
        if goal is not None:
            others = [record[k] for k in ("g_p", "g_v", "fix") if record.get(k) is not None]
            spread = max([math.dist(goal, o) for o in others] + [0.1])
            entities.append(m.SceneEntity(
                timestamp=now, frame_id="odom", id="target", lifetime=life, spheres=[m.SpherePrimitive(
                    pose=self._pose(goal[0], goal[1], 0.0), size=m.Vector3(x=2 * spread, y=2 * spread, z=0.05),
                    color=m.Color(r=1.0, g=0.6, b=0.0, a=0.6))]))
        if record.get("fix") is not None and goal is None:
            fx, fy = record["fix"]
            frame = frames.MAP if "offset" in record else frames.ODOM  # S3 (also localising): the robot in the map
            entities.append(m.SceneEntity(timestamp=now, frame_id=frame, id="fix", lifetime=life, spheres=[m.SpherePrimitive(
                pose=self._pose(fx, fy, 0.0), size=m.Vector3(x=0.2, y=0.2, z=0.05), color=m.Color(r=0.2, g=0.4, b=1.0, a=0.8))]))
        if self.rays:
            points = [m.Point3(x=px, y=py, z=0.05) for ray in self.rays for px, py in ray]
            entities.append(m.SceneEntity(timestamp=now, frame_id="odom", id="bearings", lifetime=life, lines=[m.LinePrimitive(
                type=m.LinePrimitiveLineType.LineList, thickness=0.02, points=points,
                color=m.Color(r=0.1, g=0.8, b=0.2, a=0.8))]))
        for name, (ax, ay) in self.anchors.items():
            entities.append(m.SceneEntity(
                timestamp=now, frame_id=frames.MAP, id=f"anchor {name}",
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

    def _transform(self, tf: frames.Transform) -> Any:
        m = messages
        return m.FrameTransform(timestamp=self._now(), parent_frame_id=tf.parent, child_frame_id=tf.child,
                                translation=m.Vector3(x=tf.xyz[0], y=tf.xyz[1], z=tf.xyz[2]),
                                rotation=m.Quaternion(**tf.quaternion()))

    def _ns(self) -> int:
        """The view's clock: robot time in a run (0 before the first odometry), else the host's
        wall clock."""
        if self.clock == "host":
            return time.time_ns()
        return 0 if self.robot_time is None else max(0, round(self.robot_time * 1e9))

    def _now(self) -> Any:
        ns = self._ns()
        return messages.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)

    def _log(self, channel: Any, message: Any) -> None:
        channel.log(message, log_time=self._ns())
        self.published += 1


def ble_address(lsb_first_hex: str) -> str:
    """A BLE address as rfhoming spells it everywhere (the run log, the ROS messages, the
    XPLR-AOA's tag ids): MSB first, upper-case hex, no colons (``AC0000000001``); framed
    records carry it LSB first, as on the air."""
    return bytes.fromhex(lsb_first_hex)[::-1].hex().upper()


class _Listener(ServerListener):
    """Sets ``subscribed`` when a client first subscribes to a channel."""

    def __init__(self, subscribed: threading.Event) -> None:
        self.subscribed = subscribed

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.subscribed.set()
