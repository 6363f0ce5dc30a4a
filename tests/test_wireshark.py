"""The generated Wireshark dissector shows what FrameDecoder decodes, field by field."""

from __future__ import annotations

import os
import random
import shutil
import subprocess
from pathlib import Path

import construct as cs
import pytest

from rfhoming.protocol import pcapng
from rfhoming.protocol.frames import RECORD_TYPES, FrameDecoder, encode_frame
from rfhoming.protocol.frames.records import AntennaReading
from rfhoming.protocol.frames.wireshark import lua_dissector
from strategies import chunked


def body_fields(rt) -> list[str]:
    """(dotted) abbreviations of a type's body fields, as the dissector names them."""
    names = []
    for sc in rt.body.subcons:
        if isinstance(sc.subcon, cs.Array) and isinstance(sc.subcon.count, int):  # a group
            names += [f"{rt.kind}.{sc.name}.{m.name}" for m in sc.subcon.subcon.subcons]
        else:
            names.append(f"{rt.kind}.{sc.name}")
    return names


def test_every_declared_field_is_in_the_dissector() -> None:
    lua = lua_dissector()
    for code, rt in RECORD_TYPES.items():
        assert f'[0x{code:02X}] = {{kind = "{rt.kind}"' in lua
        for abbr in body_fields(rt):
            assert f'"{abbr.rsplit(".", 1)[1]}"' in lua


def sample(rng: random.Random) -> list:
    """One record of every type, then random ones, with sizes from empty tails to large."""
    def ints(n: int, lo: int, hi: int) -> list[int]:
        return [rng.randint(lo, hi) for _ in range(n)]

    make = {
        "adv_report": lambda s: (bytes(ints(6, 0, 255)), 0, 3, -60, 127, 37, bytes(ints(rng.randint(0, 31), 0, 255))),
        "rf_frame": lambda s: (1, 5, 0, 2, -99, 40, 255, 0x80, s, bytes(ints(rng.randint(0, 20), 0, 255))),
        "antenna_set": lambda s: (s, 5, 0, -99, 15, tuple(AntennaReading(*ints(2, 0, 84), rng.randint(-999, 999)) for _ in range(4))),
        "status": lambda s: (2, 1, 0, 3, s * 1000, 0, 1),
        "odometry": lambda s: (*ints(2, -9999, 9999), rng.randint(-3141592, 3141592), 300, -100, 4),
        "velocity_command": lambda s: (250, -500, 300),
        "range_scan": lambda s: (-1571, 17, tuple(ints(rng.randint(0, 181), 0, 8000))),
        "range_scan_v2": lambda s: (-1570796, 1570796, 8000, tuple(ints(rng.randint(0, 181), 0, 8000))),
        "log_text": lambda s: (f"step {s} ok",),
        "node_command": lambda s: (1, bytes([5, 0])),
    }
    types = list(RECORD_TYPES.values())
    chosen = types + [rng.choice(types) for _ in range(40)]
    return [rt.cls(rng.randint(0, 255), s, s * 20_000, *make[rt.kind](s)) for s, rt in enumerate(chosen)]


def capture(tmp_path: Path) -> tuple[Path, list[tuple[int, bytes]]]:
    """A base link with records both ways, damage mixed in, cut at random and interleaved."""
    rng = random.Random(7)
    recs = sample(rng)
    inbound = b"".join(encode_frame(r) for r in recs[::2])
    inbound = inbound[:100] + b"\x01\x02garbage" + inbound[100:] + b"\x05ab\0" + b"\x01" * 1100 + b"\0"
    damaged = bytearray(encode_frame(recs[3]))
    damaged[5] ^= 0x10
    outbound = b"".join(encode_frame(r) for r in recs[1::2]) + bytes(damaged) + encode_frame(recs[5])
    streams = {pcapng.INBOUND: chunked(inbound, [64, 7, 200, 1]), pcapng.OUTBOUND: chunked(outbound, [33, 90])}
    packets = []
    while any(streams.values()):
        direction = rng.choice([d for d, s in streams.items() if s])
        packets.append((direction, streams[direction].pop(0)))
    blob = pcapng.section_header() + pcapng.interface("/dev/ttyUSB0", "rss", pcapng.LINKTYPE_FRAMES)
    blob += b"".join(pcapng.packet(0, i * 1e-3, data, d) for i, (d, data) in enumerate(packets))
    path = tmp_path / "base.pcapng"
    path.write_bytes(blob)
    return path, packets


def expected_rows(packets: list[tuple[int, bytes]], abbrevs: list[str]) -> list[dict[str, list[str]]]:
    """Per packet, the values each field should show: FrameDecoder per direction."""
    decoders = {pcapng.INBOUND: FrameDecoder(), pcapng.OUTBOUND: FrameDecoder()}
    rows = []
    for direction, data in packets:
        row: dict[str, list[str]] = {a: [] for a in abbrevs}
        for item in decoders[direction].feed(data):
            if item.kind == "drop":
                row["rfhoming.drop"].append(item.reason)
                continue
            row["rfhoming.kind"].append(item.kind)
            row["rfhoming.seq"].append(str(item.seq))
            subcons = RECORD_TYPES[item.type_code].body.subcons
            for sc, after in zip(subcons, [*subcons[1:], None]):
                field = f"rfhoming.{item.kind}.{sc.name}"
                if isinstance(sc.subcon, cs.Rebuild):  # a tail's length: shown, not a record field
                    row[field].append(str(len(getattr(item, after.name))))
                    continue
                value = getattr(item, sc.name)
                if isinstance(value, tuple) and value and isinstance(value[0], AntennaReading):
                    for reading in value:
                        for member, v in reading._asdict().items():
                            row[f"{field}.{member}"].append(str(v))
                elif isinstance(value, tuple):
                    row[field] += [str(v) for v in value]
                elif isinstance(value, bytes):
                    row[field] += [value.hex()] if value else []
                else:
                    row[field].append(str(value))
        rows.append(row)
    return rows


@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark is not installed (apt-get install tshark)")
def test_tshark_with_the_dissector_shows_what_the_decoder_decodes(tmp_path: Path) -> None:
    path, packets = capture(tmp_path)
    lua = tmp_path / "rfhoming.lua"
    lua.write_text(lua_dissector())
    abbrevs = ["rfhoming.kind", "rfhoming.seq", "rfhoming.drop"]
    abbrevs += [f"rfhoming.{a}" for rt in RECORD_TYPES.values() for a in body_fields(rt)]
    fields = [arg for a in abbrevs for arg in ("-e", a)]
    done = subprocess.run(
        ["tshark", "-X", f"lua_script:{lua}", "-r", str(path), "-T", "fields", *fields,
         "-E", "occurrence=a", "-E", "aggregator=|", "-E", "separator=/t"],
        capture_output=True, text=True, env={**os.environ, "HOME": str(tmp_path)}, timeout=120,
    )
    assert done.returncode == 0 and "Lua" not in done.stderr, done.stderr
    shown = [
        {a: (v.split("|") if v else []) for a, v in zip(abbrevs, line.split("\t"))}
        for line in done.stdout.splitlines()
    ]
    expected = expected_rows(packets, abbrevs)
    assert len(shown) == len(expected)
    for number, (got, want) in enumerate(zip(shown, expected), 1):
        assert got == want, f"packet {number}"
    drops = [r for row in expected for r in row["rfhoming.drop"]]
    assert {"cobs", "crc", "oversize"} <= set(drops)
    assert sum(len(row["rfhoming.kind"]) for row in expected) >= 40
