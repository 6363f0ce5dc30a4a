"""The public Python API: devices by port spec, decoded items as plain typed objects.

``rfhoming.open(spec)`` gives a :class:`Devices` handle, ``rfhoming.read(spec)`` iterates its
items; both work with ``for``/``with`` and with ``async for``/``async with``. A handle owns the
same drivers as ``rfhoming listen`` (set-up, reconnect, reboot recovery), so a program gets what
the command line prints; ``capture=`` records what ``rfhoming capture`` records. Every item
carries its wire bytes (``raw``). :class:`Reader` decodes a stream the caller opened.
docs/api.md is the guide; every example there runs in the tests.
"""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
from collections.abc import AsyncIterator, Collection, Iterable, Iterator
from pathlib import Path
from typing import (
    TYPE_CHECKING,
    Any,
    Generic,
    Literal,
    NamedTuple,
    Protocol,
    TypeAlias,
    TypedDict,
    TypeVar,
    Union,
    Unpack,
    get_args,
)
from typing import overload as _overload

from rfhoming.host import losses
from rfhoming.host.capture import CaptureWriter, describe_dialects
from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.portspec import PortSpec
from rfhoming.host.session import health, open_drivers
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.errors import Error
from rfhoming.protocol.espat import Event, Final, Info, ScanReport
from rfhoming.protocol.frames.records import (
    AdvReport,
    AntennaSet,
    LogText,
    NodeCommand,
    Odometry,
    RangeScan,
    RangeScanV2,
    RfFrame,
    Status,
    VelocityCommand,
)
from rfhoming.protocol.jsonable import as_dict
from rfhoming.protocol.uconnect.items import AngleEvent, Echo, FinalCode, InfoLine, Startup, TagData, UnknownLine
from rfhoming.reader import H4Packet, decode_stream, read_function, stream_protocol, track

if TYPE_CHECKING:  # bumble's, imported only with an hci: port
    from rfhoming.host.drivers.hci import Advertisement, HciPacket

QUEUE_SIZE = 10_000
"""Items held for a slow reader; beyond this a live device's oldest are dropped and counted,
while a recording waits for the reader."""
HAND_OVER_WAIT = 0.005  # seconds between tries to hand a recording's item to a caller who lags

CHATTER = frozenset({"echo", "info", "final"})
"""The AT conversation the driver holds with the board: not yielded unless asked for."""


Item: TypeAlias = Union[
    AngleEvent, TagData, Startup, Echo, InfoLine, FinalCode, UnknownLine,  # XPLR-AOA (u-connectLocate)
    AdvReport, RfFrame, AntennaSet, Status, Odometry, VelocityCommand, RangeScan, RangeScanV2, LogText, NodeCommand,  # framed
    ScanReport, Info, Final, Event,  # ESP-AT
    "Advertisement", "HciPacket", H4Packet,  # HCI (H4Packet: a Reader over h4)
    Drop,
]
"""Every item a device can yield; narrow it with ``match item.kind`` or ``isinstance`` (or ask ``open``
for one kind)."""

ItemT = TypeVar("ItemT", bound=Item, covariant=True)

Kind: TypeAlias = Literal[
    "angle", "tag_data", "startup", "echo", "info", "final", "unknown",
    "adv_report", "rf_frame", "antenna_set", "status", "odometry", "velocity_command", "range_scan", "range_scan_v2",
    "log_text", "node_command", "scan_report", "event", "advertisement", "hci", "h4_packet", "drop",
]
"""The ``kind`` of every :data:`Item`: what ``kinds=`` takes, so a type checker flags a misspelt one."""
KINDS: tuple[str, ...] = get_args(Kind)


class UnknownKind(Error, ValueError):
    """``kinds=`` names a kind no device yields (a typo would otherwise yield nothing, silently)."""


def _kinds(kinds: Iterable[str] | None) -> frozenset[str] | None:
    """``kinds`` checked against :data:`KINDS`; UnknownKind lists them."""
    if kinds is None:
        return None
    if isinstance(kinds, str):  # "angle" would be the kinds "a", "n", ...
        raise UnknownKind(f"kinds={kinds!r}: give a collection of kinds, e.g. kinds={{{kinds!r}}}")
    chosen = frozenset(kinds)
    unknown = sorted(chosen - set(KINDS))
    if unknown:
        raise UnknownKind(f"kinds: unknown {', '.join(map(repr, unknown))}; the kinds are {', '.join(KINDS)}")
    return chosen


