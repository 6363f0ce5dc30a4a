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

``likelihood = "bounded"`` is ours. Obstacles only attenuate, and a dish off its axis only loses
gain, so a fix's range reads long, almost never short: behind one 8 dB wall it is 2.5 times
the truth. S2's weights pull the cloud out to that phantom. The bounded weights take the range
as an upper bound: every distance up to ``range_slack`` times the fix's range weighs the same;
beyond that, the weight falls as a Gaussian in ln(distance / range). Bearings (Gaussian,
``bearing_sigma_deg``) place the emitter along the ray, and the robot's own motion
triangulates it. The emitter is static (positions diffuse slowly, no velocity). A floor keeps
one outlier from ruling a particle out. When the cloud explains a fix badly on average, a
tenth of it is redrawn from the fix (sensor resetting).
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
    likelihood: str = "s2"  # "s2": the weights above; "bounded": range as an upper bound (ours)
    bearing_sigma_deg: float = 20.0  # bounded: Gaussian bearing error
    range_slack: float = 1.3  # bounded: any distance up to this factor times the fix's range is as
    range_sigma_far: float = 0.15  # likely as any other; beyond, Gaussian in ln(distance / range)
    floor: float = 1e-3  # bounded: no fix can rule a particle out alone (outliers)
    diffusion: float = 0.05  # bounded: a static emitter; positions diffuse by this many m per √s
    inject_below: float = 0.05  # bounded: when the cloud explains a fix this badly on average,
    inject_fraction: float = 0.1  # redraw this share of particles from the fix itself


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
        self.injections = 0
        self._t_theta = params.t_theta * 180.0 / math.pi  # per radian
        self._c_theta = math.radians(params.c_theta)
        self._grid = np.arange(params.n) / params.n
        self._accel_half_width = params.accel_sigma * math.sqrt(3.0)

    def predict(self, dt: float) -> None:
        """S2: random acceleration, uniform with variance accel_sigma² (a quarter of the cost of
        Gaussian draws; summed over steps the motion noise is Gaussian all the same). Bounded:
        a static emitter, positions diffusing by ``diffusion`` m/√s."""
        if self.params.likelihood == "bounded":
            self.x[:2] += self.rng.normal(0, self.params.diffusion * math.sqrt(dt), (2, self.params.n))
            return
        a = self.rng.random((2, self.params.n))
        a -= 0.5
        a *= 2 * self._accel_half_width
        self.x[:2] += self.x[2:] * dt + a * (0.5 * dt * dt)
        self.x[2:] += a * dt

    def update(self, robot: tuple[float, float, float], s_r: float, s_theta: float) -> None:
        """One instantaneous fix: range s_r (m), bearing s_theta (rad) relative to the robot."""
        p = self.params
        if not self.initialised:
            self._initialise(robot, s_r, s_theta)
            return
        dx = self.x[0] - robot[0]
        dy = self.x[1] - robot[1]
        dist = np.hypot(dx, dy)
        err_t = np.arctan2(dy, dx) - (robot[2] + s_theta + math.pi)
        err_t %= 2 * math.pi
        err_t -= math.pi  # wrapped to [−π, π)
        if p.likelihood == "s2":
            w_r = np.minimum(np.maximum(1 - p.t_r * (np.abs(dist - s_r) - p.c_r), 0.1), 1.0)
            w_t = np.minimum(np.maximum(1 - self._t_theta * (np.abs(err_t) - self._c_theta), 0.1), 1.0)
            self.w *= np.sqrt(w_r * w_t)
        else:
            far = np.maximum(np.log(np.maximum(dist, 0.05) / s_r) - math.log(p.range_slack), 0.0)
            far /= p.range_sigma_far
            z = err_t / math.radians(p.bearing_sigma_deg)
            likelihood = p.floor + np.exp(-0.5 * (z * z + far * far))
            if float(self.w @ likelihood) < p.inject_below:  # the cloud is lost: reseed part of it
                k = int(p.inject_fraction * p.n)
                idx = self.rng.choice(p.n, k, replace=False)
                self.x[:2, idx] = self._from_fix(robot, s_r, s_theta, k)
                likelihood[idx] = 1.0
                self.w[idx] = 1.0 / p.n
                self.injections += 1
            self.w *= likelihood
        self.w /= self.w.sum()
        if 1.0 / np.dot(self.w, self.w) < p.n / 2:
            self.resample()

    def _initialise(self, robot: tuple[float, float, float], s_r: float, s_theta: float) -> None:
        """S2: a cloud around the first fix. Bounded: spread along the fix's ray up to its range,
        since walls and off-axis dishes only ever make a range read long."""
        p = self.params
        bearing = robot[2] + s_theta
        if p.likelihood == "s2":
            self.x[0] = robot[0] + s_r * math.cos(bearing) + self.rng.normal(0, p.init_sigma, p.n)
            self.x[1] = robot[1] + s_r * math.sin(bearing) + self.rng.normal(0, p.init_sigma, p.n)
        else:
            self.x[:2] = self._from_fix(robot, s_r, s_theta, p.n)
        self.x[2:] = 0.0
        self.initialised = True

    def _from_fix(self, robot: tuple[float, float, float], s_r: float, s_theta: float, k: int) -> np.ndarray:
        """k positions drawn from one fix: along its ray, at or inside its range."""
        p = self.params
        r = self.rng.uniform(min(0.2, s_r), s_r, k)
        a = robot[2] + s_theta + self.rng.normal(0, math.radians(p.bearing_sigma_deg), k)
        return np.stack([robot[0] + r * np.cos(a), robot[1] + r * np.sin(a)])

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
        return np.asarray(self.x[:2] @ self.w)

    def relative(self, robot: tuple[float, float, float]) -> tuple[float, float]:
        """(range m, bearing rad) of the estimate from the robot; the bearing is the circular
        weighted mean of the particles' bearings."""
        dx = self.x[0] - robot[0]
        dy = self.x[1] - robot[1]
        ang = np.arctan2(dy, dx) - robot[2]
        bearing = math.atan2(float(self.w @ np.sin(ang)), float(self.w @ np.cos(ang)))
        return float(self.w @ np.hypot(dx, dy)), bearing
