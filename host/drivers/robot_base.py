"""Robot base driver: velocity commands out, odometry and range scans in.

The host sends a stop on shutdown and on any exception (use the driver as an async context
manager around the work that drives the robot); every command carries a timeout, so the base's
own watchdog stops it if the host dies outright -- the second line of defence.
"""

from __future__ import annotations

from typing import Any

from rfhoming.host.drivers.common import BoundedStream, Wiring
from rfhoming.host.drivers.robot import SCAN_PERIOD_S as SCAN_PERIOD_S  # where older code finds them
from rfhoming.host.drivers.robot import SCAN_RANGE_MIN as SCAN_RANGE_MIN
from rfhoming.host.drivers.robot import SCAN_TIME_INCREMENT_S as SCAN_TIME_INCREMENT_S
from rfhoming.host.drivers.robot import SCAN_V1_RANGE_MAX as SCAN_V1_RANGE_MAX
from rfhoming.host.drivers.robot import CommandedBase, Pose2D, Scan
from rfhoming.host.drivers.rss import FRAME_ITEMS, NodeClock
from rfhoming.host.ports import Disconnected, HostPort
from rfhoming.protocol.frames import (
    FrameDecoder,
    NodeCommand,
    Odometry,
    RangeScan,
    RangeScanV2,
    VelocityCommand,
    encode_frame,
)

CMD_BRAKE = 5  # node command: 1 = shed speed at the base's emergency deceleration, 0 = normal ramp


def scan_of(record: RangeScan | RangeScanV2, t_host: float = 0.0) -> Scan:
    """A range scan record of either version in SI units. Version 2 carries its first and last
    beam in µrad, so the step is exact; version 1 carried a step rounded to whole mrad."""
    ranges = tuple(r / 1000 if r else None for r in record.ranges_mm)
    if isinstance(record, RangeScanV2):
        first, last = record.angle_min_urad / 1e6, record.angle_max_urad / 1e6
        step = (last - first) / (len(ranges) - 1) if len(ranges) > 1 else 0.0
        return Scan(t_host, first, step, ranges, record.range_max_mm / 1000)
    return Scan(t_host, record.angle_min_mrad / 1000, record.angle_inc_mrad / 1000, ranges)


class BaseDriver(CommandedBase):
    """rfhoming's own base over a serial port: COBS-framed records (docs/protocol.md)."""

    kind = "base"
    items = FRAME_ITEMS

    @classmethod
    def options(cls, wiring: Wiring) -> dict[str, Any]:
        """A run's command timeout: the base stops by itself when commands stop this long."""
        return {} if wiring.config is None else {"command_timeout_ms": wiring.config.loop.command_timeout_ms}

    def __init__(self, port: HostPort, *, command_timeout_ms: int = 300, reconnect: bool = True,
                 out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out)
        self.decoder = FrameDecoder()
        self._sent = FrameDecoder()  # what the host wrote, for an export's commands
        self.command_timeout_ms = command_timeout_ms
        self.watchdog = f"the base's watchdog, within {command_timeout_ms} ms"
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
                self.out.put(scan_of(record, t_host))

    def sent(self, data: bytes) -> list[Any]:
        return self._sent.feed(data)

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
