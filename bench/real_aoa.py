"""rfhoming locate on real XPLR-AOA recordings with ground truth, scored as the data set says.

DIR is laid out as the published XPLR-AOA mobility recordings of Girolami et al. (IEEE Access 11,
2023; doi:10.5281/zenodo.7759557; docs/RESULTS.md, "Real recordings"), rendered as rfhoming reads
them: ``site.toml``, ``captures/UC_runR.pcapng`` (each anchor's ``+UUDF`` lines at the logged times)
and ``ground_truth/UC_runR.csv`` (one waypoint per row, ``arrival_ms,leave_ms,x_cm,y_cm``). Each
capture is located by ``rfhoming locate SITE --from capture:FILE`` in its own process, exactly as a
user runs it; the ground truth is read here only, to score (host/groundtruth.py: ticks every 0.5 s
from the first waypoint + 0.5 s to the last, the last position printed at or before each tick,
5 m before the first) and for the angle statistics (host/angle_residuals.py: each report against
the angle the board would give for the true position; bias, spread, tails, |azimuth| compression,
autocorrelation time, missing events). Use cases are the captures' name prefixes (``uc1_run3`` is
use case ``uc1``). Each use case's positions are also scored for their stated uncertainty:
``coverage95``, the fraction of ticks whose truth lies inside the position's 95 % ellipse (its x-y
covariance; 0.90-0.98 wanted), and the positions' median sigma.

``--self-cal``: also, for each use case, `rfhoming calibrate SITE --self` on the recordings of
every *other* use case (a copy of the site file, no ground truth), then locate this use case's
recordings with that calibration: what a user gets who calibrated on an earlier walk of the room.
``--locate ARGS``: extra arguments for every `rfhoming locate` (one string, e.g. "--tracker ekf").
``--cv``: how the angles tracker's defaults were chosen (docs/estimation.md): for each use case,
a coordinate search over the report model's and the motion's settings (CV_STEPS) from the
defaults, scored on that use case alone (in-process, the same scoring rule), then judged on
every other use case; the defaults themselves scored beside (~25 scorings a fold, minutes).
``--kinds FOLDER``: cross-kind folds (the 2026-12 field report): the defaults and every one-setting move of CV_STEPS
scored on each kind of walk -- the use cases, and the walks in FOLDER as one more kind
(bench/carried_walks.py --keep FOLDER writes emulated carried walks of the same room) -- then the
best on each kind alone and on each mix that leaves one kind out, judged on every kind, the held-out
ones marked (one scoring per candidate and kind: ~20 x the kinds' locate time).

    python bench/real_aoa.py --data DIR [--self-cal] [--json]
    python bench/carried_walks.py --data DIR --keep walks && python bench/real_aoa.py --data DIR --kinds walks
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

import rfhoming
from rfhoming.host import site as sites
from rfhoming.host.angle_residuals import angle_stats, residuals
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.groundtruth import FIRST_TICK_S, TICK_S, WalkedPath, area_of, load_waypoints, score

RFHOMING = [sys.executable, "-m", "rfhoming"]


def recordings(data: Path) -> dict[str, list[tuple[Path, Path]]]:
    """Use case -> [(capture, ground truth)], in name order; SystemExit naming what is missing."""
    found: dict[str, list[tuple[Path, Path]]] = {}
    for capture in sorted((data / "captures").glob("*.pcapng")):
        truth = data / "ground_truth" / f"{capture.stem}.csv"
        if not truth.exists():
            raise SystemExit(f"real_aoa: {capture} has no ground truth {truth}")
        found.setdefault(capture.stem.rsplit("_run", 1)[0], []).append((capture, truth))
    if not found or not (data / "site.toml").exists():
        raise SystemExit(f"real_aoa: {data} needs site.toml, captures/*.pcapng and ground_truth/*.csv "
                         "(the layout of the XPLR-AOA recordings: bench/real_aoa.py --help)")
    try:  # every file checked before any run: a bad row is one line and exit 2, not a score of 10^8 m
        area = area_of(a.position for a in sites.load(data / "site.toml").anchors)
        for runs in found.values():
            for _, truth in runs:
                load_waypoints(truth, area)
    except rfhoming.Error as exc:
        print(f"{Path(sys.argv[0]).stem}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return found


def positions(site: Path, capture: Path, extra: Sequence[str]) -> list[dict[str, Any]]:
    """Every position line `rfhoming locate` prints for the capture (t, x, y, cov, ...)."""
    done = subprocess.run([*RFHOMING, "locate", str(site), "--from", f"capture:{capture}", *extra],
                          capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"real_aoa: rfhoming locate failed on {capture}: {done.stderr.strip().splitlines()[-1:]}")
    rows = (json.loads(line) for line in done.stdout.splitlines() if line.startswith("{"))
    return [p for p in rows if p.get("kind") == "position"]


def locate(site: Path, capture: Path, extra: Sequence[str]) -> list[tuple[float, float, float]]:
    """(t, x, y) of every position `rfhoming locate` prints for the capture."""
    return [(p["t"], p["x"], p["y"]) for p in positions(site, capture, extra)]


ELLIPSE_95 = -2.0 * math.log(0.05)
"""The squared Mahalanobis radius of a 2-D Gaussian's 95 % ellipse (chi-square, 2 dof: 5.99)."""


