"""S4: localise static BLE beacons from RSSI on moving receivers, with an EKF or a UKF.

State per beacon: x = (p_1 … p_M, p_b), the M receiver positions and the beacon, each of
dimension D (2 or 3). Motion: x ← x + B u, with u the receivers' measured displacements
(B = [I; 0]: the beacon does not move) and process noise Q on the receivers only, scaled by the
step length (variable time step). Measurements: each receiver's position (R_pos) and, where the
receiver heard the beacon, its RSSI s_i = P0 − 10 n log10 |p_i − p_b| (R_rssi). A receiver
that heard nothing (NaN) contributes no information: its row of H is zero, which leaves the
update exactly as if the row were absent (the thesis's "missing receivers" future work).
Receivers carried ``height_m`` above the beacon (UAVs; S4 §3.1 sets the beacon's z_b = 0 and
does not estimate it) hear it at the 3-D distance, √(|p_i − p_b|² + h²), in the plane's state.

Everything is vectorised over K beacons (arrays with a leading K axis), so a campaign runs
thousands of beacons in one call; K = 1 is the single-beacon case.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LN10 = math.log(10.0)


@dataclass(frozen=True)
class S4Model:
    receivers: int = 3
    dim: int = 2
    p0_dbm: float = -40.23
    n: float = 2.0
    q: float = 0.05  # receiver process variance per nominal step (m²)
    r_pos: float = 0.05  # receiver position measurement variance (m²)
    r_rssi: float = 9.0  # RSSI measurement variance (dB²)
    nominal_dt: float = 0.1
    height_m: float = 0.0  # receivers above the beacon, known (S4: z_b = 0, the MAVs' height measured)

    @property
    def size(self) -> int:
        return (self.receivers + 1) * self.dim

    def distance(self, rssi: np.ndarray) -> np.ndarray:
        return 10 ** ((self.p0_dbm - rssi) / (10 * self.n))

    def ground_range(self, rssi: np.ndarray) -> np.ndarray:
        """The horizontal distance an RSSI stands for, receivers ``height_m`` above the beacon."""
        return np.sqrt(np.maximum(self.distance(rssi) ** 2 - self.height_m**2, 0.0))


def _split(model: S4Model, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, S) -> receivers (K, M, D), beacon (K, D)."""
    k = x.shape[0]
    return x[:, : model.receivers * model.dim].reshape(k, model.receivers, model.dim), x[:, -model.dim :]


def measure(model: S4Model, x: np.ndarray) -> np.ndarray:
    """h(x): receiver positions then RSSI per receiver, (K, M·D + M)."""
    rec, beacon = _split(model, x)
    dist = np.sqrt(np.sum((rec - beacon[:, None, :]) ** 2, axis=2) + model.height_m**2)
    rssi = model.p0_dbm - 10 * model.n * np.log10(np.maximum(dist, 1e-3))
    return np.concatenate([rec.reshape(x.shape[0], -1), rssi], axis=1)


def jacobian(model: S4Model, x: np.ndarray) -> np.ndarray:
    """∂h/∂x, (K, M·D + M, S)."""
    k, m, d = x.shape[0], model.receivers, model.dim
    rec, beacon = _split(model, x)
    h = np.zeros((k, m * d + m, model.size))
    h[:, : m * d, : m * d] = np.eye(m * d)
    diff = rec - beacon[:, None, :]
    dist2 = np.maximum(np.sum(diff**2, axis=2) + model.height_m**2, 1e-6)
    g = (-10 * model.n / LN10) * diff / dist2[:, :, None]  # ∂rssi_i/∂p_i, (K, M, D)
    for i in range(m):
        h[:, m * d + i, i * d : (i + 1) * d] = g[:, i]
        h[:, m * d + i, m * d :] = -g[:, i]
    return h


def _noise(model: S4Model, dt: float) -> tuple[np.ndarray, np.ndarray]:
    m, d = model.receivers, model.dim
    q = np.zeros(model.size)
    q[: m * d] = model.q * dt / model.nominal_dt
    r = np.concatenate([np.full(m * d, model.r_pos), np.full(m, model.r_rssi)])
    return np.diag(q), r


