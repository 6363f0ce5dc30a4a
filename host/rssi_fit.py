"""What a recording's RSSI does, against the truth: its statistics, and a profile fitted to them.

Given readings of several links (a transmitter heard by a receiver) with where the moving end
truly was, :func:`rssi_stats` measures what docs/emulator.md's measured RSSI model is made of,
each by a rule that needs no model of it:

- the log-distance fit of all readings (P0 at 1 m, n) and the scatter about it;
- each link's own fit (exponent, and level at the recording's typical distance, the pivot),
  with a standard error from a jackknife over 2 m cells (neighbouring readings share their
  shadowing, so the readings themselves would understate it); the spread of the exponents and
  levels less those errors (a random-effects estimate) is what the links really differ by;
- from the residuals of the links' own fits, over pairs of readings of one link: readings at the
  same place (within ``SAME_PLACE_M``) at least ``SEPARATE_S`` apart share only the shadowing
  (their mean product is its variance; its fall with distance gives the correlation distance);
  at the same place closer in time they also share what changes in time (the excess over the
  shadowing, fitted by sd^2 exp(-dt / time)); the rest of the variance is white;
- readings missed (gaps in each stretch of readings at the link's nominal interval) and how
  long the gaps run;
- for the XPLR-AOA, its second polarisation less the first.

:func:`estimate` makes a profile of one recording's direct estimates; :func:`calibrate`
corrects it by emulating the recording (indirect inference); :func:`pool` makes one
``[rssi.NAME]`` table of several recordings' with each figure's source. For benches and
``radio-fit`` only: a localiser never sees the truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from scipy import optimize
from scipy.spatial import cKDTree

from rfhoming.host.angle_residuals import correlation_time
from rfhoming.protocol.rssi_profile import Exponent, Loss, Offset, Polarisation, Residual, RssiProfile, Shadowing

SAME_PLACE_M = 0.15
"""Readings this close share their place (the shadowing field is smooth over it)."""

SEPARATE_S = 30.0
"""Readings this far apart in time share nothing that changes in time."""

SHADOW_BINS_M = (0.0, 0.15, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
"""Distance bins of the shadowing's correlation."""

TIME_BINS_S = (0.0, 0.6, 1.2, 2.5, 5.0, 10.0, 20.0, SEPARATE_S)
"""Time bins of the same place's covariance."""

CELL_M = 2.0
"""Jackknife cells: wider than the shadowing's correlation distance."""

PAIR_CAP = 2500
"""Readings per link (a fixed random subset beyond it) in the pair statistics: bounds their cost."""

MIN_PAIRS = 200
"""A bin with fewer pairs tells nothing."""


@dataclass(frozen=True)
class Readings:
    """One recording's readings of one kind of radio, with the truth (arrays of equal length)."""

    name: str
    source: str  # the files, for the profile's sources
    link: np.ndarray  # int: which link (transmitter, receiver)
    series: np.ndarray  # int: a stretch of one link's readings with no break but missed ones
    t: np.ndarray  # seconds
    rssi: np.ndarray  # dBm
    distance_m: np.ndarray  # true distance between the ends
    xy: np.ndarray  # (N, 2): where the moving end truly was, metres
    interval_s: float  # a link's nominal time between readings
    second: np.ndarray | None = None  # the XPLR-AOA's second polarisation, dBm


