"""A MAVLink vehicle (ArduPilot Rover or Copter, PX4) as the homing loop's robot base: body
velocity setpoints out, odometry in (rfhoming.protocol.mavlink, cited in docs/protocol.md).

Safety first. The driver never arms a vehicle unless the user asked (``arm=1``) and never takes
over from a pilot: a vehicle in a manual mode (MANUAL, STABILIZE, POSCTL ...) ends the run with
one line saying how to switch. Otherwise it puts the vehicle in GUIDED (ArduPilot) or OFFBOARD
(PX4, after streaming zero setpoints, as PX4 requires), then sends one setpoint per loop command
-- one per odometry, well above the rate each autopilot needs to keep moving. A vehicle that
leaves that mode (the pilot's switch, a failsafe) gets no more setpoints and ends the run. When
the run ends it is sent zero velocity and then HOLD (Rover, PX4) or BRAKE (Copter). If the host
dies, the autopilot's own setpoint timeout (GUID_TIMEOUT, COM_OF_LOSS_T) stops it.

Every write follows an input (a vehicle HEARTBEAT is answered with the ground station's; each
setpoint follows an odometry), so a replay of the capture writes the same bytes.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from rfhoming.host.drivers.common import BoundedStream
from rfhoming.host.drivers.robot import CommandedBase, Pose2D
from rfhoming.host.mavlinkport import MavlinkPort
from rfhoming.host.ports import Disconnected, Tap
from rfhoming.host.portspec import PortSpec
from rfhoming.protocol import mavlink as ml
from rfhoming.protocol.errors import Error

log = logging.getLogger(__name__)

SETUP_TIMEOUT_S = 5.0  # *assumed*: from the first HEARTBEAT to driving (two commands answered)
TELEMETRY_HZ = 50  # LOCAL_POSITION_NED and ATTITUDE, asked of the vehicle: the loop's odometry rate
STREAM_BEFORE_SWITCH_S = 1.0  # PX4 enables offboard after more than a second of setpoints (PX4 Offboard Mode)


class _SetUp(asyncio.Event):
    """``connected`` of a vehicle: set when it is set up to be driven, not when its port opens
    (the loop starts on it, and its odometry watchdog with it), as a ROS 2 base's port opens at
    its first odometry."""

    def set(self) -> None:  # the port's open (Driver._run)
        pass

    def ready(self) -> None:
        super().set()


class VehicleError(Error):
    """The vehicle cannot be driven as it is (mode, arming, a refused command); one line says what to do."""


class MavlinkBaseDriver(CommandedBase):
    kind = "mavlink"
    sets_up = True
    watchdog = "the autopilot's setpoint timeout (GUID_TIMEOUT / COM_OF_LOSS_T)"

    def __init__(self, port: Any, *, sysid: int | None = None, compid: int | None = None, arm: bool = False,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out)
        self.codec = ml.Codec()
        self.sysid, self.compid, self.arm = sysid, compid, arm
        self.autopilot: ml.Autopilot | None = None
        self.mode: int | None = None
        self.armed = False
        self.time_boot_ms = 0
        self._attitude: Any = None
        self._local: tuple[Any, float] | None = None  # the newest LOCAL_POSITION_NED and when it came
        self._heartbeat = asyncio.Event()
        self.step = "waiting"  # of the set-up: waiting, streaming, switching, arming, driving, failed, done
        self._asked: int | None = None  # the command whose COMMAND_ACK the set-up waits for
        self._heartbeat_asked = False
        self._stream_from: int | None = None  # PX4: time_boot_ms of the first zero setpoint before the switch
        self.connected: _SetUp = _SetUp()
        self.speaks_first = bool(getattr(port, "speaks_first", False)
                                 or getattr(port, "description", {}).get("speaks_first") == "1")
        self.counters.update(packets=0, bad_packets=0, heartbeats=0, other_systems=0)

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> MavlinkBaseDriver:
        s = spec.settings
        if port is None:
            port = MavlinkPort(spec.where, baud=spec.baud or 57600, name=spec.name or spec.where, taps=taps,
                               expose=s.get("expose", False))
        options.pop("command_timeout_ms", None)  # the autopilot's own timeout applies (GUID_TIMEOUT, COM_OF_LOSS_T)
        return cls(port, sysid=s.get("sysid"), compid=s.get("compid"), arm=s.get("arm", False), **options)

    @staticmethod
    def describe_spec(spec: PortSpec) -> dict[str, str]:
        """What a capture's interface records: whether this end spoke first (a replay writes it too)."""
        return {"speaks_first": str(int(MavlinkPort.speaks_first_on(spec.where)))}

    def silent_hint(self) -> str:
        return ("no MAVLink HEARTBEAT: is the vehicle (or SITL) sending to this address, and is the connection "
                "string the one its telemetry port or MAVProxy --out uses?")

    # -- inbound: every set-up step follows a message, so a replay takes the same steps ----------

    def on_chunk(self, data: bytes, t_host: float) -> None:
        before = self.codec.bad
        for message in self.codec.feed(data):
            self._on_message(message, t_host)
        if self.codec.bad > before:
            self.counters["bad_packets"] += self.codec.bad - before
            self.emit(t_host, {"kind": "drop", "why": "corrupt MAVLink packet"})

    def _ours(self, message: Any) -> bool:
        """From the vehicle being driven (its ids given, or those of the first vehicle heard)."""
        system, component = message.get_srcSystem(), message.get_srcComponent()
        return system == self.sysid and (self.compid is None or component == self.compid)

    def _on_message(self, message: Any, t_host: float) -> None:
        kind = message.get_type()
        if kind == "HEARTBEAT" and self.sysid is None and ml.is_vehicle(message):
            self.sysid = message.get_srcSystem()
        elif self.step == "waiting" and not self._heartbeat_asked and ml.from_autopilot(message, self.sysid):
            self._heartbeat_asked = True  # its telemetry came first: ask for its HEARTBEAT now, not within a second
            self._send(ml.request_message(message.get_srcSystem(), message.get_srcComponent(), ml.mav.MAVLINK_MSG_ID_HEARTBEAT),
                       counted=False)
        if not self._ours(message):
            self.counters["other_systems"] += 1
            return
        self.counters["packets"] += 1
        if self.step == "failed":
            return
        if kind == "HEARTBEAT" and ml.is_vehicle(message):
            self._on_heartbeat(message)
        elif kind == "COMMAND_ACK" and message.command == self._asked:
            self._on_ack(message)
        elif kind == "ATTITUDE":
            self._attitude = message
        elif kind == "LOCAL_POSITION_NED" and self._attitude is not None:
            self._on_position(message, t_host)

    def _on_heartbeat(self, message: Any) -> None:
        self.counters["heartbeats"] += 1
        if self.compid is None:
            self.compid = message.get_srcComponent()
        try:
            ap = self.autopilot = ml.autopilot_of(message)
        except ml.UnknownAutopilot as exc:
            self._fail(f"the vehicle is {exc}")
            return
        self.mode, self.armed = message.custom_mode, ml.armed(message)
        self._heartbeat.set()
        self._send(ml.gcs_heartbeat(), counted=False)  # a ground station is there: the GCS failsafe's input
        if self.step == "waiting":
            self._begin()
        elif self.step == "driving" and self.mode != ap.guided:
            self._fail(f"the vehicle left {ap.mode_name(ap.guided)} for {ap.mode_name(self.mode)} (the pilot or a "
                       "failsafe took over); rfhoming stopped sending setpoints")
        elif self.step == "driving" and not self.armed:
            self._fail("the vehicle disarmed; rfhoming stopped sending setpoints")

    def _begin(self) -> None:
        """The first HEARTBEAT: ask for odometry, check the vehicle may be driven, then switch
        it to the guided mode (PX4: after a second of setpoints) and arm it if asked."""
        ap, system, component = self.autopilot, self.sysid, self.compid or 0
        assert ap is not None and system is not None and self.mode is not None
        self.problem = f"setting up the {ap.name} vehicle (system {system})"
        for message_id in (ml.mav.MAVLINK_MSG_ID_ATTITUDE, ml.mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
            self._send(ml.message_interval(system, component, message_id, TELEMETRY_HZ))
        if self.mode in ap.manual:
            self._fail(f"the vehicle is in {ap.mode_name(self.mode)}, a pilot's mode: rfhoming does not take over "
                       f"from a pilot; switch it to {ap.mode_name(ap.hold)} (or {ap.mode_name(ap.guided)}) on the "
                       "transmitter or ground station, then start again")
        elif not self.armed and not self.arm:
            self._fail("the vehicle is disarmed and rfhoming arms only when asked: arm it yourself, or add ,arm=1 "
                       "to the port spec")
        elif self.mode != ap.guided and ap.stream_before_switch:
            self.step = "streaming"  # _on_position sends the setpoints, then the switch
        elif self.mode != ap.guided:
            self._ask(ml.set_mode(system, component, ap, ap.guided), "switching")
        elif not self.armed:
            self._ask(ml.arm(system, component), "arming")
        else:
            self._drive()

    def _on_ack(self, message: Any) -> None:
        assert self.autopilot is not None and self.sysid is not None
        what = {"switching": f"mode {self.autopilot.mode_name(self.autopilot.guided)}", "arming": "arming (arm=1)"}
        if message.result not in (ml.mav.MAV_RESULT_ACCEPTED, ml.mav.MAV_RESULT_IN_PROGRESS):
            self._fail(f"the vehicle refused {what.get(self.step, self.step)} ({ml.result_name(message.result)}); "
                       "its ground station's messages say why (pre-arm checks, EKF, geofence)")
        elif self.step == "switching" and not self.armed:
            self._ask(ml.arm(self.sysid, self.compid or 0), "arming")
        else:  # accepted: the vehicle is in the guided mode and armed (a later HEARTBEAT that says otherwise ends the run)
            self._asked, self.armed, self.mode = None, True, self.autopilot.guided
            self._drive()

    def _ask(self, message: Any, step: str) -> None:
        self._asked, self.step = message.command, step
        self._send(message)

    def _drive(self) -> None:
        """Set up: the loop starts (``connected``) with the newest odometry already in its stream."""
        self.step, self.state, self.problem = "driving", "streaming", None
        if self._local is not None:
            self._emit_pose(*self._local)
        self.connected.ready()

    def _on_position(self, local: Any, t_host: float) -> None:
        self.time_boot_ms = local.time_boot_ms
        self._local = (local, t_host)
        if self.step == "driving":
            self._emit_pose(local, t_host)
        elif self.step == "streaming":  # PX4 engages offboard only on a stream that is already there
            assert self.autopilot is not None and self.sysid is not None
            self._setpoint(0.0, 0.0)
            self._stream_from = self.time_boot_ms if self._stream_from is None else self._stream_from
            if self.time_boot_ms - self._stream_from >= STREAM_BEFORE_SWITCH_S * 1000:
                self._ask(ml.set_mode(self.sysid, self.compid or 0, self.autopilot, self.autopilot.guided), "switching")

    def _emit_pose(self, local: Any, t_host: float) -> None:
        pose = ml.pose_of(local, self._attitude)
        item = Pose2D(t_host, local.time_boot_ms / 1000, pose.x, pose.y, pose.theta, pose.v, pose.w, 0)
        self.latest = item
        self.emit(t_host, item)
        self.out.put(item)

    def _fail(self, why: str) -> None:
        self.step, self.state, self.problem = "failed", "setup_failed", why
        self.error = VehicleError(why)  # the supervisor ends the run with it, naming the port
        log.error("%s: %s", self.port.name, why)

    # -- outbound --------------------------------------------------------------------------

    def _send(self, message: Any, *, counted: bool = True) -> bool:
        try:
            self.port.write(self.codec.encode(message))
        except Disconnected:
            if counted:
                self.counters["unsent"] += 1
            return False
        return True

    def _setpoint(self, v: float, w: float) -> bool:
        assert self.autopilot is not None and self.sysid is not None
        return self._send(ml.velocity_setpoint(self.time_boot_ms, self.sysid, self.compid or 0,
                                               self.autopilot.frame, v, w))

    def send_velocity(self, v: float, w: float) -> bool:
        """A body velocity setpoint (v m/s forward, ω rad/s counter-clockwise); False (counted)
        while the vehicle is not in rfhoming's hands (not set up, or taken over)."""
        if self.step != "driving":
            self.counters["unsent"] += 1
            return False
        sent = self._setpoint(v, w)
        self.counters["commands"] += sent
        return sent

    async def session(self) -> None:
        """After every open: say hello where this end must speak first, then wait for the set-up
        (done message by message in :meth:`on_chunk`); one that stalls fails the run, saying where."""
        if self.speaks_first:  # udpout:, tcp:: the vehicle learns of this end from its first packet
            self._send(ml.gcs_heartbeat(), counted=False)
        await self._heartbeat.wait()
        try:
            async with asyncio.timeout(SETUP_TIMEOUT_S):
                await self.connected.wait()
        except TimeoutError:
            if self.step != "failed":
                stalled = {"streaming": "streaming setpoints before the switch",
                           "switching": f"no COMMAND_ACK to {ml.command_name(self._asked or 0)}",
                           "arming": f"no COMMAND_ACK to {ml.command_name(self._asked or 0)}"}
                self._fail(f"set-up stalled after {SETUP_TIMEOUT_S:g} s: {stalled.get(self.step, self.step)}; is the "
                           "link two-way (the vehicle hears this end), and the vehicle's telemetry on?")

    async def __aexit__(self, *exc: Any) -> None:
        """Zero velocity, then the autopilot's holding mode (the loop's own stops stay in guided mode)."""
        if self.step != "driving":  # never driven (or taken over): nothing of rfhoming's to stop
            return
        await super().__aexit__(*exc)
        if self.autopilot is not None and self.sysid is not None:
            self.step = "done"
            self._send(ml.set_mode(self.sysid, self.compid or 0, self.autopilot, self.autopilot.hold))
