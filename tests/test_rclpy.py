"""ROS 2's own client library against rfhoming: a node written with rclpy (ROS 2 Jazzy's wheels,
rmw_fastrtps_cpp, i.e. Fast DDS, ROS 2's default middleware) in a process of its own
(tests/rclpy_node.py: nothing of rfhoming in it), on loopback only (docs/ros2/fastdds-loopback.xml).
The node drives the emulated ROS 2 robot and sees it move; hears what a ``ros2:`` base and
``--ros2`` publish, with ROS 2's types, QoS, REP 105 frames and REP 117 ranges; is a robot that
``rfhoming run --base ros2:`` homes, the emulated radios riding on it (``emulate --pose-from``);
and reads ``locate --ros2``'s poses. Topics whose types have no wheel (tf2_msgs,
rfhoming_msgs) are checked in the node's ROS graph: their names and types."""

from __future__ import annotations

import json
import math
import os
import platform
import random
import sys
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import pytest
import rigs

pytest.importorskip("cyclonedds")

ROOT = Path(__file__).resolve().parent.parent
NODE = Path(__file__).with_name("rclpy_node.py")
WHEELS = "ros-jazzy-rclpy ros-jazzy-rmw-fastrtps-cpp ros-jazzy-nav-msgs ros-jazzy-sensor-msgs ros-jazzy-geometry-msgs"
HAS_WHEELS = sys.platform == "linux" and platform.machine() == "x86_64" and (3, 11) <= sys.version_info < (3, 15)
"""Where ROS 2 Jazzy's wheels exist (pyproject's test extra installs them there)."""

MISSING = not all(find_spec(name) for name in ("rclpy", "nav_msgs", "sensor_msgs", "geometry_msgs"))
if MISSING and not (os.environ.get("CI") and HAS_WHEELS):
    pytest.skip(f"needs ROS 2 Jazzy's rclpy (Linux x86_64, Python 3.11-3.14): pip install {WHEELS}",
                allow_module_level=True)


@pytest.fixture(autouse=True)
def wheels() -> None:
    """On CI, where the test extra installs the wheels, their absence fails each test."""
    if MISSING:
        pytest.fail(f"CI must have ROS 2 Jazzy's rclpy (pyproject's test extra installs it): pip install {WHEELS}",
                    pytrace=False)


def random_domain() -> int:
    return random.SystemRandom().randint(61, 76)  # tests/test_ros2.py random_domain says why


def rclpy_node(tmp_path: Path, domain: int, *args: str) -> rigs.Child:
    """tests/rclpy_node.py on ``domain``, its stdin a pipe (closed: it ends 3 s later)."""
    return rigs.Child([sys.executable, str(NODE), str(domain), "300", "--log-dir", str(tmp_path), *args], stdin=True)


def ended(node: rigs.Child) -> list[dict[str, Any]]:
    """Everything the node printed, taken or not, once it has ended (its stdin closed first)."""
    if node.proc.stdin is not None and not node.proc.stdin.closed:
        node.proc.stdin.close()
    assert node.wait(120) == 0, node.stderr()
    return [json.loads(line) for line in node.output()[0].splitlines()]


def ready(node: rigs.Child, domain: int) -> None:
    assert node.json_line(120, "the node's ready line") == {"ready": domain}


def heard(lines: list[dict[str, Any]], topic: str) -> list[dict[str, Any]]:
    return [line for line in lines if line.get("topic") == topic]


def publishers(lines: list[dict[str, Any]], topic: str) -> list[dict[str, str]]:
    """What the ROS graph said of ``topic``'s publishers when its first message came."""
    return next(line["publishers"] for line in lines if line.get("topic") == topic and "publishers" in line)


def graph(lines: list[dict[str, Any]]) -> dict[str, list[str]]:
    return next(line["graph"] for line in lines if "graph" in line)


