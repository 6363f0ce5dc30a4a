"""Constant-velocity Kalman filter on position fixes, with its noise in physical units.

State (x, y, z, vx, vy, vz). The process noise is a white acceleration of spectral density
``accel_psd`` (m^2/s^3): over dt it adds the standard CV covariance q*[[dt^3/3, dt^2/2],
[dt^2/2, dt]] per axis, so the setting means the same at 10 Hz and at 50 Hz. A fix whose
innovation is beyond ``gate`` (chi-square, 3 dof) is refused (counted); after
``max_misses`` refusals in a row the filter restarts from the next fix (the tag was moved).
"""

from __future__ import annotations

import math

import numpy as np

_P, _V = np.arange(3), np.arange(3, 6)  # position and velocity indices of the state


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
        """F = [[I, dt I], [0, I]] and Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]], set block
        by block (np.kron made them at several times the cost, a live fix tick's largest share)."""
        f = np.eye(6)
        f[_P, _V] = dt
        q = np.zeros((6, 6))
        q[_P, _P] = dt**3 / 3 * self.q
        q[_P, _V] = q[_V, _P] = dt**2 / 2 * self.q
        q[_V, _V] = dt * self.q
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


class BearingEkf(ConstantVelocity):
    """The same constant-velocity state, updated by each anchor's angle pair as it arrives
    (an extended Kalman filter on bearings) instead of by fixes.

    h(p) = the board angles of p seen from ``origin`` through ``rot`` (board -> world), in
    radians, board sign, read by the anchor's angle ``model`` (docs/estimation.md); its
    Jacobian is written out. A pair whose innovation is beyond ``gate`` (chi-square, 2 dof) is
    refused (a reflection, a fold) and leaves the state as it was, time included: the track's
    age then says how long the angles have disagreed with it. ``max_misses`` refusals in a row
    end the track (``t`` None, counted in ``restarts``): the tag jumped, and the caller starts
    it again from a fix. With ``height`` the z state is pinned after every update."""

    def __init__(self, accel_psd: float = 1.0, gate: float = 16.0, max_misses: int = 25) -> None:
        super().__init__(accel_psd, gate, max_misses)

    def start(self, t: float, point: np.ndarray, covariance: np.ndarray) -> None:
        self.t = None
        self.misses = 0
        self.update(t, point, covariance)

    def _miss(self) -> bool:
        self.misses += 1
        self.counters["gated"] += 1
        if self.misses >= self.max_misses:
            self.counters["restarts"] += 1
            self.t = None
            self.misses = 0
        return False

    def update_angles(self, t: float, origin: np.ndarray, rot: np.ndarray, azimuth_deg: float,
                      elevation_deg: float, sigma_deg: float, height: float | None = None,
                      model: str = "spherical") -> bool:
        if self.t is None:
            raise ValueError("start the filter from a first fix")
        f, q = self._transition(max(0.0, t - self.t))
        x = f @ self.x
        p = f @ self.p @ f.T + q
        d = rot.T @ (x[:3] - origin)
        rho2 = d[0] ** 2 + d[1] ** 2
        rho = np.sqrt(rho2)
        r2 = rho2 + d[2] ** 2
        if rho < 1e-6 or d[0] < 0:  # on the anchor, or behind its plane: no usable angle
            return self._miss()
        if model == "cone":
            r = math.sqrt(r2)
            sy, sz = d[1] / r, d[2] / r
            predicted = np.array([-math.asin(sy), math.asin(sz)])
            # d(asin(d_k / r))/dd = (e_k - (d_k / r) d / r) / (r sqrt(1 - (d_k / r)^2))
            g_y = (np.array([0.0, 1.0, 0.0]) - sy * d / r) / (r * math.sqrt(max(1e-9, 1 - sy * sy)))
            g_z = (np.array([0.0, 0.0, 1.0]) - sz * d / r) / (r * math.sqrt(max(1e-9, 1 - sz * sz)))
            jac_d = np.array([-g_y, g_z])
        else:
            predicted = np.array([-np.arctan2(d[1], d[0]), np.arctan2(d[2], rho)])
            jac_d = np.array([[d[1] / rho2, -d[0] / rho2, 0.0],
                              [-d[0] * d[2] / (rho * r2), -d[1] * d[2] / (rho * r2), rho / r2]])
        h = np.zeros((2, 6))
        h[:, :3] = jac_d @ rot.T
        innovation = np.radians([azimuth_deg, elevation_deg]) - predicted
        pht = p @ h.T
        (a, b), (c, e) = (h @ pht).tolist()
        var = math.radians(sigma_deg) ** 2
        a, e = a + var, e + var
        s_inv = np.array([[e, -b], [-c, a]]) / (a * e - b * c)  # 2 x 2: cheaper than LAPACK
        d2 = float(innovation @ s_inv @ innovation)
        if d2 > self.gate:
            return self._miss()
        self.t = max(t, self.t)
        self.misses = 0
        k = pht @ s_inv
        self.x = x + k @ innovation
        self.p = p - k @ (h @ p)
        self.p = (self.p + self.p.T) / 2  # rounding makes P - KHP drift from symmetric
        if height is not None:
            self.x[2], self.x[5] = height, 0.0
            self.p[[2, 5], :] = 0.0
            self.p[:, [2, 5]] = 0.0
        self.counters["updates"] += 1
        return True


def rts_smooth(times: np.ndarray, points: np.ndarray, covariances: np.ndarray, accel_psd: float = 1.0,
               gate: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel smoothing of one tag's fixes over a whole recording: the same
    constant-velocity model as :class:`ConstantVelocity` run forward, then backward, so each
    position rests on the fixes after it as well as before (not causal: recordings only).
    A fix beyond ``gate`` of the forward prediction is left out (the forward filter coasts).
    Returns (states (N, 6): position and velocity, position covariances (N, 3, 3)) at ``times``."""
    cv = ConstantVelocity(accel_psd, gate, max_misses=10**9)
    n = len(times)
    xs_f, ps_f, xs_p, ps_p, fs = [], [], [], [], []
    for k in range(n):
        if cv.t is None:
            cv.update(times[k], points[k], covariances[k])
            f = np.eye(6)
            xs_p.append(cv.x.copy())
            ps_p.append(cv.p.copy())
        else:
            f, q = cv._transition(max(0.0, times[k] - cv.t))
            xs_p.append(f @ cv.x)
            ps_p.append(f @ cv.p @ f.T + q)
            if not cv.update(times[k], points[k], covariances[k]):
                cv.x, cv.p, cv.t = xs_p[-1], ps_p[-1], max(cv.t, times[k])
        fs.append(f)
        xs_f.append(cv.x.copy())
        ps_f.append(cv.p.copy())
    xs, ps = list(xs_f), list(ps_f)
    for k in range(n - 2, -1, -1):
        f = fs[k + 1]
        gain = ps_f[k] @ f.T @ np.linalg.pinv(ps_p[k + 1])
        xs[k] = xs_f[k] + gain @ (xs[k + 1] - xs_p[k + 1])
        ps[k] = ps_f[k] + gain @ (ps[k + 1] - ps_p[k + 1]) @ gain.T
    return np.array(xs), np.array([p[:3, :3] for p in ps])
