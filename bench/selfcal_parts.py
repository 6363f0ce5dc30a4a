"""Which parts of the self-calibration help: each anchor's azimuth bias, its scale, the |azimuth|
compression, the elevation. Each variant holds some of them (self_calibrate's ``hold`` and
``elevation``) and is scored two ways: as written (a calibration the guard refuses leaves the
site uncalibrated, as `rfhoming calibrate --self` leaves a user's site file) and as if applied
regardless (what the guard kept out).

- Emulated (default): the kit room with the hard boards, as bench/locate_bench.py runs it --
  per seed one 2 x ``--duration`` walk, the first half self-calibrates, the second half is
  scored (Locator, Cauchy loss: its "+ self-calibration instead" row against "uncalibrated site,
  cauchy (the reference)"), per seed and pooled.
- ``--data DIR``: the Girolami et al. recordings (docs/RESULTS.md, "Real recordings"; the layout
  of bench/real_aoa.py): calibrated on one use case's runs, the other's located (in-process,
  locate's defaults) and scored by the data set's rule -- both directions. No ground truth
  reaches the calibration.

    python bench/selfcal_parts.py [--seeds 1 2 3] [--duration 60] [--data DIR] [--variants NAME ...] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rfhoming.host import site as sites
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.locate import Locator
from rfhoming.host.self_calibration import SelfCalibration, self_calibrate

SITE = "docs/sites/kit-room.toml"

VARIANTS: dict[str, dict[str, Any]] = {
    "default (elevation held)": {},
    "+ elevation fitted (tracker check)": {"elevation": True},
    "no compression": {"hold": ("az_compression",)},
    "bias only (scale, compression held)": {"hold": ("az_scale", "az_compression")},
}


def calibrated(site: sites.Site, result: SelfCalibration) -> sites.Site:
    return replace(site, anchors=tuple(replace(a, calibration=f.calibration, angle_model=f.angle_model)
                                       for a, f in zip(site.anchors, result.fits)))


def emulated(seeds: Sequence[int], duration: float, variants: Sequence[str]) -> dict[str, Any]:
    from rfhoming.campaigns.kit import HARD_BOARDS, record

    base = sites.load(SITE)
    errors: dict[str, dict[str, list[float]]] = {}
    per_seed: list[dict[str, Any]] = []

    def scored(site: sites.Site, rec: Any) -> list[float]:
        loc = Locator(site, reorder_s=0.0, loss="cauchy")
        out = [p for e in rec.events for p in loc.feed(e)] + loc.flush()
        return [float(np.linalg.norm(p.point[:2] - rec.truth(p.tag, p.t)[:2])) for p in out if p.t >= duration]

    for seed in seeds:
        print(f"seed {seed}", file=sys.stderr, flush=True)
        rec = record(seed, 2 * duration, boards=HARD_BOARDS)
        earlier = [e for e in rec.events if e.t < duration]
        reference = scored(base, rec)
        errors.setdefault("uncalibrated", {}).setdefault("written", []).extend(reference)
        row: dict[str, Any] = {"seed": seed, "uncalibrated_m": round(float(np.mean(reference)), 4)}
        for name in variants:
            result = self_calibrate(base, [earlier], **VARIANTS[name])
            applied = scored(calibrated(base, result), rec)
            written = applied if result.write else reference
            errors.setdefault(name, {}).setdefault("written", []).extend(written)
            errors[name].setdefault("applied", []).extend(applied)
            row[name] = {"written": result.write, "mean_m": round(float(np.mean(written)), 4),
                         "if_applied_m": round(float(np.mean(applied)), 4), "verdict": result.verdict}
        per_seed.append(row)
    pooled = {name: {k: round(float(np.mean(v)), 4) for k, v in e.items()} for name, e in errors.items()}
    return {"seeds": list(seeds), "duration_s": duration, "pooled_mean_m": pooled, "per_seed": per_seed}


def real(data: Path, variants: Sequence[str]) -> dict[str, Any]:
    import rfhoming
    from rfhoming.host.groundtruth import load_waypoints, score

    site = sites.load(data / "site.toml")
    captures = sorted((data / "captures").glob("*.pcapng"))
    events = {c.stem: [bearing_of(got.t, got.item) for got in rfhoming.read(f"capture:{c}", kinds={"angle"})] for c in captures}
    cases: dict[str, list[str]] = {}
    for c in captures:
        cases.setdefault(c.stem.rsplit("_run", 1)[0], []).append(c.stem)

    def mean_error(s: sites.Site, uc: str) -> float:
        per_run = []
        for run in cases[uc]:
            loc = Locator(s)
            out = [p for e in events[run] for p in loc.feed(e)] + loc.flush()
            per_run.append(score(load_waypoints(data / "ground_truth" / f"{run}.csv"),
                                 [(p.t, float(p.point[0]), float(p.point[1])) for p in out]))
        return round(float(np.mean(np.concatenate(per_run))), 3)

    out: dict[str, Any] = {"uncalibrated_m": {uc: mean_error(site, uc) for uc in cases}}
    for name in variants:
        out[name] = {}
        for test in cases:
            train = [r for uc, runs in cases.items() if uc != test for r in runs]
            print(f"{name}: calibrated on {len(train)} runs, locating {test}", file=sys.stderr, flush=True)
            result = self_calibrate(site, [events[r] for r in train], **VARIANTS[name])
            applied = mean_error(calibrated(site, result), test)
            out[name][test] = {"written": result.write, "mean_m": applied if result.write else
                               out["uncalibrated_m"][test], "if_applied_m": applied, "verdict": result.verdict}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3], help="emulated seeds (none: skip)")
    ap.add_argument("--duration", type=float, default=60.0, help="seconds scored per seed (default 60)")
    ap.add_argument("--data", type=Path, help="also the real recordings in DIR (bench/real_aoa.py's layout)")
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS), metavar="NAME",
                    help="which variants (default all): " + "; ".join(VARIANTS))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    result: dict[str, Any] = {"load_before": os.getloadavg()[0], "python": platform.python_version()}
    cpu = time.process_time()
    if args.data:
        result["real"] = real(args.data, args.variants)
    if args.seeds:
        result["emulated"] = emulated(args.seeds, args.duration, args.variants)
    result["cpu_s"] = round(time.process_time() - cpu, 1)
    result["load_after"] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(result))
        return 0
    if "real" in result:
        r = result["real"]
        print(f"real recordings, uncalibrated: {json.dumps(r['uncalibrated_m'])}")
        for name in args.variants:
            for uc, v in r[name].items():
                print(f"  {name:40} -> {uc}: {v['mean_m']:.3f} m ({'written' if v['written'] else 'refused'}; "
                      f"if applied {v['if_applied_m']:.3f} m)")
    if "emulated" in result:
        e = result["emulated"]
        print(f"emulated kit room, hard boards, seeds {e['seeds']}: pooled mean 2-D error (m)")
        for name, v in e["pooled_mean_m"].items():
            print(f"  {name:40} {v['written']:.3f}" + (f" (if applied {v['applied']:.3f})" if "applied" in v else ""))
        for row in e["per_seed"]:
            print(f"  seed {row['seed']}: uncalibrated {row['uncalibrated_m']:.3f}; " + "; ".join(
                f"{name} {row[name]['mean_m'] - row['uncalibrated_m']:+.3f}"
                f"{'' if row[name]['written'] else ' (refused)'}" for name in args.variants))
    return 0


if __name__ == "__main__":
    sys.exit(main())
