"""A MAVLink vehicle (ArduPilot Rover or Copter, PX4) as the homing loop's robot base: body
velocity setpoints out, odometry in (rfhoming.protocol.mavlink, cited in docs/protocol.md).

Safety first. The driver never arms a vehicle unless the user asked (``arm=1``) and never takes
over from a pilot: a vehicle in a manual mode (MANUAL, STABILIZE, POSCTL ...) ends the run with
one line saying how to switch. Otherwise it puts the vehicle in GUIDED (ArduPilot) or OFFBOARD
(PX4, after streaming zero setpoints, as PX4 requires), then sends one setpoint per loop command
-- one per odometry, well above the rate each autopilot needs to keep moving. If the host dies,
the autopilot's own setpoint timeout (GUID_TIMEOUT, COM_OF_LOSS_T) stops it.

It drives one vehicle, and believes nothing else: the first vehicle HEARTBEAT (or ``sysid=``)
fixes the system and component it listens to, a UDP link the address (host/mavlinkport.py).
A vehicle that leaves the guided mode or disarms (a ground station's mode change, the pilot's
switch, a failsafe) is taken over: no more setpoints, and no mode command either -- the mode
someone else chose stands; the loop ends the run on the TakenOver item, which its log and
summary record. Each of these ends the run with one line (an Error the supervisor raises):

- its HEARTBEAT stops for ``HEARTBEAT_LOSS_S`` of its own clock while its telemetry goes on, or
  (live) the vehicle falls silent for that long on the wall clock;
- it sends a value no vehicle can mean (NaN, inf, 1e38: rfhoming.protocol.mavlink.refusal);
- another sender speaks as the vehicle (its system and component ids, from another address);
- a second vehicle speaks before the driving starts and ``sysid=`` did not say which to drive
  (after, it is ignored: counted, warned once);
- a command is refused or unanswered during the set-up.

Every exit after rfhoming asked for the guided mode (or, the vehicle already in it, to arm) -- an
error, a refused arming, the end of the run, Ctrl-C, SIGTERM -- sends zero velocity and then the
holding mode: HOLD (Rover, PX4) or BRAKE (Copter), or the spec's ``end=``.

Every write follows an input, so a replay of the capture writes the same bytes. During the
set-up each follows a message the driver reads (a vehicle HEARTBEAT is answered with the ground
station's). Once driving, every write is the loop's and carries the odometry the loop acts on
(:meth:`acting_on`), never the newest the driver read: the capture stamps a datagram when it
came, and how many came before the loop took its odometry is the machine's load live and the
recording's order in a replay. So the setpoints carry that odometry's ``time_boot_ms``, and the
ground station's HEARTBEAT goes out once a second of the vehicle's clock, with the first of the
loop's odometries in it, not when the vehicle's came in.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from typing import Any

from rfhoming.host.drivers.common import BoundedStream, Wiring
from rfhoming.host.drivers.robot import CommandedBase, Pose2D, TakenOver
from rfhoming.host.mavlinkport import MavlinkPort
from rfhoming.host.ports import Disconnected, Tap
from rfhoming.host.portspec import PortSpec
from rfhoming.protocol import mavlink as ml
from rfhoming.protocol.errors import Error

log = logging.getLogger(__name__)

SETUP_TIMEOUT_S = 5.0  # *assumed*: from the first HEARTBEAT to driving (two commands answered)
TELEMETRY_HZ = 50  # LOCAL_POSITION_NED and ATTITUDE, asked of the vehicle: the loop's odometry rate
STREAM_BEFORE_SWITCH_S = 1.0  # PX4 enables offboard after more than a second of setpoints (PX4 Offboard Mode)
HEARTBEAT_PERIOD_S = 1.0  # ArduPilot and PX4 send HEARTBEAT at 1 Hz (docs/protocol.md §10)
ENDED = ("failed", "done", "taken")  # the set-up's steps after which nothing more is sent or believed
HEARTBEAT_LOSS_S = 3.5
"""Three HEARTBEATs missed, and half a period for jitter: the link is lost (MAVLink's heartbeat
service calls a system gone after four or five missed; a vehicle being driven, sooner)."""


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

    @classmethod
    def options(cls, wiring: Wiring) -> dict[str, Any]:
        """A live run watches the vehicle's silence on the wall clock too; lockstep runs and
        replays (the loop's wall-clock watchdog off) only on the vehicle's own clock."""
        live = wiring.config is None or not math.isinf(wiring.config.loop.odometry_wall_timeout_s)
        return {"silence_s": HEARTBEAT_LOSS_S if live else None}

    def __init__(self, port: Any, *, sysid: int | None = None, compid: int | None = None, arm: bool = False,
                 end: str | None = None, datagrams: bool = False, silence_s: float | None = HEARTBEAT_LOSS_S,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out)
        self.codec = ml.Codec()
        self.sysid, self.compid, self.arm, self.end = sysid, compid, arm, end
        self.chosen = sysid is not None  # the user named the vehicle: a second one is no doubt about which
        self.datagrams = datagrams  # each chunk is a whole datagram (a UDP link): no packet spans two
        self.silence_s = silence_s
        self.autopilot: ml.Autopilot | None = None
        self.mode: int | None = None
        self.armed = False
        self.time_boot_ms = 0  # the newest odometry's the driver read
        self._acting_ms: int | None = None  # the odometry's the loop acts on (acting_on): what setpoints carry
        self._beat_second: int | None = None  # the vehicle's second of the ground station's last HEARTBEAT, driving
        self._attitude: Any = None
        self._local: tuple[Any, float] | None = None  # the newest LOCAL_POSITION_NED and when it came
        self._heartbeat = asyncio.Event()
        self.step = "waiting"  # of the set-up: waiting, streaming, switching, arming, driving, then one of ENDED
        self.took = False  # rfhoming asked for the guided mode, to arm, or drove: every exit leaves the vehicle holding
        self.taken_over = False  # the pilot or a failsafe changed its mode or disarmed it: their choice stands
        self._asked: int | None = None  # the command whose COMMAND_ACK the set-up waits for
        self._heartbeat_asked = False
        self._stream_from: int | None = None  # PX4: time_boot_ms of the first zero setpoint before the switch
        self._beat_ms: int | None = None  # the vehicle's clock at its first telemetry after its last HEARTBEAT
        self._heard_at = time.monotonic()  # the wall clock when the vehicle last spoke
        self._others: set[str] = set()  # the other vehicles warned of
        self._foreign = ml.Codec()  # reads datagrams of other senders (host/mavlinkport.py)
        self.connected: _SetUp = _SetUp()
        self.speaks_first = bool(getattr(port, "speaks_first", False)
                                 or getattr(port, "description", {}).get("speaks_first") == "1")
        if hasattr(port, "on_foreign"):
            port.on_foreign = self._on_foreign
        self.counters.update(packets=0, bad_packets=0, junk_bytes=0, unknown_messages=0, refused_values=0,
                             heartbeats=0, other_systems=0)

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> MavlinkBaseDriver:
        s = spec.settings
        if port is None:
            port = MavlinkPort(spec.where, baud=spec.baud or 57600, name=spec.name or spec.where, taps=taps,
                               expose=s.get("expose", False), sysid=s.get("sysid"))
        options.pop("command_timeout_ms", None)  # the autopilot's own timeout applies (GUID_TIMEOUT, COM_OF_LOSS_T)
        return cls(port, sysid=s.get("sysid"), compid=s.get("compid"), arm=s.get("arm", False), end=s.get("end"),
                   datagrams=MavlinkPort.datagrams_on(spec.where), **options)

    @staticmethod
    def describe_spec(spec: PortSpec) -> dict[str, str]:
        """What a capture's interface records: whether this end spoke first (a replay writes it too)."""
        return {"speaks_first": str(int(MavlinkPort.speaks_first_on(spec.where)))}

    def silent_hint(self) -> str:
        return ("no MAVLink HEARTBEAT: is the vehicle (or SITL) sending to this address, and is the connection "
                "string the one its telemetry port or MAVProxy --out uses?")

    # -- inbound: every set-up step follows a message, so a replay takes the same steps ----------

    def on_chunk(self, data: bytes, t_host: float) -> None:
        codec = self.codec
        before = codec.bad
        for item in codec.feed(data, datagram=self.datagrams):
            if isinstance(item, ml.Refused):
                self._on_refused(item)
            else:
                self._on_message(item, t_host)
        self.counters.update(bad_packets=codec.bad, junk_bytes=codec.junk, unknown_messages=codec.unknown,
                             refused_values=codec.refused)
        if codec.bad > before:
            self.emit(t_host, {"kind": "drop", "why": "corrupt MAVLink packet"})

    def _ours(self, message: Any) -> bool:
        """From the vehicle being driven (its ids given, or those of the first vehicle heard)."""
        system, component = message.get_srcSystem(), message.get_srcComponent()
        return system == self.sysid and (self.compid is None or component == self.compid)

    def _on_message(self, message: Any, t_host: float) -> None:
        kind = message.get_type()
        vehicle = kind == "HEARTBEAT" and ml.is_vehicle(message)
        if vehicle and self.sysid is None:
            self.sysid = message.get_srcSystem()
        elif self.step == "waiting" and not self._heartbeat_asked and ml.from_autopilot(message, self.sysid):
            self._heartbeat_asked = True  # its telemetry came first: ask for its HEARTBEAT now, not within a second
            self._send(ml.request_message(message.get_srcSystem(), message.get_srcComponent(), ml.mav.MAVLINK_MSG_ID_HEARTBEAT),
                       counted=False)
        if not self._ours(message):
            self.counters["other_systems"] += 1
            if vehicle:
                self._second_vehicle(message, "on this link")
            return
        self.counters["packets"] += 1
        self._heard_at = time.monotonic()
        if self.step in ENDED:
            return
        if vehicle:
            self._on_heartbeat(message, t_host)
        elif kind == "COMMAND_ACK" and message.command == self._asked:
            self._on_ack(message)
        elif kind == "ATTITUDE":
            self._attitude = message
        elif kind == "LOCAL_POSITION_NED" and self._attitude is not None:
            self._on_position(message, t_host)

    def _on_refused(self, refused: ml.Refused) -> None:
        """A value no vehicle can mean, from the vehicle: its estimate cannot be driven on."""
        if self.sysid is None or not self._ours(refused.message):
            self.counters["other_systems"] += 1
        elif self.step not in ENDED:
            self._fail(f"the vehicle sent {refused.why}: its position or attitude cannot be driven on (check its "
                       "EKF and position source); rfhoming stopped")

    def _on_foreign(self, source: tuple[str, int], data: bytes) -> None:
        """A datagram from a sender that is not the vehicle (dropped by the port, counted there)."""
        if self.step in ENDED or self.sysid is None:
            return
        for item in self._foreign.feed(data, datagram=True):
            message = item.message if isinstance(item, ml.Refused) else item
            if self._ours(message):
                self._fail(f"another sender, {source[0]}:{source[1]}, speaks as the vehicle (system {self.sysid}) "
                           "beside it: rfhoming drives only a vehicle it can tell apart; if two vehicles share one "
                           "system id, give each its own (ArduPilot SYSID_THISMAV, PX4 MAV_SYS_ID)")
                return
            if message.get_type() == "HEARTBEAT" and ml.is_vehicle(message):
                self._second_vehicle(message, f"at {source[0]}:{source[1]}")

    def _second_vehicle(self, heartbeat: Any, where: str) -> None:
        """Another vehicle speaks: before the driving starts, with no ``sysid=``, there is no
        telling which one the user meant; after it, it is ignored (warned once)."""
        who = f"system {heartbeat.get_srcSystem()} component {heartbeat.get_srcComponent()}"
        if who in self._others or self.step in ENDED:
            return
        self._others.add(who)
        if self.step != "driving" and not self.chosen:
            self._fail(f"two vehicles speak ({who} {where}, besides system {self.sysid}): name the one to drive "
                       "with ,sysid=N in the port spec")
        else:
            log.warning("%s: another vehicle, %s, speaks %s: ignored (rfhoming drives system %s only)",
                        self.port.name, who, where, self.sysid)

    def _on_heartbeat(self, message: Any, t_host: float) -> None:
        self.counters["heartbeats"] += 1
        self._beat_ms = None  # heartbeat loss counts from the next telemetry
        if self.compid is None:
            self.compid = message.get_srcComponent()
        try:
            ap = self.autopilot = ml.autopilot_of(message)
        except ml.UnknownAutopilot as exc:
            self._fail(f"the vehicle is {exc}")
            return
        self.mode, self.armed = message.custom_mode, ml.armed(message)
        self._heartbeat.set()
        if self.step != "driving":  # driving, the loop's odometry says when (acting_on)
            self._send(ml.gcs_heartbeat(), counted=False)  # a ground station is there: the GCS failsafe's input
        if self.step == "waiting":
            self._begin()
        elif self.step == "driving" and self.mode != ap.guided:
            self._taken(ap.mode_name(self.mode), f"the vehicle left {ap.mode_name(ap.guided)} for "
                        f"{ap.mode_name(self.mode)} (a ground station, the pilot or a failsafe took over); rfhoming "
                        "stopped sending setpoints and leaves it there", t_host)
        elif self.step == "driving" and not self.armed:
            self._taken("disarmed", "the vehicle disarmed (a ground station, the pilot or a failsafe); rfhoming "
                        "stopped sending setpoints", t_host)

    def _taken(self, mode: str, why: str, t_host: float) -> None:
        """Someone else has the vehicle: nothing more is sent, and the loop ends the run on the
        item (its log and summary say so), in the order of the vehicle's messages."""
        self.step, self.taken_over = "taken", True
        log.info("%s: %s", self.port.name, why)
        item = TakenOver(t_host, mode, why)
        self.emit(item.t_host, item)
        self.out.put(item)

    def _begin(self) -> None:
        """The first HEARTBEAT: ask for odometry, check the vehicle may be driven, then switch
        it to the guided mode (PX4: after a second of setpoints) and arm it if asked."""
        ap, system, component = self.autopilot, self.sysid, self.compid or 0
        assert ap is not None and system is not None and self.mode is not None
        self.problem = f"setting up the {ap.name} vehicle (system {system})"
        for message_id in (ml.mav.MAVLINK_MSG_ID_ATTITUDE, ml.mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
            self._send(ml.message_interval(system, component, message_id, TELEMETRY_HZ))
        try:
            ap.end_mode(self.end)
        except ValueError as exc:
            self._fail(str(exc))
            return
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
            self._switch()
        elif not self.armed:  # already in the guided mode: arming is rfhoming's first command that takes it
            self.took = True
            self._ask(ml.arm(system, component), "arming")
        else:
            self._drive()

    def _switch(self) -> None:
        """Ask for the guided mode: from here on, every exit leaves the vehicle holding."""
        assert self.autopilot is not None and self.sysid is not None
        self.took = True
        self._ask(ml.set_mode(self.sysid, self.compid or 0, self.autopilot, self.autopilot.guided), "switching")

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
        """Set up: the loop starts (``connected``) with the newest odometry already in its stream,
        and acts on it (its first stop carries it) until it takes the next."""
        self.step, self.state, self.problem, self.took = "driving", "streaming", None, True
        self._acting_ms = self.time_boot_ms
        if self._local is not None:
            self._emit_pose(*self._local)
        self.connected.ready()

    def acting_on(self, odometry: Pose2D) -> None:
        """The loop acts on ``odometry``: its setpoints carry its ``time_boot_ms``; the first of a
        second of the vehicle's clock brings the ground station's HEARTBEAT (1 Hz, as the
        vehicle's own) -- so the bytes written follow the loop's odometry alone."""
        super().acting_on(odometry)
        ms = round(odometry.t_robot * 1000)
        self._acting_ms = ms
        if self.step == "driving" and ms // 1000 != self._beat_second:  # a rebooted clock starts a second too
            self._beat_second = ms // 1000
            self._send(ml.gcs_heartbeat(), counted=False)

    def _on_position(self, local: Any, t_host: float) -> None:
        self._check_heartbeat(local.time_boot_ms)
        self.time_boot_ms = local.time_boot_ms
        self._local = (local, t_host)
        if self.step == "driving":
            self._emit_pose(local, t_host)
        elif self.step == "streaming":  # PX4 engages offboard only on a stream that is already there
            self._setpoint(0.0, 0.0, self.time_boot_ms)
            self._stream_from = self.time_boot_ms if self._stream_from is None else self._stream_from
            if self.time_boot_ms - self._stream_from >= STREAM_BEFORE_SWITCH_S * 1000:
                self._switch()

    def _check_heartbeat(self, time_boot_ms: int) -> None:
        """Telemetry goes on: has the vehicle's HEARTBEAT stopped (on the vehicle's own clock, so a
        replay and a lockstep world decide the same)?"""
        if self._beat_ms is None or time_boot_ms < self._beat_ms:  # after a HEARTBEAT, or a reboot's clock
            self._beat_ms = time_boot_ms
        elif time_boot_ms - self._beat_ms > HEARTBEAT_LOSS_S * 1000 and self.step != "waiting" and self.step not in ENDED:
            self._fail(f"no HEARTBEAT from the vehicle for {HEARTBEAT_LOSS_S:g} s of its clock while its telemetry "
                       f"goes on (it sends one a second): its link or autopilot is not well; rfhoming stopped")

    def _emit_pose(self, local: Any, t_host: float) -> None:
        pose = ml.pose_of(local, self._attitude)
        item = Pose2D(t_host, local.time_boot_ms / 1000, pose.x, pose.y, pose.theta, pose.v, pose.w, 0)
        self.latest = item
        self.emit(t_host, item)
        self.out.put(item)

    def _fail(self, why: str) -> None:
        """The run ends: the supervisor raises the error (one line, naming the port)."""
        self.step, self.state, self.problem = "failed", "setup_failed", why
        self.error = VehicleError(why)
        log.info("%s: %s", self.port.name, why)

    # -- outbound --------------------------------------------------------------------------

    def _send(self, message: Any, *, counted: bool = True) -> bool:
        try:
            self.port.write(self.codec.encode(message))
        except Disconnected:
            if counted:
                self.counters["unsent"] += 1
            return False
        return True

    def _setpoint(self, v: float, w: float, time_boot_ms: int) -> bool:
        assert self.autopilot is not None and self.sysid is not None
        return self._send(ml.velocity_setpoint(time_boot_ms, self.sysid, self.compid or 0, self.autopilot.frame, v, w))

    @property
    def _loop_ms(self) -> int:
        """What the loop's setpoints carry: the time of the odometry it acts on (the driver's
        newest before the driving began, as the set-up's own zero setpoints do)."""
        return self.time_boot_ms if self._acting_ms is None else self._acting_ms

    def send_velocity(self, v: float, w: float) -> bool:
        """A body velocity setpoint (v m/s forward, ω rad/s counter-clockwise); False (counted)
        while the vehicle is not in rfhoming's hands (not set up, or taken over)."""
        if self.step != "driving":
            self.counters["unsent"] += 1
            return False
        sent = self._setpoint(v, w, self._loop_ms)
        self.counters["commands"] += sent
        return sent

    async def session(self) -> None:
        """After every open: say hello where this end must speak first, then wait for the set-up
        (done message by message in :meth:`on_chunk`); one that stalls fails the run, saying where.
        Then, live, watch for the vehicle falling silent."""
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
            return
        while self.silence_s is not None and self.step == "driving":
            await asyncio.sleep(self.silence_s / 4)
            if time.monotonic() - self._heard_at > self.silence_s and self.step == "driving":
                self._fail(f"the vehicle has said nothing for {self.silence_s:g} s (no HEARTBEAT, no telemetry): "
                           "its link is lost; rfhoming stopped")

    async def __aexit__(self, *exc: Any) -> None:
        """However the run ends, once rfhoming asked for the guided mode: zero velocity, then the
        holding mode (or ``end=``). Not when the pilot or a failsafe took the vehicle: their mode stands."""
        if not self.took or self.taken_over or self.autopilot is None or self.sysid is None:
            return
        self.step = "done"
        self.counters["stops"] += 1
        stopped = self._setpoint(0.0, 0.0, self._loop_ms)
        end = self.autopilot.end_mode(self.end)
        if not (self._send(ml.set_mode(self.sysid, self.compid or 0, self.autopilot, end)) and stopped):
            log.warning("%s: could not send the final stop and %s; %s stops the vehicle", self.port.name,
                        self.autopilot.mode_name(end), self.watchdog)
        await asyncio.sleep(0)
