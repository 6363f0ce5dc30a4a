"""Fitting a radio profile's ``[aoa]`` error process to recordings with a known walk.

The process is protocol/radio_profile.py's :class:`AngleError` per axis and :class:`Missing`
(docs/emulator.md, "Radio profiles"). From each recording's residuals (host/angle_residuals.py:
each report less the angle the board would give for the true position), per axis:

1. curves over the true |azimuth| (7.5-degree bins with enough reports): the compression
   (azimuth: the median outward-signed error, 0 at boresight, since the error is odd in the
   angle and a shift there would tear the angles apart; each anchor's factor on it) or the
   offset (elevation: each bin's median less the median of all); the spread (each bin's robust
   sigma over all) and, after the bursts are set aside, the outward skew;
2. bursts: runs of reports more than :data:`BURST_SIGMAS` core sigmas from their recording's
   level, joined across gaps up to :data:`BURST_GAP_S`: how often they start, how long they
   last, how far off they are and which way;
3. the rest, in units of the spread, from the pair products of the reports outside bursts (the
   method of moments), binned by time, distance and turn apart: within a recording (the slow
   wander plus the field), across recordings of one anchor and within one far apart in time
   (the field alone: its length and heading scale), far apart in place (the levels, and the
   bias); a grid over length, heading scale and time, non-negative least squares for the
   variances at each point, the three held to the variance; white noise is what is left;
4. missing events: each anchor's share of the advertisements it did not report, against the
   anchor of its recording that reported most (as the statistic of host/angle_residuals.py), and
   the mean run of losses from the gaps in its stream.

Where the recordings cannot tell the field from the wander (no place visited twice: no second
walk and no return), all of the slow error is put in the field and the profile says so in
``[aoa.assumed]``. For fitting and benches only: no localiser ever sees the truth.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

from rfhoming.host.angle_residuals import Residuals, mad_sigma, missing_fraction
from rfhoming.host.groundtruth import WalkedPath
from rfhoming.protocol.radio_profile import AngleError, AoaProfile, Missing, Source

CURVE_STEP_DEG = 7.5
"""The curves' knots over the true |azimuth|, and each knot's bin width (centred on it)."""

MIN_BIN_EVENTS = 100
"""Reports a curve's bin needs before it is a knot."""

BURST_SIGMAS = 3.0
"""A report this many core sigmas (1.4826 MAD) from its recording's level is in a burst."""

SKEW_QUANTILES = (15.87, 84.13)
"""The skew compares the spread above the median (to this upper quantile) with the spread below."""

BURST_GAP_S = 0.2
"""Reports beyond the threshold this close in time belong to one burst."""

PAIR_GRID_S = 0.1
"""Reports are thinned to one per this many seconds for the pair products."""

ACROSS_THIN = 2
"""Pairs across recordings take every this many thinned reports of each (their bins fill anyway)."""

FAR_S = 10.0
"""Pairs of one recording further apart in time than this see no slow wander: the field and bias alone."""

FAR_M = 3.0
"""Pairs further apart than this see no field: the bias alone."""

LAG_EDGES_S = (0.0, 0.15, 0.25, 0.4, 0.6, 0.8, 1.0, 1.3, 1.7, 2.2, 3.0, 4.0, 5.5, 7.5, FAR_S)
DISTANCE_EDGES_M = (0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0, 1.3, 1.7, 2.2, FAR_M, math.inf)
LENGTH_GRID_M = tuple(float(v) for v in np.geomspace(0.05, 10.0, 25))
TIME_GRID_S = tuple(float(v) for v in np.geomspace(0.05, FAR_S / 3, 20))
HEADING_GRID_M = (0.0, *(float(v) for v in np.geomspace(0.05, 10.0, 19)))

GRID_STRIDE = 3
"""The grid search first takes every third point of each grid, then every point near the best."""

MIN_PAIRS = 50
"""Pairs a bin needs before it is an equation of the fit."""

ZERO_LAG_WEIGHT = 100.0
"""The variance's equation weighs this many times the biggest bin: the parts add up to it."""

