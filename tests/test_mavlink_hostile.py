"""MAVLink: a vehicle (or anyone on its link) that lies, against rfhoming's MAVLink base
in process. The lies are made with pymavlink alone (tests/hostile_vehicle.py); the honest part
of the vehicle is the emulated autopilot (test_mavlink.FakeLink). Each test failed on the code
before the fix: values were taken as the pose, a lost HEARTBEAT went unnoticed, a second
vehicle was driven without a word, a refused or unanswered set-up left the vehicle in GUIDED,
junk cost the good packets after it, the UDP link listened to anyone and the run log took NaN.
tests/test_mavlink_hostile_run.py runs the same lies against ``rfhoming run`` in its own process."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import math
import socket
from typing import Any

import pytest

pytest.importorskip("pymavlink")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from hostile_vehicle import heartbeat, local_position, packets  # noqa: E402
from test_mavlink import FakeLink, commands, driven, exchange  # noqa: E402

from rfhoming.firmware.mavlink_vehicle import MavlinkVehicle, VehicleOptions  # noqa: E402
from rfhoming.host.drivers import mavlink_base  # noqa: E402
from rfhoming.host.drivers.mavlink_base import MavlinkBaseDriver  # noqa: E402
from rfhoming.host.homing.loop import RunLog  # noqa: E402
from rfhoming.host.mavlinkport import MavlinkPort  # noqa: E402
from rfhoming.host.ports import PortError  # noqa: E402
from rfhoming.protocol import mavlink as ml  # noqa: E402

HOLD, MANUAL, LOITER = 4, 0, 5  # ArduPilot Rover's custom modes


def attitude(ms: int, yaw: float = 0.0, yawspeed: float = 0.0) -> Any:
    return mav.MAVLink_attitude_message(ms, 0.0, 0.0, yaw, 0.0, 0.0, yawspeed)


def telemetry(ms: int, **position: float) -> bytes:
    """The vehicle's ATTITUDE and LOCAL_POSITION_NED at ``ms`` of its clock, no HEARTBEAT."""
    local = mav.MAVLink_local_position_ned_message(ms, position.get("x", 0.0), position.get("y", 0.0), 0.0,
                                                    position.get("vx", 0.0), 0.0, 0.0)
    return packets(1, 1, attitude(ms, position.get("yaw", 0.0), position.get("yawspeed", 0.0)), local)


def end(driver: MavlinkBaseDriver) -> None:
    """Leave the driver's ``async with``, as every end of a run does."""
    asyncio.run(driver.__aexit__(None, None, None))


def modes_asked(link: FakeLink) -> list[int]:
    return [int(m.param2) for m in link.written if m.get_type() == "COMMAND_LONG" and m.command == mav.MAV_CMD_DO_SET_MODE]


# -- values no vehicle can mean ---------------------------------------------------------------

IMPOSSIBLE = [
    ("LOCAL_POSITION_NED.x", {"x": math.nan}), ("LOCAL_POSITION_NED.y", {"y": math.inf}),
    ("LOCAL_POSITION_NED.x", {"x": 1e38}), ("LOCAL_POSITION_NED.vx", {"vx": -1e38}),
    ("ATTITUDE.yaw", {"yaw": math.nan}), ("ATTITUDE.yawspeed", {"yawspeed": 1e38}),
]


@pytest.mark.parametrize(("field", "values"), IMPOSSIBLE)
def test_the_decoder_refuses_values_no_vehicle_can_mean(field: str, values: dict[str, float]) -> None:
    decoder = ml.Codec()
    items = decoder.feed(telemetry(1000, **values))
    refused = [i for i in items if isinstance(i, ml.Refused)]
    assert len(refused) == 1 and refused[0].why.startswith(field) and decoder.refused == 1
    assert ml.MavlinkDecoder().feed(telemetry(1000, **values)) == [m for m in items if not isinstance(m, ml.Refused)]
    edge = decoder.feed(telemetry(1000, x=ml.POSITION_LIMIT_M, yaw=float.fromhex("0x1.921fb6p+1")))  # float32 pi
    assert [m.get_type() for m in edge] == ["ATTITUDE", "LOCAL_POSITION_NED"]


