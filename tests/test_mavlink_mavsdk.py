"""MAVSDK -- a MAVLink implementation rfhoming did not write (its C++ core, through its Python
wrapper) -- connects to `rfhoming emulate --robot mavlink` as a ground station and sees the
emulated ArduPilot rover's mode, armed state, position and velocity change as it commands them."""

from __future__ import annotations

import asyncio
import math
import socket

import pytest

pytest.importorskip("pymavlink")
mavsdk = pytest.importorskip("mavsdk.asyncio")
from mavsdk.asyncio.plugins.action.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.offboard.offboard import OffboardAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry.telemetry import TelemetryAsync  # noqa: E402
from mavsdk.plugins.offboard import VelocityBodyYawspeed  # noqa: E402
from mavsdk.plugins.telemetry import FlightMode  # noqa: E402

DEADLINE_S = 60.0  # hang guard only


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def until(read, test=lambda _: True):  # noqa: ANN001, ANN201
    """The first value ``read()`` returns that passes ``test`` (MAVSDK keeps the latest of each)."""
    while True:
        value = await read()
        if test(value):
            return value
        await asyncio.sleep(0.05)


@pytest.mark.slow
def test_mavsdk_sees_the_emulated_rover_obey_it(tmp_path, emulated) -> None:  # noqa: ANN001
    port = free_udp_port()
    world = emulated("s0-open", "--robot", f"mavlink:udpout:127.0.0.1:{port}", link_dir=tmp_path, devices=2)
    base = world.endpoints["base"]
    assert base["kind"] == "mavlink" and base["path"] == f"mavlink:udpin:127.0.0.1:{port}"
    asyncio.run(asyncio.wait_for(_ground_station(port), DEADLINE_S))


async def _ground_station(port: int) -> None:
    config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
    async with mavsdk.Mavsdk(config) as gcs:
        await gcs.add_any_connection(f"udpin://127.0.0.1:{port}")
        vehicle = await gcs.first_autopilot(timeout_s=20.0)
        assert vehicle is not None, "MAVSDK found no autopilot"
        telemetry, action, offboard = TelemetryAsync(vehicle), ActionAsync(vehicle), OffboardAsync(vehicle)
        speed = lambda p: abs(p.velocity.north_m_s) + abs(p.velocity.east_m_s)  # noqa: E731
        assert await until(telemetry.flight_mode, lambda m: m != FlightMode.UNKNOWN) == FlightMode.HOLD  # as it boots
        assert await telemetry.armed() is False
        start = await until(telemetry.position_velocity_ned, lambda p: math.isfinite(p.position.north_m))
        assert speed(start) < 1e-3  # still

        await action.arm()
        assert await until(telemetry.armed, bool)
        await offboard.set_velocity_body(VelocityBodyYawspeed(0.5, 0.0, 0.0, 0.0))
        await offboard.start()  # ArduPilot: GUIDED
        await until(telemetry.flight_mode, lambda m: m == FlightMode.OFFBOARD)
        moving = await until(telemetry.position_velocity_ned, lambda p: speed(p) > 0.3)
        # s0-open's robot starts facing +x (east): forward is east in NED
        assert moving.velocity.east_m_s > 0.3 and abs(moving.velocity.north_m_s) < 0.05
        moved = await until(telemetry.position_velocity_ned, lambda p: p.position.east_m - start.position.east_m > 0.3)
        assert abs(moved.position.north_m - start.position.north_m) < 0.05

        await action.hold()
        await until(telemetry.flight_mode, lambda m: m == FlightMode.HOLD)
        await until(telemetry.position_velocity_ned, lambda p: speed(p) < 1e-3)  # it stops
