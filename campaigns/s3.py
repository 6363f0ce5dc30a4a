"""S3 (2025): RSSI filters on Table I's noise profile, and trilateration vs multilateration
with four corner beacons at S3's nine test points, (−2.5, 0, 2.5 m)².

RSSI at a distance is drawn from S3's own measurements (Table I: mean and std per distance,
linearly interpolated between the tabulated distances; ESP32 RSSI is an integer; beyond 5 m the
mean continues on a log-distance curve with n = 2.7 and the std stays at 5 m's). Each beacon
link also carries a bias drawn once per fix (σ ``LINK_SIGMA_DB``; S3 gives none, the real
recordings show 3–6 dB). Filters run in the host's fixed point (Q8.8 dBm): running median of
5, EMA (α = 1/8), scalar Kalman (q = 0.05, r = 16 dB², the [trilat] defaults). Ranges come from
S3's own exponential fit, d = 0.0165 e^(−0.0662 RSSI) (the model S3 chose over n = 2.7).

S3 reports one measurement per test point; here every fix is one measurement (5 s of
Kalman-filtered RSSI per beacon), repeated ``runs`` times per point to give its spread. The
arena's size is not given: the beacons sit at the corners of a 6 m and of a 7 m square (the
test points must lie inside), and both are shown.

Under ``--radio measured|PROFILE`` (campaigns/rssi_draws.py) the readings keep Table I's mean
but the noise about it is the profile's BLE receivers' (S3's ESP32 scanners hear BLE beacons:
``[rssi.ble]``), in place of Table I's std and the per-fix bias: each beacon link's exponent
(about Table I's mean, turned with S3's n = 2.7) and offset, the shadowing at where beacon and
receiver stand, the correlated residual and white noise at 10 Hz, and the readings lost (a
filter sees only the readings it got). Every fix draws its own links from its job's seed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from rfhoming.campaigns import rssi_draws
from rfhoming.campaigns.report import figure, save, table
from rfhoming.campaigns.runner import Campaign, Job, Report
from rfhoming.host.estimation.bearings import Degenerate
from rfhoming.host.estimation.filters import ema_batch, kalman_batch, running_median_batch
from rfhoming.host.estimation.lateration import multilaterate, strongest_three, trilaterate
from rfhoming.host.estimation.ranging import Exponential, LogDistance
from rfhoming.protocol.radio_profile import IDEAL

TABLE1_D = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0])
TABLE1_MEAN = np.array([-17.04, -44.80, -64.30, -69.48, -75.62, -76.92, -79.44, -79.60, -83.84, -79.45, -87.23])
TABLE1_STD = np.array([0.21, 3.13, 4.36, 6.66, 1.58, 3.39, 3.20, 2.10, 4.67, 5.38, 7.01])
PAPER_KALMAN_STD = (0.017, 1.092)  # after filtering, dB (range over the distances)
PAPER_ERROR_CM = {"trilateration": (0, 216), "multilateration": (54, 361)}  # over 9 test points
ARENAS = {"6 m": 3.0, "7 m": 3.5}  # beacons at (±h, ±h)
POINTS = [(x, y) for y in (2.5, 0.0, -2.5) for x in (-2.5, 0.0, 2.5)]
PAPER_POINT_CM = {  # S3 Tables II and III: one measurement per point
    (0.0, 0.0): (0, 281.68), (2.5, 2.5): (25.50, 75.56), (-2.5, 2.5): (63.38, 53.85), (-2.5, -2.5): (41.16, 361.46),
    (2.5, -2.5): (216.08, 129.95), (0.0, 2.5): (105.06, 179.65), (-2.5, 0.0): (59.98, 107.88),
    (0.0, -2.5): (141.20, 210.43), (2.5, 0.0): (116.70, 89.49)}
RANGING = Exponential(0.0165, -0.0662)  # S3's fit
BEYOND_TABLE = LogDistance(-64.3, 2.7, 1.0)  # the simulated radio beyond Table I's 5 m
LINK_SIGMA_DB = 3.0
SAMPLES = 500  # per distance, as in Table I
FIX_SAMPLES = 50  # RSSI samples per beacon behind one position fix (5 s at 10 Hz)
READ_S = 0.1  # between readings (10 Hz): the measured residual and losses run in time
PAPER_RADIO = "ble"  # S3's receivers: ESP32 BLE scanners hearing BLE beacons ([rssi.ble] of a profile)
IDEAL_NOISE = ("ideal: Table I's std per distance (integer dBm) and a per-beacon bias σ 3 dB drawn once per fix "
               "(the paper's noise)")


def mean_at(distance: np.ndarray) -> np.ndarray:
    """Table I's mean at each distance (beyond 5 m continued by the fit)."""
    d = np.asarray(distance, float)
    return np.asarray(np.where(d <= 5.0, np.interp(d, TABLE1_D, TABLE1_MEAN), BEYOND_TABLE.rssi(np.maximum(d, 1e-3))),
                      float)