@dataclass(frozen=True)
class RssiStats:
    """What :func:`rssi_stats` measured (dB, metres, seconds; fractions 0..1)."""

    name: str
    source: str
    readings: int
    links: int
    p0_dbm: float  # the pooled log-distance fit, at 1 m
    exponent: float
    scatter_db: float  # std about it
    pivot_m: float  # geometric mean distance
    near_m: float  # 1st and 99th percentiles of the distances
    far_m: float
    link_exponents: tuple[float, ...]
    exponent_sd: float  # std of the links' exponents as fitted
    exponent_mean: float  # mean of the links' exponents
    exponent_true_sd: float  # less their jackknife errors
    offset_sd_db: float  # std of the links' mean residual about the pooled fit
    offset_true_sd_db: float  # std of the links' own levels at the pivot, less their errors
    variance_db2: float  # of the residuals about each link's own fit
    shadowing_sd_db: float
    shadowing_corr: tuple[tuple[float, float, int], ...]  # (distance, correlation, pairs)
    shadowing_distance_m: float  # nan where the recording cannot tell (too few places)
    same_place: tuple[tuple[float, float, int], ...]  # (dt, covariance, pairs)
    residual_sd_db: float
    residual_time_s: float
    white_sd_db: float
    corr_time_s: float  # median over stretches of the lag where the residual's autocorrelation < 0.5
    missing: float  # mean over links
    link_missing: tuple[float, ...]
    burst_readings: float  # mean readings missed in a row
    burst_s: float  # the loss chain's mean burst that gives it
    polarisation_mean_db: float | None
    polarisation_sd_db: float | None
    residuals: np.ndarray = field(repr=False)  # about the pooled fit, for the KS distance

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for k, v in self.__dict__.items():
            if k != "residuals":
                out[k] = _rounded(v)
        return out


def rssi_stats(r: Readings) -> RssiStats:
    """The statistics of one recording (module docstring)."""
    pooled_p0, pooled_n = _line(r.distance_m, r.rssi, 1.0)
    about_pooled = r.rssi - (pooled_p0 - 10 * pooled_n * np.log10(r.distance_m))
    pivot = float(np.exp(np.mean(np.log(r.distance_m))))
    links = np.unique(r.link)
    own = np.empty_like(r.rssi)
    n_fit, n_se, level, level_se, offsets = [], [], [], [], []
    for k in links:
        m = r.link == k
        offsets.append(float(about_pooled[m].mean()))
        p0, n = _line(r.distance_m[m], r.rssi[m], pivot)
        own[m] = r.rssi[m] - (p0 - 10 * n * np.log10(r.distance_m[m] / pivot))
        se = _jackknife(r.distance_m[m], r.rssi[m], r.xy[m], pivot)
        n_fit.append(n)
        level.append(p0)
        n_se.append(se[1])
        level_se.append(se[0])
    exps = np.array(n_fit)
    variance = float(np.mean(own**2))
    shadow_corr, same_place = _pair_moments(r, own)
    c_shadow = same_place_covariance(shadow_corr)
    shadow_distance = correlation_distance([(h, c / c_shadow, n) for h, c, n in shadow_corr]) if c_shadow > 0 else math.nan
    excess = [(dt, c - c_shadow, n) for dt, c, n in same_place]
    residual_var, residual_time = _exponential_fit(excess, variance - c_shadow, r.interval_s)
    white = max(0.0, variance - c_shadow - residual_var)
    times = [correlation_time(r.t[m], own[m]) for s in np.unique(r.series) if (m := r.series == s).sum() >= 10]
    finite = [x for x in times if math.isfinite(x)]
    link_missing, burst = _missing(r)
    missing = float(np.mean(link_missing))
    pol_mean = pol_sd = None
    if r.second is not None:
        diff = r.second - r.rssi
        pol_mean, pol_sd = float(np.mean(diff)), float(np.std(diff))
    return RssiStats(
        r.name, r.source, len(r.rssi), len(links), pooled_p0, pooled_n, float(np.std(about_pooled)), pivot,
        float(np.percentile(r.distance_m, 1)), float(np.percentile(r.distance_m, 99)),
        tuple(float(x) for x in exps), float(np.std(exps, ddof=1)), float(np.mean(exps)),
        _random_effects_sd(exps, np.array(n_se)), float(np.std(offsets, ddof=1)),
        _random_effects_sd(np.array(level), np.array(level_se)), variance,
        math.sqrt(max(c_shadow, 0.0)), tuple((float(h), float(c / variance), int(n)) for h, c, n in shadow_corr),
        shadow_distance, tuple((float(dt), float(c), int(n)) for dt, c, n in same_place),
        math.sqrt(residual_var), residual_time, math.sqrt(white),
        float(np.median(finite)) if finite else math.nan, missing, tuple(link_missing), burst,
        burst_seconds(missing, burst, r.interval_s), pol_mean, pol_sd, about_pooled)