def inside_95(path: WalkedPath, rows: Sequence[dict[str, Any]]) -> np.ndarray:
    """Per scoring tick (groundtruth.score's: the last position at or before it) whether the
    truth lies inside that position's 95 % ellipse (its x-y covariance); ticks before the first
    position are left out."""
    ticks = np.arange(path.start_s + FIRST_TICK_S, path.end_s + 1e-9, TICK_S)
    rows = sorted(rows, key=lambda p: p["t"])
    idx = np.searchsorted([p["t"] for p in rows], ticks + 1e-9, side="right") - 1
    truth = path.at(ticks)
    inside = []
    for k in np.flatnonzero(idx >= 0):
        p = rows[idx[k]]
        e = np.array([p["x"], p["y"]]) - truth[k]
        cov = np.array(p["cov"], float)[:2, :2]
        inside.append(bool(np.linalg.det(cov) > 0 and e @ np.linalg.solve(cov, e) <= ELLIPSE_95))
    return np.array(inside, bool)


def coverage(runs: Sequence[tuple[Path, Path]], located: Sequence[Sequence[dict[str, Any]]]) -> dict[str, object]:
    """The fraction of ticks whose truth lies inside the position's 95 % ellipse (want 0.90-0.98),
    pooled and per run, and the positions' median sigma (sqrt of the x-y covariance's mean diagonal)."""
    per_run = [inside_95(load_waypoints(truth), rows) for (_, truth), rows in zip(runs, located)]
    sigmas = [math.sqrt(max(0.0, (p["cov"][0][0] + p["cov"][1][1]) / 2)) for rows in located for p in rows]
    return {"coverage95": round(float(np.mean(np.concatenate(per_run))), 3),
            "coverage95_runs": {c.stem: round(float(np.mean(i)), 3) for (c, _), i in zip(runs, per_run)},
            "sigma_median_m": round(float(np.median(sigmas)), 3) if sigmas else None}


def self_calibrated(site: Path, captures: Sequence[Path], into: Path) -> tuple[Path, str]:
    """A copy of ``site`` in ``into`` self-calibrated on ``captures`` (unchanged where calibrate
    refuses, as a user's site file would be), and calibrate's verdict line."""
    copy = into / "site.toml"
    shutil.copy(site, copy)
    sources = [arg for c in captures for arg in ("--from", f"capture:{c}")]
    done = subprocess.run([*RFHOMING, "calibrate", str(copy), "--self", *sources],
                          capture_output=True, text=True, check=False)
    lines = [ln for ln in (done.stdout + done.stderr).splitlines() if ln.strip()]
    if done.returncode:  # refused (the walks do not determine it): the user keeps the uncalibrated site
        return copy, "refused: " + (lines[-1] if lines else f"exit {done.returncode}")
    summary = [json.loads(ln) for ln in done.stdout.splitlines() if ln.startswith('{"kind": "self_calibration"')]
    return copy, (summary[-1]["verdict"] if summary else lines[-1] if lines else "")


