"""Fixed-anchor localisation on emulated rooms with hidden per-board errors: each option's
accuracy and cost.

Rooms: the kit scenario (12 x 6 m, four wall anchors, three walking tags) with the emulator's
hidden per-board errors (mounting, azimuth/elevation scale and bias, wall reflections), for
each of ``--seeds``; ``--room wall`` raises the anchors to 2.3 m and carries every walking tag
at 1.1 m (campaigns.kit.WALL_ROOM: a room that fails like a real one; the site file then gives
the anchors' height and the tags' one height); ``--boards hard`` (default) also turns on the emulator's harder options
(campaigns.kit.HARD_BOARDS: the cone angle model, |azimuth| compression toward +-90, slow
multipath wander, elevation sigma 8 deg; each *assumed*, emulator/anchors.py). Each seed gives
a 2 x ``--duration`` run: the first half is the self-calibration's "earlier recording of the
room", every row is scored on the second half (held out); the surveyed calibration uses a
separate run with static tags at known points (same seed, same hidden errors).

Rows (2-D position error against the emulator's truth at the 10 Hz ticks, pooled over seeds):
- baseline: each anchor's median azimuth over 0.5 s, anchors as if at the tag's height,
  unweighted 2-D least squares of the bearing lines;
- the Locator step by step: spherical -> cone angle model -> Cauchy loss -> calibrated on
  surveyed points -> self-calibrated instead -> EKF tracker / RTS smoother on top.

Cost: CPU microseconds (process time) per angle event through Locator.feed, best of
``--repeats`` passes.

A self-calibration that does not beat the uncalibrated site on its own held-out epochs writes
nothing: its rows then use the uncalibrated site (never a loss by construction, and the bench
shows whether it holds on the scored half too).

    python bench/locate_bench.py [--seeds 1 2 3] [--duration 60] [--boards hard|plain] [--room kit|wall] [--json]
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

from rfhoming.campaigns.kit import CALIBRATION_POINTS, HARD_BOARDS, WALL_ROOM, Recording, record
from rfhoming.host import site as sites
from rfhoming.host.calibration import calibrate
from rfhoming.host.self_calibration import self_calibrate
from rfhoming.host.estimation.bearings import Degenerate, triangulate
from rfhoming.host.locate import Locator, smooth

SITE = "docs/sites/kit-room.toml"
WARM_UP_S = 2.0


def baseline(site: sites.Site, rec: Recording, t_from: float, rate_hz: float = 10.0, window_s: float = 0.5
             ) -> list[float]:
    """The naive pipeline's 2-D errors at every tick from ``t_from``."""
    anchors = site.anchor_by_id()
    recent: dict[tuple[str, str], list[tuple[float, float]]] = {}
    errors = []
    next_tick = math.ceil(rec.events[0].t * rate_hz) / rate_hz

    def tick(t: float) -> None:
        for tag in rec.tags:
            pos, bearings = [], []
            for anchor_id, anchor in anchors.items():
                angles = [a for s, a in recent.get((tag, anchor_id), []) if t - window_s < s <= t]
                if angles:
                    pos.append(anchor.position[:2])
                    bearings.append(math.radians(anchor.yaw_deg - statistics.median(angles)))
            if len(pos) >= 2 and t >= t_from:
                try:
                    point, _ = triangulate(np.array(pos), np.array(bearings))
                except Degenerate:
                    continue
                errors.append(float(np.linalg.norm(point - rec.truth(tag, t)[:2])))

    for event in rec.events:
        t = event.t
        while next_tick <= t:
            tick(next_tick)
            next_tick += 1 / rate_hz
        window = recent.setdefault((event.tag, event.anchor), [])
        window.append((t, event.clockwise_deg))
        if len(window) > 200:
            del window[:100]
    return errors


def run(site: sites.Site, events: list, *, smoothed: bool = False, **options) -> tuple[list, float, dict]:
    """(positions, CPU seconds for all events, counters) of the Locator on ``events``."""
    loc = Locator(site, reorder_s=0.0, track=not smoothed and options.pop("track", True), **options)
    out = []
    t0 = time.process_time()  # CPU time: the figure is cost, not the shared machine's queueing
    for event in events:
        out += loc.feed(event)
    out += loc.flush()
    if smoothed:
        out = smooth(out)
    return out, time.process_time() - t0, loc.counters


def scored(rec: Recording, positions: list, t_from: float) -> list[float]:
    return [float(np.linalg.norm(p.point[:2] - rec.truth(p.tag, p.t)[:2])) for p in positions if p.t >= t_from]


