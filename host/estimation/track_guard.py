"""Is a tag's track still where its reports say? A check on a fixed scale, not the tracker's own.

A tracker judges a report by its own covariance: once it has drifted off, that covariance has
grown to cover the drift (a sigma of 185 km on the poor board of the 2026-12 field report) and every report
looks fine to it. So once a second (``CHECK_S``) the track is held against the recent reports
in degrees: the balanced median residual of each report against where the track put the tag
at the report's time (estimation/bearing_consensus.py). The track is lost when that median
exceeds ``LOST_DEG`` and the reports' own best point (their consensus) explains them better by
``EXCESS_DEG``, at ``LOST_CHECKS`` checks in a row; the caller then restarts from that point.
A consensus that misses its reports by more than ``CONSENSUS_DEG`` is no better than noise (a
burst of wild angles): nothing restarts from it.

The thresholds are angles of the board's error, fixed: 20 degrees of median miss is four times
an XPLR-AOA's (about 5) and below the second board's 25 (so its tracks are always checked);
an excess of 10 degrees is the miss of a track some 1.5 m off at 8 m.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from rfhoming.host.estimation.bearing_consensus import Bearings, Consensus, balanced_median, consensus
from rfhoming.host.estimation.extent import Extent

CHECK_S = 1.0
"""How often a track is checked (s of the reports' time)."""

LOST_DEG = 20.0
"""A track whose reports miss it by less than this (balanced median, degrees) is kept unchecked."""

EXCESS_DEG = 10.0
"""The consensus must explain the reports better than the track by this (degrees)."""

CONSENSUS_DEG = 45.0
"""A consensus that misses its reports by more explains nothing (degrees)."""

LOST_CHECKS = 2
"""Checks in a row the track must fail (one bad second is not a lost track)."""

MIN_ANCHORS = 2
"""Anchors the reports must come from for a check or a restart."""

HISTORY = 1000
"""The track's positions kept (at 10 ticks a second, 100 s: longer than any report window)."""

HELD_S = 5.0
"""A track held back inside the extent (Extent.hold) at every report for this long is lost (s)."""

SPREAD_CHECKS = 30
"""The board's error scale (:attr:`TrackGuard.spread_deg`) is the median over this many checks,
once there are SPREAD_MIN (the first few, while a new track settles, miss by more)."""

SPREAD_MIN = 10


class TrackGuard:
    """One tag's track: ``record`` each position given, ``check`` now and then."""

    def __init__(self, extent: Extent) -> None:
        self.extent = extent
        self._history: deque[tuple[float, float, float]] = deque(maxlen=HISTORY)
        self._next_check = -math.inf
        self._failed = 0
        self._spreads: deque[float] = deque(maxlen=SPREAD_CHECKS)
        self._held_since: float | None = None

    @property
    def spread_deg(self) -> float | None:
        """How far the reports miss the tag (balanced median, degrees), over the last checks: the
        track's miss while it holds, the consensus' when it is lost; None before SPREAD_MIN checks."""
        return float(np.median(self._spreads)) if len(self._spreads) >= SPREAD_MIN else None

    def reset(self) -> None:
        """A new track: the old one's positions no longer speak for it."""
        self._history.clear()
        self._failed = 0
        self._held_since = None

    def held(self, t: float, outside: bool) -> None:
        """The tracker's state after a report at ``t`` was (``outside``) or was not held back in."""
        self._held_since = (t if self._held_since is None else self._held_since) if outside else None

    def held_too_long(self, t: float) -> bool:
        """Held back at every report for HELD_S: the reports keep pushing it out, it is lost."""
        return self._held_since is not None and t - self._held_since >= HELD_S

    def record(self, t: float, point: np.ndarray) -> None:
        self._history.append((t, float(point[0]), float(point[1])))

    def due(self, t: float) -> bool:
        if t < self._next_check:
            return False
        self._next_check = t + CHECK_S
        return True

    def track_at(self, times: np.ndarray) -> np.ndarray:
        """Where the track put the tag at each time (held before its first position)."""
        h = np.array(self._history)
        return np.stack([np.interp(times, h[:, 0], h[:, 1]), np.interp(times, h[:, 0], h[:, 2])], axis=1)

    def check(self, reports: Bearings, times: np.ndarray) -> Consensus | None:
        """The point to restart from when the track is lost, else None."""
        if not self._history or len(np.unique(reports.anchor)) < MIN_ANCHORS:
            return None
        miss = float(balanced_median(reports.residuals_along(self.track_at(times)), reports.anchor))
        if miss <= LOST_DEG:
            self._spreads.append(miss)
            self._failed = 0
            return None
        best = consensus(reports, self.extent)
        if best.median_deg > CONSENSUS_DEG or miss - best.median_deg <= EXCESS_DEG:
            self._spreads.append(min(miss, CONSENSUS_DEG))
            self._failed = 0
            return None
        self._spreads.append(best.median_deg)
        self._failed += 1
        return best if self._failed >= LOST_CHECKS else None
