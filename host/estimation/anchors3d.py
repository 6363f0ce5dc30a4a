"""Fixed AoA anchors in 3-D: board angles -> world rays -> a robust weighted least-squares fix.

Board frame (docs/estimation.md, "Fixed anchors in 3-D"): x is the boresight (out of the
antenna side of the C211), y the board's left, z its top edge. The board reports
azimuth in the x-y plane with its own sign (negative = tag to the LEFT, u-blox UBX-21004616,
figure "C211 azimuth angles") and elevation out of that plane (positive = toward the top edge),
both -90..90 degrees. The anchor's pose turns the board frame into the world frame
(x, y on the floor, z up): yaw about world z (CCW from +x, like every heading in rfhoming),
then pitch (positive = boresight tilted up), then roll about the boresight.

Two readings of the two angles (``model``, an anchor setting): "spherical", azimuth in the
x-y plane and elevation out of it (atan2 angles), and "cone", the direction cosines a planar
array's two axes measure: sin(az) = -u.y, sin(el) = u.z (docs/estimation.md, "The angle model").

The fix minimises sum_i w_i rho(|(I - u_i u_i^T)(p - o_i)|^2), the squared distance of p from each
ray, with w_i = 1 / (r_i sigma_i)^2: an angle error sigma_i moves the ray sideways by about
r_i sigma_i at the range r_i along it, so the weights need a first fix (iterated); rho is a
robust loss (Huber, or Cauchy which lets a reflected ray pull far less).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rfhoming.host.estimation.bearings import Degenerate as Degenerate  # re-exported: its fits raise it

MIN_RANGE_M = 0.3
"""Ranges along a ray below this are treated as this (no infinite weights)."""

HUBER_K = 2.0
"""Normalised residuals beyond this are down-weighted (Huber): a reflection is not a fit."""

OUTLIER_CHI2 = 9.0
"""A ray left out must miss the others' fix by more than this (3 sigma, squared)."""

SUSPECT_CHI2 = 4.0
"""A fix with a ray beyond 2 sigma is checked for one bad anchor."""

CAUCHY_C = 1.5
"""Cauchy loss scale (normalised residual): weight 1 / (1 + (z / c)^2)."""

ANGLE_MODELS = ("spherical", "cone")
LOSSES = ("huber", "cauchy")


def rotation(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Board -> world rotation: R = Rz(yaw) Ry(-pitch) Rx(roll)."""
    y, p, r = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    cz, sz, cp, sp, cr, sr = math.cos(y), math.sin(y), math.cos(p), math.sin(p), math.cos(r), math.sin(r)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, -sp], [0, 1, 0], [sp, 0, cp]])  # Ry(-pitch): +pitch lifts x toward z
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    board_to_world: np.ndarray = rz @ ry @ rx
    return board_to_world


def board_direction(azimuth_deg: float, elevation_deg: float, model: str = "spherical") -> np.ndarray:
    """Unit vector in the board frame for the board's (azimuth, elevation) (board sign).

    "cone": the angles are direction cosines along the array's axes; a pair no direction has
    (sin^2 az + sin^2 el > 1, noise near the edge) is put on the board's plane."""
    a, e = math.radians(-azimuth_deg), math.radians(elevation_deg)
    if model == "cone":
        y, z = math.sin(a), math.sin(e)
        n = y * y + z * z
        if n > 1.0:
            y, z, n = y / math.sqrt(n), z / math.sqrt(n), 1.0
        return np.array([math.sqrt(1.0 - n), y, z])
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def board_angles(direction: Sequence[float], model: str = "spherical") -> tuple[float, float]:
    """Inverse of :func:`board_direction` for a vector in front of the board (degrees)."""
    x, y, z = direction
    if model == "cone":
        r = math.sqrt(x * x + y * y + z * z)
        return -math.degrees(math.asin(y / r)), math.degrees(math.asin(z / r))
    return -math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, math.hypot(x, y)))


