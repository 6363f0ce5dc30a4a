"""Raw bytes with every decoded item, and a reader over a stream the caller opened.

The decoders of :mod:`rfhoming.protocol` take bytes in any chunking and give items; they do not
say which bytes made which item. :class:`Framer` cuts the stream where the protocol's decoder
frames it and feeds the decoder one unit at a time, so that each item comes with its exact wire
bytes (as pyubx2 yields ``(raw, parsed)``):

- ``uconnect`` (XPLR-AOA): a line with the terminator that ended it -- CR LF, or a lone CR or
  LF as the decoder also accepts; a CR that ends one read is a terminator of its own (the LF
  after it, read later, is a blank line, in no item's bytes). Blank lines (around every URC)
  belong to no item.
- ``esp-at``: a line through its LF (its CRs included), as the decoder splits.
- ``frames``: the COBS frame with its delimiters, ``00 | COBS | 00`` as ``encode_frame`` writes
  it (the zero before it is the one that ended what came before).
- ``h4``: the packet, indicator byte first (the splitter's own unit).

A drop carries the bytes it was made of too: an overlong line's are those held when it was
dropped (what follows, up to the line end, is skipped by the decoder and in no item). Feeding
one unit at a time passes the C accelerator's batching by, which is why the CLI does not do it.

:class:`Reader` decodes a stream the caller opened (a ``serial.Serial``, a socket, a binary
file): it reads and decodes, nothing more -- it sends no command, so an XPLR-AOA must already be
streaming (``rfhoming.open`` holds the set-up conversation; docs/api.md says what to send).
"""

from __future__ import annotations

import io
import re
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from typing import ClassVar, Literal, NamedTuple

from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error
from rfhoming.protocol.jsonable import as_dict

STREAM_PROTOCOLS = ("uconnect", "esp-at", "frames", "h4")
"""The wire protocols that are byte streams (``ros2`` is DDS samples, not a stream)."""

_CUTS = {"uconnect": re.compile(rb"\r\n|\r|\n"), "esp-at": re.compile(rb"\n"), "frames": re.compile(rb"\0")}
READ_SIZE = 4096


class _H4Packet(NamedTuple):
    data: bytes


class H4Packet(_H4Packet):
    """One HCI packet as the H4 splitter cut it, indicator byte first (bumble's
    ``HCI_Packet.from_bytes`` parses it); what a Reader over ``h4`` yields."""

    __slots__ = ()
    kind: ClassVar[Literal["h4_packet"]] = "h4_packet"
    to_dict = as_dict


class ReaderError(Error, ValueError):
    """A stream or protocol a Reader cannot read; the message says what to give instead."""


def stream_protocol(name: str) -> str:
    """A wire protocol's canonical name (a device kind names its protocol: ``xplr-aoa`` ->
    ``uconnect``); ReaderError for one that is not a byte stream."""
    canonical = devices.kind(name).protocol if devices.is_kind(name) else devices.protocol(name).name
    if canonical not in STREAM_PROTOCOLS:
        raise ReaderError(f"{name}: {canonical} is not a byte stream a Reader can decode; "
                          f"the stream protocols are {', '.join(STREAM_PROTOCOLS)}")
    return canonical


def new_decoder(protocol: str) -> Any:
    return devices.load(devices.protocol(protocol).decoder)()


class Framer:
    """``feed(bytes) -> [(raw, item)]``: the decoder's items, each with the bytes it came from,
    the same items as the decoder gives for the same bytes in any chunking."""

    def __init__(self, protocol: str, decoder: Any = None) -> None:
        self.protocol = stream_protocol(protocol)
        self.decoder = decoder if decoder is not None else new_decoder(self.protocol)
        self._cut = _CUTS.get(self.protocol)
        self._held = b""  # the unfinished unit's bytes (the decoder holds them too)
        self._skipping = False  # after an overlong unit: its rest is no item's
        self._lead = b""  # frames: the zero that ended the previous unit

    def feed(self, data: bytes) -> list[tuple[bytes, Any]]:
        if self._cut is None:  # h4: the splitter's packets are their own bytes
            return [(item if isinstance(item, bytes) else item.raw, item) for item in self.decoder.feed(data)]
        out: list[tuple[bytes, Any]] = []
        start = 0
        for match in self._cut.finditer(data):
            piece = data[start:match.end()]
            start = match.end()
            unit = piece if self._skipping else self._held + piece
            self._held, self._skipping = b"", False
            raw = self._lead + unit if self.protocol == "frames" else unit
            out += [(raw, item) for item in self.decoder.feed(piece)]
            if self.protocol == "frames":
                self._lead = b"\0"
        tail = data[start:]
        if tail:
            items = self.decoder.feed(tail)
            if not self._skipping:
                self._held += tail
            if items:  # a unit past the decoder's bound, dropped: what it held is the drop's
                out += [(self._lead + self._held, item) for item in items]
                self._held, self._skipping, self._lead = b"", True, b""
        return out

    def flush(self) -> list[tuple[bytes, Any]]:
        """End of input: a last unit without its terminator (a last line, a torn frame)."""
        flush = getattr(self.decoder, "flush", None)
        items = flush() if flush is not None else []
        raw, self._held, self._skipping = self._lead + self._held, b"", False
        return [(raw, item) for item in items]


