"""Where a walked tag really was: waypoint files, and the scoring rule of the real recordings.

A waypoint file (the layout of ``girolami_xplr_aoa/ground_truth/*.csv``) has one row per
waypoint, ``arrival_ms,leave_ms,x_cm,y_cm``: epoch milliseconds, ``leave_ms`` NaN where the walker
did not stop, centimetres. The walker moves in a straight line at constant speed from one
waypoint's leaving (or arrival) to the next one's arrival and stands still from arrival to leave.

The ground truth is for scoring and for fitting radio profiles only (``bench/``, ``radio-fit
--truth``): no localiser, tracker or calibration is ever given it.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfhoming.protocol.errors import Error
from rfhoming.protocol.textfile import read_text

TICK_S = 0.5
"""The scoring rule's tick: every 500 ms ..."""

FIRST_TICK_S = 0.5
"""... from the first waypoint's time plus this ..."""

NO_ESTIMATE_M = 5.0
"""... and this error at a tick before the first position."""


class GroundTruthError(Error, ValueError):
    """A waypoint file that cannot be read; the message names the file, the row and the fix."""


@dataclass(frozen=True)
class Waypoint:
    arrive_s: float
    leave_s: float  # == arrive_s where the walker did not stop
    x: float  # metres
    y: float


@dataclass(frozen=True)
class WalkedPath:
    """A walk through waypoints; :meth:`at` interpolates it."""

    waypoints: tuple[Waypoint, ...]

    @property
    def start_s(self) -> float:
        return self.waypoints[0].arrive_s

    @property
    def end_s(self) -> float:
        return self.waypoints[-1].arrive_s

    @property
    def last_s(self) -> float:
        """When the walk is over: the last waypoint left (a static survey's point: its dwell's end)."""
        return self.waypoints[-1].leave_s

    def at(self, t: Sequence[float] | np.ndarray) -> np.ndarray:
        """(N, 2) positions at the times ``t`` (held at the ends)."""
        times, xy = self._knots()
        tt = np.asarray(t, float)
        return np.stack([np.interp(tt, times, xy[:, 0]), np.interp(tt, times, xy[:, 1])], axis=1)

    def moving(self, t: Sequence[float] | np.ndarray) -> np.ndarray:
        """Whether the walker is between waypoints (not standing) at each of ``t``."""
        tt = np.asarray(t, float)
        standing = np.zeros(tt.shape, bool)
        for w in self.waypoints:
            standing |= (tt >= w.arrive_s) & (tt <= w.leave_s)
        inside = (tt > self.start_s) & (tt < self.last_s)
        return inside & ~standing

    def heading(self, t: Sequence[float] | np.ndarray) -> np.ndarray:
        """The walker's heading (rad, CCW from +x) at each of ``t``: the way it moves, or, standing,
        the way it last moved (the first leg's way before it moves at all)."""
        times, xy = self._knots()
        step = np.diff(xy, axis=0)
        moving = np.hypot(step[:, 0], step[:, 1]) > 1e-9
        if not moving.any():
            return np.zeros(np.shape(t))
        last = np.maximum.accumulate(np.where(moving, np.arange(len(step)), -1))
        way = np.arctan2(step[:, 1], step[:, 0])[np.where(last >= 0, last, int(np.argmax(moving)))]
        return np.asarray(way[np.clip(np.searchsorted(times, np.asarray(t, float), side="right") - 1, 0, len(step) - 1)])

    def _knots(self) -> tuple[np.ndarray, np.ndarray]:
        times, xy = [], []
        for w in self.waypoints:
            times.append(w.arrive_s)
            xy.append((w.x, w.y))
            if w.leave_s > w.arrive_s:
                times.append(w.leave_s)
                xy.append((w.x, w.y))
        return np.array(times), np.array(xy)


MAX_BYTES = 1 << 20
"""The largest waypoint file read: 1 MiB, some 30,000 rows (the recordings' are 10-16 rows, 416 bytes)."""
MAX_WAYPOINTS = 10_000
"""The most waypoints in a walk: a 10^6-row file kept bench/fidelity.py busy past 400 s."""
MAX_STEP_S = 6 * 3600.0
"""The longest time from one row to the next, or of one stop: a stray row 10^15 ms later is a typo."""
FAR_M = 100_000.0
"""No waypoint lies farther from the origin than this (100 km), with or without a site."""
AREA_MARGIN_M = 10.0
"""How far outside the rectangle of a site's anchors a waypoint may lie."""

Area = tuple[float, float, float, float]
"""Where waypoints may lie: (x_min, y_min, x_max, y_max), metres."""


