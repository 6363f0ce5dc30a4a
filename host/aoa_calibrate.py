"""Calibrating a fitted ``[aoa]`` against the emulator's own board: what ``rfhoming radio-fit`` does after the fit.

The direct fit (host/aoa_fit.py) turns the recordings' residuals into the process's parameters,
but the emulator does not hand that process to a host as it is: its board rounds and
median-buffers each tag's angles (firmware_py/xplr_aoa.py), the field is sampled along a walk
at the tag's own rate, some events are lost, and the statistics themselves (the median
autocorrelation time, 1.4826 MAD, the tail beyond 20 degrees) are not the parameters. So the
direct fit's profile, run through the emulator, gives statistics that differ from the
recordings' it came from (docs/RESULTS.md, "The emulated XPLR-AOA against real recordings").

Calibration closes that loop. The fitted profile is simulated through the emulator's board
(a :data:`~rfhoming.protocol.radio_profile.Board`, passed in: the host cannot import the
emulator) on the recordings' own walks, at their event rates, in a few fixed rooms
(:data:`ROOMS`: each its own field and per-board compression); the statistics of
host/angle_residuals.py are taken of those reports as of the real ones; and each parameter is
moved by the ratio of the real statistic to the simulated one (a fixed-point iteration,
:data:`ITERATIONS` times, each step's factor held to :data:`MAX_STEP`):

==========================  =========================================================
statistic                   parameter(s)
==========================  =========================================================
1.4826 MAD (az, el)         the field's, the wander's, the white and the bias sigmas
tail beyond 20 deg (az, el) the burst rate
autocorrelation time (az)   the wander's time (the field's length without a wander)
worst missing fraction      the loss rates (low and high)
compression by |azimuth|    the compression curve's knots in that bin (a shift, added)
==========================  =========================================================

Each figure it moved says so in its ``[aoa.sources]`` entry (the recordings stay those it was
fitted to). For fitting only: a localiser never sees the truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from rfhoming.host.angle_residuals import COMPRESSION_BINS_DEG, AngleStats, Residuals, angle_stats, true_angles
from rfhoming.host.groundtruth import WalkedPath
from rfhoming.host.site import Site
from rfhoming.protocol.radio_profile import AngleError, AoaProfile, Board, BoardWalk, Source

ROOMS = tuple(range(9001, 9009))
"""The rooms (room seeds) the profile is simulated in: fixed, so a fit is repeatable."""

SEED = 9000
"""The first simulated run's seed (each room's run: this plus the room's index)."""

ITERATIONS = 3
"""Fixed-point steps (each one simulation of every walk in every room)."""

MAX_STEP = 2.0
"""A step moves a parameter by at most this factor either way (a statistic that barely moves
with its parameter does not throw it far)."""

SCHEDULE_SLACK = 1.05
"""The emulated tag sends every interval / this plus up to 10 % (the emulator's schedule), so
its mean rate is the recording's (bench/fidelity.py does the same)."""

MIN_SLOW_TIME_S = 0.05
"""The wander's time is kept above this (below it, events at 10-50 Hz see white noise)."""


@dataclass(frozen=True)
class WalkToCalibrate:
    """One recording to reproduce: its walk as each of its anchors saw it, and its real residuals."""

    id: str
    boards: tuple[BoardWalk, ...]
    real: dict[str, Residuals]
    anchors: tuple[str, ...]  # the anchors' names, in the order of ``boards``


def walk_to_calibrate(site: Site, wid: str, path: WalkedPath, real: dict[str, Residuals], height: float,
                      rng: np.random.Generator) -> WalkToCalibrate:
    """The recording ``wid``'s walk for the emulator's board: each anchor that reported in it
    hears the tag along ``path`` at the recording's event rate (its best anchor's reports per
    second), on its own jittered schedule, as the emulator's boards do."""
    reported = {name: r for name, r in real.items() if len(r.t) >= 2}
    first = min(float(r.t[0]) for r in reported.values())
    last = max(float(r.t[-1]) for r in reported.values())
    interval = (last - first) / max(len(r.t) for r in reported.values()) / SCHEDULE_SLACK
    boards, names = [], []
    for anchor in site.anchors:
        if anchor.name not in reported:
            continue
        steps = interval * (1.0 + rng.uniform(0.0, 0.1, int((last - first) / interval) + 2))
        t = first + float(rng.uniform(0.0, interval)) + np.r_[0.0, np.cumsum(steps)]
        t = t[t <= last]
        points = np.column_stack([path.at(t), np.full(len(t), height)])
        truth = true_angles(anchor, points)
        tag = np.column_stack([points, path.heading(t)])
        pose = (*(float(v) for v in anchor.position), math.radians(anchor.yaw_deg))
        boards.append(BoardWalk(anchor.name, (pose[0], pose[1], pose[2], pose[3]), t, truth[:, 0], truth[:, 1], tag))
        names.append(anchor.name)
    return WalkToCalibrate(wid, tuple(boards), real, tuple(names))


