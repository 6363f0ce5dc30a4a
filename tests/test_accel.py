"""The C accelerator and the pure-Python decoders give the same items, drops and counters.

Differential tests: the same bytes, cut the same way, go through a decoder on each path.
The C side is skipped (with the reason) only where the extension could not be built, and
that is itself a failure where a C compiler exists: pip should have built it.
"""

from __future__ import annotations

import binascii
import os
import shlex
import shutil
import sysconfig

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.protocol.accel import ACCEL, PURE_ENV, describe
from rfhoming.protocol.frames import MAX_ENCODED, FrameDecoder, Odometry, encode_frame, encode_inner
from rfhoming.protocol.uconnect import MAX_LINE, AngleEvent, Dialect, FinalCode, UConnectDecoder, encode_angle_event
from rfhoming.protocol.uconnect.decoder import parse_angle_event
from strategies import angle_events, chunked, records

needs_accel = pytest.mark.skipif(ACCEL is None, reason=describe())


def test_accelerator_is_built_where_a_compiler_exists() -> None:
    cc = shlex.split(sysconfig.get_config_var("CC") or "cc")[0]
    if os.environ.get(PURE_ENV, "") not in ("", "0") or shutil.which(cc) is None:
        pytest.skip(describe())
    assert ACCEL is not None, f"{cc} exists but protocol._accel is missing: run pip install -e . again"


def run(decoder, pieces: list[bytes]) -> tuple[list, dict]:
    out = []
    for piece in pieces:
        out += decoder.feed(piece)
    out += decoder.flush()
    return out, dict(decoder.counters)


def both(make, data: bytes, sizes: list[int]) -> tuple[list, dict]:
    """Decode on both paths; assert they agree; return the C path's output."""
    pieces = chunked(data, sizes)
    fast = run(make(), pieces)
    assert fast == run(make(pure=True), pieces)
    return fast


@needs_accel
@given(st.binary(max_size=3000))
def test_crc16_matches_binascii(data: bytes) -> None:
    assert ACCEL.crc16(data) == binascii.crc_hqx(data, 0xFFFF)


# ---- +UUDF lines -------------------------------------------------------------------------

events = st.sampled_from(list(Dialect)).flatmap(
    lambda d: angle_events(d).map(lambda e: encode_angle_event(e, d))
)


@st.composite
def mutated_line(draw: st.DrawFn) -> bytes:
    """An encoded event with a few bytes replaced by what breaks parsers: signs, zeros,
    quotes, commas, NUL, non-ASCII, line ends."""
    line = draw(events)
    at = draw(st.integers(0, len(line)))
    cut = draw(st.integers(0, 4))
    text = draw(st.binary(max_size=4) | st.text('0123456789,-+" AFaf\r\n', max_size=4).map(str.encode))
    return line[:at] + text + line[at + cut :]


other_lines = st.sampled_from(
    [b"OK\r\n", b"ERROR\r\n", b"AT+GMR\r\r\n", b'"2.1.0"\r\n', b"+STARTUP\r\n", b"\r\n", b"\n\r",
     b"+UUDFP:CCF9578E0D8A,0201\r\n", b"+UUDF:bad\r\n", b"hello\r\n", b"z" * (MAX_LINE + 3) + b"\n"]
)
streams = st.lists(events | mutated_line() | other_lines | st.binary(max_size=80), max_size=30).map(b"".join)
sizes = st.lists(st.integers(1, 700), min_size=1, max_size=8)


@needs_accel
@given(streams, sizes)
def test_uudf_paths_agree_on_any_stream(data: bytes, sizes: list[int]) -> None:
    both(UConnectDecoder, data, sizes)


@needs_accel
@given(st.lists(events, min_size=1, max_size=20))
def test_uudf_c_path_takes_every_valid_event(lines: list[bytes]) -> None:
    items, angles, rest = ACCEL.scan_uudf(b"", b"".join(lines), AngleEvent)
    assert angles == len(lines) and rest == b""
    assert items == [parse_angle_event(line.strip(b"\r\n")) for line in lines]


