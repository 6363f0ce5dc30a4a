"""A walker's angle reports made here, with the error processes real XPLR-AOA boards show.

Not the emulator (which runs the firmware behind bytes): plain ``(t, AngleEvent)`` lists for the
localiser's tests, each error process a parameter, so a test can switch one on and see what it
does. A room of four wall anchors 2.3 m up (12 x 6 m, like the real recordings' room), a tag at
1.1 m walking through waypoints at ``speed`` with a ``dwell_s`` stop at each. Each anchor reports
at ``rate_hz`` (a fraction ``missing`` dropped), in the cone angle model with |azimuth|
``compression``, plus its own slow error (Ornstein-Uhlenbeck: ``slow_deg``, correlation time
``slow_s`` while the walker moves and ``stand_slow_s`` while it stands), white noise
(``white_deg``) and a fraction ``outliers`` of reports anywhere in +-60 degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfhoming.host.estimation.anchors3d import board_angles_many
from rfhoming.host.site import Anchor, Site, TagInfo
from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import AngleEvent

TAG = "CCF9578E0D8A"
ROOM = Site("synthetic-room", (
    Anchor("west", "000000000A01", None, (0.0, 3.0, 2.3), 0.0),
    Anchor("south", "000000000A02", None, (6.0, 0.0, 2.3), 90.0),
    Anchor("east", "000000000A03", None, (12.0, 3.0, 2.3), 180.0),
    Anchor("north", "000000000A04", None, (6.0, 6.0, 2.3), -90.0)), (TagInfo(TAG, "walker", 1.1),))


@dataclass(frozen=True)
class Walk:
    events: list[Bearing]
    knots_t: np.ndarray
    knots_xy: np.ndarray

    def truth(self, t: float | np.ndarray) -> np.ndarray:
        tt = np.asarray(t, float)
        return np.stack([np.interp(tt, self.knots_t, self.knots_xy[:, 0]),
                         np.interp(tt, self.knots_t, self.knots_xy[:, 1])], axis=-1)


def walk(seed: int, *, waypoints: list[tuple[float, float]] | None = None, speed: float = 0.8, dwell_s: float = 0.0,
         rate_hz: float = 37.0, missing: float = 0.03, compression: float = 0.2, white_deg: float = 6.0,
         slow_deg: float = 6.0, slow_s: float = 2.0, stand_slow_s: float = 30.0, el_white_deg: float = 8.0,
         outliers: float = 0.03, site: Site = ROOM) -> Walk:
    rng = np.random.default_rng(seed)
    points = waypoints or [(2.0, 4.8), (2.0, 1.2), (6.0, 1.2), (6.0, 4.8), (10.0, 4.8), (10.0, 1.2), (4.0, 3.0)]
    knots_t, knots_xy = [0.0], [points[0]]
    t = 0.0
    for a, b in zip(points, points[1:]):
        if dwell_s:
            t += dwell_s
            knots_t.append(t)
            knots_xy.append(a)
        t += math.dist(a, b) / speed
        knots_t.append(t)
        knots_xy.append(b)
    path = Walk([], np.array(knots_t), np.array(knots_xy, float))
    end = knots_t[-1] + (dwell_s or 1.0)
    events: list[Bearing] = []
    height = site.tags[0].height or 1.1
    for anchor in site.anchors:
        times = np.arange(rng.uniform(0, 1 / rate_hz), end, 1 / rate_hz)
        times = times[rng.random(len(times)) >= missing]
        xy = path.truth(times)
        moving = np.linalg.norm(np.gradient(xy, axis=0), axis=1) > 1e-6
        local = (np.column_stack([xy, np.full(len(times), height)]) - np.asarray(anchor.position)) @ anchor.rotation()
        true = board_angles_many(local, "cone")
        az = true[:, 0] * (1 - compression * (true[:, 0] / 90) ** 2)
        slow = np.zeros((len(times), 2))
        for k in range(1, len(times)):
            dt = times[k] - times[k - 1]
            a = math.exp(-dt / (slow_s if moving[k] else stand_slow_s))
            slow[k] = a * slow[k - 1] + rng.normal(0, 1, 2) * slow_deg * math.sqrt(1 - a * a)
        az = az + slow[:, 0] + rng.normal(0, white_deg, len(times))
        el = true[:, 1] + slow[:, 1] + rng.normal(0, el_white_deg, len(times))
        wild = rng.random(len(times)) < outliers
        az[wild] = rng.uniform(-60, 60, int(wild.sum()))
        for t_k, a_k, e_k in zip(times, az, el):
            events.append(bearing_of(float(t_k), AngleEvent(TAG, -50, int(round(max(-90.0, min(90.0, a_k)))),
                                                            int(round(max(-90.0, min(90.0, e_k)))), -50, 37, anchor.id,
                                                            "", 0)))
    events.sort(key=lambda item: item.t)
    return Walk(events, path.knots_t, path.knots_xy)