class Received(NamedTuple, Generic[ItemT]):
    """One decoded item, with the host time its bytes arrived, the device it came from and
    ``raw``, its exact bytes on the wire (the line with its CR LF, the COBS frame with its
    zeros, the H4 packet; docs/api.md says what they are for each protocol)."""

    t: float
    device: str
    item: ItemT
    raw: bytes = b""

    @property
    def kind(self) -> str:
        return str(self.item.kind)

    def to_dict(self) -> dict[str, Any]:
        """``{"device", "t", "kind", <fields>}``: the form ``rfhoming listen --json`` prints (no raw)."""
        return {"device": self.device, "t": self.t, **as_dict(self.item)}


class Devices(Generic[ItemT]):
    """Open devices: iterate to get :class:`Received` items; ``health()`` for counters.

    ``specs`` are port specs (``xplr-aoa:/dev/ttyUSB0,baud=1000000,tags=...``,
    ``capture:run.pcapng``, ``auto`` ...). ``kinds`` keeps only those item kinds (``"angle"``,
    ``"adv_report"``, ``"drop"`` ...: :data:`KINDS`; another is refused with :class:`UnknownKind`);
    by default everything but the AT conversation.
    ``duration`` ends the stream after that many seconds; a capture ends by itself.
    ``capture``: a pcapng file to record every byte both ways, as ``rfhoming capture -o`` does
    (a path: created, and closed when the stream ends; a :class:`CaptureWriter`: written to,
    left open for its owner).
    """

    def __init__(self, *specs: str | PortSpec, kinds: Iterable[Kind] | None = None,
                 duration: float | None = None, baud: int | None = None, flow: str | None = None,
                 capture: str | Path | CaptureWriter | None = None) -> None:
        if not specs:
            raise ValueError("give at least one port spec, e.g. rfhoming.open('xplr-aoa:/dev/ttyUSB0')")
        self.specs = specs
        self.kinds = _kinds(kinds)
        self.duration = duration
        self.baud, self.flow = baud, flow
        self.capture = capture
        self.recording: CaptureWriter | None = None  # the capture being written, while streaming
        self.drivers: list[Driver] = []
        self.dropped = 0
        self._thread: threading.Thread | None = None
        self._stop: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def wanted(self, kind: str) -> bool:
        return kind in self.kinds if self.kinds is not None else kind not in CHATTER

    def health(self) -> list[dict[str, Any]]:
        """Per device: state, port/decoder/driver counters, handling latency."""
        return health(self.drivers)

    # -- asynchronous -------------------------------------------------------------------
    async def stream(self) -> AsyncIterator[Received[ItemT]]:
        """Open the devices, yield their items until ``duration``, the end of a capture, or
        until the consumer stops; the devices are closed however it ends. PortError / ValueError
        say why a device could not be opened."""
        items: BoundedStream[Received[ItemT] | None] = BoundedStream(QUEUE_SIZE)

        def listener_of(driver: Driver) -> Any:
            tracker = track(driver)
            driver.consumers.append(items)  # a recording waits for the caller to take its items

            def listener(device: str, t: float, item: Any) -> None:
                if self.wanted(item.kind):
                    before = items.dropped
                    items.put(Received(t, device, item, tracker.current))
                    self.dropped += items.dropped - before
            return listener

        capture = self.recording = (CaptureWriter(self.capture) if isinstance(self.capture, (str, Path))
                                    else self.capture)
        try:
            self.drivers = await open_drivers(list(self.specs), baud=self.baud, flow=self.flow,
                                              taps=[capture.tap] if capture else [],
                                              describe=capture.describe if capture else None)
        except BaseException:
            self._end_capture()
            raise
        for driver in self.drivers:
            driver.listeners.append(listener_of(driver))
        tasks = [asyncio.create_task(d.run()) for d in self.drivers]
        dialects = asyncio.create_task(describe_dialects(self.drivers, capture)) if capture else None
        lost = asyncio.create_task(losses.watch(self.health))
        self._stop = stopped = asyncio.Event()

        async def watch() -> None:
            """End the stream on stop, at ``duration``, when a driver fails or all have ended."""
            stop = asyncio.create_task(stopped.wait())
            clock = asyncio.get_running_loop()
            end = None if self.duration is None else clock.time() + self.duration
            try:
                while True:
                    timeout = None if end is None else max(0.0, end - clock.time())
                    done, _ = await asyncio.wait([*tasks, stop], timeout=timeout,
                                                 return_when=asyncio.FIRST_COMPLETED)
                    failed = any(t.done() and not t.cancelled() and t.exception() for t in tasks)
                    if not done or stop in done or failed or all(t.done() for t in tasks):
                        return
            finally:
                stop.cancel()
                await items.room()  # the end evicts no item
                items.put(None)

        watcher = asyncio.create_task(watch())
        try:
            while (got := await items.get()) is not None:
                yield got
            for task in tasks:
                if task.done() and not task.cancelled() and (error := task.exception()) is not None:
                    raise error
        finally:
            watcher.cancel()
            for task in [*tasks, lost, *([dialects] if dialects else [])]:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(BaseException):
                    await task
            for driver in self.drivers:
                await driver.port.close()
            self._end_capture()

    def _end_capture(self) -> None:
        """Close a capture this handle opened; flush one it was given."""
        capture, self.recording = self.recording, None
        if capture is not None and capture is not self.capture:
            capture.close()
        elif capture is not None:
            capture.flush()

    def __aiter__(self) -> AsyncIterator[Received[ItemT]]:
        return self.stream()

    async def __aenter__(self) -> Devices[ItemT]:
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._stop is not None:
            self._stop.set()

    # -- synchronous --------------------------------------------------------------------
    def __iter__(self) -> Iterator[Received[ItemT]]:
        """The same stream from a background event loop, for programs without asyncio."""
        out: queue.Queue[tuple[str, Any]] = queue.Queue(QUEUE_SIZE)

        async def pump() -> None:
            try:
                async for got in self.stream():
                    while not self._hand_over(out, got):
                        await asyncio.sleep(HAND_OVER_WAIT)
                await self._hand_last(out, ("end", None))
            except BaseException as exc:  # handed to the caller's thread below
                await self._hand_last(out, ("error", exc))

        def run() -> None:
            self._loop = asyncio.new_event_loop()
            try:
                self._loop.run_until_complete(pump())
            finally:
                self._loop.close()

        self._thread = threading.Thread(target=run, name="rfhoming-devices", daemon=True)
        self._thread.start()
        try:
            while True:
                what, value = out.get()
                if what == "item":
                    yield value
                elif what == "error":
                    raise value
                else:
                    return
        finally:
            self.close()

    def _hand_over(self, out: queue.Queue[tuple[str, Any]], got: Received[ItemT]) -> bool:
        """Put an item in the caller's queue; False while it is full and a recording can wait
        for the caller (until the stream is stopped), else the item is dropped and counted."""
        try:
            out.put_nowait(("item", got))
        except queue.Full:
            stopped = self._stop is not None and self._stop.is_set()
            if not stopped and any(getattr(d.port, "is_file", False) for d in self.drivers):
                return False
            self.dropped += 1
        return True

    async def _hand_last(self, out: queue.Queue[tuple[str, Any]], last: tuple[str, Any]) -> None:
        """The end (or the error) for a caller who still reads; nothing for one who has left
        (``close``): a full queue would otherwise hold this thread, and its devices, forever."""
        while True:
            try:
                out.put_nowait(last)
                return
            except queue.Full:
                if self._stop is not None and self._stop.is_set():
                    return
                await asyncio.sleep(HAND_OVER_WAIT)

    def close(self) -> None:
        """Stop the stream and close the devices (also on leaving ``with``)."""
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    def __enter__(self) -> Devices[ItemT]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Options(TypedDict, total=False):
    """The keyword options of :func:`open` and :func:`read` besides ``kinds``."""

    duration: float | None
    baud: int | None
    flow: str | None
    capture: str | Path | CaptureWriter | None


