"""Tag positions from N fixed anchors' angle streams: merge, window, fix, track.

:class:`Locator` is fed bearing readings (host/bearing.py) from every anchor in any interleaving;
it sorts them by host arrival time (holding each for ``reorder_s``: serial reads of several
ports are stamped in arrival order but may reach us slightly out of it), keeps each
(tag, anchor) pair's angles of the last ``window_s`` seconds, and at its own rate (ticks at
multiples of 1/rate_hz of host time) fixes every tag from the anchors still fresh (heard
within ``stale_s``): each anchor's median corrected angles become a world ray; the rays give a
robust 3-D (or known-height) fix. From a first fix on, the default tracker (``tracker="angles"``,
estimation/angle_tracker.py) takes every angle pair as it arrives with each anchor's slow error
as a state and heavy-tailed reports; the older ones are a constant-velocity filter on the fixes
(``tracker="cv"``) and a bearing EKF without error states (``tracker="ekf"``). Output depends only on
the events and their stamps, so a live run and a replay of its capture print the same lines.
Board timestamps (each board's uptime) are not used.
"""

from __future__ import annotations

import heapq
import math
import statistics
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.anchors3d import LOSSES, Degenerate, Fix, Ray, angle_sigma_deg, locate, make_ray
from rfhoming.host.estimation.angle_tracker import AngleNoise, AngleTracker, TrackerBank
from rfhoming.host.estimation.tracking import BearingEkf, ConstantVelocity, rts_smooth
from rfhoming.host.site import Anchor, Calibration, Site, uncompress

TRACKERS = ("angles", "cv", "ekf")
"""angles (default): every angle pair updates position, velocity and each anchor's slow error
(heavy-tailed reports; made for real boards, docs/estimation.md); cv: a constant-velocity filter
on the fixes (cheapest); ekf: the same state updated by every angle pair, no error states."""

ACCEL_PSD = {"angles": 0.05, "cv": 1.0, "ekf": 1.0}
"""Each tracker's default white acceleration (m^2/s^3): the angles tracker's chosen by
cross-validation on real walks (docs/estimation.md), the others' for walking."""

AGILE_ACCEL_PSD = 1.0
"""The angles tracker runs its smooth model (``accel_psd``) beside an agile one of this white
acceleration and mixes them by how well each foresees the reports (angle_tracker.TrackerBank):
the real walks' steady walker wants the smooth model, a turn, a start or a faster walker (the
emulator's walk at 1.2 m/s) the agile one."""

MAX_PENDING = 100_000
"""Events held for reordering at most (then the oldest are processed early, counted)."""

SYSTEMATIC = 0.6
"""The part of an angle's error (a fraction of sigma_deg) that a median does not average away:
bias, mounting, multipath (the kit scenario's residual after calibration is of this size)."""

FORGET_S = 60.0
"""A (tag, anchor) pair silent this long is forgotten, and a tag with no pair left."""

MAX_PER_PAIR = 2000
"""Angles kept per (tag, anchor) at most, whatever the window (a bound, not a setting)."""


@dataclass(frozen=True)
class Position:
    t: float
    tag: str
    point: np.ndarray  # (3,) metres
    covariance: np.ndarray  # (3, 3) m^2
    anchors: tuple[str, ...]  # anchor names the fix rests on
    rejected: tuple[str, ...]
    tracked: bool
    quality: float | None = None  # the fix's chi-square per degree of freedom (None: no fix this tick)
    smoothed: bool = False  # True: from the RTS smoother over a whole recording (not causal)
    t_fix: float | None = None  # a raw fix: the mean time of the angles it rests on

    def as_dict(self) -> dict[str, Any]:
        out = {"t": round(self.t, 6), "tag": self.tag, "x": round(float(self.point[0]), 3),
               "y": round(float(self.point[1]), 3), "z": round(float(self.point[2]), 3),
               "cov": [[round(float(v), 5) for v in row] for row in self.covariance],
               "anchors": list(self.anchors), "rejected": list(self.rejected)}
        if self.quality is not None:  # named as on the site bus (protocol/sitebus.py)
            out["chi2_per_dof"] = round(self.quality, 3)
        if self.smoothed:
            out["smoothed"] = True
        return out