def area_of(anchors_xy: Iterable[Sequence[float]], margin_m: float = AREA_MARGIN_M) -> Area:
    """The rectangle of a site's anchors grown by ``margin_m``: where its walks' waypoints may lie."""
    xy = np.array([p[:2] for p in anchors_xy], float).reshape(-1, 2)
    (x0, y0), (x1, y1) = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    return float(x0), float(y0), float(x1), float(y1)


def load_waypoints(path: Path, area: Area | None = None) -> WalkedPath:
    """A waypoint CSV as a :class:`WalkedPath`; GroundTruthError naming the row when it is not one: too large,
    not UTF-8 text, rows out of time order or hours apart, or a waypoint outside ``area`` (:func:`area_of`)."""
    text = read_text(path, "ground truth", GroundTruthError, MAX_BYTES).removeprefix("\ufeff")
    points: list[Waypoint] = []
    for row_no, row in enumerate(csv.reader(text.splitlines()), 1):
        if not row or not "".join(row).strip():
            continue
        if row_no == 1 and not _is_number(row[0]):
            continue  # a header line
        if len(row) != 4:
            raise GroundTruthError(f"{path} row {row_no}: expected arrival_ms,leave_ms,x_cm,y_cm, got {len(row)} fields")
        try:
            arrive, leave, x, y = (float(v) for v in row)
        except ValueError:
            raise GroundTruthError(f"{path} row {row_no}: {','.join(row)[:80]!r} is not four numbers") from None
        if not all(math.isfinite(v) for v in (arrive, x, y)) or not (math.isnan(leave) or leave >= arrive):
            raise GroundTruthError(f"{path} row {row_no}: arrival and position must be finite numbers and "
                                   "leave_ms NaN or not before arrival_ms")
        point = Waypoint(arrive / 1000, (arrive if math.isnan(leave) else leave) / 1000, x / 100, y / 100)
        _check(point, points[-1] if points else None, area, f"{path} row {row_no}")
        if len(points) == MAX_WAYPOINTS:
            raise GroundTruthError(f"{path} row {row_no}: more than {MAX_WAYPOINTS:,} waypoints; is it the right file?")
        points.append(point)
    if not points or (len(points) == 1 and points[0].leave_s <= points[0].arrive_s):
        raise GroundTruthError(f"{path}: a walk needs two waypoints, or one with a dwell (leave_ms after arrival_ms: "
                               f"a static survey's point), found {len(points)} without")
    return WalkedPath(tuple(points))


def _check(point: Waypoint, previous: Waypoint | None, area: Area | None, where: str) -> None:
    """GroundTruthError at ``where`` for a waypoint out of time order, hours after the last, or off the site."""
    if previous is not None and point.arrive_s < previous.leave_s:
        raise GroundTruthError(f"{where}: arrives before the previous waypoint was left; rows must be in time order")
    step = point.arrive_s - previous.leave_s if previous is not None else 0.0
    for what, seconds in (("arrives", step), ("stands", point.leave_s - point.arrive_s)):
        if seconds > MAX_STEP_S:
            raise GroundTruthError(f"{where}: {what} {seconds:.3g} s after the previous time; rows more than "
                                   f"{MAX_STEP_S / 3600:g} h apart are a typo (times are in milliseconds)")
    if math.hypot(point.x, point.y) > FAR_M:
        raise GroundTruthError(f"{where}: the waypoint ({point.x:.3g}, {point.y:.3g}) m is more than "
                               f"{FAR_M / 1000:g} km from the origin (positions are in centimetres)")
    if area is not None and not (area[0] <= point.x <= area[2] and area[1] <= point.y <= area[3]):
        raise GroundTruthError(f"{where}: the waypoint ({point.x:.3g}, {point.y:.3g}) m lies outside the site "
                               f"(its anchors' rectangle plus {AREA_MARGIN_M:g} m: x {area[0]:g} to {area[2]:g}, "
                               f"y {area[1]:g} to {area[3]:g}); positions are in centimetres in the site's frame")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def score(path: WalkedPath, positions: Sequence[tuple[float, float, float]]) -> np.ndarray:
    """The horizontal error at each tick of the recordings' rule: ticks every TICK_S from the first
    waypoint's time + FIRST_TICK_S to the last waypoint's; the estimate is the last position
    ``(t, x, y)`` at or before the tick (NO_ESTIMATE_M before the first)."""
    ticks = np.arange(path.start_s + FIRST_TICK_S, path.end_s + 1e-9, TICK_S)
    est = np.array(sorted(positions), float).reshape(-1, 3)
    truth = path.at(ticks)
    idx = np.searchsorted(est[:, 0], ticks + 1e-9, side="right") - 1
    errors = np.full(len(ticks), NO_ESTIMATE_M)
    seen = idx >= 0
    errors[seen] = np.hypot(*(est[idx[seen], 1:3] - truth[seen]).T)
    return errors
