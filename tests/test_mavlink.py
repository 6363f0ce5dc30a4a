"""The MAVLink base: the robot-base interface every base implements, the NED/FRD <-> ENU/FLU
conversion, and the driver's safety rules against the emulated autopilot (sans-IO, in-process):
it never arms unless asked, never takes over from a pilot, stops driving when the vehicle leaves
the guided mode, and streams setpoints before PX4's OFFBOARD switch."""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

pytest.importorskip("pymavlink")

from rfhoming.emulator.mavlinkrobot import MAX_PEERS, MavlinkLink  # noqa: E402
from rfhoming.firmware.mavlink_vehicle import MavlinkVehicle, VehicleOptions  # noqa: E402
from rfhoming.host.drivers.mavlink_base import MavlinkBaseDriver  # noqa: E402
from rfhoming.host.drivers.robot import Pose2D, RobotBase, TakenOver  # noqa: E402
from rfhoming.host.drivers.robot_base import BaseDriver  # noqa: E402
from rfhoming.host.drivers.ros2_base import Ros2BaseDriver  # noqa: E402
from rfhoming.host.ports import HostPort  # noqa: E402
from rfhoming.protocol import mavlink as ml  # noqa: E402
from rfhoming.protocol.mavlink import mav  # noqa: E402
from test_typing import mypy  # noqa: E402


def test_every_robot_base_implements_the_interface() -> None:
    async def made() -> list[Any]:
        return [BaseDriver(HostPort("x")), Ros2BaseDriver(HostPort("x")), MavlinkBaseDriver(FakeLink())]

    for base in asyncio.run(made()):
        assert isinstance(base, RobotBase), type(base).__name__
    assert not isinstance(object(), RobotBase)


@pytest.mark.slow
def test_every_robot_base_implements_the_interface_for_mypy(tmp_path: Path) -> None:
    (tmp_path / "bases.py").write_text(
        "from rfhoming.host.drivers.mavlink_base import MavlinkBaseDriver\n"
        "from rfhoming.host.drivers.robot import RobotBase\n"
        "from rfhoming.host.drivers.robot_base import BaseDriver\n"
        "from rfhoming.host.drivers.ros2_base import Ros2BaseDriver\n\n\n"
        "def drive(base: RobotBase) -> None:\n    base.send_velocity(0.1, 0.0)\n\n\n"
        "def each(a: BaseDriver, b: Ros2BaseDriver, c: MavlinkBaseDriver) -> None:\n"
        "    drive(a)\n    drive(b)\n    drive(c)\n    drive(object())  # the check's own proof that it can fail\n")
    done = mypy(tmp_path, "bases.py")
    errors = [line for line in done.stdout.splitlines() if ": error:" in line]
    assert len(errors) == 1 and "bases.py:15:" in errors[0] and '"object"' in errors[0], done.stdout


def test_ned_and_frd_become_enu_and_flu() -> None:
    """North 1 m, east 2 m, heading north-east (45° clockwise from north), moving ahead at 1 m/s
    and turning right (clockwise) at 0.1 rad/s -> x east 2, y north 1, yaw 45° counter-clockwise
    from east, v 1 m/s, ω -0.1 rad/s."""
    local = SimpleNamespace(x=1.0, y=2.0, vx=math.sqrt(0.5), vy=math.sqrt(0.5))
    attitude = SimpleNamespace(yaw=math.pi / 4, yawspeed=0.1)
    pose = ml.pose_of(local, attitude)
    assert pose.x == 2.0 and pose.y == 1.0
    assert pose.theta == pytest.approx(math.pi / 4) and pose.v == pytest.approx(1.0) and pose.w == pytest.approx(-0.1)
    facing_east = ml.pose_of(SimpleNamespace(x=0.0, y=0.0, vx=0.0, vy=0.5), SimpleNamespace(yaw=math.pi / 2, yawspeed=0.0))
    assert facing_east.theta == pytest.approx(0.0) and facing_east.v == pytest.approx(0.5)
    (n, e, vn, ve), yaw, rate = ml.ned_of(pose)
    assert (n, e, yaw, rate) == pytest.approx((1.0, 2.0, math.pi / 4, 0.1)) and (vn, ve) == pytest.approx((local.vx, local.vy))
    assert ml.body_velocity(0.5, 0.2) == (0.5, 0.0, 0.0, -0.2)  # FLU counter-clockwise is FRD negative yaw rate