Spec: TypeAlias = "str | PortSpec"


class Opener(Protocol):
    """The signature of :func:`open` and :func:`read` for type checkers: asked for one kind,
    ``kinds={"angle"}``, the items are that kind's type (``Received[AngleEvent]``); otherwise
    any :data:`Item`."""

    # fmt: off
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["angle"]], **options: Unpack[Options]) -> Devices[AngleEvent]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["tag_data"]], **options: Unpack[Options]) -> Devices[TagData]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["startup"]], **options: Unpack[Options]) -> Devices[Startup]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["echo"]], **options: Unpack[Options]) -> Devices[Echo]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["info"]], **options: Unpack[Options]) -> Devices[InfoLine | Info]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["final"]], **options: Unpack[Options]) -> Devices[FinalCode | Final]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["unknown"]], **options: Unpack[Options]) -> Devices[UnknownLine]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["adv_report"]], **options: Unpack[Options]) -> Devices[AdvReport]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["rf_frame"]], **options: Unpack[Options]) -> Devices[RfFrame]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["antenna_set"]], **options: Unpack[Options]) -> Devices[AntennaSet]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["status"]], **options: Unpack[Options]) -> Devices[Status]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["odometry"]], **options: Unpack[Options]) -> Devices[Odometry]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["velocity_command"]], **options: Unpack[Options]) -> Devices[VelocityCommand]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["range_scan"]], **options: Unpack[Options]) -> Devices[RangeScan]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["log_text"]], **options: Unpack[Options]) -> Devices[LogText]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["node_command"]], **options: Unpack[Options]) -> Devices[NodeCommand]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["scan_report"]], **options: Unpack[Options]) -> Devices[ScanReport]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["event"]], **options: Unpack[Options]) -> Devices[Event]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["advertisement"]], **options: Unpack[Options]) -> Devices[Advertisement]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["hci"]], **options: Unpack[Options]) -> Devices[HciPacket]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Collection[Literal["drop"]], **options: Unpack[Options]) -> Devices[Drop]: ...
    @_overload
    def __call__(self, *specs: Spec, kinds: Iterable[Kind] | None = None, **options: Unpack[Options]) -> Devices[Item]: ...
    # fmt: on