def _line(d: np.ndarray, rssi: np.ndarray, d0: float) -> tuple[float, float]:
    """(level at d0, n) of the least-squares log-distance line."""
    x = -10 * np.log10(d / d0)
    (level, n), *_ = np.linalg.lstsq(np.stack([np.ones_like(x), x], axis=1), rssi, rcond=None)
    return float(level), float(n)


def _jackknife(d: np.ndarray, rssi: np.ndarray, xy: np.ndarray, d0: float) -> tuple[float, float]:
    """Standard errors of (level, n) by deleting one CELL_M cell at a time (inf below 3 cells
    or where the rest holds one distance)."""
    cells = np.floor(xy / CELL_M).astype(np.int64)
    keys = cells[:, 0] * 1_000_003 + cells[:, 1]
    blocks = np.unique(keys)
    if len(blocks) < 3:
        return math.inf, math.inf
    fits = []
    for b in blocks:
        keep = keys != b
        if np.ptp(d[keep]) == 0:
            return math.inf, math.inf
        fits.append(_line(d[keep], rssi[keep], d0))
    f = np.array(fits)
    g = len(blocks)
    var = (g - 1) / g * ((f - f.mean(axis=0)) ** 2).sum(axis=0)
    return float(math.sqrt(var[0])), float(math.sqrt(var[1]))


def _random_effects_sd(values: np.ndarray, se: np.ndarray) -> float:
    """The spread of what the values estimate: their variance less the mean squared error of
    each (links with an infinite error left out; 0 where the errors explain it all)."""
    ok = np.isfinite(se)
    if ok.sum() < 2:
        return math.nan
    return math.sqrt(max(0.0, float(np.var(values[ok], ddof=1) - np.mean(se[ok] ** 2))))


def _pair_moments(r: Readings, own: np.ndarray) -> tuple[list[tuple[float, float, int]], list[tuple[float, float, int]]]:
    """Mean products of one link's residuals over pairs of readings: by distance apart for pairs
    at least SEPARATE_S apart in time, and by time apart for pairs at the same place."""
    rng = np.random.default_rng(0)
    nh, nt = len(SHADOW_BINS_M) - 1, len(TIME_BINS_S) - 1
    h_sum, h_prod, h_n = np.zeros(nh), np.zeros(nh), np.zeros(nh)
    t_sum, t_prod, t_n = np.zeros(nt), np.zeros(nt), np.zeros(nt)
    for k in np.unique(r.link):
        idx = np.flatnonzero(r.link == k)
        if len(idx) > PAIR_CAP:
            idx = np.sort(rng.choice(idx, PAIR_CAP, replace=False))
        pairs = cKDTree(r.xy[idx]).query_pairs(SHADOW_BINS_M[-1], output_type="ndarray")
        if not len(pairs):
            continue
        i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]
        h = np.hypot(*(r.xy[i] - r.xy[j]).T)
        dt = np.abs(r.t[i] - r.t[j])
        prod = own[i] * own[j]
        far = (dt >= SEPARATE_S) & (h < SHADOW_BINS_M[-1])
        hb = np.digitize(h[far], SHADOW_BINS_M) - 1
        h_sum += np.bincount(hb, h[far], nh)
        h_prod += np.bincount(hb, prod[far], nh)
        h_n += np.bincount(hb, None, nh)
        near = (h < SAME_PLACE_M) & (dt < SEPARATE_S) & (dt > 0)
        tb = np.digitize(dt[near], TIME_BINS_S) - 1
        t_sum += np.bincount(tb, dt[near], nt)
        t_prod += np.bincount(tb, prod[near], nt)
        t_n += np.bincount(tb, None, nt)
    shadow = [(float(s / n), float(p / n), int(n)) for s, p, n in zip(h_sum, h_prod, h_n) if n >= MIN_PAIRS]
    same = [(float(s / n), float(p / n), int(n)) for s, p, n in zip(t_sum, t_prod, t_n) if n >= MIN_PAIRS]
    return shadow, same


