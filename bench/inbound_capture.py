"""A long recording of fixed anchors with no set-up exchange, through `rfhoming locate`.

    python bench/inbound_capture.py [--seconds 100] [--tags 1] [--speed 0 --speed 10] [--json]

Writes what a third-party logger gives: four XPLR-AOA anchors of docs/sites/kit-room.toml,
inbound bytes only, each tag heard by each anchor at 20 Hz (the C209 tag's 50 ms advertising
interval, docs/protocol.md), one line per chunk. Then runs `rfhoming locate --from
capture:FILE,speed=S` for each --speed and prints, per speed, the positions, the events the
locator took, and every anchor's `queue_dropped`: at any speed every event should be used.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from rfhoming.host import site as sites
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.estimation.anchors3d import board_angles

SITE = Path(__file__).resolve().parents[1] / "docs" / "sites" / "kit-room.toml"
RATE_HZ = 20.0
TAGS = ["CCF9578E0D8A", "CCF9578E0D8B", "CCF9578E0D8C"]


def write(path: Path, seconds: float, tags: int) -> int:
    """The capture; returns its number of angle events."""
    site = sites.load(SITE)
    rng = np.random.default_rng(1)
    rows = []
    for k in range(int(seconds * RATE_HZ)):
        for i, tag in enumerate(TAGS[:tags]):
            for j, a in enumerate(site.anchors):
                t = k / RATE_HZ + i * 0.013 + j * 0.003
                where = np.array([6 + 4 * math.cos(t / 10 + i), 3 + 2 * math.sin(t / 10 + i), 1.0])
                az, el = board_angles(a.rotation().T @ (where - np.array(a.position)))
                line = f'+UUDF:{tag},-42,{round(az + rng.normal(0, 1))},{round(el)},-43,37,"{a.id}","",{int(t * 1000)}\r\n'
                rows.append((1000.0 + t, a.name, line.encode()))
    writer = CaptureWriter(path)
    for a in site.anchors:
        writer.describe(a.name, kind="xplr-aoa")
    for t, port, data in sorted(rows):
        writer.tap(port, "in", t, data)
    writer.close()
    return len(rows)


def locate(path: Path, speed: float) -> dict:
    cli = subprocess.run([sys.executable, "-m", "rfhoming", "locate", str(SITE), "--from", f"capture:{path},speed={speed:g}"],
                         capture_output=True, text=True, timeout=3600)
    if cli.returncode:
        raise SystemExit(cli.stderr)
    summary = json.loads(cli.stdout.splitlines()[-1])
    counters = [json.loads(line) for line in cli.stderr.splitlines() if line.startswith('{"kind": "counters"')]
    return {"speed": speed, "positions": len(cli.stdout.splitlines()) - 1, "events": summary["events"],
            "queue_dropped": {c["device"]: c["queue_dropped"] for c in counters}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=100.0)
    p.add_argument("--tags", type=int, choices=(1, 2, 3), default=1)
    p.add_argument("--speed", type=float, action="append", help="replay speeds (default 0 and 10)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "inbound.pcapng"
        events = write(path, args.seconds, args.tags)
        runs = [locate(path, s) for s in args.speed or [0.0, 10.0]]
    result = {"seconds": args.seconds, "tags": args.tags, "recorded_events": events, "runs": runs}
    if args.json:
        print(json.dumps(result))
        return
    print(f"{args.seconds:g} s, {args.tags} tag(s), {events} angle events recorded")
    for r in runs:
        print(f"  speed={r['speed']:g}: {r['positions']} positions, {r['events']} events used, "
              f"queue_dropped {r['queue_dropped']}")


if __name__ == "__main__":
    main()
