"""Walks the project makes itself, for the radio-profile tests: a tag carried around a loop
in front of fixed anchors, its reports drawn from the emulator's measured error process
(emulator/aoa_error.py) with known parameters. No recording is read (tests never read
the real recordings)."""

from __future__ import annotations

import numpy as np

from rfhoming.emulator.aoa_error import MeasuredAoa
from rfhoming.host.angle_residuals import true_angles
from rfhoming.host.groundtruth import WalkedPath, Waypoint
from rfhoming.host.site import Site, parse
from rfhoming.protocol.radio_profile import AoaProfile
from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import AngleEvent

TAG = "CCF9578E0D8A"

SITE = parse({
    "site": {"name": "test-room"},
    "anchors": {"west": {"id": "CCF9578E0A01", "position": [0.0, 3.0, 2.3], "yaw_deg": 0.0},
                "south": {"id": "CCF9578E0A02", "position": [6.0, 0.0, 2.3], "yaw_deg": 90.0}},
    "tags": {TAG: {"height": 1.1}},
})
"""Two wall anchors of a 12 x 6 m room, 2.3 m up, and the walked tag at 1.1 m."""

LOOP = ((2.0, 1.5), (9.0, 1.5), (9.0, 4.5), (2.0, 4.5), (2.0, 1.5))
"""The walk: round the room, 20 m."""


def walk(start_s: float, speed_m_s: float = 0.5, loop: tuple[tuple[float, float], ...] = LOOP,
         dwell_s: float = 0.0) -> WalkedPath:
    """Once round ``loop`` at ``speed_m_s`` from ``start_s``, standing ``dwell_s`` at each corner."""
    points, t = [], start_s
    for k, (x, y) in enumerate(loop):
        if k:
            t += float(np.hypot(x - loop[k - 1][0], y - loop[k - 1][1])) / speed_m_s
        points.append(Waypoint(t, t + dwell_s, x, y))
        t += dwell_s
    return WalkedPath(tuple(points))


def reports(profile: AoaProfile, path: WalkedPath, seed: int, room_seed: int = 1, rate_hz: float = 20.0,
            site: Site = SITE) -> list[Bearing]:
    """Every anchor's reports of the tag along ``path``, through the measured process."""
    rng = np.random.default_rng(seed)
    boards = {a.name: MeasuredAoa(profile, a.name, rng, room_seed) for a in site.anchors}
    height = site.tags[0].height or 1.0
    times = np.arange(path.start_s, path.end_s, 1.0 / rate_hz)
    xy, headings = path.at(times), path.heading(times)
    out = []
    for a in site.anchors:
        truth = true_angles(a, np.column_stack([xy, np.full(len(times), height)]))
        for t, (x, y), h, (az, el) in zip(times, xy, headings, truth):
            got = boards[a.name].report(TAG, float(t), float(az), float(el), (*a.position, np.radians(a.yaw_deg)),
                                        (float(x), float(y), height, float(h)))
            if got is not None:
                out.append(bearing_of(float(t), AngleEvent(TAG, -60, round(got[0]), round(got[1]), -62, 37, a.id, "",
                                                           int(t * 1000) & 0x7FFFFFFF)))
    return sorted(out, key=lambda e: e.t)


def wire(r: Bearing) -> AngleEvent:
    """The +UUDF event :func:`reports` made ``r`` of (for a capture of it)."""
    return AngleEvent(r.tag, int(r.rssi or 0), int(r.clockwise_deg), int(r.elevation_deg or 0), -62, 37, r.anchor, "",
                      int(r.t * 1000) & 0x7FFFFFFF)
