"""What an anchor's angles get wrong: residuals against a known walk, and the statistics of them.

Given a site (anchor poses as mounted, no calibration), a recording's angle events and the
walker's true path (host/groundtruth.py), each event's residual is the reported angle less the
angle the board would report for the true position in its own frame (docs/estimation.md, "Fixed
anchors in 3-D"). The statistics are the ones the real-data and fidelity benches print and that a
radio profile is fitted to: bias, spread (std and 1.4826 MAD), tail fractions, |azimuth|
compression by angle off boresight, how long an error stays (autocorrelation time), and missing
events. For benches and profile fitting only: a localiser never sees the truth.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.anchors3d import board_angles_many
from rfhoming.host.groundtruth import WalkedPath
from rfhoming.host.site import Anchor, Site

TAIL_DEG = 20.0
"""A report off by more than this is in the tail (a reflection or a lost lock, not noise)."""

COMPRESSION_BINS_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 90.0)
"""Bins of the true |azimuth| off boresight for the compression figures."""

ACF_GRID_S = 0.1
"""Residuals are put on this time grid for their autocorrelation."""

ACF_LEVEL = 0.5
"""The autocorrelation time: the lag at which the residual's autocorrelation first falls below this."""

MAD_TO_SIGMA = 1.4826
"""1.4826 MAD estimates a Gaussian's sigma, untouched by the tails."""


@dataclass(frozen=True)
class Residuals:
    """One anchor's events of one recording, with the truth (arrays of equal length, degrees)."""

    anchor: str  # the anchor's name in the site file
    t: np.ndarray  # host seconds
    az: np.ndarray  # reported
    el: np.ndarray
    az_true: np.ndarray
    el_true: np.ndarray
    rssi: np.ndarray  # dBm, the first polarisation
    distance_m: np.ndarray  # anchor to true tag position, 3-D
    moving: np.ndarray  # bool: the walker between waypoints

    @property
    def az_err(self) -> np.ndarray:
        return np.asarray(self.az - self.az_true)

    @property
    def el_err(self) -> np.ndarray:
        return np.asarray(self.el - self.el_true)


def true_angles(anchor: Anchor, points: np.ndarray) -> np.ndarray:
    """(N, 2) board (azimuth, elevation) of world points (N, 3) as the anchor is mounted, in its
    angle model (degrees, the board's sign)."""
    local = (np.asarray(points, float) - np.asarray(anchor.position)) @ anchor.rotation()
    return board_angles_many(local, anchor.angle_model)


def residuals(site: Site, events: Iterable[Bearing], path: WalkedPath,
              tag: str | None = None, height: float | None = None) -> dict[str, Residuals]:
    """Per anchor (by name), the residuals of ``tag``'s events (the site's first tag by default)
    against ``path`` at the tag's height (the site's, or ``height``), over the walk (first to
    last waypoint: before and after it, where the walker was is not known)."""
    tag = tag or (site.tags[0].id if site.tags else None)
    info = site.tag(tag) if tag else None
    z = height if height is not None else (info.height if info and info.height is not None else None)
    if z is None:
        raise ValueError("the tag's height is needed: give it in the site file's [tags.ID] or as height=")
    by_anchor: dict[str, list[tuple[float, float, float, float]]] = {}
    names = {a.id: a for a in site.anchors}
    for r in events:
        if r.anchor in names and (tag is None or r.tag == tag) and path.start_s <= r.t <= path.last_s:
            by_anchor.setdefault(r.anchor, []).append((r.t, r.clockwise_deg, r.elevation_deg or 0.0,
                                                   math.nan if r.rssi is None else r.rssi))
    out = {}
    for anchor_id, rows in by_anchor.items():
        anchor = names[anchor_id]
        arr = np.array(sorted(rows), float)
        times = arr[:, 0]
        points = np.column_stack([path.at(times), np.full(len(times), z)])
        truth = true_angles(anchor, points)
        out[anchor.name] = Residuals(anchor.name, times, arr[:, 1], arr[:, 2], truth[:, 0], truth[:, 1], arr[:, 3],
                                     np.linalg.norm(points - np.asarray(anchor.position), axis=1), path.moving(times))
    return out


