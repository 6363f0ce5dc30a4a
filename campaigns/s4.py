"""S4 (CTU thesis): the Monte-Carlo simulation of beacon localisation from RSSI on three moving
receivers, EKF and UKF, and a filterpy EKF of the same model on a subsample for speed.

The simulation (S4, docs/RESULTS.md "The seed papers' results, reproduced"): three receivers in a fixed formation (an L of 0.6 m sides,
centred on the path) fly a lawn-mower over the 4 × 8 m area (lanes 0.8 m apart, there and back) at
0.2 m/s for 320 s at 10 Hz; 10 beacons per flight, uniform in the area. Each step the guidance
commands u = (next path point − measured position); the true receivers move by u plus process
noise Q = 0.01 I, their positions are measured with R = 0.01 I. RSSI: P0 = −40.23 dBm, n = 2,
plus χ ~ N(μχ, 5) dB with μχ = ±2 dB drawn 50/50 once per beacon-receiver link (the thesis's
filter R = 9 dB² is that mixture's variance, 4 + 5); nothing is heard beyond 4 m. The filters are told Q = 0.05 I,
R = 0.05 I and 9 dB², and start from S4's circle-intersection initialiser (n_init = 30,
c_f = 3, c_w = 500).

Under ``--radio measured|PROFILE`` (campaigns/rssi_draws.py) the RSSI keeps the thesis's law
(P0, n = 2: what the filters are told) and the 4 m range, but the noise about it is the
profile's BLE receivers' (S4's receivers hear BLE beacons: ``[rssi.ble]``) in place of χ: each
beacon-receiver link's exponent and offset, the shadowing over where beacon and receiver are
(the same place, the same shadowing), the correlated residual and white noise at 10 Hz, and the
readings lost (NaN, as unheard). The flights and beacons are the ideal run's of the same seed.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from rfhoming.campaigns import rssi_draws
from rfhoming.campaigns.report import figure, save, table
from rfhoming.campaigns.runner import Campaign, Job, Report
from rfhoming.host.estimation.beacon import (BeaconEkf, BeaconUkf, CircleInitializer, S4Model, initial_state, jacobian,
                                             measure, refine_batch)
from rfhoming.protocol.radio_profile import IDEAL

PAPER = {"ekf": {"mean_m": 0.234, "p95_m": 0.65, "max_m": 2.0, "total_s": 868},
         "ukf": {"mean_m": 0.243, "p95_m": 0.65, "max_m": 2.0, "total_s": 1658}}
"""S4 over 10,000 beacons: means; "95 % < 0.65 m, max > 2 m"; MATLAB run times."""
BEACONS_PER_FLIGHT = 10
FLIGHTS_PER_JOB = 50
STEPS, DT, SPEED = 3200, 0.1, 0.2
FORMATION = np.array([[0.0, 0.0], [0.6, 0.0], [0.0, 0.6]]) - 0.2  # centred on the path
TRUE_Q, TRUE_R_POS, RSSI_VAR, BIAS_DB, R_MAX = 0.01, 0.01, 5.0, 2.0, 4.0
MODEL = S4Model()  # what the filters are told: Q 0.05, R 0.05 and 9 dB²
PAPER_RADIO = "ble"  # S4's receivers hear BLE beacons ([rssi.ble] of a profile)
IDEAL_NOISE = ("ideal: the thesis's χ ~ N(±2 dB per link, 5 dB²) about P0 −40.23 dBm, n 2 (the paper's noise)")


def lawnmower(steps: int = STEPS) -> np.ndarray:
    """The formation's reference point at each step: lanes x = 0, 0.8, … 4 from y = 0 to 8 and
    back along the same path (no jump at the end)."""
    corners = []
    for i, x in enumerate(np.arange(0.0, 4.01, 0.8)):
        ys = (0.0, 8.0) if i % 2 == 0 else (8.0, 0.0)
        corners += [(x, ys[0]), (x, ys[1])]
    pts = np.array(corners)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    s = SPEED * DT * np.arange(steps + 1)
    s = cum[-1] - np.abs(cum[-1] - s % (2 * cum[-1]))  # there and back
    return np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=1)


def flights(n: int, seed: int, radio: str = IDEAL) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Simulate ``n`` flights: measured receiver positions (S+1, n, 3, 2), commands (S, n, 3, 2),
    RSSI (S, n·10, 3) with NaN where unheard, true beacons (n·10, 2). Under a measured
    ``radio`` the same flights and beacons, the RSSI from its profile's table."""
    rng = np.random.default_rng(seed)
    measured = rssi_draws.rssi_radio(radio, PAPER_RADIO)
    receivers = np.empty((STEPS, n * BEACONS_PER_FLIGHT, 3, 2)) if measured is not None else None
    ref = lawnmower()[:, None, None, :] + FORMATION[None, None]  # (S+1, 1, 3, 2)
    beacons = rng.uniform([0.0, 0.0], [4.0, 8.0], (n * BEACONS_PER_FLIGHT, 2))
    true = np.broadcast_to(ref[0], (n, 3, 2)).copy()
    z = np.empty((STEPS + 1, n, 3, 2))
    u = np.empty((STEPS, n, 3, 2))
    rssi = np.empty((STEPS, n * BEACONS_PER_FLIGHT, 3))
    bias = rng.choice([-BIAS_DB, BIAS_DB], (n * BEACONS_PER_FLIGHT, 3))  # fixed per link
    z[0] = true + rng.normal(0, math.sqrt(TRUE_R_POS), true.shape)
    for s in range(STEPS):
        u[s] = ref[s + 1] - z[s]
        true += u[s] + rng.normal(0, math.sqrt(TRUE_Q), true.shape)
        z[s + 1] = true + rng.normal(0, math.sqrt(TRUE_R_POS), true.shape)
        rec = np.repeat(true, BEACONS_PER_FLIGHT, axis=0)  # (K, 3, 2)
        d = np.linalg.norm(rec - beacons[:, None], axis=2)
        noise = bias + rng.normal(0, math.sqrt(RSSI_VAR), d.shape)
        r = MODEL.p0_dbm - 10 * MODEL.n * np.log10(np.maximum(d, 1e-3)) + noise
        rssi[s] = np.where(d > R_MAX, np.nan, r)
        if receivers is not None:
            receivers[s] = rec
    if measured is not None and receivers is not None:
        rssi = measured_rssi(receivers, beacons, measured, np.random.default_rng([seed, 1]))
    return z, u, rssi, beacons


