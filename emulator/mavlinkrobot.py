"""The emulated robot base as a MAVLink vehicle: the base's firmware model moves it, an
autopilot model (rfhoming.firmware.mavlink_vehicle) speaks MAVLink 2 for it over UDP on
127.0.0.1, as ArduPilot's SITL does.

The vehicle listens on its own ephemeral port and answers whoever spoke last there (a ground
station with ``udpout:127.0.0.1:PORT``), or sends to the ground station it was given
(``--robot mavlink:udpout:127.0.0.1:PORT``; the ground station then listens with ``udpin:``).
Each odometry record of the firmware becomes ATTITUDE and LOCAL_POSITION_NED (and a HEARTBEAT
each second), and the firmware is told the velocity the autopilot drives at that instant.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from rfhoming.emulator.links import Link
from rfhoming.firmware.mavlink_vehicle import MavlinkVehicle, VehicleOptions
from rfhoming.protocol import mavlink as ml
from rfhoming.protocol.frames import FrameDecoder, Odometry, VelocityCommand, encode_frame

FIRMWARE_TIMEOUT_MS = 100  # each odometry tick re-sends the autopilot's velocity; the firmware stops if they stop


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, link: MavlinkLink) -> None:
        self.link = link

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.link.from_gcs(data, addr)


class MavlinkLink(Link):
    def __init__(self, gcs: tuple[str, int] | None = None, options: VehicleOptions = VehicleOptions()) -> None:
        super().__init__()
        self.vehicle = MavlinkVehicle(options)
        self.gcs = gcs
        self.peer = gcs
        self.decoder = FrameDecoder()
        self.t = 0.0  # the vehicle's boot clock, from the firmware's odometry
        self.port = 0
        self._transport: asyncio.DatagramTransport | None = None
        self._seq = 0
        self.counters.update(datagrams_in=0, datagrams_out=0)
        self.on_command: Callable[[], None] = lambda: None  # a setpoint came: the lockstep's answer

    def describe(self) -> dict[str, Any]:
        host_spec = (f"mavlink:udpin:{self.gcs[0]}:{self.gcs[1]}" if self.gcs
                     else f"mavlink:udpout:127.0.0.1:{self.port}")
        o = self.vehicle.options
        return {"kind": "mavlink", "protocol": "mavlink", "path": host_spec,
                "mavlink": {"vehicle": f"127.0.0.1:{self.port}", "autopilot": o.autopilot, "type": o.vehicle,
                            "mode": self.vehicle.autopilot.mode_name(self.vehicle.mode), "armed": self.vehicle.armed,
                            "system": o.system}}

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        transport, _ = await loop.create_datagram_endpoint(lambda: _Datagrams(self), local_addr=("127.0.0.1", 0))
        self._transport = transport
        self.port = transport.get_extra_info("sockname")[1]
        self.plugged = True

    def from_gcs(self, data: bytes, addr: Any) -> None:
        if not self.plugged:
            return
        if self.gcs is None:
            self.peer = addr
        self.counters["datagrams_in"] += 1
        self.counters["rx_bytes"] += len(data)
        setpoints = self.vehicle.counters["setpoints"]
        self._to_gcs(self.vehicle.feed(data, self.t))
        if self.vehicle.counters["setpoints"] != setpoints:
            self.on_command()

    def _to_gcs(self, data: bytes) -> None:
        if data and self._transport is not None and self.peer is not None:
            self._transport.sendto(data, self.peer)
            self.counters["datagrams_out"] += 1
            self.counters["tx_bytes"] += len(data)

    def send(self, data: bytes) -> None:
        """The firmware's bytes: each odometry record is the vehicle's telemetry, and the moment
        the autopilot's velocity is handed to the firmware."""
        if not self.plugged:
            self.counters["dropped_bytes"] += len(data)
            return
        for record in self.decoder.feed(data):
            if isinstance(record, Odometry):
                self.t = record.t_us / 1e6
                pose = ml.PoseEnu(record.x_mm / 1000, record.y_mm / 1000, record.theta_urad / 1e6,
                                  record.v_mm_s / 1000, record.w_mrad_s / 1000)
                self._to_gcs(self.vehicle.telemetry(self.t, pose))
                self._drive(*self.vehicle.velocity(self.t))

    def _drive(self, v: float, w: float) -> None:
        self._seq = (self._seq + 1) & 0xFFFF
        frame = encode_frame(VelocityCommand(0, self._seq, 0, max(-32768, min(32767, round(v * 1000))),
                                             max(-32768, min(32767, round(w * 1000))), FIRMWARE_TIMEOUT_MS))
        asyncio.get_running_loop().call_soon(self.on_receive, frame)  # not inside the firmware's own send

    async def unplug(self) -> None:
        self.plugged = False
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        self.counters["unplugs"] += 1
