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


def test_a_replayed_angle_stream_without_set_up_is_no_false_alarm(tmp_path):
    """Old code: each driver sent AT into the replay, waited, and reported a wiring problem
    (and after the wake timeout "set-up failed ... is this an XPLR-AOA") though every event was used."""
    import json
    import subprocess

    from rfhoming.host.capture import CaptureWriter
    from tests.test_locate import RFHOMING

    path = tmp_path / "angles.pcapng"
    writer = CaptureWriter(path)
    anchors = (("west", "CCF9578E0A01", -20), ("east", "CCF9578E0A02", 25), ("south", "CCF9578E0A03", 10))
    for port, _, _ in anchors:
        writer.describe(port, kind="xplr-aoa")
    for k in range(300):
        for port, anchor, az in anchors:
            line = f'+UUDF:{TAG},-42,{az},-10,-43,37,"{anchor}","",{k * 20}\r\n'
            writer.tap(port, "in", 1000.0 + k * 0.02, line.encode())
    writer.close()
    cli = subprocess.run([*RFHOMING, "-v", "locate", str(SITE), "--from", f"capture:{path}"],
                         capture_output=True, text=True, timeout=60)
    assert cli.returncode == 0, cli.stderr
    counters = [json.loads(line) for line in cli.stderr.splitlines() if line.startswith('{"kind": "counters"')]
    assert len(counters) == 3 and all(c["problem"] is None for c in counters), counters
    assert "set-up failed" not in cli.stderr and "AT" not in cli.stderr.replace("ATTR", "")
    notes = [line for line in cli.stderr.splitlines() if "no set-up exchange" in line]
    assert len(notes) == 1 and "west, east, south" in notes[0]
    summary = json.loads(cli.stdout.splitlines()[-1])
    assert summary["events"] == 900
