"""The C reference of the framing (c_reference/) agrees bit for bit with the Python codec.

The library is compiled with the machine's C compiler (strict C99, warnings as errors) and
called through ctypes. Frames the C encoder writes must equal ``encode_frame`` byte for byte and
decode with ``FrameDecoder`` to the same record; Python's frames must go through the C decoder
and parsers and come back out of the C encoder unchanged.
"""

from __future__ import annotations

import ctypes as C
import random
import struct as pystruct
import subprocess
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from cobs import cobs

from rfhoming.protocol.frames import RECORD_TYPES, AntennaReading, FrameDecoder, encode_frame
from rfhoming.protocol.frames.codec import MAX_ENCODED
from rfhoming.protocol.frames.records import MAX_INNER, crc16
from cref import SOURCE, build_harness, compiler, python_words, run_harness
from strategies import records

U8, I8, U16, I16, U32, I32 = C.c_uint8, C.c_int8, C.c_uint16, C.c_int16, C.c_uint32, C.c_int32
P8 = C.POINTER(C.c_uint8)


NO_CC = "no C compiler on PATH (cc, gcc or clang): the C reference cannot be checked"


@pytest.fixture(scope="module")
def lib(tmp_path_factory: pytest.TempPathFactory) -> C.CDLL:
    cc = compiler()
    if cc is None:
        pytest.skip(NO_CC)
    out = tmp_path_factory.mktemp("cref") / "librfh_frames.so"
    cmd = [cc, "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-shared", "-fPIC",
           "-o", str(out), str(SOURCE / "rfh_frames.c")]
    subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=300)
    return C.CDLL(str(out))


class Header(C.Structure):
    _fields_ = [("node_id", U8), ("seq", U16), ("t_us", U32)]


class AdvReport(C.Structure):
    _fields_ = [("addr", U8 * 6), ("addr_type", U8), ("adv_props", U8), ("rssi_dbm", I8),
                ("tx_power_dbm", I8), ("channel", U8), ("ad_len", U8), ("ad", P8)]


class RfFrame(C.Structure):
    _fields_ = [("antenna", U8), ("channel", U8), ("page", U8), ("trx_ctrl_2", U8),
                ("rssi_base_dbm", I8), ("ed", U8), ("lqi", U8), ("rx_status", U8),
                ("emitter_seq", U16), ("psdu_len", U8), ("psdu", P8)]


class Antenna(C.Structure):
    _fields_ = [("ed", U8), ("lqi", U8), ("dt_us", I16)]


class AntennaSet(C.Structure):
    _fields_ = [("emitter_seq", U16), ("channel", U8), ("page", U8), ("rssi_base_dbm", I8),
                ("valid_mask", U8), ("antennas", Antenna * 4)]


class Status(C.Structure):
    _fields_ = [("device_kind", U8), ("fw_major", U8), ("fw_minor", U8), ("fw_patch", U8),
                ("uptime_ms", U32), ("tx_dropped", U16), ("rx_errors", U16)]


class Odometry(C.Structure):
    _fields_ = [("x_mm", I32), ("y_mm", I32), ("theta_urad", I32), ("v_mm_s", I16),
                ("w_mrad_s", I16), ("flags", U8)]


class VelocityCommand(C.Structure):
    _fields_ = [("v_mm_s", I16), ("w_mrad_s", I16), ("timeout_ms", U16)]


class RangeScan(C.Structure):
    _fields_ = [("angle_min_mrad", I16), ("angle_inc_mrad", I16), ("count", U8),
                ("ranges_mm", C.POINTER(U16))]


class RangeScanV2(C.Structure):
    _fields_ = [("angle_min_urad", I32), ("angle_max_urad", I32), ("range_max_mm", U16), ("count", U8),
                ("ranges_mm", C.POINTER(U16))]


class LogText(C.Structure):
    _fields_ = [("text", P8), ("len", C.c_size_t)]


class NodeCommand(C.Structure):
    _fields_ = [("command", U8), ("args", P8), ("args_len", C.c_size_t)]


class Decoder(C.Structure):
    _fields_ = [("buf", U8 * MAX_ENCODED), ("len", C.c_size_t), ("discarding", C.c_int),
                ("inner", U8 * MAX_INNER), ("inner_len", C.c_size_t), ("type", U8),
                ("header", Header), ("drop", C.c_int), ("frames", U32), ("drops", U32)]