def _observation(model: S4Model, z_pos: np.ndarray, rssi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stacked measurement and its 'present' mask (False for missing RSSI)."""
    rssi = np.asarray(rssi, float)
    z = np.concatenate([np.asarray(z_pos, float).reshape(len(rssi), -1), np.nan_to_num(rssi)], axis=1)
    present = np.concatenate([np.ones((len(rssi), model.receivers * model.dim), bool), ~np.isnan(rssi)], axis=1)
    return z, present


class BeaconEkf:
    """Extended Kalman filter over K beacons at once.

    The step is written for its fixed shapes: H's constant identity block, R and I are built
    once (per K), h(x) and its Jacobian come from one shared difference, and the rest is
    a handful of batched matrix products, because at K = 1 numpy's per-call overhead, not
    arithmetic, is the cost (bench/estimation_bench.py). The x and p attributes stay plain
    arrays a caller may replace (s4_air grows K).
    """

    def __init__(self, model: S4Model, x0: np.ndarray, p0: np.ndarray) -> None:
        self.model = model
        self.x = np.array(x0, float).reshape(-1, model.size)
        self.p = np.broadcast_to(p0, (len(self.x), model.size, model.size)).copy()
        q, r = _noise(model, model.nominal_dt)
        self._q_nominal = q
        self._r = r
        self._r_diag = np.diag(r)
        self._eye = np.eye(model.size)
        self._h = np.zeros((0, len(r), model.size))  # Jacobian buffer, sized per K on first use
        self._slope = -10 * model.n / LN10  # as in jacobian()
        rd = model.receivers * model.dim
        self._g_rows = rd + np.repeat(np.arange(model.receivers), model.dim)
        self._g_cols = np.arange(rd)

    @property
    def beacon(self) -> np.ndarray:
        return self.x[:, -self.model.dim :]

    def predict(self, u: np.ndarray, dt: float | None = None) -> None:
        """u: receiver displacements (K, M·D) since the last step."""
        m = self.model
        q = self._q_nominal if dt is None else _noise(m, dt)[0]
        self.x[:, : m.receivers * m.dim] += np.asarray(u, float).reshape(len(self.x), -1)
        self.p += q

    def _jacobian_buffer(self, k: int) -> np.ndarray:
        if self._h.shape[0] != k:
            rd = self.model.receivers * self.model.dim
            self._h = np.zeros((k, len(self._r), self.model.size))
            self._h[:, :rd, :rd] = np.eye(rd)
        return self._h

    def update(self, z_pos: np.ndarray, rssi: np.ndarray) -> None:
        """z_pos: measured receiver positions (K, M·D); rssi: (K, M), NaN where not heard."""
        m = self.model
        x, k, rd, mr = self.x, len(self.x), m.receivers * m.dim, m.receivers
        rssi = np.asarray(rssi, float).reshape(k, mr)
        heard = rssi == rssi  # not NaN
        diff = x[:, :rd].reshape(k, mr, m.dim) - x[:, None, rd:]
        dist2 = np.maximum((diff * diff).sum(axis=2) + m.height_m**2, 1e-6)  # as measure()/jacobian() clamp
        y = np.empty((k, len(self._r)))
        y[:, :rd] = np.asarray(z_pos, float).reshape(k, rd) - x[:, :rd]
        y[:, rd:] = np.where(heard, rssi - (m.p0_dbm - 5 * m.n * np.log10(dist2)), 0.0)
        g = diff * (heard * self._slope / dist2)[:, :, None]  # unheard: a zero row
        h = self._jacobian_buffer(k)
        h[:, self._g_rows, self._g_cols] = g.reshape(k, rd)  # ∂rssi_i/∂p_i: block diagonal
        h[:, rd:, rd:] = -g
        hp = h @ self.p
        kt = np.linalg.solve(hp @ h.transpose(0, 2, 1) + self._r_diag, hp)  # Kᵀ = S⁻¹ H P (S, P symmetric)
        x += (y[:, None, :] @ kt)[:, 0]
        p = self.p - kt.transpose(0, 2, 1) @ hp  # P − K S Kᵀ, the Joseph form's value at the optimal gain
        self.p = 0.5 * (p + p.transpose(0, 2, 1))  # kept exactly symmetric


class BeaconUkf:
    """Unscented Kalman filter over K beacons at once (α = 1e-3, β = 2, κ = 0 as in S4)."""

    def __init__(self, model: S4Model, x0: np.ndarray, p0: np.ndarray,
                 alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0) -> None:
        self.model = model
        self.x = np.array(x0, float).reshape(-1, model.size)
        self.p = np.broadcast_to(p0, (len(self.x), model.size, model.size)).copy()
        n = model.size
        self.lam = alpha**2 * (n + kappa) - n
        self.wm = np.full(2 * n + 1, 1 / (2 * (n + self.lam)))
        self.wc = self.wm.copy()
        self.wm[0] = self.lam / (n + self.lam)
        self.wc[0] = self.wm[0] + 1 - alpha**2 + beta

    @property
    def beacon(self) -> np.ndarray:
        return self.x[:, -self.model.dim :]

    def _sigmas(self) -> np.ndarray:
        n = self.model.size
        sym = (self.p + self.p.transpose(0, 2, 1)) / 2
        root = np.linalg.cholesky((n + self.lam) * sym + 1e-12 * np.eye(n))  # (K, n, n), columns
        offsets = root.transpose(0, 2, 1)  # rows are the columns of the root
        return np.concatenate([self.x[:, None], self.x[:, None] + offsets, self.x[:, None] - offsets], axis=1)

    def predict(self, u: np.ndarray, dt: float | None = None) -> None:
        m = self.model
        q, _ = _noise(m, m.nominal_dt if dt is None else dt)
        self.x[:, : m.receivers * m.dim] += np.asarray(u, float).reshape(len(self.x), -1)
        self.p += q  # linear motion: the unscented transform would return exactly this

    def update(self, z_pos: np.ndarray, rssi: np.ndarray) -> None:
        m = self.model
        z, present = _observation(m, z_pos, rssi)
        _, r = _noise(m, m.nominal_dt)
        sig = self._sigmas()  # (K, 2n+1, n)
        k_, npts, n = sig.shape
        zs = measure(m, sig.reshape(-1, n)).reshape(k_, npts, -1) * present[:, None, :]
        z_mean = np.einsum("p,kpj->kj", self.wm, zs)
        dz = zs - z_mean[:, None]
        dx = sig - self.x[:, None]
        s = np.einsum("p,kpi,kpj->kij", self.wc, dz, dz) + np.diag(r)
        pxz = np.einsum("p,kpi,kpj->kij", self.wc, dx, dz)
        gain = np.linalg.solve(s, pxz.transpose(0, 2, 1)).transpose(0, 2, 1)
        self.x += np.einsum("kij,kj->ki", gain, (z - z_mean) * present)
        self.p -= gain @ s @ gain.transpose(0, 2, 1)


class CircleInitializer:
    """S4's initial beacon estimate, vectorised over K beacons.

    For ``n_init`` steps: low-pass each receiver's RSSI s_f ← (c_f s_f + s)/(c_f + 1), turn it
    into a distance, intersect every pair of receiver circles (of two intersections keep the one
    with the smaller summed distance to all circles), average the points, and keep a running
    mean over the steps. Initial covariance c_w / n_init on the beacon's x and y. In 3-D the
    circles are taken in the x-y plane and z starts at the receivers' mean height.
    """

    def __init__(self, model: S4Model, beacons: int, n_init: int = 30, c_f: float = 3.0, c_w: float = 500.0) -> None:
        self.model = model
        self.n_init, self.c_f, self.c_w = n_init, c_f, c_w
        self._sf = np.full((beacons, model.receivers), np.nan)
        self._sum = np.zeros((beacons, model.dim))
        self._count = np.zeros(beacons)
        self.steps = 0

    @property
    def ready(self) -> bool:
        return self.steps >= self.n_init

    def update(self, receivers: np.ndarray, rssi: np.ndarray) -> None:
        """receivers (K, M, D), rssi (K, M) with NaN where not heard."""
        rssi = np.asarray(rssi, float)
        filtered = np.where(np.isnan(self._sf), rssi, (self.c_f * self._sf + rssi) / (self.c_f + 1))
        self._sf = np.where(np.isnan(rssi), self._sf, filtered)  # a missing reading keeps the old value
        radius = self.model.ground_range(self._sf)
        centres = np.asarray(receivers, float)[:, :, :2]
        m = self.model.receivers
        points, valid = [], []
        for i in range(m):
            for j in range(i + 1, m):
                both = _intersections(centres[:, i], radius[:, i], centres[:, j], radius[:, j])
                # of two intersections keep the one with the smaller summed distance to all circles
                cost = [np.nansum(np.abs(np.linalg.norm(centres - p[:, None], axis=2) - radius), axis=1) for p in both]
                pick = np.where((cost[0] <= cost[1])[:, None], both[0], both[1])
                points.append(pick)
                valid.append(~np.isnan(pick).any(axis=1))
        pts = np.stack(points, axis=1)  # (K, pairs, 2)
        ok = np.stack(valid, axis=1)
        n_ok = ok.sum(axis=1)
        mean_xy = np.where(n_ok[:, None] > 0, np.nansum(np.where(ok[:, :, None], pts, 0), axis=1) / np.maximum(n_ok, 1)[:, None], np.nan)
        have = np.asarray(~np.isnan(mean_xy).any(axis=1))
        estimate = np.zeros((len(mean_xy), self.model.dim))
        estimate[:, :2] = np.nan_to_num(mean_xy)
        if self.model.dim == 3:
            estimate[:, 2] = np.asarray(receivers)[:, :, 2].mean(axis=1)
        self._sum += np.where(have[:, None], estimate, 0)
        self._count += have
        self.steps += 1

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """(beacon estimate (K, D), its covariance (K, D, D)); NaN where nothing intersected yet."""
        est = self._sum / np.where(self._count > 0, self._count, np.nan)[:, None]
        cov = np.broadcast_to(np.eye(self.model.dim) * self.c_w / self.n_init, (len(est), self.model.dim, self.model.dim))
        return est, cov.copy()


def _intersections(c1: np.ndarray, r1: np.ndarray, c2: np.ndarray, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two intersections of circles (c1, r1), (c2, r2), vectorised; circles that do not meet
    give the point on the line of centres where they come closest (both results equal)."""
    d_vec = c2 - c1
    d = np.linalg.norm(d_vec, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (r1**2 - r2**2 + d**2) / (2 * d)
        h = np.sqrt(np.maximum(r1**2 - a**2, 0.0))
        unit = d_vec / d[:, None]
    base = c1 + a[:, None] * unit
    perp = np.stack([-unit[:, 1], unit[:, 0]], axis=1)
    bad = (d < 1e-9) | np.isnan(r1) | np.isnan(r2)
    p1 = np.where(bad[:, None], np.nan, base + h[:, None] * perp)
    p2 = np.where(bad[:, None], np.nan, base - h[:, None] * perp)
    return p1, p2


def initial_state(model: S4Model, receivers: np.ndarray, beacon: np.ndarray, beacon_cov: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Filter state and covariance from receiver positions (K, M, D) and a beacon estimate."""
    k = len(beacon)
    x = np.concatenate([np.asarray(receivers, float).reshape(k, -1), beacon], axis=1)
    p = np.zeros((k, model.size, model.size))
    rd = model.receivers * model.dim
    p[:, :rd, :rd] = np.eye(rd) * model.r_pos
    p[:, rd:, rd:] = beacon_cov
    return x, p


def refine_batch(model: S4Model, receivers: np.ndarray, rssi: np.ndarray, beacon: np.ndarray,
                 offset_sigma_db: float = 2.0, iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """A smoother after the filter: the beacon position and one RSSI offset per receiver link,
    fitted jointly to every reading of the flight (Gauss-Newton, from the filter's estimate).

    The per-link offset (S4's μχ, drawn once per link) is a bias the forward filter cannot
    average away; jointly over the whole flight it is separable from range, because the
    receivers pass the beacon from many sides. The offsets carry a zero-mean prior of
    ``offset_sigma_db`` so that a link heard from one side only cannot trade its offset
    against range without bound. receivers (S, K, M, D) measured positions; rssi (S, K, M), NaN
    where unheard; beacon (K, D). Returns (beacon (K, D), offsets (K, M) dB)."""
    b = np.array(beacon, float)[:, :2].copy()
    k, m = b.shape[0], model.receivers
    pos = np.asarray(receivers, float)[..., :2]
    heard = ~np.isnan(rssi)
    s_obs = np.nan_to_num(rssi)
    offsets = np.zeros((k, m))
    slope = 10 * model.n / LN10
    prior = 1.0 / offset_sigma_db**2
    count = heard.sum(axis=0)  # readings per link, (K, M)
    px, py = pos[..., 0], pos[..., 1]
    for _ in range(iterations):
        dx, dy = px - b[None, :, None, 0], py - b[None, :, None, 1]  # p - b, (S, K, M)
        d2 = np.maximum(dx * dx + dy * dy + model.height_m**2, 1e-4)
        pred = model.p0_dbm + offsets[None] - 5 * model.n * np.log10(d2)
        r = np.where(heard, s_obs - pred, 0.0)
        w = np.where(heard, slope / d2, 0.0)
        gx, gy = w * dx, w * dy  # ∂pred/∂b, (S, K, M)
        a = np.zeros((k, 2 + m, 2 + m))
        a[:, 0, 0] = np.einsum("skm,skm->k", gx, gx)
        a[:, 1, 1] = np.einsum("skm,skm->k", gy, gy)
        a[:, 0, 1] = a[:, 1, 0] = np.einsum("skm,skm->k", gx, gy)
        a[:, 0, 2:] = a[:, 2:, 0] = gx.sum(axis=0)  # against ∂pred/∂o_m = 1
        a[:, 1, 2:] = a[:, 2:, 1] = gy.sum(axis=0)
        a[:, 2:, 2:] = (count + prior)[:, :, None] * np.eye(m)[None]
        rhs = np.concatenate([np.einsum("skm,skm->k", gx, r)[:, None], np.einsum("skm,skm->k", gy, r)[:, None],
                              r.sum(axis=0) - prior * offsets], axis=1)
        a[:, :2, :2] += np.eye(2) * 1e-3 * (a[:, 0, 0] + a[:, 1, 1])[:, None, None]  # damping
        step = np.linalg.solve(a, rhs[..., None])[..., 0]
        move = step[:, :2]
        norm = np.linalg.norm(move, axis=1, keepdims=True)
        b += move * np.minimum(1.0, 0.5 / np.maximum(norm, 1e-12))  # at most 0.5 m a step
        offsets += step[:, 2:]
    out = np.array(beacon, float).copy()
    out[:, :2] = b
    return out, offsets


def batch_cost(model: S4Model, receivers: np.ndarray, rssi: np.ndarray, beacon: np.ndarray, offsets: np.ndarray,
               offset_sigma_db: float = 2.0) -> np.ndarray:
    """What :func:`refine_batch` minimises, per beacon (K,): the squared RSSI residuals of the
    fit plus its offsets' prior -- so fits from several starts can be compared."""
    pos = np.asarray(receivers, float)[..., :2]
    heard = ~np.isnan(rssi)
    d2 = np.maximum(np.sum((pos - np.asarray(beacon, float)[None, :, None, :2]) ** 2, axis=3) + model.height_m**2, 1e-4)
    pred = model.p0_dbm + offsets[None] - 5 * model.n * np.log10(d2)
    r = np.where(heard, np.nan_to_num(rssi) - pred, 0.0)
    cost: np.ndarray = np.sum(r * r, axis=(0, 2)) + np.sum(offsets**2, axis=1) / offset_sigma_db**2
    return cost