REVISIT_M = 1.0
"""Two reports of one anchor this close in place, from two recordings or one recording FAR_S
apart, are the same place visited again ..."""

MIN_SPATIAL_PAIRS = 500
"""... and this many such pairs (thinned) tell the field from the slow wander."""


@dataclass(frozen=True)
class Walk:
    """One recording with its truth: ``residuals`` by anchor name (host/angle_residuals.py)."""

    id: str
    path: WalkedPath
    residuals: dict[str, Residuals]


@dataclass
class _Series:
    """One anchor's reports in one recording, on one axis."""

    walk: str
    anchor: str
    t: np.ndarray
    err: np.ndarray  # reported - true, degrees
    true: np.ndarray  # degrees, this axis's
    azimuth: np.ndarray  # degrees, the true azimuth (the curves' argument)
    xy: np.ndarray  # (N, 2) the tag's true place
    heading: np.ndarray  # rad, the way its carrier went


@dataclass
class AxisFit:
    """One axis's figures and what each rests on (for the profile's sources and the report)."""

    error: AngleError
    sources: dict[str, Source] = field(default_factory=dict)
    assumed: dict[str, str] = field(default_factory=dict)
    report: dict[str, object] = field(default_factory=dict)


def fit_aoa(walks: Sequence[Walk]) -> tuple[AoaProfile, dict[str, object]]:
    """The profile's ``[aoa]`` for these recordings, and a report of what the fit saw."""
    if not walks or not any(w.residuals for w in walks):
        raise ValueError("no angle reports to fit: the recordings hold none of the site's anchors and tag")
    fits = {}
    for axis in ("azimuth", "elevation"):
        series = _series(walks, axis)
        fits[axis] = fit_axis(series, compress=axis == "azimuth") if _reported(series) else _not_reported(axis, series)
    missing, missing_sources, missing_report = fit_missing(walks)
    sources = {f"{axis}.{k}": v for axis, f in fits.items() for k, v in f.sources.items()}
    sources.update({f"missing.{k}": v for k, v in missing_sources.items()})
    assumed = {f"{axis}.{k}": v for axis, f in fits.items() for k, v in f.assumed.items()}
    assumed["carried_board"] = CARRIED
    profile = AoaProfile(fits["azimuth"].error, fits["elevation"].error, missing, sources, assumed)
    report: dict[str, object] = {axis: f.report for axis, f in fits.items()}
    report["missing"] = missing_report
    report["warnings"] = warnings(profile)
    return profile, report


def _reported(series: list[_Series]) -> bool:
    """Whether the board reports this axis at all: a board without it (no elevation) prints
    one value throughout (0), which is not an angle with an error to fit."""
    said = np.concatenate([s.err + s.true for s in series]) if series else np.zeros(0)
    return bool(len(said)) and float(np.ptp(said)) > 0


def _not_reported(axis: str, series: list[_Series]) -> AxisFit:
    """A quiet :class:`AngleError` for an axis the board does not report, and why."""
    said = float((series[0].err + series[0].true)[0]) if series else 0.0
    fit = AxisFit(AngleError())
    why = f"the board reports no {axis} (every report {said:g} deg): nothing to fit, the profile gives it no error"
    fit.assumed = {f.name: why for f in dataclasses.fields(AngleError)}
    fit.report = {"events": int(sum(len(s.t) for s in series)), "reported": False}
    return fit


BOUNDS = {"field_length_m": (LENGTH_GRID_M[0], LENGTH_GRID_M[-1]),
          "field_heading_m": (math.nan, HEADING_GRID_M[-1]),  # 0: no heading effect, a real answer
          "slow_time_s": (TIME_GRID_S[0], TIME_GRID_S[-1])}
"""The fit's grids: a figure at either end is where the grid stopped, not what the data say."""

COMPRESSION_SPREAD_WARN = 0.5
"""A per-board compression spread beyond this draws boards 1.5x (and 0.5x) the curve and more:
the anchors disagree about the curve rather than share one."""