@pytest.mark.parametrize(("field", "values"), IMPOSSIBLE[:3] + IMPOSSIBLE[4:5])
def test_a_vehicle_sending_an_impossible_value_is_stopped_and_left_in_hold(field: str, values: dict[str, float]) -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    before = driver.latest
    driver.on_chunk(telemetry(2600, **values), 2.6)
    assert isinstance(driver.error, Exception) and field in str(driver.error), driver.error
    assert driver.latest is before and all(math.isfinite(v) for v in before[2:7])  # never the pose
    assert not driver.send_velocity(0.5, 0.0)
    end(driver)
    assert modes_asked(link)[-1] == HOLD and link.vehicle.mode == HOLD


def test_the_run_log_is_strict_json() -> None:
    out = io.StringIO()
    log = RunLog(out)
    log.write("odometry", 1.0, x=1.5)
    with pytest.raises(ValueError, match="not finite"):
        log.write("odometry", 1.1, x=math.nan)
    json.loads(out.getvalue(), parse_constant=lambda token: pytest.fail(f"a bare {token} in the run log"))


# -- the vehicle's HEARTBEAT --------------------------------------------------------

def test_a_heartbeat_lost_while_telemetry_goes_on_stops_the_run_and_leaves_hold() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    ms = driver.time_boot_ms
    driver.on_chunk(packets(1, 1, heartbeat(15, True)), 2.5)  # its last HEARTBEAT (GUIDED, armed)
    steps = round(mavlink_base.HEARTBEAT_LOSS_S * 50)  # telemetry at 50 Hz: the last one 3.48 s after the first, inside the bound
    for k in range(1, steps + 1):
        driver.on_chunk(telemetry(ms + 20 * k), k / 50)
    assert driver.error is None and driver.send_velocity(0.1, 0.0)
    for k in range(steps + 1, steps + 10):
        driver.on_chunk(telemetry(ms + 20 * k), k / 50)
    assert "no HEARTBEAT" in str(driver.error) and not driver.send_velocity(0.1, 0.0)
    end(driver)
    assert modes_asked(link)[-1] == HOLD


def test_heartbeats_each_second_keep_the_run_going() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    exchange(driver, link, 3 * mavlink_base.HEARTBEAT_LOSS_S)  # the emulated autopilot beats once a second
    assert driver.error is None and driver.counters["heartbeats"] >= 3 * mavlink_base.HEARTBEAT_LOSS_S


# -- every exit after the switch: HOLD (or end=) ----------------------------------------------

class Unanswered(FakeLink):
    """A link on which the vehicle never acknowledges ``command``."""

    def __init__(self, vehicle: MavlinkVehicle, command: int) -> None:
        super().__init__(vehicle)
        self.command = command

    def write(self, data: bytes) -> None:
        before = len(self.inbox)
        super().write(data)
        answers = ml.Codec(1, 1).feed(self.inbox[before:])
        if any(m.get_type() == "COMMAND_ACK" and m.command == self.command for m in answers):
            self.inbox = self.inbox[:before]


def test_a_refused_arming_leaves_the_vehicle_in_hold() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD", prearm_ok=False), arm=True)
    assert "refused arming" in str(driver.error)
    end(driver)
    assert modes_asked(link) == [15, HOLD] and link.vehicle.mode == HOLD


def test_a_refused_arming_of_a_vehicle_already_guided_leaves_it_in_hold() -> None:
    """No mode switch was needed: arming was rfhoming's first command, and the exit still holds
    (before the fix the vehicle was left in GUIDED, no mode command sent)."""
    driver, link = driven(VehicleOptions(mode="GUIDED", prearm_ok=False), arm=True)
    assert "refused arming" in str(driver.error) and not link.vehicle.armed
    end(driver)
    assert modes_asked(link) == [HOLD] and link.vehicle.mode == HOLD