def same_place_covariance(shadow_corr: Sequence[tuple[float, float, int]]) -> float:
    """The shadowing's variance: the covariance of the nearest bin, if it is the same place."""
    if not shadow_corr or shadow_corr[0][0] >= SAME_PLACE_M:
        return 0.0
    return max(0.0, shadow_corr[0][1])


def correlation_distance(corr: Sequence[tuple[float, float, int]]) -> float:
    """The length L of exp(-(h / L)^2) that fits the correlation by distance best (least squares,
    each bin weighted by the square root of its pairs); nan with fewer than three bins."""
    if len(corr) < 3:
        return math.nan
    h, c, n = (np.array(v, float) for v in zip(*corr))
    w = np.sqrt(n)

    def cost(length: float) -> float:
        return float(np.sum(w * (c - np.exp(-((h / length) ** 2))) ** 2))

    best = optimize.minimize_scalar(cost, bounds=(0.05, 20.0), method="bounded")
    return float(best.x)


def _exponential_fit(excess: Sequence[tuple[float, float, int]], ceiling: float, interval_s: float) -> tuple[float, float]:
    """(variance, time) of a exp(-dt / time) fitted to the same place's covariance above the
    shadowing (variance at most ``ceiling``, time at least the readings' interval: what changes
    faster is white to them); (0, nan) where it shows none."""
    if len(excess) < 2 or ceiling <= 0:
        return 0.0, math.nan
    dt, c, n = (np.array(v, float) for v in zip(*excess))
    w = np.sqrt(n)

    def cost(p: np.ndarray) -> float:
        return float(np.sum(w * (c - p[0] * np.exp(-dt / p[1])) ** 2))

    start = np.array([min(max(c[0], 0.0), ceiling), 2.0])
    start[1] = max(start[1], interval_s)
    best = optimize.minimize(cost, start, bounds=[(0.0, ceiling), (interval_s, 600.0)], method="L-BFGS-B")
    variance, time = (float(v) for v in best.x)
    return (variance, time) if variance > 0.01 * ceiling else (0.0, math.nan)


def _missing(r: Readings) -> tuple[list[float], float]:
    """Each link's fraction of readings missed (gaps of each stretch at the nominal interval)
    and the mean number missed in a row, over all links."""
    fractions: list[float] = []
    bursts: list[float] = []
    for k in np.unique(r.link):
        got = missed = 0
        for s in np.unique(r.series[r.link == k]):
            t = np.sort(r.t[(r.link == k) & (r.series == s)])
            gaps = np.maximum(np.round(np.diff(t) / r.interval_s) - 1, 0)
            got += len(t)
            missed += int(gaps.sum())
            bursts.extend(gaps[gaps > 0])
        fractions.append(missed / (got + missed))
    return fractions, float(np.mean(bursts)) if bursts else 0.0


def burst_seconds(fraction: float, burst_readings: float, interval_s: float) -> float:
    """The mean burst (s) of the two-state chain in time (protocol/rssi_profile.py, ``Loss``)
    whose sampling every ``interval_s`` misses ``fraction`` of the readings in runs of
    ``burst_readings`` on average. Sampled, the chain stays lost with probability
    q = p + (1 - p) exp(-interval / tau), tau = burst (1 - p), and a run lasts 1 / (1 - q)."""
    if fraction <= 0 or burst_readings <= 0:
        return math.nan
    stay = 1.0 - 1.0 / max(burst_readings, 1.0)
    ratio = (stay - fraction) / (1.0 - fraction)
    tau = interval_s / math.log(100.0) if ratio <= 0.01 else -interval_s / math.log(ratio)
    return tau / (1.0 - fraction)


