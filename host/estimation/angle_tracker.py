"""A walking tag tracked on every anchor's angles, each anchor's slow error a state of its own.

Real XPLR-AOA angles (docs/estimation.md, "Real angles") are not independent reports around
the truth: an anchor's error wanders (multipath as the walker moves: correlated over one to a
few seconds, tens while the walker stands), and a few reports are far off (a reflection, a lost
lock). Averaging consecutive reports as if independent trusts an anchor that has merely repeated
its error forty times. So the state holds, beside the tag's position and velocity, each anchor's
current azimuth and elevation error ``b`` (degrees), an Ornstein-Uhlenbeck process of standard
deviation ``slow_deg`` and correlation time ``slow_s``; a report is

    reported = compress(h(p)) + b_anchor + white noise (sigma ``white_deg`` / cos(angle off boresight))

with h the anchor's angle model (anchors3d) and compress the boards' |azimuth| compression. The
update is an extended Kalman filter's with a Student-t likelihood (``dof``): a report whose
innovation is far beyond its covariance -- which includes the slow error the state already
carries, so a slow error is not mistaken for an outlier -- has its noise inflated by
(dof + d2) / (dof + m) (one step of the t-distribution's variational update) and pulls little.
A report repeated adds little because, once the slow error is known as well as the reports tell
it, another report mostly confirms it: the weighting by what a report adds follows from the
state, not from a window.

Missing reports need nothing: the states predict over any gap. Elevation from high wall anchors
says little about the range: its noise is wider (``el_white_deg``), and a known tag height pins
z (or, with ``height_sigma``, is a prior). The tag moves as a constant-velocity model with white
acceleration ``accel_psd`` (m^2/s^3), which also lets it stand.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rfhoming.host.estimation.anchors3d import MIN_RANGE_M
from rfhoming.host.estimation.extent import Extent

HEIGHT_S = 2.0
"""With a height prior (``height_sigma``), how long the tag's height takes to wander (s)."""


@dataclass(frozen=True)
class AngleNoise:
    """The reports' error model (degrees, seconds); defaults chosen by cross-validation on real
    recordings (docs/estimation.md, "How the defaults were chosen")."""

    white_deg: float = 8.0
    """Azimuth noise of one report at boresight, independent from report to report."""
    slow_deg: float = 4.5
    """The slow azimuth error's standard deviation (per anchor)."""
    slow_s: float = 2.0
    """Its correlation time."""
    el_white_deg: float = 12.0
    el_slow_deg: float = 5.0
    el_slow_s: float = 2.0
    dof: float = 2.0
    """Student-t degrees of freedom of the reports (small: heavy tails; 0: Gaussian)."""
    max_cos_factor: float = 6.0
    """The white noise grows as 1 / cos(angle off boresight), at most this many times."""


@dataclass
class _Anchor:
    origin: np.ndarray
    rot: np.ndarray  # board -> world
    cone: bool