def warnings(profile: AoaProfile) -> list[str]:
    """One line per fitted figure that sits at the end of its grid or is implausibly wide,
    naming it (radio-fit prints them; the profile is still written)."""
    out = []
    for axis in ("azimuth", "elevation"):
        error: AngleError = getattr(profile, axis)
        for name, (low, high) in BOUNDS.items():
            value = float(getattr(error, name))
            if f"{axis}.{name}" not in profile.assumed and (math.isclose(value, low, rel_tol=0.02) or math.isclose(value, high, rel_tol=0.02)):
                out.append(f"{axis}.{name} = {value:g} is at the end of the fit's grid ({low:g}..{high:g}): the "
                           "recordings do not determine it; walk more places, and more than once")
        if error.compression_spread > COMPRESSION_SPREAD_WARN:
            out.append(f"{axis}.compression_spread = {error.compression_spread:g} (> {COMPRESSION_SPREAD_WARN:g}): "
                       "the anchors' compression curves disagree; an emulated board may draw "
                       f"{1 + 2 * error.compression_spread:.1f}x the curve")
    return out


CARRIED = ("no recording of a board carried on a robot is known to the project: a carried board (S0's, and the "
           "docking station's array that tracks the robot, S1's) takes the fixed anchors' figures, its field over "
           "where both the board and the tag are")


def _series(walks: Sequence[Walk], axis: str) -> list[_Series]:
    out = []
    for w in walks:
        for name, r in w.residuals.items():
            if len(r.t) == 0:
                continue
            err, true = (r.az_err, r.az_true) if axis == "azimuth" else (r.el_err, r.el_true)
            out.append(_Series(w.id, name, r.t, np.asarray(err, float), np.asarray(true, float),
                               np.asarray(r.az_true, float), w.path.at(r.t), w.path.heading(r.t)))
    return out


def fit_axis(series: list[_Series], compress: bool) -> AxisFit:
    """One axis's :class:`AngleError` from its series."""
    everyone = tuple(sorted({s.walk for s in series}))
    knots = curve_knots(series)
    shifts, factors = compression(series, knots) if compress else ((), [])
    for s in series:
        s.err = s.err - np.sign(s.true) * np.interp(np.abs(s.azimuth), knots, shifts) if shifts else s.err
    offsets = () if compress else offset_curve(series, knots)
    for s in series:
        s.err = s.err - np.interp(np.abs(s.azimuth), knots, offsets) if offsets else s.err
    level = {id(s): float(np.median(s.err)) for s in series}
    spread = spread_curve(series, knots, level)
    for s in series:  # from here on, the random part in units of the spread
        s.err = level[id(s)] + (s.err - level[id(s)]) / np.interp(np.abs(s.azimuth), knots, spread)
    core_sigma = mad_sigma(np.concatenate([s.err - level[id(s)] for s in series]))
    threshold = BURST_SIGMAS * max(core_sigma, 0.5)
    bursts, in_burst = _bursts(series, level, threshold)
    core_time = sum(float(s.t[-1] - s.t[0]) for s in series) - sum(b.duration for b in bursts)
    core = [(s, ~mask) for s, mask in zip(series, in_burst)]
    bias = float(np.median(np.concatenate([s.err[keep] for s, keep in core])))
    skew = skew_curve(core, knots)
    slow = _moments(core, bias, threshold)
    spread_sd = float(np.std(factors, ddof=1)) if len(factors) >= 2 else 0.0
    error = AngleError(
        bias_deg=round(bias, 2), bias_sigma_deg=round(math.sqrt(slow.bias_var), 2),
        field_sigma_deg=round(math.sqrt(slow.field_var), 2), field_length_m=round(slow.length_m, 3),
        field_heading_m=round(slow.heading_m, 3),
        slow_sigma_deg=round(math.sqrt(slow.slow_var), 2), slow_time_s=round(slow.time_s, 3),
        white_sigma_deg=round(math.sqrt(slow.white_var), 2),
        burst_rate_hz=round(len(bursts) / max(core_time, 1e-9), 4),
        burst_duration_s=round(float(np.mean([b.duration for b in bursts])) if bursts else 0.1, 3),
        burst_offset_min_deg=round(threshold, 2),
        burst_offset_excess_deg=round(float(np.mean([max(0.0, abs(b.offset) - threshold) for b in bursts]))
                                      if bursts else 0.0, 2),
        burst_outward=round(float(np.mean([b.outward for b in bursts])) if bursts else 0.5, 3),
        curve_at_deg=tuple(knots), compression_deg=tuple(round(v, 2) for v in shifts),
        compression_spread=round(spread_sd, 3), offset_deg=tuple(round(v, 2) for v in offsets),
        spread=tuple(round(v, 3) for v in spread), skew=tuple(round(v, 3) for v in skew))
    fit = AxisFit(error, _sources(everyone, slow, threshold, compress))
    if not slow.identified:
        fit.assumed["slow_sigma_deg"] = ("no place was visited twice (a second walk, or a return more than "
                                         f"{FAR_S:g} s later, within {REVISIT_M:g} m): the slow error cannot be told apart "
                                         "from a field over position, and is all put in the field (real dwells show "
                                         "errors that stay put)")
        fit.sources.pop("slow_sigma_deg")
    if not compress:
        fit.assumed["compression_spread"] = "no compression curve is fitted to this axis (only |azimuth| compresses)"
    elif len(factors) < 2:
        fit.assumed["compression_spread"] = ("fewer than two anchors saw angles wide enough to compare their "
                                             "compression: every board is given the pooled curve")
        fit.sources.pop("compression_spread")
    fit.report = {"events": int(sum(len(s.t) for s in series)), "core_sigma_deg": round(core_sigma, 2),
                  "bursts": len(bursts), "spatial_pairs": slow.spatial_pairs, "fit_rms": round(slow.rms, 3),
                  "compression_factors": [round(f, 3) for f in factors]}
    return fit