HOW = {
    "exponent": "each link's own log-distance fit: the mean exponent, and the spread across links that, the "
                "recording emulated on its own links and places, gives the fits' spread; low/high: the extreme "
                "links; pivot: the geometric mean distance; near/far: the 1st and 99th percentiles of the distances "
                "(the widest over the recordings)",
    "offset": "each link's mean residual about the pooled log-distance fit: the spread across links that, "
              "emulated, gives theirs",
    "shadowing": f"pairs of a link's readings at one place (< {SAME_PLACE_M:g} m) >= {SEPARATE_S:g} s apart: the sd "
                 "such that the recording emulated gives their covariance; L: exp(-(h/L)^2) fitted to their "
                 "correlation by distance apart",
    "residual": f"pairs at one place < {SEPARATE_S:g} s apart: their covariance above the shadowing, sd^2 "
                "exp(-dt/time) (time at least the readings' interval); white: the rest of the variance about each "
                "link's own fit",
    "loss": "gaps in each link's readings at its nominal interval (links' fractions as a uniform of the same mean "
            "and spread) and their runs, as a chain in time",
    "polarisation": "the second polarisation less the first, on every event",
}
"""How each group's figures come from a recording (its source text)."""


def estimate(s: RssiStats, title: str = "") -> RssiProfile:
    """Every group's direct estimate from one recording's statistics: the start of
    :func:`calibrate`. Groups it cannot tell keep what it measured nearest (its sources say so)."""
    src = s.source
    exponent = Exponent(mean=_clip(s.exponent_mean, -2, 8), sd=_clip(_finite(s.exponent_true_sd, 0.0), 0, 5),
                        low=_clip(min(s.link_exponents), -2, 8), high=_clip(max(s.link_exponents), -2, 8),
                        pivot_m=s.pivot_m, near_m=s.near_m, far_m=s.far_m, source=src)
    offset = Offset(sd_db=_clip(_finite(s.offset_true_sd_db, s.offset_sd_db), 0, 40), source=src)
    shadowing = Shadowing(sd_db=_clip(s.shadowing_sd_db, 0, 40), distance_m=_clip(_finite(s.shadowing_distance_m, 1.0), 0.05, 1000),
                          source=src)
    residual = Residual(sd_db=_clip(s.residual_sd_db, 0, 40), time_s=_clip(_finite(s.residual_time_s, 1.0), 0.01, 3600),
                        white_sd_db=_clip(s.white_sd_db, 0, 40), source=src)
    spread = math.sqrt(3) * float(np.std(s.link_missing))
    loss = Loss(fraction_low=_clip(s.missing - spread, 0, 0.99), fraction_high=_clip(s.missing + spread, 0, 0.99),
                burst_s=_clip(_finite(s.burst_s, 0.01), 0.001, 3600), source=src)
    polarisation = None
    if s.polarisation_mean_db is not None and s.polarisation_sd_db is not None:
        polarisation = Polarisation(mean_db=_clip(s.polarisation_mean_db, -40, 40), sd_db=_clip(s.polarisation_sd_db, 0, 40),
                                    source=src)
    return RssiProfile(exponent, offset, shadowing, residual, loss, polarisation, title)


def calibrate(start: RssiProfile, real: RssiStats, uses: Sequence[str], simulate: Callable[[RssiProfile, int], RssiStats],
              seeds: int = 3, rounds: int = 3) -> RssiProfile:
    """Indirect inference: the figures whose direct estimates are biased adjusted, ``rounds``
    times, until the recording emulated with the profile (``simulate(profile, seed)``: the same
    links, places and times through the measured channel, statistics taken as of the real)
    gives the real statistics, median over ``seeds`` (the same seeds every round). Biased are
    the shadowing's sd (a link's own fit takes up some of its field) and the spreads of the
    exponents and offsets (the field and the noise spread a few links' fits too): the emulation
    makes the same mistakes, so matching it corrects them. The residual's and the losses'
    estimates are unbiased (tests/test_measured_rssi.py) and far noisier than any bias, so they
    stay as measured. Only the groups in ``uses`` move."""
    p = start
    for _ in range(rounds):
        p = _adjusted(p, real, uses, _median_of([simulate(p, seed) for seed in range(seeds)]))
    return p


