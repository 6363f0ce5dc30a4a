"""The ROS 2 base (``--base ros2:``): rfhoming's own CDR codec checked against Cyclone DDS's
serializer (a program rfhoming did not write), and the driver over a real DDS domain on
loopback -- a cyclonedds "robot" publishes /odom and /scan and reads /cmd_vel."""

from __future__ import annotations

import asyncio
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("cyclonedds")

from rfhoming.host import dds as dds_io  # noqa: E402
from rfhoming.protocol import ros2dds as dds  # noqa: E402
from rfhoming.host.drivers.robot_base import Pose2D, Scan  # noqa: E402
from rfhoming.host.drivers.ros2_base import Ros2BaseDriver, Topics  # noqa: E402
from rfhoming.host.portspec import PortSpecError, parse  # noqa: E402
from rfhoming.host.supervise import DeviceNotReady, supervise  # noqa: E402
from rfhoming.protocol import ros2  # noqa: E402

finite = st.floats(-1e6, 1e6, allow_nan=False)
f32 = st.floats(-1e6, 1e6, allow_nan=False, width=32)
name = st.text(st.characters(min_codepoint=32, max_codepoint=0x2FF), max_size=20)
stamp = st.builds(ros2.Stamp, st.integers(-2**31, 2**31 - 1), st.integers(0, 999_999_999))


def random_domain() -> int:
    """1-60 here; tests/test_rclpy.py draws from 61-76, tests/test_fastdds.py from 77-153,
    tests/test_ros2_emulated.py from 154-191 and tests/test_ros2_live.py from 192-229, so files
    running side by side (pytest-xdist) never share a domain."""
    return random.SystemRandom().randint(1, 60)


@given(stamp, name, name, finite, finite, st.floats(-3.1, 3.1), finite, finite)
@settings(max_examples=60, deadline=None)
def test_odometry_cdr_is_cyclones(stamp: ros2.Stamp, frame: str, child: str, x: float, y: float, yaw: float,
                                  v: float, w: float) -> None:
    msg = dds.Odometry(dds.Header(dds.Time(*stamp), frame), child)
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = v, w
    theirs = msg.serialize()
    ours = ros2.encode_odometry(ros2.Odometry(stamp, frame, child, x, y, yaw, v, w))
    assert ours == theirs
    got = ros2.decode_odometry(theirs)
    assert (got.stamp, got.frame_id, got.child_frame_id, got.x, got.y, got.v, got.w) == (stamp, frame, child, x, y, v, w)
    assert got.yaw == pytest.approx(yaw, abs=1e-9)


@given(stamp, name, st.lists(f32, max_size=50), st.lists(f32, max_size=5), st.lists(f32, min_size=7, max_size=7))
@settings(max_examples=60, deadline=None)
def test_laser_scan_cdr_is_cyclones(stamp: ros2.Stamp, frame: str, ranges: list[float], intensities: list[float],
                                    fields: list[float]) -> None:
    theirs = dds.LaserScan(dds.Header(dds.Time(*stamp), frame), *fields, ranges, intensities).serialize()
    scan = ros2.LaserScan(stamp, frame, *fields, tuple(ranges), tuple(intensities))
    assert ros2.encode_scan(scan) == theirs
    assert ros2.decode_scan(theirs) == scan


@given(finite, finite, st.none() | stamp, name)
@settings(max_examples=60, deadline=None)
def test_twist_and_twist_stamped_cdr_are_cyclones(v: float, w: float, stamp: ros2.Stamp | None, frame: str) -> None:
    twist = dds.Twist(dds.Vector3(v, 0, 0), dds.Vector3(0, 0, w))
    ours = ros2.encode_twist(ros2.Twist(v, w, stamp, frame if stamp else ""))
    if stamp is None:
        assert ours == twist.serialize()
        assert dds.Twist.deserialize(ours) == twist
    else:
        assert ours == dds.TwistStamped(dds.Header(dds.Time(*stamp), frame), twist).serialize()
        assert ros2.decode_twist(ours, stamped=True) == ros2.Twist(v, w, stamp, frame)