def _sources(everyone: tuple[str, ...], slow: _Moments, threshold: float, compress: bool) -> dict[str, Source]:
    """How each figure of an axis was fitted, and from which recordings."""
    moments = ("method of moments on the pair products of the reports outside bursts (thinned to one per "
               f"{PAIR_GRID_S:g} s, clipped at the burst threshold, in units of the spread)")
    cut = f"beyond {BURST_SIGMAS:g} x 1.4826 MAD ({threshold:.1f} deg) of each recording's median"
    hows = {
        "bias_deg": "median error outside bursts" + (", after the compression" if compress else ""),
        "bias_sigma_deg": moments + f": pairs more than {FAR_S:g} s and {FAR_M:g} m apart within a recording",
        "field_sigma_deg": moments + ": pairs of one anchor in different recordings, or one recording more "
                           f"than {FAR_S:g} s apart, by distance apart",
        "field_length_m": "as field_sigma_deg: exp(-D / length) fitted by a grid over the length",
        "field_heading_m": "as field_sigma_deg: D = hypot(distance, heading scale x chord between the walker's "
                           "headings), fitted by a grid over the scale",
        "slow_sigma_deg": moments + f": pairs within a recording by time apart (up to {FAR_S:g} s), less the field",
        "slow_time_s": "as slow_sigma_deg: exp(-dt / time) fitted by a grid over the time",
        "white_sigma_deg": "the variance outside bursts less the bias, field and slow parts",
        "skew": "(q84 - 2 median + q16) / (q84 - q16) of the outward-signed reports outside bursts, in units of "
                f"the spread, in the same {CURVE_STEP_DEG:g}-degree bins",
        "burst_rate_hz": f"runs of reports {cut} (joined across {BURST_GAP_S:g} s) per second outside them",
        "burst_duration_s": "mean length of those runs (first to last report)",
        "burst_offset_min_deg": "the threshold that defines a burst",
        "burst_offset_excess_deg": "mean of each run's median |offset| beyond the threshold",
        "burst_outward": "share of those runs whose offset points away from boresight",
        "spread": f"1.4826 MAD about each recording's median in {CURVE_STEP_DEG:g}-degree bins of the true |azimuth| "
                  f"with at least {MIN_BIN_EVENTS} reports, over that of all reports",
    }
    if compress:
        hows["compression_deg"] = (f"median outward-signed error in {CURVE_STEP_DEG:g}-degree bins of the true "
                                   f"|azimuth| with at least {MIN_BIN_EVENTS} reports; 0 at boresight")
        hows["compression_spread"] = ("standard deviation over the anchors of each one's least-squares factor on the "
                                      "pooled curve (its own bin medians, where the curve shifts 2 degrees or more)")
    else:
        hows["offset_deg"] = (f"median error in {CURVE_STEP_DEG:g}-degree bins of the true |azimuth| with at least "
                              f"{MIN_BIN_EVENTS} reports, less the median of all")
    used = {k: everyone for k in hows}
    for k in ("field_sigma_deg", "field_length_m", "field_heading_m"):
        used[k] = tuple(sorted(slow.spatial_walks)) or everyone
    return {k: Source(used[k], v) for k, v in hows.items()}


