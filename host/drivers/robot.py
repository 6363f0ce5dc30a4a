"""The robot-base interface: what the homing loop, the run assembly, the recorder and the
replay need of a robot base, whatever drives it (rfhoming's serial base, a ROS 2 robot, a
MAVLink vehicle).

Velocity goes out in REP 103 terms (v m/s forward, ω rad/s counter-clockwise, base_link FLU);
odometry (:class:`Pose2D`, on the base's own clock) and range scans (:class:`Scan`) come in on
the driver's ``out`` stream. :class:`CommandedBase` is what the three drivers share: the final
stop when the work that drives the robot ends, however it ends.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol, runtime_checkable

from rfhoming.host.drivers.common import BoundedStream, Driver

log = logging.getLogger(__name__)


class Pose2D(NamedTuple):
    t_host: float
    t_robot: float  # the base's own clock (seconds, unwrapped): the loop's time axis
    x: float
    y: float
    theta: float
    v: float
    w: float
    flags: int


class TakenOver(NamedTuple):
    """The base is no longer the loop's: someone else chose its mode or disarmed it (a ground
    station, the pilot, a failsafe). The run ends with it, recorded in its log and summary."""

    t_host: float
    mode: str  # the mode it was put in ("disarmed" when that was all)
    why: str  # one line for the user


SCAN_V1_RANGE_MAX = 65.535  # a version-1 scan does not say its sensor's range: the record's largest
SCAN_RANGE_MIN = 0.001  # the records' shortest range: 1 mm (0 mm means no return; docs/protocol.md, 0x22/0x23)
SCAN_PERIOD_S = 0.1  # the emulated scanner's period (emulator BaseRunner.SCAN_PERIOD_S); *assumed* for a real base
SCAN_TIME_INCREMENT_S = 0.0  # beams taken at one instant, as the emulated scanner casts them; *assumed* for a real one


class Scan(NamedTuple):
    t_host: float
    angle_min: float  # radians, the first beam, counter-clockwise from ahead
    angle_increment: float
    ranges: tuple[float | None, ...]  # metres, None = no return
    range_max: float = SCAN_V1_RANGE_MAX  # metres, the sensor's
    range_min: float = SCAN_RANGE_MIN  # metres: a beam below it is no return
    scan_time: float = SCAN_PERIOD_S  # seconds from one scan to the next
    time_increment: float = SCAN_TIME_INCREMENT_S  # seconds from one beam to the next

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * max(0, len(self.ranges) - 1)


@runtime_checkable
class RobotBase(Protocol):
    """A robot base as the homing loop drives it. ``kind`` is its device-table record (which
    says whether it ``brakes``); ``run`` keeps its link up until cancelled; items go to ``out``."""

    kind: str
    port: Any  # HostPort-shaped: name, counters, taps
    out: BoundedStream[Any]
    state: str
    counters: dict[str, int]
    listeners: list[Callable[[str, float, Any], None]]
    latest: Pose2D | None  # the newest odometry

    @property
    def connected(self) -> asyncio.Event:
        """Set while the base can be driven (the loop starts on it)."""
        ...

    def acting_on(self, odometry: Pose2D) -> None:
        """The odometry the loop acts on now, one of this base's own from ``out``: what it sends
        until the next call is stamped on it, not on a newer one the driver has read meanwhile
        (how far a driver reads ahead of the loop is the machine's load, live, and the
        recording's order in a replay: a stamp taken from it differs between the two)."""
        ...

    def send_velocity(self, v: float, w: float) -> bool:
        """(v m/s, ω rad/s) in base_link (REP 103 FLU); False when it could not be sent."""
        ...

    def stop(self) -> bool:
        """Zero velocity now."""
        ...

    def brake(self, on: bool) -> bool:
        """Emergency deceleration on or off, where the base has one (counted where it has not)."""
        ...

    async def run(self) -> None: ...

    def health(self) -> dict[str, Any]: ...

    async def __aenter__(self) -> Any: ...

    async def __aexit__(self, *exc: Any) -> None: ...


class CommandedBase(Driver):
    """What the drivers of a robot base share: the latest odometry and scan, the command
    counters, and a stop on leaving the ``async with`` around the work that drives the robot
    (on an exception, on Ctrl-C) -- the base's own command timeout is the second line of defence."""

    kind = "base"
    watchdog = "the base's command timeout"  # what stops the robot when the final stop cannot be sent

    def __init__(self, port: Any, *, reconnect: bool = True, out: BoundedStream[Any] | None = None,
                 queue_size: int = 500) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.latest: Pose2D | None = None
        self.acting: Pose2D | None = None  # the odometry the loop acts on (:meth:`acting_on`)
        self.counters.update(commands=0, stops=0, unsent=0, brakes=0, brakes_off=0)

    def acting_on(self, odometry: Pose2D) -> None:
        """A base whose commands carry no time (rfhoming's serial base) only keeps it."""
        self.acting = odometry

    def send_velocity(self, v: float, w: float) -> bool:
        raise NotImplementedError

    def stop(self) -> bool:
        self.counters["stops"] += 1
        return self.send_velocity(0.0, 0.0)

    def brake(self, on: bool) -> bool:
        """A base without a brake mode: counted, nothing sent (it ramps down by its own limits)."""
        self.counters["brakes" if on else "brakes_off"] += 1
        return True

    async def __aenter__(self) -> CommandedBase:
        return self

    async def __aexit__(self, *exc: Any) -> None:
        if not self.stop() and self.port.counters["opens"]:  # a base never reached was never driven
            log.error("%s: could not send the final stop; %s stops it", self.port.name, self.watchdog)
        await asyncio.sleep(0)