STRUCTS = {0x01: AdvReport, 0x02: RfFrame, 0x03: AntennaSet, 0x10: Status, 0x20: Odometry,
           0x21: VelocityCommand, 0x22: RangeScan, 0x23: RangeScanV2, 0x7F: LogText, 0x80: NodeCommand}
TAILS = {0x01: ("ad", "ad_len"), 0x02: ("psdu", "psdu_len"), 0x80: ("args", "args_len")}


def _bytes_ptr(data: bytes) -> Any:
    return C.cast(C.create_string_buffer(data, max(len(data), 1)), P8)


def to_c(record: Any) -> tuple[C.Structure, list]:
    """The C struct for ``record``, and the buffers it points into (kept alive by the caller)."""
    code = record.type_code
    fields = record._asdict()
    for name in ("node_id", "seq", "t_us"):
        fields.pop(name)
    keep: list = []
    if code in TAILS:
        ptr_name, len_name = TAILS[code]
        data = fields.pop(ptr_name)
        keep.append(_bytes_ptr(data))
        fields[ptr_name], fields[len_name] = keep[-1], len(data)
        if code == 0x01:
            fields["addr"] = (U8 * 6)(*fields["addr"])
    elif code == 0x03:
        fields["antennas"] = (Antenna * 4)(*[Antenna(*a) for a in fields["antennas"]])
    elif code in (0x22, 0x23):
        ranges = fields.pop("ranges_mm")
        keep.append((U16 * max(len(ranges), 1))(*ranges))
        fields["ranges_mm"], fields["count"] = C.cast(keep[-1], C.POINTER(U16)), len(ranges)
    elif code == 0x7F:
        data = fields.pop("text").encode()
        keep.append(_bytes_ptr(data))
        fields["text"], fields["len"] = keep[-1], len(data)
    return STRUCTS[code](**fields), keep


def c_encode(lib: C.CDLL, record: Any, header: Header | None = None) -> bytes:
    struct, _keep = to_c(record)
    return c_encode_struct(lib, record.type_code, header or Header(record.node_id, record.seq, record.t_us), struct)


def c_encode_struct(lib: C.CDLL, code: int, header: Header, struct: C.Structure) -> bytes:
    out = (U8 * 1100)()
    fn = getattr(lib, "rfh_encode_" + RECORD_TYPES[code].kind)
    n = fn(out, C.c_size_t(len(out)), C.byref(header), C.byref(struct))
    return bytes(out[:n])


def py_frame(record: Any) -> bytes | None:
    try:
        return encode_frame(record)
    except ValueError:  # inner frame over MAX_INNER: the C encoder must refuse it too
        return None


@pytest.mark.slow
@settings(max_examples=10_000, deadline=None)
@given(records)
def test_c_frames_decode_bit_exactly_with_python(lib: C.CDLL, record: Any) -> None:
    expected = py_frame(record)
    frame = c_encode(lib, record)
    if expected is None:
        assert frame == b""
        return
    assert frame == expected
    got = FrameDecoder(pure=True).feed(frame)
    assert got == FrameDecoder(pure=True).feed(expected)
    assert len(got) == 1
    if got[0].kind != "drop":  # the validators reject some random field values, alike on both
        assert got[0] == record


def c_decode(lib: C.CDLL, data: bytes) -> list[tuple[int, Any]]:
    """Feed ``data`` to a C decoder: (result, decoder snapshot as bytes) per frame end."""
    dec = Decoder()
    lib.rfh_decoder_init(C.byref(dec))
    lib.rfh_decoder_feed.restype = C.c_int
    out = []
    for byte in data:
        res = lib.rfh_decoder_feed(C.byref(dec), C.c_uint8(byte))
        if res == 1:
            out.append((res, reencode(lib, dec)))
        elif res == 2:
            out.append((res, dec.drop))
    return out