def curve_knots(series: list[_Series]) -> tuple[float, ...]:
    """0, then every CURVE_STEP_DEG of true |azimuth| whose bin holds enough reports."""
    true = np.abs(np.concatenate([s.azimuth for s in series]))
    knots = [0.0]
    for k in np.arange(CURVE_STEP_DEG, 90.0, CURVE_STEP_DEG):
        if (np.abs(true - k) < CURVE_STEP_DEG / 2).sum() >= MIN_BIN_EVENTS:
            knots.append(float(k))
    return tuple(knots)


def _in_bin(azimuth: np.ndarray, knot: float) -> np.ndarray:
    a = np.abs(azimuth)
    return np.asarray((a < CURVE_STEP_DEG / 2) if knot == 0 else (np.abs(a - knot) < CURVE_STEP_DEG / 2), bool)


def compression(series: list[_Series], knots: tuple[float, ...]) -> tuple[tuple[float, ...], list[float]]:
    """The outward shift at each knot (0 at boresight: the error is odd in the angle) and each
    anchor's least-squares factor on that curve (anchors that saw two knots that shift 2 degrees or more)."""
    az = np.concatenate([s.azimuth for s in series])
    outward = np.concatenate([s.err * np.sign(s.true) for s in series])
    shifts = tuple(0.0 if k == 0 else float(np.median(outward[_in_bin(az, k)])) for k in knots)
    factors = []
    for anchor in sorted({s.anchor for s in series}):
        mine = [s for s in series if s.anchor == anchor]
        a_az = np.concatenate([s.azimuth for s in mine])
        a_out = np.concatenate([s.err * np.sign(s.true) for s in mine])
        pairs = [(shift, float(np.median(a_out[_in_bin(a_az, k)]))) for k, shift in zip(knots, shifts)
                 if abs(shift) >= 2.0 and _in_bin(a_az, k).sum() >= MIN_BIN_EVENTS]
        if len(pairs) >= 2:
            c = np.array(pairs)
            factors.append(float(c[:, 0] @ c[:, 1] / (c[:, 0] @ c[:, 0])))
    return (shifts if len(knots) > 1 else ()), factors


def offset_curve(series: list[_Series], knots: tuple[float, ...]) -> tuple[float, ...]:
    """Each knot's median error less the median of all (() with one knot)."""
    az = np.concatenate([s.azimuth for s in series])
    err = np.concatenate([s.err for s in series])
    if len(knots) < 2:
        return ()
    overall = float(np.median(err))
    return tuple(float(np.median(err[_in_bin(az, k)])) - overall for k in knots)


def skew_curve(core: list[tuple[_Series, np.ndarray]], knots: tuple[float, ...]) -> tuple[float, ...]:
    """Each knot's outward skew: (q84 - 2 median + q16) / (q84 - q16) of the outward-signed
    reports outside bursts (0 where a bin has too few)."""
    az = np.concatenate([s.azimuth[keep] for s, keep in core])
    out = np.concatenate([s.err[keep] * np.where(s.true[keep] < 0, -1.0, 1.0) for s, keep in core])
    values = []
    for k in knots:
        inside = out[_in_bin(az, k)]
        low, mid, high = np.percentile(inside, (SKEW_QUANTILES[0], 50.0, SKEW_QUANTILES[1])) if len(inside) else (0, 0, 0)
        values.append(float((high - 2 * mid + low) / (high - low)) if len(inside) >= MIN_BIN_EVENTS and high > low else 0.0)
    return tuple(values)


