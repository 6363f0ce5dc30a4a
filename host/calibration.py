"""Per-anchor calibration from tags at known points: a yaw offset and azimuth/elevation scale and
bias, fitted so that the corrected angles point at the points -- only those the points determine.

Model (reported angles, board sign): az = s_az * az_true + b_az, el = s_el * el_true + b_el,
where (az_true, el_true) are the board angles (in the anchor's angle model) of the point seen
from the anchor's position with its yaw turned by the offset. What is fitted, and why not:

- the azimuth bias always; the azimuth scale when the points span ``MIN_AZ_SPAN_DEG`` of
  azimuth seen from the anchor; the yaw offset only when it is not the azimuth bias by another
  name (for a board near level the two move every point's azimuth alike: correlation above
  ``SAME_CORRELATION``);
- elevation only when the points are at different heights (``MIN_HEIGHT_SPREAD_M``): with every
  point at one height the elevation scale and bias trade against the ranges and the pitch, and a
  fit runs anywhere (on a real recording: el_scale -3.29, which the site file refuses). ``azimuth_only`` holds elevation at its defaults as well.

The fit is robust (soft-L1 on 2-degree residuals: a reflected point does not drag it) and held
inside the site file's limits (``site.CALIBRATION_LIMITS``); a parameter that ends on a limit
is refused with the reason, since the points then do not fit the anchor's nominal pose. Each
anchor is fitted in both angle models and the one with the smaller residual over all anchors
is chosen (or the one asked for).

Points: a tag that stays at one point all recording, or one tag carried from point to point,
with a time window per point or windows found from the recording (:func:`find_dwells`).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import cast

import numpy as np
from scipy.optimize import least_squares

from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.anchors3d import ANGLE_MODELS, board_angles_many, rotation
from rfhoming.host.site import CALIBRATION_LIMITS, Anchor, Calibration, Site
from rfhoming.protocol.errors import Error

MIN_EVENTS = 10
"""Angle events an (anchor, point) pair needs to count."""

MIN_AZ_SPAN_DEG = 20.0
"""Azimuth span of the points (seen from the anchor) that determines the azimuth scale."""

MIN_HEIGHT_SPREAD_M = 0.3
"""Height spread of the points that determines elevation at all."""

SAME_CORRELATION = 0.95
"""Yaw offset and azimuth bias this correlated are one parameter: the bias is fitted."""

ROBUST_DEG = 2.0
"""Soft-L1 scale of the residuals (degrees)."""

PARAMS = ("yaw_offset_deg", "az_scale", "az_bias_deg", "el_scale", "el_bias_deg")
DEFAULT = np.array([0.0, 1.0, 0.0, 1.0, 0.0])


class CalibrationError(Error, ValueError):
    """Not enough data to calibrate an anchor, or a fit the site file would refuse; the
    message says what to record or check."""


@dataclass(frozen=True)
class Point:
    """A known position of ``tag`` (x, y, z metres), during [start_s, end_s] seconds from the
    recording's first angle event (None: the whole recording)."""

    tag: str
    position: tuple[float, float, float]
    start_s: float | None = None
    end_s: float | None = None


@dataclass(frozen=True)
class AnchorFit:
    anchor: str
    calibration: Calibration
    points: int
    rms_before_deg: float
    rms_after_deg: float
    angle_model: str = "spherical"
    sigma: dict[str, float] = field(default_factory=dict)  # fitted parameter -> its standard deviation
    held: dict[str, str] = field(default_factory=dict)  # parameter not fitted -> why
    rms_by_model: dict[str, float] = field(default_factory=dict)


def _predict(anchor: Anchor, theta: np.ndarray, points: np.ndarray, model: str, compression: float = 0.0
             ) -> np.ndarray:
    """The reported angles of ``points``: the boards' shared |azimuth| ``compression`` (the
    site's az_compression, which locate models) first, then this anchor's scale and bias."""
    yaw_off, s_az, b_az, s_el, b_el = theta
    rot = rotation(anchor.yaw_deg + yaw_off, anchor.pitch_deg, anchor.roll_deg)
    ang = board_angles_many((points - np.asarray(anchor.position)) @ rot, model)
    az = ang[:, 0] * (1 - compression * (ang[:, 0] / 90) ** 2)
    return np.stack([s_az * az + b_az, s_el * ang[:, 1] + b_el], axis=1)


def _jacobian(f: Callable[[np.ndarray], np.ndarray], theta: np.ndarray, free: list[int]) -> np.ndarray:
    r0 = f(theta)
    cols = []
    for k in free:
        step = np.zeros(5)
        step[k] = 1e-4
        cols.append((f(theta + step) - r0) / 1e-4)
    return np.stack(cols, axis=1)


