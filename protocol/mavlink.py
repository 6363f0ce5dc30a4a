"""MAVLink for a vehicle driven by velocity: the wire (pymavlink's generated MAVLink 2 common
dialect), the autopilots' modes, and the frame conversions, sans-IO.

Every fact here is cited in docs/protocol.md, "MAVLink vehicles". The vehicle's frames are NED
(local position, from the EKF origin) and FRD (body); rfhoming's are REP 103 ENU (odom) and
FLU (base_link). :func:`pose_of` and :func:`ned_of` are the one place they are converted, both
ways (the emulated vehicle uses the second).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

from pymavlink.dialects.v20 import common as _common  # type: ignore[import-untyped]

from rfhoming.protocol.errors import Error

mav = _common  # the generated MAVLink 2 dialect, for the driver and the emulated vehicle

GCS_SYSTEM = 255  # a ground station's customary system id
GCS_COMPONENT = mav.MAV_COMP_ID_ONBOARD_COMPUTER  # a companion computer driving the vehicle

VELOCITY_AND_YAW_RATE = 0x05E7
"""POSITION_TARGET_TYPEMASK: velocity and yaw rate used, position, acceleration and yaw ignored
(ArduPilot "Rover Commands in Guided Mode": Use Vel+Yaw Rate, 1511)."""

IGNORE_VELOCITY = 0b11000  # POSITION_TARGET_TYPEMASK bits 3 and 4: vx, vy ignored (a rover ignores vz)
IGNORE_YAW_RATE = 0x800  # bit 11

PX4_OFFBOARD, PX4_AUTO, PX4_AUTO_LOITER = 6, 4, 3  # PX4 custom main mode / AUTO sub mode (px4_custom_mode.h)


@dataclass(frozen=True)
class Autopilot:
    """What rfhoming needs to know of one autopilot's vehicle type."""

    name: str
    modes: dict[int, str]  # custom_mode -> name
    guided: int  # the mode velocity setpoints drive
    hold: int  # where the vehicle is left when the run ends (stopped, holding)
    manual: frozenset[int]  # a pilot is driving: rfhoming refuses to take over
    frame: int  # MAV_FRAME of body-relative velocity setpoints
    body_frames: frozenset[int]  # the frames it reads body-relative velocity in
    stream_before_switch: bool  # setpoints must be streaming before the switch to ``guided`` (PX4)
    command_timeout_s: float  # the autopilot stops a vehicle whose setpoints stop this long (default)
    timeout_parameter: str

    def mode_name(self, custom_mode: int) -> str:
        return self.modes.get(custom_mode, f"mode {custom_mode}")

    def end_mode(self, name: str | None) -> int:
        """The mode the vehicle is left in: ``name`` (a spec's ``end=``), else :attr:`hold`.
        ValueError when ``name`` is not one of its modes, or one that needs a pilot or takes
        setpoints (then nothing would hold the vehicle)."""
        if name is None:
            return self.hold
        number = next((n for n, m in self.modes.items() if m == name), None)
        if number is None or number in self.manual or number == self.guided:
            allowed = ", ".join(m for n, m in self.modes.items() if n not in self.manual and n != self.guided)
            raise ValueError(f"end={name} is not a mode {self.name} can be left in; one of {allowed}")
        return number