def spread_curve(series: list[_Series], knots: tuple[float, ...], level: dict[int, float]) -> tuple[float, ...]:
    """The robust spread at each knot over that of all reports (1 everywhere with one knot)."""
    az = np.concatenate([s.azimuth for s in series])
    dev = np.concatenate([s.err - level[id(s)] for s in series])
    overall = max(mad_sigma(dev), 1e-6)
    values = []
    for k in knots:
        inside = _in_bin(az, k)
        values.append(mad_sigma(dev[inside]) / overall if inside.sum() >= MIN_BIN_EVENTS else math.nan)
    good = [v for v in values if math.isfinite(v)]
    if len(knots) < 2 or not good:
        return tuple(1.0 for _ in knots)
    return tuple(v if math.isfinite(v) else good[0] for v in values)


@dataclass(frozen=True)
class _Burst:
    start: float
    duration: float
    offset: float  # median deviation, in units of the spread
    outward: bool  # the offset points away from boresight (the true angle's sign)


def _bursts(series: list[_Series], level: dict[int, float], threshold: float) -> tuple[list[_Burst], list[np.ndarray]]:
    """Every burst, and per series which reports are in one."""
    bursts: list[_Burst] = []
    masks = []
    for s in series:
        dev = s.err - level[id(s)]
        idx = np.nonzero(np.abs(dev) > threshold)[0]
        mask = np.zeros(len(s.t), bool)
        step = float(np.median(np.diff(s.t))) if len(s.t) > 1 else 0.0
        start = 0
        for k in range(1, len(idx) + 1):
            if k == len(idx) or s.t[idx[k]] - s.t[idx[k - 1]] > BURST_GAP_S:
                run = idx[start:k]
                mask[run[0]:run[-1] + 1] = True
                offset = float(np.median(dev[run]))
                bursts.append(_Burst(float(s.t[run[0]]), float(s.t[run[-1]] - s.t[run[0]]) + step, offset,
                                     bool(offset * np.sign(s.true[run[0]]) > 0)))
                start = k
        masks.append(mask)
    return bursts, masks


def _thin(t: np.ndarray) -> np.ndarray:
    """Indices of the first report in each PAIR_GRID_S slot."""
    slots = np.floor((t - t[0]) / PAIR_GRID_S)
    return np.nonzero(np.r_[True, np.diff(slots) > 0])[0]


WITHIN, LATER, ACROSS = 0, 1, 2
"""Pair kinds: one recording within FAR_S, one recording further apart in time, two recordings."""

CHORD_EDGES = (0.0, 0.1, 0.3, 0.6, 1.0, 1.5, 2.01)
"""Bins of the heading chord |u1 - u2| (0: same way; 2: opposite)."""

_BINS: int = 3 * len(LAG_EDGES_S) * (len(DISTANCE_EDGES_M) - 1) * (len(CHORD_EDGES) - 1)

@dataclass
class _Pairs:
    """Pair products binned by (kind, time apart, distance apart, turn apart): per bin their sum,
    count, and the sums of time apart, distance apart and heading chord (for the bin's means)."""

    sums: np.ndarray = field(default_factory=lambda: np.zeros((5, _BINS)))

    def add(self, kind: int, dt: np.ndarray, d: np.ndarray, chord: np.ndarray, prod: np.ndarray) -> None:
        tb = np.minimum(np.digitize(dt, LAG_EDGES_S) - 1, len(LAG_EDGES_S) - 1) if kind == WITHIN else 0 * dt
        db = np.digitize(d, DISTANCE_EDGES_M) - 1
        hb = np.minimum(np.digitize(chord, CHORD_EDGES) - 1, len(CHORD_EDGES) - 2)
        index = ((kind * len(LAG_EDGES_S) + tb) * (len(DISTANCE_EDGES_M) - 1) + db) * (len(CHORD_EDGES) - 1) + hb
        index = index.astype(int).ravel()
        for row, values in enumerate((prod, np.ones(prod.shape), dt, d, chord)):
            self.sums[row] += np.bincount(index, values.ravel(), _BINS)



