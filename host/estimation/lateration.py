"""Position from distances to known anchors: S3's trilateration and least-squares multilateration.

Both detect degenerate geometry (collinear or coincident anchors) and raise
:class:`~host.estimation.bearings.Degenerate` instead of returning nonsense.
"""

from __future__ import annotations

import contextlib

import numpy as np

from rfhoming.host.estimation.bearings import Degenerate

MIN_AREA_M2 = 0.05
"""Anchors spanning a smaller triangle are treated as collinear."""


def trilaterate(anchors: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """S3's closed form from the first three anchors (typo in the paper's last step corrected):
    A1 x + C1 y = B, A2 x + C2 y = D."""
    (x1, y1), (x2, y2), (x3, y3) = np.asarray(anchors, float)[:3]
    d1, d2, d3 = np.asarray(distances, float)[:3]
    a1, a2 = -2 * (x1 - x2), -2 * (x1 - x3)
    c1, c2 = -2 * (y1 - y2), -2 * (y1 - y3)
    b = d1**2 - d2**2 - (x1**2 + y1**2) + (x2**2 + y2**2)
    d = d1**2 - d3**2 - (x1**2 + y1**2) + (x3**2 + y3**2)
    det = a1 * c2 - c1 * a2
    if abs(det) / 8 < MIN_AREA_M2:  # det = 8 × triangle area
        raise Degenerate("the three anchors are (nearly) collinear")
    return np.array([(b * c2 - c1 * d) / det, (a1 * d - a2 * b) / det])


def strongest_three(rssi: np.ndarray) -> np.ndarray:
    """Indices of the three strongest readings (S3 uses 3 of its 4 beacons)."""
    return np.argsort(np.asarray(rssi))[::-1][:3]


def multilaterate(anchors: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """Least squares X = (AᵀA)⁻¹AᵀB with rows A_i = 2(x1 − x_i, y1 − y_i),
    B_i = d_i² − d1² − (x_i² + y_i²) + (x1² + y1²), i = 2..N."""
    p = np.asarray(anchors, float).reshape(-1, 2)
    d = np.asarray(distances, float).ravel()
    if len(p) < 3:
        raise Degenerate("need at least three anchors")
    a = 2 * (p[0] - p[1:])
    b = d[1:] ** 2 - d[0] ** 2 - np.sum(p[1:] ** 2, axis=1) + np.sum(p[0] ** 2)
    if np.linalg.matrix_rank(a, tol=1e-6) < 2 or np.linalg.cond(a) > 1e6:
        raise Degenerate("the anchors are (nearly) collinear")
    x: np.ndarray = np.linalg.lstsq(a, b, rcond=None)[0]
    return x


def rssi_position(anchors: np.ndarray, rssi_dbm: np.ndarray, p0_dbm: float, n: float,
                  huber_db: float = 3.0, max_range_m: float = 10.0, iterations: int = 30) -> np.ndarray:
    """The position whose log-distance RSSI, P0 − 10 n log10(d_i), best meets the readings, in
    dB with a Huber loss (``huber_db``): iteratively reweighted Gauss-Newton from the linear
    least squares of the ranges and from the anchors' centroid, the lower cost kept.

    Beside :func:`multilaterate`: RSSI errors are about equal in dB on every link, so a far
    link's range is worse in metres (the dB fit weighs each link by that, the squared ranges
    of the linear form do the opposite), and one link off by a wall or a fade is held to a
    linear, not a squared, cost."""
    p = np.asarray(anchors, float).reshape(-1, 2)
    z = np.asarray(rssi_dbm, float).ravel()
    if len(p) < 3 or len(z) != len(p):
        raise Degenerate("need at least three anchors, one reading each")
    a = p[1:] - p[0]
    if np.linalg.matrix_rank(a, tol=1e-6) < 2:
        raise Degenerate("the anchors are (nearly) collinear")
    slope = 10 * n / np.log(10)

    def cost(x: np.ndarray) -> float:
        r = np.abs(z - (p0_dbm - 10 * n * np.log10(np.maximum(np.linalg.norm(x - p, axis=1), 0.1))))
        return float(np.sum(np.where(r <= huber_db, 0.5 * r**2, huber_db * (r - 0.5 * huber_db))))

    starts = [p.mean(axis=0)]
    with contextlib.suppress(Degenerate):
        ranges = np.minimum(10 ** ((p0_dbm - z) / (10 * n)), max_range_m)
        starts.append(multilaterate(p, ranges))
    best: np.ndarray | None = None
    for x in starts:
        for _ in range(iterations):
            diff = x - p
            d2 = np.maximum(np.sum(diff**2, axis=1), 0.01)
            r = z - (p0_dbm - 5 * n * np.log10(d2))  # reading − model
            w = np.where(np.abs(r) <= huber_db, 1.0, huber_db / np.maximum(np.abs(r), 1e-9))
            jac = slope * diff / d2[:, None]  # d(reading − model)/dx
            h = jac.T @ (w[:, None] * jac) + 1e-6 * np.eye(2)
            step = -np.linalg.solve(h, jac.T @ (w * r))
            norm = float(np.linalg.norm(step))
            if norm > 1.0:  # a trust region: far from the anchors the dB surface is flat
                step *= 1.0 / norm
            x = x + step
            if norm < 1e-4:
                break
        if best is None or cost(x) < cost(best):
            best = x
    assert best is not None
    return best


def offset_and_links(anchors: np.ndarray, which: np.ndarray, odo: np.ndarray, rssi_dbm: np.ndarray,
                     start: np.ndarray, p0_dbm: float, n: float, *, p0_sd_db: float = 6.0, n_sd: float = 0.5,
                     link_sd_db: float = 3.0, reading_sd_db: float = 6.0, independent: float = 15.0,
                     huber_db: float = 9.0, iterations: int = 8) -> np.ndarray:
    """The odometry frame's offset to the anchors' frame with the radios' constants, from
    readings taken along a path: θ = (offset x, y, P0, n, one offset per link) minimising

        Σ_readings ρ((z − P0 − b_k + 10 n log10 |odo + offset − anchor_k|) / s) / independent
          + ((P0 − p0_dbm) / p0_sd_db)² + ((n − n_prior) / n_sd)² + Σ_k (b_k / link_sd_db)²

    (ρ: Huber at ``huber_db``; ``independent``: readings per independent one, as a link's
    errors hold for a second and at a place). ``which``: each reading's anchor index;
    ``start``: θ to begin from (length 4 + anchors). Gauss-Newton, reweighted; the priors keep
    what one place cannot tell apart (the offset against the links' constants) where they say."""
    p = np.asarray(anchors, float).reshape(-1, 2)
    k = len(p)
    theta = np.asarray(start, float).copy()
    prior = np.concatenate([[0.0, 0.0, p0_dbm, n], np.zeros(k)])
    prior_w = np.concatenate([[0.0, 0.0, 1 / p0_sd_db**2, 1 / n_sd**2], np.full(k, 1 / link_sd_db**2)])
    rows = np.arange(len(which))
    for _ in range(iterations):
        diff = odo + theta[:2] - p[which]
        d2 = np.maximum(np.sum(diff**2, axis=1), 0.01)
        lg = 0.5 * np.log10(d2)
        r = rssi_dbm - (theta[2] + theta[4 + which] - 10 * theta[3] * lg)  # reading − model
        w = np.where(np.abs(r) <= huber_db, 1.0, huber_db / np.maximum(np.abs(r), 1e-9)) / (reading_sd_db**2 * independent)
        jac = np.zeros((len(which), 4 + k))  # d model / d θ
        jac[:, :2] = -10 * theta[3] / np.log(10) * diff / d2[:, None]
        jac[:, 2] = 1.0
        jac[:, 3] = -10 * lg
        jac[rows, 4 + which] = 1.0
        h = jac.T @ (w[:, None] * jac) + np.diag(prior_w) + 1e-9 * np.eye(4 + k)
        g = jac.T @ (w * r) - prior_w * (theta - prior)
        step = np.linalg.solve(h, g)
        if np.linalg.norm(step[:2]) > 1.0:
            step *= 1.0 / float(np.linalg.norm(step[:2]))
        theta = theta + step
        if np.linalg.norm(step) < 1e-3:
            break
    return theta