def rep117(scan: dict[str, Any]) -> None:
    """REP 117, as docs/protocol.md says rfhoming keeps it: every beam a range within
    [range_min, range_max] or +inf (no return); never NaN; -inf only below range_min (not here)."""
    assert scan["beams"] == scan["in_range"] + scan["pos_inf"] and scan["nan"] == 0 and scan["neg_inf"] == 0, scan


SENSOR_QOS = {"reliability": "BEST_EFFORT", "durability": "VOLATILE"}
DEFAULT_QOS = {"reliability": "RELIABLE", "durability": "VOLATILE"}


def test_an_rclpy_node_drives_the_emulated_ros2_robot_and_reads_its_topics(tmp_path: Path, emulated) -> None:
    """The quick one: ``emulate --robot ros2`` as a ROS 2 robot to rclpy -- /cmd_vel moves it,
    /odom (sensor-data QoS, odom -> base_link) shows it, /scan keeps REP 117, /tf is a TFMessage."""
    domain = random_domain()
    with emulated("s2-a", "--robot", f"ros2:domain={domain}", link_dir=tmp_path):
        node = rclpy_node(tmp_path, domain, "--listen", "/odom=nav_msgs/msg/Odometry",
                          "--listen", "/scan=sensor_msgs/msg/LaserScan", "--drive", "0.3,0,0.3")
        with node:
            ready(node, domain)
            node.until('"driven"', 120)  # discovery and 0.3 m at 0.3 m/s, however busy the machine
            lines = ended(node)
    assert next(line["driven"] for line in lines if "driven" in line) >= 0.3
    odom = heard(lines, "/odom")
    assert all(o["type"] == "nav_msgs/msg/Odometry" and o["frame"] == "odom" and o["child"] == "base_link" for o in odom)
    assert publishers(lines, "/odom") == [{"type": "nav_msgs/msg/Odometry", **SENSOR_QOS}]
    first, last = odom[0], odom[-1]
    assert math.dist((first["x"], first["y"]), (last["x"], last["y"])) >= 0.3
    # straight ahead (w = 0): along the heading it started with, and /odom said how fast
    assert math.atan2(last["y"] - first["y"], last["x"] - first["x"]) == pytest.approx(first["yaw"], abs=0.05)
    assert any(o["v"] == pytest.approx(0.3, abs=0.01) for o in odom)
    scans = heard(lines, "/scan")
    assert scans and publishers(lines, "/scan") == [{"type": "sensor_msgs/msg/LaserScan", **SENSOR_QOS}]
    for scan in scans:
        assert scan["frame"] == "laser" and scan["beams"] == 181 and scan["range_max"] == 8.0
        assert scan["angle_min"] == pytest.approx(-math.pi / 2, abs=1e-6)
        rep117(scan)
    topics = graph(lines)
    assert topics["/tf"] == ["tf2_msgs/msg/TFMessage"] and topics["/cmd_vel"] == ["geometry_msgs/msg/Twist"]