def fit_anchor(anchor: Anchor, points: np.ndarray, measured: np.ndarray, *, model: str = "spherical",
               azimuth_only: bool = False, compression: float = 0.0) -> AnchorFit:
    """One anchor's fit from its (point, median angles) pairs in one angle model, on top of
    the boards' shared |azimuth| ``compression``."""
    truth = _predict(anchor, DEFAULT, points, model, compression)
    held: dict[str, str] = {}
    free = [2]
    if np.ptp(truth[:, 0]) >= MIN_AZ_SPAN_DEG:
        free.append(1)
    else:
        held["az_scale"] = (f"the points span {np.ptp(truth[:, 0]):.0f} deg of azimuth from this anchor; "
                            f"a scale needs {MIN_AZ_SPAN_DEG:g}+")
    spread = float(np.ptp(points[:, 2]))
    if azimuth_only:
        held["el_scale"] = held["el_bias_deg"] = "azimuth-only calibration"
    elif spread < MIN_HEIGHT_SPREAD_M:
        why = (f"every point at one height (spread {spread:.2f} m < {MIN_HEIGHT_SPREAD_M:g} m): elevation "
               "scale and bias trade against range and pitch")
        held["el_scale"] = held["el_bias_deg"] = why
    else:
        free.append(4)
        if np.ptp(truth[:, 1]) >= MIN_AZ_SPAN_DEG / 2:
            free.append(3)
        else:
            held["el_scale"] = (f"the points span {np.ptp(truth[:, 1]):.0f} deg of elevation; "
                                f"a scale needs {MIN_AZ_SPAN_DEG / 2:g}+")
    weights = np.ones(2)
    if 4 not in free:
        weights[1] = 0.0  # elevation held: its residuals say nothing about the azimuth parameters

    def resid(theta: np.ndarray) -> np.ndarray:
        return np.asarray((_predict(anchor, theta, points, model, compression) - measured) * weights, float).ravel()

    jac = _jacobian(resid, DEFAULT, [0, 2])
    corr = abs(float(jac[:, 0] @ jac[:, 1]) / (np.linalg.norm(jac[:, 0]) * np.linalg.norm(jac[:, 1]) + 1e-12))
    if corr > SAME_CORRELATION:
        held["yaw_offset_deg"] = (f"moves every point's azimuth like the bias (correlation {corr:.2f}): "
                                  "fitted as the bias")
    else:
        free.append(0)
    free.sort()
    lo = np.array([CALIBRATION_LIMITS[p][0] for p in PARAMS])
    hi = np.array([CALIBRATION_LIMITS[p][1] for p in PARAMS])

    def sub(x: np.ndarray) -> np.ndarray:
        theta = DEFAULT.copy()
        theta[free] = x
        return theta

    def fun(x: np.ndarray) -> np.ndarray:
        return resid(sub(x))

    solution = least_squares(fun, DEFAULT[free], bounds=(lo[free], hi[free]),
                             loss="soft_l1", f_scale=ROBUST_DEG)
    theta = sub(solution.x)
    for k in free:
        if min(theta[k] - lo[k], hi[k] - theta[k]) < 1e-3 * (hi[k] - lo[k]):
            raise CalibrationError(
                f"anchor {anchor.name}: {PARAMS[k]} ran to the site file's limit {lo[k]:g}..{hi[k]:g}: its "
                f"angles do not fit the points from its nominal pose; check its position, yaw_deg and "
                f"pitch_deg, and the points (or calibrate --azimuth-only)")
    r = resid(theta)
    n_used = int(weights.sum()) * len(points)
    rms_after = math.sqrt(float(r @ r) / n_used)
    r0 = resid(DEFAULT)
    rms_before = math.sqrt(float(r0 @ r0) / n_used)
    j = _jacobian(resid, theta, free)
    dof = max(1, n_used - len(free))
    try:
        cov = np.linalg.inv(j.T @ j) * max(float(r @ r) / dof, 0.25)
        sig = {PARAMS[k]: float(math.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(free)}
    except np.linalg.LinAlgError:
        sig = {PARAMS[k]: math.inf for k in free}
    cal = Calibration(*(float(v) for v in theta))
    return AnchorFit(anchor.name, cal, len(points), rms_before, rms_after, model, sig, held)


def find_dwells(events: Sequence[Bearing], tag: str, *, min_s: float = 5.0,
                still_deg: float = 2.0, t0: float | None = None) -> list[tuple[float, float]]:
    """The spans (seconds from ``t0``, default the first event) in which ``tag`` stood still:
    runs of 1 s bins in which no anchor's median azimuth moved more than ``still_deg`` from the
    bin before, ``min_s`` or longer, one bin trimmed at each end (the tag being set down)."""
    if not events:
        return []
    t0 = events[0].t if t0 is None else t0
    bins: dict[int, dict[str, list[float]]] = {}
    for r in events:
        if r.tag == tag:
            bins.setdefault(int((r.t - t0) // 1.0), {}).setdefault(r.anchor, []).append(r.clockwise_deg)
    medians = {k: {a: statistics.median(v) for a, v in b.items() if len(v) >= 3} for k, b in bins.items()}
    still = []
    for k in sorted(medians):
        prev = medians.get(k - 1)
        common = set(medians[k]) & set(prev or {})
        still.append((k, prev is not None and bool(prev) and len(common) >= 2
                      and all(abs(medians[k][a] - prev[a]) <= still_deg for a in common)))
    runs: list[list[int]] = []  # [first bin, last bin] of each still run
    for k, ok in still:
        if ok and runs and runs[-1][1] == k - 1:
            runs[-1][1] = k
        elif ok:
            runs.append([k - 1, k])  # the bin before matched this one: part of the dwell
    return [(float(a + 1), float(b)) for a, b in runs if b - a - 1 >= min_s]


def assign_dwells(events: Sequence[Bearing], points: list[Point]) -> tuple[list[Point], list[str]]:
    """Points without a window get the dwells found in the recording, in order, per tag;
    (points with windows, one report line per tag); CalibrationError when the counts differ."""
    out, report = [], []
    t0 = events[0].t if events else 0.0
    by_tag: dict[str, list[Point]] = {}
    for p in points:
        by_tag.setdefault(p.tag, []).append(p)
    for tag, pts in by_tag.items():
        if all(p.start_s is not None for p in pts):
            out += pts
            continue
        if len(pts) == 1 and pts[0].start_s is None:
            out += pts  # one point: the whole recording
            continue
        dwells = find_dwells(events, tag, t0=t0)
        spans = ", ".join(f"{a:.0f}-{b:.0f} s" for a, b in dwells) or "none"
        if len(dwells) != len(pts):
            raise CalibrationError(f"tag {tag}: {len(pts)} points listed without from_s/to_s, but the recording "
                                   f"shows {len(dwells)} dwells of 5 s or more ({spans}); give each point "
                                   "from_s and to_s (seconds from the first angle event)")
        out += [replace(p, start_s=a, end_s=b) for p, (a, b) in zip(pts, dwells)]
        report.append(f"tag {tag}: {len(dwells)} dwells found ({spans}), taken as its points in the listed order")
    return out, report


def _samples(events: list[Bearing], points: list[Point]) -> dict[tuple[str, int], list[tuple[float, float]]]:
    """(anchor id, point index) -> the (azimuth, elevation) of every event of the point's tag
    within its time window (seconds from the first event)."""
    t0 = events[0].t if events else 0.0
    samples: dict[tuple[str, int], list[tuple[float, float]]] = {}
    by_tag: dict[str, list[int]] = {}
    for i, p in enumerate(points):
        by_tag.setdefault(p.tag, []).append(i)
    for r in events:
        for i in by_tag.get(r.tag, ()):
            p = points[i]
            if p.start_s is None or p.end_s is None or p.start_s <= r.t - t0 <= p.end_s:
                samples.setdefault((r.anchor, i), []).append((r.clockwise_deg, r.elevation_deg or 0.0))
    return samples


def _fit_one(anchor: Anchor, samples: dict[tuple[str, int], list[tuple[float, float]]], points: list[Point], model: str,
             azimuth_only: bool, compression: float) -> AnchorFit:
    """One anchor's fit in one angle model, from the median angles of each point it saw."""
    seen = [(i, v) for (a, i), v in sorted(samples.items()) if a == anchor.id and len(v) >= MIN_EVENTS]
    if len(seen) < 3:
        raise CalibrationError(
            f"anchor {anchor.name} ({anchor.id}) saw {len(seen)} known point(s) with {MIN_EVENTS}+ "
            "angles each; it needs 3 or more: record longer or add points it sees")
    pts = np.array([points[i].position for i, _ in seen], float)
    measured = np.array([(statistics.median(a for a, _ in v), statistics.median(e for _, e in v))
                         for _, v in seen])
    return fit_anchor(replace(anchor, calibration=Calibration()), pts, measured, model=model,
                      azimuth_only=azimuth_only, compression=compression)


def calibrate(site: Site, events: Iterable[Bearing],
              points: dict[str, tuple[float, float, float]] | list[Point], *, azimuth_only: bool = False,
              angle_model: str = "auto") -> list[AnchorFit]:
    """Fit every anchor of ``site`` from angle events of tags at known ``points`` (tag -> x, y,
    z, or :class:`Point` s with time windows); ``angle_model`` "auto" picks the model with the
    smaller residual over all anchors. CalibrationError names an anchor that saw too few points
    or whose fit would leave the site file's limits."""
    events = list(events)
    if isinstance(points, dict):
        points = [Point(tag, cast(tuple[float, float, float], tuple(map(float, p)))) for tag, p in points.items()]
    samples = _samples(events, points)
    models = ANGLE_MODELS if angle_model == "auto" else (angle_model,)
    per_model: dict[str, list[AnchorFit]] = {}
    errors: dict[str, CalibrationError] = {}
    for model in models:
        try:
            per_model[model] = [_fit_one(anchor, samples, points, model, azimuth_only, site.az_compression)
                                for anchor in site.anchors]
        except CalibrationError as exc:
            errors[model] = exc
    if not per_model:
        raise next(iter(errors.values()))
    total = {m: math.sqrt(sum(f.rms_after_deg**2 for f in fits) / len(fits)) for m, fits in per_model.items()}
    best = min(total, key=total.__getitem__)
    return [replace(f, rms_by_model={m: round(total[m], 3) for m in total}) for f in per_model[best]]
