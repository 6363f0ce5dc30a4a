"""What real noise does to the ranging fits, the filters and lateration.

Data: two public recordings by other teams, never a dependency of the test suite; --data names
the folder that holds both (their sources and layout: docs/RESULTS.md, "Estimation on real recordings").
- danis_ble_rssi/: Daniş et al. (CC0), github.com/philotuxo/Position-Annotated-BLE-RSSI-Dataset:
  12 receivers, one beacon at 6 static points (hst_set_2).
- kolakowski_ble_robot/: Kołakowski (CC BY 4.0), doi:10.5281/zenodo.5457591: a tag on a robot
  with LiDAR-SLAM ground truth, 6 anchors.

    python bench/validate_real_data.py --data DIR [--json]

Prints Markdown tables (the ones in docs/RESULTS.md).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

from rfhoming.host.estimation import filters as f
from rfhoming.host.estimation.bearings import Degenerate
from rfhoming.host.estimation.fixed import from_q8, to_q8
from rfhoming.host.estimation.lateration import multilaterate, strongest_three, trilaterate
from rfhoming.host.estimation.ranging import S3_TABLE, Exponential, LogDistance, fit_exponential, fit_log_distance

WARMUP = 20
SITE_DIAGONAL_M = 27.0
"""Daniş: the site is 20.7 × 17.6 m; no range beyond its diagonal is believable."""
TAG_HEIGHT_M = 0.3
"""Kołakowski: the tag's height on the robot is not given; assumed."""


def filter_stds(series: list[np.ndarray]) -> dict[str, float]:
    """Mean over links of the std after each filter (first WARMUP samples skipped)."""
    makers = {
        "raw": None,
        "moving average N=10": lambda: f.MovingAverage(10),
        "EMA α=1/8": lambda: f.Ema(3),
        "median N=5": lambda: f.RunningMedian(5),
        "Kalman q=0.05 r=25": lambda: f.ScalarKalman(0.05, 25.0),
    }
    out = {}
    for name, make in makers.items():
        stds = []
        for s in series:
            if len(s) <= WARMUP + 5:
                continue
            if make is None:
                y = s
            else:
                flt = make()
                y = np.array([from_q8(flt.update(to_q8(v))) for v in s])
            stds.append(np.std(y[WARMUP:]))
        out[name] = float(np.mean(stds))
    return out


def danis(root: Path) -> dict:
    base = root / "danis_ble_rssi"
    dev = (base / "cnf" / "tetam.dev").read_text()
    dongles = json.loads(re.search(r"Dongles:(\{.*?\})\s*\n", dev, re.S).group(1))
    sensors = {alias: np.array(pos, float) for _mac, (pos, _color, alias) in dongles.items()}
    points: dict[tuple, dict[str, np.ndarray]] = {}
    for path in sorted((base / "hst_set_2").glob("*.mbd")):
        alias, x, y, z = path.stem.split("_")
        rssi = np.array([float(line.split(",")[3]) for line in path.read_text().splitlines() if line.count(",") >= 3])
        points.setdefault((float(x), float(y), float(z)), {})[alias] = rssi
    d_all, r_all, per_sensor = [], [], {}
    for point, readings in points.items():
        for alias, rssi in readings.items():
            d = float(np.linalg.norm(sensors[alias] - np.array(point)))
            d_all.append(np.full(len(rssi), d))
            r_all.append(rssi)
            per_sensor.setdefault(alias, ([], []))
            per_sensor[alias][0].append(np.full(len(rssi), d))
            per_sensor[alias][1].append(rssi)
    pooled = fit_log_distance(np.concatenate(d_all), np.concatenate(r_all))
    sensor_fits = {a: fit_log_distance(np.concatenate(ds), np.concatenate(rs)) for a, (ds, rs) in per_sensor.items()}
    model: LogDistance = pooled.model  # type: ignore[assignment]
    errors_multi, errors_tri, errors_clamped, rows = [], [], [], []
    for point, readings in points.items():
        names = sorted(readings)
        pos = np.array([sensors[a] for a in names])
        mean_rssi = np.array([readings[a].mean() for a in names])
        d3 = model.distance(mean_rssi)
        dz = pos[:, 2] - point[2]
        dh = np.sqrt(np.maximum(d3**2 - dz**2, 0.01))
        truth = np.array(point[:2])
        multi = multilaterate(pos[:, :2], dh)
        clamped = multilaterate(pos[:, :2], np.minimum(dh, SITE_DIAGONAL_M))
        try:
            idx = strongest_three(mean_rssi)
            tri = trilaterate(pos[idx, :2], dh[idx])
            e_tri = float(np.linalg.norm(tri - truth))
        except Degenerate:
            e_tri = float("nan")
        e_multi = float(np.linalg.norm(multi - truth))
        e_clamped = float(np.linalg.norm(clamped - truth))
        errors_multi.append(e_multi)
        errors_tri.append(e_tri)
        errors_clamped.append(e_clamped)
        rows.append({"point": point[:2], "multilateration_m": e_multi, "clamped_m": e_clamped,
                     "trilateration_3_strongest_m": e_tri})
    tracks = danis_tracks(base, dongles, model)
    return {
        "tracks": tracks,
        "samples": int(sum(len(r) for r in r_all)),
        "pooled": {"p0_dbm": pooled.model.p0_dbm, "n": pooled.model.n, "sigma_db": pooled.rssi_residual_db},
        "per_sensor_n": [min(s.model.n for s in sensor_fits.values()), max(s.model.n for s in sensor_fits.values())],
        "per_sensor_sigma_db": [min(s.rssi_residual_db for s in sensor_fits.values()),
                                max(s.rssi_residual_db for s in sensor_fits.values())],
        "filters_std_db": filter_stds([r for readings in points.values() for r in readings.values()]),
        "points": rows,
        "multilateration_mean_m": float(np.mean(errors_multi)),
        "clamped_mean_m": float(np.mean(errors_clamped)),
        "trilateration_mean_m": float(np.nanmean(errors_tri)),
    }


