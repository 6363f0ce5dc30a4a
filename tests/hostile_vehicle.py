"""A MAVLink vehicle that lies, for the tests of the MAVLink base: an ArduPilot Rover on
UDP loopback, written on pymavlink alone -- not on rfhoming's codec or its emulated autopilot --
so that what it sends is what any vehicle, or anyone on the network, could send.

It runs on a thread in real time, as a vehicle does: HEARTBEAT at 1 Hz, ATTITUDE and
LOCAL_POSITION_NED at 50 Hz, COMMAND_LONG answered with COMMAND_ACK (mode, arming, message
interval, request message), setpoints counted. Its lies can be switched on while it runs:

- ``position``: what LOCAL_POSITION_NED says (NaN, inf, 1e38 ...);
- ``heartbeats``: False stops its HEARTBEAT while the telemetry goes on;
- ``refuse_arm``: arming answered MAV_RESULT_FAILED, as failing pre-arm checks answer it;
- ``unanswered``: commands it never acknowledges;
- :meth:`switch_to`: a mode change of its own (the pilot's switch, a failsafe);
- :meth:`speak` / :meth:`impostor`: datagrams from another socket (another port on this
  machine), as another vehicle or another system id would send them;
- ``junk``: a seeded random.Random makes it send ``junk_each`` datagrams of :meth:`garbage`
  from its own socket after each of its telemetry datagrams (a noisy radio bridge).

What it was told is kept in ``received`` (every message) and ``mode`` (the mode it is in).
"""

from __future__ import annotations

import math
import random
import select
import socket
import threading
import time
from typing import Any

from pymavlink.dialects.v20 import common as mav

MODES = {"MANUAL": 0, "HOLD": 4, "GUIDED": 15}  # ArduPilot Rover's custom modes (Rover/mode.h)
NAMES = {number: name for name, number in MODES.items()}
TELEMETRY_S = 0.02


def packets(system: int, component: int, *messages: Any) -> bytes:
    """Messages packed as ``system``/``component`` would send them."""
    link = mav.MAVLink(None, srcSystem=system, srcComponent=component)
    return b"".join(bytes(m.pack(link)) for m in messages)


def heartbeat(mode: int, armed: bool) -> Any:
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GROUND_ROVER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, mode,
                                         mav.MAV_STATE_ACTIVE if armed else mav.MAV_STATE_STANDBY, 3)


def local_position(ms: int, north: float, east: float) -> Any:
    return mav.MAVLink_local_position_ned_message(ms, north, east, 0.0, 0.0, 0.0, 0.0)


