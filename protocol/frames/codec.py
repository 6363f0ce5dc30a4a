"""Frame codec: ``00 | COBS(header | body | crc16) | 00`` <-> typed records.

:class:`FrameDecoder` is sans-IO: bytes in any chunking go in, records come out in order.
A zero byte ends every frame, so garbage costs at most the frame it touches and the next
intact frame is never lost. Every rejected frame is a :class:`~protocol.drop.Drop`, counted
by reason; a record is returned only after COBS, length, CRC, version, type, body length and
field checks all pass. Where the C accelerator is built (:mod:`rfhoming.protocol.accel`), its
``scan_frames`` splits the chunk and checks COBS and CRC; the rest happens here either way.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from collections.abc import Callable
from typing import Any

from cobs import cobs

from rfhoming.protocol.accel import ACCEL
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.frames.fast import CRC_STRUCT, DECODERS, ENCODERS, HEADER_SIZE, HEADER_STRUCT, BadText
from rfhoming.protocol.frames.records import MAX_INNER, RECORD_TYPES, VERSION, crc16

MAX_ENCODED = MAX_INNER + math.ceil(MAX_INNER / 254)
"""Longest COBS-encoded frame; a longer run without a zero is dropped as oversize."""

MIN_INNER = HEADER_SIZE + CRC_STRUCT.size

ED_MAX = 84
ED_INVALID = 255
THETA_MAX_URAD = 3_141_593


def _ed_ok(ed: int) -> bool:
    return ed <= ED_MAX or ed == ED_INVALID


def _antennas_problem(antennas: Any) -> str | None:
    for ed, _lqi, _dt in antennas:
        if ed > ED_MAX and ed != ED_INVALID:
            return f"ed {ed} not in 0..84 or 255"
    return None


VALIDATORS: dict[int, Callable[[Any], str | None]] = {
    0x02: lambda r: (
        f"antenna {r.antenna} not in 0..3" if r.antenna > 3
        else None if _ed_ok(r.ed) else f"ed {r.ed} not in 0..84 or 255"
    ),
    0x03: lambda r: _antennas_problem(r.antennas),
    0x20: lambda r: (
        None if -THETA_MAX_URAD <= r.theta_urad <= THETA_MAX_URAD
        else f"theta_urad {r.theta_urad} outside ±π·10⁶"
    ),
}
"""Range checks beyond what the declaration's types already bound (reason ``field``)."""


def encode_inner(record: Any) -> bytes:
    """Header + body + CRC for ``record`` (fast path; agrees with records.build_inner)."""
    code = record.type_code
    try:
        body = ENCODERS[code](record)
        data = HEADER_STRUCT.pack(VERSION, code, record.node_id, record.seq, record.t_us) + body
    except struct.error as exc:
        raise ValueError(f"{record.kind} record has a field out of range: {exc}") from None
    if len(data) + CRC_STRUCT.size > MAX_INNER:
        raise ValueError(f"{record.kind} record of {len(data) + 2} bytes exceeds {MAX_INNER}")
    return data + CRC_STRUCT.pack(crc16(data))


def encode_frame(record: Any) -> bytes:
    """The bytes on the wire for one record, with a zero before and after."""
    encoded: bytes = cobs.encode(encode_inner(record))
    return b"\0" + encoded + b"\0"


def _decode_frame(frame: bytes) -> Any:
    """One COBS frame (no zeros) -> record or Drop: the pure-Python path, and the C path's
    fallback for the frames it hands back."""
    if len(frame) > MAX_ENCODED:
        return Drop("oversize", f"frame longer than {MAX_INNER} bytes", frame[:64])
    try:
        inner = cobs.decode(frame)
    except cobs.DecodeError as exc:
        return Drop("cobs", str(exc), frame)
    if len(inner) > MAX_INNER:  # up to 1028 bytes fit in MAX_ENCODED; the encoder writes none of them
        return Drop("oversize", f"frame decodes to {len(inner)} bytes, more than {MAX_INNER}", frame[:64])
    end = len(inner) - 2
    if end < HEADER_SIZE:
        return Drop("short", f"{len(inner)} bytes, a frame has at least {MIN_INNER}", frame)
    if CRC_STRUCT.unpack_from(inner, end)[0] != crc16(inner[:end]):
        return Drop("crc", "CRC-16 mismatch", frame)
    return _decode_inner(inner)


def _decode_inner(inner: bytes) -> Any:
    """The checks after COBS and CRC. A drop from here on carries the decoded inner frame
    (header | body | crc), which says more than its COBS encoding."""
    end = len(inner) - 2
    version, code, node, seq, t_us = HEADER_STRUCT.unpack_from(inner)
    if version != VERSION:
        return Drop("version", f"version {version}, expected {VERSION}", inner)
    decode = DECODERS.get(code)
    if decode is None:
        return Drop("type", f"unknown record type 0x{code:02X}", inner)
    try:
        record = decode(inner, end, node, seq, t_us)
    except BadText as exc:
        return Drop("text", str(exc), inner)
    if record is None:
        kind = RECORD_TYPES[code].kind
        return Drop("length", f"{kind} body length {end - HEADER_SIZE} does not fit", inner)
    check = VALIDATORS.get(code)
    if check is not None:
        problem = check(record)
        if problem is not None:
            return Drop("field", problem, inner)
    return record


class FrameDecoder:
    """Incremental decoder: ``feed(bytes) -> list[record | Drop]``, bounded memory.

    ``counters`` counts records by kind and drops as ``drop.<reason>``; reasons: ``cobs``,
    ``short``, ``crc``, ``version``, ``type``, ``length``, ``text``, ``field``, ``oversize``.
    """

    def __init__(self, *, pure: bool = False) -> None:
        """``pure=True`` keeps to the Python path even where the C accelerator is built."""
        self._rest = b""
        self._discarding = False
        self._scan = None if pure or ACCEL is None else ACCEL.scan_frames
        self.counters: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[Any]:
        """Decode every frame that ``data`` completes; keep the unfinished one."""
        if self._scan is None or self._discarding:
            return self._feed_python(data)
        scanned = self._scan(self._rest, data, MAX_ENCODED)
        if scanned is None:  # the unfinished frame grows past MAX_ENCODED
            return self._feed_python(data)
        frames: list[Any]  # inner bytes, or a 1-tuple of a raw frame left to us
        frames, self._rest = scanned
        if not frames:
            return frames
        # inner bytes passed COBS and CRC in C; a 1-tuple is a raw frame that did not
        inner, raw = _decode_inner, _decode_frame
        out = [inner(f) if f.__class__ is bytes else raw(f[0]) for f in frames]
        self._count(out)
        return out

    def _feed_python(self, data: bytes) -> list[Any]:
        if self._discarding:
            zero = data.find(b"\0")
            if zero < 0:
                return []
            data, self._discarding = data[zero:], False
        parts = (self._rest + data).split(b"\0") if self._rest else data.split(b"\0")
        self._rest = parts.pop()
        if len(self._rest) > MAX_ENCODED:
            parts.append(self._rest)
            self._rest, self._discarding = b"", True
        out = [_decode_frame(frame) for frame in parts if frame]
        self._count(out)
        return out

    def _count(self, items: list[Any]) -> None:
        counters = self.counters
        for item in items:
            counters["drop." + item.reason if item.kind == "drop" else item.kind] += 1

    def flush(self) -> list[Any]:
        """End of input: an unterminated tail is a torn frame."""
        rest, self._rest, self._discarding = self._rest, b"", False
        if not rest:
            return []
        self.counters["drop.torn"] += 1
        return [Drop("torn", "input ended inside a frame", rest[:64])]