def danis_tracks(base: Path, dongles: dict, model: LogDistance) -> dict:
    """Moving beacon: once a second, multilateration from every receiver heard in the last
    2 s (ranges from the pooled static fit, clamped to the site), raw vs Kalman-filtered RSSI."""
    positions = {mac: np.array(pos, float) for mac, (pos, _c, _a) in dongles.items()}
    out = {}
    for path in sorted((base / "trk").glob("*.mbd")):
        rows = [line.split(",") for line in path.read_text().splitlines() if line.count(",") >= 6]
        rows.sort(key=lambda r: float(r[0]))
        errors: dict[str, list[float]] = {"raw": [], "kalman": []}
        kalman: dict[str, f.ScalarKalman] = {}
        latest: dict[str, dict[str, tuple[float, float]]] = {"raw": {}, "kalman": {}}
        next_fix = float(rows[0][0]) + 2.0
        for r in rows:
            t, mac, rssi = float(r[0]), r[1], float(r[3])
            if mac not in positions:
                continue
            k = kalman.setdefault(mac, f.ScalarKalman(0.05, 25.0))
            latest["raw"][mac] = (t, rssi)
            latest["kalman"][mac] = (t, from_q8(k.update(to_q8(rssi))))
            if t < next_fix:
                continue
            next_fix = t + 1.0
            truth = np.array([float(r[4]), float(r[5])])
            for label, table in latest.items():
                heard = [(m, v) for m, (tm, v) in table.items() if t - tm <= 2.0]
                if len(heard) < 3:
                    continue
                pos = np.array([positions[m] for m, _ in heard])
                d3 = model.distance(np.array([v for _, v in heard]))
                dh = np.minimum(np.sqrt(np.maximum(d3**2 - (pos[:, 2] - float(r[6])) ** 2, 0.01)), SITE_DIAGONAL_M)
                try:
                    errors[label].append(float(np.linalg.norm(multilaterate(pos[:, :2], dh) - truth)))
                except Degenerate:
                    continue
        out[path.stem.replace("_all_sensors", "")] = {
            label: {"fixes": len(e), "mean_m": float(np.mean(e)), "median_m": float(np.median(e))}
            for label, e in errors.items() if e}
    return out