def _px4(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


ARDUPILOT_BODY = frozenset({mav.MAV_FRAME_BODY_NED, mav.MAV_FRAME_BODY_OFFSET_NED})
ARDUPILOT_ROVER = Autopilot(
    "ArduPilot Rover",
    {0: "MANUAL", 1: "ACRO", 3: "STEERING", 4: "HOLD", 5: "LOITER", 6: "FOLLOW", 7: "SIMPLE", 8: "DOCK",
     9: "CIRCLE", 10: "AUTO", 11: "RTL", 12: "SMART_RTL", 15: "GUIDED", 16: "INITIALISING"},
    guided=15, hold=4, manual=frozenset({0, 1, 3}), frame=mav.MAV_FRAME_BODY_OFFSET_NED, body_frames=ARDUPILOT_BODY,
    stream_before_switch=False, command_timeout_s=3.0, timeout_parameter="GUID_TIMEOUT")
ARDUPILOT_COPTER = Autopilot(
    "ArduPilot Copter",
    {0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL", 7: "CIRCLE",
     9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 16: "POSHOLD", 17: "BRAKE"},
    guided=4, hold=17, manual=frozenset({0, 1, 2, 5, 11, 13, 14, 16}), frame=mav.MAV_FRAME_BODY_OFFSET_NED, body_frames=ARDUPILOT_BODY,
    stream_before_switch=False, command_timeout_s=3.0, timeout_parameter="GUID_TIMEOUT")
PX4 = Autopilot(
    "PX4",
    {_px4(1): "MANUAL", _px4(2): "ALTCTL", _px4(3): "POSCTL", _px4(PX4_AUTO, PX4_AUTO_LOITER): "HOLD",
     _px4(PX4_AUTO, 4): "MISSION", _px4(PX4_AUTO, 5): "RTL", _px4(PX4_AUTO, 6): "LAND", _px4(5): "ACRO",
     _px4(PX4_OFFBOARD): "OFFBOARD", _px4(7): "STABILIZED"},
    guided=_px4(PX4_OFFBOARD), hold=_px4(PX4_AUTO, PX4_AUTO_LOITER),
    manual=frozenset({_px4(1), _px4(2), _px4(3), _px4(5), _px4(7)}), frame=mav.MAV_FRAME_BODY_NED,
    body_frames=frozenset({mav.MAV_FRAME_BODY_NED}), stream_before_switch=True, command_timeout_s=1.0, timeout_parameter="COM_OF_LOSS_T")

COPTERS = {mav.MAV_TYPE_QUADROTOR, mav.MAV_TYPE_HEXAROTOR, mav.MAV_TYPE_OCTOROTOR, mav.MAV_TYPE_TRICOPTER,
           mav.MAV_TYPE_COAXIAL, mav.MAV_TYPE_HELICOPTER}


class UnknownAutopilot(Error, ValueError):
    """A HEARTBEAT from an autopilot (or vehicle type) rfhoming does not know how to drive."""


def autopilot_of(heartbeat: Any) -> Autopilot:
    """The autopilot behind a vehicle's HEARTBEAT (its ``autopilot`` and ``type`` fields)."""
    if heartbeat.autopilot == mav.MAV_AUTOPILOT_PX4:
        return PX4
    if heartbeat.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
        if heartbeat.type in (mav.MAV_TYPE_GROUND_ROVER, mav.MAV_TYPE_SURFACE_BOAT):
            return ARDUPILOT_ROVER
        if heartbeat.type in COPTERS:
            return ARDUPILOT_COPTER
        raise UnknownAutopilot(f"an ArduPilot vehicle of MAV_TYPE {heartbeat.type} (rfhoming drives Rover and Copter)")
    raise UnknownAutopilot(f"MAV_AUTOPILOT {heartbeat.autopilot} (rfhoming drives ArduPilot and PX4)")


def armed(heartbeat: Any) -> bool:
    return bool(heartbeat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)


def is_vehicle(heartbeat: Any) -> bool:
    """A HEARTBEAT of a vehicle's autopilot, not of a ground station, gimbal or camera."""
    return bool(heartbeat.type != mav.MAV_TYPE_GCS and heartbeat.autopilot != mav.MAV_AUTOPILOT_INVALID)


class PoseEnu(NamedTuple):
    """Odometry in rfhoming's terms: ENU position (m), yaw counter-clockwise from east (rad),
    forward speed (m/s) and yaw rate (rad/s, counter-clockwise: FLU)."""

    x: float
    y: float
    theta: float
    v: float
    w: float


def pose_of(local: Any, attitude: Any) -> PoseEnu:
    """LOCAL_POSITION_NED (x north, y east) and ATTITUDE (yaw clockwise from north, FRD rates) ->
    ENU/FLU: x east, y north, yaw counter-clockwise from east, ω counter-clockwise."""
    yaw_ned = attitude.yaw
    theta = math.atan2(math.cos(yaw_ned), math.sin(yaw_ned))  # pi/2 - yaw, wrapped
    speed = local.vx * math.cos(yaw_ned) + local.vy * math.sin(yaw_ned)  # along the vehicle's heading
    return PoseEnu(local.y, local.x, theta, speed, -attitude.yawspeed)


def ned_of(pose: PoseEnu) -> tuple[tuple[float, float, float, float], float, float]:
    """The inverse of :func:`pose_of`: ((north, east, v_north, v_east), yaw clockwise from north,
    yaw rate FRD) for a pose in ENU/FLU."""
    yaw_ned = math.atan2(math.cos(pose.theta), math.sin(pose.theta))
    v_north, v_east = pose.v * math.cos(yaw_ned), pose.v * math.sin(yaw_ned)
    return (pose.y, pose.x, v_north, v_east), yaw_ned, -pose.w


def body_velocity(v: float, w: float) -> tuple[float, float, float, float]:
    """(v m/s forward, ω rad/s counter-clockwise) in FLU -> (vx, vy, vz, yaw_rate) in FRD."""
    return v, 0.0, 0.0, -w


def command_of(setpoint: Any) -> tuple[float, float]:
    """A body velocity setpoint as the vehicle reads it -> (v forward m/s, ω counter-clockwise rad/s)."""
    return setpoint.vx, (0.0 if setpoint.type_mask & IGNORE_YAW_RATE else -setpoint.yaw_rate)


class Refused(NamedTuple):
    """A whole, well-formed message whose values no vehicle can mean (:func:`refusal`): it never
    reaches the driver's pose, the estimator or a log, only this note of why."""

    message: Any
    why: str


POSITION_LIMIT_M = 1e5  # from the EKF origin: 100 km, where float32 still resolves 8 mm
SPEED_LIMIT_M_S = 100.0
ANGLE_LIMIT = math.pi + 1e-3  # ATTITUDE's angles are documented -pi..+pi (float32 rounds pi up)
RATE_LIMIT = 35.0  # rad/s: 2000 deg/s, the full scale of the IMUs autopilots use

LIMITS: dict[str, dict[str, float]] = {
    "LOCAL_POSITION_NED": {"x": POSITION_LIMIT_M, "y": POSITION_LIMIT_M, "z": POSITION_LIMIT_M,
                           "vx": SPEED_LIMIT_M_S, "vy": SPEED_LIMIT_M_S, "vz": SPEED_LIMIT_M_S},
    "ATTITUDE": {"roll": ANGLE_LIMIT, "pitch": ANGLE_LIMIT, "yaw": ANGLE_LIMIT,
                 "rollspeed": RATE_LIMIT, "pitchspeed": RATE_LIMIT, "yawspeed": RATE_LIMIT},
}
"""The largest magnitude taken of each float of the messages the driver reads (docs/protocol.md
§10 says why each); a message beyond one is refused whole."""


def refusal(message: Any) -> str | None:
    """Why ``message``'s values cannot be a vehicle's (a non-finite or absurd field), or None."""
    kind = message.get_type()
    for name, limit in LIMITS.get(kind, {}).items():
        value = getattr(message, name)
        if not math.isfinite(value):
            return f"{kind}.{name} = {value}, not a number a vehicle can mean"
        if abs(value) > limit:
            return f"{kind}.{name} = {value:g}, beyond {limit:g}: no vehicle rfhoming drives is there"
    return None


V1_MARKER, V2_MARKER = 0xFE, 0xFD
V1_HEADER, V2_HEADER, CRC_LEN, SIGNATURE_LEN = 6, 10, 2, 13


def _frame_length(buf: bytearray, i: int) -> int | None:
    """The length of the frame starting at ``buf[i]`` (a start marker), or None while its header
    is incomplete; 0 for a header no frame has (incompatibility flags MAVLink 2 does not define)."""
    if buf[i] == V1_MARKER:
        return V1_HEADER + buf[i + 1] + CRC_LEN if len(buf) > i + 1 else None
    if len(buf) <= i + 2:
        return None
    flags = buf[i + 2]
    if flags & ~mav.MAVLINK_IFLAG_SIGNED:
        return 0
    return V2_HEADER + buf[i + 1] + CRC_LEN + (SIGNATURE_LEN if flags & mav.MAVLINK_IFLAG_SIGNED else 0)


class Codec:
    """MAVLink 2 packets out (this end's system and component ids, its own sequence) and in.

    In, it frames the bytes itself and lets pymavlink check and decode each frame: a frame that
    fails (bad CRC, impossible header) costs one byte, and the hunt for the next start marker
    goes on from the byte after its marker, so junk never takes the good packets after it with
    it (pymavlink's own parser drops a bad frame's whole declared length, up to 280 bytes). A
    frame of a message outside the common dialect (ArduPilot's own, say) is passed over whole,
    as MAVLink's parsers do. On a datagram link each datagram is whole on its own (a packet
    never spans two): ``feed(..., datagram=True)`` drops what is left of a truncated frame, so
    a junk datagram ending in a start marker cannot swallow the next datagram's packets."""

    def __init__(self, system: int = GCS_SYSTEM, component: int = GCS_COMPONENT) -> None:
        self.mav = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        self.bad = 0  # frames that failed their checks, and truncated ones
        self.junk = 0  # bytes outside any frame
        self.unknown = 0  # whole frames of messages outside the common dialect
        self.refused = 0  # whole messages with values no vehicle means (Refused)
        self._buf = bytearray()

    def encode(self, message: Any) -> bytes:
        data = bytes(message.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data

    def feed(self, data: bytes, *, datagram: bool = False) -> list[Any]:
        """Every whole message in ``data`` (after what came before), a :class:`Refused` in place
        of one whose values are impossible; junk and corrupt frames counted."""
        buf = self._buf
        buf += data
        out: list[Any] = []
        i = 0
        while i < len(buf):
            start = min((k for k in (buf.find(V1_MARKER, i), buf.find(V2_MARKER, i)) if k >= 0), default=len(buf))
            self.junk += start - i
            i = start
            n = _frame_length(buf, i) if i < len(buf) else None
            if n is None or len(buf) - i < n:
                break  # the rest of the frame is still to come
            try:
                message = self.mav.decode(bytearray(buf[i:i + n])) if n else None
            except mav.MAVError:
                message = None
            if message is None:
                self.bad += 1
                i += 1  # not a frame after all: hunt on from the next byte
                continue
            i += n
            if message.get_type().startswith("UNKNOWN_"):
                self.unknown += 1
                continue
            why = refusal(message)
            if why is not None:
                self.refused += 1
                out.append(Refused(message, why))
            else:
                out.append(message)
        del buf[:i]
        if datagram and buf:
            self.bad += 1
            self.junk += len(buf)
            buf.clear()
        return out


def has_vehicle_heartbeat(datagram: bytes, system: int | None) -> bool:
    """Whether ``datagram`` holds a vehicle's HEARTBEAT (of ``system``, if given): what a
    listening link locks on to."""
    return any(not isinstance(m, Refused) and m.get_type() == "HEARTBEAT" and is_vehicle(m)
               and system in (None, m.get_srcSystem()) for m in Codec().feed(datagram, datagram=True))


def heartbeat(autopilot: int, vehicle_type: int, base_mode: int, custom_mode: int, status: int) -> Any:
    return mav.MAVLink_heartbeat_message(vehicle_type, autopilot, base_mode, custom_mode, status, 3)


def gcs_heartbeat() -> Any:
    return heartbeat(mav.MAV_AUTOPILOT_INVALID, mav.MAV_TYPE_GCS, 0, 0, mav.MAV_STATE_ACTIVE)


def command_long(system: int, component: int, command: int, *params: float) -> Any:
    p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    return mav.MAVLink_command_long_message(system, component, command, 0, *p)


def set_mode(system: int, component: int, autopilot: Autopilot, custom_mode: int) -> Any:
    """MAV_CMD_DO_SET_MODE with the custom mode (PX4 splits it into main and sub mode)."""
    flag = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if autopilot is PX4:
        return command_long(system, component, mav.MAV_CMD_DO_SET_MODE, flag, (custom_mode >> 16) & 0xFF,
                            (custom_mode >> 24) & 0xFF)
    return command_long(system, component, mav.MAV_CMD_DO_SET_MODE, flag, custom_mode)


def arm(system: int, component: int) -> Any:
    return command_long(system, component, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)


def request_message(system: int, component: int, message_id: int) -> Any:
    return command_long(system, component, mav.MAV_CMD_REQUEST_MESSAGE, message_id)


def from_autopilot(message: Any, system: int | None) -> bool:
    """A message from a vehicle's autopilot component (of ``system``, if known)."""
    return (message.get_srcComponent() == mav.MAV_COMP_ID_AUTOPILOT1
            and (system is None or message.get_srcSystem() == system))


def message_interval(system: int, component: int, message_id: int, hz: float) -> Any:
    return command_long(system, component, mav.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / hz)


def velocity_setpoint(time_boot_ms: int, system: int, component: int, frame: int, v: float, w: float) -> Any:
    vx, vy, vz, yaw_rate = body_velocity(v, w)
    return mav.MAVLink_set_position_target_local_ned_message(
        time_boot_ms & 0xFFFFFFFF, system, component, frame, VELOCITY_AND_YAW_RATE,
        0.0, 0.0, 0.0, vx, vy, vz, 0.0, 0.0, 0.0, 0.0, yaw_rate)


def result_name(result: int) -> str:
    entry = mav.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else f"result {result}"


def command_name(command: int) -> str:
    entry = mav.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"command {command}"


class MavlinkDecoder:
    """The wire protocol's decoder for the device table (tools that decode any capture):
    bytes -> MAVLink messages (one whose values are impossible is counted, not shown)."""

    def __init__(self) -> None:
        self.codec = Codec()

    @property
    def counters(self) -> dict[str, int]:
        c = self.codec
        return {"bad_packets": c.bad, "junk_bytes": c.junk, "unknown_messages": c.unknown, "refused_values": c.refused}

    def feed(self, data: bytes) -> list[Any]:
        return [m for m in self.codec.feed(data) if not isinstance(m, Refused)]