def measured_rssi(receivers: np.ndarray, beacons: np.ndarray, radio: rssi_draws.Radio, rng: np.random.Generator
                  ) -> np.ndarray:
    """RSSI (S, K, 3) of beacons (K, 2) heard by the true receivers (S, K, 3, 2) a step apart,
    under a measured radio: the thesis's law plus each link's draws and the time processes;
    NaN beyond R_MAX and where a reading is lost."""
    ch = rssi_draws.channel(radio, MODEL.n, rng)
    d = np.linalg.norm(receivers - beacons[None, :, None], axis=3)  # (S, K, 3)
    power = MODEL.p0_dbm - 10 * MODEL.n * np.log10(np.maximum(d, 1e-3))
    k, m = d.shape[1], d.shape[2]
    loss = np.empty((k, m))
    for b in range(k):
        for j in range(m):
            link = (f"beacon{b}", f"receiver{j}")
            ends = np.column_stack([np.broadcast_to(beacons[b], (len(d), 2)), receivers[:, b, j]])
            power[:, b, j] += ch.turned_db(link, d[:, b, j]) + ch.shadowing_at(link, ends)
            loss[b, j] = ch.link(link).loss
    time = rssi_draws.TimeProcesses(ch, loss, DT, rng)
    for s in range(len(d)):
        power[s] += time.noise()
        power[s][time.missed()] = np.nan
    return np.asarray(np.where(d > R_MAX, np.nan, power), float)