@dataclass(frozen=True)
class AngleStats:
    """The statistics of one or more anchors' residuals (degrees; fractions 0..1; seconds)."""

    events: int
    az_bias: float  # median residual
    az_std: float
    az_mad_sigma: float  # 1.4826 MAD
    az_tail: float  # fraction with |residual| > TAIL_DEG
    el_bias: float
    el_std: float
    el_mad_sigma: float
    el_tail: float
    compression: dict[str, float]  # "45-60": median(|reported| - |true|) for true |az| in that bin
    corr_time_s: float  # median over the recordings' anchors of the autocorrelation time
    missing: float  # fraction of the recording's advertisements this anchor did not report (worst anchor)

    def as_dict(self) -> dict[str, object]:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def angle_stats(groups: Sequence[dict[str, Residuals]], anchors: Sequence[str] | None = None) -> AngleStats:
    """Statistics pooled over recordings (each a :func:`residuals` result), of all anchors or of
    ``anchors``; the autocorrelation time is the median over (recording, anchor) pairs and the
    missing fraction the worst pair's."""
    chosen = [r for g in groups for name, r in g.items() if anchors is None or name in anchors]
    if not chosen:
        raise ValueError("no residuals to summarise")
    az = np.concatenate([r.az_err for r in chosen])
    el = np.concatenate([r.el_err for r in chosen])
    true_abs = np.concatenate([np.abs(r.az_true) for r in chosen])
    shrink = np.concatenate([np.abs(r.az) - np.abs(r.az_true) for r in chosen])
    compression = {}
    for lo, hi in zip(COMPRESSION_BINS_DEG, COMPRESSION_BINS_DEG[1:]):
        inside = (true_abs >= lo) & (true_abs < hi)
        if inside.sum() >= 10:
            compression[f"{lo:g}-{hi:g}"] = float(np.median(shrink[inside]))
    times = [correlation_time(r.t, r.az_err) for r in chosen]
    missing = [missing_fraction(g, name) for g in groups for name in g if anchors is None or name in anchors]
    return AngleStats(len(az), float(np.median(az)), float(np.std(az)), mad_sigma(az), tail_fraction(az),
                      float(np.median(el)), float(np.std(el)), mad_sigma(el), tail_fraction(el), compression,
                      float(np.median([x for x in times if math.isfinite(x)] or [math.nan])), float(max(missing)))


def mad_sigma(x: np.ndarray) -> float:
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


def tail_fraction(x: np.ndarray, limit: float = TAIL_DEG) -> float:
    return float(np.mean(np.abs(x) > limit))


def correlation_time(t: np.ndarray, err: np.ndarray, grid_s: float = ACF_GRID_S, level: float = ACF_LEVEL) -> float:
    """The lag (s) at which the autocorrelation of ``err`` (sampled and held on a grid of
    ``grid_s``, mean removed) first falls below ``level``; NaN when too short to tell."""
    if len(t) < 10 or t[-1] - t[0] < 20 * grid_s:
        return math.nan
    grid = np.arange(t[0], t[-1], grid_s)
    held = err[np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(err) - 1)]
    x = held - held.mean()
    n = len(x)
    spectrum = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    if acf[0] <= 0:
        return math.nan
    acf = acf / acf[0]
    below = np.nonzero(acf < level)[0]
    return float(below[0] * grid_s) if len(below) else math.nan


def missing_fraction(group: dict[str, Residuals], anchor: str) -> float:
    """The fraction of the recording's advertisements that ``anchor`` did not report, taking the
    anchor that reported most over the common time span as hearing every one."""
    start = max(r.t[0] for r in group.values())
    end = min(r.t[-1] for r in group.values())
    counts = {name: int(((r.t >= start) & (r.t <= end)).sum()) for name, r in group.items()}
    most = max(counts.values())
    return 1.0 - counts[anchor] / most if most else math.nan


def ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    """The two-sample Kolmogorov-Smirnov distance: the largest gap between the empirical CDFs."""
    return float(stats.ks_2samp(a, b).statistic)
