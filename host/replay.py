"""Replay: recorded inbound bytes through the same decoders and drivers as a live run.

:class:`ReplayPort` stands where a :class:`~host.ports.HostPort` stands. It hands the driver
each recorded inbound chunk with its recorded timestamp, as fast as possible or at the recorded
pace (``speed``). A recorded answer that followed one of the host's writes is released only
after the driver has written again, so the driver's commands are answered from the capture in
the order they were answered live. The replayed host's writes are matched one for one, in order,
with the recorded ones (a host may write several times between two reads: the base's brake mode
and its velocity); writes that differ from the recording are counted (``diverged``): the
replayed host did not do what the live one did.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rfhoming.host.capture import DISCONNECTED, NOTE, SNIFFED, parse_description
from rfhoming.host.ports import Chunk, Disconnected, EndOfInput, Tap
from rfhoming.protocol import devices, pcapng

ANSWER_TIMEOUT = 2.0
MAX_PENDING_WRITES = 256  # writes not yet matched with the recording; beyond, the oldest go (diverged)


class Sequencer:
    """Releases the inbound chunks of several replay ports in their recorded global order.

    A port's next chunk goes out only when every earlier chunk of every port has been taken
    and its reader has come back for more (it has handled the previous one). The loop upstairs
    then sees its inputs in the order the live host did.

    ``lead``: a port's chunks recorded before its host first wrote go out at once, as bytes
    waiting in a port's buffer when it is opened do (a replay of drivers alone, with no loop
    to feed in order: a board's +STARTUP must reach its driver before its first AT, as live).
    """

    def __init__(self, packets: dict[str, list[pcapng.Packet]], *, lead: bool = False) -> None:
        self._free = {name: _lead(ps) if lead else 0 for name, ps in packets.items()}
        order = sorted((p.t, name, i) for name, ps in packets.items() for i, p in enumerate(ps)
                       if p.direction != pcapng.OUTBOUND and i >= self._free[name])
        self._order = [(name, i) for _, name, i in order]
        self._pos = 0
        self._moved = asyncio.Event()

    def free(self, name: str, index: int) -> bool:
        """Whether this chunk goes out at once (``lead``), outside the global order."""
        return index < self._free.get(name, 0)

    async def turn(self, name: str, index: int) -> None:
        """Wait until (name, index) is the next inbound chunk to release."""
        while self._pos < len(self._order) and self._order[self._pos] != (name, index):
            self._moved.clear()
            await self._moved.wait()

    def taken(self) -> None:
        self._pos += 1
        self._moved.set()


class ReplayPort:
    """``match_writes``: the recorded writes are made again by whoever replays (a driver's
    set-up, the homing loop's commands) and are matched; False for writes nobody will make
    (the loop's, in a replay of the drivers alone), which are then passed over at once."""

    is_file = True  # its reader may wait for its consumers (host/drivers/common.py Driver._read)

    def __init__(self, name: str, packets: list[pcapng.Packet], *, speed: float | None = None,
                 sequencer: Sequencer | None = None, match_writes: bool = True,
                 description: dict[str, str] | None = None) -> None:
        self.name = self.spec = name
        self.description = description or {}  # the interface's recorded facts (a ROS 2 base's topics)
        self.packets = packets
        self.speed = speed
        self.baud = 115200
        self.taps: list[Tap] = []
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0,
                         "disconnects": 0, "dropped_bytes": 0, "diverged": 0, "unanswered": 0}
        self._i = 0
        self._writes: deque[bytes] = deque(maxlen=MAX_PENDING_WRITES)  # made, not yet matched
        self._written = asyncio.Event()
        self._open = False
        self._t0: tuple[float, float] | None = None
        self.sequencer = sequencer
        self._holding = False
        self.match_writes = match_writes
        self._wait = match_writes  # for a recorded write not made yet; not once the host went its own way
        self.first_divergence: dict[str, Any] | None = None  # where the replayed host first wrote otherwise

    @property
    def is_open(self) -> bool:
        return self._open

    async def open(self) -> None:
        if self._i >= len(self.packets):
            raise EndOfInput(f"{self.name}: end of capture")
        self._open = True
        self.counters["opens"] += 1

    def set_baud(self, baud: int) -> None:
        self.baud = baud

    async def read(self) -> Chunk:
        if self._holding and self.sequencer is not None:  # the reader is back: the chunk it had is handled
            self._holding = False
            self.sequencer.taken()
        while self._i < len(self.packets):
            p = self.packets[self._i]
            self._i += 1
            if p.direction == pcapng.OUTBOUND:
                if self.match_writes:
                    await self._await_write(p)
                continue
            sequencer = self.sequencer if self.sequencer is not None and not self.sequencer.free(self.name, self._i - 1) \
                else None  # this chunk waits for its turn
            ordered = sequencer is not None
            if sequencer is not None:
                await sequencer.turn(self.name, self._i - 1)
            if p.comment == DISCONNECTED:
                if sequencer is not None:
                    sequencer.taken()
                self._open = False
                self.counters["disconnects"] += 1
                for tap in self.taps:  # as a live port's taps hear it go
                    tap(self.name, "lost", p.t, b"")
                raise Disconnected(f"{self.name}: disconnected here in the recording")
            self._holding = ordered
            await self._pace(p.t)
            for tap in self.taps:
                tap(self.name, "in", p.t, p.data)
            self.counters["bytes_in"] += len(p.data)
            self.counters["chunks_in"] += 1
            return Chunk(p.t, p.data)
        self._open = False
        raise EndOfInput(f"{self.name}: end of capture")

    async def _await_write(self, expected: pcapng.Packet) -> None:
        """The live host wrote here: match the replayed host's next write, waiting for it if
        it has not come yet (until it diverged). Only the oldest unmatched write will do: keeping
        just the latest would pair two writes in a row with one recorded write and leave the next
        unanswered."""
        if not self._writes and not self._wait:
            return
        if not self._writes:
            self._written.clear()
            try:
                async with asyncio.timeout(ANSWER_TIMEOUT):  # not wait_for: on 3.11 it can swallow a
                    await self._written.wait()                # cancellation that meets the awaited write
            except TimeoutError:
                self.counters["unanswered"] += 1
                self._diverged(expected, None)
                return
        wrote = self._writes.popleft()
        if wrote != expected.data:
            self.counters["diverged"] += 1
            self._diverged(expected, wrote)

    def _diverged(self, expected: pcapng.Packet, wrote: bytes | None) -> None:
        """The replayed host no longer does what the live one did: say where, and from here on
        release the recorded inputs without waiting for writes that will not come."""
        if self.first_divergence is None:
            self.first_divergence = {"device": self.name, "t": expected.t, "recorded": expected.data.hex(),
                                     "wrote": None if wrote is None else wrote.hex()}
        self._wait = False

    def write(self, data: bytes) -> None:
        for tap in self.taps:  # a capture of the replayed run hears the host, as on a live port
            tap(self.name, "out", time.time(), data)
        self.counters["bytes_out"] += len(data)
        if len(self._writes) == self._writes.maxlen:  # the oldest is never matched now
            self.counters["diverged"] += 1
        self._writes.append(data)
        self._written.set()

    async def _pace(self, t: float) -> None:
        if not self.speed:  # as fast as possible: a chunk that is due is there, as in a port's buffer
            return
        if self._t0 is None:
            self._t0 = (t, time.monotonic())
        due = self._t0[1] + (t - self._t0[0]) / self.speed
        await asyncio.sleep(max(0.0, due - time.monotonic()))

    async def close(self) -> None:
        self._open = False


def _lead(packets: list[pcapng.Packet]) -> int:
    """How many of a port's first packets came in before its host first wrote; none if it
    never wrote (a recording of inbound bytes alone goes wholly in the global order)."""
    return next((i for i, p in enumerate(packets) if p.direction == pcapng.OUTBOUND), 0)


def load_capture(path: Path | str, *, partial: Callable[[pcapng.CaptureFormatError], None] | None = None
                 ) -> tuple[list[pcapng.Interface], dict[int, list[pcapng.Packet]], int]:
    """Interfaces, packets per interface, and the size of a torn tail (0 if the file is whole).

    The packets are those the live drivers handled: bytes recorded while a port's protocol was
    sniffed (comment ``sniffed``) and the host's notes (:func:`notes`) are in the file for the
    record, not replayed.

    A malformed capture raises :class:`~rfhoming.protocol.pcapng.CaptureFormatError` (offset and
    problem). Given ``partial``, the error goes to it instead and everything before the bad block
    is returned, the bytes from there on counted as the tail; it still raises if nothing before
    the bad block was an interface.
    """
    interfaces, per, torn, _ = read_capture(path, partial=partial)
    return interfaces, per, torn


def read_capture(path: Path | str, *, partial: Callable[[pcapng.CaptureFormatError], None] | None = None
                 ) -> tuple[list[pcapng.Interface], dict[int, list[pcapng.Packet]], int, list[str]]:
    """:func:`load_capture`, and the section headers' comments (a homing run's record)."""
    data = Path(path).read_bytes()
    reader = pcapng.Reader()
    try:
        interfaces, packets, torn = pcapng.read_sections(data, reader)
    except pcapng.CaptureFormatError as exc:
        interfaces = [i for i in exc.items if isinstance(i, pcapng.Interface)]
        if not partial or not interfaces:
            raise
        partial(exc)
        packets, torn = [i for i in exc.items if isinstance(i, pcapng.Packet)], len(data) - exc.offset
    per: dict[int, list[pcapng.Packet]] = {i: [] for i in range(len(interfaces))}
    for p in packets:
        if p.comment not in (SNIFFED, NOTE):
            per[p.interface_id].append(p)
    return interfaces, per, torn, reader.comments


def notes(path: Path | str) -> list[dict[str, Any]]:
    """The host's notes in a capture (:meth:`~host.capture.CaptureWriter.note`), in order."""
    reader = pcapng.Reader()
    try:
        _, packets, _ = pcapng.read_sections(Path(path).read_bytes(), reader)
    except pcapng.CaptureFormatError as exc:  # a torn capture: the notes before the tear
        packets = [i for i in exc.items if isinstance(i, pcapng.Packet)]
    return [json.loads(p.data) for p in packets if p.comment == NOTE]


def describe(iface: pcapng.Interface) -> dict[str, Any]:
    wire = devices.by_linktype(iface.linktype)
    return {"protocol": wire.name if wire else None, **parse_description(iface.description)}
