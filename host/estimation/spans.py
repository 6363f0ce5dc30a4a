"""How far back a fix looks at an anchor's reports, and when the anchor is stale: one rule for
the per-tag Locator (host/locate.py) and the site bus's BatchLocator (estimation/batch.py), so
both fix a tag from the same reports. A slow anchor (a board reporting 0.5-3 times a second)
gets a window and a staleness that widen with its usual gap between reports."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

MAX_SPAN_S = 20.0
"""A slow anchor's window and staleness widen up to this (s): the 2026-12 field report's board reports 0.5-3 a second."""

RAY_REPORTS = 5
"""A fix's ray rests on at least this many of its anchor's reports (its window widens for them)."""

STALE_GAPS = 3.0
"""An anchor is stale after this many of its usual gaps between reports (and stale_s)."""

RATE_REPORTS = 8
"""An anchor's usual gap: the mean over its last this many."""


def usual_gap(newest: ArrayLike, back: ArrayLike, n: ArrayLike) -> np.ndarray:
    """The mean gap over an anchor's last ``n`` reports (n = min(reports - 1, RATE_REPORTS)):
    ``newest`` its newest report's time, ``back`` the time n reports before it; inf where n is 0."""
    some = np.asarray(n) > 0  # where there is none, 0 / 1 (not -inf - -inf) before it is set to inf
    span = np.where(some, newest, 0.0) - np.where(some, back, 0.0)
    return np.where(some, span / np.maximum(n, 1), np.inf)


def stale_after(gap: ArrayLike, stale_s: float) -> np.ndarray:
    """How long an anchor of this usual gap may be silent and still count: stale_s, or
    STALE_GAPS of its gaps (up to MAX_SPAN_S); stale_s for an anchor heard once."""
    g = np.asarray(gap, float)
    return np.where(np.isinf(g), stale_s, np.minimum(MAX_SPAN_S, np.maximum(stale_s, STALE_GAPS * g)))


def ray_span(gap: ArrayLike, window_s: float) -> np.ndarray:
    """How far before its newest report a fix's ray takes an anchor's reports: window_s, widened
    to RAY_REPORTS of its gaps (up to MAX_SPAN_S; MAX_SPAN_S for an anchor heard once)."""
    return np.asarray(np.minimum(MAX_SPAN_S, np.maximum(window_s, RAY_REPORTS * np.asarray(gap, float))))
