"""``--ros2`` on listen, serve and locate: what each command senses arrives on ROS 2 and
decodes in a second reader written with plain cyclonedds and its own types
(tests/ros2_listener.py): raw readings as rfhoming_msgs/AoaAngle, the base's /odom and /tf,
/tf_static with the REP 105 frames, and locate's fixes as PoseWithCovarianceStamped and
PointStamped in ``map``. Each command runs in its own process on emulated devices."""

from __future__ import annotations

import json
import math
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rigs

pytest.importorskip("cyclonedds")

ROOT = Path(__file__).resolve().parent.parent
LISTENER = Path(__file__).with_name("ros2_listener.py")
RFHOMING = [sys.executable, "-m", "rfhoming"]


def random_domain() -> int:
    return random.SystemRandom().randint(192, 229)  # tests/test_ros2.py random_domain says why


def heard_while(domain: int, extra: list[str], command: list[str]) -> list[dict]:
    """Run ``command`` (an rfhoming command line) while the second reader listens on ``domain``
    for its usual topics and ``extra``; what it heard, one dict per sample."""
    with rigs.Child([sys.executable, str(LISTENER), str(domain), "120", *extra], stdin=True) as listener:
        assert json.loads(listener.line(60, "the listener's ready line")) == {"ready": domain}
        done = subprocess.run([*RFHOMING, *command], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        listener.proc.stdin.close()  # stdin closed: it reads what is on its way, then ends
        listener.wait(timeout=60)
        out = listener.stdout()
    return [json.loads(line) for line in out.splitlines()]


def emulate(scenario: str, link_dir: Path, endpoints: int) -> tuple[rigs.World, list[dict]]:
    emulator = rigs.emulate(scenario, "--seed", "1", link_dir=link_dir, devices=endpoints)
    return emulator, list(emulator.endpoints.values())


def stop(emulator: rigs.World) -> None:
    emulator.stop()


def check_angles(heard: list[dict], frame: str) -> None:
    angles = [h for h in heard if h["topic"] == "rfhoming/aoa/angle"]
    assert len(angles) > 20, {h["topic"] for h in heard}
    assert all(h["frame"] == frame and len(h["tag"]) == 12 and -90 <= h["board_azimuth"] <= 90 and 37 <= h["channel"] <= 39
               for h in angles)
    # REP 103 in the board's frame: the board's sign turned (a tag on its left is + here, - as printed)
    assert all(h["azimuth"] == pytest.approx(-math.radians(h["board_azimuth"]), abs=1e-6) for h in angles)


@pytest.mark.slow
def test_listen_and_serve_publish_the_readings_and_the_base(tmp_path: Path) -> None:
    emulator, endpoints = emulate("s0-open", tmp_path, 2)
    try:
        aoa, base = (next(e["path"] for e in endpoints if e["device"] == d) for d in ("aoa", "base"))
        domain = random_domain()
        listened = heard_while(domain, ["rfhoming/aoa/angle", "tf_static"],
                               ["listen", aoa, f"base:{base}", "--duration", "4", "--ros2", f"domain={domain}"])
        served = heard_while(domain, ["rfhoming/aoa/angle", "tf_static"],
                             ["serve", aoa, "--port", "0", "--duration", "4", "--ros2", f"domain={domain}"])
    finally:
        stop(emulator)
    # listen with a base: its odometry as /odom and /tf; every stamp the host's clock (s since 1970)
    check_angles(listened, "aoa_link")
    assert {"odom", "tf", "tf_static", "rfhoming/aoa/angle"} <= {h["topic"] for h in listened}
    assert all(h["frame"] == "odom" and h["child"] == "base_link" for h in listened if h["topic"] == "odom")
    static = next(h for h in listened if h["topic"] == "tf_static")
    assert ["base_link", "aoa_link"] in static["frames"] and ["base_link", "laser"] in static["frames"]
    assert all(h["stamp"] > 1.7e9 for h in listened if h["topic"] in ("rfhoming/aoa/angle", "odom"))
    # serve without a base: the angles on the host's clock too
    check_angles(served, "aoa_link")
    assert "odom" not in {h["topic"] for h in served}
    assert all(h["stamp"] > 1.7e9 for h in served if h["topic"] == "rfhoming/aoa/angle")


@pytest.mark.slow
def test_locate_publishes_each_tags_fix_in_map_and_the_anchors_in_tf_static(tmp_path: Path) -> None:
    link_dir = tmp_path / "links"
    link_dir.mkdir()
    site = tmp_path / "site.toml"
    site.write_text((ROOT / "docs" / "sites" / "kit-room.toml").read_text().replace("/tmp/rfhoming-kit", str(link_dir)))
    tags = ("CCF9578E0D8A", "CCF9578E0D8B", "CCF9578E0D8C")
    emulator, _ = emulate("kit-room", link_dir, 4)
    try:
        domain = random_domain()
        extra = ["rfhoming/aoa/angle", "tf_static", *(f"rfhoming/tag_{t}/{w}" for t in tags for w in ("pose", "point"))]
        heard = heard_while(domain, extra, ["locate", str(site), "--duration", "5", "--ros2", f"domain={domain}"])
    finally:
        stop(emulator)
    anchors = {"CCF9578E0A01": (0.0, 3.0, 2.2), "CCF9578E0A02": (12.0, 3.0, 2.2), "CCF9578E0A03": (6.0, 0.0, 2.2)}
    angles = [h for h in heard if h["topic"] == "rfhoming/aoa/angle"]
    assert {h["frame"] for h in angles} >= {f"anchor_{a}" for a in anchors}
    assert all(h["frame"] == f"anchor_{h['anchor']}" for h in angles)
    static = next(h for h in heard if h["topic"] == "tf_static")
    placed = dict(zip((child for _, child in static["frames"]), static["transforms"]))
    assert all(parent == "map" for parent, _ in static["frames"])
    for anchor, xyz in anchors.items():  # the site's surveyed positions; a unit quaternion
        assert placed[f"anchor_{anchor}"][:3] == list(xyz)
        assert math.isclose(sum(q * q for q in placed[f"anchor_{anchor}"][3:]), 1.0)
    for tag in tags:
        poses = [h for h in heard if h["topic"] == f"rfhoming/tag_{tag}/pose"]
        points = [h for h in heard if h["topic"] == f"rfhoming/tag_{tag}/point"]
        assert len(poses) > 10 and len(points) > 10, tag
        assert all(h["frame"] == "map" for h in poses + points)
        last = poses[-1]
        assert 0 <= last["xyz"][0] <= 12 and 0 <= last["xyz"][1] <= 6
        cov = last["covariance"]
        held = tag != "CCF9578E0D8C"  # the site gives the cart's and the trolley's height: z is not estimated
        assert cov[0] > 0 and cov[7] > 0 and (cov[14] < 1e-12 if held else cov[14] > 1e-12), (tag, cov[:15])
        assert cov[21] == cov[28] == cov[35] == 1e6  # no orientation
        assert last["orientation"] == [0.0, 0.0, 0.0, 1.0]


@pytest.mark.slow
def test_a_run_with_a_serial_base_publishes_no_cmd_vel_and_stamps_on_the_hosts_clock(tmp_path: Path) -> None:
    """``run --ros2`` with rfhoming's serial base: what the domain's discovery announces (DDS's
    DCPSPublication, read by the plain cyclonedds listener) holds no writer of rt/cmd_vel -- a
    ROS 2 base on the domain would drive on it -- but the mirror rt/rfhoming/cmd_vel; every
    stamp is the host's wall clock during the run, not the base's (1970)."""
    emulator, endpoints = emulate("s0-open", tmp_path, 2)
    try:
        aoa, base = (next(e["path"] for e in endpoints if e["device"] == d) for d in ("aoa", "base"))
        domain = random_domain()
        began = time.time()
        heard = heard_while(domain, ["publications", "rfhoming/aoa/angle"],
                            ["run", "--aoa", aoa, "--base", base, "--ros2", f"domain={domain}"])
        ended = time.time()
    finally:
        stop(emulator)
    published = {h["name"] for h in heard if h["topic"] == "DCPSPublication"}
    assert {"rt/rfhoming/cmd_vel", "rt/odom", "rt/tf", "rt/rfhoming/aoa/angle"} <= published, published
    assert "rt/cmd_vel" not in published
    assert not [h for h in heard if h["topic"] == "cmd_vel"]
    mirrored = [h for h in heard if h["topic"] == "rfhoming/cmd_vel"]
    assert any(h["v"] > 0.1 for h in mirrored)
    stamps = [h["stamp"] for h in heard if h["topic"] in ("odom", "rfhoming/aoa/angle")]
    stamps += [t for h in heard if h["topic"] == "tf" for t in h["stamps"]]
    assert len(stamps) > 100 and all(began <= t <= ended for t in stamps), (min(stamps), max(stamps), began, ended)