AREA_CENTRE, AREA_PRIOR_VAR = (2.0, 4.0), 16.0
VARIANTS = {"ekf": ("ekf", "circles"), "ukf": ("ukf", "circles"), "ekf_area": ("ekf", "area"),
            "ekf_smoothed": ("ekf", "circles+smoother"), "ekf_area_smoothed": ("ekf", "area+smoother")}
"""S4's filters with S4's initialiser; ours: the EKF started from the survey area instead, and
either EKF followed by the smoother (host.estimation.beacon.refine_batch: beacon and per-link
offsets fitted to the whole flight, offset prior σ 2 dB = S4's |μχ|)."""
SMOOTHED = {"ekf_smoothed": "ekf", "ekf_area_smoothed": "ekf_area"}
LABELS = {"circles": "S4's initialiser", "area": "ours: started from the area",
          "circles+smoother": "ours: S4's initialiser + smoother", "area+smoother": "ours: from the area + smoother"}


def run_filter(kind: str, z: np.ndarray, u: np.ndarray, rssi: np.ndarray, init: str = "circles"
               ) -> tuple[np.ndarray, float, int]:
    """Final beacon estimates (K, 2), the filter's seconds, and its steps.

    ``init``: "circles" is S4's initialiser over the first n_init steps (a beacon no circle pair
    reached yet starts at the receivers); "area" starts every beacon at the survey area's centre
    with a 4 m standard deviation, so a beacon is first placed by the filter itself."""
    k = rssi.shape[1]
    zk = np.repeat(z, BEACONS_PER_FLIGHT, axis=1)  # (S+1, K, 3, 2)
    uk = np.repeat(u, BEACONS_PER_FLIGHT, axis=1)
    s = 0
    if init == "circles":
        circles = CircleInitializer(MODEL, k)
        while not circles.ready:
            circles.update(zk[s + 1], rssi[s])
            s += 1
        beacon, cov = circles.estimate()
        centre = zk[s].reshape(k, -1, 2).mean(axis=1)
        x0, p0 = initial_state(MODEL, zk[s], np.where(np.isnan(beacon), centre, beacon), cov)
    else:
        x0, p0 = initial_state(MODEL, zk[0], np.tile(AREA_CENTRE, (k, 1)),
                               np.broadcast_to(np.eye(2) * AREA_PRIOR_VAR, (k, 2, 2)).copy())
    filt = (BeaconEkf if kind == "ekf" else BeaconUkf)(MODEL, x0, p0)
    t0 = time.perf_counter()
    for step in range(s, STEPS):
        filt.predict(uk[step].reshape(k, -1), DT)
        filt.update(zk[step + 1].reshape(k, -1), rssi[step])
    return filt.beacon.copy(), time.perf_counter() - t0, STEPS - s


