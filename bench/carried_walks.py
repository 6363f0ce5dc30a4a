"""Emulated carried walks: the withheld kind of the 2026-12 field report (long walks, a person carrying the tag
and standing at four long stops), made in the emulator, and how close their statistics come to
the issue's.

Each walk is about 280 s through the room of DIR's ``site.toml`` (the XPLR-AOA data set's office
room): waypoints on its 1.2 m grid, walked at a person's pace, four of them long stops that fill
87 % of the walk (the 2026-12 field report: "the four long stops of each walk (87 % of the scored ticks)"), the
others brief pauses. The long stops are drawn from STOP_PLACES, so walks come back to the same
places (the issue compares stops at the same place across walks). The emulator plays the site's
anchors under a radio profile (``carried`` by default: protocol/profiles/carried.toml) and its
bytes become a capture laid out like the real ones, with a waypoint file beside it
(``arrival_ms,leave_ms,x_cm,y_cm``), so ``rfhoming locate`` and bench/real_aoa.py read them as
they read the recordings.

Printed: the angle statistics of the emulated walks (host/angle_residuals.py, spherical reading)
beside the 2026-12 field report's figures for the withheld walks, the stops' own figures (RMS of each stop's mean
azimuth error; how far two walks' means at the same place and anchor differ), and ``rfhoming
locate``'s mean error with its defaults (the data set's scoring rule; while moving and standing).

    python bench/carried_walks.py --data DIR [--walks 6] [--radio carried] [--keep FOLDER] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import json
import math
import os
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from fidelity import _emulate, scenario_toml
from real_aoa import locate

import rfhoming
from rfhoming.host import site as sites
from rfhoming.host.angle_residuals import angle_stats, residuals
from rfhoming.host.groundtruth import WalkedPath, Waypoint, load_waypoints, score

ISSUE_50 = {"az_std": 15.4, "az_tail": 0.21, "el_std": 21.8, "corr_time_s": 25.0, "compression_60_90": -19.0,
            "stop_mean_az_rms": 14.0, "stop_walk_to_walk_az": 7.4}
"""the 2026-12 field report's figures for the withheld walks (spherical reading; uc1 + uc2: 9.5, 4.9 %, 11.6, ~1 s)."""

WALK_S = 280.0
"""A walk's length (the 2026-12 field report: "Long walks (about 280 s each)")."""
LONG_STOPS = 4
STOPPED_SHARE = 0.87
"""Four long stops, 87 % of the scored time (the 2026-12 field report)."""
WAYPOINTS = 12
"""Waypoints per walk: "stops at many waypoints" (the data set's other walks have 10-16)."""
PACE_M_S = (0.5, 0.8)
"""A person's walking speed, uniform (*assumed*: the data set's uc1 walks at 0.4-0.5 m/s)."""
GRID_M = 1.2
"""The data set's waypoint grid (its README: "a 1.2 m grid")."""
STOPS = (((2.4, 1.2), (2.4, 2.4)), ((6.0, 2.4), (4.8, 2.4)), ((9.6, 1.2), (8.4, 1.2)), ((9.6, 4.8), (9.6, 3.6)),
         ((3.6, 4.8), (4.8, 4.8)), ((7.2, 3.6), (7.2, 2.4)))
"""Where long stops are made (each walk takes four), each reached from the same waypoint before it:
walks meet at the same places, facing the same way (as a walk repeated on one route would)."""
RATE_HZ = 37.5
"""Each anchor's report rate: the data set's (~150 +UUDF lines/s over four anchors)."""
TAG = "000000008401"
EPOCH_S = 1.7e9
ROOM_SEED = 50
"""Every carried walk is one room (its profile's fields): the withheld walks share one room."""