@pytest.mark.slow
def test_an_rclpy_node_hears_a_run_through_a_ros2_base(tmp_path: Path, emulated, cli) -> None:
    """``run --base ros2: --ros2``: the robot's /odom and the driver's /cmd_vel (ROS 2's default
    QoS, its stop three zeros), and --ros2's target, events and the commands' mirror, as rclpy reads them."""
    domain = random_domain()
    with emulated("s0-open", "--robot", f"ros2:domain={domain}", link_dir=tmp_path) as emulator:
        listen = [f"--listen={t}" for t in ("/odom=nav_msgs/msg/Odometry", "/cmd_vel=geometry_msgs/msg/Twist",
                                            "/rfhoming/cmd_vel=geometry_msgs/msg/Twist",
                                            "/rfhoming/target=geometry_msgs/msg/PointStamped",
                                            "/rfhoming/events=std_msgs/msg/String")]
        with rclpy_node(tmp_path, domain, *listen) as node:
            ready(node, domain)
            run = cli("run", "--aoa", emulator.path("aoa"), "--base", f"ros2:domain={domain}", "--ros2", f"domain={domain}")
            lines = ended(node)
    assert run.returncode == 0 and json.loads(run.stdout)["arrived"], run.stderr
    assert publishers(lines, "/cmd_vel") == [{"type": "geometry_msgs/msg/Twist", **DEFAULT_QOS}]
    commands = [(c["v"], c["w"]) for c in heard(lines, "/cmd_vel")]
    assert any(v > 0.1 for v, _ in commands) and commands[-3:] == [(0.0, 0.0)] * 3
    mirrored = heard(lines, "/rfhoming/cmd_vel")
    assert any(c["v"] > 0.1 for c in mirrored)
    assert publishers(lines, "/rfhoming/cmd_vel") == [{"type": "geometry_msgs/msg/Twist", **DEFAULT_QOS}]
    targets = heard(lines, "/rfhoming/target")
    assert targets and all(t["frame"] == "odom" and t["type"] == "geometry_msgs/msg/PointStamped" for t in targets)
    assert "arrived" in {e["data"] for e in heard(lines, "/rfhoming/events")}
    # the robot's odometry: one publisher (--ros2 does not publish a ros2: base's /odom again)
    assert publishers(lines, "/odom") == [{"type": "nav_msgs/msg/Odometry", **SENSOR_QOS}]
    topics = graph(lines)
    assert topics["/tf_static"] == ["tf2_msgs/msg/TFMessage"]
    assert topics["/rfhoming/aoa/angle"] == ["rfhoming_msgs/msg/AoaAngle"]


@pytest.mark.slow
def test_an_rclpy_node_hears_rfhomings_own_base_and_scan(tmp_path: Path, emulated, cli) -> None:
    """``--ros2`` with rfhoming's serial base: the base's odometry as /odom (odom -> base_link) and
    its range scans as /scan, clamped per REP 117 by rfhoming, as rclpy reads them."""
    domain = random_domain()
    with emulated("s0-house", link_dir=tmp_path) as emulator:
        with rclpy_node(tmp_path, domain, "--listen=/odom=nav_msgs/msg/Odometry",
                        "--listen=/scan=sensor_msgs/msg/LaserScan") as node:
            ready(node, domain)
            done = cli("listen", emulator.path("aoa"), f"base:{emulator.path('base')}", "--duration", "4",
                       "--ros2", f"domain={domain}")
            lines = ended(node)
    assert done.returncode == 0, done.stderr
    odom = heard(lines, "/odom")
    assert odom and all(o["frame"] == "odom" and o["child"] == "base_link" for o in odom)
    assert all(o["stamp"] > 1.7e9 for o in odom)  # the host's wall clock (docs/usage.md)
    scans = heard(lines, "/scan")
    assert scans and all(s["frame"] == "laser" for s in scans)
    for scan in scans:
        rep117(scan)
        assert scan["range_min"] > 0 and scan["in_range"] > 0  # a house: walls within reach
    assert graph(lines)["/tf_static"] == ["tf2_msgs/msg/TFMessage"]


