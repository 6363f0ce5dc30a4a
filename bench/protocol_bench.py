"""Decoder throughput: +UUDF lines and every binary record type, from raw 64-byte chunks.

In the same run, two references on comparable input: pynmeagps's NMEAReader on NMEA
sentences of similar length, and the construct declaration of the same records parsed
interpreted (COBS decode + construct parse with its CRC check).

    python bench/protocol_bench.py            # table
    python bench/protocol_bench.py --json     # one JSON object
    python bench/protocol_bench.py --mb 2     # quicker, smaller streams
    python bench/protocol_bench.py --pure     # the pure-Python decoders, C accelerator built or not
    python bench/protocol_bench.py --parts    # also time the pieces BENCHMARKS.md explains with

Needs the bench extra: pip install -e '.[bench]'
"""

from __future__ import annotations

import argparse
import io
import json
import platform
import random
import sys
import time
import timeit
from collections.abc import Callable
from typing import Any

from cobs import cobs

from rfhoming.protocol import accel
from rfhoming.protocol.frames import (
    AdvReport,
    AntennaReading,
    AntennaSet,
    FrameDecoder,
    LogText,
    NodeCommand,
    Odometry,
    RangeScan,
    RfFrame,
    Status,
    VelocityCommand,
    encode_frame,
    encode_inner,
    parse_inner,
)
from rfhoming.protocol.uconnect import AngleEvent, Dialect, UConnectDecoder, encode_angle_event

CHUNK = 64


def chunks(stream: bytes) -> list[bytes]:
    return [stream[i : i + CHUNK] for i in range(0, len(stream), CHUNK)]


def interleaved(runs: int, ours: Callable[[], Any], reference: Callable[[], Any]) -> tuple[float, float]:
    """Fastest of ``runs`` wall-clock timings of each, alternating them round by round.

    The machine's speed drifts; alternating and keeping the minimum of each compares the
    two under the same conditions.
    """
    best = [float("inf"), float("inf")]
    for _ in range(runs):
        for i, fn in enumerate((ours, reference)):
            t0 = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t0)
    return best[0], best[1]


