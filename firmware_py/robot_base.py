"""Differential-drive robot base controller: velocity commands in, odometry and scans out.

Sans-IO. Velocity commands (0x21) set a target clamped to the speed and turn-rate limits; the
applied velocity moves toward it no faster than the acceleration limits allow. A command's
``timeout_ms`` arms the watchdog: when it expires the base brakes to a stop and flags it
(odometry flags bit 0) -- the second line of defence behind the host's own stop.

Braking: speed is normally shed at ``a_max`` like it is gained. Node command 5 (``brake``, arg
1/0) switches the base to shed speed at ``a_emergency`` instead, until switched off; a watchdog
stop always uses it. This is the fault/safety-stop deceleration motor controllers keep apart
from their normal ramp (docs/protocol.md cites it); the host uses it on stale data.

The emulator asks :meth:`tick` for the applied (v, ω) each step and integrates the true pose;
the base integrates its own odometry from the same wheel speeds with a configurable wheel-slip
error (scale on v and ω, plus a yaw drift), so odometry drifts from truth as on a real robot.
Odometry (0x20) at 50 Hz; a range scan (0x23, its first and last beam in µrad) whenever the
emulator provides one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from rfhoming.firmware.framed_node import FramedNode
from rfhoming.protocol.frames import NodeCommand, Odometry, RangeScanV2, VelocityCommand

ODOMETRY_PERIOD_US = 20_000
FLAG_WATCHDOG, FLAG_CONTACT, FLAG_MOTORS = 1, 2, 4
CMD_STATUS, CMD_BRAKE = 4, 5


@dataclass(frozen=True)
class BaseLimits:
    v_max: float = 0.7  # m/s
    w_max: float = 1.5  # rad/s
    a_max: float = 1.0  # m/s², speeding up and (normally) slowing down
    a_emergency: float = 4.0  # m/s², slowing down in brake mode and on a watchdog stop
    alpha_max: float = 4.0  # rad/s²


@dataclass(frozen=True)
class Slip:
    v_scale: float = 0.0  # odometry sees v·(1 + v_scale)
    w_scale: float = 0.0
    yaw_drift: float = 0.0  # rad/s added to the odometry's ω while moving


class RobotBaseFirmware(FramedNode):
    DEVICE_KIND = 3

    def __init__(self, node_id: int = 0, limits: BaseLimits = BaseLimits(), slip: Slip = Slip(),
                 start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        super().__init__(node_id)
        self.limits = limits
        self.slip = slip
        self.counters.update(commands=0, watchdog_stops=0)
        self.v = self.w = 0.0  # applied, m/s and rad/s
        self._target = (0.0, 0.0)
        self._deadline_us: int | None = None
        self.watchdog_tripped = False
        self.braking = False  # brake mode (node command 5): shed speed at a_emergency
        self.contact = False
        self.x, self.y, self.theta = start_pose  # odometry frame, m and rad
        self._next_odometry_us = 0
        self._last_us: int | None = None
        self._boot_us = 0  # emulator time of the last reset: the MCU clock counts from there

    def halt(self) -> None:
        """Stop now and forget the last command (a controller restart)."""
        self.v = self.w = 0.0
        self._target, self._deadline_us = (0.0, 0.0), None

    def reset(self, now_us: int) -> None:
        """An MCU reset at emulator time ``now_us``: motors stop, the last command is forgotten,
        the microsecond clock and the record counter restart at 0 (odometry survives: it is kept
        in RAM that the reset does not clear)."""
        self.halt()
        self.watchdog_tripped = self.braking = False
        self._boot_us, self._now_us = now_us, 0
        self._seq = 0
        self._next_odometry_us = self._next_status_us = 0
        self._last_us = None

    def command(self, cmd: NodeCommand) -> None:
        if cmd.command == CMD_STATUS:
            self.send_status()
        elif cmd.command == CMD_BRAKE and len(cmd.args) == 1 and cmd.args[0] in (0, 1):
            self.braking = bool(cmd.args[0])
        else:
            self.log(f"unknown command {cmd.command}")

    def receive(self, data: bytes) -> None:
        """Velocity commands (0x21) and node commands (0x80) from the host."""
        for item in self._decoder.feed(data):
            if isinstance(item, VelocityCommand):
                self._velocity(item)
            elif isinstance(item, NodeCommand):
                self.command(item)
            else:
                self.counters["rx_errors"] += 1

    def _velocity(self, cmd: VelocityCommand) -> None:
        lim = self.limits
        v = max(-lim.v_max, min(lim.v_max, cmd.v_mm_s / 1000))
        w = max(-lim.w_max, min(lim.w_max, cmd.w_mrad_s / 1000))
        self._target = (v, w)
        self._deadline_us = self._now_us + cmd.timeout_ms * 1000
        self.watchdog_tripped = False
        self.counters["commands"] += 1

    def step(self, sim_us: int) -> tuple[float, float]:
        """Advance to emulator time ``sim_us``; returns the applied (v, ω) over the step."""
        now_us = sim_us - self._boot_us  # the MCU's own clock, from its last reset
        dt = 0.0 if self._last_us is None else (now_us - self._last_us) / 1e6
        self._last_us = now_us
        self.tick(now_us)
        if self._deadline_us is not None and now_us >= self._deadline_us:
            self._target, self._deadline_us = (0.0, 0.0), None
            self.watchdog_tripped = True
            self.counters["watchdog_stops"] += 1
        tv, tw = self._target
        shedding = abs(tv) < abs(self.v) or tv * self.v < 0
        a = self.limits.a_emergency if shedding and (self.braking or self.watchdog_tripped) else self.limits.a_max
        self.v += max(-a * dt, min(a * dt, tv - self.v))
        self.w += max(-self.limits.alpha_max * dt, min(self.limits.alpha_max * dt, tw - self.w))
        moving = self.v != 0.0 or self.w != 0.0
        v_odo = self.v * (1 + self.slip.v_scale)
        w_odo = self.w * (1 + self.slip.w_scale) + (self.slip.yaw_drift if moving else 0.0)
        self.theta = math.remainder(self.theta + w_odo * dt, 2 * math.pi)
        self.x += v_odo * dt * math.cos(self.theta)
        self.y += v_odo * dt * math.sin(self.theta)
        if now_us >= self._next_odometry_us:
            self._next_odometry_us = now_us + ODOMETRY_PERIOD_US
            self._send_odometry()
        return self.v, self.w

    def _send_odometry(self) -> None:
        flags = (FLAG_WATCHDOG if self.watchdog_tripped else 0) | (FLAG_CONTACT if self.contact else 0)
        flags |= FLAG_MOTORS
        self.send(Odometry(
            self.node_id, self.next_seq(), self._now_us & 0xFFFFFFFF,
            _sat(round(self.x * 1000), 31), _sat(round(self.y * 1000), 31),
            max(-3_141_592, min(3_141_592, round(self.theta * 1e6))),
            _sat(round(self.v * 1000), 15), _sat(round(self.w * 1000), 15), flags,
        ))

    def send_scan(self, angle_min: float, angle_max: float, range_max: float,
                  ranges_m: Sequence[float | None]) -> None:
        """Package a scan the world measured (radians of the first and last beam, metres):
        mm, 0 = no return, at most 255 beams."""
        self.send_scan_mm(angle_min, angle_max, range_max,
                          tuple(0 if r is None else max(1, min(65535, round(r * 1000))) for r in ranges_m[:255]))

    def send_scan_mm(self, angle_min: float, angle_max: float, range_max: float, ranges: tuple[int, ...]) -> None:
        """:meth:`send_scan` with the ranges already in its wire form (mm, 0 = no return, 1..65535)."""
        self.send(RangeScanV2(self.node_id, self.next_seq(), self._now_us & 0xFFFFFFFF,
                              round(angle_min * 1e6), round(angle_max * 1e6), min(65535, round(range_max * 1000)),
                              ranges))


def _sat(value: int, bits: int) -> int:
    """Saturate to a signed ``bits+1``-bit field instead of wrapping."""
    high = (1 << bits) - 1
    return max(-high - 1, min(high, value))
