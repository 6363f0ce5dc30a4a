"""The neutral bearing reading: a tag's direction as one anchor sees it, whatever the board.

Every direction-finding source (the XPLR-AOA driver, an angles file, a board yet to come) turns
its own reports into :class:`Bearing`; controllers, ``locate``, calibration, the site bus and
``radio-fit`` read nothing else, so a new AoA board is a device record, a driver and a model
(docs/hardware.md, "A new AoA board").
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Bearing(NamedTuple):
    """One report of a tag seen from an anchor, in the anchor's frame (REP 103: x the boresight,
    z up), SI units."""

    t: float
    """Host time the report arrived (s): the clock the locator orders and windows on."""
    anchor: str
    """The anchor's id, as a site file names it (the XPLR-AOA's anchor id, by default its MAC)."""
    tag: str
    azimuth: float
    """Radians over the whole circle, (-pi, pi], counter-clockwise from the boresight seen from
    above (REP 103): positive = the tag to the anchor's left."""
    elevation: float | None = None
    """Radians out of the anchor's plane, positive up; None: the board gives none."""
    rssi: float | None = None
    """dBm of the report's packet; None: the board gives none."""

    @property
    def azimuth_deg(self) -> float:
        """The azimuth in degrees, to a nanodegree: a board's whole degrees come back whole (a
        plain ``math.degrees`` of their radians is 1e-14 off for some), so medians and ties
        over them are what they were in the board's own numbers."""
        return round(math.degrees(self.azimuth), 9)

    @property
    def elevation_deg(self) -> float | None:
        return None if self.elevation is None else round(math.degrees(self.elevation), 9)

    @property
    def clockwise_deg(self) -> float:
        """The azimuth in degrees counted clockwise (positive = the tag to the anchor's right):
        the sign the locator's board models and a site file's calibrations are written in (the
        XPLR-AOA's own, docs/protocol.md "The angle event")."""
        return 0.0 - self.azimuth_deg  # 0.0 - x: no -0.0 at the boresight


def wrap(azimuth: float) -> float:
    """An angle in radians onto (-pi, pi]."""
    a = math.remainder(azimuth, math.tau)
    return math.pi if a == -math.pi else a
