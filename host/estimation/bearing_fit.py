"""A static tag's position from many bearings taken along the robot's path, fitted robustly.

Real XPLR-AOA bearings are not S0's white noise (docs/emulator.md, "Radio profiles": the
project's measured profile): their errors have heavy tails (bursts of 15-30°), are slow (the
same few degrees for a second or more, and over a metre or two of the room), and the board
reads wide angles too near its boresight. S0's estimates rest on the last readings (Kohonen's
k per reading, a 20-reading vector goal), so a slow error or a burst drags its goal along for
as long as it lasts. Here every kept ray of the run votes:

- rays are kept sparsely along the path (one per ``spacing_m`` travelled, ``spacing_deg``
  turned or ``spacing_s`` elapsed): readings taken in one place share its slow error, and
  many of them must not outvote the rest of the path;
- the position minimises Σ ρ(angle residual / ``scale_deg``) over the rays, ρ the Cauchy loss
  (Levenberg-Marquardt on two parameters, the cost and stopping rules of scipy's
  ``least_squares``): a burst's rays or a wrong-branch fold have bounded pull;
  within ``near_m`` of a ray's origin its residual shrinks to the ray's miss distance over
  ``near_m`` (an angle seen from a point next to the robot says nothing, and a point there would
  fit the newest rays however they point);
- each ray's RSSI range enters too, weakly (``range_rel_sigma`` relative, the same loss): along
  a straight approach every ray agrees and only ranges tell how far the tag is;
- the fit is trusted (:meth:`BearingFit.estimate` gives it) once most rays agree with it and,
  counting only the rays taken ``near_m`` or farther from it (the robot's own rays beside a
  point vouch for any point there), they span enough parallax (``min_spread_deg`` of bearing
  change seen from the fitted point) and the bearings alone (without the ranges) place it well
  enough: their standard deviation (times ``std_inflation``) below ``trust_abs_m`` +
  ``trust_rel`` × its distance from the robot. On a straight approach only the ranges tell how far the tag is, and RSSI
  ranges can read short: S0's own estimates are reported then.

Frames: world x/y in metres, bearings in radians counter-clockwise from +x.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class _Solution:
    x: np.ndarray
    cost: float  # ½ Σ ln(1 + f²)
    jac: np.ndarray  # as scipy's least_squares reports it under a robust loss: J √max(ρ' + 2ρ''f², ε)


def _cauchy_least_squares(fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], start: tuple[float, float],
                          max_nfev: int = 60, tol: float = 1e-8) -> _Solution | None:
    """Minimise ½ Σ ln(1 + f_i(p)²) over a 2-D p: Levenberg-Marquardt with the loss's curvature in
    the normal matrix (Jᵀ diag(max(ρ' + 2ρ''f², ε)) J, as scipy's robust-loss scaling). The cost and stopping rules are
    scipy ``least_squares(loss="cauchy", max_nfev=60)``'s (ftol = xtol = gtol = 1e-8), without
    its trust-region machinery, which cost ~50 times the residuals on two parameters.
    ``fun`` gives the residuals and their Jacobian. None when the start's residuals are not finite."""
    p = np.array(start, dtype=float)
    f, j = fun(p)
    if not np.all(np.isfinite(f)):
        return None
    z = f * f
    cost = 0.5 * float(np.sum(np.log1p(z)))
    nfev, damping = 1, 1e-3
    while nfev < max_nfev:
        t = 1.0 + z
        curvature = np.maximum((1.0 - z) / (t * t), EPS)  # ρ' + 2ρ''f², as scipy scales J
        (a11, a12), (_, a22) = ((j * curvature[:, None]).T @ j).tolist()
        g1, g2 = (j.T @ (f / t)).tolist()  # the gradient: Σ ρ' f ∇f
        if max(abs(g1), abs(g2)) < tol:
            break
        done = False
        while nfev < max_nfev:
            b11, b22 = a11 * (1 + damping), a22 * (1 + damping)
            det = b11 * b22 - a12 * a12
            if not det > 0:
                damping *= 10
                if damping > 1e12:
                    done = True
                    break
                continue
            step = np.array([-(b22 * g1 - a12 * g2) / det, -(b11 * g2 - a12 * g1) / det])
            trial = p + step
            f_new, j_new = fun(trial)
            nfev += 1
            z_new = f_new * f_new
            cost_new = 0.5 * float(np.sum(np.log1p(z_new)))
            if math.isfinite(cost_new) and cost_new < cost:
                small_step = math.hypot(*step.tolist()) < tol * (tol + math.hypot(*p.tolist()))
                small_drop = cost - cost_new < tol * cost
                p, f, j, z, cost = trial, f_new, j_new, z_new, cost_new
                damping = max(damping * 0.3, 1e-9)
                done = small_step or small_drop
                break
            damping *= 10
            if damping > 1e12:
                done = True
                break
        if done:
            break
    if not np.all(np.isfinite(p)):
        return None
    scale = np.sqrt(np.maximum((1.0 - z) / (1.0 + z) ** 2, EPS))
    return _Solution(p, cost, j * scale[:, None])


@dataclass(frozen=True)
class Fit:
    position: tuple[float, float]
    rays: int
    spread_deg: float  # the bearings of the rays taken near_m or farther, seen from the fitted point, max - min
    inliers: float  # the fraction of rays within 2 scales of the fitted point
    median_residual_deg: float
    recent_inliers: float  # the same fraction over the newest ``recent`` rays
    bearing_std_m: float  # the position's largest standard deviation from the bearings alone (no ranges)


@dataclass
class BearingFit:
    """Rays (x, y, bearing, range) kept along the path; :meth:`estimate` the robust fit."""

    spacing_m: float = 0.05
    spacing_deg: float = 4.0
    spacing_s: float = 0.25
    max_rays: int = 600
    min_rays: int = 25
    scale_deg: float = 6.0
    range_rel_sigma: float = 0.6  # a ray's RSSI range: this fraction of itself is one scale
    min_spread_deg: float = 20.0
    min_inliers: float = 0.5
    refit_every: int = 5  # kept rays between fits (a fit costs a few ms)
    recent: int = 20  # the newest rays, checked against the fit
    min_recent_inliers: float = 0.3  # fewer of them agree with the fit: the older rays are dropped
    near_m: float = 1.0  # nearer a ray's origin than this, its residual is the miss distance / near_m
    std_inflation: float = 1.0  # the kept rays' errors are not independent (slow errors), but the scale is generous: 1
    trust_abs_m: float = 0.1  # trusted when the bearings alone place it within this
    trust_rel: float = 0.15  # ... plus this fraction of its distance from the robot
    _rays: deque[tuple[float, float, float, float]] | None = None
    _last: tuple[float, float, float, float] | None = None  # t, x, y, bearing of the last kept ray
    _fit: Fit | None = None
    _since_fit: int = 0

    def __post_init__(self) -> None:
        self._rays = deque(maxlen=self.max_rays)

    @property
    def rays(self) -> int:
        assert self._rays is not None
        return len(self._rays)

    def clear(self) -> None:
        assert self._rays is not None
        self._rays.clear()
        self._last, self._fit, self._since_fit = None, None, 0

    def add(self, t: float, x: float, y: float, bearing: float, distance: float,
            guess: tuple[float, float] | None = None) -> bool:
        """Keep the ray if the robot moved, turned or waited enough since the last kept one; refit
        now and then (from ``guess``, the caller's current goal, or the last fit). True: kept."""
        assert self._rays is not None
        last = self._last
        if last is not None:
            moved = math.hypot(x - last[1], y - last[2])
            turned = abs(math.degrees(math.remainder(bearing - last[3], 2 * math.pi)))
            if moved < self.spacing_m and turned < self.spacing_deg and t - last[0] < self.spacing_s:
                return False
        self._last = (t, x, y, bearing)
        self._rays.append((x, y, bearing, distance))
        self._since_fit += 1
        if len(self._rays) >= self.min_rays and (self._fit is None or self._since_fit >= self.refit_every):
            self._since_fit = 0
            self._fit = self.fit(guess)
            if self._fit is not None and self._fit.recent_inliers < self.min_recent_inliers:
                # the robot now sees the tag elsewhere than the older rays said (they were taken
                # out of its sight, or through a doorway): forget them, the recent ones tell
                for _ in range(len(self._rays) - self.recent):
                    self._rays.popleft()
                self._fit = self.fit(None)
        return True

    def estimate(self) -> tuple[float, float] | None:
        """The fitted position once it is trusted (enough rays, parallax and agreement), else None."""
        f, last = self._fit, self._last
        if f is None or last is None or f.spread_deg < self.min_spread_deg or f.inliers < self.min_inliers:
            return None
        if f.bearing_std_m > self.trust_abs_m + self.trust_rel * math.dist(f.position, last[1:3]):
            return None  # the bearings alone do not place it (a straight approach: only ranges would)
        return f.position

    @property
    def last_fit(self) -> Fit | None:
        return self._fit

    def fit(self, guess: tuple[float, float] | None = None) -> Fit | None:
        """The robust fit over every kept ray, from ``guess`` (or the last fit, or the ranges' mean
        point); None with too few rays or a failed solve."""
        assert self._rays is not None
        if len(self._rays) < 2:
            return None
        rays = np.array(self._rays, dtype=float)
        x, y, a, d = rays[:, 0], rays[:, 1], rays[:, 2], rays[:, 3]
        scale = math.radians(self.scale_deg)
        range_sigma = np.maximum(self.range_rel_sigma * d, 0.3)

        near_m, n = self.near_m, len(rays)
        cos_a, sin_a = np.cos(a), np.sin(a)
        inv_sigma = 1.0 / range_sigma
        j = np.empty((2 * n, 2))

        def residuals(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """The residuals and their Jacobian in closed form, from one shared difference."""
            dx, dy = p[0] - x, p[1] - y
            angle = np.arctan2(dy * cos_a - dx * sin_a, dx * cos_a + dy * sin_a)  # seen minus ray, wrapped
            r = np.maximum(np.hypot(dx, dy), 1e-12)
            near = np.minimum(r * (1.0 / near_m), 1.0)  # within near_m of a ray's origin: its miss distance
            f = np.concatenate([angle * near * (1.0 / scale), (r - d) * inv_sigma])
            fade = np.where(near < 1.0, angle * (1.0 / (near_m * scale)) / r, 0.0)  # ∂near/∂p = (dx, dy) / (r near_m)
            k = near / (r * r * scale)
            j[:n, 0] = fade * dx - dy * k
            j[:n, 1] = fade * dy + dx * k
            q = inv_sigma / r
            j[n:, 0] = dx * q
            j[n:, 1] = dy * q
            return f, j.copy()

        starts: list[tuple[float, float]] = []
        if guess is not None:
            starts.append((float(guess[0]), float(guess[1])))
        if self._fit is not None:
            starts.append(self._fit.position)
        starts.append((float(np.mean(x + d * np.cos(a))), float(np.mean(y + d * np.sin(a)))))  # the vector goals' mean
        best: _Solution | None = None
        for start in dict.fromkeys(starts):  # each distinct start once: a trusted fit is also S0's guess
            sol = _cauchy_least_squares(residuals, start)
            if sol is not None and (best is None or sol.cost < best.cost):
                best = sol
        if best is None:
            return None
        p = best.x
        seen = np.arctan2(p[1] - y, p[0] - x)
        angle_res = np.degrees(np.abs(np.remainder(seen - a + math.pi, 2 * math.pi) - math.pi))
        inliers = float(np.mean(angle_res < 2 * self.scale_deg))
        # parallax and precision from the rays taken at least near_m away only: rays from beside
        # the fitted point would vouch for any point there (their residuals are miss distances)
        far = np.hypot(p[0] - x, p[1] - y) >= self.near_m
        std, spread_deg = math.inf, 0.0
        if np.count_nonzero(far) >= max(2, self.min_rays // 2):
            mean_dir = math.atan2(float(np.mean(np.sin(seen[far]))), float(np.mean(np.cos(seen[far]))))
            spread = np.degrees(np.remainder(seen[far] - mean_dir + math.pi, 2 * math.pi) - math.pi)
            spread_deg = float(np.max(spread) - np.min(spread))
            j = np.asarray(best.jac, dtype=float)[:len(rays)][far]  # their angle rows, as the loss weighs them
            try:
                cov = np.linalg.inv(j.T @ j)
                std = float(np.sqrt(max(float(np.max(np.linalg.eigvalsh(cov))), 0.0))) * self.std_inflation
            except np.linalg.LinAlgError:
                std = math.inf
        return Fit((float(p[0]), float(p[1])), len(rays), spread_deg, inliers,
                   float(np.median(angle_res)), float(np.mean(angle_res[-self.recent:] < 2 * self.scale_deg)),
                   std if math.isfinite(std) else math.inf)