class AngleTracker:
    """Position, velocity and each anchor's slow (azimuth, elevation) error, updated by every report.

    ``start`` from a first fix; ``predicted(t)`` gives the position at ``t`` without changing the
    state; ``update(t, k, az, el)`` takes anchor ``k``'s report (degrees, already corrected by
    its calibration) and returns the report's squared Mahalanobis distance. ``lost`` turns true
    after ``max_far`` reports in a row beyond ``far`` (chi-square, 2 dof): the tag is not where
    the state says, and the caller starts again from a fix."""

    def __init__(self, origins: Sequence[Sequence[float]], rotations: Sequence[np.ndarray], models: Sequence[str],
                 noise: AngleNoise = AngleNoise(), accel_psd: float = 0.1, height: float | None = None,
                 height_sigma: float | None = None, compression: float = 0.0, far: float = 100.0,
                 max_far: int = 40) -> None:
        """``compression``: the boards' |azimuth| compression c, reported = a (1 - c (a / 90)^2)
        before the slow error and the noise (the site's az_compression)."""
        self.anchors = [_Anchor(np.asarray(o, float), np.asarray(r, float), m == "cone")
                        for o, r, m in zip(origins, rotations, models)]
        self.noise = noise
        self.q = accel_psd
        self.height = height
        self.height_sigma = height_sigma
        self.compression = compression
        self.far = far
        self.max_far = max_far
        n_a = len(self.anchors)
        self.n = 6 + 2 * n_a
        self.t: float | None = None
        self.x = np.zeros(self.n)
        self.p = np.eye(self.n)
        self.far_in_row = 0
        self.counters = {"updates": 0, "downweighted": 0, "restarts": 0}
        self.log_density = 0.0
        """The sum over updates of each report's predictive log density under the model
        (Student-t, up to a constant): how well the state foresaw the reports."""

    @property
    def lost(self) -> bool:
        return self.t is None

    def hold(self, extent: Extent) -> bool:
        """The state back inside ``extent`` (Extent.hold); True when it was outside."""
        return self.t is not None and extent.hold(self.x)

    def renoise(self, noise: AngleNoise) -> None:
        """Go on with another report model (the slow errors' spread in the state adapts as it predicts)."""
        self.noise = noise

    def start(self, t: float, point: np.ndarray, covariance: np.ndarray, speed_sigma: float = 1.0) -> None:
        """(Re)start at a fix: its position and covariance, velocity unknown (``speed_sigma`` m/s),
        every slow error at zero with its stationary spread."""
        n_a = len(self.anchors)
        self.x = np.zeros(self.n)
        self.x[:3] = point
        self.p = np.zeros((self.n, self.n))
        self.p[:3, :3] = covariance + np.eye(3) * 1e-4
        self.p[3:6, 3:6] = np.eye(3) * speed_sigma**2
        if self.height is not None:
            self.p[5, 5] = 0.0
            if self.height_sigma is not None:
                self.x[2] = self.height
                self.p[2, :] = self.p[:, 2] = 0.0
                self.p[2, 2] = self.height_sigma**2
        self.p[6:6 + n_a, 6:6 + n_a] = np.eye(n_a) * self.noise.slow_deg**2
        self.p[6 + n_a:, 6 + n_a:] = np.eye(n_a) * self.noise.el_slow_deg**2
        self.t = t
        self.far_in_row = 0
        self._pin()

    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        n_a, nz = len(self.anchors), self.noise
        f_diag = np.ones(self.n)
        q_diag = np.zeros(self.n)
        a, e = math.exp(-dt / nz.slow_s), math.exp(-dt / nz.el_slow_s)
        f_diag[6:6 + n_a], q_diag[6:6 + n_a] = a, nz.slow_deg**2 * (1 - a * a)
        f_diag[6 + n_a:], q_diag[6 + n_a:] = e, nz.el_slow_deg**2 * (1 - e * e)
        if self.height is not None and self.height_sigma is not None:  # z wanders about the height
            h = math.exp(-dt / HEIGHT_S)
            f_diag[[2, 5]] = h, 0.0
            q_diag[2] = self.height_sigma**2 * (1 - h * h)
        return f_diag, q_diag

    def _propagate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The state and covariance predicted to ``t`` (no earlier than the state's time)."""
        assert self.t is not None
        dt = max(0.0, t - self.t)
        if dt == 0.0:
            return self.x.copy(), self.p.copy()
        f_diag, q_diag = self._transition(dt)
        x = self.x * f_diag
        x[:3] += dt * self.x[3:6]
        if self.height is not None and self.height_sigma is not None:
            x[2] += (1 - f_diag[2]) * self.height
        # P' = F P F^T + Q with F = diag(f) plus dt at (position, velocity): done by blocks
        p = self.p * np.outer(f_diag, f_diag)
        pv = self.p[3:6, :] * f_diag[None, :]
        p[:3, :] += dt * pv
        p[:, :3] += dt * pv.T
        p[:3, :3] += dt * dt * self.p[3:6, 3:6]
        p[np.diag_indices(self.n)] += q_diag
        q = self.q
        for i in range(2 if self.height is not None else 3):
            p[i, i] += q * dt**3 / 3
            p[i, i + 3] += q * dt**2 / 2
            p[i + 3, i] += q * dt**2 / 2
            p[i + 3, i + 3] += q * dt
        return x, p

    def predicted(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, its covariance) at ``t``, the state unchanged."""
        if self.t is None:
            raise ValueError("start the tracker from a first fix")
        x, p = self._propagate(t)
        return x[:3], p[:3, :3]

    def _pin(self) -> None:
        if self.height is not None and self.height_sigma is None:
            self.x[2], self.x[5] = self.height, 0.0
            self.p[[2, 5], :] = 0.0
            self.p[:, [2, 5]] = 0.0

    def _measure(self, k: int, point: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Anchor ``k``'s predicted report (degrees), its Jacobian by the position (2, 3) and
        the board-frame range along the boresight (m; <= 0 behind the board)."""
        anc = self.anchors[k]
        d = anc.rot.T @ (point - anc.origin)
        deg = 180.0 / math.pi
        if anc.cone:
            r = math.sqrt(float(d @ d))
            sy, sz = d[1] / r, d[2] / r
            angles = np.array([-math.asin(sy), math.asin(sz)]) * deg
            g_y = (np.array([0.0, 1.0, 0.0]) - sy * d / r) / (r * math.sqrt(max(1e-9, 1 - sy * sy)))
            g_z = (np.array([0.0, 0.0, 1.0]) - sz * d / r) / (r * math.sqrt(max(1e-9, 1 - sz * sz)))
            jac = np.array([-g_y, g_z]) * deg
        else:
            rho2 = max(d[0] ** 2 + d[1] ** 2, 1e-12)
            rho = math.sqrt(rho2)
            r2 = rho2 + d[2] ** 2
            angles = np.array([-math.atan2(d[1], d[0]), math.atan2(d[2], rho)]) * deg
            jac = np.array([[d[1] / rho2, -d[0] / rho2, 0.0],
                            [-d[0] * d[2] / (rho * r2), -d[1] * d[2] / (rho * r2), rho / r2]]) * deg
        c = self.compression
        if c:
            a = angles[0] / 90.0
            jac[0] *= 1 - 3 * c * a * a
            angles[0] *= 1 - c * a * a
        return angles, jac @ anc.rot.T, float(d[0])

    def update(self, t: float, k: int, azimuth_deg: float, elevation_deg: float) -> float:
        """Take anchor ``k``'s report at ``t``; the report's squared Mahalanobis distance (nan
        when it could not be used: the state puts the tag behind the board)."""
        if self.t is None:
            raise ValueError("start the tracker from a first fix")
        x, p = self._propagate(t)
        n_a, nz = len(self.anchors), self.noise
        angles, jac, ahead = self._measure(k, x[:3])
        if ahead < MIN_RANGE_M:
            self.x, self.p, self.t = x, p, max(t, self.t)
            return math.nan
        ba, be = 6 + k, 6 + n_a + k
        miss = (azimuth_deg - angles[0] - x[ba] + 180.0) % 360.0 - 180.0  # a board that sees all round: +-180 meet
        innovation = np.array([miss, elevation_deg - angles[1] - x[be]])
        off = max(math.cos(math.radians(angles[0])) * math.cos(math.radians(angles[1])), 1.0 / nz.max_cos_factor)
        r_diag = np.array([(nz.white_deg / off) ** 2, (nz.el_white_deg / off) ** 2])
        # P H^T for H = [jac | 0 | e_ba | e_be]: the position columns through jac, one column each bias
        pht = p[:, :3] @ jac.T
        pht[:, 0] += p[:, ba]
        pht[:, 1] += p[:, be]
        hph = jac @ pht[:3] + np.array([pht[ba], pht[be]])
        s = hph + np.diag(r_diag)
        s_inv = _inverse2(s)
        d2 = float(innovation @ s_inv @ innovation)
        self.log_density += _log_density(d2, float(s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]), nz.dof)
        if nz.dof > 0:
            w = (nz.dof + 2.0) / (nz.dof + d2)
            if w < 1.0:  # a report far off: its noise inflated (Student-t), it pulls little
                s_inv = _inverse2(hph + np.diag(r_diag / w))
                self.counters["downweighted"] += 1
        gain = pht @ s_inv
        self.x = x + gain @ innovation
        self.p = p - gain @ pht.T
        self.p = (self.p + self.p.T) / 2
        self.t = max(t, self.t)
        self._pin()
        self.counters["updates"] += 1
        self.far_in_row = self.far_in_row + 1 if d2 > self.far else 0
        if self.far_in_row >= self.max_far:
            self.t = None
            self.counters["restarts"] += 1
        return d2