def board_angles_many(d: np.ndarray, model: str = "spherical") -> np.ndarray:
    """:func:`board_angles` of (N, 3) board-frame vectors -> (N, 2) degrees (for the fits)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    if model == "cone":
        r = np.sqrt(x * x + y * y + z * z)
        return np.asarray(np.degrees(np.stack([-np.arcsin(np.clip(y / r, -1, 1)), np.arcsin(np.clip(z / r, -1, 1))], axis=1)))
    return np.asarray(np.degrees(np.stack([-np.arctan2(y, x), np.arctan2(z, np.hypot(x, y))], axis=1)))


def angle_sigma_deg(azimuth_deg: float, elevation_deg: float, sigma0_deg: float) -> float:
    """Expected error of one angle pair: a planar array's resolution falls as the cosine of
    the angle off boresight, so sigma grows as 1/cos toward +-90 (capped at 6x)."""
    c = math.cos(math.radians(azimuth_deg)) * math.cos(math.radians(elevation_deg))
    return sigma0_deg / max(c, 1 / 6)


@dataclass(frozen=True)
class Ray:
    """One anchor's line of sight to a tag in the world frame."""

    anchor: str
    origin: np.ndarray  # (3,) metres
    direction: np.ndarray  # (3,) unit
    sigma_rad: float
    mirror: np.ndarray | None = None  # the +-90 fold's other candidate (two-sided anchors)


def make_ray(anchor: str, origin: Sequence[float], rot: np.ndarray, azimuth_deg: float, elevation_deg: float,
             sigma0_deg: float, two_sided: bool = False, model: str = "spherical") -> Ray:
    """The world ray of one (azimuth, elevation) from an anchor at ``origin`` turned by ``rot``;
    a two-sided anchor (nothing behind it blocks tags) also carries the fold's mirror image."""
    d = board_direction(azimuth_deg, elevation_deg, model)
    sigma = math.radians(angle_sigma_deg(azimuth_deg, elevation_deg, sigma0_deg))
    mirror = rot @ (d * np.array([-1.0, 1.0, 1.0])) if two_sided else None
    return Ray(anchor, np.asarray(origin, float), rot @ d, sigma, mirror)


@dataclass(frozen=True)
class Fix:
    """A position with its covariance (metres, m^2) and which anchors it rests on."""

    point: np.ndarray  # (3,)
    covariance: np.ndarray  # (3, 3); z row/column zero when the height was given
    used: tuple[str, ...]
    rejected: tuple[str, ...]
    chi2: float

    @property
    def rms(self) -> float:
        """The fix's quality: rms normalised miss of its rays (about 1 when they agree as
        their sigmas say; several when an anchor is biased or reflected)."""
        return math.sqrt(self.chi2 / max(1, len(self.used)))


