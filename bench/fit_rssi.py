"""Fit the measured RSSI profile's ``[rssi.*]`` tables to real recordings, and check the emulator
against them.

    python bench/fit_rssi.py --data DIR [--seeds 4] [--rounds 2] [--json]

DIR holds three public recordings by other teams (their sources: each folder's SOURCE.txt;
docs/RESULTS.md, "Measured radios: RSSI"), read here and never by the test suite:

- ``danis_ble_rssi/``: 12 BLE receivers, one beacon. ``hst_set_2/*.mbd``: the beacon still at 6
  places for 30 min each (*danis-static*); ``trk/*.mbd``: carried along 9 tracks with camera
  ground truth (*danis-moving*). One advertisement every 0.455 s.
- ``kolakowski_ble_robot/``: a tag on a robot (LiDAR-SLAM ground truth), 6 anchors;
  ``calibration/calibration_df.csv``: 4104 readings every 1/3 s over four sessions, each the
  log-mean of what an anchor heard in the third of a second (the data set's own processing), NaN
  where it heard nothing. The tag is 1.3 m up (the data set's description).
- ``girolami_xplr_aoa/``: four XPLR-AOA anchors, a walking tag (1.1 m up), eight recordings with
  waypoint ground truth; each ``+UUDF`` event's RSSI (field 2) and second polarisation (field 5).

For each recording host/rssi_fit.py measures the statistics of docs/emulator.md's measured RSSI
model; the ``[rssi.ble]`` table pools the BLE recordings, ``[rssi.xplr]`` is Girolami's, and
``[rssi.subghz]`` takes ``[rssi.ble]``'s figures as *assumed* (no recording of a 915 MHz
directional receiver exists here). Then every recording is emulated with the fitted table:
the measured channel of emulator/measured_rssi.py at each reading's time and true place, on
the same links, with the recording's own log-distance law as the scenario's, over ``--seeds``
seeds; each statistic is the median over them, beside the real one.

Prints the three tables as TOML (for the project's profile) and the fidelity table; ``--json``
prints one object instead.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit

import rfhoming
from rfhoming.emulator.measured_rssi import MeasuredChannel
from rfhoming.emulator.radio import PathLossModel
from rfhoming.host import site as sites
from rfhoming.host.angle_residuals import ks_distance, residuals
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.groundtruth import load_waypoints
from rfhoming.host.rssi_fit import Readings, RssiStats, calibrate, estimate, pool, rssi_stats
from rfhoming.protocol.rssi_profile import RssiProfile

DANIS_INTERVAL_S = 0.455
"""Daniş: the beacon advertises every 0.455 s (the median gap between a receiver's readings)."""

KOLAKOWSKI_TAG_HEIGHT_M = 1.3
"""Kołakowski: "the tag was attached ... on a one meter long wooden pole, which placed it at the
height of 1.3 m" (the data set's description)."""

KOLAKOWSKI_INTERVAL_S = 1 / 3
"""Kołakowski: one row every 1/3 s."""

USES: dict[str, tuple[str, ...]] = {
    "danis-static": ("residual", "shadowing", "loss"),
    "danis-moving": ("exponent", "offset", "shadowing", "residual", "loss"),
    "kolakowski": ("exponent", "offset", "shadowing", "residual", "loss"),
    "girolami": ("exponent", "offset", "shadowing", "residual", "polarisation"),
}
"""What each recording measures. danis-static has six places a link: too few for an exponent or
a level (they are in its fidelity row). girolami's missed events are the [aoa] table's: an
XPLR-AOA event carries its angle and its RSSI, and is lost with both."""

RADIO_OF = {"danis-static": "ble", "danis-moving": "ble", "kolakowski": "ble", "girolami": "xplr"}

SUBGHZ_ASSUMED = ("no public recording of the AT86RF212 node, or of any 915 MHz receiver behind directional "
                  "antennas, with ground truth was found: the BLE recordings' figures (indoor links through "
                  "furniture and walls, the nearest measured) are taken as they are")

STATS = ("scatter_db", "exponent_sd", "offset_sd_db", "shadowing_sd_db", "shadowing_distance_m", "missing",
         "corr_time_s", "polarisation_sd_db")
"""The fidelity table's statistics (host/rssi_fit.py's RssiStats), and the KS distance."""


def danis(root: Path) -> list[Readings]:
    base = root / "danis_ble_rssi"
    text = (base / "cnf" / "tetam.dev").read_text()
    found = re.search(r"Dongles:(\{.*?\})\s*\n", text, re.S)
    if found is None:
        raise SystemExit(f"fit_rssi: {base}/cnf/tetam.dev has no Dongles line")
    dongles = json.loads(found.group(1))
    by_mac = {mac: (i, np.array(pos, float)) for i, (mac, (pos, _c, _alias)) in enumerate(sorted(dongles.items()))}
    by_alias = {alias: by_mac[mac] for mac, (_p, _c, alias) in dongles.items()}
    rows: list[tuple[int, int, float, float, float, float, float]] = []
    for s, path in enumerate(sorted((base / "hst_set_2").glob("*.mbd"))):
        alias, x, y, z = path.stem.split("_")
        link, pos = by_alias[alias]
        point = np.array([float(x), float(y), float(z)])
        d = float(np.linalg.norm(pos - point))
        for line in path.read_text().splitlines():
            f = line.split(",")
            rows.append((link, s, float(f[0]), float(f[3]), d, point[0], point[1]))
    static = _readings("danis-static", "danis_ble_rssi/hst_set_2/*.mbd", rows, DANIS_INTERVAL_S)
    rows = []
    for k, path in enumerate(sorted((base / "trk").glob("*.mbd"))):
        for line in path.read_text().splitlines():
            f = line.split(",")
            if len(f) < 7 or f[1] not in by_mac:
                continue
            link, pos = by_mac[f[1]]
            point = np.array([float(f[4]), float(f[5]), float(f[6])])
            rows.append((link, k * 100 + link, float(f[0]), float(f[3]), float(np.linalg.norm(pos - point)),
                         point[0], point[1]))
    moving = _readings("danis-moving", "danis_ble_rssi/trk/*.mbd", rows, DANIS_INTERVAL_S)
    return [static, moving]


def kolakowski(root: Path) -> Readings:
    base = root / "kolakowski_ble_robot"
    anchors = np.loadtxt(base / "anchors.csv", delimiter=",", skiprows=1)[:, 1:]
    cal = np.genfromtxt(base / "calibration" / "calibration_df.csv", delimiter=",", skip_header=1)
    t = cal[:, 1] / 1e9  # columns: index, ts (ns), x, heading, y, rssi_1..rssi_6
    session = np.concatenate([[0], np.cumsum(np.diff(t) > 5.0)])
    xyz = np.stack([cal[:, 2], cal[:, 4], np.full(len(cal), KOLAKOWSKI_TAG_HEIGHT_M)], axis=1)
    rows = []
    for a in range(len(anchors)):
        d = np.linalg.norm(xyz - anchors[a], axis=1)
        for i in np.flatnonzero(~np.isnan(cal[:, 5 + a])):
            rows.append((a, int(session[i]) * 10 + a, float(t[i]), float(cal[i, 5 + a]), float(d[i]),
                         float(xyz[i, 0]), float(xyz[i, 1])))
    return _readings("kolakowski", "kolakowski_ble_robot/calibration/calibration_df.csv", rows, KOLAKOWSKI_INTERVAL_S)


def girolami(root: Path) -> Readings:
    base = root / "girolami_xplr_aoa"
    site = sites.load(base / "site.toml")
    names = [a.name for a in site.anchors]
    rows, seconds = [], []
    for k, capture in enumerate(sorted((base / "captures").glob("*.pcapng"))):
        path = load_waypoints(base / "ground_truth" / f"{capture.stem}.csv")
        items = [(got.t, got.item) for got in rfhoming.read(f"capture:{capture}", kinds={"angle"})]
        second = {(t, e.anchor_id): e.reserved for t, e in items}  # the board's field 5 (a 1.0 board's RSSI)
        events = [bearing_of(t, e) for t, e in items]
        ids = {a.name: a.id for a in site.anchors}
        for name, r in residuals(site, events, path).items():
            a = names.index(name)
            xy = path.at(r.t)
            for j in range(len(r.t)):
                rows.append((a, k * 10 + a, float(r.t[j]), float(r.rssi[j]), float(r.distance_m[j]),
                             float(xy[j, 0]), float(xy[j, 1])))
                seconds.append(second[(r.t[j], ids[name])])
    gaps = [np.diff(sorted(t for a, s, t, *_ in rows if s == series)) for series in {row[1] for row in rows}]
    interval = float(np.median(np.concatenate(gaps)))
    return replace(_readings("girolami", "girolami_xplr_aoa/captures/*.pcapng", rows, interval),
                   second=np.array(seconds, float)[np.argsort([row[2] for row in rows], kind="stable")])


def _readings(name: str, source: str, rows: Sequence[tuple[int, int, float, float, float, float, float]],
              interval_s: float) -> Readings:
    a = np.array(rows, float)
    a = a[np.argsort(a[:, 2], kind="stable")]
    return Readings(name, source, a[:, 0].astype(int), a[:, 1].astype(int), a[:, 2], a[:, 3], a[:, 4], a[:, 5:7],
                    interval_s)


def emulate(real: Readings, stats: RssiStats, rssi: RssiProfile, seed: int) -> Readings:
    """The recording again through the measured channel: the same links, times and true places,
    every advertisement the recording missed put back (in its gap, at the interval) for the
    channel to lose or not; the recording's own log-distance fit as the scenario's law."""
    t, link, series, d, xy = _with_missed(real)
    model = PathLossModel(p0_dbm=stats.p0_dbm, n=stats.exponent)
    channel = MeasuredChannel(model, rssi, np.random.default_rng(seed))
    out = np.full(len(t), np.nan)
    second = np.full(len(t), np.nan)
    for i in np.argsort(t, kind="stable"):
        name = (str(link[i]), "receiver")
        if channel.lost(name, t[i]):
            continue
        ends = ((float(xy[i, 0]), float(xy[i, 1])), (0.0, 0.0))  # the receiver never moves: its place is any
        out[i] = channel.sample(name, model.mean_dbm(float(d[i])), t=float(t[i]), ends=ends, distance_m=float(d[i]))
        second[i] = channel.second_dbm(name, out[i])
    kept = ~np.isnan(out)
    return Readings(f"{real.name} (emulated)", real.source, link[kept], series[kept], t[kept], out[kept], d[kept],
                    xy[kept], real.interval_s, second[kept] if real.second is not None else None)


def _with_missed(r: Readings) -> tuple[np.ndarray, ...]:
    """(t, link, series, distance, xy) of every reading and of each one missed in a gap (at
    the interval, its place and distance interpolated)."""
    parts = []
    for s in np.unique(r.series):
        idx = np.flatnonzero(r.series == s)
        idx = idx[np.argsort(r.t[idx], kind="stable")]
        t = r.t[idx]
        steps = np.maximum(np.round(np.diff(t) / r.interval_s), 1)
        filled = np.concatenate([[t[0]]] + [t[j] + (t[j + 1] - t[j]) * np.arange(1, int(n) + 1) / n
                                            for j, n in enumerate(steps)])
        parts.append(np.stack([filled, np.full(len(filled), r.link[idx[0]]), np.full(len(filled), s),
                               np.interp(filled, t, r.distance_m[idx]), np.interp(filled, t, r.xy[idx, 0]),
                               np.interp(filled, t, r.xy[idx, 1])], axis=1))
    a = np.concatenate(parts)
    return a[:, 0], a[:, 1].astype(int), a[:, 2].astype(int), a[:, 3], a[:, 4:6]


def fit(recordings: Sequence[Readings], seeds: int, rounds: int) -> tuple[dict[str, RssiStats], dict[str, RssiProfile],
                                                                      dict[str, RssiProfile]]:
    """Each recording's statistics and own profile (its direct estimates, calibrated by emulating
    it), and the tables that pool them by radio."""
    stats = {r.name: rssi_stats(r) for r in recordings}
    own: dict[str, RssiProfile] = {}
    for r in recordings:
        uses = USES[r.name]
        start = estimate(stats[r.name])
        start = replace(start, loss=start.loss if "loss" in uses else None,
                        polarisation=start.polarisation if "polarisation" in uses else None)
        own[r.name] = calibrate(start, stats[r.name], uses, _simulator(r, stats[r.name]), seeds, rounds)
    tables: dict[str, RssiProfile] = {}
    for radio, title in (("ble", "BLE scanners (ESP32 node, ESP-AT, HCI)"), ("xplr", "the XPLR-AOA board's RSSI")):
        tables[radio] = pool({n: (own[n], USES[n]) for n in own if RADIO_OF[n] == radio}, title)
    tables["subghz"] = assumed_from(tables["ble"], "the AT86RF212 four-dish node (915 MHz)")
    return stats, own, tables


def _simulator(r: Readings, stats: RssiStats) -> Callable[[RssiProfile, int], RssiStats]:
    return lambda p, seed: rssi_stats(emulate(r, stats, p, seed))


def assumed_from(ble: RssiProfile, title: str) -> RssiProfile:
    """``ble``'s figures, each group marked assumed with why."""
    marked = {g: replace(getattr(ble, g), source=f"[rssi.ble]'s: {getattr(ble, g).source}", assumed=SUBGHZ_ASSUMED)
              for g in ("exponent", "offset", "shadowing", "residual", "loss") if getattr(ble, g) is not None}
    return replace(ble, title=title, **marked)


def fidelity(recordings: Sequence[Readings], stats: dict[str, RssiStats], profiles: dict[str, RssiProfile],
             seeds: int) -> dict[str, dict[str, object]]:
    """Per recording: each statistic real and emulated with ``profiles[recording]`` (median and
    range over ``seeds``), and the KS distance of the residuals about the log-distance fit."""
    out: dict[str, dict[str, object]] = {}
    for r in recordings:
        real, p = stats[r.name], profiles[r.name]
        runs = [rssi_stats(emulate(r, real, p, 1000 + seed)) for seed in range(seeds)]  # not the fit's seeds
        row: dict[str, object] = {}
        for name in STATS:
            x = getattr(real, name)
            if x is None or not math.isfinite(x) or (name == "missing" and p.loss is None):
                continue
            ys = [float(v) for e in runs if (v := getattr(e, name)) is not None and math.isfinite(v)]
            row[name] = {"real": round(float(x), 3), "emulated": round(float(np.median(ys)), 3),
                         "range": [round(min(ys), 3), round(max(ys), 3)]}
        row["ks"] = {"emulated": round(float(np.median([ks_distance(real.residuals, e.residuals) for e in runs])), 3)}
        out[r.name] = row
    return out


TITLES = {"scatter_db": "scatter about the log-distance fit, dB", "exponent_sd": "exponent spread (std of the links' fits)",
          "offset_sd_db": "offset spread (std of the links' mean residuals), dB",
          "shadowing_sd_db": "shadowing (same place, >= 30 s apart), dB",
          "shadowing_distance_m": "shadowing correlation distance, m", "missing": "missing fraction (mean of links)",
          "corr_time_s": "residual correlation time (acf < 0.5), s",
          "polarisation_sd_db": "second polarisation less the first, std, dB",
          "ks": "KS distance of the residuals, real vs emulated"}


def print_report(result: dict[str, Any]) -> None:
    print("# the project's measured RSSI tables (bench/fit_rssi.py)\n")
    print(tomlkit.dumps({"rssi": result["tables"]}))
    for title, key in (("the project's tables", "fidelity"), ("each recording's own fit", "fidelity_own")):
        rows: dict[str, dict[str, Any]] = result[key]
        names = list(rows)
        print(f"\nEmulated with {title}: real / emulated (median of {result['seeds']} seeds; off by)\n")
        print("| statistic | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
        for stat in (*STATS, "ks"):
            cells = []
            for n in names:
                v = rows[n].get(stat)
                if v is None:
                    cells.append("—")
                elif stat == "ks":
                    cells.append(f"{v['emulated']:.3f}")
                else:
                    off = f" ({100 * (v['emulated'] / v['real'] - 1):+.0f} %)" if v["real"] else ""
                    cells.append(f"{v['real']:.3g} / {v['emulated']:.3g}{off}")
            print(f"| {TITLES[stat]} | " + " | ".join(cells) + " |")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True,
                    help="the folder holding danis_ble_rssi/, kolakowski_ble_robot/ and girolami_xplr_aoa/")
    ap.add_argument("--seeds", type=int, default=4, help="emulations of each recording per round and for the "
                    "fidelity table (default 4)")
    ap.add_argument("--rounds", type=int, default=2, help="calibration rounds (default 2)")
    ap.add_argument("--json", action="store_true", help="one JSON object instead of TOML and a table")
    args = ap.parse_args(argv)
    missing = [d for d in ("danis_ble_rssi", "kolakowski_ble_robot", "girolami_xplr_aoa") if not (args.data / d).is_dir()]
    if missing:
        print(f"fit_rssi: no {missing[0]}/ in {args.data}: pass --data with the folder that holds the recordings",
              file=sys.stderr)
        return 2
    load_before = os.getloadavg()[0]
    recordings = [*danis(args.data), kolakowski(args.data), girolami(args.data)]
    stats, own, tables = fit(recordings, args.seeds, args.rounds)
    project = {r.name: tables[RADIO_OF[r.name]] for r in recordings}
    result: dict[str, Any] = {
        "load_before": load_before,
        "seeds": args.seeds,
        "rounds": args.rounds,
        "tables": {name: t.to_table() for name, t in tables.items()},
        "own": {name: p.to_table() for name, p in own.items()},
        "stats": {name: s.as_dict() for name, s in stats.items()},
        "fidelity": fidelity(recordings, stats, project, args.seeds),
        "fidelity_own": fidelity(recordings, stats, own, args.seeds),
        "load_after": os.getloadavg()[0],
    }
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print_report(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
