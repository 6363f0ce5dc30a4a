"""The port a ROS 2 robot base is reached by: DDS samples as sample records, HostPort-shaped
(joining the domain: rfhoming.host.dds; the types: rfhoming.protocol.ros2dds)."""

import asyncio
import time
from typing import Any

from cyclonedds.pub import DataWriter

from rfhoming.host.dds import participant, reader, writer
from rfhoming.host.drivers.ros2_base import Topics
from rfhoming.host.ports import Chunk, Disconnected, PortError, Tap
from rfhoming.protocol import ros2
from rfhoming.protocol.ros2dds import TYPES, DdsError

MAX_QUEUED = 2000  # samples not yet read by the driver; beyond, new ones are dropped (counted)


class Ros2Port:
    """A ROS 2 robot base, HostPort-shaped: each chunk read is one sample record (topic +
    CDR) from /odom or /scan; each write is one record for the command topic. Every sample
    passes the taps, so a capture holds what the loop used and a replay feeds the same bytes.

    ``open`` returns when the first odometry arrives (a base that publishes nothing is not
    ready: the supervisor ends the run at the kind's deadline)."""

    def __init__(self, topics: Topics, *, name: str | None = None, taps: list[Tap] | None = None) -> None:
        self.topics = topics
        self.spec = f"ros2:domain={topics.domain}" + (f",ns={topics.ns}" if topics.ns else "")
        self.name = name or self.spec
        self.baud = 0
        self.taps: list[Tap] = list(taps or [])
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0, "disconnects": 0,
                         "dropped_bytes": 0, "samples_dropped": 0}
        self._queue: asyncio.Queue[Chunk] = asyncio.Queue()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._odometry = asyncio.Event()
        self._entities: list[Any] = []
        self._writer: DataWriter[Any] | None = None

    @property
    def is_open(self) -> bool:
        return self._writer is not None

    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._odometry = asyncio.Event()
        t = self.topics
        try:
            dp = participant(t.domain, t.discovery)
        except DdsError as exc:
            raise PortError(str(exc)) from None
        odom, scan, cmd = t.name(t.odom), t.name(t.scan), t.name(t.cmd_vel)
        self._entities = [reader(dp, odom, ros2.ODOMETRY, lambda s: self._from_dds(odom, ros2.ODOMETRY, s)),
                          reader(dp, scan, ros2.LASER_SCAN, lambda s: self._from_dds(scan, ros2.LASER_SCAN, s))]
        self._writer = writer(dp, cmd, t.command_type)
        self._command_type = TYPES[t.command_type]
        self.counters["opens"] += 1
        await self._odometry.wait()

    def _from_dds(self, topic: str, ros_type: str, sample: Any) -> None:
        """Cyclone's listener thread: the sample's CDR, to the event loop."""
        record = ros2.encode_record(topic, ros_type, sample.serialize())
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._received, topic, record)

    def _received(self, topic: str, record: bytes) -> None:
        now = round(time.time() * 1e6) / 1e6
        for tap in self.taps:
            tap(self.name, "in", now, record)
        self.counters["bytes_in"] += len(record)
        self.counters["chunks_in"] += 1
        if self._queue.qsize() >= MAX_QUEUED:
            self.counters["samples_dropped"] += 1
            return
        self._queue.put_nowait(Chunk(now, record))
        if topic == self.topics.name(self.topics.odom):  # the first odometry: the base is there
            self._odometry.set()

    async def read(self) -> Chunk:
        if self._writer is None:
            raise Disconnected(f"{self.name} is not open")
        return await self._queue.get()

    def take_pending(self) -> list[Chunk]:
        chunks = []
        while not self._queue.empty():
            chunks.append(self._queue.get_nowait())
        return chunks

    def write(self, data: bytes) -> None:
        """One sample record for the command topic, published."""
        if self._writer is None:
            raise Disconnected(f"{self.name} is not open")
        record = ros2.decode_record(data)
        if record.type != self.topics.command_type:
            raise PortError(f"{self.name}: a {record.type} where {self.topics.command_type} is published")
        now = round(time.time() * 1e6) / 1e6
        for tap in self.taps:
            tap(self.name, "out", now, data)
        self.counters["bytes_out"] += len(data)
        self._writer.write(self._command_type.deserialize(record.data))

    async def close(self) -> None:
        self._writer = None
        self._entities = []
        self._loop = None
