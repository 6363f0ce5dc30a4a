"""RSSI <-> distance: the log-distance model (both ways), S3's exponential model, and the
calibration fits (P0 with n fixed, (P0, n) by least squares, (a, b)), with residual statistics.

log-distance: RSSI(d) = P0 − 10 n log10(d / d0)  (S3's model, its sign typo corrected)
exponential:  d = a · exp(b · RSSI)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import overload

import numpy as np


@dataclass(frozen=True)
class LogDistance:
    p0_dbm: float
    n: float
    d0_m: float = 1.0

    def rssi(self, d: np.ndarray | float) -> np.ndarray | float:
        return self.p0_dbm - 10 * self.n * np.log10(np.maximum(d, 1e-6) / self.d0_m)

    @overload
    def distance(self, rssi: float) -> float: ...
    @overload
    def distance(self, rssi: np.ndarray) -> np.ndarray: ...
    def distance(self, rssi: np.ndarray | float) -> np.ndarray | float:
        return self.d0_m * 10 ** ((self.p0_dbm - np.asarray(rssi)) / (10 * self.n))


@dataclass(frozen=True)
class Exponential:
    a: float
    b: float

    @overload
    def distance(self, rssi: float) -> float: ...
    @overload
    def distance(self, rssi: np.ndarray) -> np.ndarray: ...
    def distance(self, rssi: np.ndarray | float) -> np.ndarray | float:
        return self.a * np.exp(self.b * np.asarray(rssi))


@dataclass(frozen=True)
class Fit:
    model: LogDistance | Exponential
    rssi_residual_db: float | None
    """std of RSSI around the fitted curve (log-distance fits)"""
    distance_rmse_m: float
    n_samples: int


def _checked(d: np.ndarray, rssi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d, rssi = np.asarray(d, float).ravel(), np.asarray(rssi, float).ravel()
    if d.shape != rssi.shape or len(d) < 2:
        raise ValueError("need at least two (distance, RSSI) pairs of equal length")
    if np.any(d <= 0):
        raise ValueError("distances must be positive")
    return d, rssi


def _log_fit_result(model: LogDistance, d: np.ndarray, rssi: np.ndarray) -> Fit:
    resid = rssi - model.rssi(d)
    rmse = float(np.sqrt(np.mean((model.distance(rssi) - d) ** 2)))
    return Fit(model, float(np.std(resid)), rmse, len(d))


def fit_p0(d: np.ndarray, rssi: np.ndarray, n: float = 2.0, d0: float = 1.0) -> Fit:
    """P0 with n fixed (S4 §2.2): P0 = mean(RSSI + 10 n log10(d/d0))."""
    d, rssi = _checked(d, rssi)
    model = LogDistance(float(np.mean(rssi + 10 * n * np.log10(d / d0))), n, d0)
    return _log_fit_result(model, d, rssi)


def fit_log_distance(d: np.ndarray, rssi: np.ndarray, d0: float = 1.0) -> Fit:
    """(P0, n) by least squares on RSSI = P0 − 10 n log10(d/d0)."""
    d, rssi = _checked(d, rssi)
    x = -10 * np.log10(d / d0)
    if np.ptp(x) == 0:
        raise ValueError("all samples at one distance: n cannot be fitted (fix n and use fit_p0)")
    a = np.stack([np.ones_like(x), x], axis=1)
    (p0, n), *_ = np.linalg.lstsq(a, rssi, rcond=None)
    return _log_fit_result(LogDistance(float(p0), float(n), d0), d, rssi)


def fit_log_distance_binned(d: np.ndarray, rssi: np.ndarray, d0: float = 1.0, bin_m: float = 0.25,
                            min_samples: int = 5) -> Fit:
    """(P0, n) by least squares through the median distance and median RSSI of each ``bin_m``
    distance bin holding at least ``min_samples`` readings.

    A robust form of :func:`fit_log_distance` for a calibration drive: a median does not move
    with a tail or a pile of readings at the receiver's floor (a ±1 m range noise near a 0.5 m
    stop piles readings at the smallest distance, tens of dB above the curve, and pulls a plain
    fit's n up), yet equals the mean for symmetric noise. Each bin counts once, so a long dwell
    at the stop does not outweigh the drive."""
    d, rssi = _checked(d, rssi)
    bins = np.round(d / bin_m)
    centres, medians = [], []
    for b in np.unique(bins):
        inside = bins == b
        if inside.sum() >= min_samples:
            centres.append(np.median(d[inside]))
            medians.append(np.median(rssi[inside]))
    if len(centres) < 2:
        raise ValueError(f"readings fill fewer than two {bin_m} m distance bins of {min_samples}: "
                         "drive over a longer distance")
    x = -10 * np.log10(np.array(centres) / d0)
    a = np.stack([np.ones_like(x), x], axis=1)
    (p0, n), *_ = np.linalg.lstsq(a, np.array(medians), rcond=None)
    return _log_fit_result(LogDistance(float(p0), float(n), d0), d, rssi)


def fit_exponential(d: np.ndarray, rssi: np.ndarray) -> Fit:
    """(a, b) of d = a·exp(b·RSSI), least squares on ln d (a log-linear fit)."""
    d, rssi = _checked(d, rssi)
    if np.ptp(rssi) == 0:
        raise ValueError("all samples at one RSSI: b cannot be fitted")
    a_mat = np.stack([np.ones_like(rssi), rssi], axis=1)
    (ln_a, b), *_ = np.linalg.lstsq(a_mat, np.log(d), rcond=None)
    model = Exponential(float(np.exp(ln_a)), float(b))
    rmse = float(np.sqrt(np.mean((model.distance(rssi) - d) ** 2)))
    return Fit(model, None, rmse, len(d))


S3_TABLE = (
    # distance m, mean dBm, std dB (500 samples each; "~0" taken as 0.05 m)
    (0.05, -17.04, 0.21), (0.5, -44.80, 3.13), (1.0, -64.30, 4.36), (1.5, -69.48, 6.66),
    (2.0, -75.62, 1.58), (2.5, -76.92, 3.39), (3.0, -79.44, 3.20), (3.5, -79.60, 2.10),
    (4.0, -83.84, 4.67), (4.5, -79.45, 5.38), (5.0, -87.23, 7.01),
)
"""S3 Table I."""
