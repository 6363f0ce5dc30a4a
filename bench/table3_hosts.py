"""S0 Table 3's realistic rows under measured radios with four host configurations, on the
campaign's own targets and seeds: where the campaign's final error comes from.

    python bench/table3_hosts.py [--runs 8] [--seed 0] [--radio measured] [--json]

Each target k of ``rfhoming campaign s0-table3 --runs R --seed S --radio measured`` (its
``realistic`` rows: one set of runs under a profile), homed in process, the same scenario
and seed as the campaign's job, by:

- ``campaign``: the campaign's host (ray fusion on, P0 and n from its calibration session
  through the same radios, campaigns/calibration.py);
- ``calibrated-no-fusion``: the same calibration, ray fusion off (S0's defaults);
- ``fusion-uncalibrated``: ray fusion on, the config's default P0 and n (not calibrated);
- ``demo``: ``rfhoming demo``'s host (defaults: no fusion, not calibrated).

The host never reads the radio model; the calibration session's fit is printed beside.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from typing import Any

from rfhoming.campaigns import calibration, closed_loop, s0
from rfhoming.emulator.scenario import load
from rfhoming.host.homing.config import Config

VARIANTS = ("campaign", "calibrated-no-fusion", "fusion-uncalibrated", "demo")


def host(variant: str, seed: int, radio: str) -> Config:
    calibrated = s0.host_config("s0-open", seed, None, radio=radio)
    return {"campaign": calibrated, "calibrated-no-fusion": replace(calibrated, s0=Config().s0),
            "fusion-uncalibrated": s0.OURS, "demo": Config()}[variant]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--radio", default="measured")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    load0 = os.getloadavg()
    fit = calibration.cached("s0-open", args.seed, None, None, args.radio)
    rows: list[dict[str, Any]] = []
    for variant in VARIANTS:
        config = host(variant, args.seed, args.radio)
        for k, target in enumerate(s0.targets(args.runs, args.seed)):
            job_seed = args.seed * 100_000 + k  # as s0.table3_jobs
            scenario = load("s0-open", seed=job_seed, target=target, aoa_preset=None, radio=args.radio)
            m = closed_loop.metrics(closed_loop.run(scenario, config, job_seed), target)
            rows.append({"variant": variant, "k": k, "target": [round(v, 3) for v in target],
                         **{key: m[key] for key in ("success", "time_s", "goal_error_m", "final_error_m")}})
            if not args.json:
                print(variant, k, rows[-1]["target"], m["success"], m["time_s"], m["goal_error_m"], m["final_error_m"],
                      flush=True)
    summary = {v: {"success": sum(bool(r["success"]) for r in rows if r["variant"] == v),
                   "final_error_m": [min(r["final_error_m"] for r in rows if r["variant"] == v),
                                     max(r["final_error_m"] for r in rows if r["variant"] == v)],
                   "goal_error_m": [min(r["goal_error_m"] for r in rows if r["variant"] == v and r["goal_error_m"] is not None),
                                    max(r["goal_error_m"] for r in rows if r["variant"] == v and r["goal_error_m"] is not None)]}
               for v in VARIANTS}
    out = {"radio": args.radio, "runs": args.runs, "seed": args.seed, "calibration": fit.summary(),
           "summary": summary, "rows": rows, "load_before": [round(v, 2) for v in load0],
           "load_after": [round(v, 2) for v in os.getloadavg()], "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    if args.json:
        json.dump(out, sys.stdout)
        print()
    else:
        print("calibration", fit.summary())
        for v, s in summary.items():
            print(f"{v}: {s['success']}/{args.runs} succeed, final {s['final_error_m']} m, goal {s['goal_error_m']} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