def kolakowski(root: Path) -> dict:
    base = root / "kolakowski_ble_robot"
    anchors = np.loadtxt(base / "anchors.csv", delimiter=",", skiprows=1)[:, 1:]
    cal = np.genfromtxt(base / "calibration" / "calibration_df.csv", delimiter=",", skip_header=1)
    test = np.genfromtxt(base / "tests" / "test_robot_df.csv", delimiter=",", skip_header=1)
    # columns: index, ts, x, heading, y, rssi_1..6
    def dist(rows: np.ndarray) -> np.ndarray:
        xyz = np.stack([rows[:, 2], rows[:, 4], np.full(len(rows), TAG_HEIGHT_M)], axis=1)
        return np.linalg.norm(xyz[:, None, :] - anchors[None], axis=2)

    d_cal = dist(cal)
    fits = []
    for i in range(len(anchors)):
        heard = ~np.isnan(cal[:, 5 + i])
        fits.append(fit_log_distance(d_cal[heard, i], cal[heard, 5 + i]))
    d_test = dist(test)
    truth = test[:, [2, 4]]
    out = {"anchors": len(anchors), "calibration_samples": len(cal), "test_samples": len(test),
           "per_anchor_n": [float(ft.model.n) for ft in fits],
           "per_anchor_sigma_db": [float(ft.rssi_residual_db) for ft in fits]}
    for label, smooth in (("raw", False), ("Kalman q=0.05 r=25", True)):
        rssi = test[:, 5:11].copy()
        if smooth:  # a missing reading leaves the filter as it was
            for i in range(rssi.shape[1]):
                k = f.ScalarKalman(0.05, 25.0)
                last = np.nan
                for row, v in enumerate(rssi[:, i]):
                    if not np.isnan(v):
                        last = from_q8(k.update(to_q8(v)))
                    rssi[row, i] = last
        errs = []
        for row in range(len(test)):
            heard = ~np.isnan(rssi[row])
            if heard.sum() < 3:
                continue
            d3 = np.array([fits[i].model.distance(rssi[row, i]) for i in np.flatnonzero(heard)])
            dh = np.sqrt(np.maximum(d3**2 - (anchors[heard, 2] - TAG_HEIGHT_M) ** 2, 0.01))
            try:
                errs.append(np.linalg.norm(multilaterate(anchors[heard, :2], dh) - truth[row]))
            except Degenerate:
                continue
        errs = np.array(errs)
        out[f"multilateration_{label}"] = {"mean_m": float(errs.mean()), "median_m": float(np.median(errs)),
                                          "p95_m": float(np.percentile(errs, 95)), "rows_used": len(errs)}
    residuals = np.concatenate([test[:, 5 + i] - fits[i].model.rssi(d_test[:, i]) for i in range(len(anchors))])
    out["test_rssi_residual_db"] = float(np.nanstd(residuals))
    out["missing_fraction"] = float(np.isnan(test[:, 5:11]).mean())
    return out


def s3_table() -> dict:
    """S3's Table I means: our fits and the paper's published models, distance RMSE."""
    d, rssi, _ = np.array(S3_TABLE).T
    ours_log, ours_exp = fit_log_distance(d, rssi), fit_exponential(d, rssi)
    paper_log = LogDistance(float(rssi[2]), 2.7)  # RSSI(d0 = 1 m) from the table, n = 2.7
    paper_exp = Exponential(0.0165, -0.0662)

    def rmse(model) -> float:
        return float(np.sqrt(np.mean((model.distance(rssi) - d) ** 2)))

    return {"ours_log": {"p0": ours_log.model.p0_dbm, "n": ours_log.model.n, "rmse_m": ours_log.distance_rmse_m},
            "ours_exp": {"a": ours_exp.model.a, "b": ours_exp.model.b, "rmse_m": ours_exp.distance_rmse_m},
            "paper_log_rmse_m": rmse(paper_log), "paper_exp_rmse_m": rmse(paper_exp)}