def _inverse2(s: np.ndarray) -> np.ndarray:
    (a, b), (c, d) = s.tolist()
    inverse: np.ndarray = np.array([[d, -b], [-c, a]]) / (a * d - b * c)
    return inverse


def _log_density(d2: float, det: float, dof: float) -> float:
    """A 2-D report's predictive log density (less the constants): Student-t of ``dof`` (0: Gaussian)."""
    spread = -0.5 * math.log(max(det, 1e-300))
    return spread - (0.5 * d2 if dof <= 0 else (dof + 2) / 2 * math.log1p(d2 / dof))


class TrackerBank:
    """Several :class:`AngleTracker` s that differ only in how the tag moves (their white
    acceleration), run side by side on the same reports; the position is their mixture, each
    weighted by how well it has foreseen the recent reports (its predictive density, with
    ``forget`` per report so that a walker who turns or stops moves the weight within seconds).
    A steady walker is followed by the smooth model, a turn or a start by the agile one."""

    def __init__(self, trackers: Sequence[AngleTracker], forget: float = 0.98) -> None:
        self.trackers = list(trackers)
        self.forget = forget
        self.log_weights = np.zeros(len(self.trackers))
        self.counters = self.trackers[0].counters  # the first's: one count per report
        self.log_density = 0.0
        """The sum of each report's predictive log density under the mixture."""

    @property
    def t(self) -> float | None:
        return self.trackers[0].t

    @property
    def lost(self) -> bool:
        return any(tr.lost for tr in self.trackers)

    def renoise(self, noise: AngleNoise) -> None:
        for tr in self.trackers:
            tr.renoise(noise)

    def hold(self, extent: Extent) -> bool:
        """Each tracker's state back inside ``extent`` (Extent.hold); True when one was outside."""
        return any([extent.hold(tr.x) for tr in self.trackers])

    def start(self, t: float, point: np.ndarray, covariance: np.ndarray) -> None:
        for tr in self.trackers:
            tr.start(t, point, covariance)
        self.log_weights[:] = 0.0

    def weights(self) -> np.ndarray:
        w = np.exp(self.log_weights - self.log_weights.max())
        return np.asarray(w / w.sum())

    def predicted(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        w = self.weights()
        parts = [tr.predicted(t) for tr in self.trackers]
        mean = sum(wk * p for wk, (p, _) in zip(w, parts))
        cov = sum(wk * (c + np.outer(p - mean, p - mean)) for wk, (p, c) in zip(w, parts))
        return np.asarray(mean), np.asarray(cov)

    def update(self, t: float, k: int, azimuth_deg: float, elevation_deg: float) -> float:
        before = [tr.log_density for tr in self.trackers]
        d2 = [tr.update(t, k, azimuth_deg, elevation_deg) for tr in self.trackers]
        gained = np.array([tr.log_density - b for tr, b in zip(self.trackers, before)])
        top = float(gained.max())
        self.log_density += top + math.log(float(self.weights() @ np.exp(gained - top)))
        self.log_weights = self.forget * self.log_weights + gained
        if any(tr.lost for tr in self.trackers):
            for tr in self.trackers:
                tr.t = None
        return d2[0]