def reencode(lib: C.CDLL, dec: Decoder) -> bytes | None:
    """Parse the decoder's last frame with the C parser of its type and encode it again in C."""
    code = dec.type
    if code not in STRUCTS:
        return None
    body_len = dec.inner_len - 11
    body = C.cast(C.byref(dec.inner, 9), P8)
    struct = STRUCTS[code]()
    parse = getattr(lib, "rfh_parse_" + RECORD_TYPES[code].kind)
    if code in (0x22, 0x23):
        raw = P8()
        if not parse(body, C.c_size_t(body_len), C.byref(struct), C.byref(raw)):
            return None
        ranges = bytes(raw[: 2 * struct.count])
        keep = (U16 * max(struct.count, 1))(*[int.from_bytes(ranges[i : i + 2], "little") for i in range(0, len(ranges), 2)])
        struct.ranges_mm = C.cast(keep, C.POINTER(U16))
    elif not parse(body, C.c_size_t(body_len), C.byref(struct)):
        return None
    header = Header(dec.header.node_id, dec.header.seq, dec.header.t_us)
    return c_encode_struct(lib, code, header, struct)


@pytest.mark.slow
@settings(max_examples=1500, deadline=None)
@given(st.lists(records, min_size=1, max_size=4))
def test_python_frames_round_trip_through_the_c_decoder(lib: C.CDLL, recs: list) -> None:
    frames = [f for f in map(py_frame, recs) if f is not None]
    got = c_decode(lib, b"".join(frames))
    assert got == [(1, f) for f in frames]


@given(records, st.integers(0, 10_000), st.integers(0, 7))
def test_c_decoder_rejects_a_flipped_bit(lib: C.CDLL, record: Any, where: int, bit: int) -> None:
    frame = py_frame(record)
    if frame is None:
        return
    i = 1 + where % (len(frame) - 2)  # a byte between the delimiters
    bad = bytearray(frame)
    bad[i] ^= 1 << bit
    got = c_decode(lib, bytes(bad) + frame)
    assert all(res == 2 for res, _ in got[:-1])  # the damaged part: only drops, never a record
    assert got[-1] == (1, frame)  # the intact frame after it survives


def test_oversize_run_is_dropped_once_and_the_next_frame_survives(lib: C.CDLL) -> None:
    frame = py_frame(RECORD_TYPES[0x21].cls(1, 2, 3, 4, 5, 6))
    got = c_decode(lib, b"\x01" * (MAX_ENCODED + 50) + frame)
    assert got == [(2, 1), (1, frame)]  # 1 = RFH_DROP_OVERSIZE


def test_antenna_readings_survive(lib: C.CDLL) -> None:
    rec = RECORD_TYPES[0x03].cls(9, 1, 2, 3, 11, 0, -97, 0b1011, tuple(AntennaReading(i, 255 - i, -i) for i in range(4)))
    assert FrameDecoder(pure=True).feed(c_encode(lib, rec)) == [rec]


@given(records)
def test_a_buffer_of_exactly_the_frame_size_is_enough_and_one_byte_less_is_refused(lib: C.CDLL, record: Any) -> None:
    expected = py_frame(record)
    if expected is None:
        return
    struct, _keep = to_c(record)
    header = Header(record.node_id, record.seq, record.t_us)
    fn = getattr(lib, "rfh_encode_" + record.kind)
    for cap, want in ((len(expected), expected), (len(expected) - 1, b"")):
        out = (U8 * cap)()
        n = fn(out, C.c_size_t(cap), C.byref(header), C.byref(struct))
        assert bytes(out[:n]) == want


