"""Binary framing: construct and the fast path agree; corruption is dropped, never accepted."""

from __future__ import annotations

import struct

import pytest
from cobs import cobs
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.protocol.drop import Drop
from rfhoming.protocol.frames import (
    MAX_ENCODED,
    MAX_INNER,
    RECORD_TYPES,
    AntennaReading,
    AntennaSet,
    FrameDecoder,
    LogText,
    Odometry,
    RangeScan,
    RfFrame,
    VelocityCommand,
    build_inner,
    crc16,
    encode_frame,
    encode_inner,
    parse_inner,
)
from rfhoming.protocol.frames.codec import VALIDATORS
from strategies import chunked, record_of, records

ODO = Odometry(7, 1, 123456, 1500, -250, 1570796, 300, -100, 0b100)


def valid(record) -> bool:
    check = VALIDATORS.get(record.type_code)
    return check is None or check(record) is None


def decode(data: bytes) -> list:
    d = FrameDecoder()
    return d.feed(data) + d.flush()


def test_crc_check_value() -> None:
    assert crc16(b"123456789") == 0x29B1


def test_golden_odometry_frame() -> None:
    inner = bytes.fromhex("012007010040e20100dc050000" "06ffffff" "ecf71700" "2c01" "9cff" "04")
    assert encode_inner(ODO)[:-2] == inner
    assert encode_inner(ODO)[-2:] == struct.pack("<H", crc16(inner))
    assert encode_frame(ODO) == b"\0" + cobs.encode(encode_inner(ODO)) + b"\0"


@pytest.mark.parametrize("code", sorted(RECORD_TYPES))
@given(data=st.data())
def test_construct_and_fast_path_agree(code: int, data) -> None:
    record = data.draw(record_of(RECORD_TYPES[code]))
    inner = encode_inner(record)
    assert inner == build_inner(record)
    assert parse_inner(inner) == record
    (item,) = decode(b"\0" + cobs.encode(inner) + b"\0")
    if valid(record):
        assert item == record and type(item) is RECORD_TYPES[code].cls
    else:
        assert isinstance(item, Drop) and item.reason == "field"


@given(st.lists(records.filter(valid), max_size=12), st.lists(st.integers(1, 80), min_size=1, max_size=10))
def test_any_chunking_gives_identical_output(recs: list, sizes: list[int]) -> None:
    stream = b"".join(encode_frame(r) for r in recs)
    d = FrameDecoder()
    out = []
    for piece in chunked(stream, sizes):
        out += d.feed(piece)
    assert out + d.flush() == recs
    assert sum(d.counters.values()) == len(recs)


@given(st.lists(records.filter(valid), min_size=1, max_size=6), st.binary(max_size=300))
def test_frame_after_garbage_is_never_lost(recs: list, garbage: bytes) -> None:
    out = decode(garbage + b"".join(encode_frame(r) for r in recs))
    assert [i for i in out if i.kind != "drop"] == recs