def _chi2_per_dof(fix: Fix, height: float | None, height_sigma: float | None) -> float:
    """The rays' chi-square about the fix per degree of freedom: two angles a ray, less the three
    coordinates (two when the height is a constraint), as BatchLocator's."""
    fixed = height is not None and height_sigma is None
    return fix.chi2 / max(1, 2 * len(fix.used) - (2 if fixed else 3))


class Locator:
    def __init__(self, site: Site, *, track: bool = True, tracker: str = "angles", accel_psd: float | None = None,
                 reorder_s: float = 0.2, calibrated: bool = True, loss: str = "huber",
                 height_sigma: float | None = None, noise: AngleNoise = AngleNoise()) -> None:
        """``loss``: the fix's robust loss (anchors3d.LOSSES); ``height_sigma``: a known tag
        height is a prior of this sigma (m) rather than a constraint (None); ``accel_psd``: the
        tracker's white acceleration (None: its default, ACCEL_PSD); ``noise``: the angles
        tracker's report model."""
        if tracker not in TRACKERS:
            raise ValueError(f"tracker must be one of {', '.join(TRACKERS)}")
        if loss not in LOSSES:
            raise ValueError(f"loss must be one of {', '.join(LOSSES)}")
        self.loss = loss
        self.height_sigma = height_sigma
        self.site = site
        self.anchors = site.anchor_by_id()
        self.rotations = {a.id: a.rotation() if calibrated else _uncalibrated(a).rotation() for a in site.anchors}
        self._origins = {a.id: np.array(a.position) for a in site.anchors}
        self.calibrated = calibrated
        self.wanted = {t.id for t in site.tags}
        self.track = track
        self.tracker = tracker
        self.accel_psd = ACCEL_PSD[tracker] if accel_psd is None else accel_psd
        self.noise = noise
        self._index = {a.id: k for k, a in enumerate(site.anchors)}
        self.reorder_s = reorder_s
        self.period = 1.0 / site.rate_hz
        self._pending: list[tuple[float, str, str, float, float]] = []
        self._latest = -math.inf
        self._next_tick: float | None = None
        self._windows: dict[tuple[str, str], deque[tuple[float, float, float]]] = {}
        self._trackers: dict[str, ConstantVelocity] = {}
        self._ekfs: dict[str, BearingEkf] = {}
        self._angle_trackers: dict[str, AngleTracker | TrackerBank] = {}
        self.log_density = 0.0
        """The sum of the angles tracker's reports' predictive log densities (in the reported
        angles' units), over ``reports_scored`` reports: its mean says how well a site (its
        calibration) lets the tracker foresee the reports."""
        self.reports_scored = 0
        self._lost: dict[str, float] = {}  # anchor id -> host time its driver last reported it gone
        self.counters = {"events": 0, "unknown_anchor": 0, "other_tag": 0, "late": 0, "overflow": 0,
                         "fixes": 0, "no_fix": 0, "rejected_anchor": 0, "gated": 0, "restarts": 0,
                         "disconnects": 0, "downweighted": 0, "outside_fov": 0}

    # -- input -------------------------------------------------------------------------
    def feed(self, reading: Bearing) -> list[Position]:
        """One reading (stamped with its host arrival time); the positions now due."""
        t = reading.t
        anchor = self.anchors.get(reading.anchor)
        if anchor is None:
            self.counters["unknown_anchor"] += 1
            return []
        admitted = anchor.admit(reading)
        if admitted is None:
            self.counters["outside_fov"] += 1
            return []
        reading = admitted
        if self.wanted and reading.tag not in self.wanted:
            self.counters["other_tag"] += 1
            return []
        self.counters["events"] += 1
        heapq.heappush(self._pending, (t, reading.anchor, reading.tag, reading.clockwise_deg, reading.elevation_deg or 0.0))
        self._latest = max(self._latest, t)
        out: list[Position] = []
        while self._pending and (self._pending[0][0] <= self._latest - self.reorder_s or len(self._pending) > MAX_PENDING):
            if len(self._pending) > MAX_PENDING:
                self.counters["overflow"] += 1
            out += self._take(heapq.heappop(self._pending))
        return out

    def disconnected(self, t: float, anchor_ids: list[str] | set[str]) -> None:
        """These anchors' device went away at host time ``t``: fixes from ``t`` on leave out
        their angles from before it, instead of reusing them for up to ``stale_s`` (a moving tag
        would be pulled toward where it was)."""
        for anchor_id in anchor_ids:
            self._lost[anchor_id] = t
        self.counters["disconnects"] += len(anchor_ids)

    def flush(self) -> list[Position]:
        """End of input: the events still held for reordering, and the ticks they pass."""
        out: list[Position] = []
        while self._pending:
            out += self._take(heapq.heappop(self._pending))
        return out

    def _take(self, item: tuple[float, str, str, float, float]) -> list[Position]:
        t, anchor_id, tag, az, el = item
        out: list[Position] = []
        if self._next_tick is None:
            self._next_tick = math.ceil(t / self.period) * self.period
        while self._next_tick <= t:
            out += self._tick(self._next_tick)
            self._next_tick += self.period
        window = self._windows.get((tag, anchor_id))
        if window is None:
            window = self._windows[(tag, anchor_id)] = deque(maxlen=MAX_PER_PAIR)
        if window and t < window[-1][0]:
            self.counters["late"] += 1  # later than reorder_s: taken, out of order
        cal = self.anchors[anchor_id].calibration
        a, e = cal.correct(az, el) if self.calibrated else (float(az), float(el))
        window.append((t, a, e))
        tracker = self._angle_trackers.get(tag)
        if tracker is not None and not tracker.lost:
            before, density = tracker.counters["downweighted"], tracker.log_density
            if math.isfinite(tracker.update(t, self._index[anchor_id], a, e)):  # the density of the reading
                self.log_density += tracker.log_density - density - (cal.log_stretch(a) if self.calibrated else 0.0)
                self.reports_scored += 1
            self.counters["downweighted"] += tracker.counters["downweighted"] - before
            if tracker.lost:  # its reports disagreed with it for too long: the next tick fixes afresh
                self.counters["restarts"] += 1
        ekf = self._ekfs.get(tag)
        if ekf is not None and ekf.t is not None:
            info = self.site.tag(tag)
            sigma = math.hypot(angle_sigma_deg(a, e, self.site.sigma_deg), self.site.sigma_deg * SYSTEMATIC)
            a = float(uncompress(a, self.site.az_compression))  # the bearing EKF's model has no compression
            if not ekf.update_angles(t, self._origins[anchor_id], self.rotations[anchor_id], a, e, sigma,
                                     info.height if info else None, self.anchors[anchor_id].angle_model):
                self.counters["gated"] += 1
                if ekf.t is None:  # refused max_misses pairs in a row: the next tick fixes afresh
                    self.counters["restarts"] += 1
        return out

    # -- output ------------------------------------------------------------------------
    def rays_at(self, tag: str, t: float) -> tuple[list[Ray], float]:
        """Each fresh anchor's ray for ``tag`` at ``t`` and the mean time of the angles used."""
        rays, times = [], []
        sigma0 = self.site.sigma_deg
        for anchor_id, anchor in self.anchors.items():
            window = self._windows.get((tag, anchor_id))
            if not window or window[-1][0] < t - self.site.stale_s:
                continue
            while window and window[0][0] < t - self.site.stale_s - self.site.window_s:
                window.popleft()
            lost = self._lost.get(anchor_id, -math.inf)
            since = lost if t >= lost else -math.inf  # a tick before the loss still had the anchor
            last = next((w[0] for w in reversed(window) if since < w[0] <= t), None)
            if last is None:
                continue
            first = max(since, last - self.site.window_s)
            recent = [w for w in window if first < w[0] <= last]
            az = float(uncompress(statistics.median(w[1] for w in recent), self.site.az_compression))
            el = statistics.median(w[2] for w in recent)
            sigma = math.hypot(sigma0 * 1.25 / math.sqrt(len(recent)), sigma0 * SYSTEMATIC)
            rays.append(make_ray(anchor.name, anchor.position, self.rotations[anchor_id], az, el, sigma,
                                 anchor.two_sided, anchor.angle_model))
            times.append(sum(w[0] for w in recent) / len(recent))
        return rays, sum(times) / len(times) if times else t

    def _tick(self, t: float) -> list[Position]:
        out = []
        gone = [k for k, w in self._windows.items() if not w or w[-1][0] < t - FORGET_S]
        for key in gone:  # tags that left (or were never wanted): bounded memory
            del self._windows[key]
            if not any(k[0] == key[0] for k in self._windows):
                self._trackers.pop(key[0], None)
                self._ekfs.pop(key[0], None)
                self._angle_trackers.pop(key[0], None)
        for tag in sorted({k[0] for k in self._windows}):
            info = self.site.tag(tag)
            height = info.height if info else None
            ekf = self._ekfs.get(tag) or self._angle_trackers.get(tag)
            if ekf is not None and ekf.t is not None and ekf.t >= t - self.site.stale_s:
                fresh = tuple(a.name for a_id, a in self.anchors.items()
                              if (w := self._windows.get((tag, a_id))) and w[-1][0] >= t - self.site.stale_s
                              and not w[-1][0] <= self._lost.get(a_id, -math.inf) <= t)  # none since lost
                point, cov = ekf.predicted(t)
                out.append(Position(t, tag, point, cov, fresh, (), True))
                continue
            rays, t_fix = self.rays_at(tag, t)
            if len(rays) < (2 if height is not None else 3):
                self.counters["no_fix"] += 1
                continue
            try:
                fix = locate(rays, height=height, loss=self.loss, height_sigma=self.height_sigma)
            except Degenerate:
                self.counters["no_fix"] += 1
                continue
            self.counters["fixes"] += 1
            self.counters["rejected_anchor"] += len(fix.rejected)
            if not self.track:
                out.append(Position(t, tag, fix.point, fix.covariance, fix.used, fix.rejected, False, _chi2_per_dof(fix, height, self.height_sigma),
                                    t_fix=t_fix))
                continue
            if self.tracker == "angles":  # a fix starts (or restarts) the tracker; angles drive it
                angles = self._angle_trackers[tag] = self._new_angle_tracker(height)
                angles.start(t_fix, fix.point, fix.covariance)
                point, cov = angles.predicted(t)
                out.append(Position(t, tag, point, cov, fix.used, fix.rejected, True, _chi2_per_dof(fix, height, self.height_sigma)))
                continue
            if self.tracker == "ekf":  # a fix starts (or restarts) the filter; angles drive it
                ekf = self._ekfs[tag] = BearingEkf(self.accel_psd)
                ekf.start(t_fix, fix.point, fix.covariance)
                point, cov = ekf.predicted(t)
                out.append(Position(t, tag, point, cov, fix.used, fix.rejected, True, _chi2_per_dof(fix, height, self.height_sigma)))
                continue
            tracker = self._trackers.setdefault(tag, ConstantVelocity(self.accel_psd))
            if not tracker.update(t_fix, fix.point, fix.covariance):
                self.counters["gated"] += 1
            if tracker.t is None:
                continue
            point, cov = tracker.predicted(t)
            if height is not None and self.height_sigma is None:  # a constraint, not a prior
                point = np.array([point[0], point[1], height])
            out.append(Position(t, tag, point, cov, fix.used, fix.rejected, True, _chi2_per_dof(fix, height, self.height_sigma)))
        return out

    def _new_angle_tracker(self, height: float | None) -> AngleTracker | TrackerBank:
        anchors = self.site.anchors

        def one(q: float) -> AngleTracker:
            return AngleTracker([a.position for a in anchors], [self.rotations[a.id] for a in anchors],
                                [a.angle_model for a in anchors], self.noise, q, height, self.height_sigma,
                                self.site.az_compression)

        if self.accel_psd >= AGILE_ACCEL_PSD:
            return one(self.accel_psd)
        return TrackerBank([one(self.accel_psd), one(AGILE_ACCEL_PSD)])


def smooth(fixes: list[Position], accel_psd: float = 1.0) -> list[Position]:
    """RTS-smoothed positions from a whole recording's raw fixes (``Locator(track=False)``),
    labelled ``smoothed``; each at its tick, from the smoothed state at its angles' mean time."""
    out = []
    for tag in sorted({p.tag for p in fixes}):
        mine = [p for p in fixes if p.tag == tag]
        times = np.array([p.t if p.t_fix is None else p.t_fix for p in mine])
        states, covs = rts_smooth(times, np.array([p.point for p in mine]), np.array([p.covariance for p in mine]),
                                  accel_psd)
        for p, x, c, t_fix in zip(mine, states, covs, times):
            point = x[:3] + x[3:] * (p.t - t_fix)
            out.append(replace(p, point=point, covariance=c, tracked=True, smoothed=True))
    return sorted(out, key=lambda p: (p.t, p.tag))


def _uncalibrated(anchor: Anchor) -> Anchor:
    return replace(anchor, calibration=Calibration())