class RawTracker:
    """A driver's decoder, fed unit by unit: while the driver handles an item, ``current`` is
    that item's bytes (b"" for an item the driver makes from no one unit)."""

    def __init__(self, framer: Framer | None = None) -> None:
        self.framer = framer
        self.current = b""

    def feed(self, data: bytes) -> Iterator[Any]:
        assert self.framer is not None
        return self._walk(self.framer.feed(data))

    def flush(self) -> Iterator[Any]:
        assert self.framer is not None
        return self._walk(self.framer.flush())

    def _walk(self, pairs: list[tuple[bytes, Any]]) -> Iterator[Any]:
        try:
            for raw, item in pairs:
                self.current = raw
                yield item
        finally:
            self.current = b""

    def __getattr__(self, name: str) -> Any:  # counters and the rest are the decoder's
        return getattr(self.framer.decoder if self.framer is not None else None, name)


def track(driver: Any) -> RawTracker:
    """Make ``driver`` tell the bytes of each item it emits: its decoder (``decoder``, or an HCI
    driver's H4 ``splitter``) is fed unit by unit; a driver that gets one sample per chunk (a
    ROS 2 base) has the chunk as its item's bytes. A client of ``rfhoming serve`` is no device
    of the table: its items come as the server's JSON, not the device's bytes (raw b"")."""
    if not devices.is_kind(driver.kind):
        return RawTracker()
    protocol = devices.kind(driver.kind, notice=False).protocol
    for attribute in ("decoder", "splitter"):
        decoder = getattr(driver, attribute, None)
        if decoder is not None and protocol in STREAM_PROTOCOLS:
            tracker = RawTracker(Framer(protocol, decoder))
            setattr(driver, attribute, tracker)
            return tracker
    tracker = RawTracker()
    on_chunk = driver.on_chunk

    def chunk_is_the_item(data: bytes, t_host: float) -> None:
        tracker.current = data
        try:
            on_chunk(data, t_host)
        finally:
            tracker.current = b""

    driver.on_chunk = chunk_is_the_item
    return tracker


def _now() -> float:
    return round(time.time() * 1e6) / 1e6  # µs, as the ports stamp their chunks


def read_function(stream: Any, size: int = READ_SIZE) -> tuple[Callable[[], bytes], bool]:
    """How to read a stream the caller opened, and whether an empty read is its end (a file, a
    socket whose peer closed) or only a timeout (a pyserial port with ``timeout=``)."""
    if isinstance(stream, io.TextIOBase):
        raise ReaderError(f"{getattr(stream, 'name', stream)!r} is open in text mode; open it in binary mode ('rb')")
    if hasattr(stream, "recv"):  # a socket
        return (lambda: stream.recv(size)), True
    if hasattr(stream, "in_waiting"):  # pyserial: take what is waiting, or block for one byte
        if getattr(stream, "timeout", None) == 0:
            raise ReaderError(f"{stream_name(stream)} is non-blocking (timeout=0): a Reader would spin on it; "
                              "open it with timeout=None (block) or a number of seconds")
        return (lambda: stream.read(max(1, min(stream.in_waiting, size)))), False
    read = getattr(stream, "read1", None) or getattr(stream, "read", None)
    if read is None:
        raise ReaderError(f"cannot read {stream!r}: give a serial.Serial, a socket or a binary file object")
    return (lambda: read(size)), True


def stream_name(stream: Any) -> str:
    for attribute in ("port", "name"):
        value = getattr(stream, attribute, None)
        if isinstance(value, str):
            return value
    try:
        host, port = stream.getpeername()[:2]
        return f"socket://{host}:{port}"
    except (AttributeError, OSError, TypeError, ValueError):
        return type(stream).__name__


def decode_stream(stream: Any, protocol: str, kinds: Iterable[str] | None, name: str | None,
                  make: Callable[[float, str, Any, bytes], Any]) -> Iterator[Any]:
    """The items of ``stream`` as ``make(t, name, item, raw)``, until its end."""
    framer = Framer(protocol)
    read, empty_is_end = read_function(stream)
    wanted = frozenset(kinds) if kinds is not None else None
    device = name or stream_name(stream)

    def keep(item: Any) -> bool:
        return wanted is None or item.kind in wanted

    while True:
        data = read()
        t = _now()
        if not data:
            if empty_is_end:
                break
            continue
        for raw, item in framer.feed(data):
            item = H4Packet(item) if isinstance(item, bytes) else item
            if keep(item):
                yield make(t, device, item, raw)
    for raw, item in framer.flush():
        if keep(item):
            yield make(_now(), device, item, raw)