def rssi_at(distance: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, len(distance)) integer RSSI with Table I's mean and std at each distance (beyond 5 m
    the last std, the mean continued by the fit)."""
    d = np.asarray(distance, float)
    std = np.interp(np.minimum(d, 5.0), TABLE1_D, TABLE1_STD)
    return np.asarray(np.round(mean_at(d) + std * rng.standard_normal((n, len(d)))), float)


def measured_rssi(ends: np.ndarray, n: int, radio: rssi_draws.Radio, rng: np.random.Generator
                  ) -> list[np.ndarray]:
    """Each link's integer RSSI over ``n`` readings ``READ_S`` apart under a measured radio,
    the lost readings left out. ``ends``: (links, 4), beacon x, y and receiver x, y; the mean
    is Table I's at their distance."""
    ch = rssi_draws.channel(radio, BEYOND_TABLE.n, rng)
    out = []
    for i, (bx, by, rx, ry) in enumerate(np.asarray(ends, float)):
        link, d = (f"beacon{i}", "receiver"), math.hypot(bx - rx, by - ry)
        mean = float(mean_at(np.array([d]))[0])
        got = [round(ch.sample(link, mean, t=k * READ_S, ends=((bx, by), (rx, ry)), distance_m=d))
               for k in range(n) if not ch.lost(link, k * READ_S)]
        out.append(np.array(got, float))
    return out


def _kalman_last(raw: np.ndarray) -> float:
    return float(kalman_batch((raw.reshape(-1, 1) * 256).astype(np.int64), 0.05, 16.0)[-1, 0] / 256)


def _filtered(raw: np.ndarray) -> dict[str, np.ndarray]:
    q8 = (raw * 256).astype(np.int64)
    return {"raw": raw, "median": running_median_batch(q8, 5) / 256, "ema": ema_batch(q8, 3) / 256,
            "kalman": kalman_batch(q8, 0.05, 16.0) / 256}


def filters_run(seed: int, radio: str = IDEAL) -> dict[str, Any]:
    """Each filter's output std per Table I distance, after a 20-sample settling (under a
    measured radio: one beacon at each distance, the readings it got of 500 at 10 Hz)."""
    rng = np.random.default_rng(seed)
    measured = rssi_draws.rssi_radio(radio, PAPER_RADIO)
    if measured is None:
        out = _filtered(rssi_at(TABLE1_D, SAMPLES, rng))
        return {"kind": "filters", **{k: np.round(v[20:].std(axis=0), 4).tolist() for k, v in out.items()}}
    ends = np.column_stack([TABLE1_D, np.zeros((len(TABLE1_D), 3))])
    columns = [_filtered(raw.reshape(-1, 1)) for raw in measured_rssi(ends, SAMPLES, measured, rng)]
    return {"kind": "filters", **{k: [round(float(c[k][20:].std()), 4) for c in columns] for k in FILTERS},
            "radios": measured.describe(PAPER_RADIO)}


def anchors(arena: str) -> np.ndarray:
    h = ARENAS[arena]
    return np.array([[-h, -h], [h, -h], [h, h], [-h, h]])