def filterpy_ekf(z: np.ndarray, u: np.ndarray, rssi: np.ndarray, beacons: int) -> tuple[np.ndarray, float, int]:
    """The same EKF written with filterpy, one beacon at a time, on the first ``beacons``."""
    from filterpy.kalman import ExtendedKalmanFilter

    m = MODEL
    zk = np.repeat(z, BEACONS_PER_FLIGHT, axis=1)[:, :beacons]
    uk = np.repeat(u, BEACONS_PER_FLIGHT, axis=1)[:, :beacons]
    rssi = rssi[:, :beacons]
    out, seconds, steps = [], 0.0, 0
    r_full = np.diag([m.r_pos] * 6 + [m.r_rssi] * 3)
    for b in range(beacons):
        init = CircleInitializer(m, 1)
        s = 0
        while not init.ready:
            init.update(zk[s + 1, b:b + 1], rssi[s, b:b + 1])
            s += 1
        est, cov = init.estimate()
        est = np.where(np.isnan(est), zk[s, b].mean(axis=0), est)
        x0, p0 = initial_state(m, zk[s, b:b + 1], est, cov)
        f = ExtendedKalmanFilter(dim_x=8, dim_z=9, dim_u=6)
        f.x, f.P = x0[0].reshape(8, 1), p0[0]
        f.F = np.eye(8)
        f.B = np.vstack([np.eye(6), np.zeros((2, 6))])
        f.Q = np.diag([m.q] * 6 + [0.0, 0.0])
        t0 = time.perf_counter()
        for step in range(s, STEPS):
            f.predict(uk[step, b].reshape(6, 1))
            keep = np.concatenate([np.ones(6, bool), ~np.isnan(rssi[step, b])])  # unheard rows left out
            zz = np.concatenate([zk[step + 1, b].ravel(), rssi[step, b]])[keep].reshape(-1, 1)
            f.update(zz, lambda x, keep=keep: jacobian(m, x.reshape(1, -1))[0][keep],
                     lambda x, keep=keep: measure(m, x.reshape(1, -1))[0][keep].reshape(-1, 1),
                     R=r_full[np.ix_(keep, keep)])
        seconds += time.perf_counter() - t0
        steps += STEPS - s
        out.append(f.x[-2:, 0].copy())
    return np.array(out), seconds, steps


def batch(index: int, seed: int, flights_: int, reference: int, radio: str = IDEAL) -> dict[str, Any]:
    """One job: ``flights_`` flights, EKF and UKF on all their beacons, and (for ``reference``
    > 0) the filterpy EKF on the first ``reference`` beacons; ``radio``: the RSSI's."""
    z, u, rssi, beacons = flights(flights_, seed, radio)
    row: dict[str, Any] = {"beacons": len(beacons)}
    measured = rssi_draws.rssi_radio(radio, PAPER_RADIO)
    if measured is not None:
        row["radios"] = measured.describe(PAPER_RADIO)
    estimates: dict[str, np.ndarray] = {}
    for name, (kind, init) in VARIANTS.items():
        if name in SMOOTHED:
            t0 = time.perf_counter()
            estimates[name], _ = refine_batch(MODEL, np.repeat(z[1:], BEACONS_PER_FLIGHT, axis=1), rssi,
                                              estimates[SMOOTHED[name]], iterations=6)
            seconds = row[f"{SMOOTHED[name]}_seconds"] + time.perf_counter() - t0
            steps = STEPS
        else:
            estimates[name], seconds, steps = run_filter(kind, z, u, rssi, init)
        row[f"{name}_seconds"] = seconds
        row[f"{name}_error_m"] = np.round(np.linalg.norm(estimates[name] - beacons, axis=1), 4).tolist()
        row[f"{name}_us_per_beacon_step"] = seconds / steps / len(beacons) * 1e6
    if reference:  # beacons are independent in the batch: its first rows are the same filters
        est, seconds, steps = filterpy_ekf(z, u, rssi, reference)
        row["filterpy_error_m"] = np.round(np.linalg.norm(est - beacons[:reference], axis=1), 4).tolist()
        row["filterpy_vs_ours_m"] = float(np.max(np.linalg.norm(est - estimates["ekf"][:reference], axis=1)))
        row["filterpy_us_per_beacon_step"] = seconds / steps * 1e6
    return row


def jobs(runs: int, seed: int) -> list[Job]:
    """``runs`` beacons, FLIGHTS_PER_JOB flights (500 beacons) per job; the first job also runs
    the filterpy reference on 20 beacons (all of them if it has fewer)."""
    n_flights = math.ceil(runs / BEACONS_PER_FLIGHT)
    out = []
    for i, start in enumerate(range(0, n_flights, FLIGHTS_PER_JOB)):
        flights_ = min(FLIGHTS_PER_JOB, n_flights - start)
        out.append(Job(i, "rfhoming.campaigns.s4:batch", {"index": i, "seed": seed * 100_000 + i, "flights_": flights_,
                                                 "reference": min(20, flights_ * BEACONS_PER_FLIGHT) if i == 0 else 0}))
    return out


