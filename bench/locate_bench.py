"""Fixed-anchor localisation on the emulator's kit scenario: accuracy and cost, one run.

Rows (2-D position error against the emulator's truth, at the same 10 Hz ticks, same events):
- baseline: each anchor's median azimuth over the last 0.5 s, anchors as if at the tag's
  height (no elevation, no pitch), unweighted 2-D least squares of the bearing lines;
- pipeline, uncalibrated: rfhoming's Locator (3-D rays, weights, consensus, CV tracking) with
  the site's nominal poses;
- pipeline, calibrated: the same after `calibrate` on a separate run of the same anchors (same
  seed, same hidden errors) with static tags at known points;
- the calibrated pipeline without tracking (raw fixes), to show what the filter does;
- the calibrated pipeline with the EKF on bearings instead of the CV filter on fixes.

Cost: CPU microseconds (process time) per angle event through Locator.feed (merging,
windows, fixes, tracking), the best of ``--repeats`` passes.

    python bench/locate_bench.py [--seed 1] [--duration 60] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from dataclasses import replace

import numpy as np

from rfhoming.campaigns.kit import CALIBRATION_POINTS, Recording, record
from rfhoming.host import site as sites
from rfhoming.host.calibration import calibrate
from rfhoming.host.estimation.bearings import Degenerate, triangulate
from rfhoming.host.locate import Locator

SITE = "docs/sites/kit-room.toml"
WARM_UP_S = 2.0


def baseline(site: sites.Site, rec: Recording, rate_hz: float = 10.0, window_s: float = 0.5) -> list[float]:
    """The naive pipeline's 2-D errors at every tick."""
    anchors = site.anchor_by_id()
    recent: dict[tuple[str, str], list[tuple[float, int]]] = {}
    errors = []
    next_tick = math.ceil(rec.events[0][0] * rate_hz) / rate_hz

    def tick(t: float) -> None:
        for tag in rec.tags:
            pos, bearings = [], []
            for anchor_id, anchor in anchors.items():
                angles = [a for s, a in recent.get((tag, anchor_id), []) if t - window_s < s <= t]
                if angles:
                    pos.append(anchor.position[:2])
                    bearings.append(math.radians(anchor.yaw_deg - statistics.median(angles)))
            if len(pos) >= 2 and t >= WARM_UP_S:
                try:
                    point, _ = triangulate(np.array(pos), np.array(bearings))
                except Degenerate:
                    continue
                errors.append(float(np.linalg.norm(point - rec.truth(tag, t)[:2])))

    for t, event in rec.events:
        while next_tick <= t:
            tick(next_tick)
            next_tick += 1 / rate_hz
        window = recent.setdefault((event.instance_id, event.anchor_id), [])
        window.append((t, event.azimuth))
        if len(window) > 200:
            del window[:100]
    return errors


def pipeline(site: sites.Site, rec: Recording, *, track: bool = True, tracker: str = "cv"
             ) -> tuple[list[float], float, dict]:
    """(2-D errors, seconds for all events, counters) of the Locator."""
    loc = Locator(site, track=track, tracker=tracker, reorder_s=0.0)
    out = []
    t0 = time.process_time()  # CPU time: the figure is cost, not the shared machine's queueing
    for t, event in rec.events:
        out += loc.feed(t, event)
    out += loc.flush()
    elapsed = time.process_time() - t0
    errors = [float(np.linalg.norm(p.point[:2] - rec.truth(p.tag, p.t)[:2])) for p in out if p.t >= WARM_UP_S]
    return errors, elapsed, loc.counters


def summary(errors: list[float]) -> dict:
    e = np.array(errors)
    return {"fixes": len(e), "mean_m": round(float(e.mean()), 3), "median_m": round(float(np.median(e)), 3),
            "p95_m": round(float(np.percentile(e, 95)), 3)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of the kit scenario (default 60)")
    ap.add_argument("--calibration-s", type=float, default=8.0, help="seconds of the calibration run (default 8)")
    ap.add_argument("--repeats", type=int, default=3, help="passes for the cost figure (best is kept)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    site = sites.load(SITE)
    print(f"recording {args.calibration_s:g} s calibration + {args.duration:g} s kit run (seed {args.seed})",
          file=sys.stderr)
    cal_run = record(args.seed, args.calibration_s, calibration=True)
    fits = calibrate(site, cal_run.events, CALIBRATION_POINTS)
    calibrated = replace(site, anchors=tuple(replace(a, calibration=f.calibration) for a, f in zip(site.anchors, fits)))
    rec = record(args.seed, args.duration)
    rows = {"baseline": summary(baseline(site, rec))}
    before, _, c_before = pipeline(site, rec)
    rows["pipeline uncalibrated"] = summary(before) | {"anchors_rejected": c_before["rejected_anchor"]}
    after, _, c_after = pipeline(calibrated, rec)
    rows["pipeline calibrated"] = summary(after) | {"anchors_rejected": c_after["rejected_anchor"]}
    raw, _, _ = pipeline(calibrated, rec, track=False)
    rows["calibrated, no tracking"] = summary(raw)
    ekf, _, _ = pipeline(calibrated, rec, tracker="ekf")
    rows["calibrated, EKF on bearings"] = summary(ekf)
    cost = min(pipeline(calibrated, rec)[1] for _ in range(args.repeats)) / len(rec.events) * 1e6
    cost_ekf = min(pipeline(calibrated, rec, tracker="ekf")[1] for _ in range(args.repeats)) / len(rec.events) * 1e6
    gain = 1 - rows["pipeline calibrated"]["mean_m"] / rows["baseline"]["mean_m"]
    result = {"seed": args.seed, "duration_s": args.duration, "events": len(rec.events), "rows": rows,
              "calibration": [{"anchor": f.anchor, "rms_before_deg": round(f.rms_before_deg, 2),
                               "rms_after_deg": round(f.rms_after_deg, 2)} for f in fits],
              "mean_below_baseline": round(gain, 3), "us_per_event": round(cost, 1),
              "us_per_event_ekf": round(cost_ekf, 1),
              "python": platform.python_version(), "machine": platform.machine()}
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"kit-room, seed {args.seed}, {args.duration:g} s, {len(rec.events)} angle events; 2-D error, metres")
    print(f"{'':28} {'fixes':>6} {'mean':>6} {'median':>7} {'p95':>6}")
    for name, r in rows.items():
        print(f"{name:28} {r['fixes']:6d} {r['mean_m']:6.3f} {r['median_m']:7.3f} {r['p95_m']:6.3f}")
    print(f"calibrated pipeline mean error {100 * gain:.0f} % below the baseline (target >= 30 %)")
    for f in fits:
        print(f"calibration {f.anchor}: angle rms {f.rms_before_deg:.2f} -> {f.rms_after_deg:.2f} deg")
    print(f"cost {cost:.1f} us per angle event, tracking included (target <= 50); "
          f"with the EKF on bearings {cost_ekf:.1f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