def uudf_stream(target_bytes: int, rng: random.Random) -> tuple[bytes, int]:
    lines = []
    for i in range(4096):
        event = AngleEvent(
            f"CCF9578E{i % 65536:04X}", rng.randint(-80, -30), rng.randint(-90, 90),
            rng.randint(-90, 90), rng.randint(-80, -30), rng.choice((37, 38, 39)),
            "CCF9578E0D89", "", rng.randint(0, 2**31 - 1),
        )
        lines.append(encode_angle_event(event, Dialect.V1_0))
    block = b"".join(lines)
    reps = -(-target_bytes // len(block))
    return block * reps, len(lines) * reps


def nmea_stream(target_bytes: int) -> tuple[bytes, int]:
    body = b"GNGGA,103228.00,5327.04319,S,00214.41396,E,1,12,0.99,52.4,M,47.9,M,,"
    checksum = 0
    for c in body:
        checksum ^= c
    line = b"$" + body + b"*%02X\r\n" % checksum
    reps = target_bytes // len(line)
    return line * reps, reps


def bench_uudf(mb: float, runs: int, nmea_mb: float, pure: bool) -> dict[str, Any]:
    from pynmeagps import NMEAReader

    stream, n = uudf_stream(int(mb * 1e6), random.Random(1))
    pieces = chunks(stream)

    def ours() -> None:
        d = UConnectDecoder(pure=pure)
        for p in pieces:
            d.feed(p)
        assert d.counters["angle"] == n, d.counters

    nmea, n_nmea = nmea_stream(int(nmea_mb * 1e6))

    def reference() -> None:
        count = sum(1 for _ in NMEAReader(io.BytesIO(nmea)))
        assert count == n_nmea

    t, t_ref = interleaved(runs, ours, reference)
    us, us_ref = t / n * 1e6, t_ref / n_nmea * 1e6
    return {
        "stream_mb": len(stream) / 1e6,
        "line_bytes": len(stream) / n,
        "lines": n,
        "us_per_line": us,
        "lines_per_s": n / t,
        "mb_per_s": len(stream) / t / 1e6,
        "pynmeagps_line_bytes": len(nmea) / n_nmea,
        "pynmeagps_lines": n_nmea,
        "pynmeagps_us_per_line": us_ref,
        "speedup_vs_pynmeagps": us_ref / us,
    }


def sample_records(rng: random.Random) -> dict[str, Callable[[int], Any]]:
    """One generator per record type: varied, valid, typical sizes."""
    def r8() -> int:
        return rng.randint(0, 255)

    return {
        "adv_report": lambda s: AdvReport(1, s & 0xFFFF, s, rng.randbytes(6), 0, 0x13, rng.randint(-100, -30), 127, 255, rng.randbytes(20)),
        "rf_frame": lambda s: RfFrame(2, s & 0xFFFF, s, s & 3, 5, 0, 0x24, -99, rng.randint(0, 84), r8(), 0x80, s & 0xFFFF, rng.randbytes(8)),
        "antenna_set": lambda s: AntennaSet(2, s & 0xFFFF, s, s & 0xFFFF, 5, 0, -99, 15, tuple(AntennaReading(rng.randint(0, 84), r8(), i) for i in range(4))),
        "status": lambda s: Status(2, s & 0xFFFF, s, 2, 1, 0, 3, s, 0, 0),
        "odometry": lambda s: Odometry(7, s & 0xFFFF, s, rng.randint(-9999, 9999), rng.randint(-9999, 9999), rng.randint(-3141592, 3141592), 300, -100, 4),
        "velocity_command": lambda s: VelocityCommand(0, s & 0xFFFF, s, 250, -500, 300),
        "range_scan": lambda s: RangeScan(7, s & 0xFFFF, s, -1571, 17, tuple(rng.randint(0, 8000) for _ in range(181))),
        "log_text": lambda s: LogText(2, s & 0xFFFF, s, f"ed calibration step {s} ok"),
        "node_command": lambda s: NodeCommand(0, s & 0xFFFF, s, 1, b"\x05\x00"),
    }


def bench_records(mb: float, runs: int, reference_records: int, pure: bool) -> dict[str, Any]:
    rng = random.Random(2)
    results: dict[str, Any] = {}
    for kind, make in sample_records(rng).items():
        block = [encode_frame(make(s)) for s in range(2000)]
        blob = b"".join(block)
        reps = -(-int(mb * 1e6) // len(blob))
        stream = blob * reps
        n = len(block) * reps
        pieces = chunks(stream)

        def ours() -> None:
            d = FrameDecoder(pure=pure)
            for p in pieces:
                d.feed(p)
            assert d.counters[kind] == n, d.counters

        def reference() -> None:
            for f in block[:reference_records]:
                parse_inner(cobs.decode(f[1:-1]))

        assert parse_inner(cobs.decode(block[0][1:-1])) == FrameDecoder().feed(block[0])[0]
        t, t_ref = interleaved(runs, ours, reference)
        us, us_ref = t / n * 1e6, t_ref / min(reference_records, len(block)) * 1e6
        results[kind] = {
            "stream_mb": len(stream) / 1e6,
            "frame_bytes": len(stream) / n,
            "records": n,
            "us_per_record": us,
            "records_per_s": n / t,
            "mb_per_s": len(stream) / t / 1e6,
            "construct_us_per_record": us_ref,
            "speedup_vs_construct": us_ref / us,
        }
    return results


def bench_parts(rng: random.Random) -> dict[str, float]:
    """µs per call of the pieces the record figures are made of (best of 5 timeit runs)."""
    from rfhoming.protocol.frames.codec import VALIDATORS
    from rfhoming.protocol.frames.fast import DECODERS
    from rfhoming.protocol.frames.records import crc16

    def us(fn: Callable[[], Any], number: int = 100_000) -> float:
        return min(timeit.repeat(fn, number=number, repeat=5)) / number * 1e6

    makers = sample_records(rng)
    scan = makers["range_scan"](1)
    inner = encode_inner(scan)
    antennas = makers["antenna_set"](1)
    held = FrameDecoder()
    parts = {
        "crc16_binascii_379_bytes": us(lambda: crc16(inner[:-2])),
        "range_scan_body_decode": us(lambda: DECODERS[0x22](inner, len(inner) - 2, 7, 1, 1)),
        "antenna_set_ed_check": us(lambda: VALIDATORS[0x03](antennas)),
        "feed_64_bytes_no_frame_end": us(lambda: (setattr(held, "_rest", b"\x02" * 100), held.feed(b"\x01" * 64))),
    }
    if accel.ACCEL is not None:
        parts["crc16_accel_379_bytes"] = us(lambda: accel.ACCEL.crc16(inner[:-2]))
    return parts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--mb", type=float, default=10.0, help="stream size per case, MB (default 10)")
    parser.add_argument("--runs", type=int, default=5, help="alternating rounds per case, best kept (default 5)")
    parser.add_argument("--parts", action="store_true", help="also time the pieces (CRC, range_scan body, ED check, a chunk with no frame end)")
    parser.add_argument("--pure", action="store_true", help="measure the pure-Python decoders even where the C accelerator is built")
    args = parser.parse_args()
    try:
        import pynmeagps  # noqa: F401
    except ImportError:
        print("protocol_bench needs pynmeagps: pip install -e '.[bench]'", file=sys.stderr)
        return 2
    if not args.json:
        print(f"decoding {args.mb:g} MB per case in {CHUNK}-byte chunks, best of {args.runs} ...", file=sys.stderr)
    implementation = "pure Python (--pure)" if args.pure else accel.describe()
    result = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "chunk_bytes": CHUNK,
        "implementation": implementation,
        "uudf": bench_uudf(args.mb, args.runs, nmea_mb=min(args.mb, 1.0), pure=args.pure),
        "records": bench_records(args.mb, args.runs, reference_records=2000, pure=args.pure),
    }
    if args.parts:
        result["parts_us"] = bench_parts(random.Random(3))
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    u = result["uudf"]
    print(f"decoders: {implementation}")
    print(f"+UUDF  {u['us_per_line']:.2f} us/line  {u['lines_per_s']:,.0f} lines/s  {u['mb_per_s']:.1f} MB/s  "
          f"(pynmeagps {u['pynmeagps_us_per_line']:.1f} us/line: {u['speedup_vs_pynmeagps']:.1f}x)")
    print(f"{'record':<17}{'bytes':>6}{'us/rec':>8}{'rec/s':>11}{'MB/s':>7}{'construct us':>14}{'speedup':>9}")
    for kind, r in result["records"].items():
        print(f"{kind:<17}{r['frame_bytes']:>6.0f}{r['us_per_record']:>8.2f}{r['records_per_s']:>11,.0f}"
              f"{r['mb_per_s']:>7.1f}{r['construct_us_per_record']:>14.1f}{r['speedup_vs_construct']:>8.1f}x")
    for part, us in result.get("parts_us", {}).items():
        print(f"part {part:<30}{us:>8.2f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