def _median_of(runs: Sequence[RssiStats]) -> Callable[[str], float]:
    """A statistic's median over emulations (nan where none has it)."""
    def emulated(name: str) -> float:
        values = [float(v) for r in runs if (v := getattr(r, name)) is not None and math.isfinite(v)]
        return float(np.median(values)) if values else math.nan
    return emulated


def _adjusted(p: RssiProfile, real: RssiStats, uses: Sequence[str], emulated: Callable[[str], float]) -> RssiProfile:
    """One round of :func:`calibrate`: spreads a bias adds to move in quadrature, the rest in proportion."""
    def quad(x: float, stat: str) -> float:
        return math.sqrt(max(0.0, x * x + getattr(real, stat) ** 2 - emulated(stat) ** 2)) if _ok(real, stat, emulated) else x

    def ratio(x: float, stat: str) -> float:
        return x * getattr(real, stat) / emulated(stat) if _ok(real, stat, emulated) and emulated(stat) > 0 else x

    groups: dict[str, Any] = {}
    if "exponent" in uses:
        groups["exponent"] = replace(p.exponent, sd=_clip(quad(p.exponent.sd, "exponent_sd"), 0, 5))
    if "offset" in uses:
        groups["offset"] = replace(p.offset, sd_db=_clip(quad(p.offset.sd_db, "offset_sd_db"), 0, 40))
    if "shadowing" in uses:
        # the distance stays the direct estimate: a longer one to make up for what each link's own fit takes
        # of the field would spread the links' exponents beyond what the recordings show
        groups["shadowing"] = replace(p.shadowing, sd_db=_clip(ratio(p.shadowing.sd_db, "shadowing_sd_db"), 0, 40))
    return replace(p, **groups)


def _ok(real: RssiStats, stat: str, emulated: Callable[[str], float]) -> bool:
    x = getattr(real, stat)
    return x is not None and math.isfinite(x) and math.isfinite(emulated(stat))


def pool(fitted: Mapping[str, tuple[RssiProfile, Sequence[str]]], title: str = "") -> RssiProfile:
    """One radio's table from recordings' own profiles (name -> (profile, the groups it
    measures)): each figure the mean over the recordings that measure its group; each group's
    source says how, and each recording's figures."""
    def chosen(group: str) -> list[tuple[str, Any]]:
        return [(name, getattr(p, group)) for name, (p, uses) in fitted.items() if group in uses]

    out: dict[str, Any] = {}
    cls: Any
    for group, cls in (("exponent", Exponent), ("offset", Offset), ("shadowing", Shadowing), ("residual", Residual),
                       ("loss", Loss), ("polarisation", Polarisation)):
        each = chosen(group)
        if not each:
            continue
        figures = [f.name for f in fields(cls) if f.name not in ("source", "assumed")]
        values = {f: float(np.mean([getattr(g, f) for _, g in each])) for f in figures}
        if group == "exponent":
            values.update(low=min(g.low for _, g in each), high=max(g.high for _, g in each),
                          near_m=min(g.near_m for _, g in each), far_m=max(g.far_m for _, g in each))
        listed = "; ".join(f"{g.source.split(':')[0]}: " + ", ".join(f"{f} {getattr(g, f):.3g}" for f in figures)
                           for _, g in each)
        how = f"{HOW[group]}. {listed}" + ("; the mean of these" if len(each) > 1 else "") + " (bench/fit_rssi.py)"
        out[group] = cls(**{f: round(v, 3) for f, v in values.items()}, source=how)
    return RssiProfile(**out, title=title)


def _clip(x: float, low: float, high: float) -> float:
    return float(min(high, max(low, x)))


def _finite(x: float, otherwise: float) -> float:
    return x if math.isfinite(x) else otherwise


def _rounded(v: object) -> object:
    if isinstance(v, float):
        return round(v, 4) if math.isfinite(v) else None
    if isinstance(v, tuple):
        return [_rounded(x) for x in v]
    return v