@given(st.lists(records.filter(valid), min_size=2, max_size=6), st.data())
def test_bit_flip_never_yields_a_corrupted_record(recs: list, data) -> None:
    frames = [encode_frame(r) for r in recs]
    stream = bytearray(b"".join(frames))
    bit = data.draw(st.integers(0, len(stream) * 8 - 1))
    stream[bit // 8] ^= 1 << (bit % 8)
    hit = next(i for i, f in enumerate(frames) if sum(map(len, frames[: i + 1])) * 8 > bit)
    out = decode(bytes(stream))
    accepted = [i for i in out if i.kind != "drop"]
    assert all(r in recs for r in accepted)
    survivors = [r for i, r in enumerate(recs) if abs(i - hit) > 1]
    assert all(r in accepted for r in survivors)
    assert recs[hit] not in accepted or recs.count(recs[hit]) > 1


@given(st.lists(records.filter(valid), min_size=2, max_size=6), st.data())
def test_dropped_byte_costs_at_most_the_frames_it_touches(recs: list, data) -> None:
    frames = [encode_frame(r) for r in recs]
    stream = b"".join(frames)
    at = data.draw(st.integers(0, len(stream) - 1))
    out = decode(stream[:at] + stream[at + 1 :])
    accepted = [i for i in out if i.kind != "drop"]
    assert all(r in recs for r in accepted)
    assert len(accepted) >= len(recs) - 2


def frame(inner: bytes) -> bytes:
    return b"\0" + cobs.encode(inner) + b"\0"


def with_crc(data: bytes) -> bytes:
    return data + struct.pack("<H", crc16(data))


@pytest.mark.parametrize(
    ("wire", "reason"),
    [
        (b"\0\x05ab\0", "cobs"),
        (frame(with_crc(b"\x01\x20\x07")), "short"),
        (frame(encode_inner(ODO)[:-1] + b"\x00"), "crc"),
        (frame(with_crc(b"\x02" + encode_inner(ODO)[1:-2])), "version"),
        (frame(with_crc(b"\x01\x55" + encode_inner(ODO)[2:-2])), "type"),
        (frame(with_crc(encode_inner(ODO)[:-3])), "length"),
        (frame(with_crc(encode_inner(ODO)[:-2] + b"\x00")), "length"),
        (frame(with_crc(encode_inner(RangeScan(1, 1, 1, 0, 10, (1, 2)))[:-4])), "length"),
        (encode_frame(ODO._replace(theta_urad=3_141_594)), "field"),
        (encode_frame(RfFrame(1, 1, 1, 4, 1, 0, 0, -99, 10, 0, 0, 1, b"")), "field"),
        (encode_frame(RfFrame(1, 1, 1, 0, 1, 0, 0, -99, 85, 0, 0, 1, b"")), "field"),
        (frame(with_crc(encode_inner(LogText(1, 1, 1, ""))[:-2] + b"\xff")), "text"),
        (frame(with_crc(encode_inner(LogText(1, 1, 1, ""))[:-2] + b"x\0" * 507)), "oversize"),  # 1025 bytes
    ],
)
def test_each_drop_reason(wire: bytes, reason: str) -> None:
    d = FrameDecoder()
    (item,) = d.feed(wire)
    assert isinstance(item, Drop) and item.reason == reason, item
    assert d.counters == {"drop." + reason: 1}


def test_oversize_run_is_dropped_and_memory_bounded() -> None:
    d = FrameDecoder()
    out = []
    for _ in range(50):
        out += d.feed(b"\x01" * 100)
        assert len(d._rest) <= MAX_ENCODED
    out += d.feed(b"\x01\x01\0" + encode_frame(ODO))
    assert [i.kind for i in out] == ["drop", "odometry"]
    assert out[0].reason == "oversize" and d.counters["drop.oversize"] == 1


def test_largest_frame_fits_and_larger_is_refused() -> None:
    text = "x" * (MAX_INNER - 11)
    big = LogText(1, 1, 1, text)
    assert decode(encode_frame(big)) == [big]
    with pytest.raises(ValueError, match="exceeds 1024"):
        encode_frame(LogText(1, 1, 1, text + "x"))


def test_torn_frame_at_end_of_input() -> None:
    d = FrameDecoder()
    assert d.feed(encode_frame(ODO)[:-5]) == []
    (item,) = d.flush()
    assert item.reason == "torn" and item.raw == encode_frame(ODO)[1:-5]  # the frame, no leading zero
    d.feed(b"\0" + b"\x01" * 200)
    (item,) = d.flush()
    assert item.raw == b"\x01" * 64  # a drop's raw bytes are bounded (docs/protocol.md)


def test_antenna_set_groups_readings() -> None:
    rec = AntennaSet(3, 9, 1000, 42, 1, 0, -99, 0b1011, tuple(AntennaReading(10 * i, 200, -i) for i in range(4)))
    (item,) = decode(encode_frame(rec))
    assert item.antennas[3] == AntennaReading(30, 200, -3)


def test_velocity_command_host_to_base() -> None:
    cmd = VelocityCommand(0, 5, 0, 250, -520, 300)
    assert decode(encode_frame(cmd)) == [cmd]


# -- range checks at their edges (mutation testing found them untested) ----------------------
def _rf(ed: int = 0, antenna: int = 0):
    from rfhoming.protocol.frames import RfFrame

    return RfFrame(1, 2, 3, antenna, 1, 0, 0, -91, ed, 200, 0, 9, b"\x01\x02")


def _odo(theta: int):
    from rfhoming.protocol.frames import Odometry

    return Odometry(7, 1, 123456, 1500, -250, theta, 300, -100, 4)


def _set(ed: int):
    return AntennaSet(3, 9, 1000, 42, 1, 0, -99, 0b1111, tuple(AntennaReading(ed if i == 2 else 0, 200, -i) for i in range(4)))


EDGES = [(_set(84), True), (_set(85), False), (_set(255), True), (_rf(ed=84), True), (_rf(ed=85), False), (_rf(ed=254), False), (_rf(ed=255), True),
         (_rf(antenna=3), True), (_rf(antenna=4), False),
         (_odo(3_141_593), True), (_odo(3_141_594), False), (_odo(-3_141_593), True), (_odo(-3_141_594), False)]


@pytest.mark.parametrize("pure", [False, True])
@pytest.mark.parametrize(("record", "accepted"), EDGES)
def test_range_checks_at_their_edges(record, accepted: bool, pure: bool) -> None:
    items = FrameDecoder(pure=pure).feed(encode_frame(record))
    if accepted:
        assert items == [record]
    else:
        assert len(items) == 1 and isinstance(items[0], Drop) and items[0].reason == "field"


def test_a_record_class_that_drifts_from_its_declaration_fails_at_import() -> None:
    """The classes are written out for type checkers; _declare holds them to the wire declarations."""
    from rfhoming.protocol.frames.records import ODOMETRY, STATUS, Odometry, _declare

    assert _declare(Odometry, ODOMETRY).kind == "odometry"
    with pytest.raises(TypeError, match="Odometry has fields"):
        _declare(Odometry, STATUS)
