"""An autopilot's MAVLink face, sans-IO: what ArduPilot Rover or Copter, or PX4, says and
accepts while a ground station drives it by velocity (docs/protocol.md, "MAVLink vehicles").

It keeps the mode and the arming state, answers COMMAND_LONGs with COMMAND_ACK, takes body
velocity setpoints in the autopilot's guided mode, and turns the vehicle's pose into
HEARTBEAT (1 Hz), ATTITUDE and LOCAL_POSITION_NED. :meth:`velocity` is what the motors should
do now: zero unless armed, in the guided mode and with a setpoint younger than the autopilot's
timeout (GUID_TIMEOUT for ArduPilot; PX4 leaves OFFBOARD for HOLD after COM_OF_LOSS_T).
In RTL (a ground station's or a failsafe's choice) it drives back to where it was armed, then
a rover stops there and a copter lands and disarms.
The vehicle's motion is the robot base's (emulator/mavlinkrobot.py); time is its boot clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rfhoming.protocol import mavlink as ml
from rfhoming.protocol.mavlink import mav

HEARTBEAT_PERIOD_S = 1.0  # MAVLink microservices, Heartbeat: 1 Hz
RTL_SPEED_M_S = 0.5  # *assumed*: the emulated bases' pace (ArduPilot's RTL_SPEED 0 means WP_SPEED, 2 m/s on Rover)
RTL_TURN_GAIN = 2.0  # *assumed*: rad/s of yaw rate per radian of heading error, up to RTL_TURN_MAX
RTL_TURN_MAX = 1.0  # rad/s
RTL_ARRIVED_M = 0.2  # *assumed*: home reached (ArduPilot Rover's WP_RADIUS is 2 m by default; the emulated world is small)
LAND_SPEED_M_S = 0.5  # ArduPilot Copter LAND_SPEED default 50 cm/s
AUTOPILOTS = {("ardupilot", "rover"): (ml.ARDUPILOT_ROVER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, mav.MAV_TYPE_GROUND_ROVER),
              ("ardupilot", "copter"): (ml.ARDUPILOT_COPTER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, mav.MAV_TYPE_QUADROTOR),
              ("px4", "rover"): (ml.PX4, mav.MAV_AUTOPILOT_PX4, mav.MAV_TYPE_GROUND_ROVER),
              ("px4", "copter"): (ml.PX4, mav.MAV_AUTOPILOT_PX4, mav.MAV_TYPE_QUADROTOR)}


@dataclass
class VehicleOptions:
    autopilot: str = "ardupilot"  # or px4
    vehicle: str = "rover"  # or copter (flies the same plane at ``altitude``)
    mode: str = "HOLD"  # the mode it boots in
    armed: bool = False
    prearm_ok: bool = True  # False: arming is refused, as failing pre-arm checks refuse it
    system: int = 1
    component: int = 1
    command_timeout_s: float | None = None  # None: the autopilot's default (GUID_TIMEOUT 3 s, COM_OF_LOSS_T 1 s)
    altitude: float = 2.0  # metres above the EKF origin (a copter)


class MavlinkVehicle:
    def __init__(self, options: VehicleOptions = VehicleOptions()) -> None:
        key = (options.autopilot, options.vehicle)
        if key not in AUTOPILOTS:
            raise ValueError(f"autopilot={options.autopilot}, vehicle={options.vehicle}: the emulated vehicles are "
                             "autopilot=ardupilot|px4 and vehicle=rover|copter")
        self.autopilot, self.mav_autopilot, self.mav_type = AUTOPILOTS[key]
        names = {name: number for number, name in self.autopilot.modes.items()}
        if options.mode.upper() not in names:
            raise ValueError(f"mode={options.mode}: a {self.autopilot.name} mode, one of {', '.join(names)}")
        self.options = options
        self.mode = names[options.mode.upper()]
        self.armed = options.armed
        self.timeout_s = options.command_timeout_s or self.autopilot.command_timeout_s
        self.codec = ml.Codec(options.system, options.component)
        self.setpoint: tuple[float, float] = (0.0, 0.0)
        self.setpoint_at: float | None = None  # boot seconds of the newest setpoint
        self.stream_since: float | None = None  # when the current unbroken setpoint stream began
        self._next_heartbeat = 0.0
        self.rtl = names.get("RTL")
        self.pose: ml.PoseEnu | None = None  # the newest, from :meth:`telemetry`
        self.home: tuple[float, float] | None = None  # where it was armed (east, north), or first seen armed
        self.altitude = options.altitude if options.vehicle == "copter" else 0.0
        self._landed_at: float | None = None  # boot seconds of the last altitude step while landing
        self.counters = {"setpoints": 0, "commands": 0, "refused": 0, "timeouts": 0}

    # -- the ground station's packets ----------------------------------------------------

    def feed(self, data: bytes, t: float) -> bytes:
        """The ground station's bytes at boot time ``t``; returns the vehicle's answers."""
        out = b""
        for message in self.codec.feed(data):
            kind = message.get_type()
            if kind == "COMMAND_LONG" and message.target_system in (0, self.options.system):
                out += self._command(message, t)
            elif kind == "SET_POSITION_TARGET_LOCAL_NED" and message.target_system == self.options.system:
                self._setpoint(message, t)
        return out

    def _setpoint(self, message: Any, t: float) -> None:
        fresh = self.setpoint_at is not None and t - self.setpoint_at <= self.timeout_s
        self.stream_since = self.stream_since if fresh and self.stream_since is not None else t
        self.setpoint_at = t
        self.counters["setpoints"] += 1
        if message.coordinate_frame in self.autopilot.body_frames and not message.type_mask & ml.IGNORE_VELOCITY:
            self.setpoint = ml.command_of(message)
        else:  # *assumed*: position and earth-frame targets are not modelled; the vehicle holds
            self.setpoint = (0.0, 0.0)

    def _command(self, message: Any, t: float) -> bytes:
        self.counters["commands"] += 1
        result = mav.MAV_RESULT_ACCEPTED
        if message.command == mav.MAV_CMD_DO_SET_MODE:
            result = self._set_mode(message, t)
        elif message.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if message.param1 == 1 and not self.options.prearm_ok:
                result = mav.MAV_RESULT_FAILED  # ArduPilot: "PreArm: ..." and FAILED
            else:
                self.armed = message.param1 == 1
                if self.armed and self.pose is not None:
                    self.home = (self.pose.x, self.pose.y)  # home is set at arming
        elif message.command == mav.MAV_CMD_REQUEST_MESSAGE and message.param1 == mav.MAVLINK_MSG_ID_HEARTBEAT:
            return (self.codec.encode(mav.MAVLink_command_ack_message(message.command, result))
                    + self.codec.encode(self.heartbeat()))
        elif message.command != mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = mav.MAV_RESULT_UNSUPPORTED
        if result != mav.MAV_RESULT_ACCEPTED:
            self.counters["refused"] += 1
        return self.codec.encode(mav.MAVLink_command_ack_message(message.command, result))

    def _set_mode(self, message: Any, t: float) -> int:
        if self.autopilot is ml.PX4:
            wanted = (int(message.param2) << 16) | (int(message.param3) << 24)
        else:
            wanted = int(message.param2)
        if wanted not in self.autopilot.modes or (wanted == self.rtl and self.home is None):
            return int(mav.MAV_RESULT_FAILED)  # ArduPilot refuses RTL before home is set (Rover/mode_rtl.cpp)
        if wanted == self.autopilot.guided and self.autopilot.stream_before_switch and not self._streaming(t):
            return int(mav.MAV_RESULT_TEMPORARILY_REJECTED)  # PX4: no setpoint stream yet
        self.mode = wanted
        return int(mav.MAV_RESULT_ACCEPTED)

    def _streaming(self, t: float) -> bool:
        """PX4: setpoints coming for more than a second, the newest within the loss timeout."""
        return (self.stream_since is not None and self.setpoint_at is not None
                and t - self.setpoint_at <= self.timeout_s and t - self.stream_since >= 1.0)

    # -- the vehicle's side --------------------------------------------------------------

    def velocity(self, t: float) -> tuple[float, float]:
        """What the vehicle drives at boot time ``t`` (v m/s, ω rad/s counter-clockwise)."""
        if self.setpoint_at is not None and t - self.setpoint_at > self.timeout_s:
            self.setpoint_at = None
            self.setpoint = (0.0, 0.0)
            self.counters["timeouts"] += 1
            if self.autopilot is ml.PX4 and self.mode == self.autopilot.guided:
                self.mode = self.autopilot.hold  # offboard lost: COM_OBL_RC_ACT's default, Hold
        if self.armed and self.mode == self.rtl:
            return self._return_to_launch(t)
        if not self.armed or self.mode != self.autopilot.guided or self.setpoint_at is None:
            return 0.0, 0.0
        return self.setpoint

    def _return_to_launch(self, t: float) -> tuple[float, float]:
        """RTL: turn towards home and drive there; there, a rover stops and a copter descends at
        LAND_SPEED and disarms on the ground (ArduPilot RTL with RTL_ALT_FINAL 0, PX4 Return)."""
        if self.pose is None or self.home is None:
            return 0.0, 0.0
        dx, dy = self.home[0] - self.pose.x, self.home[1] - self.pose.y
        if (distance := math.hypot(dx, dy)) > RTL_ARRIVED_M:
            self._landed_at = None
            error = math.remainder(math.atan2(dy, dx) - self.pose.theta, math.tau)
            w = max(-RTL_TURN_MAX, min(RTL_TURN_MAX, RTL_TURN_GAIN * error))
            return min(RTL_SPEED_M_S, distance) * max(0.0, math.cos(error)), w  # slowing over its last 0.5 m
        if self.options.vehicle == "copter":
            if self._landed_at is not None:
                self.altitude = max(0.0, self.altitude - LAND_SPEED_M_S * (t - self._landed_at))
            self._landed_at = t
            if self.altitude == 0.0:
                self.armed = False  # ArduPilot and PX4 disarm once landed
        return 0.0, 0.0

    def telemetry(self, t: float, pose: ml.PoseEnu) -> bytes:
        """The vehicle's pose at boot time ``t``: HEARTBEAT when one is due, ATTITUDE and
        LOCAL_POSITION_NED."""
        self.pose = pose
        if self.armed and self.home is None:
            self.home = (pose.x, pose.y)  # booted armed: home is where it was first seen
        out = b""
        if t >= self._next_heartbeat:
            self._next_heartbeat = t + HEARTBEAT_PERIOD_S
            out += self.codec.encode(self.heartbeat())
        (north, east, v_north, v_east), yaw, yaw_rate = ml.ned_of(pose)
        ms = int(t * 1000) & 0xFFFFFFFF
        z = -self.altitude if self.altitude else 0.0  # a rover: 0.0, not -0.0 (the bytes replays compare)
        out += self.codec.encode(mav.MAVLink_attitude_message(ms, 0.0, 0.0, yaw, 0.0, 0.0, yaw_rate))
        out += self.codec.encode(mav.MAVLink_local_position_ned_message(ms, north, east, z, v_north, v_east, 0.0))
        return out

    def heartbeat(self) -> Any:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        if self.mode == self.autopilot.guided:
            base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
        return ml.heartbeat(self.mav_autopilot, self.mav_type, base, self.mode, status)
