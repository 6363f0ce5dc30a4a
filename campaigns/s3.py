"""S3 (2025): RSSI filters on Table I's noise profile, and trilateration vs multilateration on
the 5 × 5 m arena with four corner beacons.

RSSI at a distance is drawn from S3's own measurements (Table I: mean and std per distance,
linearly interpolated between the tabulated distances; ESP32 RSSI is an integer). Filters run
in the host's fixed point (Q8.8 dBm): running median of 5, EMA (α = 1/8), scalar Kalman
(q = 0.05, r = 16 dB², the [trilat] defaults). Ranges come from the paper's log-distance fit
(RSSI(1 m) = −64.3 dBm, n = 2.7).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rfhoming.campaigns.report import figure, save, table
from rfhoming.campaigns.runner import Campaign, Job, Report
from rfhoming.host.estimation.bearings import Degenerate
from rfhoming.host.estimation.filters import ema_batch, kalman_batch, running_median_batch
from rfhoming.host.estimation.lateration import multilaterate, strongest_three, trilaterate
from rfhoming.host.estimation.ranging import LogDistance

TABLE1_D = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0])
TABLE1_MEAN = np.array([-17.04, -44.80, -64.30, -69.48, -75.62, -76.92, -79.44, -79.60, -83.84, -79.45, -87.23])
TABLE1_STD = np.array([0.21, 3.13, 4.36, 6.66, 1.58, 3.39, 3.20, 2.10, 4.67, 5.38, 7.01])
PAPER_KALMAN_STD = (0.017, 1.092)  # after filtering, dB (range over the distances)
PAPER_ERROR_CM = {"trilateration": (0, 216), "multilateration": (54, 361)}  # over 9 test points
ANCHORS = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0]])
POINTS = [(x, y) for y in (1.25, 2.5, 3.75) for x in (1.25, 2.5, 3.75)]
RANGING = LogDistance(-64.3, 2.7, 1.0)
SAMPLES = 500  # per distance, as in Table I
FIX_SAMPLES = 50  # RSSI samples per beacon behind one position fix (5 s at 10 Hz)


def rssi_at(distance: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, len(distance)) integer RSSI with Table I's mean and std at each distance (beyond 5 m
    the last std, the mean continued by the fit)."""
    d = np.asarray(distance, float)
    mean = np.where(d <= 5.0, np.interp(d, TABLE1_D, TABLE1_MEAN), RANGING.rssi(np.maximum(d, 1e-3)))
    std = np.interp(np.minimum(d, 5.0), TABLE1_D, TABLE1_STD)
    return np.round(mean + std * rng.standard_normal((n, len(d))))


def filters_run(seed: int) -> dict[str, Any]:
    """Each filter's output std per Table I distance, after a 20-sample settling."""
    rng = np.random.default_rng(seed)
    raw = rssi_at(TABLE1_D, SAMPLES, rng)
    q8 = (raw * 256).astype(np.int64)
    out = {"raw": raw, "median": running_median_batch(q8, 5) / 256, "ema": ema_batch(q8, 3) / 256,
           "kalman": kalman_batch(q8, 0.05, 16.0) / 256}
    return {"kind": "filters", **{k: np.round(v[20:].std(axis=0), 4).tolist() for k, v in out.items()}}


def point_run(point: int, seed: int) -> dict[str, Any]:
    """One fix at test point ``point``: Kalman-filtered RSSI per beacon -> ranges -> both methods."""
    rng = np.random.default_rng(seed)
    truth = np.array(POINTS[point])
    d = np.linalg.norm(ANCHORS - truth, axis=1)
    raw = rssi_at(d, FIX_SAMPLES, rng)
    rssi = kalman_batch((raw * 256).astype(np.int64), 0.05, 16.0)[-1] / 256
    ranges = np.asarray(RANGING.distance(rssi), float)
    row: dict[str, Any] = {"kind": "fix", "point": point}
    try:
        top = strongest_three(rssi)
        row["trilateration_m"] = round(float(np.linalg.norm(trilaterate(ANCHORS[top], ranges[top]) - truth)), 4)
    except Degenerate:
        row["trilateration_m"] = None
    try:
        row["multilateration_m"] = round(float(np.linalg.norm(multilaterate(ANCHORS, ranges) - truth)), 4)
    except Degenerate:
        row["multilateration_m"] = None
    return row


