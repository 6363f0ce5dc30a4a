"""Self-calibration's cost on a long walk: ``--walks`` recordings of ``--walk-s`` seconds each of
the emulated wall room (anchors 2.3 m up, every tag at 1.1 m, the hard boards: campaigns.kit) --
one long walk cut into pieces, the same boards throughout -- each its own --from source as `rfhoming calibrate SITE --self` takes them, then
self_calibrate as that command runs it (held-out folds, every candidate angle model, the
final fit). Reports epochs, CPU and wall seconds, and the held-out verdict.

    python bench/selfcal_bench.py [--walks 8] [--walk-s 110] [--seed 1] [--json]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import replace

from rfhoming.campaigns.kit import HARD_BOARDS, WALL_ROOM, record
from rfhoming.host import site as sites
from rfhoming.host.self_calibration import self_calibrate

SITE = "docs/sites/kit-room.toml"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--walks", type=int, default=8, help="recordings (default 8)")
    ap.add_argument("--walk-s", type=float, default=110.0, help="seconds each (default 110)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    base = sites.load(SITE)
    site = replace(base, anchors=tuple(replace(a, position=(*a.position[:2], WALL_ROOM["anchor_height_m"]))
                                       for a in base.anchors), tags=tuple(replace(t, height=None) for t in base.tags))
    print(f"recording {args.walks} walks of {args.walk_s:g} s", file=sys.stderr)
    events = record(args.seed, args.walks * args.walk_s, boards=HARD_BOARDS, room=WALL_ROOM).events
    walks = [[e for e in events if k * args.walk_s <= e.t < (k + 1) * args.walk_s] for k in range(args.walks)]
    cpu, wall = time.process_time(), time.perf_counter()
    result = self_calibrate(site, walks, height=WALL_ROOM["tag_height_m"],
                            progress=lambda text: print(text, end="", file=sys.stderr, flush=True))
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    out = {"epochs": result.epochs, "anchors": len(result.fits), "cpu_s": round(cpu, 2), "wall_s": round(wall, 2),
           "written": result.write, "verdict": result.verdict, "walks": args.walks, "walk_s": args.walk_s,
           "python": platform.python_version(), "machine": platform.machine()}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{result.epochs} epochs x {len(result.fits)} anchors: {cpu:.1f} s CPU, {wall:.1f} s wall; "
              f"{result.verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