def stats(errors: np.ndarray) -> dict[str, float]:
    return {"mean_m": round(float(errors.mean()), 4), "median_m": round(float(np.median(errors)), 4),
            "p95_m": round(float(np.percentile(errors, 95)), 4), "max_m": round(float(errors.max()), 4)}


def report(rows: list[dict[str, Any]]) -> Report:
    errors = {k: np.concatenate([r[f"{k}_error_m"] for r in rows]) for k in VARIANTS}
    beacons = sum(r["beacons"] for r in rows)
    radios = rows[0].get("radios")
    summary: dict[str, Any] = {"radios": radios or {"radio": IDEAL, "noise": IDEAL_NOISE}, "beacons": beacons}
    lines = []
    for name, (kind, init) in VARIANTS.items():
        us = float(np.average([r[f"{name}_us_per_beacon_step"] for r in rows], weights=[r["beacons"] for r in rows]))
        summary[name] = {**stats(errors[name]), "us_per_beacon_step": round(us, 2)}
        if name in PAPER:
            paper = PAPER[name]
            lines.append([f"{kind.upper()}, paper (10,000 beacons, MATLAB)", paper["mean_m"], None, "< 0.65",
                          "> 2", round(paper["total_s"] / (10_000 * STEPS) * 1e6, 1)])
        s = summary[name]
        lines.append([f"{kind.upper()}, {LABELS[init]} ({beacons:,} beacons)", s["mean_m"], s["median_m"],
                      s["p95_m"], s["max_m"], s["us_per_beacon_step"]])
    ref = next((r for r in rows if "filterpy_error_m" in r), None)
    md = rssi_draws.radios_line(radios, IDEAL_NOISE, "S4's BLE receivers", "the thesis's law", "χ; the filters are still told 9 dB²") + "\n\n"
    md += table(["filter", "mean error m", "median m", "95th percentile m", "max m", "µs per beacon-step"], lines)
    if ref is not None:
        fp = np.array(ref["filterpy_error_m"])
        speedup = ref["filterpy_us_per_beacon_step"] / summary["ekf"]["us_per_beacon_step"]
        summary["filterpy"] = {"beacons": len(fp), "mean_m": round(float(fp.mean()), 4),
                               "us_per_beacon_step": round(ref["filterpy_us_per_beacon_step"], 2),
                               "max_difference_to_ours_m": ref["filterpy_vs_ours_m"], "speedup": round(speedup, 1)}
        md += (f"\n\nfilterpy `ExtendedKalmanFilter` on the same data, {len(fp)} beacons one at a time: "
               f"{ref['filterpy_us_per_beacon_step']:.1f} µs per beacon-step, ours batched "
               f"{summary['ekf']['us_per_beacon_step']:.2f}: **{speedup:.0f}× faster**; their estimates "
               f"differ from ours by at most {ref['filterpy_vs_ours_m']:.2g} m.")
    md += ("\n\nThe paper's µs per beacon-step is its total time over 10,000 beacons × 3,200 steps "
           "(S4 reports 868 s and 1658 s).")

    def plot(path: Path) -> None:
        fig, axes = figure(path, 1, width=6)
        bins = np.linspace(0, max(2.0, float(max(e.max() for e in errors.values()))), 60)
        for kind, e in errors.items():
            axes[0].hist(e, bins=bins, histtype="step", label=f"{kind} (mean {e.mean():.3f} m)")
        axes[0].axvline(PAPER["ekf"]["mean_m"], color="k", ls="--", label="S4 EKF mean 0.234 m")
        axes[0].set_xlabel("final beacon error (m)")
        axes[0].set_yscale("log")
        axes[0].legend()
        save(fig, path)

    return Report(summary, md, plot)


CAMPAIGN = Campaign("s4-montecarlo", "S4 Monte Carlo: EKF and UKF beacon localisation from three moving receivers",
                    "beacons (10 per flight, 500 per job)", 10_000, jobs, report, requires=("filterpy",))