def point_run(point: int, seed: int, arena: str = "6 m", radio: str = IDEAL) -> dict[str, Any]:
    """One fix at test point ``point``: Kalman-filtered RSSI per beacon -> ranges -> both methods
    (on the beacons heard: under a measured radio a beacon may miss every reading)."""
    rng = np.random.default_rng(seed)
    truth = np.array(POINTS[point])
    ANCHORS = anchors(arena)
    d = np.linalg.norm(ANCHORS - truth, axis=1)
    measured = rssi_draws.rssi_radio(radio, PAPER_RADIO)
    row: dict[str, Any] = {"kind": "fix", "point": point, "arena": arena}
    if measured is None:
        raw = rssi_at(d, FIX_SAMPLES, rng) + np.round(rng.normal(0, LINK_SIGMA_DB, len(d)))
        rssi = kalman_batch((raw * 256).astype(np.int64), 0.05, 16.0)[-1] / 256
    else:
        ends = np.column_stack([ANCHORS, np.broadcast_to(truth, ANCHORS.shape)])
        rssi = np.array([_kalman_last(r) if len(r) else np.nan for r in measured_rssi(ends, FIX_SAMPLES, measured, rng)])
        row["radios"] = measured.describe(PAPER_RADIO)
    heard = np.flatnonzero(~np.isnan(rssi))  # what the receiver measured: nothing else
    beacons, rssi = ANCHORS[heard], rssi[heard]
    ranges = np.asarray(RANGING.distance(rssi), float)
    try:
        if len(heard) < 3:
            raise Degenerate("fewer than three beacons heard")
        top = strongest_three(rssi)
        row["trilateration_m"] = round(float(np.linalg.norm(trilaterate(beacons[top], ranges[top]) - truth)), 4)
    except Degenerate:
        row["trilateration_m"] = None
    try:
        row["multilateration_m"] = round(float(np.linalg.norm(multilaterate(beacons, ranges) - truth)), 4)
    except Degenerate:
        row["multilateration_m"] = None
    return row


def jobs(runs: int, seed: int) -> list[Job]:
    out = [Job(0, "rfhoming.campaigns.s3:filters_run", {"seed": seed})]
    for arena in ARENAS:
        for p in range(len(POINTS)):
            for k in range(runs):
                out.append(Job(len(out), "rfhoming.campaigns.s3:point_run",
                               {"point": p, "seed": seed * 100_000 + p * 10_000 + k, "arena": arena}))
    return out


FILTERS = ("raw", "median", "ema", "kalman")
METHODS = ("trilateration", "multilateration")


def report(rows: list[dict[str, Any]]) -> Report:
    filt = next(r for r in rows if r["kind"] == "filters")
    radios = rssi_draws.radios_line(filt.get("radios"), IDEAL_NOISE, "S3's BLE receivers", "Table I's mean",
                                    "Table I's std and the per-fix bias")
    md = radios + "\n\n" + _filters_section(filt)
    fixes = [r for r in rows if r["kind"] == "fix"]
    summary: dict[str, Any] = {"radios": filt.get("radios", {"radio": IDEAL, "noise": IDEAL_NOISE}),
                               "filters_std_db": {n: filt[n] for n in FILTERS}, "arenas": {}}
    for arena in ARENAS:
        entries = [_point_entry(fixes, p, xy, arena) for p, xy in enumerate(POINTS)]
        summary["arenas"][arena] = _arena_summary(entries)
        md += _arena_section(arena, entries)
    paper_wins = sum(1 for t, m in PAPER_POINT_CM.values() if t < m)
    md += _comparison_table(summary, paper_wins)
    summary["paper_trilateration_better_at"] = paper_wins
    return Report(summary, md, lambda path: _plot(path, filt, summary))


def _filters_section(filt: dict[str, Any]) -> str:
    """Table I's RSSI spread at each distance after each filter, beside the paper's."""
    lines = [[f"{d:g}", TABLE1_STD[i], *(filt[n][i] for n in FILTERS)] for i, d in enumerate(TABLE1_D)]
    md = ("RSSI std (dB) at each Table I distance, 500 samples, after each filter:\n\n" if "radios" not in filt else
          "RSSI std (dB) at each Table I distance (one beacon link each, standing), 500 readings at 10 Hz less the lost "
          "ones, after each filter:\n\n")
    md += table(["distance m", "paper raw std", "ours raw", "median(5)", "EMA 1/8", "Kalman"], lines)
    md += (f"\n\nPaper: Kalman-filtered std {PAPER_KALMAN_STD[0]}–{PAPER_KALMAN_STD[1]} dB; ours "
           f"{min(filt['kalman']):.3f}–{max(filt['kalman']):.3f} dB.\n\n")
    return md


def _point_entry(fixes: list[dict[str, Any]], p: int, xy: tuple[float, float], arena: Any) -> dict[str, Any]:
    """One test point of one arena: its fixes, and each method's error percentiles (cm)."""
    rs = [r for r in fixes if r["point"] == p and r["arena"] == arena]
    entry: dict[str, Any] = {"point": xy, "fixes": len(rs)}
    for m in METHODS:
        v = 100 * np.array([r[f"{m}_m"] for r in rs if r[f"{m}_m"] is not None])
        entry[m] = {"median_cm": round(float(np.median(v)), 1), "p10_cm": round(float(np.percentile(v, 10)), 1),
                    "p90_cm": round(float(np.percentile(v, 90)), 1)} if len(v) else None
    return entry


