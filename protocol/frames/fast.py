"""Hot-path codecs derived from the construct declarations in :mod:`rfhoming.protocol.frames.records`.

Each body is a fixed little-endian prefix, optionally followed by one variable tail whose
length is the last fixed field (``ad``, ``psdu``, ``ranges_mm``) or the rest of the frame
(``text``, ``args``). :func:`derive_layout` reads that shape off the declaration once, at
import, so the decoder runs one ``struct.unpack_from`` per record and never interprets a
declaration per field. A test checks every type against construct on random records.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import construct as cs

from rfhoming.protocol.frames.records import HEADER, RECORD_TYPES, AntennaReading, RecordType

HEADER_STRUCT = struct.Struct("<BBBHI")
CRC_STRUCT = struct.Struct("<H")
HEADER_SIZE = HEADER_STRUCT.size
assert HEADER.sizeof() == HEADER_SIZE, "header declaration and struct layout disagree"


@dataclass(frozen=True)
class Layout:
    """The shape of one body: fixed prefix, then at most one tail."""

    fixed: struct.Struct
    tail: str
    """'' (none), 'counted' (length = last fixed field), 'rest_bytes' or 'rest_text'."""
    tail_item: struct.Struct | None
    """Element format of a counted array tail; None for a counted bytes tail."""
    group: tuple[int, int] | None
    """(count, width) of a fixed Array(count, Struct) ending the prefix, regrouped into tuples."""


def _format_char(con: cs.Construct) -> str:
    if isinstance(con, cs.FormatField):
        if con.fmtstr[0] != "<":
            raise TypeError(f"{con} is not little-endian")
        return str(con.fmtstr[1:])
    if isinstance(con, cs.Bytes) and isinstance(con.length, int):
        return f"{con.length}s"
    raise TypeError(f"no struct layout for {con!r}")


def derive_layout(body: cs.Struct) -> Layout:
    """Read the fixed prefix and the tail off a body declaration."""
    chars: list[str] = []
    tail, tail_item, group = "", None, None
    names = [sc.name for sc in body.subcons]
    for index, renamed in enumerate(body.subcons):
        con = renamed.subcon
        last = index == len(body.subcons) - 1
        if isinstance(con, cs.Rebuild):
            if index != len(body.subcons) - 2:
                raise TypeError("a length field must directly precede its tail")
            chars.append(_format_char(con.subcon))
        elif isinstance(con, cs.Array) and isinstance(con.count, int):
            width = len(con.subcon.subcons)
            chars.append("".join(_format_char(sc.subcon) for sc in con.subcon.subcons) * con.count)
            group = (con.count, width)
            if not last:
                raise TypeError("a fixed array of structs must end the prefix")
        elif last and isinstance(con, cs.Bytes):
            tail = "counted"
        elif last and isinstance(con, cs.Array):
            tail, tail_item = "counted", struct.Struct("<" + _format_char(con.subcon))
        elif last and isinstance(con, cs.StringEncoded):
            tail = "rest_text"
        elif last and con is cs.GreedyBytes:
            tail = "rest_bytes"
        else:
            chars.append(_format_char(con))
    if tail == "counted" and not isinstance(body.subcons[-2].subcon, cs.Rebuild):
        raise TypeError(f"tail {names[-1]} has no length field")
    return Layout(struct.Struct("<" + "".join(chars)), tail, tail_item, group)


BodyDecoder = Callable[[bytes, int, int, int, int], Any]
"""(inner, end, node_id, seq, t_us) -> record, or None when the length does not fit; raises
:class:`BadText` for a text tail that is not UTF-8."""


class BadText(ValueError):
    """A text tail (``log_text``) whose bytes are not UTF-8; the message says where."""


def _make_decoder(rt: RecordType) -> BodyDecoder:
    layout = derive_layout(rt.body)
    unpack = layout.fixed.unpack_from
    size = layout.fixed.size
    start = HEADER_SIZE + size
    new = tuple.__new__
    cls = rt.cls

    if layout.group is not None:
        count, width = layout.group
        head = len(cls._fields) - 3 - 1  # fixed fields before the group
        groups = [slice(head + i * width, head + (i + 1) * width) for i in range(count)]

        def decode_grouped(inner: bytes, end: int, node: int, seq: int, t: int) -> Any:
            if end != start:
                return None
            v = unpack(inner, HEADER_SIZE)
            readings = tuple([new(AntennaReading, v[g]) for g in groups])
            return new(cls, (node, seq, t) + v[:head] + (readings,))

        return decode_grouped

    if layout.tail == "":

        def decode_fixed(inner: bytes, end: int, node: int, seq: int, t: int) -> Any:
            if end != start:
                return None
            return new(cls, (node, seq, t) + unpack(inner, HEADER_SIZE))

        return decode_fixed

    if layout.tail == "counted" and layout.tail_item is None:

        def decode_counted_bytes(inner: bytes, end: int, node: int, seq: int, t: int) -> Any:
            if end < start:
                return None
            v = unpack(inner, HEADER_SIZE)
            if end != start + v[-1]:
                return None
            return new(cls, (node, seq, t) + v[:-1] + (inner[start:end],))

        return decode_counted_bytes

    if layout.tail == "counted" and layout.tail_item is not None:
        item = layout.tail_item
        item_char = item.format[1:]
        arrays: dict[int, struct.Struct] = {}

        def decode_counted_array(inner: bytes, end: int, node: int, seq: int, t: int) -> Any:
            if end < start:
                return None
            v = unpack(inner, HEADER_SIZE)
            n = v[-1]
            if end != start + n * item.size:
                return None
            array = arrays.get(n)
            if array is None:
                array = arrays[n] = struct.Struct(f"<{n}{item_char}")
            return new(cls, (node, seq, t) + v[:-1] + (array.unpack_from(inner, start),))

        return decode_counted_array

    text = layout.tail == "rest_text"

    def decode_rest(inner: bytes, end: int, node: int, seq: int, t: int) -> Any:
        if end < start:
            return None
        raw = inner[start:end]
        rest: bytes | str = raw
        if text:
            try:
                rest = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise BadText(f"{rt.kind} is not UTF-8: {exc.reason} at byte {exc.start}") from None
        return new(cls, (node, seq, t) + unpack(inner, HEADER_SIZE) + (rest,))

    return decode_rest


BodyEncoder = Callable[[Any], bytes]


def _make_encoder(rt: RecordType) -> BodyEncoder:
    layout = derive_layout(rt.body)
    pack = layout.fixed.pack
    nfixed = len(rt.cls._fields) - 3

    if layout.group is not None:

        def encode_grouped(r: Any) -> bytes:
            *head, readings = r[3:]
            return pack(*head, *(x for reading in readings for x in reading))

        return encode_grouped
    if layout.tail == "":
        return lambda r: pack(*r[3:])
    if layout.tail == "counted":
        item = layout.tail_item

        def encode_counted(r: Any) -> bytes:
            *head, tail = r[3:]
            if item is None:
                return pack(*head, len(tail)) + bytes(tail)
            return pack(*head, len(tail)) + struct.pack(f"<{len(tail)}{item.format[1:]}", *tail)

        return encode_counted
    text = layout.tail == "rest_text"

    def encode_rest(r: Any) -> bytes:
        *head, rest = r[3 : 3 + nfixed]
        return pack(*head) + (rest.encode("utf-8") if text else bytes(rest))

    return encode_rest


DECODERS: dict[int, BodyDecoder] = {code: _make_decoder(rt) for code, rt in RECORD_TYPES.items()}
ENCODERS: dict[int, BodyEncoder] = {code: _make_encoder(rt) for code, rt in RECORD_TYPES.items()}