@dataclass
class _Moments:
    bias_var: float
    field_var: float
    slow_var: float
    white_var: float
    length_m: float
    heading_m: float
    time_s: float
    identified: bool
    spatial_pairs: int
    spatial_walks: set[str]
    rms: float
    levels: tuple[float, float]  # the far pairs' mean products: across recordings, within one


def _moments(core: list[tuple[_Series, np.ndarray]], bias: float, clip: float) -> _Moments:
    """Bias, field and slow variances, the field's length and heading scale, the wander's time, white."""
    thinned = []
    for s, keep in core:
        t, y, xy, h = s.t[keep], np.clip(s.err[keep] - bias, -clip, clip), s.xy[keep], s.heading[keep]
        if len(t) >= 2:
            k = _thin(t)
            thinned.append((s, t[k], y[k], xy[k], np.column_stack([np.cos(h[k]), np.sin(h[k])])))
    pairs = _Pairs()
    spatial_walks: set[str] = set()
    spatial_pairs = 0
    variance_sum, variance_n = 0.0, 0
    for i, (si, ti, yi, pi, ui) in enumerate(thinned):
        variance_sum += float(np.sum(yi * yi))
        variance_n += len(yi)
        for sj, tj, yj, pj, uj in thinned[i:]:
            if sj.anchor != si.anchor:
                continue
            d = np.hypot(pi[:, None, 0] - pj[None, :, 0], pi[:, None, 1] - pj[None, :, 1])
            chord = np.hypot(ui[:, None, 0] - uj[None, :, 0], ui[:, None, 1] - uj[None, :, 1])
            prod = yi[:, None] * yj[None, :]
            dt = np.abs(ti[:, None] - tj[None, :])
            if sj is si:
                upper = np.triu(np.ones(d.shape, bool), 1)
                near, far = upper & (dt < FAR_S), upper & (dt >= FAR_S)
                pairs.add(WITHIN, dt[near], d[near], chord[near], prod[near])
                pairs.add(LATER, dt[far], d[far], chord[far], prod[far])
                close = int((far & (d < REVISIT_M)).sum())
            else:  # every other pair each way: the field needs far fewer than recordings hold
                d, chord, prod, dt = (m[::ACROSS_THIN, ::ACROSS_THIN] for m in (d, chord, prod, dt))
                pairs.add(ACROSS, dt, d, chord, prod)
                close = int((d < REVISIT_M).sum())
            if close:
                spatial_pairs += close
                spatial_walks |= {si.walk, sj.walk}
    return _solve(pairs, variance_sum / max(variance_n, 1), variance_n, spatial_pairs, spatial_walks)


