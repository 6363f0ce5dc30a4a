"""Position from distances to known anchors: S3's trilateration and least-squares multilateration.

Both detect degenerate geometry (collinear or coincident anchors) and raise
:class:`~host.estimation.bearings.Degenerate` instead of returning nonsense.
"""

from __future__ import annotations

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