class FakeLink:
    """A port between the driver and an emulated autopilot: what the driver writes reaches the
    vehicle model, whose answers wait in ``inbox`` for :func:`exchange`."""

    def __init__(self, vehicle: MavlinkVehicle | None = None) -> None:
        self.vehicle = vehicle
        self.name = "fake"
        self.counters = {"opens": 1, "bytes_in": 0}
        self.taps: list[Any] = []
        self.written: list[Any] = []
        self.inbox = b""
        self.t = 0.0

    def write(self, data: bytes) -> None:
        self.written += ml.Codec(1, 1).feed(data)
        if self.vehicle is not None:
            self.inbox += self.vehicle.feed(data, self.t)

    async def close(self) -> None:
        pass


def exchange(driver: MavlinkBaseDriver, link: FakeLink, seconds: float) -> None:
    """``seconds`` of the vehicle's telemetry at 50 Hz, its answers handed to the driver as they come."""
    assert link.vehicle is not None
    for _ in range(round(seconds * 50)):
        link.t += 0.02
        driver.on_chunk(link.vehicle.telemetry(link.t, ml.PoseEnu(0, 0, 0, 0, 0)), link.t)
        while link.inbox:
            answers, link.inbox = link.inbox, b""
            driver.on_chunk(answers, link.t)


def commands(link: FakeLink) -> list[int]:
    return [m.command for m in link.written if m.get_type() == "COMMAND_LONG"]


def driven(options: VehicleOptions, **settings: Any) -> tuple[MavlinkBaseDriver, FakeLink]:
    async def make() -> tuple[MavlinkBaseDriver, FakeLink]:
        link = FakeLink(MavlinkVehicle(options))
        driver = MavlinkBaseDriver(link, **settings)
        exchange(driver, link, 2.5)
        return driver, link

    return asyncio.run(make())


