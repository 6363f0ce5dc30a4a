"""radio-fit's calibration through the emulator's board (host/aoa_calibrate.py): the fixed-point
loop on a toy board whose every statistic is a known distortion of its parameter, the
emulator's board as the hook (emulator/aoa_error.py's simulated_errors), and a profile fitted to
walks the emulator made with known parameters. Walks the project makes (tests/aoa_walks.py);
never the real recordings."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import pytest

from aoa_walks import SITE, TAG, reports, walk
from rfhoming.emulator.aoa_error import simulated_errors
from rfhoming.firmware.xplr_aoa import output_angles
from rfhoming.host.angle_residuals import angle_stats, residuals
from rfhoming.host.aoa_calibrate import (
    STATISTICS,
    WalkToCalibrate,
    calibrate,
    simulate,
    simulated,
    statistics,
    walk_to_calibrate,
)
from rfhoming.host.radio_fit import Recording, fit
from rfhoming.protocol.radio_profile import AngleError, AoaProfile, BoardWalk, Missing, Reported, Source
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import AngleEvent

CURVE = (0.0, 30.0, 60.0)


def toy_board(profile: AoaProfile, walk_: Sequence[BoardWalk], seed: int, room: int) -> list[Reported]:
    """A board that distorts each statistic in a known way: the wander (an AR(1) of the
    profile's sigma and time) comes out at 0.7 of its sigma and half its time, the loss of the
    last board at half the highest rate (the first loses none), bursts (+-30 degrees, one report each) at 0.4 of the rate, and the compression at
    half the curve. No field, no rounding."""
    rng = np.random.default_rng([seed, room])
    out: list[Reported] = []
    for n, b in enumerate(walk_):
        angles = []
        for axis, true in (("azimuth", b.azimuth), ("elevation", b.elevation)):
            e: AngleError = getattr(profile, axis)
            dt = np.diff(b.t, prepend=b.t[0])
            keep = np.exp(-dt / (0.5 * e.slow_time_s))
            slow = np.zeros(len(b.t))
            x = float(rng.normal(0.0, e.slow_sigma_deg))
            for k, (f, z) in enumerate(zip(keep, rng.normal(0.0, e.slow_sigma_deg, len(b.t)))):
                x = x * f + math.sqrt(1 - f * f) * z
                slow[k] = x
            burst = (rng.random(len(b.t)) < 1 - np.exp(-0.4 * e.burst_rate_hz * dt)) * rng.choice([-30.0, 30.0], len(b.t))
            shift = 0.5 * np.sign(true) * np.array([e.compression(abs(a)) for a in b.azimuth])
            angles.append(true + shift + 0.7 * slow + burst)
        loss = 0.5 * profile.missing.rate_high * n / max(1, len(walk_) - 1)  # the first board hears every one
        kept = np.nonzero(rng.random(len(b.t)) >= loss)[0]
        out.append((kept, angles[0][kept], angles[1][kept]))
    return out


KNOWN = AoaProfile(
    azimuth=AngleError(slow_sigma_deg=5.0, slow_time_s=1.6, burst_rate_hz=0.4,
                       curve_at_deg=(0.0, 15.0, 30.0, 45.0, 60.0, 75.0),
                       compression_deg=(0.0, 0.0, -2.0, -6.0, -14.0, -18.0)),
    elevation=AngleError(slow_sigma_deg=7.0, slow_time_s=1.0, burst_rate_hz=0.3),
    missing=Missing(0.0, 0.08, 1.0))
"""What the toy board's "real" walks are made with."""


def _direct(known: AoaProfile) -> AoaProfile:
    """A direct fit as biased as the toy board makes it: every parameter where the board's
    statistic of it points, so the calibration has the whole way to go."""
    az, el = known.azimuth, known.elevation
    return AoaProfile(
        azimuth=dataclasses.replace(az, slow_sigma_deg=0.7 * az.slow_sigma_deg, slow_time_s=0.5 * az.slow_time_s,
                                    burst_rate_hz=0.4 * az.burst_rate_hz,
                                    compression_deg=tuple(0.5 * c for c in az.compression_deg)),
        elevation=dataclasses.replace(el, slow_sigma_deg=0.7 * el.slow_sigma_deg, burst_rate_hz=0.4 * el.burst_rate_hz),
        missing=Missing(0.0, 0.5 * known.missing.rate_high, 1.0),
        sources={"azimuth.slow_time_s": Source(("w0", "w1"), "a grid over the time")})


def _walks(board: object = toy_board, profile: AoaProfile = KNOWN, count: int = 2) -> list[WalkToCalibrate]:
    """``count`` loops of the test room, their "real" residuals made by ``board`` under ``profile``."""
    rng = np.random.default_rng(5)
    out = []
    for k in range(count):
        path = walk(100.0 * k)
        plain = residuals(SITE, reports(AoaProfile(), path, seed=k), path)  # the event rate and the anchors
        w = walk_to_calibrate(SITE, f"w{k}", path, plain, 1.1, rng)
        out.append(dataclasses.replace(w, real=simulated(board, profile, w, seed=70 + k, room=70)))  # type: ignore[arg-type]
    return out


ROOMS = (1, 2, 3, 4)


def test_the_loop_finds_what_the_toy_board_needs_to_give_the_real_statistics() -> None:
    walks = _walks(count=6)
    start = _direct(KNOWN)
    real = statistics(angle_stats([w.real for w in walks]))
    before = simulate(toy_board, start, walks, ROOMS)
    assert before["az_tail"] < 0.6 * real["az_tail"] and before["corr_time_s"] < 0.7 * real["corr_time_s"]
    profile, report = calibrate(start, walks, toy_board, iterations=5, rooms=ROOMS)
    after = simulate(toy_board, profile, walks, ROOMS)
    for name in STATISTICS:
        assert after[name] == pytest.approx(real[name], rel=0.12), name
    for name in ("compression_45-60", "compression_60-90"):
        assert after[name] == pytest.approx(real[name], abs=1.0), name
    az = profile.azimuth
    # the toy board's distortions undone: each parameter back near the one the walks were made with
    assert az.slow_time_s == pytest.approx(1.6, rel=0.25) and az.slow_sigma_deg == pytest.approx(5.0, rel=0.15)
    # the tails: some 80 reports of the "real" walks
    assert az.burst_rate_hz == pytest.approx(0.4, rel=0.5) and az.burst_rate_hz > 2 * 0.4 * 0.4
    assert profile.elevation.burst_rate_hz == pytest.approx(0.3, rel=0.5)
    assert profile.missing.rate_high == pytest.approx(0.08, rel=0.3)
    # one step moves every knot of a bin alike (60 and 75 share the 60-90 degree bin)
    assert az.compression(60.0) == pytest.approx(-14.0, abs=3.5) and az.compression(60.0) < -7.0 - 3.0
    assert len(report["steps"]) == 5  # type: ignore[arg-type]
    how = profile.sources["azimuth.slow_time_s"]
    assert how.recordings == ("w0", "w1") and how.how.startswith("a grid over the time; calibrated")
    assert "autocorrelation time" in how.how


def test_a_statistic_that_barely_moves_does_not_throw_its_parameter_far() -> None:
    walks = _walks()
    start = dataclasses.replace(_direct(KNOWN), missing=Missing(0.0, 0.001, 1.0))  # far too few lost
    profile, _ = calibrate(start, walks, toy_board, iterations=1, rooms=ROOMS)
    assert profile.missing.rate_high == pytest.approx(0.002)  # one step: at most twice


def test_the_board_rounds_and_takes_the_median_of_three_as_the_firmware() -> None:
    assert output_angles([1.4, 10.6, -3.0, 95.0]) == [1, 11, 1, 11]
    assert output_angles([1.4, 10.6, -3.0, 95.0], smooth=False) == [1, 11, -3, 90]


def test_the_emulators_board_reports_whole_degrees_and_loses_events() -> None:
    walks = _walks(board=simulated_errors, profile=KNOWN, count=1)
    (w,) = walks
    for b, (kept, az, el) in zip(w.boards, simulated_errors(KNOWN, w.boards, 3, 1)):
        assert 0.85 * len(b.t) < len(kept) < len(b.t) and np.all(az == np.round(az)) and np.all(np.abs(el) <= 90)
    assert simulated_errors(KNOWN, w.boards, 3, 1)[0][1].tolist() == simulated_errors(KNOWN, w.boards, 3, 1)[0][1].tolist()


EMULATED = AoaProfile(
    azimuth=AngleError(bias_deg=1.0, field_sigma_deg=4.0, field_length_m=1.0, field_heading_m=1.0,
                       slow_sigma_deg=3.0, slow_time_s=0.5, white_sigma_deg=1.0, burst_rate_hz=0.15,
                       burst_duration_s=0.4, burst_offset_min_deg=20.0, burst_offset_excess_deg=5.0,
                       curve_at_deg=CURVE, compression_deg=(0.0, -2.0, -12.0)),
    elevation=AngleError(bias_deg=-4.0, field_sigma_deg=5.0, slow_sigma_deg=4.0, slow_time_s=0.5,
                         burst_rate_hz=0.1, burst_duration_s=0.4, burst_offset_min_deg=25.0),
    missing=Missing(0.0, 0.06, 1.2))
"""Known parameters for walks the emulator's own board makes."""


def _recordings(profile: AoaProfile, count: int) -> list[Recording]:
    """``count`` walks of one room through the emulator's board, as recordings of their events."""
    rng = np.random.default_rng(11)
    ids = {a.name: a.id for a in SITE.anchors}
    out = []
    for k in range(count):
        path = walk(100.0 * k)
        plain = residuals(SITE, reports(AoaProfile(), path, seed=k), path)
        w = walk_to_calibrate(SITE, f"w{k}", path, plain, 1.1, rng)
        events = [bearing_of(float(b.t[i]), AngleEvent(TAG, -60, int(a), int(e), -62, 37, ids[b.board], "", 0))
                  for b, (kept, az, el) in zip(w.boards, simulated_errors(profile, w.boards, 40 + k, 40))
                  for i, a, e in zip(kept.tolist(), az.tolist(), el.tolist())]
        out.append(Recording(f"w{k}", f"capture:w{k}.pcapng", sorted(events, key=lambda x: x.t), path, f"w{k}.csv"))
    return out


@pytest.mark.slow
def test_radio_fit_calibrated_through_the_emulators_board_gives_the_walks_statistics_back() -> None:
    """Walks the emulator's own board made with known parameters, fitted with the board as the
    hook: after calibration the spread, both tails and the missing events are each within 15 %
    of theirs in the calibration's rooms, closer than the direct fit's worst (its missing
    events, some 30 % short: the board's rounding and median). (Not asserted: the known parameters themselves, nor the
    autocorrelation time: on three walks of one room it is the room's field more than the
    wander's time, and other rooms' fields give other times.)"""
    recordings = _recordings(EMULATED, 3)
    calibrated, report = fit(SITE, recordings, "calibrated", board=simulated_errors)
    assert calibrated.aoa is not None
    real: dict[str, float] = report["calibration"]["real"]  # type: ignore[index]
    steps: list[dict[str, dict[str, float]]] = report["calibration"]["steps"]  # type: ignore[index]
    first, last = steps[0]["simulated"], steps[-1]["simulated"]
    names = ("az_mad_sigma", "az_tail", "el_tail", "missing")
    for name in names:
        assert last[name] == pytest.approx(real[name], rel=0.15), name
    assert max(abs(last[n] / real[n] - 1) for n in names) < max(abs(first[n] / real[n] - 1) for n in names)
    assert calibrated.aoa.azimuth.slow_time_s >= 0.05
    assert "calibrated (host/aoa_calibrate.py)" in calibrated.aoa.sources["azimuth.burst_rate_hz"].how