@needs_accel
def test_uudf_c_path_hands_back_the_chunk_that_overflows() -> None:
    assert ACCEL.scan_uudf(b"x" * MAX_LINE, b"y", AngleEvent) is None
    d = UConnectDecoder()
    assert d.feed(b"x" * MAX_LINE) == []
    (drop,) = d.feed(b"y")
    assert drop.reason == "overlong" and d._rest == b""
    assert d.feed(b"zz\r\nOK\r\n") == [FinalCode(True)]


# ---- COBS frames -------------------------------------------------------------------------


@st.composite
def damaged_frames(draw: st.DrawFn) -> bytes:
    """Frames with bit flips, deletions, garbage and over-long runs mixed in."""
    parts = []
    for rec in draw(st.lists(records, max_size=8)):
        frame = bytearray(encode_frame(rec))
        damage = draw(st.sampled_from(["none", "flip", "delete", "garbage"]))
        if damage == "flip":
            bit = draw(st.integers(0, len(frame) * 8 - 1))
            frame[bit // 8] ^= 1 << (bit % 8)
        elif damage == "delete":
            del frame[draw(st.integers(0, len(frame) - 1))]
        elif damage == "garbage":
            frame[draw(st.integers(0, len(frame))) : 0] = draw(st.binary(max_size=40))
        parts.append(bytes(frame))
    if draw(st.booleans()):
        parts.insert(draw(st.integers(0, len(parts))), b"\x01" * draw(st.integers(MAX_ENCODED - 2, MAX_ENCODED + 40)))
    return b"".join(parts)


@needs_accel
@given(damaged_frames(), sizes)
def test_frame_paths_agree_on_any_stream(data: bytes, sizes: list[int]) -> None:
    both(FrameDecoder, data, sizes)


@needs_accel
@given(st.lists(records, min_size=1, max_size=10), sizes)
def test_frame_paths_agree_on_intact_frames(recs: list, sizes: list[int]) -> None:
    out, _ = both(FrameDecoder, b"".join(encode_frame(r) for r in recs), sizes)
    assert len(out) == len(recs)


@needs_accel
def test_frame_c_path_hands_back_what_it_does_not_take() -> None:
    odo = Odometry(7, 1, 123456, 1500, -250, 1570796, 300, -100, 4)
    wire = encode_frame(odo)
    assert ACCEL.scan_frames(b"\x01" * MAX_ENCODED, b"\x01", MAX_ENCODED) is None
    items, rest = ACCEL.scan_frames(wire[1:5], wire[5:] + b"\x05ab\0\x01\x01", MAX_ENCODED)
    assert items == [encode_inner(odo), (b"\x05ab",)] and rest == b"\x01\x01"


@needs_accel
def test_frame_c_path_bounds_the_unfinished_frame() -> None:
    d = FrameDecoder()
    for _ in range(MAX_ENCODED // 64 + 2):
        d.feed(b"\x01" * 64)
        assert len(d._rest) <= MAX_ENCODED
    assert d.counters["drop.oversize"] == 1


@needs_accel
def test_a_frame_that_decodes_past_the_limit_is_oversize_on_both_paths() -> None:
    """1025..1028 inner bytes fit in MAX_ENCODED; the encoder writes none, so both paths drop them."""
    import struct

    from cobs import cobs

    from rfhoming.protocol.frames.records import crc16

    for size in (1024, 1025, 1028):
        data = struct.pack("<BBBHI", 1, 0x7F, 1, 2, 3) + b"x\0" * ((size - 11) // 2) + b"x" * ((size - 11) % 2)
        wire = b"\0" + cobs.encode(data + struct.pack("<H", crc16(data))) + b"\0"
        out, _ = both(FrameDecoder, wire, [len(wire)])
        assert [getattr(i, "reason", i.kind) for i in out] == ["log_text" if size == 1024 else "oversize"]
