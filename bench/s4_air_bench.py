"""S4 from the air over several seeds: the metric S4 reports, pooled over every beacon of every run.

Each seed is one ``rfhoming demo --scenario s4-air --in-process --seed N`` (its own process, in
lockstep: the emulated MAVLink copter carries three ESP32 scanners over the ten beacons). Each
run's last run-log estimate of every beacon is compared with the emulator's truth (the demo's
own summary does the same per run); the pooled mean, 95th percentile and max are printed beside
S4's EKF (mean 0.234 m, 95 % below 0.65 m), for the forward EKF and for the EKF followed by
the smoother, with each run's arrival and final distance to the beacon it held over.

    python bench/s4_air_bench.py --seeds 1-5 --json
    python bench/s4_air_bench.py --seeds 1-5 --radio measured   # radios as bad as real ones
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

PAPER = {"mean_m": 0.234, "p95_below_m": 0.65}


def seeds(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def errors(out: Path, key: str) -> list[float]:
    """Every beacon's final error in a run's folder, for the run log's ``key`` estimates."""
    last = None
    for line in (out / "run.jsonl").read_text().splitlines():
        if f'"{key}"' in line:
            last = json.loads(line)
    truth = json.loads((out / "truth.jsonl").read_text().splitlines()[-1])["targets"]
    found = {} if last is None else last[key]
    return [math.dist(found[t["id"]], (t["x"], t["y"])) for t in truth if t["id"] in found]


def stats(values: list[float]) -> dict[str, Any] | None:
    if not values:  # no run localised a beacon
        return None
    e = np.array(values)
    return {"beacons": len(e), "mean_m": round(float(e.mean()), 3), "p95_m": round(float(np.percentile(e, 95)), 3),
            "max_m": round(float(e.max()), 3)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=seeds, default=seeds("1-5"), help="N or N-M (default 1-5)")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    parser.add_argument("--radio", default="ideal", metavar="ideal|measured|PROFILE",
                        help="the emulated radios, as demo --radio (default ideal: S4's own radio)")
    args = parser.parse_args()
    load_before = os.getloadavg()
    runs, pooled = [], {"beacons": [], "smoothed": []}
    with tempfile.TemporaryDirectory(prefix="s4-air-") as tmp:
        for seed in args.seeds:
            out = Path(tmp) / str(seed)
            done = subprocess.run([sys.executable, "-m", "rfhoming", "demo", "--scenario", "s4-air", "--in-process",
                                   "--seed", str(seed), "--radio", args.radio, "--json", "--out", str(out)],
                                  capture_output=True, text=True, timeout=1800)
            if done.returncode not in (0, 1):
                print(f"s4_air_bench: seed {seed}: {done.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
                return 2
            summary = json.loads(done.stdout)
            for key in pooled:
                pooled[key] += errors(out, key)
            runs.append({"seed": seed, "success": summary["success"], "simulated_time_s": summary["simulated_time_s"],
                         "final_position_error_m": summary["final_position_error_m"],
                         "localisation": summary["localisation"]})
    report = {"runs": runs, "ekf": stats(pooled["beacons"]), "ekf_smoothed": stats(pooled["smoothed"]),
              "s4_paper": PAPER, "radio": args.radio, "load_before": [round(v, 2) for v in load_before],
              "load_after": [round(v, 2) for v in os.getloadavg()]}
    if args.json:
        print(json.dumps(report))
    else:
        for run in runs:
            print(f"seed {run['seed']}: arrived {run['success']}, {run['final_position_error_m']} m from the beacon")
        for name in ("ekf", "ekf_smoothed"):
            s = report[name]
            print(f"{name:<13} {s['beacons']} beacons: mean {s['mean_m']} m, p95 {s['p95_m']} m, max {s['max_m']} m "
                  f"(S4: mean 0.234 m, 95 % below 0.65 m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
