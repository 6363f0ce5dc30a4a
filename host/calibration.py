"""Per-anchor calibration from tags at known points: a yaw offset and azimuth/elevation scale and
bias, fitted so that the corrected angles point at the points.

Model (reported angles, board sign): az = s_az * az_true + b_az, el = s_el * el_true + b_el,
where (az_true, el_true) are the board angles of the point seen from the anchor's position with
its yaw turned by the offset. For a level board a yaw offset and an azimuth bias are the same
thing; a weak prior (``PRIOR_DEG``) on both splits it evenly rather than leaving the fit
singular. Gauss-Newton on the medians of each (anchor, point) pair; at least three points that
an anchor sees, not all on one line through it.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from rfhoming.host.estimation.anchors3d import board_angles, rotation
from rfhoming.host.site import Anchor, Calibration, Site
from rfhoming.protocol.errors import Error
from rfhoming.protocol.uconnect import AngleEvent

PRIOR_DEG = 5.0
"""Prior sigma on the yaw offset and the azimuth bias (degrees); scales' prior sigma is 0.3."""

MIN_EVENTS = 10
"""Angle events an (anchor, point) pair needs to count."""


class CalibrationError(Error, ValueError):
    """Not enough data to calibrate an anchor; the message says what to record."""


@dataclass(frozen=True)
class AnchorFit:
    anchor: str
    calibration: Calibration
    points: int
    rms_before_deg: float
    rms_after_deg: float


def _predict(anchor: Anchor, theta: np.ndarray, points: np.ndarray) -> np.ndarray:
    yaw_off, s_az, b_az, s_el, b_el = theta
    rot = rotation(anchor.yaw_deg + yaw_off, anchor.pitch_deg, anchor.roll_deg)
    out = []
    for p in points:
        az, el = board_angles(rot.T @ (p - np.asarray(anchor.position)))
        out.append((s_az * az + b_az, s_el * el + b_el))
    return np.array(out)


def _residual(anchor: Anchor, theta: np.ndarray, points: np.ndarray, measured: np.ndarray) -> np.ndarray:
    prior = np.array([theta[0] / PRIOR_DEG, theta[2] / PRIOR_DEG, (theta[1] - 1) / 0.3, (theta[3] - 1) / 0.3,
                      theta[4] / (3 * PRIOR_DEG)])
    return np.concatenate([(_predict(anchor, theta, points) - measured).ravel(), prior])


def fit_anchor(anchor: Anchor, points: np.ndarray, measured: np.ndarray) -> tuple[Calibration, float, float]:
    """(calibration, rms angle error before, after) for one anchor's (point, median angles)."""
    theta = np.array([0.0, 1.0, 0.0, 1.0, 0.0])
    before = float(np.sqrt(np.mean((_predict(anchor, theta, points) - measured) ** 2)))
    for _ in range(10):
        r = _residual(anchor, theta, points, measured)
        jac = np.empty((len(r), 5))
        for k in range(5):
            step = np.zeros(5)
            step[k] = 1e-4
            jac[:, k] = (_residual(anchor, theta + step, points, measured) - r) / 1e-4
        delta = np.linalg.lstsq(jac, -r, rcond=None)[0]
        theta = theta + delta
        if np.abs(delta).max() < 1e-5:
            break
    after = float(np.sqrt(np.mean((_predict(anchor, theta, points) - measured) ** 2)))
    cal = Calibration(float(theta[0]), float(theta[1]), float(theta[2]), float(theta[3]), float(theta[4]))
    return cal, before, after


def calibrate(site: Site, events: Iterable[tuple[float, AngleEvent]], points: dict[str, tuple[float, float, float]]
              ) -> list[AnchorFit]:
    """Fit every anchor of ``site`` from angle events of tags at known ``points`` (tag -> x, y, z);
    CalibrationError names an anchor that saw too few points."""
    samples: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for _, event in events:
        if event.instance_id in points:
            samples.setdefault((event.anchor_id, event.instance_id), []).append((event.azimuth, event.elevation))
    fits = []
    for anchor in site.anchors:
        seen = [(tag, v) for (a, tag), v in sorted(samples.items()) if a == anchor.id and len(v) >= MIN_EVENTS]
        if len(seen) < 3:
            raise CalibrationError(f"anchor {anchor.name} ({anchor.id}) saw {len(seen)} known point(s) with "
                                   f"{MIN_EVENTS}+ angles each; it needs 3 or more: record longer or add points it sees")
        pts = np.array([points[tag] for tag, _ in seen], float)
        measured = np.array([(statistics.median(a for a, _ in v), statistics.median(e for _, e in v)) for _, v in seen])
        cal, before, after = fit_anchor(replace(anchor, calibration=Calibration()), pts, measured)
        fits.append(AnchorFit(anchor.name, cal, len(seen), before, after))
    return fits
