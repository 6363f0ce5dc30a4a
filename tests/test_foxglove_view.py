"""The live Foxglove view: a WebSocket client subscribes during ``demo --foxglove`` and decodes
the scene with nothing but what the server advertises (protobuf schemas, JSON)."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import threading
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rigs
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from rfhoming.host.drivers.robot_base import Scan
from rfhoming.host.foxglove_view import LAYOUT, FoxgloveView
from rfhoming.host.homing.grid import OccupancyGrid
from rfhoming.host.homing.types import Pose

SUBPROTOCOL = "foxglove.sdk.v1"
SAFETY_S = 60  # bounds each wait, so a broken server fails the test instead of hanging it


def decoders(channels: list[dict]) -> dict[int, tuple[str, object]]:
    """channel id -> (topic, bytes -> message), from the advertised schemas alone."""
    out = {}
    for ch in channels:
        if ch["encoding"] == "json":
            assert ch["schemaEncoding"] == "jsonschema" and json.loads(ch["schema"])["properties"], ch["topic"]
            out[ch["id"]] = (ch["topic"], json.loads)
            continue
        assert ch["encoding"] == "protobuf" and ch["schemaEncoding"] == "protobuf"
        pool = descriptor_pool.DescriptorPool()
        for fd in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(ch["schema"])).file:
            pool.Add(fd)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(ch["schemaName"]))
        out[ch["id"]] = (ch["topic"], cls.FromString)
    return out


def watch(address: str, got: dict[str, list] | None = None, info: dict | None = None) -> dict[str, list]:
    """Subscribe to every channel as it is advertised; topic -> decoded messages (into ``got``
    as they come, if given), until the server goes away. ``info`` collects the server info,
    the advertised channels and the time messages (spec: binary opcode 2, u64 ns)."""
    got = defaultdict(list) if got is None else got
    info = {} if info is None else info
    channels: dict[int, tuple[str, object]] = {}
    with connect(address, subprotocols=[SUBPROTOCOL], open_timeout=SAFETY_S) as ws:
        try:
            while True:
                frame = ws.recv(timeout=SAFETY_S)
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "serverInfo":
                        info["serverInfo"] = op
                    if op["op"] == "advertise":
                        info.setdefault("channels", []).extend(op["channels"])
                        fresh = decoders(op["channels"])
                        subs = [{"id": cid, "channelId": cid} for cid in fresh]
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        channels.update(fresh)
                    continue
                if frame[0] == 0x02:  # time: op, timestamp u64 ns
                    info.setdefault("time", []).append(int.from_bytes(frame[1:9], "little"))
                    continue
                assert frame[0] == 0x01  # message data: op, subscription id u32, log time u64, payload
                sub = int.from_bytes(frame[1:5], "little")
                topic, parse = channels[sub]
                got.setdefault(topic, []).append(parse(frame[13:]))
        except ConnectionClosed:
            pass
    return got


def watched_demo(out: Path, *args: str) -> tuple[dict[str, list], list[dict]]:
    """``demo --foxglove=0`` watched from start to end: what the client got, and the run log."""
    demo = subprocess.Popen([sys.executable, "-m", "rfhoming", "demo", "--out", str(out), "--foxglove=0",
                             "--json", "--linger", "0", *(args or ("--speed", "0"))], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = json.loads(rigs.readline(demo, "stderr", SAFETY_S))
        assert first["kind"] == "listening" and first["address"].startswith("ws://127.0.0.1:")
        got = watch(first["address"])
        _, err = demo.communicate(timeout=SAFETY_S)
    finally:
        if demo.poll() is None:
            demo.kill()
    assert demo.returncode == 0, err
    return got, [json.loads(line) for line in (out / "run.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_a_websocket_client_receives_the_scene_during_demo(tmp_path: Path) -> None:
    got, runlog = watched_demo(tmp_path)

    # the robot: its pose, the path, the transform, all decoded from protobuf
    poses = [(round(m.pose.position.x, 4), round(m.pose.position.y, 4)) for m in got["/robot/pose"]]
    final = [r for r in runlog if r["kind"] == "estimate"][-1]["pose"]
    assert len(poses) > 20 and (round(final[0], 4), round(final[1], 4)) in poses
    assert got["/tf"][-1].transforms[0].child_frame_id == "base_link"
    assert len(got["/robot/path"][-1].poses) > len(got["/robot/path"][0].poses)

    # the target estimate and the bearings, in the scene
    goals = {tuple(r["goal"]) for r in runlog if r["kind"] == "estimate" and r.get("goal")}
    entities = [e for update in got["/rfhoming/scene"] for e in update.entities]
    targets = [(e.spheres[0].pose.position.x, e.spheres[0].pose.position.y) for e in entities if e.id == "target"]
    assert targets and set(targets) <= goals
    rays = [e for e in entities if e.id == "bearings"]
    assert rays and len(rays[-1].lines[0].points) % 2 == 0

    # the raw readings and the loop's records, as JSON for plots
    assert {m["kind"] for m in got["/rfhoming/aoa"]} == {"angle"}
    commands = [r for r in runlog if r["kind"] == "command"]
    seen = got["/rfhoming/command"]
    assert len(seen) > 10
    rest = iter(commands)
    # in order and none made up; a client slower than a lockstep run may miss some, as the SDK's
    # per-client backlog is bounded (host/foxglove_view.py BACKLOG) -- a loaded machine did
    assert all(any(c == m for c in rest) for m in seen)


@pytest.mark.slow
def test_the_particle_cloud_and_mapped_obstacles_of_s2_are_published(tmp_path: Path) -> None:
    got, runlog = watched_demo(tmp_path, "--scenario", "s2-a", "--speed", "0")
    clouds = got["/rfhoming/particles"]
    assert len(clouds) > 3
    last = clouds[-1]
    assert [f.name for f in last.fields] == ["x", "y"] and last.point_stride == 8
    xy = np.frombuffer(last.data, "<f4").reshape(-1, 2)
    assert len(xy) >= 100
    goal = [r["goal"] for r in runlog if r["kind"] == "estimate" and r.get("goal")][-1]
    assert np.hypot(*(xy.mean(axis=0) - goal)) < 1.0  # the cloud sits on the filter's estimate



def test_the_obstacles_the_loop_mapped_are_published(tmp_path: Path) -> None:
    """A wall 2 m ahead seen by one scan: its cells come out as the obstacle cloud."""
    grid = OccupancyGrid((0.0, 0.0))
    angles = np.linspace(-0.5, 0.5, 21)
    grid.integrate(Pose(0.0, 0.0, 0.0), Scan(0.0, -0.5, 0.05, tuple(2.0 / np.cos(a) for a in angles)))
    view = FoxgloveView(port=0)
    view.watch(SimpleNamespace(grid=grid, controller=None))
    result: dict[str, list] = {}
    client = threading.Thread(target=watch, args=(view.address, result))
    client.start()
    try:
        for _ in range(SAFETY_S * 10):  # until the client has subscribed and got one
            view.on_runlog({"kind": "estimate", "t": 1.0, "goal": [3.0, 0.0], "pose": [0.0, 0.0, 0.0]})
            if result.get("/rfhoming/obstacles"):
                break
            client.join(0.1)
    finally:
        view.close()
        client.join(SAFETY_S)
    mapped = np.frombuffer(result["/rfhoming/obstacles"][-1].data, "<f4").reshape(-1, 2)
    assert len(mapped) >= 10
    assert all(distance_to_segment(p, (2.0, -1.2), (2.0, 1.2)) < 0.2 for p in mapped)


def distance_to_segment(p, a, b) -> float:
    p, a, b = (np.asarray(v, float) for v in (p, a, b))
    ab = b - a
    u = 0.0 if not ab.any() else float(np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0))
    return float(np.hypot(*(p - (a + u * ab))))


@pytest.mark.slow
def test_the_anchors_of_s3_are_drawn(tmp_path: Path) -> None:
    got, _ = watched_demo(tmp_path, "--scenario", "s3-arena", "--speed", "0", "--radio", "ideal")  # arrives
    header = json.loads((tmp_path / "truth.jsonl").read_text().splitlines()[0])
    entities = {e.id: e for update in got["/rfhoming/scene"] for e in update.entities}
    anchors = {k: (e.cubes[0].pose.position.x, e.cubes[0].pose.position.y) for k, e in entities.items()
               if k.startswith("anchor ")}
    assert len(anchors) >= 3
    truth = json.loads((tmp_path / "truth.jsonl").read_text().splitlines()[1])
    surveyed = {(t["x"], t["y"]) for t in truth["targets"]}  # the demo surveys them from the truth file
    assert set(anchors.values()) == surveyed and header["scenario"] == "s3-arena"


def test_the_shipped_layout_names_the_published_topics() -> None:
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]
    three_d = next(v for k, v in panels.items() if k.startswith("3D!"))
    assert {"/robot/path", "/rfhoming/scene", "/scan"} <= set(three_d["topics"])
    plotted = {p["value"].split(".")[0] for k, v in panels.items() if k.startswith("Plot!") for p in v["paths"]}
    assert {"/rfhoming/aoa", "/rfhoming/command", "/rfhoming/measurement"} <= plotted

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)


def test_a_hostile_client_is_cut_off_and_a_good_one_still_served() -> None:
    """The SDK's input bound, which rfhoming cannot set: a message over 16 MiB ends that
    client's connection (garbage and smaller messages are logged and ignored); the view keeps
    serving other clients. Outgoing, each client's backlog is BACKLOG messages."""
    view = FoxgloveView(port=0)
    try:
        with connect(view.address, subprotocols=[SUBPROTOCOL], open_timeout=SAFETY_S, max_size=None) as ws:
            ws.send(b"\x01garbage")
            try:
                ws.send(b"\x01" * (17 << 20))
                while True:  # a TimeoutError here: the server kept the client
                    ws.recv(timeout=SAFETY_S)
            except ConnectionClosed:
                pass
        with connect(view.address, subprotocols=[SUBPROTOCOL], open_timeout=SAFETY_S) as ws:
            assert json.loads(ws.recv(timeout=SAFETY_S))["op"] == "serverInfo"
    finally:
        view.close()