def _open(*specs: Spec, **options: Any) -> Devices[Any]:
    """Devices by port spec; see :class:`Devices` for the options."""
    return Devices(*specs, **options)


def _read(*specs: Spec, **options: Any) -> Devices[Any]:
    """``for item in rfhoming.read(spec)`` / ``async for``: the devices' items as they arrive."""
    return Devices(*specs, **options)


class Reader:
    """Items decoded from a stream the caller opened -- a ``serial.Serial``, a socket, a binary
    file -- as ``pyubx2.UBXReader(stream)`` does: ``for got in rfhoming.Reader(port,
    protocol="uconnect")`` yields :class:`Received` items with their ``raw`` bytes.

    ``protocol``: a stream protocol (``uconnect``, ``frames``, ``esp-at``, ``h4``) or a device
    kind that speaks one (``xplr-aoa``). ``kinds`` keeps those item kinds (default: every item,
    the AT answers included: a Reader's caller holds the conversation). It reads and decodes
    only: no set-up, no reconnect. The iteration ends at the end of a file or when a socket's
    peer closes; a serial port's read timeout is not an end (it reads on). ``name`` is the
    ``device`` of the items (default: the port or file name)."""

    def __init__(self, stream: Any, protocol: str = "uconnect", *, kinds: Iterable[Kind] | None = None,
                 name: str | None = None) -> None:
        self.stream = stream
        self.protocol = stream_protocol(protocol)  # an unknown or non-stream protocol fails here
        read_function(stream)  # so does a stream that cannot be read
        self.kinds = _kinds(kinds)
        self.name = name

    def __iter__(self) -> Iterator[Received[Item]]:
        return decode_stream(self.stream, self.protocol, self.kinds, self.name, Received)


_open.__name__ = _open.__qualname__ = "open"  # what help() and tracebacks call them
_read.__name__ = _read.__qualname__ = "read"
open: Opener = _open  # noqa: A001 - the API's verb
read: Opener = _read