def carried_walk(rng: np.random.Generator, site: sites.Site, start_s: float = EPOCH_S) -> WalkedPath:
    """One walk: about WAYPOINTS grid points at a person's pace, LONG_STOPS of them long stops at
    STOPS filling STOPPED_SHARE of WALK_S, the others pauses of 0-2 s."""
    xs = [a.position[0] for a in site.anchors]
    ys = [a.position[1] for a in site.anchors]
    grid = [(x, y) for x in np.arange(min(xs) + GRID_M, max(xs) - GRID_M / 2, GRID_M)
            for y in np.arange(min(ys) + GRID_M, max(ys) - GRID_M / 2, GRID_M)]
    stops = [STOPS[k] for k in rng.choice(len(STOPS), LONG_STOPS, replace=False)]
    places: list[tuple[float, float]] = []
    long_at = []

    def elsewhere() -> tuple[float, float]:  # a grid point other than the last place (a leg takes time)
        while True:
            x, y = grid[int(rng.integers(len(grid)))]
            if not places or math.dist((x, y), places[-1]) > 0.5:
                return float(x), float(y)

    per_leg = (WAYPOINTS - 1) // LONG_STOPS - 2
    for stop, before in stops:
        for _ in range(per_leg):
            places.append(elsewhere())
        if places and math.dist(before, places[-1]) < 0.5:
            places.pop()
        places.append(before)
        long_at.append(len(places))
        places.append(stop)
    places.append(elsewhere())
    pace = float(rng.uniform(*PACE_M_S))
    legs = [math.dist(a, b) / pace for a, b in zip(places, places[1:])]
    pauses = [0.0 if k in long_at else float(rng.uniform(0.0, 2.0)) for k in range(len(places))]
    moving_s = sum(legs) + sum(pauses)
    stopped = STOPPED_SHARE * max(WALK_S, moving_s / (1 - STOPPED_SHARE))
    shares = rng.dirichlet(np.full(LONG_STOPS, 20.0))
    for k, share in zip(long_at, shares):
        pauses[k] = float(stopped * share)
    points, t = [], start_s
    for k, (x, y) in enumerate(places):
        if k:
            t += legs[k - 1]
        points.append(Waypoint(t, t + pauses[k] if k < len(places) - 1 else t, x, y))
        t += pauses[k] if k < len(places) - 1 else 0.0
    return WalkedPath(tuple(points))


def write_truth(path: WalkedPath, out: Path) -> Path:
    """The walk as the data set's waypoint file: ``arrival_ms,leave_ms,x_cm,y_cm``."""
    with out.open("w", newline="") as f:
        w = csv.writer(f)
        for p in path.waypoints:
            w.writerow([round(p.arrive_s * 1000), round(p.leave_s * 1000) if p.leave_s > p.arrive_s else "NaN",
                        round(p.x * 100), round(p.y * 100)])
    return out


def carried_walks(site_file: Path, folder: Path, walks: int, radio: str = "carried",
                  first_seed: int = 0) -> list[tuple[Path, Path]]:
    """``walks`` emulated carried walks in ``folder``: (capture, waypoint file) each."""
    site = sites.load(site_file)
    out = []
    for k in range(first_seed, first_seed + walks):
        path = carried_walk(np.random.default_rng([ROOM_SEED, k]), site, EPOCH_S + 1000.0 * k)
        truth = write_truth(path, folder / f"carried_run{k + 1}.csv")
        path = load_waypoints(truth)  # as a reader sees it (whole centimetres, milliseconds)
        capture = folder / f"carried_run{k + 1}.pcapng"
        scenario = capture.with_suffix(".toml")
        t0 = path.start_s - 1.0
        scenario.write_text(scenario_toml(site, path, t0, 1000 / RATE_HZ / 1.05, TAG))  # the schedule adds 5 %
        asyncio.run(_emulate(scenario, radio, 1000 + k, ROOM_SEED, path.end_s - t0 + 1.0, t0, capture))
        out.append((capture, truth))
    return out


def stop_figures(site: sites.Site, runs: Sequence[tuple[Path, Path]]) -> dict[str, float]:
    """Each long stop's mean azimuth error per anchor: their RMS, and the RMS difference of two
    walks' means at the same place and anchor (the 2026-12 field report's "bias that stays put")."""
    means: dict[tuple[str, float, float], list[float]] = {}
    for capture, truth in runs:
        path = load_waypoints(truth)
        events = [(got.t, got.item) for got in rfhoming.read(f"capture:{capture}", kinds={"angle"})]
        for name, r in residuals(site, events, path).items():
            for w in path.waypoints:
                if w.leave_s - w.arrive_s < 20.0:
                    continue
                inside = (r.t > w.arrive_s + 1.0) & (r.t < w.leave_s)
                if inside.sum() >= 20:
                    means.setdefault((name, w.x, w.y), []).append(float(np.mean(r.az_err[inside])))
    every = np.array([m for ms in means.values() for m in ms])
    pairs = [a - b for ms in means.values() for i, a in enumerate(ms) for b in ms[i + 1:]]
    return {"stop_mean_az_rms": round(float(np.sqrt(np.mean(every ** 2))), 2) if len(every) else math.nan,
            "stop_walk_to_walk_az": round(float(np.sqrt(np.mean(np.square(pairs)))), 2) if pairs else math.nan,
            "stops": int(len(every)), "pairs": len(pairs)}


