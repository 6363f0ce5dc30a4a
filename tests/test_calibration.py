"""The host is never told the simulator's truth: every closed-loop campaign's host config takes
its radio constants from a calibration session through the emulated radios."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rfhoming.campaigns import calibration, s0, s1, s2
from rfhoming.emulator.scenario import load

SHIFT_DB, SHIFT_N = 6.0, 0.5


def radio_constants(campaign: str) -> tuple[str, dict[str, float]]:
    """(scenario, the host's radio constants) as the campaign builds its config."""
    if campaign == "s0-table3":
        c = s0.host_config("s0-open", 0, 3).calibration
        return "s0-open", {"p0": c.p0_dbm, "n": c.n}
    if campaign == "s0-house":
        c = s0.host_config("s0-house", 0, None, s0.HOUSE_CONFIG).calibration
        return "s0-house", {"p0": c.p0_dbm, "n": c.n}
    if campaign == "s1-dock":
        c1 = s1.host_config("aligned", 0).s1
        return "s1-dock", {"p0": c1.rssi_arrival_dbm, "n": c1.path_n, "enter": c1.enter_dbm}
    c2 = s2.host_config("d", "full-bounded", 1).s2
    return "s2-d", {"p0": c2.p0_dbm + c2.peak_gain_db, "n": c2.n}


CLOSED_LOOP = ("s0-table3", "s0-house", "s1-dock", "s2-scenarios")


@pytest.mark.parametrize("campaign", [CLOSED_LOOP[0], *(pytest.param(c, marks=pytest.mark.slow) for c in CLOSED_LOOP[1:])])
def test_host_radio_constants_come_from_measurements(campaign, monkeypatch) -> None:
    calibration.cached.cache_clear()
    scenario, plain = radio_constants(campaign)
    truth = load(scenario).path_loss
    assert plain["p0"] != truth.p0_dbm and plain["n"] != truth.n  # a fit, with its own noise
    assert abs(plain["n"] - truth.n) < 0.8  # ... of the same radio

    original = calibration.load

    def shifted(name, seed, aoa_preset=None, radio="ideal"):  # the same scenario, its radio 6 dB stronger and steeper
        sc = original(name, seed, aoa_preset, radio)
        sc.path_loss = replace(sc.path_loss, p0_dbm=sc.path_loss.p0_dbm + SHIFT_DB, n=sc.path_loss.n + SHIFT_N)
        return sc

    monkeypatch.setattr(calibration, "load", shifted)
    calibration.cached.cache_clear()
    try:
        _, moved = radio_constants(campaign)
    finally:
        calibration.cached.cache_clear()
    # P0 and n follow the radio; the stop RSSI (S1) moves with the whole curve at 0.3 m
    assert moved["n"] - plain["n"] == pytest.approx(SHIFT_N, abs=0.35)
    expected = SHIFT_DB if campaign != "s1-dock" else SHIFT_DB - 10 * SHIFT_N * np.log10(0.3)
    assert moved["p0"] - plain["p0"] == pytest.approx(expected, abs=2.0)