@pytest.mark.parametrize("command", [mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_CMD_DO_SET_MODE])
def test_an_unanswered_set_up_leaves_the_vehicle_in_hold(command: int) -> None:
    async def make() -> tuple[MavlinkBaseDriver, FakeLink]:
        link = Unanswered(MavlinkVehicle(VehicleOptions(mode="HOLD")), command)
        driver = MavlinkBaseDriver(link, arm=True)
        exchange(driver, link, 2.0)
        return driver, link

    driver, link = asyncio.run(make())
    assert driver.step in ("switching", "arming") and not driver.connected.is_set()
    end(driver)
    assert modes_asked(link)[-1] == HOLD and link.vehicle.mode == HOLD


def test_end_names_the_mode_the_vehicle_is_left_in() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True, end="LOITER")
    assert driver.error is None
    end(driver)
    assert modes_asked(link)[-1] == LOITER and link.vehicle.mode == LOITER
    refused, link = driven(VehicleOptions(mode="HOLD"), arm=True, end="MANUAL")
    assert "end=MANUAL" in str(refused.error) and "LOITER" in str(refused.error)
    assert mav.MAV_CMD_DO_SET_MODE not in commands(link)


# -- one vehicle: a second one, and someone speaking as it --------------------------------------

def test_two_vehicles_before_the_driving_starts_need_sysid() -> None:
    async def make(**settings: Any) -> tuple[MavlinkBaseDriver, FakeLink]:
        link = FakeLink(MavlinkVehicle(VehicleOptions(mode="HOLD")))
        driver = MavlinkBaseDriver(link, arm=True, **settings)
        driver.on_chunk(packets(2, 1, heartbeat(HOLD, False)), 0.0)  # heard first, but not the one meant
        exchange(driver, link, 2.5)
        return driver, link

    driver, link = asyncio.run(make())
    assert "two vehicles speak" in str(driver.error) and "sysid=" in str(driver.error), driver.error
    assert not link.vehicle.armed
    chosen, link = asyncio.run(make(sysid=1))
    assert chosen.error is None and chosen.connected.is_set() and chosen.counters["other_systems"] >= 1


def test_a_second_vehicle_while_driving_is_ignored_and_warned_of_once(caplog: pytest.LogCaptureFixture) -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    latest = driver.latest
    with caplog.at_level(logging.WARNING):
        for k in range(3):
            driver.on_chunk(packets(2, 1, heartbeat(MANUAL, True), attitude(9000 + k), local_position(9000 + k, 40.0, 40.0)), 3.0)
    assert driver.error is None and driver.latest is latest  # its MANUAL did not end the run, its pose is not ours
    warned = [r for r in caplog.records if "another vehicle" in r.getMessage()]
    assert len(warned) == 1 and "system 2" in warned[0].getMessage()


def test_another_sender_speaking_as_the_vehicle_ends_the_run() -> None:
    driver, link = driven(VehicleOptions(mode="HOLD"), arm=True)
    driver._on_foreign(("127.0.0.1", 40000), packets(1, 1, heartbeat(MANUAL, True), local_position(9000, 40.0, 40.0)))
    assert "127.0.0.1:40000" in str(driver.error) and "speaks as the vehicle" in str(driver.error)
    end(driver)
    assert modes_asked(link)[-1] == HOLD  # sent to the vehicle's own address (the port's lock)


# -- the UDP link ----------------------------------------------------------------------------

def udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(30)
    return s


def test_a_udpout_link_binds_loopback_and_hears_only_its_vehicle() -> None:
    async def main() -> None:
        with udp() as vehicle, udp() as other:
            port = MavlinkPort(f"udpout:127.0.0.1:{vehicle.getsockname()[1]}")
            await port.open()
            try:
                port.write(packets(255, 191, heartbeat(0, False)))
                _, gcs = vehicle.recvfrom(1000)
                assert gcs[0] == "127.0.0.1" and port._conn.sock.getsockname()[0] == "127.0.0.1"
                seen: list[Any] = []
                port.on_foreign = lambda source, data: seen.append(source)
                other.sendto(packets(1, 1, heartbeat(MANUAL, True)), gcs)
                vehicle.sendto(packets(1, 1, heartbeat(HOLD, False)), gcs)
                chunk = await asyncio.wait_for(port.read(), 30)
                assert ml.Codec().feed(chunk.data)[0].custom_mode == HOLD  # the vehicle's, not the other's
                assert port.counters["foreign_datagrams"] == 1 and seen == [other.getsockname()]
            finally:
                await port.close()

    asyncio.run(main())