def simulated(board: Board, aoa: AoaProfile, walk: WalkToCalibrate, seed: int, room: int) -> dict[str, Residuals]:
    """The walk's residuals as the emulator's board reports it under ``aoa`` in ``room``."""
    out = {}
    for b, name, (kept, az, el) in zip(walk.boards, walk.anchors, board(aoa, walk.boards, seed, room)):
        if len(kept) == 0:
            continue
        distance = np.linalg.norm(b.tag[kept, :3] - np.asarray(b.pose[:3]), axis=1)
        out[name] = Residuals(name, b.t[kept], az, el, b.azimuth[kept], b.elevation[kept],
                              np.full(len(kept), -60.0), distance, np.ones(len(kept), bool))
    return out


STATISTICS = ("az_mad_sigma", "az_tail", "el_mad_sigma", "el_tail", "corr_time_s", "missing")
"""The statistics calibrated, besides the compression bins."""


def statistics(s: AngleStats) -> dict[str, float]:
    """The calibrated statistics of ``s``, the compression bins as ``compression_LO-HI``."""
    values = {k: float(getattr(s, k)) for k in STATISTICS}
    values.update({f"compression_{k}": v for k, v in s.compression.items()})
    return values


def simulate(board: Board, aoa: AoaProfile, walks: Sequence[WalkToCalibrate],
             rooms: Sequence[int] = ROOMS) -> dict[str, float]:
    """The statistics of every walk run through ``board`` in each room, averaged over the rooms
    (as bench/fidelity.py averages over its repeats)."""
    per_room = [statistics(angle_stats([simulated(board, aoa, w, SEED + k, room) for w in walks]))
                for k, room in enumerate(rooms)]
    keys = set.intersection(*(set(p) for p in per_room))
    return {k: float(np.nanmean([p[k] for p in per_room])) for k in sorted(keys)}


def _ratio(real: float, sim: float) -> float | None:
    """real / simulated, held to MAX_STEP either way; None where either is not positive."""
    if not (math.isfinite(real) and math.isfinite(sim)) or real <= 0 or sim <= 0:
        return None
    return min(MAX_STEP, max(1.0 / MAX_STEP, real / sim))


def _scale_sigmas(e: AngleError, f: float) -> AngleError:
    return replace(e, field_sigma_deg=round(e.field_sigma_deg * f, 3), slow_sigma_deg=round(e.slow_sigma_deg * f, 3),
                   white_sigma_deg=round(e.white_sigma_deg * f, 3), bias_sigma_deg=round(e.bias_sigma_deg * f, 3))


