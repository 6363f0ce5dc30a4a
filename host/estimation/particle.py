"""S2: direction from four directional antennas, and the particle filter that tracks the emitter.

Axis convention (robot frame, counter-clockwise): antenna x1 looks along the heading, x2
backwards, y1 to the left, y2 to the right. With powers in dB,

    θ = atan2(y1 − y2, x1 − x2)      (0 = ahead, +90° = left; quadrant-correct)
    r = √((x1 − x2)² + (y1 − y2)²)   (dB, mapped to metres by the calibration A1, A2)

S2 writes θ = arctan((x1 − x2)/(y1 − y2)); we use the quadrant-correct form in our own axes.
S2 maps r to metres with a calibration (A1, A2) whose values it does not give; we take the
range from the strongest antenna's power, its dish gain removed, through the emitter's
log-distance model (:func:`differential_to_range`).

Particle filter (N = 1000, global frame, random-acceleration motion, the acceleration drawn
uniform with the configured variance): per particle, the
relative distance p_r and bearing p_θ (degrees) against the instantaneous sensor s_r, s_θ:
w_r = 1 − t_r (|p_r − s_r| − c_r), w_θ = 1 − t_θ (|p_θ − s_θ| − c_θ), each clamped to [0.1, 1];
weight = √(w_r w_θ), normalised; estimate = weighted mean (circular for headings); systematic
resampling when N_eff = 1 / Σ w² < N / 2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def direction(x1: float, x2: float, y1: float, y2: float) -> tuple[float, float]:
    """(θ radians CCW from the heading, r dB) from the four antenna powers (dBm)."""
    return math.atan2(y1 - y2, x1 - x2), math.hypot(x1 - x2, y1 - y2)


def differential_to_range(powers_dbm: np.ndarray, p0_dbm: float, n: float, peak_gain_db: float) -> float:
    """Distance from the strongest antenna's power, removing its dish gain (log-distance)."""
    best = float(np.nanmax(powers_dbm)) - peak_gain_db
    return 10 ** ((p0_dbm - best) / (10 * n))


@dataclass(frozen=True)
class PfParams:
    n: int = 1000
    t_r: float = 0.1
    t_theta: float = 0.01
    c_r: float = 1.0
    c_theta: float = 15.0
    accel_sigma: float = 0.2  # m/s², std of the emitter's random acceleration (uniform draws)
    init_sigma: float = 1.0  # m around the first fix


class ParticleFilter:
    """Emitter position and velocity in the world frame, from relative (range, bearing) fixes.

    Particles live in four contiguous arrays (x, y, vx, vy): every step is a handful of
    whole-array numpy operations.
    """

    def __init__(self, params: PfParams = PfParams(), rng: np.random.Generator | None = None) -> None:
        self.params = params
        self.rng = rng or np.random.default_rng()
        self.x = np.zeros((4, params.n))  # rows: x, y, vx, vy
        self.w = np.full(params.n, 1.0 / params.n)
        self.initialised = False
        self.resamples = 0
        self._t_theta = params.t_theta * 180.0 / math.pi  # per radian
        self._c_theta = math.radians(params.c_theta)
        self._grid = np.arange(params.n) / params.n
        self._accel_half_width = params.accel_sigma * math.sqrt(3.0)

    def predict(self, dt: float) -> None:
        """Random acceleration, uniform with variance accel_sigma² (a quarter of the cost of
        Gaussian draws; summed over steps the motion noise is Gaussian all the same)."""
        a = self.rng.random((2, self.params.n))
        a -= 0.5
        a *= 2 * self._accel_half_width
        self.x[:2] += self.x[2:] * dt + a * (0.5 * dt * dt)
        self.x[2:] += a * dt

    def update(self, robot: tuple[float, float, float], s_r: float, s_theta: float) -> None:
        """One instantaneous fix: range s_r (m), bearing s_theta (rad) relative to the robot."""
        p = self.params
        if not self.initialised:
            bearing = robot[2] + s_theta
            self.x[0] = robot[0] + s_r * math.cos(bearing) + self.rng.normal(0, p.init_sigma, p.n)
            self.x[1] = robot[1] + s_r * math.sin(bearing) + self.rng.normal(0, p.init_sigma, p.n)
            self.x[2:] = 0.0
            self.initialised = True
            return
        dx = self.x[0] - robot[0]
        dy = self.x[1] - robot[1]
        err_r = np.abs(np.hypot(dx, dy) - s_r)
        err_t = np.arctan2(dy, dx) - (robot[2] + s_theta + math.pi)
        err_t %= 2 * math.pi
        err_t -= math.pi  # wrapped to [−π, π)
        w_r = np.minimum(np.maximum(1 - p.t_r * (err_r - p.c_r), 0.1), 1.0)
        w_t = np.minimum(np.maximum(1 - self._t_theta * (np.abs(err_t) - self._c_theta), 0.1), 1.0)
        self.w *= np.sqrt(w_r * w_t)
        self.w /= self.w.sum()
        if 1.0 / np.dot(self.w, self.w) < p.n / 2:
            self.resample()

    def resample(self) -> None:
        """Systematic resampling: one random offset, N evenly spaced pointers."""
        n = self.params.n
        idx = np.searchsorted(np.cumsum(self.w), self._grid + self.rng.random() / n)
        np.minimum(idx, n - 1, out=idx)
        self.x = self.x.take(idx, axis=1)
        self.w.fill(1.0 / n)
        self.resamples += 1

    def estimate(self) -> np.ndarray:
        """Weighted mean position (x, y)."""
        return self.x[:2] @ self.w

    def relative(self, robot: tuple[float, float, float]) -> tuple[float, float]:
        """(range m, bearing rad) of the estimate from the robot; the bearing is the circular
        weighted mean of the particles' bearings."""
        dx = self.x[0] - robot[0]
        dy = self.x[1] - robot[1]
        ang = np.arctan2(dy, dx) - robot[2]
        bearing = math.atan2(float(self.w @ np.sin(ang)), float(self.w @ np.cos(ang)))
        return float(self.w @ np.hypot(dx, dy)), bearing