def test_a_udpin_link_locks_on_to_the_first_vehicle_heartbeat_and_answers_it_alone() -> None:
    async def main() -> None:
        with udp() as vehicle, udp() as other:
            port = MavlinkPort("udpin:127.0.0.1:0")
            await port.open()
            try:
                where = port._conn.sock.getsockname()
                other.sendto(b"\x00junk", where)  # spoke first, but is no vehicle
                await asyncio.wait_for(port.read(), 30)
                vehicle.sendto(packets(1, 1, heartbeat(HOLD, False)), where)
                await asyncio.wait_for(port.read(), 30)
                port.write(packets(255, 191, heartbeat(0, False)))
                vehicle.recvfrom(1000)
                other.sendto(packets(1, 1, local_position(1, 40.0, 40.0)), where)
                vehicle.sendto(packets(1, 1, local_position(1, 0.0, 0.0)), where)
                chunk = await asyncio.wait_for(port.read(), 30)
                assert ml.Codec().feed(chunk.data)[0].x == 0.0 and port.counters["foreign_datagrams"] == 1
                other.settimeout(0.0)
                with pytest.raises(BlockingIOError):
                    other.recvfrom(1000)  # it heard nothing of the ground station's
            finally:
                await port.close()

    asyncio.run(main())


@pytest.mark.parametrize("where", ["udpout:192.0.2.1:14550", "udpbcast:192.0.2.255:14550"])
def test_a_udp_link_reaching_other_machines_needs_expose(where: str) -> None:
    with pytest.raises(PortError, match="expose=1"):
        MavlinkPort(where)
    MavlinkPort(where, expose=True)  # the user's choice


# -- junk on the link ------------------------------------------------------------------------

GOOD = [packets(1, 1, attitude(k), local_position(k, 1.0, 2.0)) for k in range(8)]


@given(st.lists(st.tuples(st.sampled_from(range(len(GOOD))), st.binary(max_size=300)), max_size=20))
def test_junk_datagrams_never_cost_a_good_one(sequence: list[tuple[int, bytes]]) -> None:
    decoder, got = ml.Codec(), []
    for k, junk in sequence:
        decoder.feed(junk, datagram=True)
        got += [m.time_boot_ms for m in decoder.feed(GOOD[k], datagram=True) if m.get_type() == "LOCAL_POSITION_NED"]
    assert got == [k for k, _ in sequence]


def test_a_false_start_costs_one_byte_on_a_stream() -> None:
    decoder = ml.Codec()
    stream = bytes([0xFE, 200]) + b"".join(GOOD)  # a MAVLink 1 marker claiming 208 bytes over good packets
    got = decoder.feed(stream)
    assert [m.time_boot_ms for m in got if m.get_type() == "LOCAL_POSITION_NED"] == list(range(len(GOOD)))
    assert decoder.bad >= 1


@given(st.lists(st.integers(1, 40), min_size=1, max_size=60))
def test_any_chunking_of_a_stream_gives_the_same_messages(cuts: list[int]) -> None:
    stream = b"\x00\xfd\x07" + b"".join(GOOD) + b"\xfe"
    whole = [(m.get_type(), m.time_boot_ms) for m in ml.Codec().feed(stream)]
    chunked, decoder, i = [], ml.Codec(), 0
    for n in cuts * (len(stream) // sum(cuts) + 1):
        chunked += [(m.get_type(), m.time_boot_ms) for m in decoder.feed(stream[i:i + n])]
        i += n
    assert chunked == whole and len(whole) == 2 * len(GOOD)
