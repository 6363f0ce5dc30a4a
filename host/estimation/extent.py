"""Where a site's tags can be: the box the localiser keeps its positions in.

A tracker fed angles as poor as 25 degrees (the 2026-12 field report) can drift off and keep going, kilometres
away inside a 12 m room; nothing in the angles alone stops it. The site's extent does: the site
file's ``extent``, or by default the anchors' own box. A side of that box is closed where an
anchor at it looks back into the room (a wall anchor facing in, a corner anchor facing the
centre, or a two-sided one); a side no anchor looks back from is open and reaches ``REACH_M``
past the anchors (two anchors on two walls of a bigger room). Height: from the floor (z = 0,
or the lowest anchor if lower) to the highest anchor. Positions may be ``margin_m`` outside
(a tag by the wall, a fix's noise); beyond that a position is withheld and the track is lost.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MARGIN_M = 2.0
"""How far outside the extent a position may be (m): the default of [site] margin_m."""

REACH_M = 10.0
"""How far an open side of the anchors' box reaches past them (m; *assumed*: a room's size)."""

FACING = 0.25
"""An anchor closes a side when its boresight points back into the box at least this much
(the cosine of its angle to the side's inward normal: up to about 75 degrees off)."""


@dataclass(frozen=True)
class Extent:
    """An axis-aligned box (metres, the site's frame) and the margin positions may stray by."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    margin_m: float = MARGIN_M

    def inside(self, point: np.ndarray) -> bool:
        """Within the box plus the margin (and finite)."""
        return bool(self.contains(np.asarray(point, float)[:3]))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """:meth:`inside` for each row of (K, 3) points at once (the site bus's batch engine)."""
        p = np.asarray(points, float)
        lo, hi = np.array(self.lo) - self.margin_m, np.array(self.hi) + self.margin_m
        return np.asarray(np.all(np.isfinite(p) & (p >= lo) & (p <= hi), axis=-1))

    def clamp(self, point: np.ndarray) -> np.ndarray:
        """The nearest point of the box itself (no margin)."""
        return np.asarray(np.clip(np.nan_to_num(np.asarray(point, float)[:3]), self.lo, self.hi))

    def hold(self, state: np.ndarray) -> bool:
        """Put a tracker's state (position, velocity, ...) back inside the box plus the margin,
        its velocity out of the box stopped (the estimate projected onto the constraint, Simon
        2010, IET Control Theory Appl. 4(8)); False when it was inside."""
        lo, hi = np.array(self.lo) - self.margin_m, np.array(self.hi) + self.margin_m
        below, above = state[:3] < lo, state[:3] > hi
        if not (below.any() or above.any()):
            return False
        state[:3] = np.clip(state[:3], lo, hi)
        v = state[3:6]
        v[(below & (v < 0)) | (above & (v > 0))] = 0.0
        return True

    def as_dict(self) -> dict[str, object]:
        return {"lo": [round(v, 3) for v in self.lo], "hi": [round(v, 3) for v in self.hi], "margin_m": self.margin_m}


def from_anchors(origins: Sequence[Sequence[float]], boresights: Sequence[np.ndarray], two_sided: Sequence[bool],
                 margin_m: float = MARGIN_M) -> Extent:
    """The default extent of anchors at ``origins`` facing along ``boresights`` (world unit vectors)."""
    o = np.asarray(origins, float)
    b = np.asarray(boresights, float)
    both = np.asarray(two_sided, bool)
    lo, hi = o.min(axis=0), o.max(axis=0)
    near = np.maximum(1.0, 0.25 * (hi - lo))  # an anchor this near a side sits at it
    box_lo, box_hi = [0.0, 0.0, min(0.0, float(lo[2]))], [0.0, 0.0, float(hi[2])]
    for axis in (0, 1):
        at_lo = o[:, axis] <= lo[axis] + near[axis]
        at_hi = o[:, axis] >= hi[axis] - near[axis]
        box_lo[axis] = float(lo[axis]) if np.any(at_lo & (both | (b[:, axis] >= FACING))) else float(lo[axis]) - REACH_M
        box_hi[axis] = float(hi[axis]) if np.any(at_hi & (both | (b[:, axis] <= -FACING))) else float(hi[axis]) + REACH_M
    return Extent((box_lo[0], box_lo[1], box_lo[2]), (box_hi[0], box_hi[1], box_hi[2]), margin_m)
