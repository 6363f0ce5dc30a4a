"""Differential fuzzer for the two decoders and the pcapng reader.

Streams of three sorts, seeded: ``random`` bytes, ``mutated`` valid streams (bit flips, byte
deletions, insertions, duplications, truncation) and ``structure``-aware ones (valid records or
lines of every type with random field values, garbage between them; for pcapng, blocks with
random lengths, options and interface ids, concatenated sections). Each stream is decoded

- by the decoder with the C accelerator (where it is built), fed in random chunks,
- by the pure-Python decoder (``pure=True``) in the same chunks,
- by the C decoder fed the whole buffer at once,

and the three outputs must be identical. It counts escaped exceptions (anything but the
documented result: items and drops from a decoder, CaptureFormatError from the pcapng reader),
differences between the three, intact frames/lines lost (a frame or line no mutation touched,
delimiters included, that is missing from the output), and corrupt records accepted (a record
that is not one of those encoded). For the COBS records that last count is held against the
CRC-16: a touched frame that still passes COBS, length and type checks is accepted with
probability 2^-16, so the expected count is at most touched / 65536. The text protocol has no
checksum: an altered +UUDF line that still parses is reported, not held against anything.

More targets, each fed random, mutated and structure-aware input the same way:

- ``espat``: EspAtDecoder (scan reports, other lines, lines at and around the 700-byte limit);
  chunked and whole must agree and an intact report must come out;
- ``h4``: the H4 splitter on bumble-encoded events with junk; chunked and whole must agree, and
  an intact packet more than the splitter's bound (1026 bytes) past the last junk must come out
  whenever the header rules reach it from every state the junk can leave the splitter in (lost
  to a chain of plausible headers in the payloads instead: ``intact_units_misframed``, counted);
- ``ad``: the advertising-data filters on any bytes (nothing may raise);
- ``hci``: HciDriver.on_chunk (splitter, bumble's parser, data packets): nothing may escape, and
  readings and counters are the same in any chunking;
- ``cref``: the C reference (tests/rfh_harness.c, built here) against FrameDecoder, frame end by
  frame end, on near-limit frames, log_text bodies, mutated frames and random bytes;
- ``config``, ``site``, ``points``, ``profile``: the TOML readers (the last: radio profiles, from
  the shipped measured one) on random, mutated and retyped files, values among them nested 1,000
  deep and 400-digit numbers: only the project's Error may come out (``escaped.<type>`` counts
  the rest by type);
- ``truth``: the ground-truth (waypoint CSV) reader, with a site's area, on random, mutated and
  retyped files (waypoints 10^10 m away, times 10^15 ms apart or backwards, 400-digit numbers,
  UTF-16 and Latin-1 text): only the project's Error may come out;
- ``sitebus``: a site worker's drain (host/sitebus.py: the angle-batch decoder, then numpy and the
  batched engine) on one message between two good batches: random bytes, mutated batches
  (versions 1 and 2), and hostile JSON (nesting to 100,000 levels, numbers of up to 20,000 digits,
  1e999, NaN, ids with MQTT wildcards, lone surrogates, fields of the wrong type); nothing may
  escape the drain or the worker's tick, and the good batches' events must all be fed
  (``good_events_lost``): a message costs at most itself.

    python bench/fuzz.py --n 20000                     # every target, 20,000 streams each
    python bench/fuzz.py --target frames --n 1000000 --seconds 3600
    python bench/fuzz.py --target pcapng --n 100000 --json
    python bench/fuzz.py --target cref --n 1000000 --json
    python bench/fuzz.py --target sitebus --n 1000000 --json
    python bench/fuzz.py --hypothesis                  # the property tests, many more examples

--seconds bounds each target's time; the report says how many streams actually ran.
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import os
import random
import struct
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import construct as cs
from bumble import hci
from cobs import cobs

from rfhoming.host.drivers.hci import HciDriver
from rfhoming.host.ports import HostPort
from rfhoming.protocol import accel, espat, h4, pcapng, sitebus
from rfhoming.protocol import ad as adv
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.errors import Error
from rfhoming.protocol.espat import EspAtDecoder, ScanReport, encode_scan
from rfhoming.protocol.frames import FrameDecoder, encode_frame
from rfhoming.protocol.frames.records import RECORD_TYPES, AntennaReading, crc16
from rfhoming.protocol.h4 import H4Splitter
from rfhoming.protocol.uconnect import AngleEvent, Dialect, UConnectDecoder, encode_angle_event

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
import cref  # noqa: E402  (tests/cref.py: the C reference's build and its words, shared with the tests)

KINDS = ("random", "mutated", "structure")
HYPOTHESIS_FILES = ["tests/test_frames.py", "tests/test_uconnect_decoder.py", "tests/test_accel.py",
                    "tests/test_pcapng_malformed.py", "tests/test_esp_at.py", "tests/test_hci.py",
                    "tests/test_c_reference.py"]


# -- mutations ------------------------------------------------------------------------------
def mutate(rng: random.Random, data: bytes, count: int) -> tuple[bytes, list[int]]:
    """``count`` random edits; returns the new bytes and the original positions touched."""
    buf = bytearray(data)
    touched: list[int] = []
    for _ in range(count):
        if not buf:
            break
        i = rng.randrange(len(buf))
        op = rng.randrange(5)
        if op == 0:
            buf[i] ^= 1 << rng.randrange(8)
        elif op == 1:
            del buf[i]
        elif op == 2:
            buf[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
        elif op == 3:
            buf[i] = rng.choice((0, 0x0D, 0x0A, 0x22, 0x2C, rng.randrange(256)))
        else:
            j = min(len(buf), i + rng.randint(1, 16))
            buf[j:j] = buf[i:j]
        touched.append(i)
    return bytes(buf), touched


def apply_edits(rng: random.Random, parts: list[bytes], edits: int) -> tuple[bytes, set[int]]:
    """Mutate the concatenation of ``parts``; the indices of parts no edit touched.

    Edits are made part by part, so "touched" is exact: a part is touched when an edit fell in
    it. Parts carry their own delimiters (a frame its two zeros, a line its CRLFs).
    """
    n = len(parts)
    hits = [0] * n
    for _ in range(edits):
        hits[rng.randrange(n)] += 1
    out = []
    for k, part in enumerate(parts):
        out.append(mutate(rng, part, hits[k])[0] if hits[k] else part)
    return b"".join(out), {k for k in range(n) if not hits[k]}


def chunks_of(rng: random.Random, data: bytes) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        n = rng.choice((1, 2, 3, 7, 16, 64, 200, 4096))
        out.append(data[i : i + n])
        i += n
    return out


# -- structured inputs ----------------------------------------------------------------------
def _value(rng: random.Random, con: cs.Construct) -> Any:
    if isinstance(con, cs.FormatField):
        bits = struct.calcsize(con.fmtstr) * 8
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if con.fmtstr[1:].islower() else (0, (1 << bits) - 1)
        return rng.choice((lo, hi, 0, rng.randint(lo, hi), rng.randint(max(lo, -100), min(hi, 100))))
    if isinstance(con, cs.Bytes):
        n = con.length if isinstance(con.length, int) else rng.randint(0, 64)
        return rng.randbytes(n)
    if isinstance(con, cs.Array):
        if isinstance(con.count, int):
            return tuple(AntennaReading(*[_value(rng, sc.subcon) for sc in con.subcon.subcons])
                         for _ in range(con.count))
        return tuple(_value(rng, con.subcon) for _ in range(rng.randint(0, 40)))
    if isinstance(con, cs.StringEncoded):
        return "".join(chr(rng.choice((rng.randint(32, 126), rng.randint(160, 0x2FFF)))) for _ in range(rng.randint(0, 40)))
    if con is cs.GreedyBytes:
        return rng.randbytes(rng.randint(0, 8))
    raise TypeError(con)


def random_record(rng: random.Random) -> Any:
    rt = rng.choice(list(RECORD_TYPES.values()))
    body = [_value(rng, sc.subcon) for sc in rt.body.subcons if not isinstance(sc.subcon, cs.Rebuild)]
    return rt.cls(rng.randrange(256), rng.randrange(65536), rng.randrange(2**32), *body)


def random_event(rng: random.Random) -> tuple[AngleEvent, Dialect]:
    dialect = rng.choice(list(Dialect))
    seq = rng.randrange(65536) if dialect in (Dialect.V2, Dialect.EMBED) else None
    raw = dialect is Dialect.EMBED
    text = lambda: "".join(chr(rng.randint(32, 126)) for _ in range(rng.randint(0, 12))).replace('"', "")  # noqa: E731
    return AngleEvent(
        "".join(rng.choice("0123456789ABCDEF") for _ in range(12)), rng.randint(-127, 20), rng.randint(-90, 90),
        rng.randint(-90, 90), rng.randint(-127, 20) if dialect is Dialect.V1_0 else 0,
        rng.randint(37, 39) if dialect in (Dialect.V1_0, Dialect.V1_2) else rng.randint(0, 36), text(), text(),
        rng.randint(-(2**31), 2**31 - 1), seq, rng.randint(-90, 90) if raw else None,
        rng.randint(-90, 90) if raw else None), dialect


OTHER_LINES = (b"\r\nOK\r\n", b"\r\nERROR\r\n", b"\r\n+STARTUP\r\n", b"AT+GMM\r", b"\r\n+UUDFP:0,1\r\n",
               b'\r\n"2.1.0-010"\r\n', b"\r\n+UUDF:bad\r\n")


class Counts(dict):
    def add(self, key: str, n: int = 1) -> None:
        self[key] = self.get(key, 0) + n


# -- decoder targets ------------------------------------------------------------------------
class DecoderTarget:
    """A decoder with a C path and a pure path; ``parts`` builds a valid stream of units."""

    name = ""
    make: Callable[..., Any]

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        raise NotImplementedError

    def decode(self, data_chunks: list[bytes], pure: bool) -> list[Any]:
        d = self.make(pure=pure)
        out: list[Any] = []
        for c in data_chunks:
            out += d.feed(c)
        return out + d.flush()

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        expected: list[Any] = []
        intact: set[int] = set()
        if kind == "random":
            data = rng.randbytes(rng.randint(0, 2000))
        else:
            parts, expected = self.parts(rng)
            if kind == "mutated":
                data, intact = apply_edits(rng, parts, rng.randint(1, 8))
            else:  # structure: garbage between valid units
                glue = [rng.randbytes(rng.randint(0, 20)) if rng.random() < 0.3 else b"" for _ in parts]
                data = b"".join(g + p for g, p in zip(glue, parts))
                intact = {k for k in range(len(parts)) if not glue[k] and (k + 1 >= len(glue) or not glue[k + 1])}
        c.add("streams")
        c.add("bytes", len(data))
        pieces = chunks_of(rng, data)
        try:
            fast = self.decode(pieces, pure=False)
            slow = self.decode(pieces, pure=True)
            whole = self.decode([data], pure=False)
        except Exception as exc:  # noqa: BLE001 -- counting what escapes is the point
            c.add("escaped_exceptions")
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {exc} on {data[:80]!r}")
            return
        if fast != slow:
            c.add("c_vs_python_differences")
        if fast != whole:
            c.add("chunked_vs_whole_differences")
        accepted = [i for i in fast if not isinstance(i, Drop)]
        known = [e for e in expected if e is not None]
        for k in intact:
            if expected[k] is not None:
                c.add("intact_units")
                if expected[k] not in accepted:
                    c.add("intact_units_lost")
                    if len(examples) < 5:
                        examples.append(f"intact unit lost: {expected[k]!r}")
        if kind == "mutated":
            touched = len(expected) - len(intact)
            c.add("touched_units", touched)
            self.count_corrupt(accepted, known, c)

    def count_corrupt(self, accepted: list[Any], known: list[Any], c: Counts) -> None:
        c.add("corrupt_accepted", sum(1 for a in accepted if self.is_record(a) and a not in known))

    def is_record(self, item: Any) -> bool:
        return True


class FramesTarget(DecoderTarget):
    name = "frames"
    make = FrameDecoder

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        parts, expected = [], []
        for _ in range(rng.randint(1, 12)):
            record = random_record(rng)
            try:
                frame = encode_frame(record)
            except Exception:  # noqa: BLE001 -- a field value the encoder cannot write: skip
                continue
            alone = FrameDecoder(pure=True).feed(frame)
            parts.append(frame)
            expected.append(record if alone == [record] else None)  # None: the decoder rightly drops it
        return parts or [b"\0\0"], expected or [None]


class UConnectTarget(DecoderTarget):
    name = "uconnect"
    make = UConnectDecoder

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        parts, expected = [], []
        for _ in range(rng.randint(1, 12)):
            if rng.random() < 0.8:
                event, dialect = random_event(rng)
                line = encode_angle_event(event, dialect)
                alone = [i for i in UConnectDecoder(pure=True).feed(line) if i.kind == "angle"]
                parts.append(line)
                expected.append(alone[0] if len(alone) == 1 else None)
            else:
                parts.append(rng.choice(OTHER_LINES))
                expected.append(None)
        return parts, expected

    def is_record(self, item: Any) -> bool:
        return isinstance(item, AngleEvent)


# -- the pcapng reader ----------------------------------------------------------------------
def _block(kind: int, body: bytes, length: int | None = None) -> bytes:
    n = 12 + len(body) if length is None else length
    return struct.pack("<II", kind, n) + body + struct.pack("<I", n)


def _options(rng: random.Random, codes: tuple[int, ...]) -> bytes:
    out = b""
    for _ in range(rng.randint(0, 3)):
        value = rng.randbytes(rng.choice((0, 1, 2, 4, 8, rng.randint(0, 30))))
        length = len(value) if rng.random() < 0.9 else rng.randint(0, 70)
        out += struct.pack("<HH", rng.choice(codes), length) + value + b"\0" * (-len(value) % 4)
    return out + (struct.pack("<HH", 0, 0) if rng.random() < 0.8 else b"")


def valid_capture(rng: random.Random) -> bytes:
    out = b""
    for _ in range(rng.randint(1, 2)):
        out += pcapng.section_header()
        n = rng.randint(1, 3)
        for k in range(n):
            out += pcapng.interface(f"/dev/tty{k}", "protocol=rss", rng.choice((147, 148)))
        for _ in range(rng.randint(0, 10)):
            out += pcapng.packet(rng.randrange(n), rng.random() * 1e4, rng.randbytes(rng.randint(0, 60)),
                                 rng.choice((1, 2)), rng.choice(("", "disconnected", "x" * rng.randint(0, 9))))
    return out


def structured_capture(rng: random.Random) -> bytes:
    out = pcapng.section_header() if rng.random() < 0.9 else b""
    for _ in range(rng.randint(0, 8)):
        kind = rng.choice((pcapng.SHB, pcapng.IDB, pcapng.EPB, 5, 3))
        if kind == pcapng.IDB:
            body = struct.pack("<HHI", rng.choice((147, 148, 1)), 0, 0)[: rng.choice((0, 2, 8, 8, 8))]
            body += _options(rng, (pcapng.OPT_IF_NAME, pcapng.OPT_IF_TSRESOL, pcapng.OPT_IF_TSRESOL, 99))
        elif kind == pcapng.EPB:
            data = rng.randbytes(rng.randint(0, 40))
            caplen = len(data) if rng.random() < 0.8 else rng.randint(0, 100)
            body = struct.pack("<IIIII", rng.choice((0, 0, 1, 2, 2**32 - 1)), rng.randrange(2**32), rng.randrange(2**32),
                               caplen, len(data))[: rng.choice((20, 20, 20, 8, 0))]
            body += data + b"\0" * (-len(data) % 4) + _options(rng, (pcapng.OPT_EPB_FLAGS, pcapng.OPT_COMMENT))
        elif kind == pcapng.SHB:
            body = struct.pack("<IHHq", pcapng.BYTE_ORDER_MAGIC, 1, 0, -1)[: rng.choice((16, 16, 4))]
        else:
            body = rng.randbytes(rng.choice((0, 4, 8)))
        body += b"\0" * (-len(body) % 4)
        length = None if rng.random() < 0.9 else rng.choice((0, 8, 12, 13, 16 + len(body), 2**31))
        out += _block(kind, body, length)
    return out


def _read_chunked(pieces: list[bytes]) -> tuple[list[Any], int, int | None]:
    reader = pcapng.Reader()
    items: list[Any] = []
    try:
        for p in pieces:
            items += reader.feed(p)
    except pcapng.CaptureFormatError as exc:  # the buffer's state then depends on the chunking
        return items + exc.items, -1, exc.offset
    return items, reader.pending, None


class PcapngTarget:
    name = "pcapng"

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        if kind == "random":
            data = rng.randbytes(rng.randint(0, 600))
            if rng.random() < 0.5:
                data = pcapng.section_header() + data
        elif kind == "mutated":
            data = mutate(rng, valid_capture(rng), rng.randint(1, 6))[0]
        else:
            data = structured_capture(rng)
        c.add("streams")
        c.add("bytes", len(data))
        try:
            try:
                pcapng.read_all(data)
                c.add("read_whole")
            except pcapng.CaptureFormatError as exc:
                c.add("format_errors")
                if not str(exc).startswith(f"offset {exc.offset}: "):
                    c.add("errors_without_offset")
            chunked = _read_chunked(chunks_of(rng, data))
            whole = _read_chunked([data])
        except Exception as exc:  # noqa: BLE001 -- counting what escapes is the point
            c.add("escaped_exceptions")
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {exc} on {data[:80]!r}")
            return
        if chunked != whole:
            c.add("chunked_vs_whole_differences")


# -- ESP-AT, H4, advertising data, the HCI driver ------------------------------------------
def random_scan(rng: random.Random) -> ScanReport:
    return ScanReport("".join(rng.choice("0123456789ABCDEF") for _ in range(12)), rng.randint(-128, 20),
                      rng.randbytes(rng.randint(0, 31)), rng.randbytes(rng.choice((0, 0, rng.randint(0, 31)))),
                      rng.randint(0, 3))


ESPAT_LINES = (b"OK\r\n", b"ERROR\r\n", b"ready\r\n", b"+BLESCANDONE\r\n", b"AT+BLESCAN=1,0\r\n",
               b"+BLEINIT:1\r\n", b"\r\n")


class SingleTarget:
    """A decoder with one path: chunked and whole must agree; ``parts`` are valid units."""

    name = ""

    def make(self) -> Any:
        raise NotImplementedError

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        raise NotImplementedError

    def decode(self, pieces: list[bytes]) -> tuple[list[Any], dict[str, int]]:
        d = self.make()
        out = [i for p in pieces for i in d.feed(p)]
        return out, dict(d.counters)

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        if kind == "random":
            data, parts, expected, intact = rng.randbytes(rng.randint(0, 2000)), [], [], set()
        else:
            parts, expected = self.parts(rng)
            if kind == "mutated":
                data, intact = apply_edits(rng, parts, rng.randint(1, 8))
            else:
                glue = [rng.randbytes(rng.randint(0, 20)) if rng.random() < 0.3 else b"" for _ in parts]
                data = b"".join(g + p for g, p in zip(glue, parts))
                intact = {k for k in range(len(parts)) if not glue[k] and (k + 1 >= len(glue) or not glue[k + 1])}
        c.add("streams")
        c.add("bytes", len(data))
        try:
            cut = self.decode(chunks_of(rng, data))
            whole = self.decode([data])
        except Exception as exc:  # noqa: BLE001 -- counting what escapes is the point
            c.add("escaped_exceptions")
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {exc} on {data[:80]!r}")
            return
        if cut != whole:
            c.add("chunked_vs_whole_differences")
            if len(examples) < 5:
                examples.append(f"chunking changed the result on {data[:80]!r}")
        self.check_intact(data, parts, expected, intact, cut[0], c, examples)

    def check_intact(self, data: bytes, parts: list[bytes], expected: list[Any], intact: set[int], out: list[Any],
                     c: Counts, examples: list[str]) -> None:
        for k in intact:
            if expected[k] is not None:
                c.add("intact_units")
                if expected[k] not in out:
                    c.add("intact_units_lost")
                    if len(examples) < 5:
                        examples.append(f"intact unit lost: {expected[k]!r}")


class EspAtTarget(SingleTarget):
    """Lines carry only their own terminator, so a line is intact when the one before it is
    too (an edit there can take its LF away and join the two)."""

    name = "espat"

    def check_intact(self, data: bytes, parts: list[bytes], expected: list[Any], intact: set[int], out: list[Any],
                     c: Counts, examples: list[str]) -> None:
        super().check_intact(data, parts, expected, {k for k in intact if k == 0 or k - 1 in intact}, out, c, examples)

    def make(self) -> Any:
        return EspAtDecoder()

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        parts, expected = [], []
        for _ in range(rng.randint(1, 12)):
            if rng.random() < 0.7:
                report = random_scan(rng)
                parts.append(encode_scan(report))
                expected.append(report)
            else:
                n = rng.choice((espat.MAX_LINE - 1, espat.MAX_LINE, espat.MAX_LINE + 1, rng.randint(0, 40)))
                parts.append(rng.choice((b"+BLEINIT:", b"AT")) + b"1" * n + rng.choice((b"\r\n", b"\n", b"\r\r\n"))
                             if rng.random() < 0.3 else rng.choice(ESPAT_LINES))
                expected.append(None)
        return parts, expected


def random_event_packet(rng: random.Random) -> bytes:
    """An HCI event an LE scanner gets, encoded by bumble (the independent encoder)."""
    if rng.random() < 0.7:
        Report = hci.HCI_LE_Advertising_Report_Event.Report
        reports = [Report(event_type=rng.randrange(5), address_type=rng.randrange(2),
                          address=hci.Address(bytes(rng.randbytes(6))), data=rng.randbytes(rng.randint(0, 31)),
                          rssi=rng.randint(-127, 20)) for _ in range(rng.randint(1, 3))]
        return bytes(hci.HCI_LE_Advertising_Report_Event(reports))
    return bytes(hci.HCI_Command_Complete_Event(num_hci_command_packets=1, command_opcode=rng.choice((0x0C03, 0x2003)),
                                                return_parameters=bytes([0]) + rng.randbytes(rng.choice((0, 8)))))


class H4Target(SingleTarget):
    """The splitter alone. H4 has no resynchronisation marker, so after junk no parser can
    promise the next packets (a payload may hold a chain of plausible headers); what the
    splitter promises is checked instead. An intact packet that starts at least MAX_HOLD bytes
    after the last junk is *checked*; if it is lost, that is a failure (``intact_units_lost``)
    only when the header rules (protocol/h4.py, stepped here by :func:`_takes`, not by the
    splitter's code) reach it from every state the splitter can be in when it leaves the junk:
    hunting or in step at the junk's end, or in step where a packet claimed by any plausible
    header within MAX_HOLD before that end would end. Otherwise it is ``intact_units_misframed``: lost to a
    chain of plausible headers that carries on past it, which these rules cannot avoid."""

    name = "h4"

    def make(self) -> Any:
        return H4Splitter(h4.TO_HOST)

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        parts = [random_event_packet(rng) for _ in range(rng.randint(1, 60))]  # long enough to pass the bound
        return parts, list(parts)

    def check_intact(self, data: bytes, parts: list[bytes], expected: list[Any], intact: set[int], out: list[Any],
                     c: Counts, examples: list[str]) -> None:
        if not parts:
            return
        at, last_junk_end, starts = 0, 0, []
        for k, p in enumerate(parts):  # parts keep their order; junk or edits sit between/inside
            i = data.find(p, at) if k in intact else -1
            starts.append(i)
            if i < 0:
                last_junk_end = max(last_junk_end, at + 1)
            else:
                if i > at:
                    last_junk_end = i
                at = i + len(p)
        for k, i in enumerate(starts):
            if k in intact and i >= 0 and i - last_junk_end >= MAX_HOLD and all(s >= 0 for s in starts[k:]):
                c.add("intact_units")
                if parts[k] not in out:
                    if not _guaranteed(data, last_junk_end, i):
                        c.add("intact_units_misframed")
                        continue
                    c.add("intact_units_lost")
                    if len(examples) < 5:
                        examples.append(f"packet lost beyond the bound: {parts[k][:20].hex()}")


MAX_HOLD = h4.max_hold()


def _step(data: bytes, j: int, hunting: bool) -> tuple[int, bool, bool] | None:
    """The header rules at ``j``: (next position, hunting, whether a packet was taken), or
    None where the splitter waits for bytes that never come."""
    kind = data[j]
    size = h4.HEADERS[kind][0] if kind in h4.TO_HOST else 0
    if size and len(data) - j < 1 + size:
        return None
    if not size or not h4.plausible(kind, data[j + 1 : j + 1 + size]):
        return j + 1, True, False
    _, at, n = h4.HEADERS[kind]
    length = int.from_bytes(data[j + 1 + at : j + 1 + at + n], "little") & (0x3FFF if kind == h4.ISO else 0xFFFF)
    end = j + 1 + size + length
    if end > len(data):
        return None
    if hunting and not h4.resync_point(data, j):
        if end >= len(data):
            return None
        nk = data[end]
        nsize = h4.HEADERS[nk][0] if nk in h4.TO_HOST else 0
        if nsize and len(data) - end < 1 + nsize:
            return None
        if not nsize or not h4.plausible(nk, data[end + 1 : end + 1 + nsize]):
            return j + 1, True, False
    return end, False, True


def _guaranteed(data: bytes, junk_end: int, start: int) -> bool:
    """Whether the rules take the packet at ``start`` from every state the splitter can be in
    when it leaves the junk: at its end, hunting or in step, or in step at the end of a packet
    claimed by a plausible header within MAX_HOLD before that end."""
    takes: dict[tuple[int, bool], bool] = {}
    for j in range(start, junk_end - 1, -1):  # every step moves forward: fill from the packet back
        for hunting in (False, True):
            step = _step(data, j, hunting)
            if step is None:
                takes[j, hunting] = False
            elif j == start:
                takes[j, hunting] = step[2]
            else:
                nxt, h, _ = step
                takes[j, hunting] = nxt <= start and takes[nxt, h]
    entries = {junk_end}
    for q in range(max(0, junk_end - MAX_HOLD), junk_end):
        step = _step(data, q, False)
        if step is not None and step[2] and junk_end <= step[0] <= start:
            entries.add(step[0])
    return takes[junk_end, True] and all(takes[r, False] for r in entries)


class AdTarget:
    """protocol/ad.py on any bytes: the filters never raise."""

    name = "ad"

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        if kind == "random":
            data = rng.randbytes(rng.randint(0, 64))
        else:
            data = b"".join(bytes([len(v) + 1, t]) + v for t, v in (
                (rng.choice((0x01, 0x02, 0x03, 0x08, 0x09, 0x16, 0xFF, rng.randrange(256))), rng.randbytes(rng.randint(0, 30)))
                for _ in range(rng.randint(0, 4))))
            if kind == "mutated":
                data = mutate(rng, data, rng.randint(1, 4))[0]
        c.add("streams")
        try:
            list(adv.structures(data)), adv.local_name(data), adv.is_ibeacon(data), adv.is_eddystone(data)
        except Exception as exc:  # noqa: BLE001
            c.add("escaped_exceptions")
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {exc} on {data!r}")


class HciDriverTarget(SingleTarget):
    """HciDriver.on_chunk (splitter, bumble's parser, the report path): nothing escapes, and
    the readings and counters are the same in any chunking."""

    name = "hci"

    def make(self) -> Any:
        return HciDriver(HostPort("/dev/null", name="fuzz"))

    def parts(self, rng: random.Random) -> tuple[list[bytes], list[Any]]:
        parts = [random_event_packet(rng) if rng.random() < 0.85 else
                 bytes([rng.choice((2, 3, 5))]) + b"\x01\x00" + bytes([4, 0]) + rng.randbytes(4) for _ in range(rng.randint(1, 10))]
        return parts, [None] * len(parts)

    def decode(self, pieces: list[bytes]) -> tuple[list[Any], dict[str, int]]:
        d = self.make()
        for p in pieces:
            d.on_chunk(p, 0.0)
        readings = []
        while (r := d.out.get_nowait()) is not None:
            readings.append(r)
        return readings, {k: v for k, v in d.counters.items()}


# -- the C reference against the Python decoder ---------------------------------------------
def cref_input(rng: random.Random, kind: str) -> bytes:
    if kind == "random":
        return rng.randbytes(rng.randint(0, 1500))
    if kind == "mutated":
        frames = []
        for _ in range(rng.randint(1, 4)):
            try:
                frames.append(encode_frame(random_record(rng)))
            except Exception:  # noqa: BLE001 -- a value the encoder cannot write
                continue
        return mutate(rng, b"".join(frames) or b"\0\0", rng.randint(1, 6))[0]
    code = rng.choice((0x7F, 0x7F, 0x01, 0x22, 0x80, rng.randrange(256)))
    if rng.random() < 0.5:  # near the limit, zeros so that the encoding stays within 1029 bytes
        size, every = rng.randint(1015, 1035), rng.randint(2, 300)
        body = bytearray(rng.randbytes(size - 11))
        body[every - 1 :: every] = bytes(len(body[every - 1 :: every]))
    else:  # short bodies: UTF-8 edges for log_text, lengths for the others
        body = bytearray(rng.choice((rng.randbytes(rng.randint(0, 40)),
                                     "".join(chr(rng.choice((rng.randint(32, 126), rng.randint(0x80, 0x10FFFF))))
                                             for _ in range(rng.randint(0, 20))).encode("utf-8", "surrogatepass"))))
    data = struct.pack("<BBBHI", 1, code, 7, 1, 99) + bytes(body)
    return b"\0" + cobs.encode(data + struct.pack("<H", crc16(data))) + b"\0"


class CrefTarget:
    """tests/rfh_harness.c (the C reference, -O2) against FrameDecoder, word by word
    (tests/cref.py); inputs go to the harness in batches."""

    name = "cref"
    batch = 2000

    def __init__(self) -> None:
        self.exe: Path | None = None
        self.pending: list[bytes] = []

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        self.pending.append(cref_input(rng, kind))
        c.add("streams")
        if len(self.pending) >= self.batch:
            self.flush(c, examples)

    def flush(self, c: Counts, examples: list[str]) -> None:
        if not self.pending:
            return
        if self.exe is None:
            cc = cref.compiler()
            if cc is None:
                raise SystemExit("cref: no C compiler on PATH")
            self.exe = cref.build_harness(cc, Path(tempfile.mkdtemp()) / "rfh_harness", sanitize=False)
        inputs, self.pending = self.pending, []
        for data, words in zip(inputs, cref.run_harness(self.exe, inputs)):
            c.add("bytes", len(data))
            try:
                expected = cref.python_words(data)
            except Exception as exc:  # noqa: BLE001
                c.add("escaped_exceptions")
                if len(examples) < 5:
                    examples.append(f"{type(exc).__name__}: {exc} on {data[:80]!r}")
                continue
            if words != expected:
                c.add("c_vs_python_differences")
                if len(examples) < 5:
                    examples.append(f"C {words[:3]} vs Python {expected[:3]} on {data[:60].hex()}")


# -- file readers: only the project's Error (or CaptureFormatError) may come out -------------
SITE = (ROOT / "docs/sites/kit-room.toml").read_bytes()
POINTS = (ROOT / "docs/sites/kit-room-points.toml").read_bytes()
PROFILE = (ROOT / "protocol/profiles/measured.toml").read_bytes()
def _config_sample() -> bytes:
    """The documented default config (every section and key), comments dropped (they only feed
    the TOML parser), with device tables and anchors: a file the reader accepts, so mutations
    reach every check of the schema. (The sample before this was refused whole, at its
    ``[devices]`` table, so nearly every mutation stopped there.)"""
    from rfhoming.host.homing import config

    lines = [line.split(" #")[0].rstrip() for line in config.DEFAULT_TOML.splitlines()
             if line.strip() and not line.lstrip().startswith("#")]
    return ("\n".join(lines) + '\nA1 = [0.0, 0.0]\nA2 = [4.0, 0.0]\nA3 = [0.0, 3.0]\n'
            '[devices.aoa]\nport = "xplr-aoa:/dev/ttyUSB0"\nbaud = 1000000\ntags = ["CCF9578E0D8A"]\n'
            '[devices.base]\nport = "base:/dev/ttyACM0"\n').encode()


CONFIG = _config_sample()
TOML_VALUES = (b"1", b"-1", b"0.5", b"1e400", b"nan", b"inf", b"true", b'"x"', b"[1, 2, 3]", b"[]", b"{}",
               b'{a = 1}', b"[1, 2]", b'"\\u0000"', b"1979-05-27", b"[[1]]", b"9" * 400, b"-" + b"9" * 400,
               b"[" * 1000 + b"]" * 1000, b"{a = " * 100 + b"1" + b"}" * 100)


def toml_input(rng: random.Random, kind: str, sample: bytes) -> bytes:
    if kind == "random":
        return rng.randbytes(rng.randint(0, 300))
    if kind == "mutated":
        return mutate(rng, sample, rng.randint(1, 6))[0]
    lines = sample.split(b"\n")
    for _ in range(rng.randint(1, 4)):  # a value replaced by one of another type or range
        i = rng.randrange(len(lines))
        if b"=" in lines[i]:
            lines[i] = lines[i].split(b"=", 1)[0] + b"= " + rng.choice(TOML_VALUES)
        elif rng.random() < 0.3:
            lines[i] = rng.choice((b"[x]", b"[[points]]", b"[anchors.a]", b"[loop]", b"[devices]"))
    return b"\n".join(lines)


TRUTH = (b"arrival_ms,leave_ms,x_cm,y_cm\n1670598717410,NaN,240,480\n1670598719949,NaN,240,360\n"
         b"1670598722480,1670598723480,240,240\n1670598724965,NaN,360,120\n1670598727811,NaN,600,120\n")
"""A waypoint file of the layout of girolami_xplr_aoa/ground_truth/*.csv (ms, ms, cm, cm), inside kit-room."""
TRUTH_VALUES = (b"NaN", b"nan", b"inf", b"-1", b"0", b"1e10", b"1e12", b"1e15", b"1670598717410", b"9" * 400, b"",
                b"x", b"\xff", b'"1,2"', b"1e999", b"-0")


def truth_input(rng: random.Random, kind: str, sample: bytes) -> bytes:
    if kind != "structure":
        return toml_input(rng, kind, sample)
    rows = [row.split(b",") for row in sample.split(b"\n")]
    for _ in range(rng.randint(1, 3)):  # a field of another size or sign, a row moved, repeated or dropped
        row = rows[rng.randrange(1, len(rows) - 1)]
        edit = rng.random()
        if edit < 0.6 and len(row) == 4:
            row[rng.randrange(4)] = rng.choice(TRUTH_VALUES)
        elif edit < 0.8:
            rows.insert(rng.randrange(1, len(rows)), list(row))
        elif len(rows) > 2:
            rows.pop(rng.randrange(1, len(rows) - 1))
    text = b"\n".join(b",".join(row) for row in rows)
    if rng.random() < 0.1:  # another encoding of the same rows (a Latin-1 header with its accent, as Excel saves it)
        encoding = rng.choice(("utf-16", "utf-16-le", "utf-8-sig", "latin-1"))
        text = text.decode("latin-1").replace("arrival_ms", "arrivée_ms").encode(encoding, errors="replace")
    return text


class FilesTarget:
    """config, site, points, profile and ground-truth files: any bytes in the file give a result or
    the project's Error (a one-line message), nothing else."""

    def __init__(self, name: str, sample: bytes, load: Callable[[Path], Any], ok: tuple[type, ...] = (),
                 make: Callable[[random.Random, str, bytes], bytes] = toml_input) -> None:
        self.name, self.sample, self.load, self.ok, self.make = name, sample, load, ok, make
        # The reader opens a real file each time; on tmpfs that costs 0.03 ms, not the 0.5-3 ms
        # of the disk's file system (most of what an input cost).
        shm = "/dev/shm" if os.access("/dev/shm", os.W_OK) else None
        self.path = Path(tempfile.mkdtemp(dir=shm)) / f"fuzz-{name}.toml"

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        data = self.make(rng, kind, self.sample)
        self.path.write_bytes(data)
        c.add("streams")
        try:
            self.load(self.path)
            c.add("read_whole")
        except Error:
            c.add("errors")
        except Exception as exc:  # noqa: BLE001
            c.add("escaped_exceptions")
            c.add(f"escaped.{type(exc).__name__}")
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {str(exc)[:100]} on {data[:60]!r}")


def _points(path: Path) -> Any:
    from rfhoming.host.points_file import load_points

    return load_points(path)


def _config(path: Path) -> Any:
    from rfhoming.host.homing import config

    return config.load(path)


def _site(path: Path) -> Any:
    from rfhoming.host import site

    return site.load(path)


def _profile(path: Path) -> Any:
    from rfhoming.protocol import radio_profile

    return radio_profile.load(path)


@functools.cache
def _site_area() -> tuple[float, float, float, float]:
    from rfhoming.host import groundtruth, site

    return groundtruth.area_of(a.position for a in site.parse(tomllib.loads(SITE.decode())).anchors)


def _truth(path: Path) -> Any:
    from rfhoming.host import groundtruth

    return groundtruth.load_waypoints(path, _site_area())


def _capture(path: Path) -> Any:
    return pcapng.read_all(path.read_bytes())


# -- the site bus: any MQTT message a worker receives costs at most itself ------------------------
def _hostile_values() -> tuple[str, ...]:
    """JSON values that are valid text but hostile to a reader: deep, huge, odd or of the wrong
    type (built once: the deep and long ones cost more to build than to refuse)."""
    out = ["1e999", "-1e999", "1e-999", "NaN", "Infinity", "-Infinity", "0", "-1", "0.5", "9223372036854775808",
           "1e23", "true", "false", "null", '""', '"x"', '"a/#"', '"+"', '"t/1"', '"\\u0000"', '"\\ud800"', "[]",
           "{}", "[1]", '["a"]', "[[0],[0],[0]]", "[[1],[0]]", '{"v":2}']
    for depth in (10, 900, 1000, 5000, 100_000):
        out += ["[" * depth + "]" * depth, '{"a":' * depth + "1" + "}" * depth, "[" * depth]
    for digits in (20, 400, 4300, 4301, 20_000):
        out += ["9" * digits, "-" + "9" * digits, "1" + "0" * digits + ".5", "0." + "1" * digits]
    return tuple(out + ['"' + "x" * n + '"' for n in (256, 257, 100_000)])


HOSTILE = _hostile_values()


def _json_value(rng: random.Random) -> str:
    return rng.choice(HOSTILE)


def _batch_fields(rng: random.Random, anchors: list[str]) -> dict[str, str]:
    """A valid batch (version 1 or 2) as its top-level fields' JSON texts, so any can be replaced."""
    tags = [f"T{k}" for k in range(rng.randint(1, 4))]
    rows = [(1e9 + rng.uniform(0, 2), rng.choice(anchors), rng.choice(tags), rng.randint(-90, 90),
             rng.randint(-90, 90)) for _ in range(rng.randint(0, 12))]
    body = json.loads(sitebus.encode_angles("gw", rng.randrange(1000), 1e9 + 2, 0.0, rows))
    if rng.random() < 0.25:
        body = {k: body[k] for k in ("v", "gw", "seq", "sent", "offset_s")} | {"v": 1, "events": [list(r) for r in rows]}
    return {k: json.dumps(v) for k, v in body.items()}


def _replace_inside(rng: random.Random, text: str) -> str:
    """One element of a column (or a value in a list) replaced by a hostile value."""
    starts = [i for i, ch in enumerate(text) if ch in "[,"]
    if not starts:
        return _json_value(rng)
    i = rng.choice(starts) + 1
    j = i
    while j < len(text) and text[j] not in ",]":
        j += 1
    return text[:i] + _json_value(rng) + text[j:]


def sitebus_input(rng: random.Random, kind: str, anchors: list[str]) -> bytes:
    if kind == "random":
        return rng.randbytes(rng.randint(0, 2000))
    fields = _batch_fields(rng, anchors)
    if kind == "mutated":
        text = "{" + ",".join(f'"{k}":{v}' for k, v in fields.items()) + "}"
        return mutate(rng, text.encode(), rng.randint(1, 8))[0]
    roll = rng.random()
    if roll < 0.15:  # hostile alone
        return _json_value(rng).encode()
    for _ in range(rng.randint(1, 3)):  # fields retyped, added, or one element of them replaced
        key = rng.choice([*fields, "v", "x"])
        if key in fields and rng.random() < 0.5:
            fields[key] = _replace_inside(rng, fields[key])
        else:
            fields[key] = _json_value(rng)
    return ("{" + ",".join(f'"{k}":{v}' for k, v in fields.items()) + "}").encode()


class SitebusTarget:
    """Every message through the decoder; each one it passes (and every 64th it refuses) through a
    site worker between two good batches, the worker ticked every 256 of those: what escapes the
    decoder, the drain or the tick is counted, and so are good events not fed. (A refused message
    costs the drain one counter, by construction; the decoder is what has to hold.)"""

    name = "sitebus"

    def __init__(self) -> None:
        self.worker: Any = None

    def _make(self) -> Any:
        from rfhoming.emulator.site import SiteScenario
        from rfhoming.host.site import Anchor, Site
        from rfhoming.host.sitebus import Broker, Worker

        sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
        site = Site("fuzz", tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg, angle_model="spherical")
                                  for a in sc.anchors), sigma_deg=sc.sigma_deg, az_compression=0.0)
        self.now = 1e9
        # no broker is ever reached (port 1): positions wait in the publisher's bounded buffer
        worker = Worker(site, Broker("127.0.0.1", 1, False, None), worker_id="fuzz", partitions=1,
                        clock=lambda: self.now)
        self.anchors = [a.id for a in sc.anchors]
        return worker

    def _good(self, seq: int) -> bytes:
        rows = [(self.now - 0.05 + 0.01 * k, a, f"G{k % 2}", 10, -20) for k, a in enumerate(self.anchors)]
        return sitebus.encode_angles("good", seq, self.now, 0.0, rows)

    def one(self, rng: random.Random, kind: str, c: Counts, examples: list[str]) -> None:
        if self.worker is None:
            self.worker = self._make()
            self.streams = 0
        w = self.worker
        data = sitebus_input(rng, kind, self.anchors)
        c.add("streams")
        c.add("bytes", len(data))
        try:
            sitebus.decode_angles(data)
            c.add("decoded")
        except sitebus.PayloadError:
            c.add("refused")
            if rng.randrange(64):
                return
        except Exception as exc:  # noqa: BLE001 -- counting what escapes is the point
            c.add("escaped_exceptions")
            c.add(f"escaped.{type(exc).__name__}")
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {str(exc)[:100]} on {data[:60]!r}")
            return
        c.add("through_the_worker")
        self.now += 0.01
        self.streams += 1
        topic = "rfhoming/fuzz/angles/0"
        before = dict(w.counters)
        w._inbox.extend([(self.now, topic, self._good(2 * self.streams)), (self.now, topic, data),
                         (self.now, topic, self._good(2 * self.streams + 1))])
        try:
            w._drain()
            if self.streams % 256 == 0:
                w._tick(self.now)
        except Exception as exc:  # noqa: BLE001 -- counting what escapes is the point
            c.add("escaped_exceptions")
            c.add(f"escaped.{type(exc).__name__}")
            w._inbox.clear()
            if len(examples) < 5:
                examples.append(f"{type(exc).__name__}: {str(exc)[:100]} on {data[:60]!r}")
            return
        fed = w.counters["events"] - before["events"]
        if fed < 2 * len(self.anchors):
            c.add("good_events_lost", 2 * len(self.anchors) - fed)
            if len(examples) < 5:
                examples.append(f"good events lost beside {data[:60]!r}")


TARGETS: dict[str, Any] = {
    "frames": FramesTarget(), "uconnect": UConnectTarget(), "pcapng": PcapngTarget(), "espat": EspAtTarget(),
    "h4": H4Target(), "ad": AdTarget(), "hci": HciDriverTarget(), "cref": CrefTarget(),
    "config": FilesTarget("config", CONFIG, _config), "site": FilesTarget("site", SITE, _site),
    "points": FilesTarget("points", POINTS, _points), "sitebus": SitebusTarget(),
    "profile": FilesTarget("profile", PROFILE, _profile), "truth": FilesTarget("truth", TRUTH, _truth, make=truth_input),
}


KEYS = {"frames": ("chunked_vs_whole_differences", "c_vs_python_differences", "intact_units", "intact_units_lost",
                   "corrupt_accepted"),
        "uconnect": ("chunked_vs_whole_differences", "c_vs_python_differences", "intact_units", "intact_units_lost",
                     "corrupt_accepted"),
        "pcapng": ("chunked_vs_whole_differences",), "espat": ("chunked_vs_whole_differences", "intact_units_lost"),
        "h4": ("chunked_vs_whole_differences", "intact_units_lost", "intact_units_misframed"), "hci": ("chunked_vs_whole_differences",),
        "cref": ("c_vs_python_differences",), "sitebus": ("good_events_lost",)}
"""The counts every report shows, zero or not."""


def run(target: str, n: int, seconds: float, seed: int, progress: bool) -> dict[str, Any]:
    rng = random.Random(f"{seed}-{target}")
    counts, examples = Counts(), []
    for key in ("escaped_exceptions",) + KEYS.get(target, ()):
        counts[key] = 0
    t0 = time.monotonic()
    slowest = 0.0
    for k in range(n):
        s0 = time.monotonic()
        TARGETS[target].one(rng, KINDS[k % 3], counts, examples)
        slowest = max(slowest, time.monotonic() - s0)
        if time.monotonic() - t0 > seconds:
            break
        if progress and k and k % 100_000 == 0:
            print(f"  {target}: {k:,} streams, {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
    flush = getattr(TARGETS[target], "flush", None)
    if flush is not None:
        flush(counts, examples)
    out = {"target": target, "requested": n, **dict(sorted(counts.items())),
           "seconds": round(time.monotonic() - t0, 1), "slowest_stream_ms": round(slowest * 1000, 2),
           "examples": examples}
    if target == "frames":
        out["corrupt_expected_at_most"] = round(counts.get("touched_units", 0) / 65536, 2)
    return out


def run_hypothesis(profile: str) -> int:
    """The property tests under the registered ``profile`` (tests/conftest.py)."""
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "RFHOMING_HYPOTHESIS_PROFILE": profile}
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *HYPOTHESIS_FILES],
                          cwd=root, env=env).returncode


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--target", choices=[*TARGETS, "all"], default="all")
    p.add_argument("--n", type=int, default=20_000, help="streams per target (default 20,000)")
    p.add_argument("--seconds", type=float, default=600.0, help="stop a target after this long (default 600)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="one JSON object per target")
    p.add_argument("--hypothesis", nargs="?", const="fuzz", metavar="PROFILE",
                   help="instead: run the property tests under a hypothesis profile (default: fuzz)")
    args = p.parse_args(argv)
    if args.hypothesis:
        return run_hypothesis(args.hypothesis)
    logging.disable(logging.ERROR)  # bumble logs every packet it cannot parse; the counts say it
    bad = 0
    print(f"# {accel.describe()}", file=sys.stderr)
    for target in (TARGETS if args.target == "all" else [args.target]):
        result = run(target, args.n, args.seconds, args.seed, progress=not args.json)
        bad += result.get("escaped_exceptions", 0) + result.get("c_vs_python_differences", 0) \
            + result.get("chunked_vs_whole_differences", 0) + result.get("intact_units_lost", 0) \
            + result.get("good_events_lost", 0)
        if args.json:
            print(json.dumps(result), flush=True)
        else:
            print(f"{target}:")
            for key, value in result.items():
                if key not in ("target", "examples"):
                    print(f"  {key:<30} {value:,}" if isinstance(value, int) else f"  {key:<30} {value}")
            for example in result["examples"]:
                print(f"  example: {example}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