def angle_figures(site: sites.Site, runs: Sequence[tuple[Path, Path]]) -> dict[str, float]:
    """The issue's angle statistics of ``runs`` (the spherical reading, as the issue's were)."""
    site = replace(site, anchors=tuple(replace(a, angle_model="spherical") for a in site.anchors))
    groups = [residuals(site, [(got.t, got.item) for got in rfhoming.read(f"capture:{c}", kinds={"angle"})],
                        load_waypoints(t)) for c, t in runs]
    s = angle_stats(groups)
    return {"az_std": round(s.az_std, 2), "az_tail": round(s.az_tail, 3), "el_std": round(s.el_std, 2),
            "corr_time_s": round(s.corr_time_s, 2), "compression_60_90": round(s.compression.get("60-90", math.nan), 2),
            **stop_figures(site, runs)}


def locate_figures(site_file: Path, runs: Sequence[tuple[Path, Path]], extra: Sequence[str] = (),
                   jobs: int = 2) -> dict[str, float]:
    """``rfhoming locate``'s mean error on ``runs`` (the data set's rule), over all ticks and
    split into the ticks where the tag moves and stands."""
    with ThreadPoolExecutor(jobs) as pool:
        located = list(pool.map(lambda run: locate(site_file, run[0], extra), runs))
    errors, moving = [], []
    for (_, truth), positions in zip(runs, located):
        path = load_waypoints(truth)
        e = score(path, positions)
        ticks = np.arange(path.start_s + 0.5, path.end_s + 1e-9, 0.5)[:len(e)]
        errors.append(e)
        moving.append(path.moving(ticks))
    e, m = np.concatenate(errors), np.concatenate(moving)
    return {"mean_m": round(float(e.mean()), 3), "moving_mean_m": round(float(e[m].mean()), 3) if m.any() else math.nan,
            "standing_mean_m": round(float(e[~m].mean()), 3) if (~m).any() else math.nan,
            "standing_share": round(float((~m).mean()), 3), "per_walk_m": [round(float(x.mean()), 3) for x in errors]}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="a folder with the room's site.toml (girolami_xplr_aoa/)")
    ap.add_argument("--walks", type=int, default=6, help="emulated walks (default 6)")
    ap.add_argument("--radio", default="carried", help="the radio profile (default carried)")
    ap.add_argument("--locate", default="", metavar="ARGS", help="extra arguments for every rfhoming locate")
    ap.add_argument("--keep", type=Path, help="keep the walks (captures and waypoint files) in this folder")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    site_file = args.data / "site.toml"
    result: dict[str, Any] = {"radio": args.radio, "walks": args.walks, "load_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory(prefix="rfhoming-carried-") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        runs = carried_walks(site_file, folder, args.walks, args.radio)
        result["angles"] = angle_figures(sites.load(site_file), runs)
        result["locate"] = locate_figures(site_file, runs, args.locate.split())
    result["issue_50"] = ISSUE_50
    result["load_after"] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"{args.walks} emulated carried walks, radio {args.radio}\n\n| statistic | emulated | the 2026-12 field report |\n|---|---|---|")
    for key, want in ISSUE_50.items():
        print(f"| {key} | {result['angles'][key]} | {want} |")
    loc = result["locate"]
    print(f"\nlocate (defaults{' ' + args.locate if args.locate else ''}): mean {loc['mean_m']} m; moving "
          f"{loc['moving_mean_m']} m, standing {loc['standing_mean_m']} m ({100 * loc['standing_share']:.0f} % of ticks)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
