"""How well a point explains recent angle reports, on a fixed scale; and the point that explains them best.

Each report is a world ray from its anchor; on the floor plan it is a bearing (radians, any
range: a 360-degree board's as well as a +-90 one's), with a mirror bearing for a two-sided
anchor's fold. The residual of a report at a point is the angle between its bearing and the
direction from its anchor to the point (the smaller of the two for a fold). Their median is a
scale that does not grow with a tracker's covariance, and that a quarter of wild reports
cannot move: what tells a lost track (estimation/track_guard.py).

:func:`consensus` finds the point of least median residual over the site's extent (least
median of squares, Rousseeuw 1984: a grid, then Cauchy-weighted Gauss-Newton steps from its
best cell), clamped into the extent: where a lost track restarts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfhoming.host.estimation.extent import Extent

GRID_CELLS = 48
"""The coarse search's cells along the extent's longer side (bounded work whatever the site's size)."""

MIN_CELL_M = 0.25
"""Nor finer than this."""

REFINE_STEPS = 5
"""Gauss-Newton steps from the best cell."""

MIN_SCALE_DEG = 2.0
"""The Cauchy weights' scale is the residuals' robust spread, never below this."""


@dataclass(frozen=True)
class Bearings:
    """Reports as floor-plan bearings: each anchor's (x, y), its bearing and mirror (nan: none)."""

    origins: np.ndarray  # (n, 2) metres
    theta: np.ndarray  # (n,) radians, CCW from +x
    mirror: np.ndarray  # (n,) radians or nan
    anchor: np.ndarray  # (n,) an index per anchor (for balance)

    def residuals_deg(self, points: np.ndarray) -> np.ndarray:
        """|residual| (degrees) of every report at each of ``points`` (m, 2) -> (m, n)."""
        p = np.atleast_2d(points)
        d = p[:, None, :] - self.origins[None, :, :]
        seen = np.arctan2(d[..., 1], d[..., 0])
        r = np.abs(_wrap(seen - self.theta[None, :]))
        back = np.abs(_wrap(seen - self.mirror[None, :]))
        return np.asarray(np.degrees(np.where(np.isnan(back), r, np.fmin(r, back))))

    def residuals_along(self, points: np.ndarray) -> np.ndarray:
        """|residual| (degrees) of report i at ``points[i]`` (n, 2): each against where a track put the tag then."""
        d = np.asarray(points, float) - self.origins
        seen = np.arctan2(d[:, 1], d[:, 0])
        r = np.abs(_wrap(seen - self.theta))
        back = np.abs(_wrap(seen - self.mirror))
        return np.asarray(np.degrees(np.where(np.isnan(back), r, np.fmin(r, back))))


def _wrap(rad: np.ndarray) -> np.ndarray:
    return np.asarray((rad + math.pi) % (2 * math.pi) - math.pi)


def balanced_median(residuals: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """The median of ``residuals`` (..., n) with every anchor weighing the same, however many
    reports it gave (a fast anchor would otherwise outvote three slow ones)."""
    weight = 1.0 / _share(anchor)
    order = np.argsort(residuals, axis=-1)
    cum = np.cumsum(weight[order], axis=-1)
    k = np.argmax(cum >= 0.5 * cum[..., -1:], axis=-1)
    return np.asarray(np.take_along_axis(residuals, np.take_along_axis(order, k[..., None], axis=-1), axis=-1)[..., 0])


@dataclass(frozen=True)
class Consensus:
    point: np.ndarray  # (2,) metres, inside the extent
    covariance: np.ndarray  # (2, 2) m^2
    median_deg: float  # the balanced median residual there


def consensus(reports: Bearings, extent: Extent) -> Consensus:
    """The point of the extent whose balanced median residual is least, refined, and its covariance."""
    lo, hi = np.array(extent.lo[:2]), np.array(extent.hi[:2])
    cell = max(MIN_CELL_M, float(max(hi - lo)) / GRID_CELLS)
    xs = np.arange(lo[0] + cell / 2, hi[0], cell)
    ys = np.arange(lo[1] + cell / 2, hi[1], cell)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    medians = balanced_median(reports.residuals_deg(grid), reports.anchor)
    point = grid[int(np.argmin(medians))]
    info = np.eye(2) / cell**2
    for _ in range(REFINE_STEPS):  # Cauchy-weighted Gauss-Newton on the angular residuals
        d = point[None, :] - reports.origins
        rho2 = np.maximum((d * d).sum(axis=1), 1e-6)
        seen = np.arctan2(d[:, 1], d[:, 0])
        r = _wrap(seen - reports.theta)
        back = _wrap(seen - reports.mirror)
        r = np.where(np.isnan(back) | (np.abs(r) <= np.abs(back)), r, back)
        scale = max(math.radians(MIN_SCALE_DEG), 1.4826 * float(balanced_median(np.abs(r), reports.anchor)))
        jac = np.stack([-d[:, 1] / rho2, d[:, 0] / rho2], axis=1)  # d(seen)/d(point)
        w = 1.0 / (1.0 + (r / (2.0 * scale)) ** 2) / _share(reports.anchor)
        info = (jac * w[:, None]).T @ jac / scale**2
        try:
            step = np.linalg.solve(info, -(jac * w[:, None]).T @ r / scale**2)
        except np.linalg.LinAlgError:
            break
        point = np.clip(point + np.clip(step, -cell * 4, cell * 4), lo, hi)
    median = float(balanced_median(reports.residuals_deg(point), reports.anchor)[0])
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov = np.eye(2) * float(max(hi - lo)) ** 2
    return Consensus(point, np.asarray((cov + cov.T) / 2), median)


def _share(anchor: np.ndarray) -> np.ndarray:
    """How many reports each report's anchor gave: weights over it make every anchor count as
    one (its reports share one slow error: they are not independent)."""
    _, inverse, counts = np.unique(anchor, return_inverse=True, return_counts=True)
    return np.asarray(counts[inverse], float)