def test_dds_names_follow_ros2s_mapping() -> None:
    assert ros2.dds_topic("/robot1/cmd_vel") == "rt/robot1/cmd_vel"
    assert ros2.dds_type(ros2.ODOMETRY) == "nav_msgs::msg::dds_::Odometry_" == dds.Odometry.__idl_typename__
    assert dds.LaserScan.__idl_typename__ == "sensor_msgs::msg::dds_::LaserScan_"
    assert ros2.topic_name("robot1", "odom") == "/robot1/odom" and ros2.topic_name("/", "odom") == "/odom"
    assert ros2.topic_name("robot1", "/scan") == "/scan"


@given(st.binary(max_size=200))
def test_garbage_records_are_counted_drops(data: bytes) -> None:
    decoder = ros2.SampleDecoder()
    out = decoder.feed(data)
    assert len(out) <= 1 and decoder.counters["drops"] + decoder.counters["samples"] + decoder.counters[
        "other_types"] == 1


@pytest.mark.parametrize(("spec", "topics"), [
    ("ros2:", dict(domain=0, ns="", stamped=False, discovery="localhost")),
    ("ros2:domain=7,stamped=1", dict(domain=7, ns="", stamped=True)),
    ("ros2:/robot1,domain=3,cmd_vel=cmd_vel_unstamped", dict(domain=3, ns="robot1", cmd_vel="cmd_vel_unstamped")),
    ("ros2:ns=tb4,discovery=subnet", dict(ns="tb4", discovery="subnet")),
])
def test_ros2_port_specs(spec: str, topics: dict[str, object]) -> None:
    from rfhoming.host.drivers.ros2_base import topics_of

    got = topics_of(parse(spec))
    assert {k: getattr(got, k) for k in topics} == topics


@pytest.mark.parametrize("spec", ["ros2:domain=999", "ros2:discovery=everywhere", "ros2:odom=a b", "ros2:baud=9600"])
def test_bad_ros2_specs_are_one_line_errors(spec: str) -> None:
    with pytest.raises(PortSpecError) as err:
        parse(spec)
    assert "\n" not in str(err.value)


class Robot:
    """A ROS 2 robot played with plain cyclonedds: /odom and /scan out, /cmd_vel in."""

    def __init__(self, domain: int, ns: str = "", stamped: bool = False) -> None:
        dp = dds_io.participant(domain)
        self.odom = dds_io.writer(dp, ros2.topic_name(ns, "odom"), ros2.ODOMETRY, dds.DEFAULT_QOS)
        self.scan = dds_io.writer(dp, ros2.topic_name(ns, "scan"), ros2.LASER_SCAN, dds.SENSOR_QOS)
        self.commands: list[object] = []
        kind = ros2.TWIST_STAMPED if stamped else ros2.TWIST
        self.reader = dds_io.reader(dp, ros2.topic_name(ns, "cmd_vel"), kind, self.commands.append, dds.DEFAULT_QOS)

    def publish(self, t: float, x: float) -> None:
        msg = dds.Odometry(dds.Header(dds.Time(*ros2.Stamp.of(t)), "odom"), "base_link")
        msg.pose.pose.position.x = x
        self.odom.write(msg)
        self.scan.write(dds.LaserScan(dds.Header(dds.Time(*ros2.Stamp.of(t)), "laser"), -1.0, 1.0, 1.0, 0, 0.1,
                                      0.1, 8.0, [2.0, float("inf"), 0.05], []))


async def until(test, what: str, seconds: float = 60.0) -> None:
    async with asyncio.timeout(seconds):  # hang guard only
        while not test():
            await asyncio.sleep(0.02)


class Wire:
    """A port that keeps what the driver writes (sans-IO)."""

    name, taps, description = "wire", [], {"stamped": "1"}

    def __init__(self) -> None:
        self.counters = {"opens": 1}
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.written.append(data)