@pytest.mark.slow
def test_rfhoming_homes_an_rclpy_robot_whose_pose_the_emulated_radios_follow(tmp_path: Path, emulated, cli) -> None:
    """An rclpy robot of its own kinematics (/odom from 0, 0, 0; its ground truth on
    /ground_truth/pose, spawned at 5, -3, 0.7 of its world) obeys /cmd_vel; ``emulate --pose-from``
    carries the emulated AoA board on it (the first pose is s0-open's start, 0, 0, 0) and ``run
    --base ros2:`` homes it to the tag: the emulator's truth, the robot's own final pose and the
    run's summary agree."""
    domain = random_domain()
    spawn = (5.0, -3.0, 0.7)
    truth = tmp_path / "truth.jsonl"
    with rclpy_node(tmp_path, domain, "--robot", ",".join(map(str, spawn))) as robot:
        ready(robot, domain)
        with emulated("s0-open", "--seed", "3", "--pose-from", f"ros2:/ground_truth/pose,domain={domain}",
                      "--truth", str(truth), link_dir=tmp_path, devices=1) as emulator:
            assert list(emulator.endpoints) == ["aoa"]  # the scenario's base is the ROS 2 robot's
            run = cli("run", "--aoa", emulator.path("aoa"), "--base", f"ros2:domain={domain}")
            lines = ended(robot)  # the emulator still follows it: its truth ends where the robot stopped
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["arrived"]
    state = next(line["robot"] for line in lines if "robot" in line)
    assert state["commands"] > 10
    # the robot's world -> the scenario's: its spawn is the scenario's start (0, 0, 0)
    dx, dy = state["world"][0] - spawn[0], state["world"][1] - spawn[1]
    c, s = math.cos(spawn[2]), math.sin(spawn[2])
    moved = (c * dx + s * dy, -s * dx + c * dy)
    last = json.loads(truth.read_text().splitlines()[-1])
    assert (last["robot"]["x"], last["robot"]["y"]) == pytest.approx(moved, abs=0.02)
    # what rfhoming read last on /odom, and where the robot stopped after it: within the stopping
    # distance the loop keeps to for a base without brakes ([loop] stop_within_m, docs/hardware.md)
    assert math.dist(summary["pose"][:2], state["odom"][:2]) <= 0.25
    target = last["targets"][0]
    assert math.dist(moved, (target["x"], target["y"])) < 1.0


@pytest.mark.slow
def test_an_rclpy_node_reads_locates_poses(tmp_path: Path, emulated, cli) -> None:
    """``locate --ros2``: each tag's fix as PoseWithCovarianceStamped and PointStamped in ``map``,
    inside the kit room, as rclpy reads them; the anchors on /tf_static."""
    link_dir = tmp_path / "links"
    link_dir.mkdir()
    site = tmp_path / "site.toml"
    site.write_text((ROOT / "docs" / "sites" / "kit-room.toml").read_text().replace("/tmp/rfhoming-kit", str(link_dir)))
    tags = ("CCF9578E0D8A", "CCF9578E0D8B", "CCF9578E0D8C")
    domain = random_domain()
    listen = [f"--listen=/rfhoming/tag_{t}/{what}=geometry_msgs/msg/{kind}" for t in tags
              for what, kind in (("pose", "PoseWithCovarianceStamped"), ("point", "PointStamped"))]
    with emulated("kit-room", "--seed", "1", link_dir=link_dir):
        with rclpy_node(tmp_path, domain, *listen) as node:
            ready(node, domain)
            done = cli("locate", str(site), "--duration", "5", "--ros2", f"domain={domain}")
            lines = ended(node)
    assert done.returncode == 0, done.stderr
    for tag in tags:
        poses, points = heard(lines, f"/rfhoming/tag_{tag}/pose"), heard(lines, f"/rfhoming/tag_{tag}/point")
        assert poses and points, tag
        assert publishers(lines, f"/rfhoming/tag_{tag}/pose") == [
            {"type": "geometry_msgs/msg/PoseWithCovarianceStamped", **DEFAULT_QOS}]
        assert all(p["frame"] == "map" for p in poses + points)
        last = poses[-1]
        assert 0 <= last["xyz"][0] <= 12 and 0 <= last["xyz"][1] <= 6, last
        assert last["orientation"] == [0.0, 0.0, 0.0, 1.0]
        cov = last["covariance"]
        held = tag != "CCF9578E0D8C"  # the site gives the cart's and the trolley's height: z is not estimated
        assert cov[0] > 0 and cov[7] > 0 and (cov[14] < 1e-12 if held else cov[14] > 1e-12), (tag, cov[:15])
        assert cov[21] == cov[28] == cov[35] == 1e6  # no orientation
        assert {tuple(p["xyz"]) for p in points} & {tuple(p["xyz"]) for p in poses}  # the same fixes, as points
    assert graph(lines)["/tf_static"] == ["tf2_msgs/msg/TFMessage"]
