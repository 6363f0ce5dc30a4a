"""Self-calibration writes only what the data determine (host/self_calibration.py): each
parameter's uncertainty comes from the places the tag was (errors stay put at a place, so a long
stop is one sample), a parameter is written only when that uncertainty is small against its
prior and its value, and the rest is held with its value and uncertainty said."""

from __future__ import annotations

import numpy as np

from rfhoming.host import site as sites
from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.estimation.anchors3d import board_angles
from rfhoming.protocol.uconnect import AngleEvent
from test_locate import SITE

TAG = "CCF9578E0D8A"  # the kit site's "cart", height 1.0 m


def stops(site: sites.Site, places: list[tuple[float, float]], *, bias: dict[str, float], stays_deg: float,
          dwell_s: float = 8.0, rate_hz: float = 10.0, seed: int = 0) -> list[Bearing]:
    """The tag carried from place to place (a second between) and standing ``dwell_s`` at each:
    every anchor's azimuth off by its ``bias``, an error drawn per place that stays put while
    the tag stands there (``stays_deg``), and 1 deg of white noise; level boards, whole degrees."""
    rng = np.random.default_rng(seed)
    events: list[Bearing] = []
    t0 = 0.0
    for x, y in places:
        put = {a.id: rng.normal(0, stays_deg) for a in site.anchors}
        for k in range(int(dwell_s * rate_hz)):
            for j, a in enumerate(site.anchors):
                t = t0 + k / rate_hz + j * 0.004
                d = a.rotation().T @ (np.array([x, y, 1.0]) - np.array(a.position))
                az, el = board_angles(d)
                az += bias.get(a.name, 0.0) + put[a.id] + rng.normal(0, 1.0)
                el += rng.normal(0, 2.0)
                events.append(bearing_of(round(t, 6), AngleEvent(TAG, -50, int(round(np.clip(az, -90, 90))),
                                                                 int(round(np.clip(el, -90, 90))), -50, 37, a.id, "",
                                                                 int(t * 1000))))
        t0 += dwell_s + 1.0
    return events


PLACES = [(x, y) for x in (2.0, 4.5, 7.5, 10.0) for y in (1.0, 5.0)] + [(6.0, 3.0), (3.0, 3.0), (9.0, 3.0)]


def test_a_bias_the_places_determine_is_written_and_what_they_do_not_is_held() -> None:
    """West 9 deg off at every place: written, with its uncertainty. The other boards are true,
    but each place adds an error of 4 deg that stays put: their scales and biases are within
    what eleven places can tell from nothing, so they are held, each with its value and
    uncertainty said -- not written from one room's errors."""
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    result = self_calibrate(site, [stops(site, PLACES, bias={"west": 9.0}, stays_deg=4.0)])
    fits = {f.anchor: f for f in result.fits}
    west = fits["west"]
    assert "az_bias_deg" in west.sigma and west.sigma["az_bias_deg"] < 1.5
    assert abs(west.calibration.az_bias_deg - 9.0) < 3.0
    held = [(f.anchor, name, why) for f in result.fits for name, why in f.held.items() if name in ("az_scale",
                                                                                                 "az_bias_deg")]
    assert any(name == "az_scale" for _, name, _ in held)
    for anchor, name, why in held:
        assert why.startswith(("not determined", "ran to its bound")), why
        assert getattr(fits[anchor].calibration, name) == (1.0 if name == "az_scale" else 0.0)
        if why.startswith("not determined"):
            assert "+-" in why
    for f in result.fits:
        if f.anchor != "west":
            assert abs(f.calibration.az_bias_deg) < 4.0 and abs(f.calibration.az_scale - 1) < 0.1


def test_a_long_stop_is_one_place_not_many() -> None:
    """The same reports, the tag standing at three places only, however long: too few places to
    tell a board's error from a place's, and the refusal says so."""
    import pytest

    from rfhoming.host.calibration import CalibrationError
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    events = stops(site, [(2.0, 1.0), (10.0, 1.0), (6.0, 5.0)], bias={}, stays_deg=4.0, dwell_s=60.0)
    with pytest.raises(CalibrationError, match=r"the tags were in [3-5] of the room's"):
        self_calibrate(site, [events])
