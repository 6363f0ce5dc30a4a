"""Constant-velocity Kalman filter on position fixes, with its noise in physical units.

State (x, y, z, vx, vy, vz). The process noise is a white acceleration of spectral density
``accel_psd`` (m^2/s^3): over dt it adds the standard CV covariance q*[[dt^3/3, dt^2/2],
[dt^2/2, dt]] per axis, so the setting means the same at 10 Hz and at 50 Hz. A fix whose
innovation is beyond ``gate`` (chi-square, 3 dof) is refused (counted); after
``max_misses`` refusals in a row the filter restarts from the next fix (the tag was moved).
"""

from __future__ import annotations

import numpy as np


class ConstantVelocity:
    def __init__(self, accel_psd: float = 1.0, gate: float = 25.0, max_misses: int = 3) -> None:
        self.q = accel_psd
        self.gate = gate
        self.max_misses = max_misses
        self.t: float | None = None
        self.x = np.zeros(6)
        self.p = np.eye(6)
        self.misses = 0
        self.counters = {"updates": 0, "gated": 0, "restarts": 0}

    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        f = np.eye(6)
        f[:3, 3:] = dt * np.eye(3)
        q = np.zeros((6, 6))
        q[:3, :3] = dt**3 / 3 * self.q * np.eye(3)
        q[:3, 3:] = q[3:, :3] = dt**2 / 2 * self.q * np.eye(3)
        q[3:, 3:] = dt * self.q * np.eye(3)
        return f, q

    def predicted(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, its covariance) at ``t`` without changing the state."""
        if self.t is None:
            raise ValueError("no fix yet")
        f, q = self._transition(max(0.0, t - self.t))
        x = f @ self.x
        p = f @ self.p @ f.T + q
        return x[:3], p[:3, :3]

    def update(self, t: float, z: np.ndarray, r: np.ndarray) -> bool:
        """Take a fix ``z`` (3,) with covariance ``r`` (3, 3) made at ``t``; False if gated out.
        A fix older than the state is taken at the state's time (late by < one window)."""
        r = r + np.diag(np.where(np.diag(r) <= 0, 1e-6, 0.0))  # a known height: z pinned, not singular
        if self.t is None:
            self.x = np.concatenate([z, np.zeros(3)])
            self.p = np.zeros((6, 6))
            self.p[:3, :3] = r
            self.p[3:, 3:] = np.eye(3) * 1.0  # walking speed, unknown direction: 1 m/s sigma
            self.t = t
            return True
        f, q = self._transition(max(0.0, t - self.t))
        x = f @ self.x
        p = f @ self.p @ f.T + q
        s = p[:3, :3] + r
        innovation = z - x[:3]
        d2 = float(innovation @ np.linalg.solve(s, innovation))
        self.t = max(t, self.t)
        if d2 > self.gate:
            self.x, self.p = x, p
            self.misses += 1
            self.counters["gated"] += 1
            if self.misses >= self.max_misses:
                self.counters["restarts"] += 1
                self.t = None
                self.misses = 0
            return False
        k = p[:, :3] @ np.linalg.inv(s)
        self.x = x + k @ innovation
        self.p = p - k @ p[:3, :]
        self.misses = 0
        self.counters["updates"] += 1
        return True