def step(aoa: AoaProfile, real: dict[str, float], sim: dict[str, float]) -> tuple[AoaProfile, dict[str, float]]:
    """One fixed-point step: the profile moved toward the real statistics, and the factor (or,
    for the compression, the shift) each figure was moved by."""
    moved: dict[str, float] = {}
    axes = {}
    for axis, prefix in (("azimuth", "az"), ("elevation", "el")):
        e: AngleError = getattr(aoa, axis)
        f = _ratio(real[f"{prefix}_mad_sigma"], sim[f"{prefix}_mad_sigma"])
        if f is not None:
            moved.update({f"{axis}.{k}": f for k in ("field_sigma_deg", "slow_sigma_deg", "white_sigma_deg",
                                                      "bias_sigma_deg") if getattr(e, k) > 0})
            e = _scale_sigmas(e, f)
        f = _ratio(real[f"{prefix}_tail"], sim[f"{prefix}_tail"])
        if f is not None and e.burst_rate_hz > 0:
            e = replace(e, burst_rate_hz=round(min(100.0, e.burst_rate_hz * f), 5))
            moved[f"{axis}.burst_rate_hz"] = f
        axes[axis] = e
    az = axes["azimuth"]
    f = _ratio(real["corr_time_s"], sim["corr_time_s"])
    if f is not None:
        if az.slow_sigma_deg > 0:
            az = replace(az, slow_time_s=round(max(MIN_SLOW_TIME_S, az.slow_time_s * f), 4))
            moved["azimuth.slow_time_s"] = f
        elif az.field_sigma_deg > 0:
            az = replace(az, field_length_m=round(az.field_length_m * f, 4))
            moved["azimuth.field_length_m"] = f
    if az.compression_deg:
        knots = np.asarray(az.curve_at_deg)
        shifts = np.asarray(az.compression_deg, float)
        for lo, hi in zip(COMPRESSION_BINS_DEG, COMPRESSION_BINS_DEG[1:]):
            key = f"compression_{lo:g}-{hi:g}"
            if lo < 15.0 or key not in real or key not in sim:
                continue
            inside = (knots >= lo) & (knots < hi) & (knots > 0)
            shifts[inside] += real[key] - sim[key]
            if inside.any():
                moved[f"azimuth.compression_deg {lo:g}-{hi:g}"] = real[key] - sim[key]
        az = replace(az, compression_deg=tuple(round(float(v), 2) for v in np.clip(shifts, -90.0, 90.0)))
    m = aoa.missing
    f = _ratio(real["missing"], sim["missing"])
    if f is not None and m.rate_high > 0:
        m = replace(m, rate_low=round(min(0.99, m.rate_low * f), 5), rate_high=round(min(0.99, m.rate_high * f), 5))
        moved.update({f"missing.{k}": f for k in ("rate_low", "rate_high") if getattr(m, k) > 0})
    return replace(aoa, azimuth=az, elevation=axes["elevation"], missing=m), moved


def calibrate(aoa: AoaProfile, walks: Sequence[WalkToCalibrate], board: Board, *, iterations: int = ITERATIONS,
              rooms: Sequence[int] = ROOMS, progress: Callable[[str], None] = lambda _: None,
              ) -> tuple[AoaProfile, dict[str, object]]:
    """``aoa`` moved so that ``board`` on ``walks`` in ``rooms`` gives the walks' real
    statistics; and a report (the real statistics, the simulated ones before each step, the
    factors). The moved figures' sources say how."""
    real = statistics(angle_stats([w.real for w in walks]))
    history: list[dict[str, object]] = []
    total: dict[str, float] = {}
    for k in range(iterations):
        sim = simulate(board, aoa, walks, rooms)
        progress(f"calibration step {k + 1}/{iterations}: " + ", ".join(
            f"{name} {sim[name]:.3g} (real {real[name]:.3g})" for name in ("az_tail", "corr_time_s", "az_mad_sigma")
            if name in sim) + "\n")
        aoa, moved = step(aoa, real, sim)
        history.append({"simulated": {n: round(v, 4) for n, v in sim.items()},
                        "moved": {n: round(v, 4) for n, v in moved.items()}})
        for name, f in moved.items():
            total[name] = total.get(name, 0.0 if "compression" in name else 1.0)
            total[name] = total[name] + f if "compression" in name else total[name] * f
    how = (f"; calibrated (host/aoa_calibrate.py): {iterations} step(s) through the emulator's board on these "
           f"walks in rooms {rooms[0]}-{rooms[-1]}, moved {{change}} in all so that it gives the recordings' {{stat}}")
    changes: dict[str, list[str]] = {}
    for name, change in total.items():
        figure, _, where = name.partition(" ")
        changes.setdefault(figure, []).append(f"by {change:+.2f} deg in the {where}-degree bin" if where
                                              else f"x{change:.3f}")
    sources = dict(aoa.sources)
    for figure, texts in changes.items():
        axis, key = figure.split(".", 1)
        stat = ("elevation " if axis == "elevation" else "") + _STAT_OF[key]
        old = sources.get(figure)
        if old is not None:
            sources[figure] = Source(old.recordings, old.how + how.format(change=", ".join(texts), stat=stat))
    report: dict[str, object] = {"real": {n: round(v, 4) for n, v in real.items()}, "steps": history,
                                 "rooms": list(rooms)}
    return replace(aoa, sources=sources), report


_STAT_OF = {"field_sigma_deg": "1.4826 MAD", "slow_sigma_deg": "1.4826 MAD", "white_sigma_deg": "1.4826 MAD",
            "bias_sigma_deg": "1.4826 MAD", "burst_rate_hz": "tail beyond 20 deg",
            "slow_time_s": "azimuth autocorrelation time", "field_length_m": "azimuth autocorrelation time",
            "rate_low": "worst missing fraction", "rate_high": "worst missing fraction",
            "compression_deg": "|azimuth| compression"}
