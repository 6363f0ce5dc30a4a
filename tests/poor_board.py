"""Angle reports as poor as the second public board's (the 2026-12 field report), made here, seeded.

Four anchors at the corners of a 12 x 12 m square, each facing the centre, report a tag that
stands at surveyed points (a static survey: each point a dwell, as in Paulino & Pessoa's
recordings): about ``rate_hz`` reports a second per anchor (Poisson), no elevation, azimuth
errors whose median is about 25 degrees with about 5 % beyond 90 degrees (a 360-degree array's
flips). As the neutral reading (host/bearing.py) such a board gives, azimuth all round and no
elevation; or ``folded``: as ``+UUDF`` lines a user renders them in (azimuth folded into +-90,
the mirror image, elevation 0).
Each anchor's error at a point is a bias that stays while the tag stands there (multipath of a
still scene) plus white noise. ``wild`` lists (start, end) times when every report is anywhere.
Not the emulator: its boards clip azimuth to +-90 and cannot flip (emulator/aoa_error.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import math

from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.site import Anchor, Site, TagInfo
from rfhoming.protocol.uconnect import AngleEvent

TAG = "CCF9578E0D8A"
SIDE_M = 12.0
SQUARE = Site("square-12m", (
    Anchor("sw", "000000000B01", None, (0.0, 0.0, 1.5), 45.0, angle_model="spherical"),
    Anchor("se", "000000000B02", None, (SIDE_M, 0.0, 1.5), 135.0, angle_model="spherical"),
    Anchor("ne", "000000000B03", None, (SIDE_M, SIDE_M, 1.5), -135.0, angle_model="spherical"),
    Anchor("nw", "000000000B04", None, (0.0, SIDE_M, 1.5), -45.0, angle_model="spherical")),
    (TagInfo(TAG, "receiver", 1.0),), sigma_deg=3.0, az_compression=0.0)
"""The square with the site file's defaults: what a user writes before knowing the board."""

BIAS_DEG = 20.0
WHITE_DEG = 28.0
FLIP = 0.04
"""A report's error: bias (per anchor and point) and white noise, Gaussian (35 degrees together:
a median of 24 over the core), or with probability FLIP anywhere beyond 90 degrees: with the core's own tail, 5 %)."""


@dataclass(frozen=True)
class Survey:
    events: list[Bearing]
    errors_deg: np.ndarray  # each event's azimuth error before the fold (for the statistics)
    stops: list[tuple[float, float, tuple[float, float]]]  # (from, to, point)

    def truth(self, t: float) -> np.ndarray:
        return np.array(next(p for a, b, p in self.stops if a <= t < b or b == self.stops[-1][1]))


def _wrap(deg: np.ndarray) -> np.ndarray:
    return np.asarray((deg + 180.0) % 360.0 - 180.0)


def _fold(deg: np.ndarray) -> np.ndarray:
    """A 360-degree reading put in the +-90 of a +UUDF line: behind the board -> its mirror."""
    d = _wrap(deg)
    return np.asarray(np.where(d > 90.0, 180.0 - d, np.where(d < -90.0, -180.0 - d, d)))


def survey(seed: int, stops: list[tuple[float, tuple[float, float]]], *, rate_hz: float = 1.0,
           wild: tuple[tuple[float, float], ...] = (), folded: bool = False, site: Site = SQUARE) -> Survey:
    """The tag stands at each point for its duration (s), one after the other (it jumps)."""
    rng = np.random.default_rng(seed)
    spans, t = [], 0.0
    for duration, point in stops:
        spans.append((t, t + duration, point))
        t += duration
    rows: list[tuple[Bearing, float]] = []
    for anchor in site.anchors:
        times = np.cumsum(rng.exponential(1.0 / rate_hz, int(3 * t * rate_hz) + 10))
        times = times[times < t]
        bias = {k: float(rng.normal(0.0, BIAS_DEG)) for k in range(len(spans))}
        which = np.searchsorted([b for _, b, _ in spans], times, side="right")
        where = np.array([spans[k][2] for k in which])
        o = np.asarray(anchor.position[:2])
        bearing = np.degrees(np.arctan2(where[:, 1] - o[1], where[:, 0] - o[0]))
        true_az = _wrap(-(bearing - anchor.yaw_deg))  # board sign: negative = to the board's left
        err = np.array([bias[k] for k in which]) + rng.normal(0.0, WHITE_DEG, len(times))
        flip = rng.random(len(times)) < FLIP
        err[flip] = rng.choice([-1.0, 1.0], int(flip.sum())) * rng.uniform(90.0, 180.0, int(flip.sum()))
        for a, b in wild:
            now = (times >= a) & (times < b)
            err[now] = rng.uniform(-180.0, 180.0, int(now.sum()))
        seen = _wrap(true_az + err)  # board sign: clockwise
        for t_k, az, e in zip(times, seen, _wrap(err)):
            reading = (bearing_of(float(t_k), AngleEvent(TAG, -70, int(round(float(_fold(az)))), 0, -70, 37, anchor.id,
                                                         "", 0)) if folded
                       else Bearing(float(t_k), anchor.id, TAG, math.radians(-round(float(az))), None, -70.0))
            rows.append((reading, float(e)))
    rows.sort(key=lambda item: item[0].t)
    return Survey([r for r, _ in rows], np.array([e for _, e in rows]), spans)
