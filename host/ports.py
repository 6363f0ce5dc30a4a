"""Serial ports for the host: a device path, a pyserial URL or ``auto``, opened with asyncio.

One string opens anything: ``/dev/ttyACM0``, ``COM3``, a pty, ``socket://127.0.0.1:PORT``
(the emulator's TCP mode), or ``auto`` (the one recognised device of the wanted kind, see
:mod:`rfhoming.host.discovery`). Every chunk read or written passes the port's taps with a host
timestamp -- capture and metrics hang there. A failed open raises :class:`PortError` whose
message says how to fix it; a vanished device ends :meth:`HostPort.read` with
:class:`Disconnected`, and :func:`reopen` retries with back-off.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import time
from collections.abc import Callable
from typing import NamedTuple, Protocol

import serial
import serial_asyncio_fast

from rfhoming.host import hotplug
from rfhoming.protocol.errors import Error

log = logging.getLogger(__name__)

Tap = Callable[[str, str, float, bytes], None]
"""tap(port_name, direction, host time in seconds, bytes). direction: 'in', 'out', 'lost', or
'sniffed-in'/'sniffed-out' for bytes that crossed while the protocol was sniffed, before any
driver owned the port (:func:`rfhoming.host.session.open_drivers`)."""

MAX_BACKLOG = 1 << 20


class Chunk(NamedTuple):
    """Bytes as one read returned them, with the host time they arrived."""

    t: float
    data: bytes


class Port(Protocol):
    """What a driver uses of its port: a :class:`HostPort`, or a port standing in for one
    (host/replay.py's ReplayPort, a TCP or ROS 2 port)."""

    spec: str
    name: str
    baud: int
    taps: list[Tap]
    counters: dict[str, int]

    @property
    def is_open(self) -> bool: ...
    async def open(self) -> None: ...
    async def read(self) -> Chunk: ...
    def write(self, data: bytes) -> None: ...
    def set_baud(self, baud: int) -> None: ...
    async def close(self) -> None: ...


class PortError(Error):
    """A port that cannot be opened or used; the message says what to do."""


class Disconnected(PortError):
    """The device went away (unplugged, emulator stopped)."""


class EndOfInput(Exception):
    """A recording has nothing more to give: the driver stops instead of reconnecting."""


def explain(spec: str, exc: BaseException) -> str:
    """Turn an OS/pyserial error into a sentence that says how to fix it."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if spec.startswith("socket://"):
        return (f"nothing answers at {spec} ({text}); is `rfhoming emulate --tcp` (or the device "
                "server) running, and is the port the one it printed?")
    if code == errno.ENOENT or "No such file" in text:
        return (f"no device at {spec}: is it plugged in? `rfhoming devices` lists the serial ports "
                "this machine sees")
    if code == errno.EACCES or "Permission denied" in text:
        return (f"permission denied on {spec}: add yourself to the group that owns it "
                "(usually: sudo usermod -aG dialout $USER, then log out and in again)")
    if code in (errno.EAGAIN, errno.EBUSY) or "lock" in text.lower() or "busy" in text.lower():
        return (f"{spec} is busy: another program has it open (a terminal such as screen or "
                "minicom, ModemManager, or another rfhoming); close it and try again")
    return f"cannot open {spec}: {text}"


class _Protocol(asyncio.Protocol):
    def __init__(self, port: HostPort) -> None:
        self.port = port

    def data_received(self, data: bytes) -> None:
        self.port._received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.port._lost(exc)


class HostPort:
    """One serial connection with taps, counters and a bounded receive backlog."""

    def __init__(self, spec: str, *, baud: int = 115200, rtscts: bool = False,
                 name: str | None = None, taps: list[Tap] | None = None,
                 clock: Callable[[], float] = lambda: round(time.time() * 1e6) / 1e6) -> None:
        self.spec = spec
        self.name = name or spec
        self.baud = baud
        self.rtscts = rtscts
        self.taps: list[Tap] = list(taps or [])
        self.clock = clock
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0,
                         "disconnects": 0, "dropped_bytes": 0}
        self._transport: serial_asyncio_fast.SerialTransport | None = None
        self._opened_at = 0.0
        self.short_lived = 0
        """Connections in a row that ended within STABLE_S of opening (0 once one lasts)."""
        self._gone = asyncio.Event()
        self._queue: asyncio.Queue[Chunk | None] = asyncio.Queue()
        self._backlog = 0

    @property
    def is_open(self) -> bool:
        return self._transport is not None

    async def open(self) -> None:
        """Open the port; PortError explains a failure."""
        loop = asyncio.get_running_loop()
        kwargs = {"baudrate": self.baud, "rtscts": self.rtscts}
        if not self.spec.startswith(("socket://", "loop://")):
            kwargs["exclusive"] = True
        try:
            transport, _ = await serial_asyncio_fast.create_serial_connection(
                loop, lambda: _Protocol(self), self.spec, **kwargs)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PortError(explain(self.spec, exc)) from None
        _gone_is_a_disconnect(transport)
        self._transport = transport
        self._gone = asyncio.Event()
        self._queue = asyncio.Queue()
        self._backlog = 0
        self._opened_at = time.monotonic()
        self.counters["opens"] += 1

    def set_baud(self, baud: int) -> None:
        """Change the rate on the open port (probing, or following AT+UMRS)."""
        self.baud = baud
        if self._transport is not None and self._transport.serial is not None:
            self._transport.serial.baudrate = baud

    def _received(self, data: bytes) -> None:
        now = self.clock()
        for tap in self.taps:
            tap(self.name, "in", now, data)
        self.counters["bytes_in"] += len(data)
        self.counters["chunks_in"] += 1
        if self._backlog + len(data) > MAX_BACKLOG:
            self.counters["dropped_bytes"] += len(data)
            log.warning("%s: reader fell %d bytes behind; dropping", self.name, self._backlog)
            return
        self._backlog += len(data)
        self._queue.put_nowait(Chunk(now, data))

    def _lost(self, exc: Exception | None) -> None:
        if self._transport is not None:
            self.counters["disconnects"] += 1
            lived = time.monotonic() - self._opened_at
            self.short_lived = self.short_lived + 1 if lived < STABLE_S else 0
            if self.short_lived <= 1:  # once per streak of connections that drop at once
                log.warning("%s: disconnected (%s)%s", self.name, exc or "closed", "" if not self.short_lived else
                            f" {lived:.1f} s after opening; reopened with back-off up to {REOPEN_LONGEST_S:g} s while "
                            "it keeps dropping at once (another program holding the device?); counted, not logged again")
            else:
                log.debug("%s: disconnected (%s), %d in a row", self.name, exc or "closed", self.short_lived)
            for tap in self.taps:
                tap(self.name, "lost", self.clock(), b"")
        self._transport = None
        self._gone.set()
        self._queue.put_nowait(None)

    async def read(self) -> Chunk:
        """The next chunk as it arrived; Disconnected when the device has gone."""
        chunk = await self._queue.get()
        if chunk is None:
            raise Disconnected(f"{self.name} disconnected")
        self._backlog -= len(chunk.data)
        return chunk

    def take_pending(self) -> list[Chunk]:
        """Chunks that arrived but were not read yet (for a clean shutdown)."""
        chunks = []
        while not self._queue.empty():
            chunk = self._queue.get_nowait()
            if chunk is not None:
                self._backlog -= len(chunk.data)
                chunks.append(chunk)
        return chunks

    def write(self, data: bytes) -> None:
        if self._transport is None:
            raise Disconnected(f"{self.name} is not open")
        now = self.clock()
        for tap in self.taps:
            tap(self.name, "out", now, data)
        self.counters["bytes_out"] += len(data)
        self._transport.write(data)

    async def close(self) -> None:
        transport, self._transport = self._transport, None
        if transport is not None:
            transport.close()  # the fd (and its exclusive lock) goes when connection_lost runs
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0):
                    await self._gone.wait()


def _gone_is_a_disconnect(transport: serial_asyncio_fast.SerialTransport) -> None:
    """A device gone under a write (unplugged, its emulator ended first at a shutdown) is a
    disconnect, which connection_lost reports in one line (HostPort._lost); the transport
    would also hand it to the event loop's exception handler, which prints a traceback."""
    fatal = getattr(transport, "_fatal_error", None)
    if fatal is None or not hasattr(transport, "_abort"):  # a pyserial-asyncio-fast without them: its own way
        return

    def fatal_error(exc: BaseException, message: str = "Fatal error on serial transport") -> None:
        if isinstance(exc, (serial.SerialException, OSError)):
            transport._abort(exc)
        else:
            fatal(exc, message)

    transport._fatal_error = fatal_error  # type: ignore[method-assign]


STABLE_S = 5.0
"""A connection that ends sooner than this after opening is part of a streak of drops: the
driver backs off before the next reopen, and only the streak's first drop is logged."""
REOPEN_FIRST_S = 0.2
REOPEN_LONGEST_S = 5.0


def flapping_delay(short_lived: int) -> float:
    """Seconds to wait before reopening after ``short_lived`` connections in a row dropped at
    once: 0 after one that lasted, then 0.2 s doubling to 5 s (a device that accepts and drops,
    such as an endpoint another client holds, would otherwise be reopened in a busy loop)."""
    return 0.0 if short_lived <= 0 else min(REOPEN_FIRST_S * 2 ** min(short_lived - 1, 16), REOPEN_LONGEST_S)


async def reopen(port: Port, *, first: float = REOPEN_FIRST_S, longest: float = REOPEN_LONGEST_S,
                 attempts: int | None = None) -> None:
    """Open ``port``, retrying with doubling back-off until it works (or ``attempts`` run out).
    A device path that has vanished (unplugged) is watched instead and reopened as soon as it
    is back (:mod:`rfhoming.host.hotplug`), with the back-off started over."""
    delay, tries = first, 0
    while True:
        try:
            await port.open()
            return
        except PortError as exc:
            tries += 1
            if attempts is not None and tries >= attempts:
                raise
            log.info("%s: %s; retrying in %.1f s, or when it is plugged in again", port.name, exc, delay)
            if await hotplug.wait_for_return(port.spec, delay):
                delay = first
            else:
                delay = min(delay * 2, longest)
