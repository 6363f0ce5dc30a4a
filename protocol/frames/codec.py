"""Frame codec: ``00 | COBS(header | body | crc16) | 00`` <-> typed records.

:class:`FrameDecoder` is sans-IO: bytes in any chunking go in, records come out in order.
A zero byte ends every frame, so garbage costs at most the frame it touches and the next
intact frame is never lost. Every rejected frame is a :class:`~protocol.drop.Drop`, counted
by reason; a record is returned only after COBS, length, CRC, version, type, body length and
field checks all pass.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from collections.abc import Callable
from typing import Any

from cobs import cobs

from protocol.drop import Drop
from protocol.frames.fast import CRC_STRUCT, DECODERS, ENCODERS, HEADER_SIZE, HEADER_STRUCT
from protocol.frames.records import MAX_INNER, RECORD_TYPES, VERSION, crc16

MAX_ENCODED = MAX_INNER + math.ceil(MAX_INNER / 254)
"""Longest COBS-encoded frame; a longer run without a zero is dropped as oversize."""

MIN_INNER = HEADER_SIZE + CRC_STRUCT.size

ED_MAX = 84
ED_INVALID = 255
THETA_MAX_URAD = 3_141_593


def _ed_ok(ed: int) -> bool:
    return ed <= ED_MAX or ed == ED_INVALID


VALIDATORS: dict[int, Callable[[Any], str | None]] = {
    0x02: lambda r: (
        f"antenna {r.antenna} not in 0..3" if r.antenna > 3
        else None if _ed_ok(r.ed) else f"ed {r.ed} not in 0..84 or 255"
    ),
    0x03: lambda r: next(
        (f"ed {a.ed} not in 0..84 or 255" for a in r.antennas if not _ed_ok(a.ed)), None
    ),
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
    return b"\0" + cobs.encode(encode_inner(record)) + b"\0"


class FrameDecoder:
    """Incremental decoder: ``feed(bytes) -> list[record | Drop]``, bounded memory.

    ``counters`` counts records by kind and drops as ``drop.<reason>``; reasons: ``cobs``,
    ``short``, ``crc``, ``version``, ``type``, ``length``, ``field``, ``oversize``.
    """

    def __init__(self) -> None:
        self._rest = b""
        self._discarding = False
        self.counters: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[Any]:
        """Decode every frame that ``data`` completes; keep the unfinished one."""
        if self._discarding:
            zero = data.find(b"\0")
            if zero < 0:
                return []
            data, self._discarding = data[zero:], False
        parts = (self._rest + data).split(b"\0") if self._rest else data.split(b"\0")
        self._rest = parts.pop()
        out: list[Any] = []
        if len(self._rest) > MAX_ENCODED:
            parts.append(self._rest)
            self._rest, self._discarding = b"", True
        counters = self.counters
        for frame in parts:
            if frame:
                item = self._decode(frame)
                out.append(item)
                counters["drop." + item.reason if item.kind == "drop" else item.kind] += 1
        return out

    def flush(self) -> list[Any]:
        """End of input: an unterminated tail is a torn frame."""
        rest, self._rest, self._discarding = self._rest, b"", False
        if not rest:
            return []
        self.counters["drop.torn"] += 1
        return [Drop("torn", "input ended inside a frame", rest[:64])]

    @staticmethod
    def _decode(frame: bytes) -> Any:
        if len(frame) > MAX_ENCODED:
            return Drop("oversize", f"frame longer than {MAX_INNER} bytes", frame[:64])
        try:
            inner = cobs.decode(frame)
        except cobs.DecodeError as exc:
            return Drop("cobs", str(exc), frame)
        end = len(inner) - 2
        if end < HEADER_SIZE:
            return Drop("short", f"{len(inner)} bytes, a frame has at least {MIN_INNER}", frame)
        if CRC_STRUCT.unpack_from(inner, end)[0] != crc16(inner[:end]):
            return Drop("crc", "CRC-16 mismatch", frame)
        version, code, node, seq, t_us = HEADER_STRUCT.unpack_from(inner)
        if version != VERSION:
            return Drop("version", f"version {version}, expected {VERSION}", frame)
        decode = DECODERS.get(code)
        if decode is None:
            return Drop("type", f"unknown record type 0x{code:02X}", frame)
        record = decode(inner, end, node, seq, t_us)
        if record is None:
            kind = RECORD_TYPES[code].kind
            return Drop("length", f"{kind} body length {end - HEADER_SIZE} does not fit", frame)
        check = VALIDATORS.get(code)
        if check is not None:
            problem = check(record)
            if problem is not None:
                return Drop("field", problem, frame)
        return record