def _arena_summary(entries: list[dict[str, Any]]) -> dict[str, Any]:
    """Per method the range and mean of the points' medians, and where trilateration wins."""
    wins = sum(1 for e in entries if e["trilateration"] and e["multilateration"]
               and e["trilateration"]["median_cm"] < e["multilateration"]["median_cm"])
    medians = {m: [e[m]["median_cm"] for e in entries if e[m]] for m in METHODS}
    return {"points": entries, "trilateration_better_at": wins,
            **{m: {"min_cm": min(medians[m]), "max_cm": max(medians[m]),
                   "mean_cm": round(float(np.mean(medians[m])), 1)} for m in METHODS}}


def _spread(e: dict[str, Any] | None) -> str | None:
    return f"{e['median_cm']} ({e['p10_cm']}–{e['p90_cm']})" if e else None


def _arena_section(arena: Any, entries: list[dict[str, Any]]) -> str:
    """The arena's table: each test point's error, ours beside the paper's."""
    plines = []
    for entry in entries:
        xy = entry["point"]
        paper = PAPER_POINT_CM[xy]
        plines.append([f"({xy[0]:g}, {xy[1]:g})", entry["fixes"], paper[0], _spread(entry["trilateration"]),
                       paper[1], _spread(entry["multilateration"])])
    md = (f"Arena {arena} (beacons at its corners): position error (cm) per test point, one fix = 5 s of "
          f"Kalman-filtered RSSI per beacon; ours: median (10th–90th percentile) over the fixes:\n\n")
    md += table(["point m", "fixes", "paper trilateration", "ours trilateration (3 strongest)",
                 "paper multilateration", "ours multilateration (all 4)"], plines)
    return md + "\n\n"


def _comparison_table(summary: dict[str, Any], paper_wins: int) -> str:
    """The paper's error ranges and ours per arena, and where trilateration was better."""
    return table(["source", "trilateration range over points cm", "multilateration range cm",
                  "points where trilateration is better"],
                 [["paper (one measurement per point)", "–".join(map(str, PAPER_ERROR_CM["trilateration"])),
                   "–".join(map(str, PAPER_ERROR_CM["multilateration"])), f"{paper_wins}/9"]]
                 + [[f"ours, arena {a} (medians per point)",
                     f"{summary['arenas'][a]['trilateration']['min_cm']}–{summary['arenas'][a]['trilateration']['max_cm']}",
                     f"{summary['arenas'][a]['multilateration']['min_cm']}–{summary['arenas'][a]['multilateration']['max_cm']}",
                     f"{summary['arenas'][a]['trilateration_better_at']}/9"] for a in ARENAS])


def _plot(path: Path, filt: dict[str, Any], summary: dict[str, Any]) -> None:
    fig, axes = figure(path, 2)
    for n in FILTERS:
        axes[0].plot(TABLE1_D, filt[n], marker="o", label=n)
    axes[0].set_xlabel("distance (m)")
    axes[0].set_title("RSSI std after filtering (dB)")
    axes[0].legend()
    x = np.arange(len(POINTS))
    first = summary["arenas"][next(iter(ARENAS))]["points"]
    for i, m in enumerate(("trilateration", "multilateration")):
        axes[1].bar(x + (i - 0.5) * 0.4, [e[m]["median_cm"] if e[m] else np.nan for e in first], 0.4, label=f"ours {m}")
        axes[1].plot(x, [PAPER_POINT_CM[p][i] for p in POINTS], "o" if i == 0 else "s", color="k",
                     label=f"paper {m}", mfc="none" if i else "k")
    axes[1].set_xticks(x, [f"{p[0]:g},{p[1]:g}" for p in POINTS], rotation=45)
    axes[1].set_title(f"error per test point, arena {next(iter(ARENAS))} (cm)")
    axes[1].legend(fontsize=7)
    save(fig, path)


CAMPAIGN = Campaign("s3-arena", "S3: RSSI filters on Table I's noise; trilateration vs multilateration",
                    "fixes per test point (in each arena size)", 100, jobs, report)
