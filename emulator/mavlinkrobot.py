"""The emulated robot base as a MAVLink vehicle: the base's firmware model moves it, an
autopilot model (rfhoming.firmware.mavlink_vehicle) speaks MAVLink 2 for it over UDP on
127.0.0.1, as ArduPilot's SITL does.

The vehicle listens on its own ephemeral port and serves every ground station that speaks there
(``udpout:127.0.0.1:PORT``), as pymavlink's ``udpin:`` link (MAVProxy's ``--out udpin:``) serves
its clients: each sender is a peer that gets all telemetry, up to ``MAX_PEERS`` at once, and a
peer silent for ``PEER_SILENCE_S`` is forgotten (docs/protocol.md, "MAVLink vehicles"). A command's
answer goes to its sender alone. Given a ground station (``--robot mavlink:udpout:127.0.0.1:PORT``;
it listens with ``udpin:``), the vehicle sends to it always, and serves the others beside it.
Each odometry record of the firmware becomes ATTITUDE and LOCAL_POSITION_NED (and a HEARTBEAT
each second), and the firmware is told the velocity the autopilot drives at that instant.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

from rfhoming.emulator.links import Link
from rfhoming.firmware.mavlink_vehicle import MavlinkVehicle, VehicleOptions
from rfhoming.protocol import mavlink as ml
from rfhoming.protocol.frames import FrameDecoder, Odometry, VelocityCommand, encode_frame

FIRMWARE_TIMEOUT_MS = 100  # each odometry tick re-sends the autopilot's velocity; the firmware stops if they stop
MAX_PEERS = 8  # *assumed*: ground stations served at once; a newcomer beyond is not answered (counted)
PEER_SILENCE_S = 5.0
"""A peer silent this long (wall clock) is forgotten: the five missed HEARTBEATs after which the
MAVLink heartbeat service calls a system gone (a ground station sends one a second)."""
Address = tuple[str, int]


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, link: MavlinkLink) -> None:
        self.link = link

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.link.from_gcs(data, addr)


class MavlinkLink(Link):
    def __init__(self, gcs: Address | None = None, options: VehicleOptions = VehicleOptions(),
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.vehicle = MavlinkVehicle(options)
        self.gcs = gcs
        self.peers: dict[Address, float] = {}  # every other ground station, by when it last spoke (``clock``)
        self.clock = clock
        self.decoder = FrameDecoder()
        self.t = 0.0  # the vehicle's boot clock, from the firmware's odometry
        self.port = 0
        self._transport: asyncio.DatagramTransport | None = None
        self._seq = 0
        self.counters.update(datagrams_in=0, datagrams_out=0, peers_refused=0, peers_forgotten=0)
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
        peer = (str(addr[0]), int(addr[1]))
        if peer != self.gcs and peer not in self.peers:
            self._forget_silent()
            if len(self.peers) >= MAX_PEERS:
                self.counters["peers_refused"] += 1
                return
        if peer != self.gcs:
            self.peers[peer] = self.clock()
        self.counters["datagrams_in"] += 1
        self.counters["rx_bytes"] += len(data)
        setpoints = self.vehicle.counters["setpoints"]
        self._send_to(self.vehicle.feed(data, self.t), peer)
        if self.vehicle.counters["setpoints"] != setpoints:
            self.on_command()

    def _forget_silent(self) -> None:
        now = self.clock()
        for peer in [p for p, heard in self.peers.items() if now - heard > PEER_SILENCE_S]:
            del self.peers[peer]
            self.counters["peers_forgotten"] += 1

    def _to_peers(self, data: bytes) -> None:
        """Telemetry: to the ground station given, and to every peer not silent too long."""
        self._forget_silent()
        for peer in ([self.gcs] if self.gcs else []) + list(self.peers):
            self._send_to(data, peer)

    def _send_to(self, data: bytes, peer: Address) -> None:
        if data and self._transport is not None:
            self._transport.sendto(data, peer)
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
                self._to_peers(self.vehicle.telemetry(self.t, pose))
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