def _solve(o: np.ndarray, u: np.ndarray, weights: np.ndarray, height: float | None,
           height_sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted LS point (and inverse normal matrix); with ``height`` only x, y are free, or,
    given ``height_sigma`` (m), z is free with the height as a prior of that sigma.

    Normal equations in closed form: A = sum(w) I - U^T W U, b = W o - U^T W (u . o) summed."""
    uw = u * weights[:, None]
    a = weights.sum() * _I3 - u.T @ uw
    b = weights @ o - uw.T @ (u * o).sum(axis=1)
    if height is not None and height_sigma is not None:
        a[2, 2] += 1.0 / height_sigma**2
        b[2] += height / height_sigma**2
        height = None
    if height is not None:  # p = (x, y, h): move the known z to the right-hand side
        b = b[:2] - a[:2, 2] * height
        a = a[:2, :2]
    cov = _inverse(a.tolist())
    q = cov @ b
    if height is None:
        return q, cov
    full = np.zeros((3, 3))
    full[:2, :2] = cov
    return np.array([q[0], q[1], height]), full


_I3 = np.eye(3)


def _inverse(m: list[list[float]]) -> np.ndarray:
    """Inverse of a 2x2 or 3x3 normal matrix by cofactors (numpy's LAPACK call costs more than
    the whole fix at this size); Degenerate when (nearly) singular: parallel rays."""
    if len(m) == 2:
        (a, b), (c, d) = m
        det = a * d - b * c
        scale = max(abs(a), abs(d)) ** 2
        if not det > 1e-10 * scale:
            raise Degenerate("rays (nearly) parallel: no crossing")
        return np.array([[d, -b], [-c, a]]) / det
    (a, b, c), (d, e, f), (g, h, i) = m
    co = [[e * i - f * h, c * h - b * i, b * f - c * e],
          [f * g - d * i, a * i - c * g, c * d - a * f],
          [d * h - e * g, b * g - a * h, a * e - b * d]]
    det = a * co[0][0] + b * co[1][0] + c * co[2][0]
    scale = max(abs(a), abs(e), abs(i)) ** 3
    if not det > 1e-10 * scale:
        raise Degenerate("rays (nearly) parallel: no crossing")
    return np.array(co) / det


def _residuals(point: np.ndarray, o: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(range along each ray, perpendicular distance from it); range < 0 = behind the anchor."""
    d = point[None] - o
    along = (d * u).sum(axis=1)
    perp = np.sqrt(np.maximum((d * d).sum(axis=1) - along**2, 0.0))
    return along, perp


def _fit(rays: list[Ray], height: float | None, iterations: int, loss: str = "huber",
         height_sigma: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IRLS: range weights from the last fix, a robust loss on normalised residuals, folds resolved."""
    o = np.array([r.origin for r in rays])
    u = np.array([r.direction for r in rays])
    sig = np.array([r.sigma_rad for r in rays])
    folds = [(i, r.direction, r.mirror) for i, r in enumerate(rays) if r.mirror is not None]
    point, cov = _solve(o, u, 1 / sig**2, height, height_sigma)
    for _ in range(iterations):
        for i, front, back in folds:  # the fold: keep the candidate the fix lies in front of and near
            cands = np.array([front, back])
            along, perp = _residuals(point, o[[i, i]], cands)
            u[i] = cands[int(np.argmin(perp + np.where(along < 0, 1e3, 0.0)))]
        along, perp = _residuals(point, o, u)
        ranges = np.maximum(along, MIN_RANGE_M)
        z = perp / (ranges * sig)
        if loss == "cauchy":
            robust = 1.0 / (1.0 + (z / CAUCHY_C) ** 2)
        else:
            robust = np.where(z > HUBER_K, HUBER_K / np.maximum(z, 1e-12), 1.0)
        robust = np.where(along < 0, 1e-3, robust)  # a fix behind an anchor cannot be on its ray
        point, cov = _solve(o, u, robust / (ranges * sig) ** 2, height, height_sigma)
    along, perp = _residuals(point, o, u)
    z2 = (perp / (np.maximum(along, MIN_RANGE_M) * sig)) ** 2 + np.where(along < 0, 1e6, 0.0)
    return point, cov, z2


def locate(rays: list[Ray], height: float | None = None, iterations: int = 2, *, loss: str = "huber",
           height_sigma: float | None = None) -> Fix:
    """The tag's position from two or more rays (with ``height``) or three or more (3-D).

    ``loss="huber"``: one bad anchor (a reflection, a wrong mounting) is found by its residual
    and left out when the others then agree (consensus by leave-one-out). ``loss="cauchy"``
    keeps every ray, each weighted down by its own miss (more IRLS rounds, no leave-one-out).
    ``height_sigma``: the height is a prior of that sigma (m), not a constraint. Degenerate
    when the rays cannot fix a point (too few, parallel)."""
    need = 2
    if len(rays) < need:
        raise Degenerate(f"need at least {need} anchors, have {len(rays)}")
    if loss == "cauchy":
        iterations = max(iterations, 4)
    point, cov, z2 = _fit(rays, height, iterations, loss, height_sigma)
    rejected: tuple[str, ...] = ()
    if loss == "huber" and len(rays) >= 4 and z2.max() > SUSPECT_CHI2:
        best = None
        for k, bad in enumerate(rays):  # consensus: which one ray, left out, lets the rest agree?
            rest = rays[:k] + rays[k + 1:]
            try:
                p2, c2, z2b = _fit(rest, height, iterations, loss, height_sigma)
            except Degenerate:
                continue
            along, perp = _residuals(p2, bad.origin[None], bad.direction[None])
            z_bad = 1e6 if along[0] < 0 else (perp[0] / (max(along[0], MIN_RANGE_M) * bad.sigma_rad)) ** 2
            if z2b.max() < OUTLIER_CHI2 and z_bad > OUTLIER_CHI2 and (best is None or z2b.sum() < best[2].sum()):
                best = (p2, c2, z2b, rest, bad.anchor)
        if best is not None:
            point, cov, z2, rays, left_out = best
            rejected = (left_out,)
    dof = max(1, 2 * len(rays) - (2 if height is not None and height_sigma is None else 3))
    scale = max(1.0, float(z2.sum()) / dof)  # rays that disagree widen the covariance
    return Fix(point, cov * scale, tuple(r.anchor for r in rays), rejected, float(z2.sum()))
