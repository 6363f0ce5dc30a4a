"""The robust bearing fit's cost inside S0's homing under measured radios: rays kept, fits made,
and the CPU time of each fit on the event loop.

    python bench/bearing_fit_bench.py [--scenario s0-house] [--seeds 1 2 3] [--radio measured] [--json]

Each seed is one in-process demo run (``rfhoming demo --scenario S --radio R --seed N
--in-process``: lockstep, so the run depends on the seed alone, not on the machine's load).
:class:`~rfhoming.host.estimation.bearing_fit.BearingFit` is wrapped: every reading offered to
it (``add``), every ray kept, and every fit (``fit``) with its ray count and its CPU time
(``time.thread_time``: the fit runs on the event loop's thread, and this thread's CPU time
counts other processes on a shared machine much less than the wall clock does; the wall time
is given too). ``in_place``: readings offered while the robot had moved less than 1 mm since
the previous reading (standing or turning on the spot). ``standing`` also asks that it turned
less than 0.1°, from a ``heading=`` keyword to ``add``; BearingFit's ``add`` takes no heading
(the odometry spacing that gave it one was measured and not kept: docs/RESULTS.md), so
``standing`` equals ``in_place``. Fits per simulated second count the fits over the run's span
of readings.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rfhoming.demo import run_demo
from rfhoming.host.estimation import bearing_fit
from rfhoming.host.homing.config import Config


class Probe:
    """Wraps BearingFit's ``add`` and ``fit`` for one run."""

    def __init__(self) -> None:
        self.offered = self.kept = self.standing = self.kept_standing = self.in_place = self.kept_in_place = 0
        self.fits: list[tuple[int, float, float]] = []  # rays, CPU s, wall s
        self.t: list[float] = []
        self.max_rays = 0
        self._prev: tuple[float, float, float] | None = None

    def install(self) -> tuple[Any, Any]:
        cls = bearing_fit.BearingFit
        old_add, old_fit = cls.add, cls.fit
        probe = self

        def add(self: Any, t: float, x: float, y: float, *args: Any, **kwargs: Any) -> bool:
            heading = kwargs.get("heading")
            pose = (x, y, 0.0 if heading is None else float(heading))
            prev, probe._prev = probe._prev, pose
            here = prev is not None and abs(x - prev[0]) < 1e-3 and abs(y - prev[1]) < 1e-3
            still = here and prev is not None and abs(pose[2] - prev[2]) < 1.7e-3
            kept = old_add(self, t, x, y, *args, **kwargs)
            probe.offered += 1
            probe.standing += still
            probe.kept += bool(kept)
            probe.kept_standing += bool(kept) and still
            probe.in_place += here
            probe.kept_in_place += bool(kept) and here
            probe.t.append(t)
            probe.max_rays = max(probe.max_rays, self.rays)
            return bool(kept)

        def fit(self: Any, *args: Any, **kwargs: Any) -> Any:
            c0, w0 = time.thread_time(), time.perf_counter()
            out = old_fit(self, *args, **kwargs)
            probe.fits.append((self.rays, time.thread_time() - c0, time.perf_counter() - w0))
            return out

        cls.add, cls.fit = add, fit  # type: ignore[method-assign]
        return old_add, old_fit

    def summary(self) -> dict[str, Any]:
        cpu = sorted(f[1] * 1e3 for f in self.fits)
        wall = sorted(f[2] * 1e3 for f in self.fits)
        rays = [f[0] for f in self.fits]
        span = (self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

        def pct(v: list[float], q: float) -> float:
            return round(v[min(len(v) - 1, int(q * len(v)))], 3) if v else 0.0

        return {"readings_offered": self.offered, "readings_standing": self.standing, "rays_kept": self.kept,
                "rays_kept_standing": self.kept_standing, "readings_in_place": self.in_place,
                "rays_kept_in_place": self.kept_in_place, "max_rays_held": self.max_rays,
                "fits": len(self.fits), "fits_per_sim_s": round(len(self.fits) / span, 2) if span else 0.0,
                "rays_per_fit_median": statistics.median(rays) if rays else 0,
                "fit_cpu_ms_median": pct(cpu, 0.5), "fit_cpu_ms_p90": pct(cpu, 0.9), "fit_cpu_ms_max": pct(cpu, 1.0),
                "fit_wall_ms_median": pct(wall, 0.5), "fit_wall_ms_max": pct(wall, 1.0),
                "fit_cpu_ms_total": round(sum(cpu), 1), "fit_cpu_ms_per_sim_s": round(sum(cpu) / span, 2) if span else 0.0}


def one(scenario: str, seed: int, radio: str) -> dict[str, Any]:
    probe = Probe()
    old_add, old_fit = probe.install()
    try:
        with tempfile.TemporaryDirectory(prefix="rfh-bfbench-") as tmp:
            s = run_demo(scenario, seed, Path(tmp), Config(), None, in_process=True, radio=radio)
    finally:
        bearing_fit.BearingFit.add, bearing_fit.BearingFit.fit = old_add, old_fit  # type: ignore[method-assign]
    return {"seed": seed, "success": s.get("success"), "simulated_time_s": s.get("simulated_time_s"),
            "final_position_error_m": s.get("final_position_error_m"), **probe.summary()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="s0-house")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--radio", default="measured")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    load0 = os.getloadavg()
    runs = [one(args.scenario, seed, args.radio) for seed in args.seeds]
    fits = sum(r["fits"] for r in runs)
    out = {"scenario": args.scenario, "radio": args.radio, "runs": runs,
           "fits": fits, "fit_cpu_ms_total": round(sum(r["fit_cpu_ms_total"] for r in runs), 1),
           "fit_cpu_ms_mean": round(sum(r["fit_cpu_ms_total"] for r in runs) / fits, 3) if fits else 0.0,
           "fit_cpu_ms_max": max((r["fit_cpu_ms_max"] for r in runs), default=0.0),
           "max_rays_held": max(r["max_rays_held"] for r in runs),
           "load_before": [round(v, 2) for v in load0], "load_after": [round(v, 2) for v in os.getloadavg()],
           "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "python": platform.python_version()}
    if args.json:
        json.dump(out, sys.stdout)
        print()
        return 0
    print(f"{'seed':>4} {'ok':>5} {'sim s':>7} {'offered':>7} {'standing':>8} {'kept':>5} {'kept st.':>8} "
          f"{'held':>5} {'fits':>5} {'fits/s':>6} {'rays/fit':>8} {'ms med':>7} {'ms max':>7} {'ms/sim s':>8}")
    for r in runs:
        print(f"{r['seed']:>4} {str(r['success']):>5} {r['simulated_time_s']:>7} {r['readings_offered']:>7} "
              f"{r['readings_standing']:>8} {r['rays_kept']:>5} {r['rays_kept_standing']:>8} {r['max_rays_held']:>5} "
              f"{r['fits']:>5} {r['fits_per_sim_s']:>6} {r['rays_per_fit_median']:>8} {r['fit_cpu_ms_median']:>7} "
              f"{r['fit_cpu_ms_max']:>7} {r['fit_cpu_ms_per_sim_s']:>8}")
    print(f"all: {fits} fits, {out['fit_cpu_ms_mean']} ms CPU each on average, max {out['fit_cpu_ms_max']} ms; "
          f"at most {out['max_rays_held']} rays held; load {out['load_before']} -> {out['load_after']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