def summary(errors: np.ndarray) -> dict[str, float]:
    return {"mean_m": round(float(np.mean(errors)), 3), "median_m": round(float(np.median(errors)), 3),
            "p95_m": round(float(np.percentile(errors, 95)), 3), "ticks": int(len(errors))}


def score_case(site: Path, runs: Sequence[tuple[Path, Path]], extra: Sequence[str], jobs: int) -> dict[str, object]:
    with ThreadPoolExecutor(jobs) as pool:
        located = list(pool.map(lambda run: positions(site, run[0], extra), runs))
    per_run = [score(load_waypoints(truth), [(p["t"], p["x"], p["y"]) for p in rows])
               for (_, truth), rows in zip(runs, located)]
    return {**summary(np.concatenate(per_run)), "runs": {c.stem: round(float(np.mean(e)), 3)
                                                         for (c, _), e in zip(runs, per_run)},
            **coverage(runs, located)}


def angle_figures(site_path: Path, runs: Sequence[tuple[Path, Path]], model: str = "spherical") -> dict[str, object]:
    """The residual statistics of every anchor, pooled over ``runs``, and of all anchors together,
    in the angle ``model`` (spherical by default: the issue's figures; the site's default is cone)."""
    from dataclasses import replace

    site = sites.load(site_path)
    site = replace(site, anchors=tuple(replace(a, angle_model=model) for a in site.anchors))
    groups = []
    for capture, truth in runs:
        events = [bearing_of(got.t, got.item) for got in rfhoming.read(f"capture:{capture}", kinds={"angle"})]
        groups.append(residuals(site, events, load_waypoints(truth)))
    out: dict[str, object] = {"all": angle_stats(groups).as_dict()}
    for anchor in site.anchors:
        out[anchor.name] = angle_stats(groups, [anchor.name]).as_dict()
    return out


CV_STEPS: dict[str, list[float]] = {
    "accel_psd": [0.02, 0.05, 0.2], "white_deg": [6.0, 8.0, 10.0], "slow_deg": [3.0, 4.5, 6.0],
    "slow_s": [1.0, 2.0, 4.0], "el_slow_deg": [3.0, 5.0, 8.0], "dof": [2.0, 4.0, 8.0],
    "az_compression": [0.1, 0.2, 0.3]}
"""The settings the cross-validation searches, one at a time, each over these values."""

CV_ROUNDS = 1
"""Passes over CV_STEPS (one: each setting moved once, from the defaults; ~25 scorings a fold)."""


def cross_validate(site_path: Path, cases: dict[str, list[tuple[Path, Path]]]) -> dict[str, object]:
    """Per use case: the settings a coordinate search on it alone picks, its score there, and
    the score of those settings on each other use case (held out); and the defaults' scores."""
    from dataclasses import fields, replace

    from rfhoming.host.estimation.angle_tracker import AngleNoise
    from rfhoming.host.locate import ACCEL_PSD, Locator

    site = sites.load(site_path)
    events = {c: [bearing_of(got.t, got.item) for got in rfhoming.read(f"capture:{c}", kinds={"angle"})]
              for runs in cases.values() for c, _ in runs}
    noise_keys = {f.name for f in fields(AngleNoise)}
    defaults = {k: float(getattr(AngleNoise(), k)) for k in CV_STEPS if k in noise_keys}
    defaults |= {"accel_psd": ACCEL_PSD["angles"], "az_compression": site.az_compression}
    cache: dict[tuple[tuple[tuple[str, float], ...], str], float] = {}

    def mean_error(setting: dict[str, float], uc: str) -> float:
        key = (tuple(sorted(setting.items())), uc)
        if key not in cache:
            noise = AngleNoise(**{k: v for k, v in setting.items() if k in noise_keys})
            s = replace(site, az_compression=setting["az_compression"])
            errors = []
            for capture, truth in cases[uc]:
                loc = Locator(s, noise=noise, accel_psd=setting["accel_psd"])
                out = [p for e in events[capture] for p in loc.feed(e)] + loc.flush()
                errors.append(score(load_waypoints(truth), [(p.t, float(p.point[0]), float(p.point[1])) for p in out]))
            cache[key] = float(np.mean(np.concatenate(errors)))
            print(f"[cv] {uc} {json.dumps(setting)}: {cache[key]:.3f} m", file=sys.stderr, flush=True)
        return cache[key]

    folds = {}
    for train in cases:
        best, best_score = dict(defaults), mean_error(defaults, train)
        for _ in range(CV_ROUNDS):  # rounds of one-setting-at-a-time moves, until none helps
            moved = False
            for key, values in CV_STEPS.items():
                for value in values:
                    trial = best | {key: value}
                    got = mean_error(trial, train)
                    if got < best_score - 1e-4:
                        best, best_score, moved = trial, got, True
            if not moved:
                break
        folds[train] = {"chosen": best, "train_mean_m": round(best_score, 3),
                        "held_out_mean_m": {uc: round(mean_error(best, uc), 3) for uc in cases if uc != train}}
    return {"defaults": defaults, "defaults_mean_m": {uc: round(mean_error(defaults, uc), 3) for uc in cases},
            "folds": folds}