async def test_a_twist_stamped_carries_the_odometry_the_loop_acts_on_not_the_newest_read() -> None:
    """The driver may read odometry the loop has not taken yet (live, as the load has it; a
    replay, as the recording's order has it): the stamp is the loop's odometry's, exactly as its
    sample carried it (before, the newest read's: a replay under load wrote other bytes)."""
    wire = Wire()
    driver = Ros2BaseDriver(wire)
    stamps = [ros2.Stamp(1796455203, 726_982_001), ros2.Stamp(1796455203, 746_982_001)]
    for k, at in enumerate(stamps):
        odometry = ros2.Odometry(at, "odom", "base_link", 0.1 * k, 0.0, 0.0, 0.0, 0.0)
        driver.on_chunk(ros2.encode_record("/odom", ros2.ODOMETRY, ros2.encode_odometry(odometry)), float(k))
    first = driver.out.get_nowait()
    assert isinstance(first, Pose2D) and driver.latest is not None and driver.latest.t_robot > first.t_robot
    driver.acting_on(first)
    assert driver.send_velocity(0.25, 0.0)
    twist = ros2.decode_twist(ros2.decode_record(wire.written[-1]).data, stamped=True)
    assert twist.stamp == stamps[0] and (twist.v, twist.frame_id) == (0.25, "base_link")


@pytest.mark.parametrize("stamped", [False, True])
async def test_the_driver_drives_a_ros2_robot(stamped: bool) -> None:
    domain = random_domain()
    robot = Robot(domain, "r1", stamped)
    driver = Ros2BaseDriver.from_spec(parse(f"ros2:/r1,domain={domain},stamped={int(stamped)}"), [])
    task = asyncio.create_task(driver.run())
    try:
        t = 0.0

        async def feed() -> None:
            nonlocal t
            while True:
                t += 0.02
                robot.publish(t, 0.5)
                await asyncio.sleep(0.02)

        feeder = asyncio.create_task(feed())
        items: list[object] = []

        def got() -> bool:
            while (item := driver.out.get_nowait()) is not None:
                items.append(item)
            return any(isinstance(i, Pose2D) for i in items) and any(isinstance(i, Scan) for i in items)

        await until(got, "odometry and a scan")
        pose = next(i for i in items if isinstance(i, Pose2D))
        scan = next(i for i in items if isinstance(i, Scan))
        assert pose.x == 0.5 and pose.t_robot > 0
        assert scan.ranges == (2.0, None, None) and scan.angle_min == -1.0 and scan.range_max == 8.0
        assert driver.problem is None
        driver.send_velocity(0.25, -0.5)
        driver.stop()
        await until(lambda: len(robot.commands) >= 1 + 3, "the commands")
        twists = [c.twist if stamped else c for c in robot.commands]
        assert (twists[0].linear.x, twists[0].angular.z) == (0.25, -0.5)
        assert all((c.linear.x, c.angular.z) == (0, 0) for c in twists[1:4])
        if stamped:
            assert robot.commands[0].header.frame_id == "base_link" and robot.commands[0].header.stamp.sec >= 0
        feeder.cancel()
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


async def test_a_silent_ros2_base_is_a_one_line_error_at_its_deadline() -> None:
    domain = random_domain()
    driver = Ros2BaseDriver.from_spec(parse(f"ros2:domain={domain}"), [])
    task = asyncio.create_task(driver.run())
    try:
        with pytest.raises(DeviceNotReady) as err:
            await supervise({driver: 0.5})
        message = str(err.value)
        assert "\n" not in message and "/odom" in message and f"domain {domain}" in message
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


def test_loopback_only_by_default() -> None:
    xml = dds.config(5)
    assert xml is not None and '<NetworkInterface address="127.0.0.1"/>' in xml
    assert "<AllowMulticast>false</AllowMulticast>" in xml and '<Peer address="127.0.0.1"/>' in xml
    assert dds.config(5, "subnet") is None
    assert Topics().discovery == "localhost"


def test_without_cyclonedds_a_ros2_base_is_a_one_line_error(monkeypatch) -> None:
    import sys

    from rfhoming.host.ports import PortError

    monkeypatch.setitem(sys.modules, "rfhoming.host.ros2dds", None)  # import fails as without the wheel
    with pytest.raises(PortError, match=r"rfhoming\[ros2\]"):
        Ros2BaseDriver.from_spec(parse("ros2:domain=3"), [])