def jobs(runs: int, seed: int) -> list[Job]:
    out = [Job(0, "rfhoming.campaigns.s3:filters_run", {"seed": seed})]
    for p in range(len(POINTS)):
        for k in range(runs):
            out.append(Job(len(out), "rfhoming.campaigns.s3:point_run", {"point": p, "seed": seed * 100_000 + p * 10_000 + k}))
    return out


def report(rows: list[dict[str, Any]]) -> Report:
    filt = next(r for r in rows if r["kind"] == "filters")
    names = ("raw", "median", "ema", "kalman")
    lines = [[f"{d:g}", TABLE1_STD[i], *(filt[n][i] for n in names)] for i, d in enumerate(TABLE1_D)]
    md = "RSSI std (dB) at each Table I distance, 500 samples, after each filter:\n\n"
    md += table(["distance m", "paper raw std", "ours raw", "median(5)", "EMA 1/8", "Kalman"], lines)
    md += (f"\n\nPaper: Kalman-filtered std {PAPER_KALMAN_STD[0]}–{PAPER_KALMAN_STD[1]} dB; ours "
           f"{min(filt['kalman']):.3f}–{max(filt['kalman']):.3f} dB.\n\n")
    fixes = [r for r in rows if r["kind"] == "fix"]
    summary: dict[str, Any] = {"filters_std_db": {n: filt[n] for n in names}, "points": []}
    plines = []
    for p, xy in enumerate(POINTS):
        rs = [r for r in fixes if r["point"] == p]
        t = [r["trilateration_m"] for r in rs if r["trilateration_m"] is not None]
        m = [r["multilateration_m"] for r in rs if r["multilateration_m"] is not None]
        entry = {"point": xy, "fixes": len(rs), "trilateration_cm": round(100 * float(np.mean(t)), 1) if t else None,
                 "multilateration_cm": round(100 * float(np.mean(m)), 1) if m else None}
        summary["points"].append(entry)
        plines.append([f"({xy[0]:g}, {xy[1]:g})", entry["fixes"], entry["trilateration_cm"], entry["multilateration_cm"]])
    for method in ("trilateration", "multilateration"):
        values = [e[f"{method}_cm"] for e in summary["points"] if e[f"{method}_cm"] is not None]
        summary[method] = {"min_cm": min(values), "max_cm": max(values), "mean_cm": round(float(np.mean(values)), 1)}
    md += "Mean position error (cm) per test point, Kalman-filtered RSSI over 5 s per beacon:\n\n"
    md += table(["point m", "fixes", "trilateration (3 strongest)", "multilateration (all 4)"], plines)
    md += "\n\n" + table(["method", "paper range cm", "ours range cm", "ours mean cm"],
                         [[m, "–".join(map(str, PAPER_ERROR_CM[m])),
                           f"{summary[m]['min_cm']}–{summary[m]['max_cm']}", summary[m]["mean_cm"]]
                          for m in PAPER_ERROR_CM])

    def plot(path):
        fig, axes = figure(path, 2)
        for n in names:
            axes[0].plot(TABLE1_D, filt[n], marker="o", label=n)
        axes[0].set_xlabel("distance (m)")
        axes[0].set_title("RSSI std after filtering (dB)")
        axes[0].legend()
        x = np.arange(len(POINTS))
        axes[1].bar(x - 0.2, [e["trilateration_cm"] for e in summary["points"]], 0.4, label="trilateration")
        axes[1].bar(x + 0.2, [e["multilateration_cm"] for e in summary["points"]], 0.4, label="multilateration")
        axes[1].set_xticks(x, [f"{p[0]:g},{p[1]:g}" for p in POINTS], rotation=45)
        axes[1].set_title("mean error per test point (cm)")
        axes[1].legend()
        save(fig, path)

    return Report(summary, md, {"s3-arena.png": plot})


CAMPAIGN = Campaign("s3-arena", "S3: RSSI filters on Table I's noise; trilateration vs multilateration",
                    "fixes per test point", 200, jobs, report)