_KIND_WALKS: dict[str, list[tuple[list[tuple[float, object]], object]]] = {}
"""cross_kind's walks by kind (events, waypoints), set before its worker processes fork."""


def _kind_error(site: sites.Site, setting: dict[str, float], kind: str) -> float:
    """locate's mean error on one kind's walks with ``setting`` (in-process, the data set's rule)."""
    from dataclasses import fields, replace

    from rfhoming.host.estimation.angle_tracker import AngleNoise
    from rfhoming.host.locate import Locator

    noise_keys = {f.name for f in fields(AngleNoise)}
    noise = AngleNoise(**{k: v for k, v in setting.items() if k in noise_keys})
    s = replace(site, az_compression=setting["az_compression"])
    errors = []
    for events, truth in _KIND_WALKS[kind]:
        loc = Locator(s, noise=noise, accel_psd=setting["accel_psd"])
        out = [p for t, e in events for p in loc.feed(t, e)] + loc.flush()  # type: ignore[arg-type]
        errors.append(score(truth, [(p.t, float(p.point[0]), float(p.point[1])) for p in out]))  # type: ignore[arg-type]
    got = float(np.mean(np.concatenate(errors)))
    print(f"[kinds] {kind} {json.dumps(setting)}: {got:.3f} m", file=sys.stderr, flush=True)
    return got


