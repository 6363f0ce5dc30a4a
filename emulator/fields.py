"""Stationary Gaussian fields as random Fourier features (Rahimi and Recht, NIPS 2007).

The emulator's errors that stay put where things stand -- an AoA board's multipath over where the
board and the tag are, an RSSI link's shadowing over its two ends -- are such fields: a sum of
cosines whose frequencies are drawn from the kernel's spectral density, so a field is one seeded
draw that any place can be asked of, in any order, at a cost that does not grow with the places.
The two kernels the radio profiles name differ only in that density.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

Kernel = Literal["exponential", "gaussian"]
"""exponential: covariance sigma^2 exp(-|Δ| / length), frequencies a multivariate Cauchy (a normal
over sqrt(chi2_1)); gaussian: sigma^2 exp(-|Δ|^2 / length^2), frequencies N(0, 2 / length^2)."""


class FourierField:
    """One draw of a field over R^``dims`` with standard deviation ``sigma`` and correlation length
    ``length``, as ``features`` cosines."""

    def __init__(self, kernel: Kernel, sigma: float, length: float, dims: int, rng: np.random.Generator,
                 features: int) -> None:
        if kernel == "exponential":
            z = rng.standard_normal((features, dims))
            u = rng.chisquare(1.0, features)
            self.freq = z / (np.sqrt(u)[:, None] * length)
        else:
            self.freq = rng.normal(0.0, math.sqrt(2.0) / length, (features, dims))
        self.phase = rng.uniform(0.0, 2 * math.pi, features)
        self.amp = sigma * math.sqrt(2.0 / features)

    def __call__(self, where: np.ndarray) -> float:
        """The field at one place."""
        return float(self.amp * np.cos(self.freq @ where + self.phase).sum())

    def values(self, places: np.ndarray) -> np.ndarray:
        """The field at each row of ``places`` (..., dims): a flight's million readings at once."""
        return np.asarray(self.amp * np.cos(np.asarray(places, float) @ self.freq.T + self.phase).sum(axis=-1), float)