# -- differential: the C reference and the Python decoder on invalid and near-limit input ------
@pytest.fixture(scope="module")
def sanitized(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/rfh_harness.c with the C reference, built with ASan and UBSan (any report fails)."""
    cc = compiler()
    if cc is None:
        pytest.skip(NO_CC)
    return build_harness(cc, tmp_path_factory.mktemp("asan") / "rfh_harness", sanitize=True)


def inner(code: int, body: bytes) -> bytes:
    data = pystruct.pack("<BBBHI", 1, code, 7, 1, 99) + body
    return data + pystruct.pack("<H", crc16(data))


def wire(inner_frame: bytes) -> bytes:
    return b"\0" + cobs.encode(inner_frame) + b"\0"


def _near_limit(code: int, size: int, zero_every: int, fill: bytes) -> bytes:
    """A CRC-correct frame of ``size`` inner bytes; zeros every ``zero_every`` bytes let it
    decode past 1024 bytes while its encoding stays within 1029."""
    body = bytearray((fill * (size // len(fill) + 1))[: size - 11])
    body[zero_every - 1 :: zero_every] = bytes(len(body[zero_every - 1 :: zero_every]))
    return wire(inner(code, bytes(body)))


def _edit(frame: bytes, edits: list[tuple[int, int, int]]) -> bytes:
    buf = bytearray(frame)
    for where, op, value in edits:
        if not buf:
            break
        i = where % len(buf)
        if op == 0:
            buf[i] ^= 1 << (value % 8)
        elif op == 1:
            del buf[i]
        elif op == 2:
            buf.insert(i, value)
        else:
            del buf[i:]
    return bytes(buf)


inputs = st.one_of(
    st.builds(_near_limit, st.sampled_from([0x7F, 0x01, 0x80, 0x55]), st.integers(1015, 1035), st.integers(2, 300),
              st.binary(min_size=1, max_size=16)),
    st.binary(max_size=40).map(lambda b: wire(inner(0x7F, b))),  # log_text bodies, mostly not UTF-8
    st.text(max_size=40).map(lambda t: wire(inner(0x7F, t.encode("utf-8", "surrogatepass")))),
    st.tuples(records, st.lists(st.tuples(st.integers(0, 2000), st.integers(0, 3), st.integers(0, 255)), max_size=4))
    .map(lambda r: _edit(encode_frame(r[0]) if py_frame(r[0]) else b"\0\0", r[1])),
    st.binary(max_size=300),
)


@pytest.mark.slow
@settings(deadline=None)
@given(st.lists(inputs, min_size=1, max_size=4).map(b"".join))
def test_c_reference_and_python_agree_on_invalid_and_near_limit_input(sanitized: Path, data: bytes) -> None:
    """Before: Python accepted inner frames of 1025-1028 bytes (C: oversize) and C accepted a
    log_text that is not UTF-8 (Python: a "length" drop that was not about the length)."""
    assert run_harness(sanitized, [data])[0] == python_words(data)


UTF8_CASES = [b"", b"plain", "ünïcödé ✓ 𝄞".encode(), b"\xff", b"\xc0\x80", b"\xed\xa0\x80", b"\xf4\x90\x80\x80",
              b"\xe2\x82", b"ok\xe2\x82\xac\xf0\x9f\x98", b"\xf0\x9f\x98\x80"]


@pytest.mark.slow
def test_the_encoders_limits_decide_in_both_decoders(sanitized: Path) -> None:
    """Near the limit and on UTF-8's edges, case by case (built with sanitizers)."""
    cases = [_near_limit(0x7F, n, 100, b"x") for n in (1023, 1024, 1025, 1028)]
    cases += [b"\0" + b"\x01" * n + b"\0" for n in (1029, 1030)] + [wire(inner(0x7F, b)) for b in UTF8_CASES]
    got = run_harness(sanitized, cases)
    assert got == [python_words(c) for c in cases]
    kinds = [[w[0] + (w[1:] if w[0] == "D" else "") for w in words] for words in got]
    assert kinds[:6] == [["F"], ["F"], ["D1"], ["D1"], ["D1"], ["D1"]]  # 1029 x 01: 1028 zeros
    assert kinds[6:] == [["F"], ["F"], ["F"], ["L"], ["L"], ["L"], ["L"], ["L"], ["L"], ["F"]]


@pytest.mark.slow
def test_a_random_corpus_runs_clean_under_the_sanitizers(sanitized: Path) -> None:
    rng = random.Random(0)
    corpus = [rng.randbytes(rng.randint(0, 3000)) for _ in range(300)]
    corpus += [bytes(rng.choice((0, 1, 2, 0xFF, rng.randrange(256))) for _ in range(rng.randint(0, 3000)))
               for _ in range(300)]
    assert run_harness(sanitized, corpus) == [python_words(c) for c in corpus]


@pytest.mark.parametrize("text", UTF8_CASES)
def test_the_c_encoder_refuses_a_log_text_that_is_not_utf8(lib: C.CDLL, text: bytes) -> None:
    try:
        expected = encode_frame(RECORD_TYPES[0x7F].cls(7, 1, 99, text.decode("utf-8")))
    except UnicodeDecodeError:
        expected = b""
    keep = _bytes_ptr(text)
    assert c_encode_struct(lib, 0x7F, Header(7, 1, 99), LogText(keep, len(text))) == expected