def cross_kind(site_path: Path, kinds: dict[str, list[tuple[Path, Path]]], jobs: int = 2) -> dict[str, object]:
    """Settings chosen on one kind of walk (or a mix), judged on the others (the 2026-12 field report). Every
    candidate -- the defaults, and each one-setting move of CV_STEPS from them -- is scored once
    on every kind (``jobs`` processes); a training set (each kind alone, and each mix that
    leaves one kind out) picks the candidate with the least mean of its kinds' mean errors (each
    kind weighing alike), and that choice is read off on every kind. One table serves every fold."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from rfhoming.host.estimation.angle_tracker import AngleNoise
    from rfhoming.host.locate import ACCEL_PSD

    site = sites.load(site_path)
    for kind, runs in kinds.items():
        _KIND_WALKS[kind] = [([(got.t, got.item) for got in rfhoming.read(f"capture:{c}", kinds={"angle"})],
                              load_waypoints(t)) for c, t in runs]
    defaults = {k: float(getattr(AngleNoise(), k)) for k in CV_STEPS if hasattr(AngleNoise(), k)}
    defaults |= {"accel_psd": ACCEL_PSD["angles"], "az_compression": site.az_compression}
    candidates = [{}] + [{k: v} for k, values in CV_STEPS.items() for v in values if v != defaults[k]]
    names = list(kinds)
    jobs_list = [(defaults | moved, k) for moved in candidates for k in names]
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("fork")) as pool:  # the walks, shared
        scores = list(pool.map(_kind_error, [site] * len(jobs_list), *zip(*jobs_list)))
    table = [dict(zip(names, scores[i * len(names):(i + 1) * len(names)])) for i in range(len(candidates))]
    trainings = [[k] for k in names] + ([[k for k in names if k != out] for out in names] if len(names) > 2 else [])
    folds = {}
    for train in trainings:
        best = min(range(len(candidates)), key=lambda i: float(np.mean([table[i][k] for k in train])))
        folds["+".join(train)] = {"chosen": candidates[best],
                                  "judged_m": {k: round(table[best][k], 3) for k in names}}
    return {"kinds": {k: len(v) for k, v in kinds.items()}, "defaults": defaults,
            "defaults_m": {k: round(table[0][k], 3) for k in names}, "folds": folds,
            "candidates": [{"moved": c, "m": {k: round(v, 3) for k, v in row.items()}}
                           for c, row in zip(candidates, table)]}


def print_cross_kind(table: dict[str, object]) -> None:
    """Cross-kind folds as a Markdown table: each row a training set, each column a kind."""
    names = list(table["kinds"])  # type: ignore[call-overload]
    print("cross-kind folds: the setting chosen on the row's kinds (the best of the defaults and each one-setting "
          "move), its mean error on each kind\n")
    print("| chosen on | moved from the defaults | " + " | ".join(names) + " |\n|---|---|" + "---|" * len(names))
    defaults = table["defaults_m"]  # type: ignore[index]
    print("| (the defaults) | - | " + " | ".join(f"{defaults[k]:.3f} m" for k in names) + " |")
    for train, fold in table["folds"].items():  # type: ignore[attr-defined]
        cells = [f"{fold['judged_m'][k]:.3f} m" + ("" if k in train.split("+") else " (held out)") for k in names]
        print(f"| {train} | {json.dumps(fold['chosen'])} | " + " | ".join(cells) + " |")
    print()


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="a folder laid out as girolami_xplr_aoa/")
    ap.add_argument("--self-cal", action="store_true", help="also: self-calibrate on the other use cases, then locate")
    ap.add_argument("--locate", default="", metavar="ARGS", help="extra arguments for every rfhoming locate")
    ap.add_argument("--jobs", type=int, default=2, help="locate processes at once (default 2)")
    ap.add_argument("--cv", action="store_true", help="also: the cross-validation of the angles tracker's defaults")
    ap.add_argument("--kinds", type=Path, metavar="FOLDER", help="also: cross-kind folds over DIR's use cases and "
                    "the walks in FOLDER (captures and waypoint files, e.g. bench/carried_walks.py --keep FOLDER: "
                    "emulated carried walks of the same room), as one more kind named by their prefix")
    ap.add_argument("--angle-model", choices=("spherical", "cone"), default="spherical",
                    help="the angle table's reading of the reports (default spherical: the reading the data set's figures were measured in)")
    ap.add_argument("--json", action="store_true", help="one JSON object instead of tables")
    args = ap.parse_args(argv)
    data = args.data
    cases = recordings(data)
    extra = shlex.split(args.locate)
    site = data / "site.toml"
    result: dict[str, object] = {"data": str(data), "locate_args": extra, "load_before": os.getloadavg()[0]}
    result["default"] = {uc: score_case(site, runs, extra, args.jobs) for uc, runs in cases.items()}
    if args.self_cal:
        calibrated = {}
        for uc, runs in cases.items():
            others = [c for other, rs in cases.items() if other != uc for c, _ in rs]
            with tempfile.TemporaryDirectory(prefix="rfhoming-real-aoa-") as tmp:
                cal_site, verdict = self_calibrated(site, others, Path(tmp))
                calibrated[uc] = {**score_case(cal_site, runs, extra, args.jobs), "calibrated_on":
                                  sorted({c.stem.rsplit("_run", 1)[0] for c in others}), "verdict": verdict}
        result["self_calibrated"] = calibrated
    if args.cv:
        result["cross_validation"] = cross_validate(site, cases)
    if args.kinds:
        result["cross_kind"] = cross_kind(site, {**cases, **other_kinds(args.kinds)}, args.jobs)
    result["angles"] = {uc: angle_figures(site, runs, args.angle_model) for uc, runs in cases.items()}
    result["angles"]["all"] = angle_figures(site, [r for runs in cases.values() for r in runs],  # type: ignore[index]
                                            args.angle_model)
    result["load_after"] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print_tables(result)
    return 0


def other_kinds(folder: Path) -> dict[str, list[tuple[Path, Path]]]:
    """Walks of other kinds in ``folder``: each ``KIND_runR.pcapng`` with its ``KIND_runR.csv``."""
    found: dict[str, list[tuple[Path, Path]]] = {}
    for capture in sorted(folder.glob("*_run*.pcapng")):
        truth = capture.with_suffix(".csv")
        if not truth.exists():
            raise SystemExit(f"real_aoa: {capture} has no waypoint file {truth}")
        found.setdefault(capture.stem.rsplit("_run", 1)[0], []).append((capture, truth))
    if not found:
        raise SystemExit(f"real_aoa: --kinds {folder} holds no KIND_runR.pcapng with its KIND_runR.csv")
    return found


def print_tables(result: dict[str, object]) -> None:
    if "cross_kind" in result:
        print_cross_kind(result["cross_kind"])  # type: ignore[arg-type]
    if "cross_validation" in result:
        cv = result["cross_validation"]
        print(f"cross-validation: the defaults {json.dumps(cv['defaults'])} score {json.dumps(cv['defaults_mean_m'])}")  # type: ignore[index]
        for train, fold in cv["folds"].items():  # type: ignore[index]
            print(f"  tuned on {train}: {json.dumps(fold['chosen'])}, {fold['train_mean_m']:.3f} m there; held out: "
                  f"{json.dumps(fold['held_out_mean_m'])}")
        print()
    rows = [("default", result["default"])] + ([("self-calibrated on the other use cases", result["self_calibrated"])]
                                               if "self_calibrated" in result else [])
    print("| pipeline | use case | mean | median | p95 | ticks |\n|---|---|---|---|---|---|")
    for name, table in rows:
        for uc, s in table.items():  # type: ignore[attr-defined]
            print(f"| {name} | {uc} | {s['mean_m']:.3f} m | {s['median_m']:.3f} m | {s['p95_m']:.3f} m | {s['ticks']} |")
    print_coverage(rows)
    print("\nAngle residuals against the ground truth (degrees; tails: fraction beyond 20 deg; "
          "acf: autocorrelation time, s; missing: worst recording's fraction)\n")
    print("| use case | anchor | az bias | az std | az 1.4826 MAD | az tail | el bias | el std | el tail "
          "| compression 45-60 / 60-90 | acf s | missing |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    for uc, per in result["angles"].items():  # type: ignore[attr-defined]
        for anchor, s in per.items():
            c = s["compression"]
            print(f"| {uc} | {anchor} | {s['az_bias']:+.1f} | {s['az_std']:.1f} | {s['az_mad_sigma']:.1f} "
                  f"| {100 * s['az_tail']:.1f} % | {s['el_bias']:+.1f} | {s['el_std']:.1f} | {100 * s['el_tail']:.1f} % "
                  f"| {c.get('45-60', float('nan')):+.1f} / {c.get('60-90', float('nan')):+.1f} "
                  f"| {s['corr_time_s']:.2f} | {100 * s['missing']:.1f} % |")


def print_coverage(rows: Sequence[tuple[str, object]]) -> None:
    """The 95 % ellipses' coverage of the truth, per pipeline and use case (want 0.90-0.98)."""
    print("\n| pipeline | use case | truth inside the 95 % ellipse | median sigma |\n|---|---|---|---|")
    for name, table in rows:
        for uc, s in table.items():  # type: ignore[attr-defined]
            print(f"| {name} | {uc} | {100 * s['coverage95']:.1f} % of ticks | {s['sigma_median_m']:.3f} m |")


if __name__ == "__main__":
    sys.exit(main())