def test_live_ros2_messages_are_the_mcap_recordings_cdr() -> None:
    """--ros2 publishes what the MCAP recording holds: the same message serialized by
    cyclonedds (from types made of the definitions) and by mcap-ros2-support is the same bytes."""
    from mcap_ros2._dynamic import serialize_dynamic

    from rfhoming.host.export import frames, ros2live, rosmsgs

    messages = [rosmsgs.point("/rfhoming/target", 12.25, [1.0, -2.0]), rosmsgs.text("/rfhoming/events", "arrived"),
                rosmsgs.twist(0.3, -0.2), rosmsgs.odometry(3.5, 1.0, 2.0, 0.5, 0.2, 0.1, 4.0),
                rosmsgs.transforms("/tf_static", 1.0, frames.sensor_mounts(None)),
                rosmsgs.bearing(2.0, {"bearing_deg": 10.0, "range_m": 2.5, "rssi_dbm": -60.0})]
    for _topic, typename, message in messages:
        mcap = serialize_dynamic(typename, rosmsgs.msgdef(typename))[typename](message)
        assert ros2live.sample(typename, message).serialize() == mcap, typename


@pytest.mark.parametrize("stamped", [False, True])
async def test_the_emulated_robot_takes_the_command_type_it_is_told(stamped: bool) -> None:
    """``emulate --robot ros2:stamped=1`` reads TwistStamped on cmd_vel (Jazzy-era Nav2), else
    Twist; the host's base with the same stamped= drives it, odometry first as a robot's."""
    from rfhoming.emulator.ros2robot import Ros2Link
    from rfhoming.protocol.frames import FrameDecoder, Odometry, VelocityCommand, encode_frame

    domain = random_domain()
    link = Ros2Link(domain, stamped=stamped)
    received: list[object] = []
    decoder = FrameDecoder()
    link.on_receive = lambda data: received.extend(decoder.feed(data))
    await link.start()
    driver = Ros2BaseDriver.from_spec(parse(f"ros2:domain={domain},stamped={int(stamped)}"), [])
    task = asyncio.create_task(driver.run())
    try:
        t_us = 0

        async def odometry() -> None:
            nonlocal t_us
            while True:
                t_us += 20_000
                link.send(encode_frame(Odometry(0, t_us // 20_000, t_us, 1500, -250, 100_000, 300, 0, 0)))
                await asyncio.sleep(0.02)

        feeder = asyncio.create_task(odometry())
        await until(lambda: driver.latest is not None, "odometry at the host")
        async with asyncio.timeout(60):  # hang guard only: commands until the robot has one
            while not any(isinstance(r, VelocityCommand) for r in received):
                driver.send_velocity(0.25, -0.5)
                await asyncio.sleep(0.05)
        feeder.cancel()
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await link.close()
    command = next(r for r in received if isinstance(r, VelocityCommand))
    assert (command.v_mm_s, command.w_mrad_s) == (250, -500) and link.counters["commands"] >= 1


def pose_sample(ros_type: str, x: float, y: float, yaw: float) -> object:
    pose = dds.Pose(dds.Point(x, y, 0.0), dds.Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
    if ros_type == ros2.POSE_STAMPED:
        return dds.PoseStamped(dds.Header(dds.Time(1, 0), "world"), pose)
    msg = dds.Odometry(dds.Header(dds.Time(1, 0), "world"), "base_link")
    msg.pose.pose = pose
    return msg


@pytest.mark.parametrize(("ros_type", "frame"), [(ros2.POSE_STAMPED, "start"), (ros2.ODOMETRY, "world")])
async def test_pose_from_carries_the_robot_and_its_receivers_on_a_ros2_robots_pose(ros_type: str, frame: str) -> None:
    """``emulate --pose-from ros2:TOPIC``: the world's robot (and every receiver on it) follows a
    ROS 2 robot's pose, its type read from discovery; ``frame=start`` puts the first pose at the
    scenario's start (kit-home: 1.5, 1.2, 0.6) and moves the robot as that robot moves from it,
    ``frame=world`` takes the poses as they are; a non-finite pose is refused; the scenario's base
    is not served."""
    from rfhoming.emulator.runtime import Emulator, running
    from rfhoming.emulator.scenario import load

    domain = random_domain()
    emulator = Emulator(load("kit-home"), transport="pipe", speed=20.0,
                        pose_from={"topic": "/ground_truth/pose", "domain": domain, "frame": frame})
    assert emulator.base is None and all(d.board != "base" for d in emulator.devices)
    robot = emulator.world.robot
    writer = dds_io.writer(dds_io.participant(domain), "/ground_truth/pose", ros_type, dds.SENSOR_QOS)
    follower = emulator.pose_from
    assert follower is not None

    async def publish_until(x: float, y: float, yaw: float, test) -> None:  # noqa: ANN001
        async with asyncio.timeout(60):  # hang guard only: best effort, so published until it is read
            while not test():
                writer.write(pose_sample(ros_type, x, y, yaw))
                await asyncio.sleep(0.02)

    async def stepped() -> None:  # a step after the pose came: it has moved the robot
        steps = emulator.counters["steps"]
        await until(lambda: emulator.counters["steps"] > steps, "an emulator step")

    async with running(emulator):
        spawn = (5.0, -3.0, 0.7)
        await publish_until(*spawn, lambda: follower.counters["poses"] > 0)
        await stepped()
        assert follower.type == ros_type
        expected = spawn if frame == "world" else (1.5, 1.2, 0.6)
        assert (robot.x, robot.y, robot.theta) == pytest.approx(expected, abs=1e-9)
        # 1 m ahead of the spawn along its heading, turned 0.5 rad left
        ahead = (spawn[0] + math.cos(0.7), spawn[1] + math.sin(0.7), 1.2)
        await publish_until(*ahead, lambda: abs(robot.theta - (ahead[2] if frame == "world" else 1.1)) < 1e-9)
        expected = ahead if frame == "world" else (1.5 + math.cos(0.6), 1.2 + math.sin(0.6), 1.1)
        assert (robot.x, robot.y, robot.theta) == pytest.approx(expected, abs=1e-9)
        await publish_until(math.nan, 0.0, 0.0, lambda: follower.counters["refused"] > 0)
        await stepped()
        assert (robot.x, robot.y, robot.theta) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize(("text", "settings"), [
    ("ros2:/ground_truth/pose", {"topic": "/ground_truth/pose"}),
    ("ros2:odom,domain=7,frame=world,discovery=subnet", {"topic": "odom", "domain": 7, "frame": "world",
                                                         "discovery": "subnet"}),
    ("ros2:/gt,wait=2.5,stale=0.5,frame_id=map", {"topic": "/gt", "wait": 2.5, "stale": 0.5, "frame_id": "map"}),
])
def test_pose_from_specs(text: str, settings: dict[str, object]) -> None:
    from rfhoming.cli.parsers.emulate import pose_source

    assert pose_source(text) == settings


@pytest.mark.parametrize("text", ["/gt", "ros2:", "ros2:a b", "ros2:/gt,domain=300", "ros2:/gt,frame=map",
                                  "ros2:/gt,type=odometry", "mavlink:/gt", "ros2:/gt,wait=0", "ros2:/gt,stale=inf",
                                  "ros2:/gt,wait=soon", "ros2:/gt,frame_id=a b"])
def test_bad_pose_from_specs_say_what_is_wanted(text: str) -> None:
    import argparse

    from rfhoming.cli.parsers.emulate import pose_source

    with pytest.raises(argparse.ArgumentTypeError) as err:
        pose_source(text)
    assert "\n" not in str(err.value) and "ros2:" in str(err.value)


async def test_pose_from_ignores_a_writer_of_another_type_and_says_so(caplog: pytest.LogCaptureFixture) -> None:
    from rfhoming.emulator.runtime import Emulator, running
    from rfhoming.emulator.scenario import load

    domain = random_domain()
    emulator = Emulator(load("s0-open"), transport="pipe", speed=20.0, pose_from={"topic": "/gt", "domain": domain})
    writer = dds_io.writer(dds_io.participant(domain), "/gt", ros2.TWIST)
    async with running(emulator):
        await until(lambda: "geometry_msgs::msg::dds_::Twist_" in caplog.text, "the warning")
        writer.write(dds.Twist(dds.Vector3(1.0, 0, 0), dds.Vector3()))
    assert emulator.pose_from is not None and emulator.pose_from.type is None
    assert (emulator.world.robot.x, emulator.world.robot.y) == (0.0, 0.0)
    assert len([r for r in caplog.records if "--pose-from /gt" in r.getMessage()]) == 1
