"""Issue 27: the fixed-anchor localiser holds up -- the EKF recovers from a jump, calibration
writes only what its points determine and what the site file accepts, one tag carried from
point to point calibrates, the cone angle model, robust fits, self-calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfhoming.host import site as sites
from rfhoming.host.estimation.anchors3d import board_angles
from rfhoming.host.locate import Locator
from rfhoming.protocol.uconnect import AngleEvent
from tests.test_locate import SITE

TAG = "CCF9578E0D8A"  # the kit site's "cart", height 1.0 m


def synthetic(site: sites.Site, path, duration: float, *, rate_hz: float = 25.0, noise_deg: float = 1.0,
              seed: int = 0, model: str | None = None, tag: str = TAG, true=None):
    """Angle events of one tag at ``path(t)`` (x, y, z) from every anchor of ``site`` (their
    nominal poses, or ``true``: anchor id -> (rotation, az_scale, az_bias)), integer degrees
    like the board's."""
    rng = np.random.default_rng(seed)
    events = []
    for k in range(int(duration * rate_hz)):
        for j, a in enumerate(site.anchors):
            t = k / rate_hz + j * 0.004
            rot, scale, bias = true[a.id] if true else (a.rotation(), 1.0, 0.0)
            d = rot.T @ (np.asarray(path(t)) - np.array(a.position))
            if d[0] <= 0:
                continue
            m = model or getattr(a, "angle_model", "spherical")
            az, el = board_angles(d) if m == "spherical" else board_angles(d, m)
            az = scale * az + bias + rng.normal(0, noise_deg)
            el = el + rng.normal(0, 2 * noise_deg)
            events.append((round(t, 6), AngleEvent(tag, -50, round(max(-90, min(90, az))),
                                                   round(max(-90, min(90, el))), -50, 37, a.id, "", int(t * 1000))))
    return events


def run(locator: Locator, events):
    out = []
    for t, e in events:
        out += locator.feed(t, e)
    return out + locator.flush()


def test_ekf_recovers_when_the_tag_jumps():
    """Old code: one fix, every pair refused without a count, the track kept alive (its time
    advanced) and coasting until its covariance grew wide enough: metres off for seconds."""
    site = sites.load(SITE)
    a, b = np.array([3.0, 2.0, 1.0]), np.array([9.0, 4.5, 1.0])
    events = synthetic(site, lambda t: a if t < 4.0 else b, 10.0)
    loc = Locator(site, tracker="ekf", reorder_s=0.0)
    out = run(loc, events)
    settled = [p for p in out if p.t > 4.6]  # 25 refusals (0.25 s) and a fresh 0.3 s window
    assert settled and all(np.linalg.norm(p.point[:2] - b[:2]) < 0.5 for p in settled)
    assert loc.counters["restarts"] >= 1
    before = [p for p in out if 2.0 < p.t < 4.0]
    assert all(np.linalg.norm(p.point[:2] - a[:2]) < 0.3 for p in before)