def test_a_disarmed_vehicle_is_not_armed_unless_asked() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"))
    assert mav.MAV_CMD_COMPONENT_ARM_DISARM not in commands(link) and not link.vehicle.armed
    assert driver.state == "setup_failed" and "arm=1" in str(driver.error)
    assert not driver.send_velocity(0.5, 0.0)
    assert not any(m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" for m in link.written)


def test_a_vehicle_in_a_pilots_mode_is_left_to_the_pilot() -> None:
    driver, link = driven(VehicleOptions(mode="MANUAL", armed=True), arm=True)
    assert set(commands(link)) == {mav.MAV_CMD_SET_MESSAGE_INTERVAL}  # no mode change, no arming
    assert link.vehicle.autopilot.mode_name(link.vehicle.mode) == "MANUAL"
    assert "MANUAL, a pilot's mode" in str(driver.error) and "switch it to HOLD" in str(driver.error)


def test_arm_1_arms_switches_to_guided_and_drives_in_the_body_frame() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    assert driver.state == "streaming" and driver.error is None and driver.connected.is_set()
    assert link.vehicle.armed and link.vehicle.mode == ml.ARDUPILOT_ROVER.guided
    assert isinstance(driver.latest, Pose2D) and driver.latest.t_robot == pytest.approx(2.5)
    driver.acting_on(driver.latest)  # the loop takes it
    assert driver.send_velocity(0.4, 0.25)
    setpoint = link.written[-1]
    assert setpoint.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
    assert setpoint.coordinate_frame == mav.MAV_FRAME_BODY_OFFSET_NED and setpoint.type_mask == 0x05E7
    assert (setpoint.vx, setpoint.vy, setpoint.yaw_rate) == pytest.approx((0.4, 0.0, -0.25))
    assert setpoint.time_boot_ms == 2500  # the vehicle's clock, so a replay writes the same bytes
    assert link.vehicle.velocity(link.t) == pytest.approx((0.4, 0.25))


def test_the_loops_writes_follow_the_odometry_it_acts_on_not_the_newest_read() -> None:
    """Live, the driver reads datagrams the loop has not taken yet as the machine's load has it; a
    replay reads them in the recording's order. So what the loop writes -- a setpoint's
    ``time_boot_ms``, the ground station's HEARTBEAT -- follows the odometry it acts on alone
    (before the fix a setpoint carried the newest read, and the HEARTBEAT answered the vehicle's
    as it was read: a replay under load wrote other bytes)."""
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    first = driver.latest
    assert first is not None and driver.send_velocity(0.0, 0.0)
    assert link.written[-1].time_boot_ms < 500  # the loop starts on the odometry the set-up handed it
    written = len(link.written)
    exchange(driver, link, 1.0)  # a second read ahead, a vehicle HEARTBEAT in it; the loop still on `first`
    assert driver.latest.t_robot == pytest.approx(3.5) and driver.counters["heartbeats"] >= 1
    assert link.written[written:] == []  # nothing answered as it was read: driving, the loop writes
    driver.acting_on(first)
    assert driver.send_velocity(0.2, 0.0) and link.written[-1].time_boot_ms == round(first.t_robot * 1000)
    kinds = [m.get_type() for m in link.written[written:]]
    assert kinds == ["HEARTBEAT", "SET_POSITION_TARGET_LOCAL_NED"]  # the loop's first odometry of a second
    for ms in (2520, 2980, 3000, 3020):  # the ground station's HEARTBEAT once a second of the vehicle's clock
        driver.acting_on(first._replace(t_robot=ms / 1000))
    beats = [m for m in link.written[written:] if m.get_type() == "HEARTBEAT"]
    assert len(beats) == 2 and beats[0].type == mav.MAV_TYPE_GCS
    assert driver.send_velocity(0.2, 0.0) and link.written[-1].time_boot_ms == 3020


def test_a_refused_arming_fails_the_run() -> None:
    driver, _ = driven(VehicleOptions(mode="HOLD", prearm_ok=False), arm=True)
    assert "refused arming" in str(driver.error) and "MAV_RESULT_FAILED" in str(driver.error)


def test_a_vehicle_taken_over_gets_no_more_setpoints() -> None:
    """Not an error: the loop ends the run on the TakenOver item, in the vehicle's order."""
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    link.vehicle.mode = 0  # the pilot's switch: MANUAL
    exchange(driver, link, 1.1)
    assert driver.error is None and driver.taken_over
    taken = [item for item in iter(driver.out.get_nowait, None) if isinstance(item, TakenOver)]
    assert len(taken) == 1 and taken[0].mode == "MANUAL" and "left GUIDED for MANUAL" in taken[0].why
    assert not driver.send_velocity(0.5, 0.0)


def rtl(vehicle: MavlinkVehicle, start: ml.PoseEnu, seconds: float) -> ml.PoseEnu:
    """The vehicle's own RTL, integrated at 50 Hz from ``start`` (a unicycle: what the base does)."""
    pose, t = start, 0.0
    for _ in range(round(seconds * 50)):
        vehicle.telemetry(t, pose)
        v, w = vehicle.velocity(t)
        pose = ml.PoseEnu(pose.x + v * math.cos(pose.theta) * 0.02, pose.y + v * math.sin(pose.theta) * 0.02,
                          pose.theta + w * 0.02, v, w)
        t += 0.02
    return pose


@pytest.mark.parametrize("vehicle", ["rover", "copter"])
def test_rtl_returns_to_where_the_vehicle_was_armed(vehicle: str) -> None:
    """ArduPilot and PX4 return to home (set at arming) in RTL: a rover stops there, a copter
    lands and disarms; not where the mode changed."""
    model = MavlinkVehicle(VehicleOptions(mode="GUIDED", vehicle=vehicle, altitude=1.0))
    model.telemetry(0.0, ml.PoseEnu(1.0, 2.0, 0.0, 0.0, 0.0))
    model.feed(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
               .pack(mav.MAVLink(None, 255, 190)), 0.0)
    assert model.armed and model.home == (1.0, 2.0)
    model.mode = model.rtl
    end = rtl(model, ml.PoseEnu(4.0, -1.0, 2.0, 0.0, 0.0), 30.0)
    assert math.dist((end.x, end.y), (1.0, 2.0)) < 0.25 and model.velocity(30.0) == (0.0, 0.0)
    assert model.armed == (vehicle == "rover") and model.altitude == 0.0


class Peers:
    """An emulated vehicle's link on a fake transport, its clock in the test's hands."""

    def __init__(self) -> None:
        self.now = 0.0
        self.link = MavlinkLink(clock=lambda: self.now)
        self.sent: list[tuple[str, int]] = []
        self.link._transport = SimpleNamespace(sendto=lambda data, peer: self.sent.append(peer))  # type: ignore[assignment]
        self.link.plugged = True

    def telemetry(self) -> set[tuple[str, int]]:
        self.sent.clear()
        self.link._to_peers(b"telemetry")
        return set(self.sent)


def test_the_vehicle_serves_every_ground_station_and_forgets_the_silent() -> None:
    peers = Peers()
    hello = ml.Codec(255, 190).encode(ml.gcs_heartbeat())
    for port in (14550, 14551):
        peers.link.from_gcs(hello, ("127.0.0.1", port))
    assert peers.telemetry() == {("127.0.0.1", 14550), ("127.0.0.1", 14551)}  # both get all of it
    peers.now = 4.0
    peers.link.from_gcs(hello, ("127.0.0.1", 14550))
    peers.now = 6.0  # 14551 silent for 6 s
    assert peers.telemetry() == {("127.0.0.1", 14550)} and peers.link.counters["peers_forgotten"] == 1
    for port in range(20000, 20000 + MAX_PEERS):
        peers.link.from_gcs(hello, ("127.0.0.1", port))
    assert len(peers.telemetry()) == MAX_PEERS and peers.link.counters["peers_refused"] == 1


def test_the_guided_timeout_stops_the_vehicle() -> None:
    """ArduPilot stops a vehicle whose setpoints stop for GUID_TIMEOUT (3 s by default)."""
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    driver.send_velocity(0.5, 0.0)
    exchange(driver, link, 2.9)
    assert link.vehicle.velocity(link.t) == (0.5, 0.0)
    exchange(driver, link, 0.2)
    assert link.vehicle.velocity(link.t) == (0.0, 0.0)


def test_px4_gets_a_second_of_setpoints_before_the_offboard_switch() -> None:
    driver, link = driven(VehicleOptions(autopilot="px4", mode="HOLD", armed=True))
    assert driver.error is None and link.vehicle.autopilot.mode_name(link.vehicle.mode) == "OFFBOARD"
    kinds = [m.get_type() if m.get_type() != "COMMAND_LONG" else m.command for m in link.written]
    switch = kinds.index(mav.MAV_CMD_DO_SET_MODE)
    stream = [m for m in link.written[:switch] if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert stream[-1].time_boot_ms - stream[0].time_boot_ms >= 1000 and all(m.vx == 0 for m in stream)
    assert link.written[switch].param2 == ml.PX4_OFFBOARD and stream[0].coordinate_frame == mav.MAV_FRAME_BODY_NED


def test_a_listening_socket_on_the_network_needs_expose() -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "run", "--aoa", "/dev/null", "--base",
                           "mavlink:udpin:0.0.0.0:14550"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "expose=1" in done.stderr and "udpin:127.0.0.1:PORT" in done.stderr
