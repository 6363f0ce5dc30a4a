"""What every driver shares: the reconnect loop, the chunk reader and the health snapshot."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from rfhoming.host.bearing import Bearing
from rfhoming.host.ports import (
    Disconnected,
    EndOfInput,
    HostPort,
    Port,
    PortError,
    flapping_delay,
    Tap,
    reopen,
)
from rfhoming.host.portspec import PortSpec, PortSpecError

if TYPE_CHECKING:
    from rfhoming.host.homing.config import Config

log = logging.getLogger(__name__)
T = TypeVar("T")
DEFAULT_BAUD = 115200


def serial_port(spec: PortSpec, taps: list[Tap]) -> HostPort:
    """The port a spec names, at its baud rate (115,200 if it gives none) and flow control
    (``auto``: the device table's default for its kind, on for the XPLR-AOA)."""
    record = spec.device
    auto = record is not None and record.rtscts
    rtscts = auto if spec.flow in (None, "auto") else spec.flow == "rtscts"
    return HostPort(spec.where, baud=spec.baud or DEFAULT_BAUD, rtscts=rtscts, name=spec.name or spec.where, taps=taps)


class CommandFailed(Exception):
    """A device refused a set-up command or did not answer it; the message says which."""


def scan_settings(spec: PortSpec, setup: Any, **extra: Any) -> Any:
    """A BLE receiver's scan settings from a spec (active, interval, window, timeout, and the
    kind's own ``extra`` fields) over ``setup``; a window left out follows a shorter interval.
    PortSpecError when the set-up refuses the combination."""
    s = spec.settings
    interval = s.get("interval", setup.interval_ms)
    try:
        return replace(setup, active=s.get("active", setup.active), interval_ms=interval,
                       window_ms=s.get("window", min(setup.window_ms, interval)),
                       command_timeout=spec.timeout or setup.command_timeout, **extra)
    except ValueError as exc:
        raise PortSpecError(f"{spec}: {exc}") from None


class BoundedStream(Generic[T]):
    """A bounded queue of readings: when the consumer lags, the oldest go first (counted).

    A stream nobody reads (``listen`` and ``capture`` show the items to listeners instead)
    keeps only the newest and counts no loss: nothing was waiting for what it overwrote.

    A file can wait where a live port cannot: while a recording's chunk is decoded
    (:meth:`filling`) a read stream takes every item, over its bound by that chunk's items at
    most, and the recording waits (:meth:`room`) before its next chunk until the consumer has
    taken enough."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._items: deque[T] = deque()
        self._ready = asyncio.Event()
        self._taken = asyncio.Event()
        self._read = False
        self._filling = 0
        self.dropped = 0

    def put(self, item: T) -> None:
        if len(self._items) >= self.size and not (self._filling and self._read):
            self._items.popleft()
            if self._read:
                self.dropped += 1
        self._items.append(item)
        self._ready.set()

    @contextlib.contextmanager
    def filling(self) -> Iterator[None]:
        """Every item put meanwhile is kept (a recording's chunk, which then waits for :meth:`room`)."""
        self._filling += 1
        try:
            yield
        finally:
            self._filling -= 1

    async def room(self) -> None:
        """Until the stream is below its bound (at once if nobody reads it: nothing would)."""
        while self._read and len(self._items) >= self.size:
            self._taken.clear()
            await self._taken.wait()

    def get_nowait(self) -> T | None:
        """The oldest item, or None when there is none (no await: the loop's fast path)."""
        self._read = True
        if not self._items:
            return None
        self._taken.set()
        return self._items.popleft()

    async def get(self) -> T:
        self._read = True
        while not self._items:
            self._ready.clear()
            await self._ready.wait()
        self._taken.set()
        return self._items.popleft()

    def __len__(self) -> int:
        return len(self._items)

    def unread(self) -> list[T]:
        """The items waiting, oldest first, without taking them (what a run left unread)."""
        return list(self._items)

    async def __aiter__(self) -> AsyncIterator[T]:
        while True:
            yield await self.get()


@dataclass(frozen=True)
class Wiring:
    """What the program opening a driver offers it; the driver's :meth:`Driver.options` takes
    what its kind needs. ``role``, ``config``: a homing run's (host/homing/assembly.py), None
    outside one (``listen``, ``capture``, the Python API)."""

    role: str | None = None
    config: Config | None = None
    choose_tag_s: float | None = None  # no tag chosen: listen this long, then home on the only one heard
    probe_baud: bool = False  # a board sending only garbage is probed at every documented rate


class Driver:
    """Base of the drivers: keeps the port open (re-opening with back-off) and feeds chunks.

    Subclasses implement :meth:`on_chunk` (decode and route) and may extend :meth:`session`
    (work to do after each open, e.g. the AoA board's set-up). Readings go to ``out``, the
    stream the driver was given when built (a homing loop gives every driver its one input
    stream), or the driver's own bounded stream of ``queue_size``.
    """

    kind = "device"  # the device table's name for what it drives (rfhoming.protocol.devices)
    sets_up = False
    """Whether it is ready only once its set-up commands succeeded (state ``streaming``), not
    as soon as its port is open."""
    items: tuple[type, ...] = ()
    """Every type of item it shows its listeners: rfhoming.api.Item is their union (checked by
    tests/test_api_kinds.py)."""
    poke = b""
    """What to say to a silent port while sniffing (its record's ``sniff`` is not 0), to make a
    device of this kind answer."""

    @classmethod
    def speaks(cls, data: bytes) -> bool:
        """Whether ``data``, read from a port of unknown kind, shows this kind (one whose record's ``sniff`` is not 0)."""
        return False

    @classmethod
    def options(cls, wiring: Wiring) -> dict[str, Any]:
        """The constructor options its kind takes from the program opening it (a run's config)."""
        return {}

    @classmethod
    def describe_spec(cls, spec: PortSpec) -> dict[str, str]:
        """What a capture's interface records of a spec besides its kind (a ROS 2 base's topics)."""
        return {}

    def sent(self, data: bytes) -> list[Any]:
        """The items in bytes the host wrote to it (an export's commands from a capture)."""
        return []

    def __init__(self, port: Port, *, reconnect: bool = True, out: BoundedStream[Any] | None = None,
                 queue_size: int = 1000) -> None:
        self.port = port
        self.reconnect = reconnect
        self.out: BoundedStream[Any] = out if out is not None else BoundedStream(queue_size)
        self.consumers: list[BoundedStream[Any]] = [self.out]
        """The streams this driver's items go to (its own, and any a listener fills): a
        recording waits for each of them to have room before its next chunk."""
        self.state = "closed"
        self.counters: dict[str, int] = {"reconnects": 0}
        self.latency: deque[float] = deque(maxlen=1000)  # seconds to handle one chunk
        self.connected = asyncio.Event()
        self.problem: str | None = None  # what keeps the device from working, in words
        self._needs_setup = asyncio.Event()
        self.listeners: list[Callable[[str, float, Any], None]] = []
        self.error: Exception | None = None
        """Why :meth:`run` ended with an exception (e.g. a port that never opened), for a
        supervisor that does not await the task itself."""
        self.contact_clock: Callable[[], float] = time.monotonic
        self.last_item: float | None = None
        """When the last reading arrived (monotonic), for :meth:`watch_quiet`."""
        self.streaming_at = 0.0
        self.opened_at: float | None = None
        """When the port last opened (``clock``); None before the first open."""
        self.answered_at: float | None = None
        """When the first bytes came after that open; None while the port has said nothing."""

    @property
    def contact_at(self) -> float | None:
        """Where a set-up deadline starts: the device's first bytes, or the open while it is
        silent (None before the open) -- not the moment the program started, which a loaded
        machine stretches."""
        return self.answered_at if self.answered_at is not None else self.opened_at

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> Driver:
        """The driver on the port a spec names, with the spec's settings; ``options`` go to
        the constructor; ``port``: one already made (a replay, the in-process pipe) in place of
        the spec's. Kinds with settings of their own (tags, scan timing) extend it."""
        return cls(port or serial_port(spec, taps), **options)

    def emit(self, t: float, item: Any) -> Any:
        """Show one decoded item (record, line or drop) to the listeners; returns it."""
        for listener in self.listeners:
            listener(self.port.name, t, item)
        return item

    def on_chunk(self, data: bytes, t_host: float) -> None:
        raise NotImplementedError

    async def session(self) -> None:
        """Called after every successful open, while the reader runs."""
        self.state = "streaming"

    async def keep_set_up(self) -> None:
        """For devices that need commands after every open and every reboot: run ``_set_up``,
        then again whenever ``_needs_setup`` is set; a refused set-up is retried each second,
        with the reason in ``problem`` and state ``setup_failed``."""
        while True:
            self._needs_setup.clear()
            try:
                await self._set_up()
            except CommandFailed as exc:
                self.state = "setup_failed"
                self.problem = str(exc)
                log.error("%s: set-up failed: %s", self.port.name, exc)
                await asyncio.sleep(1.0)
                continue
            await self._needs_setup.wait()

    async def _set_up(self) -> None:
        raise NotImplementedError

    def silent_hint(self) -> str:
        """What to check when the port says nothing at all."""
        return "is this the right port, and the device's baud rate?"

    def bearing(self, t: float, item: Any) -> Bearing | None:
        """The neutral reading in one of its items (a direction-finding board's angle report), or
        None: what ``locate``, calibration and the site bus read of a listener's items."""
        return None

    def cannot_go_on(self) -> str | None:
        """Why it cannot serve although its port is fine (an AoA board hearing several tags and
        told to choose one), or None."""
        return None

    async def watch_quiet(self, timeout: float, what: str, hint: Callable[[], str]) -> None:
        """Set up (``streaming``), yet no ``what`` for ``timeout`` s: say in ``problem`` (and the
        log, once per silence; counter ``silent``) why that may be. Subclasses stamp
        ``last_item`` and ``streaming_at``."""
        warned = False
        while True:
            await asyncio.sleep(min(0.5, timeout / 4))
            if self.state != "streaming":
                continue
            quiet = time.monotonic() - max(self.last_item or 0.0, self.streaming_at)
            if quiet < timeout:
                if warned and self.problem and self.problem.startswith(f"no {what}"):
                    self.problem = None  # items again
                warned = False
            elif not warned:
                warned = True
                self.counters["silent"] = self.counters.get("silent", 0) + 1
                self.problem = f"no {what} for {timeout:g} s although it is set up: {hint()}"
                log.warning("%s: %s", self.port.name, self.problem)

    async def run(self) -> None:
        """Open, read and route until cancelled; reconnect when the device goes away.
        The port is closed when this ends, however it ends."""
        try:
            await self._run()
        except Exception as exc:
            self.error = exc
            raise
        finally:
            await self.port.close()

    async def _run(self) -> None:
        first = True
        while True:
            self.state = "opening"
            try:
                if first:
                    await self.port.open()
                else:
                    await reopen(self.port)
            except EndOfInput:
                self.state = "ended"
                return
            except PortError as exc:
                if first:
                    raise  # a port that never opened is a user error: say so at once
                log.warning("%s: %s", self.port.name, exc)
                continue
            if not first:
                self.counters["reconnects"] += 1
            first = False
            self.opened_at, self.answered_at = self.contact_clock(), None
            self.connected.set()
            reader = asyncio.create_task(self._read())
            setup = asyncio.create_task(self.session())
            try:
                await reader
            except Disconnected:
                self.state = "disconnected"
            except EndOfInput:
                self.state = "ended"
                return
            finally:
                self.connected.clear()
                setup.cancel()
                reader.cancel()
            if not self.reconnect:
                return
            await asyncio.sleep(flapping_delay(getattr(self.port, "short_lived", 0)))

    def drain(self) -> None:
        """At shutdown: decode what arrived but was not read yet, so nothing that a capture
        recorded goes undecoded."""
        take = getattr(self.port, "take_pending", None)
        for chunk in take() if take else ():
            self.on_chunk(chunk.data, chunk.t)

    async def _read(self) -> None:
        recording = getattr(self.port, "is_file", False)  # a file can wait for its consumers; a live port cannot
        while True:
            chunk = await self.port.read()
            if self.answered_at is None:
                self.answered_at = self.contact_clock()
            start = time.perf_counter()
            if recording:
                with contextlib.ExitStack() as keeping:
                    for stream in self.consumers:
                        keeping.enter_context(stream.filling())
                    self.on_chunk(chunk.data, chunk.t)
            else:  # a live port: no stack to keep (this runs for every chunk)
                self.on_chunk(chunk.data, chunk.t)
            self.latency.append(time.perf_counter() - start)
            for stream in self.consumers if recording else ():
                await stream.room()

    def health(self) -> dict[str, Any]:
        """Counters of the port, the decoder and the driver, plus handling latency."""
        lat = sorted(self.latency)
        p = (lambda q: round(lat[min(len(lat) - 1, int(q * len(lat)))] * 1e6, 1)) if lat else (lambda q: None)
        return {"device": self.port.name, "driver": self.kind, "state": self.state,
                **self.port.counters, **self.counters, "latency_us_p50": p(0.5), "latency_us_p99": p(0.99)}
