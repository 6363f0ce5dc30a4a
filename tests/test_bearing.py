"""The neutral bearing reading (host/bearing.py): the XPLR-AOA's sign turned into REP 103's, a
board's whole degrees kept exact, and no consumer looking at the XPLR-AOA's own item or driver."""

from __future__ import annotations

import math
import re
from pathlib import Path

from rfhoming.host.bearing import Bearing, wrap
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import AngleEvent

ROOT = Path(__file__).resolve().parents[1]


def test_a_tag_to_the_boards_left_is_a_positive_azimuth() -> None:
    """docs/protocol.md: the board's azimuth is negative to its left; REP 103 counts left positive."""
    r = bearing_of(12.5, AngleEvent("CCF9578E0D8A", -47, -30, 10, 6, 37, "A1", "", 1000))
    assert r == Bearing(12.5, "A1", "CCF9578E0D8A", math.radians(30), math.radians(10), -47.0)
    assert r.azimuth_deg == 30 and r.clockwise_deg == -30 and r.elevation_deg == 10


def test_a_boards_whole_degrees_come_back_exactly() -> None:
    for az in range(-90, 91):
        r = bearing_of(0.0, AngleEvent("T", -50, az, az, 0, 37, "A", "", 0))
        assert r.clockwise_deg == az and r.elevation_deg == az and str(r.clockwise_deg) != "-0.0"


def test_wrap_keeps_the_whole_circle_in_minus_pi_to_pi() -> None:
    assert wrap(math.radians(270)) == -math.pi / 2 and wrap(-math.pi) == math.pi and wrap(0.5) == 0.5


def test_nothing_outside_the_xplr_aoa_driver_tests_its_item_or_driver() -> None:
    """Consumers read the Bearing: isinstance on the XPLR-AOA's wire item or its driver would tie
    them to that board again (the other-boards report of 2026-12)."""
    pattern = re.compile(r"isinstance\([^)]*\b(AngleEvent|AoaDriver|TimedAngle)\b")
    package = [p for layer in ("host", "rfhoming", "campaigns", "emulator", "firmware_py", "protocol")
               for p in (ROOT / layer).rglob("*.py") if not p.is_symlink()]
    offenders = [str(p.relative_to(ROOT)) for p in package
                 if p != ROOT / "host" / "drivers" / "aoa.py" and pattern.search(p.read_text())]
    assert len(package) > 100 and offenders == []
