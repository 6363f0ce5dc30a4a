"""Foxglove's own client against the live view: ``FoxgloveClient`` from npm ``@foxglove/ws-protocol``
(the class Foxglove's app is built on), run with node as a user runs it, offering its default
subprotocol ``foxglove.websocket.v1`` (tests/foxglove_client/watch.js; ``.ci/run`` installs its
locked packages with ``npm ci``). It gets serverInfo, the advertised channels, subscribes to each,
and decodes a message on every channel with the schema the server advertised."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rfhoming.host.drivers.robot_base import Scan
from rfhoming.host.foxglove_view import FoxgloveView
from rfhoming.host.homing.grid import OccupancyGrid
from rfhoming.host.homing.types import Pose
from rfhoming.protocol.frames.records import AdvReport, AntennaReading, AntennaSet, Odometry, RangeScan
from rfhoming.protocol.uconnect.items import AngleEvent

CLIENT = Path(__file__).parent / "foxglove_client"
SAFETY_S = 60
TOPICS = ["/tf", "/tf_static", "/robot/pose", "/robot/path", "/scan", "/rfhoming/scene", "/rfhoming/particles",
          "/rfhoming/obstacles", "/rfhoming/aoa", "/rfhoming/ble", "/rfhoming/antennas", "/rfhoming/measurement",
          "/rfhoming/command", "/rfhoming/estimate"]

needs_node = pytest.mark.skipif(shutil.which("node") is None or not (CLIENT / "node_modules" / "@foxglove").is_dir(),
                                 reason="needs node and `npm ci` in tests/foxglove_client (.ci/run does both)")


def a_loop() -> SimpleNamespace:
    """What the view draws of a homing loop: S2's particles and an occupancy grid with a wall."""
    grid = OccupancyGrid((0.0, 0.0))
    angles = np.linspace(-0.5, 0.5, 21)
    grid.integrate(Pose(0.0, 0.0, 0.0), Scan(0.0, -0.5, 0.05, tuple(2.0 / np.cos(a) for a in angles)))
    pf = SimpleNamespace(initialised=True, x=np.array([[1.0, 1.5, 2.0], [0.5, 0.0, -0.5], [0.0, 0.0, 0.0]]))
    return SimpleNamespace(grid=grid, controller=SimpleNamespace(pf=pf), config=None)


def feed(view: FoxgloveView, i: int) -> None:
    """One round of everything the view publishes: device items and run log records."""
    t_us = 1_000_000 + 20_000 * i
    view.on_item("base", 0.0, Odometry(1, i, t_us, 10 * i, 0, 0, 100, 0, 0))
    view.on_item("base", 0.0, RangeScan(1, i, t_us, -500, 50, (2000,) * 21))
    view.on_item("aoa", 0.0, AngleEvent("CCF9578E0D8A", -60, 30, 0, 0, 37, "CCF9578E0D8A", "", 1000 + i, i, None, None))
    view.on_item("rss", 0.0, AdvReport(2, i, t_us, bytes.fromhex("0100000000ac"), 0, 0, -70, 0, 37, b"\x02\x01\x06"))
    view.on_item("dish", 0.0, AntennaSet(3, i, t_us, i, 11, 0, -90, 15, (AntennaReading(10, 200, 0),) * 4))
    t = t_us / 1e6
    view.on_runlog({"kind": "measurement", "t": t, "source": "ble", "address": "AC0000000001", "rssi": -70.0})
    view.on_runlog({"kind": "command", "t": t, "v": 0.2, "w": 0.0})
    view.on_runlog({"kind": "estimate", "t": t, "goal": [3.0, 0.5], "pose": [0.01 * i, 0.0, 0.0], "offset": [0.5, 0.2]})


@needs_node
def test_foxglove_client_with_its_default_subprotocol_decodes_every_channel() -> None:
    view = FoxgloveView(port=0)
    view.watch(a_loop())
    view.show_anchors({"AC0000000001": [4.0, 1.0]})
    node = subprocess.Popen(["node", "watch.js", view.address, ",".join(TOPICS), str(SAFETY_S)], cwd=CLIENT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + SAFETY_S
        i = 0
        while node.poll() is None and time.monotonic() < deadline:
            feed(view, i)  # until the client has had every channel (a late subscriber misses the first)
            i += 1
            time.sleep(0.05)
        out, err = node.communicate(timeout=SAFETY_S)
    finally:
        if node.poll() is None:
            node.kill()
        view.close()
    got = json.loads(out)
    assert got["offered"] == "foxglove.websocket.v1" and got["protocol"] == "foxglove.websocket.v1", err
    assert got["serverInfo"]["name"] == "rfhoming" and "time" in got["serverInfo"]["capabilities"]
    assert sorted(c["topic"] for c in got["channels"]) == sorted(TOPICS) and not got["errors"], got["errors"]
    assert all(got["counts"].get(topic, 0) > 0 for topic in TOPICS), got["counts"]

    last = got["last"]  # decoded with the advertised schemas: protobuf ...
    assert last["/robot/pose"]["frame_id"] == "odom" and last["/robot/pose"]["pose"]["position"]["x"] > 0
    assert {(t["parent_frame_id"], t["child_frame_id"]) for t in last["/tf_static"]["transforms"]} >= {
        ("base_link", "aoa_link"), ("base_link", "laser")}
    assert len(last["/scan"]["ranges"]) == 21 and last["/scan"]["frame_id"] == "laser"
    assert any(e["id"] == "target" for e in last["/rfhoming/scene"]["entities"])
    assert last["/rfhoming/particles"]["point_stride"] == 8
    # ... and JSON, where a BLE address is spelt one way on every channel
    assert last["/rfhoming/aoa"]["azimuth"] == 30
    assert last["/rfhoming/ble"]["address"] == last["/rfhoming/measurement"]["address"] == "AC0000000001"
    assert "addr" not in last["/rfhoming/ble"]
    assert last["/rfhoming/command"]["v"] == 0.2 and last["/rfhoming/estimate"]["goal"] == [3.0, 0.5]