def _solve(pairs: _Pairs, variance: float, events: int, spatial_pairs: int, spatial_walks: set[str]) -> _Moments:
    """The levels are the far pairs' mean products (across recordings; within one); less them,
    for each (length, heading scale, time) of the grid (every third point, then every point
    about the best of those), non-negative least squares for the
    field's, the wander's and the white variance, each bin weighted by the square root of its
    pairs and the three held to add up to the variance (the zero-lag equation, less a positive
    level: the bias's); the best fit wins."""
    prod, n, dt, d, chord = pairs.sums
    kind = np.arange(len(n)) // (_BINS // 3)
    far = d >= FAR_M * n
    level_across = _level(prod, n, far & (kind == ACROSS))
    level_within = _level(prod, n, far & (kind == LATER))
    if level_within is None:
        level_within = level_across or 0.0
    level_across = level_within if level_across is None else level_across
    rows = np.nonzero(n >= MIN_PAIRS)[0]
    identified = spatial_pairs >= MIN_SPATIAL_PAIRS
    n, mean, dt, d, chord = n[rows], prod[rows] / n[rows], dt[rows] / n[rows], d[rows] / n[rows], chord[rows] / n[rows]
    kind = kind[rows]
    # the zero-lag equation holds the parts to the variance itself (a weight above every bin's)
    target = np.r_[mean - np.where(kind == ACROSS, level_across, level_within), variance - max(level_within, 0.0)]
    weight = np.sqrt(np.r_[n, ZERO_LAG_WEIGHT * max(float(n.max()), events)])
    within = np.r_[(kind == WITHIN).astype(float), 1.0]
    white = np.r_[np.zeros(len(rows)), 1.0]
    times = TIME_GRID_S if identified else TIME_GRID_S[:1]

    def miss(k: tuple[int, ...]) -> tuple[float, np.ndarray]:
        rho = np.r_[np.exp(-np.hypot(d, HEADING_GRID_M[k[1]] * chord) / LENGTH_GRID_M[k[0]]), 1.0]
        slow = within * np.exp(-np.r_[dt, 0.0] / times[k[2]]) if identified else np.zeros(len(white))
        coef, r = nnls(np.column_stack([rho, slow, white]) * weight[:, None], target * weight)
        return float(r), coef

    sizes = (len(LENGTH_GRID_M), len(HEADING_GRID_M), len(times))
    coarse = itertools.product(*(range(0, size, GRID_STRIDE) for size in sizes))
    at = min(coarse, key=lambda k: miss(k)[0])
    near = itertools.product(*(range(max(0, i - GRID_STRIDE + 1), min(size, i + GRID_STRIDE)) for i, size in zip(at, sizes)))
    at = min(near, key=lambda k: miss(k)[0])
    residual, coef = miss(at)
    length, heading, time_s = LENGTH_GRID_M[at[0]], HEADING_GRID_M[at[1]], times[at[2]]
    field_var, slow_var, white_var = (float(v) for v in coef)
    return _Moments(max(level_within, 0.0), field_var, slow_var, white_var, length, heading,
                    time_s if identified else 1.0, identified, spatial_pairs, spatial_walks,
                    residual / math.sqrt(float(weight @ weight)), (level_across, level_within))


def _level(prod: np.ndarray, n: np.ndarray, chosen: np.ndarray) -> float | None:
    """The mean product of the chosen bins' pairs, or None without enough of them."""
    count = float(n[chosen].sum())
    return float(prod[chosen].sum()) / count if count >= MIN_PAIRS else None


def fit_missing(walks: Sequence[Walk]) -> tuple[Missing, dict[str, Source], dict[str, float]]:
    """Loss rates (each anchor against its recording's best) and the mean run of losses."""
    rates: list[float] = []
    lost, gaps = 0, 0
    for w in walks:
        if len(w.residuals) < 2:
            continue
        counts = {name: len(r.t) for name, r in w.residuals.items()}
        best = w.residuals[max(counts, key=lambda k: counts[k])]
        if len(best.t) < 2:
            continue
        interval = float(best.t[-1] - best.t[0]) / (len(best.t) - 1)
        for name, r in w.residuals.items():
            rates.append(missing_fraction(w.residuals, name))
            k = np.round(np.diff(r.t) / interval) - 1
            lost += int(k[k > 0].sum())
            gaps += int((k > 0).sum())
    ids = tuple(sorted(w.id for w in walks if len(w.residuals) >= 2))
    if not rates:
        return Missing(), {}, {"anchors": 0}
    finite = [r for r in rates if math.isfinite(r)]
    missing = Missing(rate_low=round(min(finite), 4), rate_high=round(max(finite), 4),
                      burst_events=round(max(1.0, lost / gaps) if gaps else 1.0, 3))
    how = "1 - reports / reports of the recording's anchor that reported most, over their common span"
    sources = {"rate_low": Source(ids, "least of " + how), "rate_high": Source(ids, "most of " + how),
               "burst_events": Source(ids, "advertisements lost per gap in an anchor's reports (gap / the best "
                                           "anchor's mean interval, rounded, less one)")}
    return missing, sources, {"anchors": len(rates), "rate_mean": round(float(np.mean(finite)), 4)}