class HostileVehicle:
    def __init__(self, *, system: int = 1, component: int = 1, mode: str = "HOLD", armed: bool = False) -> None:
        self.system, self.component = system, component
        self.mode, self.armed = MODES[mode], armed
        self.position: tuple[float, float] = (0.0, 0.0)  # north, east (m)
        self.heartbeats = True
        self.refuse_arm = False
        self.unanswered: set[int] = set()
        self.junk: random.Random | None = None
        self.junk_each = 1
        self.received: list[Any] = []
        self.setpoints = 0
        self.gcs: tuple[str, int] | None = None  # where the ground station spoke from
        self.spoken = threading.Event()  # the ground station's first datagram came
        self.driven = threading.Event()  # its first setpoint came
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self.port: int = self._sock.getsockname()[1]
        self._out = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        self._in = mav.MAVLink(None)
        self._in.robust_parsing = True
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._boot = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="hostile-vehicle", daemon=True)

    # -- what a test does ------------------------------------------------------------------

    def __enter__(self) -> HostileVehicle:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)
        while select.select([self._sock], [], [], 0)[0]:  # what came before it stopped (a run's last HOLD,
            self._receive()  # sent as it exited) is read too, however late the thread would have woken
        self._sock.close()

    def switch_to(self, mode: str) -> None:
        """A mode change of the vehicle's own: the next HEARTBEAT says it."""
        with self._lock:
            self.mode = MODES[mode]

    def commands(self, command: int) -> list[Any]:
        with self._lock:
            return [m for m in self.received if m.get_type() == "COMMAND_LONG" and m.command == command]

    def modes_asked(self) -> list[str]:
        """Every mode the ground station asked for, in order (MAV_CMD_DO_SET_MODE's param2)."""
        return [NAMES.get(int(m.param2), str(m.param2)) for m in self.commands(mav.MAV_CMD_DO_SET_MODE)]

    def speak(self, data: bytes) -> None:
        """``data`` to the ground station from another socket: another port on this machine."""
        assert self.gcs is not None, "the ground station has not spoken yet"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.bind(("127.0.0.1", 0))
            other.sendto(data, self.gcs)

    def impostor(self, system: int, mode: str = "MANUAL", north: float = 50.0, times: int = 1) -> None:
        """Another vehicle's HEARTBEAT and LOCAL_POSITION_NED from another port (``system`` may be
        this vehicle's own id: someone sending in its name)."""
        for _ in range(times):
            self.speak(packets(system, 1, heartbeat(MODES[mode], True), mav.MAVLink_attitude_message(
                self._ms(), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), local_position(self._ms(), north, north)))

    def garbage(self, rng: random.Random) -> bytes:
        """A datagram of junk: random bytes, a lone start marker with a long length, or one of its
        own packets with a bad CRC."""
        kind = rng.randrange(3)
        if kind == 0:
            return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 512)))
        if kind == 1:
            return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 8))) + bytes([0xFD, 255, 0])
        good = bytearray(packets(self.system, self.component, local_position(0, 0.0, 0.0)))
        good[-1] ^= 0xFF
        return bytes(good)

    # -- the vehicle -----------------------------------------------------------------------

    def _ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000)

    def _send(self, *messages: Any) -> None:
        if self.gcs is not None:
            self._sock.sendto(b"".join(bytes(m.pack(self._out)) for m in messages), self.gcs)

    def _run(self) -> None:
        next_tick, next_beat = time.monotonic(), time.monotonic()
        while not self._stop.is_set():
            ready, _, _ = select.select([self._sock], [], [], max(0.0, next_tick - time.monotonic()))
            if ready:
                self._receive()
            now = time.monotonic()
            if now < next_tick:
                continue
            next_tick = now + TELEMETRY_S
            with self._lock:
                north, east = self.position
                beat = self.heartbeats and now >= next_beat
                mode, armed = self.mode, self.armed
            if beat:
                next_beat = now + 1.0
                self._send(heartbeat(mode, armed))
            self._send(mav.MAVLink_attitude_message(self._ms(), 0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.0),
                       local_position(self._ms(), north, east))
            for _ in range(self.junk_each if self.junk is not None and self.gcs is not None else 0):
                self._sock.sendto(self.garbage(self.junk), self.gcs)

    def _receive(self) -> None:
        try:
            data, address = self._sock.recvfrom(65536)
        except OSError:
            return
        if self.gcs is None:
            self.gcs = address
            self.spoken.set()
        for message in self._in.parse_buffer(data) or ():
            if message.get_type() == "BAD_DATA":
                continue
            with self._lock:
                self.received.append(message)
            if message.get_type() == "COMMAND_LONG":
                self._command(message)
            elif message.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                self.setpoints += 1
                self.driven.set()

    def _command(self, message: Any) -> None:
        result = mav.MAV_RESULT_ACCEPTED
        with self._lock:
            if message.command == mav.MAV_CMD_DO_SET_MODE:
                self.mode = int(message.param2)
            elif message.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
                if message.param1 == 1 and self.refuse_arm:
                    result = mav.MAV_RESULT_FAILED
                else:
                    self.armed = message.param1 == 1
            mode, armed, silent = self.mode, self.armed, message.command in self.unanswered
        if silent:
            return
        self._send(mav.MAVLink_command_ack_message(message.command, result))
        if (message.command == mav.MAV_CMD_REQUEST_MESSAGE and message.param1 == mav.MAVLINK_MSG_ID_HEARTBEAT
                and self.heartbeats):
            self._send(heartbeat(mode, armed))
