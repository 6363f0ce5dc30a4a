"""S2: direction from four directional antennas, and the particle filter that tracks the emitter.

Axis convention (robot frame, counter-clockwise): antenna x1 looks along the heading, x2
backwards, y1 to the left, y2 to the right. With powers in dB,

    θ = atan2(y1 − y2, x1 − x2)      (0 = ahead, +90° = left; quadrant-correct)
    r = √((x1 − x2)² + (y1 − y2)²)   (dB, mapped to metres by the calibration A1, A2)

S2 writes θ = arctan((x1 − x2)/(y1 − y2)); we use the quadrant-correct form in our own axes.
S2 maps r to metres with a calibration (A1, A2) whose values it does not give; we take the
range from the strongest antenna's power, its dish gain removed, through the emitter's
log-distance model (:func:`differential_to_range`).

Particle filter (N = 1000, global frame, random-acceleration motion): per particle, the
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
    accel_sigma: float = 0.2  # m/s² (random acceleration of the emitter)
    init_sigma: float = 1.0  # m around the first fix


class ParticleFilter:
    """Emitter position and velocity in the world frame, from relative (range, bearing) fixes."""

    def __init__(self, params: PfParams = PfParams(), rng: np.random.Generator | None = None) -> None:
        self.params = params
        self.rng = rng or np.random.default_rng()
        self.x = np.zeros((params.n, 4))  # x, y, vx, vy
        self.w = np.full(params.n, 1.0 / params.n)
        self.initialised = False
        self.resamples = 0

    def _fix_to_world(self, robot: tuple[float, float, float], s_r: float, s_theta: float) -> np.ndarray:
        bearing = robot[2] + s_theta
        return np.array([robot[0] + s_r * math.cos(bearing), robot[1] + s_r * math.sin(bearing)])

    def predict(self, dt: float) -> None:
        a = self.rng.normal(0, self.params.accel_sigma, (self.params.n, 2))
        self.x[:, :2] += self.x[:, 2:] * dt + 0.5 * a * dt * dt
        self.x[:, 2:] += a * dt

    def update(self, robot: tuple[float, float, float], s_r: float, s_theta: float) -> None:
        """One instantaneous fix: range s_r (m), bearing s_theta (rad) relative to the robot."""
        p = self.params
        if not self.initialised:
            centre = self._fix_to_world(robot, s_r, s_theta)
            self.x[:, :2] = centre + self.rng.normal(0, p.init_sigma, (p.n, 2))
            self.x[:, 2:] = 0.0
            self.initialised = True
            return
        dx = self.x[:, 0] - robot[0]
        dy = self.x[:, 1] - robot[1]
        p_r = np.hypot(dx, dy)
        p_theta = np.degrees(np.arctan2(dy, dx) - robot[2])
        err_theta = np.abs((p_theta - math.degrees(s_theta) + 180.0) % 360.0 - 180.0)
        w_r = np.clip(1 - p.t_r * (np.abs(p_r - s_r) - p.c_r), 0.1, 1.0)
        w_t = np.clip(1 - p.t_theta * (err_theta - p.c_theta), 0.1, 1.0)
        self.w *= np.sqrt(w_r * w_t)
        self.w /= self.w.sum()
        if 1.0 / np.sum(self.w**2) < p.n / 2:
            self.resample()

    def resample(self) -> None:
        """Systematic resampling: one random offset, N evenly spaced pointers."""
        n = self.params.n
        positions = (self.rng.random() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(np.cumsum(self.w), positions), n - 1)
        self.x = self.x[idx]
        self.w = np.full(n, 1.0 / n)
        self.resamples += 1

    def estimate(self) -> np.ndarray:
        """Weighted mean position (x, y)."""
        return self.w @ self.x[:, :2]

    def relative(self, robot: tuple[float, float, float]) -> tuple[float, float]:
        """(range m, bearing rad) of the estimate from the robot; the bearing is the circular
        weighted mean of the particles' bearings."""
        dx = self.x[:, 0] - robot[0]
        dy = self.x[:, 1] - robot[1]
        ang = np.arctan2(dy, dx) - robot[2]
        bearing = math.atan2(float(self.w @ np.sin(ang)), float(self.w @ np.cos(ang)))
        return float(self.w @ np.hypot(dx, dy)), bearing
