"""MCAP logs of ROS 2 messages: an emulated homing run recorded with ``demo --mcap`` and
exported afterwards reads back with rosbags (a reader independent of the mcap writer) to the
run log's odometry, commands, estimates and bearings."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rosbags.highlevel import AnyReader
from rosbags.typesys import get_types_from_msg

from rfhoming.host.export import rosmsgs


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rfhoming", *args], capture_output=True, text=True, timeout=180)


def read_back(path: Path) -> dict[str, list[tuple[int, object]]]:
    """topic -> [(log time ns, message)], decoded by rosbags from the file's own definitions."""
    out: dict[str, list] = defaultdict(list)
    with AnyReader([path]) as reader:
        for connection, t, raw in reader.messages():
            out[connection.topic].append((t, reader.deserialize(raw, connection.msgtype)))
    return out


def seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec / 1e9


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("mcap-demo")
    done = cli("demo", "--out", str(out), "--mcap", str(out / "live.mcap"), "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    records = [json.loads(line) for line in (out / "run.jsonl").read_text().splitlines()]
    return {"out": out, "summary": summary, "runlog": records, "live": read_back(out / "live.mcap")}


def test_live_recording_holds_the_run_logs_commands(demo_run) -> None:
    commands = [r for r in demo_run["runlog"] if r["kind"] == "command"]
    got = demo_run["live"]["/rfhoming/cmd_vel"]
    assert len(commands) > 20 and len(got) == len(commands)
    for record, (t, msg) in zip(commands, got):
        assert t == round(record["t"] * 1e9)
        assert (msg.linear.x, msg.angular.z) == (record["v"], record["w"])


def test_live_recording_holds_the_odometry_the_loop_decided_on(demo_run) -> None:
    odom = {round(seconds(m.header.stamp), 4): m for _, m in demo_run["live"]["/odom"]}
    estimates = [r for r in demo_run["runlog"] if r["kind"] == "estimate"]
    assert len(estimates) > 20 and len(odom) > len(estimates)  # every odometry record, not just the decisions
    for record in estimates:
        msg = odom[record["t"]]
        x, y, theta = record["pose"]
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        assert (p.x, p.y) == pytest.approx((x, y), abs=1e-4)
        assert 2 * math.atan2(q.z, q.w) == pytest.approx(theta, abs=1e-4)
        assert (msg.header.frame_id, msg.child_frame_id) == ("odom", "base_link")


def test_live_recording_holds_the_estimates_and_bearings(demo_run) -> None:
    goals = [r for r in demo_run["runlog"] if r["kind"] == "estimate" and r.get("goal")]
    targets = demo_run["live"]["/rfhoming/target"]
    assert len(goals) > 10 and len(targets) == len(goals)
    for record, (_, msg) in zip(goals, targets):
        assert seconds(msg.header.stamp) == pytest.approx(record["t"], abs=1e-9)
        assert (msg.point.x, msg.point.y) == tuple(record["goal"])
    measurements = [r for r in demo_run["runlog"] if r["kind"] == "measurement"]
    bearings = demo_run["live"]["/rfhoming/bearing"]
    assert len(bearings) == len(measurements) > 50
    for record, (_, msg) in zip(measurements, bearings):
        assert (msg.source, msg.bearing_rad, msg.range_m, msg.board_azimuth_deg) == (
            "aoa", record["theta_s"], record["distance"], record["azimuth"])
    # every reading the loop used is one of the board's angle events, as the board gave it
    angles = Counter((m.board_azimuth_deg, m.rssi1_dbm) for _, m in demo_run["live"]["/rfhoming/aoa/angle"])
    used = Counter((r["azimuth"], r["rssi"]) for r in measurements)
    assert not used - angles


def test_export_of_run_log_and_capture_equals_the_live_recording(demo_run, tmp_path) -> None:
    out = demo_run["out"]
    done = cli("export", str(out / "run.jsonl"), "--capture", str(out / "capture.pcapng"), "-o", str(tmp_path / "x.mcap"))
    assert done.returncode == 0, done.stderr
    counts = json.loads(done.stdout)["topics"]
    exported = read_back(tmp_path / "x.mcap")
    for topic in ("/rfhoming/cmd_vel", "/rfhoming/target", "/rfhoming/bearing"):  # from the run log: all of it
        assert counts[topic] == len(exported[topic]) == len(demo_run["live"][topic]), topic
        assert [repr(m) for _, m in exported[topic]] == [repr(m) for _, m in demo_run["live"][topic]], topic
    end = round(demo_run["runlog"][-1]["t"] * 1e9)
    for topic in ("/odom", "/rfhoming/aoa/angle"):  # from the capture, which also holds the bytes read
        live = demo_run["live"][topic]            # while the drivers were being stopped, after the run
        assert counts[topic] == len(exported[topic]) >= len(live), topic
        assert [repr(m) for _, m in exported[topic][:len(live)]] == [repr(m) for _, m in live], topic
        assert all(t >= end for t, _ in exported[topic][len(live):]), topic


def test_export_of_a_capture_alone_takes_commands_from_the_bytes_sent(demo_run, tmp_path) -> None:
    out = demo_run["out"]
    done = cli("export", str(out / "capture.pcapng"), "-o", str(tmp_path / "c.mcap"))
    assert done.returncode == 0, done.stderr
    exported = read_back(tmp_path / "c.mcap")
    commands = [r for r in demo_run["runlog"] if r["kind"] == "command"]
    sent = [(m.linear.x, m.angular.z) for _, m in exported["/rfhoming/cmd_vel"]]
    logged = [(r["v"], r["w"]) for r in commands]

    def same(k: int) -> bool:  # millimetre and mrad on the wire
        return len(sent) - k >= len(logged) and all(
            abs(a - c) <= 1e-3 and abs(b - d) <= 1e-3 for (a, b), (c, d) in zip(sent[k:], logged))

    # the capture also holds the stop sent before the loop (written if odometry had come by
    # then) and the stops sent as the run closed
    assert same(0) or same(1)
    assert len([v for v, _ in logged if v > 0.1]) > 20  # a comparison that can fail
    assert "/rfhoming/target" not in exported
    assert len(exported["/odom"]) >= len(demo_run["live"]["/odom"])


def test_export_says_what_is_wrong(tmp_path) -> None:
    bad = tmp_path / "notes.txt"
    bad.write_text("hello\n")
    done = cli("export", str(bad), "-o", str(tmp_path / "x.mcap"))
    assert done.returncode == 2
    assert "not a run log line" in done.stderr and "\n" == done.stderr[-1] and done.stderr.count("\n") == 1


def test_shipped_msg_files_parse_and_are_all_built() -> None:
    cmake = (rosmsgs.MSG_DIR.parent / "CMakeLists.txt").read_text()
    for name in rosmsgs.OWN_TYPES:
        text = (rosmsgs.MSG_DIR / f"{name}.msg").read_text()
        types = get_types_from_msg(text, f"rfhoming_msgs/msg/{name}")
        assert f"rfhoming_msgs/msg/{name}" in types
        assert f'"msg/{name}.msg"' in cmake
    assert sorted(p.stem for p in rosmsgs.MSG_DIR.glob("*.msg")) == sorted(rosmsgs.OWN_TYPES)
    assert re.search(r"<name>rfhoming_msgs</name>", (rosmsgs.MSG_DIR.parent / "package.xml").read_text())


@given(st.floats(min_value=0, max_value=4e9, allow_nan=False))
def test_stamps_keep_time_to_the_nanosecond(t: float) -> None:
    s = rosmsgs.stamp(t)
    assert 0 <= s["nanosec"] < 1_000_000_000
    assert s["sec"] * 1_000_000_000 + s["nanosec"] == round(t * 1e9)


@given(st.floats(min_value=-math.pi, max_value=math.pi, allow_nan=False))
def test_yaw_quaternion_round_trips(theta: float) -> None:
    q = rosmsgs.yaw_quaternion(theta)
    assert math.hypot(q["z"], q["w"]) == pytest.approx(1.0)
    assert 2 * math.atan2(q["z"], q["w"]) == pytest.approx(theta, abs=1e-12)


def test_an_item_that_cannot_be_written_is_counted_not_raised(tmp_path) -> None:
    from rfhoming.host.export.recorder import McapRecorder
    from rfhoming.protocol.frames import Odometry
    from rfhoming.protocol.uconnect.items import AngleEvent

    recorder = McapRecorder(tmp_path / "x.mcap")
    recorder.on_item("base", 0.0, Odometry(0, 0, 1_000_000, 0, 0, 0, 0, 0, 0))
    bad = AngleEvent("CCF9578E0D8A", -60, 40_000, 0, -60, 37, "CCF9578E0D89", "", 1)  # azimuth beyond int16
    recorder.on_item("aoa", 0.0, bad)
    recorder.on_runlog({"kind": "command", "t": 1.0, "v": "fast", "w": 0.0})
    recorder.close()
    assert recorder.skipped == {"unwritable angle": 1, "unwritable command": 1}
    assert recorder.counts == {"/tf_static": 1, "/odom": 1, "/tf": 1}