def summary(errors: list[float]) -> dict:
    e = np.array(errors)
    return {"fixes": len(e), "mean_m": round(float(e.mean()), 3), "median_m": round(float(np.median(e)), 3),
            "p90_m": round(float(np.percentile(e, 90)), 3)}


def with_fits(site: sites.Site, fits, model: str | None = None) -> sites.Site:
    if fits is None:  # a self-calibration that was not written
        return site
    return replace(site, anchors=tuple(replace(a, calibration=f.calibration, angle_model=model or f.angle_model)
                                       for a, f in zip(site.anchors, fits)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds scored per seed (default 60)")
    ap.add_argument("--calibration-s", type=float, default=8.0, help="seconds of the surveyed-point run (default 8)")
    ap.add_argument("--boards", choices=("hard", "plain"), default="hard")
    ap.add_argument("--room", choices=("kit", "wall"), default="kit",
                    help="kit: the kit-room scenario as it is; wall: anchors 2.3 m up, every tag at 1.1 m")
    ap.add_argument("--repeats", type=int, default=3, help="passes for the cost figure (best is kept)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    base = sites.load(SITE)
    room = WALL_ROOM if args.room == "wall" else None
    if room:
        base = replace(base, anchors=tuple(replace(a, position=(*a.position[:2], room["anchor_height_m"]))
                                           for a in base.anchors),
                       tags=tuple(replace(t, height=room["tag_height_m"]) for t in base.tags))
    boards = HARD_BOARDS if args.boards == "hard" else None
    cone = replace(base, anchors=tuple(replace(a, angle_model="cone") for a in base.anchors))
    rows: dict[str, list[float]] = {}
    extra: dict[str, dict] = {}
    cal_report = []
    costs: dict[str, float] = {}
    for seed in args.seeds:
        print(f"seed {seed}: recording {args.calibration_s:g} s at known points + {2 * args.duration:g} s walk",
              file=sys.stderr)
        rec = record(seed, 2 * args.duration, boards=boards, room=room)
        t_from = args.duration  # the second half is scored; the first is "an earlier recording"
        earlier = [e for e in rec.events if e.t < t_from]
        surveyed = calibrate(base, record(seed, args.calibration_s, calibration=True, boards=boards,
                                          room=room).events, CALIBRATION_POINTS)
        t0 = time.process_time()
        own = self_calibrate(base, [earlier])  # each anchor's model on held-out epochs
        own_cone = self_calibrate(cone, [earlier], models="site")  # the boards' model known (set in the site)
        self_cpu = time.process_time() - t0
        no_height = self_calibrate(replace(base, tags=tuple(replace(t, height=None) for t in base.tags)), [earlier])
        truth = {t["device"]: t for t in rec.anchors_truth}
        cal_report.append({"seed": seed, "angle_model_chosen": surveyed[0].angle_model,
                           "angle_model_self": [f.angle_model for f in own.fits],
                           "self_written": own.write, "self_verdict": own.verdict,
                           "self_no_height_verdict": no_height.verdict,
                           "self_held": {f.anchor: sorted(f.held) for f in own.fits},
                           "rms_by_model_deg": surveyed[0].rms_by_model, "self_cpu_s": round(self_cpu, 2),
                           "self_epochs": own.epochs,
                           "anchors": [{"anchor": f.anchor, "az_scale_true": round(truth[f.anchor]["az_scale"], 4),
                                        "az_scale_surveyed": round(s.calibration.az_scale, 4),
                                        "az_scale_self": round(f.calibration.az_scale, 4),
                                        "az_scale_self_sd": round(f.sigma.get("az_scale", math.nan), 4)}
                                       for f, s in zip(own.fits, surveyed)]})
        mine = own.fits if own.write else None
        plans = {
            "baseline (naive bearings)": None,
            "spherical, huber, cv (old default)": (base, {}),
            "cone model": (cone, {}),
            "cone, cauchy": (cone, {"loss": "cauchy"}),
            "cone, cauchy, height prior 0.2 m": (cone, {"loss": "cauchy", "height_sigma": 0.2}),
            "uncalibrated site, cauchy (the reference)": (base, {"loss": "cauchy"}),
            "+ surveyed calibration": (with_fits(base, surveyed), {"loss": "cauchy"}),
            "+ self-calibration instead": (with_fits(base, mine), {"loss": "cauchy"}),
            "  self-cal, cone model set in the site": (with_fits(cone, own_cone.fits if own_cone.write else None),
                                                       {"loss": "cauchy"}),
            "  self-cal, tag heights not given": (with_fits(base, no_height.fits if no_height.write else None),
                                                  {"loss": "cauchy"}),
            "self-cal, no tracking": (with_fits(base, mine), {"loss": "cauchy", "track": False}),
            "self-cal, ekf tracker": (with_fits(base, mine), {"loss": "cauchy", "tracker": "ekf"}),
            "self-cal, RTS smoother (recordings)": (with_fits(base, mine), {"loss": "cauchy", "smoothed": True}),
            "surveyed, spherical (model not chosen)": (with_fits(base, surveyed, "spherical"), {}),
        }
        per_seed: dict[str, float] = {}
        for name, plan in plans.items():
            if plan is None:
                rows.setdefault(name, []).extend(baseline(base, rec, t_from))
                continue
            site, options = plan
            positions, _, counters = run(site, rec.events, **dict(options))
            errors = scored(rec, positions, t_from)
            rows.setdefault(name, []).extend(errors)
            per_seed[name] = float(np.mean(errors))
            extra.setdefault(name, {"restarts": 0})["restarts"] += counters.get("restarts", 0)
        cal_report[-1]["self_minus_uncalibrated_m"] = round(
            per_seed["+ self-calibration instead"] - per_seed["uncalibrated site, cauchy (the reference)"], 4)
        if seed == args.seeds[0]:
            n = len(rec.events)
            for name, (site, options) in (("cv, huber", (base, {})), ("cv, cauchy", (cone, {"loss": "cauchy"})),
                                          ("ekf, cauchy", (cone, {"loss": "cauchy", "tracker": "ekf"})),
                                          ("rts smoother", (cone, {"loss": "cauchy", "smoothed": True}))):
                costs[name] = round(min(run(site, rec.events, **dict(options))[1] for _ in range(args.repeats))
                                    / n * 1e6, 1)
    table = {name: summary(e) for name, e in rows.items()}
    raw = table["uncalibrated site, cauchy (the reference)"]["mean_m"]
    gain_surveyed = raw - table["+ surveyed calibration"]["mean_m"]
    gain_self = raw - table["+ self-calibration instead"]["mean_m"]
    gain_self_cone = raw - table["  self-cal, cone model set in the site"]["mean_m"]
    result = {"seeds": args.seeds, "duration_s": args.duration, "boards": args.boards, "rows": table,
              "self_recovers_of_surveyed": round(gain_self / gain_surveyed, 3) if gain_surveyed > 0 else None,
              "self_cone_recovers_of_surveyed": round(gain_self_cone / gain_surveyed, 3) if gain_surveyed > 0 else None,
              "calibration": cal_report, "us_per_event": costs,
              "python": platform.python_version(), "machine": platform.machine()}
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"kit-room, {args.boards} boards, seeds {' '.join(map(str, args.seeds))}, {args.duration:g} s scored "
          f"each (held out); 2-D error, metres")
    print(f"{'':40} {'fixes':>6} {'mean':>6} {'median':>7} {'p90':>6} {'step':>7}")
    last = None
    for name, r in table.items():
        step = "" if last is None else f"{r['mean_m'] - last:+7.3f}"
        print(f"{name:40} {r['fixes']:6d} {r['mean_m']:6.3f} {r['median_m']:7.3f} {r['p90_m']:6.3f} {step}")
        last = r["mean_m"]
    if result["self_recovers_of_surveyed"] is not None:
        print(f"self-calibration recovers {100 * result['self_recovers_of_surveyed']:.0f} % of the mean-error cut "
              f"that surveyed-point calibration gives, {100 * result['self_cone_recovers_of_surveyed']:.0f} % with the "
              "cone model set in the site (goal >= 80 %)")
    for c in cal_report:
        print(f"seed {c['seed']}: self-calibration {c['self_verdict']}; with no tag heights: "
              f"{c['self_no_height_verdict']}; held: {c['self_held']}; self-cal minus uncalibrated "
              f"{c['self_minus_uncalibrated_m']:+.3f} m")
        print(f"seed {c['seed']}: angle model chosen {c['angle_model_chosen']} {c['rms_by_model_deg']} "
              f"(self-cal: {c['angle_model_self']}); self-cal "
              f"{c['self_epochs']} epochs in {c['self_cpu_s']} s CPU; az_scale true/surveyed/self(sd): " + ", ".join(
                  f"{a['anchor']} {a['az_scale_true']:.3f}/{a['az_scale_surveyed']:.3f}/{a['az_scale_self']:.3f}"
                  f"({a['az_scale_self_sd']:.3f})" for a in c["anchors"]))
    print("cost, us per angle event: " + ", ".join(f"{k} {v}" for k, v in costs.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