def markdown(result: dict) -> str:
    d, k, t = result["danis"], result["kolakowski"], result["s3_table"]
    lines = ["### S3 Table I means (11 distances, 0.05–5 m)",
             "| model | parameters | distance RMSE on the means, m | S3 (raw samples), m |", "|---|---|---|---|",
             f"| log-distance, our LS fit | P0 {t['ours_log']['p0']:.1f} dBm, n {t['ours_log']['n']:.2f} | {t['ours_log']['rmse_m']:.3f} | |",
             f"| log-distance, S3's model | RSSI(1 m) −64.30, n 2.7 | {t['paper_log_rmse_m']:.3f} | 0.5945 |",
             f"| exponential, our fit | a {t['ours_exp']['a']:.4f}, b {t['ours_exp']['b']:.4f} | {t['ours_exp']['rmse_m']:.3f} | |",
             f"| exponential, S3's model | a 0.0165, b −0.0662 | {t['paper_exp_rmse_m']:.3f} | 0.3427 |", "","### Daniş BLE, 12 receivers, 6 static beacon points",
             f"{d['samples']} RSSI samples. Pooled log-distance fit: P0 = {d['pooled']['p0_dbm']:.1f} dBm at 1 m, "
             f"n = {d['pooled']['n']:.2f}, residual σ = {d['pooled']['sigma_db']:.2f} dB. "
             f"Per receiver: n {d['per_sensor_n'][0]:.2f}…{d['per_sensor_n'][1]:.2f}, "
             f"σ {d['per_sensor_sigma_db'][0]:.2f}…{d['per_sensor_sigma_db'][1]:.2f} dB.", "",
             "| filter (fixed point) | std of RSSI per link, dB (mean over 72 links) |", "|---|---|"]
    lines += [f"| {name} | {v:.2f} |" for name, v in d["filters_std_db"].items()]
    lines += ["", "| beacon at (x, y) m | multilateration, 12 receivers, m | same, ranges clamped to 27 m | trilateration, 3 strongest, m |",
              "|---|---|---|---|"]
    lines += [f"| ({p['point'][0]:.2f}, {p['point'][1]:.2f}) | {p['multilateration_m']:.2f} | {p['clamped_m']:.2f} | {p['trilateration_3_strongest_m']:.2f} |"
              for p in d["points"]]
    lines += [f"| **mean** | **{d['multilateration_mean_m']:.2f}** | **{d['clamped_mean_m']:.2f}** | **{d['trilateration_mean_m']:.2f}** |", "",
              "Moving beacon (the nine `trk` recordings, camera ground truth ~4 cm): one fix a second "
              "by multilateration over the receivers heard in the last 2 s, ranges from the pooled fit "
              "clamped to 27 m.", "",
              "| track | fixes | raw RSSI: mean / median error, m | Kalman q=0.05 r=25: mean / median, m |",
              "|---|---|---|---|"]
    for name, t in d["tracks"].items():
        lines.append(f"| {name} | {t['raw']['fixes']} | {t['raw']['mean_m']:.2f} / {t['raw']['median_m']:.2f} | "
                     f"{t['kalman']['mean_m']:.2f} / {t['kalman']['median_m']:.2f} |")
    lines += ["",
              "### Kołakowski BLE robot, 6 anchors, LiDAR-SLAM ground truth",
              f"Per-anchor fits on {k['calibration_samples']} calibration points: n = "
              + ", ".join(f"{n:.2f}" for n in k["per_anchor_n"]) + "; σ = "
              + ", ".join(f"{s:.1f}" for s in k["per_anchor_sigma_db"]) + " dB. "
              f"On the test run the RSSI scatters {k['test_rssi_residual_db']:.1f} dB around those fits; "
              f"{k['missing_fraction']:.0%} of its readings are missing (rows with fewer than 3 anchors are skipped).", "",
              "| test run ({} samples) | mean m | median m | 95th pct m |".format(k["test_samples"]), "|---|---|---|---|"]
    for label in ("raw", "Kalman q=0.05 r=25"):
        e = k[f"multilateration_{label}"]
        lines.append(f"| multilateration, {label} RSSI | {e['mean_m']:.2f} | {e['median_m']:.2f} | {e['p95_m']:.2f} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="the folder holding danis_ble_rssi/ and kolakowski_ble_robot/")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if not (args.data / "danis_ble_rssi").is_dir():
        print(f"no data at {args.data}: pass --data with the folder that holds danis_ble_rssi/ "
              "and kolakowski_ble_robot/", file=sys.stderr)
        return 2
    result = {"s3_table": s3_table(), "danis": danis(args.data), "kolakowski": kolakowski(args.data)}
    print(json.dumps(result, indent=1, default=float) if args.json else markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
