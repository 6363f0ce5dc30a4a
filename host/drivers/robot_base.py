"""Robot base driver: velocity commands out, odometry and range scans in.

The host sends a stop on shutdown and on any exception (use the driver as an async context
manager around the work that drives the robot); every command carries a timeout, so the base's
own watchdog stops it if the host dies outright -- the second line of defence.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any, NamedTuple

from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.drivers.rss import NodeClock
from rfhoming.host.ports import Disconnected, Port
from rfhoming.protocol.frames import (
    FrameDecoder,
    NodeCommand,
    Odometry,
    RangeScan,
    RangeScanV2,
    VelocityCommand,
    encode_frame,
)

log = logging.getLogger(__name__)

CMD_BRAKE = 5  # node command: 1 = shed speed at the base's emergency deceleration, 0 = normal ramp


class Pose2D(NamedTuple):
    t_host: float
    t_robot: float  # the base's own clock (seconds, unwrapped): the loop's time axis
    x: float
    y: float
    theta: float
    v: float
    w: float
    flags: int


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


def scan_of(record: RangeScan | RangeScanV2, t_host: float = 0.0) -> Scan:
    """A range scan record of either version in SI units. Version 2 carries its first and last
    beam in µrad, so the step is exact; version 1 carried a step rounded to whole mrad."""
    ranges = tuple(r / 1000 if r else None for r in record.ranges_mm)
    if isinstance(record, RangeScanV2):
        first, last = record.angle_min_urad / 1e6, record.angle_max_urad / 1e6
        step = (last - first) / (len(ranges) - 1) if len(ranges) > 1 else 0.0
        return Scan(t_host, first, step, ranges, record.range_max_mm / 1000)
    return Scan(t_host, record.angle_min_mrad / 1000, record.angle_inc_mrad / 1000, ranges)


class BaseDriver(Driver):
    kind = "base"

    def __init__(self, port: Port, *, command_timeout_ms: int = 300, reconnect: bool = True,
                 out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=500)
        self.decoder = FrameDecoder()
        self.command_timeout_ms = command_timeout_ms
        self.latest: Pose2D | None = None
        self.latest_scan: Scan | None = None
        self.counters.update(commands=0, stops=0, unsent=0, brakes=0, brakes_off=0)
        self._seq = 0
        self.clock = NodeClock()

    def on_chunk(self, data: bytes, t_host: float) -> None:
        for record in self.decoder.feed(data):
            self.emit(t_host, record)
            if isinstance(record, Odometry):
                pose = Pose2D(t_host, self.clock.unwrap(record.t_us) / 1e6, record.x_mm / 1000, record.y_mm / 1000, record.theta_urad / 1e6,
                              record.v_mm_s / 1000, record.w_mrad_s / 1000, record.flags)
                self.latest = pose
                self.out.put(pose)
            elif isinstance(record, (RangeScan, RangeScanV2)):
                scan = scan_of(record, t_host)
                self.latest_scan = scan
                self.out.put(scan)

    def send_velocity(self, v: float, w: float) -> bool:
        """Command (v m/s, ω rad/s); False (counted) when the base is not connected."""
        self._seq = (self._seq + 1) & 0xFFFF
        v_mm = max(-32768, min(32767, round(v * 1000)))
        w_mrad = max(-32768, min(32767, round(w * 1000)))
        try:
            self.port.write(encode_frame(VelocityCommand(0, self._seq, 0, v_mm, w_mrad, self.command_timeout_ms)))
        except Disconnected:
            self.counters["unsent"] += 1
            return False
        self.counters["commands"] += 1
        return True

    def stop(self) -> bool:
        self.counters["stops"] += 1
        return self.send_velocity(0.0, 0.0)

    def brake(self, on: bool) -> bool:
        """Brake mode on: the base sheds speed at its emergency deceleration (docs/protocol.md)."""
        self._seq = (self._seq + 1) & 0xFFFF
        try:
            self.port.write(encode_frame(NodeCommand(0, self._seq, 0, CMD_BRAKE, bytes([int(on)]))))
        except Disconnected:
            self.counters["unsent"] += 1
            return False
        self.counters["brakes" if on else "brakes_off"] += 1
        return True

    async def __aenter__(self) -> BaseDriver:
        return self

    async def __aexit__(self, *exc: Any) -> None:
        if not self.stop() and self.port.counters["opens"]:  # a base never reached was never driven
            log.error("%s: could not send the final stop; the base's watchdog stops it within %d ms",
                      self.port.name, self.command_timeout_ms)
        await asyncio.sleep(0)

