"""MCAP logs as ROS 2's tools expect them, checked with readers rfhoming did not write: the mcap
library's linear ``NonSeekingReader`` (what reads a crashed file) sees messages in log-time
order and the chunk index's time ranges do not overlap; scans follow REP 117 with the
scanner's range_min, scan_time and time_increment; every channel carries
``offered_qos_profiles`` as ``ros2 bag record`` writes it, and ``rosbags-convert`` carries it into
a rosbag2 bag's metadata.yaml (transient local for /tf_static); an AoaAngle's azimuth, drawn as a
ray in its frame through /tf_static (the mount) and /tf (odometry), passes through the tag."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from ruamel.yaml import YAML
from scipy.spatial.transform import Rotation

from rfhoming.emulator.devices import BaseRunner
from rfhoming.emulator.radio import AoaModel, measure_azimuth
from rfhoming.host.drivers import robot_base
from rfhoming.host.export import rosmsgs
from rfhoming.host.export.recorder import FLUSH_S, REORDER_S, McapRecorder
from rfhoming.host.homing.config import Mounting
from rfhoming.protocol.frames.records import Odometry, RangeScanV2
from rfhoming.protocol.uconnect.items import AngleEvent

QOS_KEYS = ["history", "depth", "reliability", "durability", "deadline", "lifespan", "liveliness",
            "liveliness_lease_duration", "avoid_ros_namespace_conventions"]  # rosbag2_storage qos.cpp, in order


def linear_log_times(path: Path) -> list[tuple[str, int, int]]:
    """(topic, log time, publish time) of every message, in file order, by the streaming reader."""
    with path.open("rb") as f:
        return [(channel.topic, m.log_time, m.publish_time)
                for _, channel, m in NonSeekingReader(f).iter_messages(log_time_order=False)]


def chunk_ranges(path: Path) -> list[tuple[int, int]]:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return [(c.message_start_time, c.message_end_time)
            for c in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)]


def assert_ordered(path: Path) -> None:
    times = [t for _, t, _ in linear_log_times(path)]
    assert times == sorted(times), next(i for i in range(1, len(times)) if times[i] < times[i - 1])
    chunks = chunk_ranges(path)
    assert len(chunks) > 3
    assert all(end <= start for (_, end), (start, _) in zip(chunks, chunks[1:])), chunks


def test_records_made_after_later_messages_are_written_in_log_time_order(tmp_path: Path) -> None:
    """The run log's records arrive up to 0.2 s after messages stamped later (the loop decides
    on odometry already written); one 2 s late (a stall) goes out with its log time raised."""
    path = tmp_path / "run.mcap"
    recorder = McapRecorder(path, clock="host")
    for i in range(200):  # 10 s of message time: ten chunks
        recorder.on_runlog({"kind": "event", "t": i * 0.05, "what": f"e{i}"})
        if i % 3 == 2:
            recorder.on_runlog({"kind": "command", "t": i * 0.05 - 0.2, "v": 0.1, "w": 0.0})
        if i == 150:
            recorder.on_runlog({"kind": "event", "t": i * 0.05 - 2.0, "what": "stalled"})
    recorder.close()
    assert_ordered(path)
    written = linear_log_times(path)
    assert recorder.summary()["late"] == 1 and len(written) == 200 + 66 + 1 + 1  # + /tf_static
    raised = [(log, publish) for _, log, publish in written if log != publish]
    assert len(raised) == 1 and raised[0][0] - raised[0][1] >= 1e9  # raised by 1.5 s; its own time kept
    assert FLUSH_S + REORDER_S <= 1.5  # docs/usage.md promises a crash loses at most 1.5 s


def scan_record(ranges_mm: list[int]) -> RangeScanV2:
    return RangeScanV2(1, 1, 0, round(-math.pi / 2 * 1e6), round(math.pi / 2 * 1e6), 8000, tuple(ranges_mm))


def test_scans_keep_rep117_with_the_scanners_facts(tmp_path: Path) -> None:
    """A range the record holds beyond range_max (the emulator's noise on an 8 m beam) is +inf;
    range_min is the records' 1 mm, scan_time the emulated scanner's period, every beam at once."""
    path = tmp_path / "scan.mcap"
    recorder = McapRecorder(path, clock="host")
    recorder.on_item("base", 1.0, scan_record([8001, 0, 7999, 1, 8002, 2500]))
    recorder.close()
    with AnyReader([path]) as reader:
        (scan,) = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == "/scan"]
    assert list(scan.ranges) == pytest.approx([math.inf, math.inf, 7.999, 0.001, math.inf, 2.5])
    assert (scan.range_min, scan.range_max) == (pytest.approx(0.001), 8.0)
    assert scan.scan_time == pytest.approx(BaseRunner.SCAN_PERIOD_S) and scan.time_increment == 0.0
    assert robot_base.SCAN_PERIOD_S == BaseRunner.SCAN_PERIOD_S  # the emulated scanner's, one number
    assert all(scan.range_min <= r <= scan.range_max for r in scan.ranges if math.isfinite(r))


def test_rep117_below_range_min_is_minus_infinity() -> None:
    assert rosmsgs.rep117(0.05, 0.1, 8.0) == -math.inf and rosmsgs.rep117(None, 0.1, 8.0) == math.inf
    assert rosmsgs.rep117(8.0, 0.1, 8.0) == 8.0 and rosmsgs.rep117(0.1, 0.1, 8.0) == 0.1


def small_recording(path: Path) -> None:
    recorder = McapRecorder(path, clock="host")
    recorder.on_item("base", 1.0, Odometry(1, 1, 0, 500, 0, 0, 0, 0, 0))
    recorder.on_item("base", 1.1, scan_record([1000] * 5))
    recorder.on_runlog({"kind": "command", "t": 1.2, "v": 0.2, "w": 0.1})
    recorder.close()


def test_channels_offer_qos_as_ros2_bag_record_writes_it(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    small_recording(path)
    with path.open("rb") as f:
        channels = {c.topic: c.metadata for c in make_reader(f).get_summary().channels.values()}
    assert {"/tf_static", "/tf", "/odom", "/scan", "/rfhoming/cmd_vel"} <= set(channels)
    for topic, metadata in channels.items():
        (profile,) = YAML(typ="safe").load(metadata["offered_qos_profiles"])
        assert list(profile) == QOS_KEYS, topic
        # metadata version 8 (an MCAP without rosbag2's metadata record): rmw's enum numbers
        assert (profile["reliability"], profile["durability"]) == (1, 1 if topic == "/tf_static" else 2), topic
        assert profile["deadline"] == {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE
    with AnyReader([path]) as reader:  # rosbags parses them as QoS
        durability = {c.topic: [q.durability.name for q in c.ext.offered_qos_profiles] for c in reader.connections}
    assert durability["/tf_static"] == ["TRANSIENT_LOCAL"] and durability["/odom"] == ["VOLATILE"]


def test_the_qos_profiles_survive_rosbags_convert_into_a_rosbag2_bag(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    small_recording(path)
    bag = tmp_path / "bag"
    done = subprocess.run([Path(sys.executable).with_name("rosbags-convert"), "--src", str(path), "--dst", str(bag)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    metadata = YAML(typ="safe").load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["storage_identifier"] == "sqlite3"
    offered = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
               for t in metadata["topics_with_message_count"]}
    assert [p["durability"] for p in offered["/tf_static"]] == ["transient_local"]
    assert [p["reliability"] for p in offered["/tf_static"]] == ["reliable"]
    assert all([p["durability"] for p in profiles] == ["volatile"] for topic, profiles in offered.items()
               if topic != "/tf_static")
    with Rosbag2Reader(bag) as reader:  # and rosbags reads the bag's QoS back
        latched = {c.topic for c in reader.connections
                   if [q.durability.name for q in c.ext.offered_qos_profiles] == ["TRANSIENT_LOCAL"]}
    assert latched == {"/tf_static"}


def quaternion(q) -> Rotation:  # noqa: ANN001
    return Rotation.from_quat([q.x, q.y, q.z, q.w])


@pytest.mark.parametrize(("yaw_deg", "upside_down", "sign"), [(0.0, False, -1), (35.0, False, -1), (-60.0, True, -1),
                                                              (20.0, False, 1)])
def test_an_aoa_bearing_drawn_through_tf_hits_the_tag(tmp_path: Path, yaw_deg: float, upside_down: bool,
                                                      sign: int) -> None:
    """The emulator's board (emulator/radio.py ``measure_azimuth``, no noise) reports a tag; the
    message's azimuth, drawn from aoa_link through the mount (/tf_static) and the robot's pose
    (/tf), passes through the tag. ``sign`` +1: a board that reports counter-clockwise
    (``[mounting] azimuth_sign``)."""
    mounting = Mounting(yaw_offset_deg=yaw_deg, upside_down=upside_down, azimuth_sign=sign, aoa_xyz_m=(0.2, -0.1, 0.3))
    robot = (1.0, 2.0, math.radians(30))
    heading = robot[2] + math.radians(yaw_deg)  # the board's boresight in odom
    board = Rotation.from_euler("ZYX", [heading, 0, math.pi if upside_down else 0])
    mount = np.array([robot[0], robot[1], 0.0]) + Rotation.from_euler("Z", robot[2]).apply(mounting.aoa_xyz_m)
    tags = [(mount[0] + d * math.cos(heading + math.radians(a)), mount[1] + d * math.sin(heading + math.radians(a)))
            for a, d in ((-70, 3.0), (-30, 2.0), (10, 4.0), (50, 2.5), (80, 3.0))]  # in front of the board
    path = tmp_path / "aoa.mcap"
    recorder = McapRecorder(path, mounting=mounting)
    recorder.on_item("base", 1.0, Odometry(1, 1, 1_000_000, round(robot[0] * 1000), round(robot[1] * 1000),
                                           round(robot[2] * 1e6), 0, 0, 0))
    for tag in tags:
        seen = board.inv().apply(np.array([*tag, mount[2]]) - mount)  # the tag in the board's frame
        ccw = math.degrees(math.atan2(seen[1], seen[0]))
        reported = measure_azimuth(AoaModel("uniform", 0.0), ccw, np.random.default_rng(1))  # the board's sign
        recorder.on_item("aoa", 1.0, AngleEvent("CCF9578E0D8A", -50, round(-sign * reported), 0, 0, 37,
                                                "CCF9578E0D89", "", 0))
    recorder.close()
    with AnyReader([path]) as reader:
        read = [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]
    tf = {(t.header.frame_id, t.child_frame_id): t.transform for topic, m in read if topic in ("/tf", "/tf_static")
          for t in m.transforms}
    angles = [m for topic, m in read if topic == "/rfhoming/aoa/angle"]
    assert len(angles) == len(tags) and {a.header.frame_id for a in angles} == {"aoa_link"}
    odom_base, base_aoa = tf[("odom", "base_link")], tf[("base_link", "aoa_link")]
    rotation = quaternion(odom_base.rotation) * quaternion(base_aoa.rotation)
    origin = quaternion(odom_base.rotation).apply([base_aoa.translation.x, base_aoa.translation.y,
                                                   base_aoa.translation.z])
    origin += [odom_base.translation.x, odom_base.translation.y, odom_base.translation.z]
    for angle, tag in zip(angles, tags):
        ray = rotation.apply([math.cos(angle.azimuth_rad), math.sin(angle.azimuth_rad), 0.0])
        to_tag = np.array([*tag, origin[2]]) - origin
        miss = np.linalg.norm(np.cross(ray, to_tag))  # distance of the tag from the ray's line
        assert np.dot(ray, to_tag) > 0 and miss < 0.02 * np.linalg.norm(to_tag), (tag, angle.azimuth_rad)


@pytest.mark.slow
def test_an_emulated_house_run_reads_in_order_with_scans_in_range(tmp_path: Path) -> None:
    """What an s0-house recording showed before the fix: chunks overlapping in time, /tf out of order for the
    linear reader, scans at 8.001 m above range_max 8.0."""
    path = tmp_path / "house.mcap"
    done = subprocess.run([sys.executable, "-m", "rfhoming", "demo", "--scenario", "s0-house", "--in-process", "--out",
                           str(tmp_path), "--mcap", str(path), "--json"], capture_output=True, text=True, timeout=600)
    assert done.returncode in (0, 1), done.stderr  # 1: did not arrive; the recording is what is checked
    assert json.loads(done.stdout)
    assert_ordered(path)
    with AnyReader([path]) as reader:
        scans = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == "/scan"]
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert len(scans) > 20  # the whole run: one scan every 0.1 s of it
    for scan in scans:
        assert all(scan.range_min <= r <= scan.range_max for r in scan.ranges if math.isfinite(r))
        assert scan.range_min > 0 and scan.scan_time > 0
    assert all(len(profiles) == 1 for profiles in qos.values()), qos
