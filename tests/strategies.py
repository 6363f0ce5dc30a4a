"""Hypothesis strategies derived from the protocol declarations, so new types are covered."""

from __future__ import annotations

import struct
from typing import Any

import construct as cs
from hypothesis import strategies as st

from rfhoming.protocol.frames.records import RECORD_TYPES, AntennaReading, RecordType
from rfhoming.protocol.uconnect import AngleEvent, Dialect


def _int_range(fmt: str) -> st.SearchStrategy[int]:
    bits = struct.calcsize("<" + fmt) * 8
    if fmt.islower():
        return st.integers(-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    return st.integers(0, (1 << bits) - 1)


def _field(con: cs.Construct) -> st.SearchStrategy[Any]:
    if isinstance(con, cs.FormatField):
        return _int_range(con.fmtstr[1:])
    if isinstance(con, cs.Bytes):
        if isinstance(con.length, int):
            return st.binary(min_size=con.length, max_size=con.length)
        return st.binary(max_size=255)
    if isinstance(con, cs.Array):
        if isinstance(con.count, int):
            items = st.builds(AntennaReading, *[_field(sc.subcon) for sc in con.subcon.subcons])
            return st.tuples(*[items] * con.count)
        return st.lists(_field(con.subcon), max_size=255).map(tuple)
    if isinstance(con, cs.StringEncoded):
        return st.text(max_size=200).filter(lambda s: len(s.encode()) <= 900)
    if con is cs.GreedyBytes:
        return st.binary(max_size=200)
    raise TypeError(con)


def record_of(rt: RecordType) -> st.SearchStrategy[Any]:
    fields = [_field(sc.subcon) for sc in rt.body.subcons if not isinstance(sc.subcon, cs.Rebuild)]
    return st.builds(rt.cls, st.integers(0, 255), st.integers(0, 65535), st.integers(0, 2**32 - 1), *fields)


records = st.one_of(*[record_of(rt) for rt in RECORD_TYPES.values()])
"""Any record of any type, including field values the validators reject."""

hex_id = st.text("0123456789ABCDEF", min_size=12, max_size=12)
quoted_text = st.text(
    st.characters(min_codepoint=32, max_codepoint=126, blacklist_characters='"'), max_size=30
)


@st.composite
def angle_events(draw: st.DrawFn, dialect: Dialect) -> AngleEvent:
    """A valid event as ``dialect`` would write it (fields the dialect lacks are None/0)."""
    seq = draw(st.integers(0, 65535)) if dialect in (Dialect.V2, Dialect.EMBED) else None
    raw = dialect is Dialect.EMBED
    return AngleEvent(
        instance_id=draw(hex_id),
        rssi1=draw(st.integers(-127, 20)),
        azimuth=draw(st.integers(-90, 90)),
        elevation=draw(st.integers(-90, 90)),
        reserved=draw(st.integers(-127, 20)),
        channel=draw(st.integers(37, 39) if dialect in (Dialect.V1_0, Dialect.V1_2) else st.integers(0, 36)),
        anchor_id=draw(quoted_text),
        user_str=draw(quoted_text),
        timestamp_ms=draw(st.integers(-(2**31), 2**31 - 1)),
        seq=seq,
        azimuth_raw=draw(st.integers(-90, 90)) if raw else None,
        elevation_raw=draw(st.integers(-90, 90)) if raw else None,
    )


def chunked(data: bytes, sizes: list[int]) -> list[bytes]:
    """Cut ``data`` into pieces of the given sizes (cycled), the last piece what is left."""
    pieces, i, k = [], 0, 0
    while i < len(data):
        n = sizes[k % len(sizes)] if sizes else len(data)
        pieces.append(data[i : i + n])
        i, k = i + n, k + 1
    return pieces


