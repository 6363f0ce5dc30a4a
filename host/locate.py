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
from rfhoming.host.estimation.anchors3d import (
    LOSSES,
    Degenerate,
    Fix,
    Ray,
    angle_sigma_deg,
    board_direction,
    locate,
    make_ray,
)
from rfhoming.host.estimation.angle_tracker import AngleNoise, AngleTracker, TrackerBank
from rfhoming.host.estimation.bearing_consensus import Bearings, Consensus, consensus
from rfhoming.host.estimation.spans import MAX_SPAN_S, RATE_REPORTS, ray_span, stale_after, usual_gap
from rfhoming.host.estimation.track_guard import MIN_ANCHORS, TrackGuard
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

CHECK_SPAN_S = 3.0
"""The track's check (estimation/track_guard.py) takes each anchor's reports of the last this many
seconds, or of its last CHECK_REPORTS (up to MAX_SPAN_S), at most CHECK_MAX of them spread evenly."""

CHECK_REPORTS = 8
CHECK_MAX = 24

FLOOR_M = 0.25
"""Added (as a standard deviation, on x and y) to an angles tracker's position covariance, times
the tag's noise scale: the error of a tag that stands where the multipath stays put for longer
than the tracker's slow errors last (2 s). Chosen so that the 95 % ellipse holds the truth at
95 % of the ticks on the shared recordings: 0.29 on uc1 (then uc2: 97.8 %), 0.21 on uc2 (then
uc1: 91.2 %); the default is the mean of the two (docs/estimation.md, "Guards")."""

POOR_BOARD = 1.5
"""A board whose reports miss the track by this many times what the noise model expects is
tracked with its noise scaled up to match (below it, with the model's: real XPLR-AOA walks miss
by 0.7-1.1 times, and a small scale is noise in the measure, not a poorer board)."""

RESCALE = 1.1
"""A tag's tracker takes a new noise scale when the board's spread moved it by this factor."""

VERTICAL = 0.2
"""A report whose ray is this near vertical (horizontal part below it) has no floor bearing."""


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
        self._windows: dict[tuple[str, str], deque[tuple[float, ...]]] = {}
        """(t, azimuth, elevation, floor bearing, its fold's) of each (tag, anchor): corrected degrees, radians."""
        self._trackers: dict[str, ConstantVelocity] = {}
        self._ekfs: dict[str, BearingEkf] = {}
        self._angle_trackers: dict[str, AngleTracker | TrackerBank] = {}
        self.extent = site.bounds()
        self._guards: dict[str, TrackGuard] = {}
        self._noise_scale: dict[str, float] = {}
        """Per tag: the angles tracker's azimuth noise over ``noise``'s, when the reports miss the
        track by more than that noise says (a poorer board than the model's): see _rescale."""
        self.log_density = 0.0
        """The sum of the angles tracker's reports' predictive log densities (in the reported
        angles' units), over ``reports_scored`` reports: its mean says how well a site (its
        calibration) lets the tracker foresee the reports."""
        self.reports_scored = 0
        self._lost: dict[str, float] = {}  # anchor id -> host time its driver last reported it gone
        self.counters = {"events": 0, "unknown_anchor": 0, "other_tag": 0, "late": 0, "overflow": 0,
                         "fixes": 0, "no_fix": 0, "rejected_anchor": 0, "gated": 0, "restarts": 0,
                         "disconnects": 0, "downweighted": 0, "outside_fov": 0, "outside": 0, "held": 0}
        """outside_fov: readings beyond their anchor's field of view (fov_deg);
        outside: positions withheld beyond the site's extent plus its margin (each a lost track);
        held: a tracker's state put back inside the extent plus margin after a report (estimation/extent.py);
        restarts: lost tracks started again (outside, held too long, or their reports' check, or the tracker's own)."""

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
        while window and window[0][0] < t - 2 * MAX_SPAN_S:
            window.popleft()
        anchor = self.anchors[anchor_id]
        cal = anchor.calibration
        a, e = cal.correct(az, el) if self.calibrated else (float(az), float(el))
        window.append((t, a, e, *self._bearing(anchor, a, e)))
        tracker = self._angle_trackers.get(tag)
        if tracker is not None and not tracker.lost:
            before, density = tracker.counters["downweighted"], tracker.log_density
            if math.isfinite(tracker.update(t, self._index[anchor_id], a, e)):  # the density of the reading
                self.log_density += tracker.log_density - density - (cal.log_stretch(a) if self.calibrated else 0.0)
                self.reports_scored += 1
            self.counters["downweighted"] += tracker.counters["downweighted"] - before
            outside = tracker.hold(self.extent)
            self.counters["held"] += outside
            self._guards[tag].held(t, outside)
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

    def _bearing(self, anchor: Anchor, a: float, e: float) -> tuple[float, float]:
        """A corrected report's floor bearing and its fold's (radians; nan: none, or a ray near vertical)."""
        rot = self.rotations[anchor.id]
        d = rot @ board_direction(self._true_azimuth(a), e, anchor.angle_model)
        if math.hypot(d[0], d[1]) < VERTICAL:
            return math.nan, math.nan
        if not anchor.two_sided:
            return math.atan2(d[1], d[0]), math.nan
        m = rot @ (rot.T @ d * np.array([-1.0, 1.0, 1.0]))
        return math.atan2(d[1], d[0]), math.atan2(m[1], m[0])

    def _true_azimuth(self, a: float) -> float:
        """A corrected azimuth with the boards' |azimuth| compression undone: a +-90 board's
        reading; one beyond +-90 (a board that sees all round) is taken as it is."""
        return float(uncompress(a, self.site.az_compression)) if abs(a) <= 90.0 else a

    def _since(self, anchor_id: str, t: float) -> float:
        """Reports of this anchor at or before this are not used at ``t`` (its device was lost then)."""
        lost = self._lost.get(anchor_id, -math.inf)
        return lost if t >= lost else -math.inf  # a tick before the loss still had the anchor

    def _stale_after(self, window: deque[tuple[float, ...]]) -> float:
        """How long this anchor may be silent and still count: stale_s, or a few of its usual gaps."""
        return float(stale_after(_gap(window), self.site.stale_s))

    def _fresh(self, tag: str, t: float) -> list[str]:
        """The anchors heard about ``tag`` recently enough (and since any loss of their device)."""
        return [a_id for a_id in self.anchors if (w := self._windows.get((tag, a_id)))
                and w[-1][0] >= t - self._stale_after(w) and not w[-1][0] <= self._lost.get(a_id, -math.inf) <= t]

    # -- output ------------------------------------------------------------------------
    def rays_at(self, tag: str, t: float) -> tuple[list[Ray], float]:
        """Each fresh anchor's ray for ``tag`` at ``t`` and the mean time of the angles used: the
        median of its last window_s seconds of angles, widened for a slow anchor until it holds
        RAY_REPORTS (up to MAX_SPAN_S)."""
        rays, times = [], []
        sigma0 = self.site.sigma_deg
        for anchor_id, anchor in self.anchors.items():
            window = self._windows.get((tag, anchor_id))
            if not window or window[-1][0] < t - self._stale_after(window):
                continue
            since = self._since(anchor_id, t)
            last = next((w[0] for w in reversed(window) if since < w[0] <= t), None)
            if last is None:
                continue
            first = max(since, last - float(ray_span(_gap(window), self.site.window_s)))
            recent = _between(window, first, last)
            az = self._true_azimuth(_circular_median([w[1] for w in recent]))
            el = statistics.median(w[2] for w in recent)
            sigma = math.hypot(sigma0 * 1.25 / math.sqrt(len(recent)), sigma0 * SYSTEMATIC)
            rays.append(make_ray(anchor.name, anchor.position, self.rotations[anchor_id], az, el, sigma,
                                 anchor.two_sided, anchor.angle_model))
            times.append(sum(w[0] for w in recent) / len(recent))
        return rays, sum(times) / len(times) if times else t

    def recent_bearings(self, tag: str, t: float) -> tuple[Bearings, np.ndarray] | None:
        """The fresh anchors' recent reports of ``tag`` as floor bearings, and their times: each
        anchor's last CHECK_SPAN_S seconds, or its last CHECK_REPORTS (within MAX_SPAN_S), at
        most CHECK_MAX spread evenly; None from fewer than MIN_ANCHORS anchors."""
        rows: list[tuple[float, float, float, int]] = []
        for k, anchor_id in enumerate(self.anchors):
            window = self._windows.get((tag, anchor_id))
            if not window or window[-1][0] < t - self._stale_after(window):
                continue
            span = min(MAX_SPAN_S, max(CHECK_SPAN_S, CHECK_REPORTS * _gap(window)))
            mine = [(w[0], w[3], w[4], k) for w in _between(window, max(self._since(anchor_id, t), t - span), t)
                    if not math.isnan(w[3])]
            rows += mine[:: -(-len(mine) // CHECK_MAX)] if mine else []
        if len({r[3] for r in rows}) < MIN_ANCHORS:
            return None
        a = np.array(rows)
        origins = np.array([self._origins[list(self.anchors)[int(k)]][:2] for k in a[:, 3]])
        return Bearings(origins, a[:, 1], a[:, 2], a[:, 3].astype(int)), a[:, 0]

    def _consensus(self, tag: str, t: float) -> Consensus | None:
        got = self.recent_bearings(tag, t)
        return None if got is None else consensus(got[0], self.extent)

    def _tick(self, t: float) -> list[Position]:
        out = []
        gone = [k for k, w in self._windows.items() if not w or w[-1][0] < t - FORGET_S]
        for key in gone:  # tags that left (or were never wanted): bounded memory
            del self._windows[key]
            if not any(k[0] == key[0] for k in self._windows):
                self._drop(key[0])
                self._guards.pop(key[0], None)
        for tag in sorted({k[0] for k in self._windows}):
            out += self._tag_tick(tag, t)
        return out

    def _drop(self, tag: str) -> None:
        self._trackers.pop(tag, None)
        self._ekfs.pop(tag, None)
        self._angle_trackers.pop(tag, None)

    def _tag_tick(self, tag: str, t: float) -> list[Position]:
        """``tag``'s position at tick ``t``: from its running track (checked), or a fresh fix."""
        info = self.site.tag(tag)
        height = info.height if info else None
        guard = self._guards.setdefault(tag, TrackGuard(self.extent))
        ekf = self._ekfs.get(tag) or self._angle_trackers.get(tag)
        fresh = self._fresh(tag, t)
        stale = max((self._stale_after(self._windows[(tag, a)]) for a in fresh), default=self.site.stale_s)
        if ekf is not None and ekf.t is not None and ekf.t >= t - stale:
            point, cov = ekf.predicted(t)
            restart: Consensus | None = None
            if not self.extent.inside(point) or guard.held_too_long(t):  # withheld: a track that left is lost
                self.counters["outside"] += 1
                restart, lost = self._consensus(tag, t), True
            elif guard.due(t) and (reports := self.recent_bearings(tag, t)) is not None:
                restart = guard.check(*reports)
                lost = restart is not None
                self._rescale(tag, guard)
            else:
                lost = False
            if not lost:
                guard.record(t, point)
                return [Position(t, tag, point, self._honest(tag, cov), tuple(self.anchors[a].name for a in fresh), (),
                                 True)]
            self.counters["restarts"] += 1
            self._drop(tag)
            guard.reset()
            if restart is None:
                return []
            return [self._start(tag, t, t, self._restart_point(restart, point, height), (), ())]
        rays, t_fix = self.rays_at(tag, t)
        if len(rays) < (2 if height is not None else 3):
            self.counters["no_fix"] += 1
            return []
        try:
            fix = locate(rays, height=height, loss=self.loss, height_sigma=self.height_sigma)
        except Degenerate:
            self.counters["no_fix"] += 1
            return []
        self.counters["fixes"] += 1
        self.counters["rejected_anchor"] += len(fix.rejected)
        quality = _chi2_per_dof(fix, height, self.height_sigma)
        if not self.extent.inside(fix.point):  # withheld; a tracker starts from the reports' consensus instead
            self.counters["outside"] += 1
            restart = self._consensus(tag, t) if self.track and self.tracker != "cv" else None
            if restart is None:
                return []
            guard.reset()
            return [self._start(tag, t, t, self._restart_point(restart, fix.point, height), fix.used, fix.rejected)]
        if not self.track:
            return [Position(t, tag, fix.point, fix.covariance, fix.used, fix.rejected, False, quality, t_fix=t_fix)]
        if self.tracker in ("angles", "ekf"):  # a fix starts (or restarts) the tracker; angles drive it
            guard.reset()
            started = self._start(tag, t, t_fix, (fix.point, fix.covariance), fix.used, fix.rejected)
            return [replace(started, quality=quality)]
        tracker = self._trackers.setdefault(tag, ConstantVelocity(self.accel_psd))
        if not tracker.update(t_fix, fix.point, fix.covariance):
            self.counters["gated"] += 1
        if tracker.t is None:
            return []
        point, cov = tracker.predicted(t)
        if height is not None and self.height_sigma is None:  # a constraint, not a prior
            point = np.array([point[0], point[1], height])
        if not self.extent.inside(point):  # withheld, and the filter starts again
            self.counters["outside"] += 1
            self.counters["restarts"] += 1
            self._trackers.pop(tag)
            return []
        return [Position(t, tag, point, cov, fix.used, fix.rejected, True, quality)]

    def _rescale(self, tag: str, guard: TrackGuard) -> None:
        """The board's error, measured on a fixed scale (the guard's spread), against the noise
        model's: a board that misses by POOR_BOARD times more or beyond gets its azimuth noise scaled
        up to match (never down: the model's noise was chosen on real boards), so a 25-degree board
        is not tracked as if it were an 8-degree one."""
        spread = guard.spread_deg
        if spread is None:
            return
        nz = self.noise
        ratio = spread / (0.6745 * math.hypot(nz.white_deg, nz.slow_deg))  # the model's median |miss|
        scale = ratio if ratio >= POOR_BOARD else 1.0
        if abs(math.log(scale / self._noise_scale.get(tag, 1.0))) < math.log(RESCALE):
            return
        self._noise_scale[tag] = scale
        tracker = self._angle_trackers.get(tag)
        if tracker is not None:
            tracker.renoise(self._noise(tag))

    def _noise(self, tag: str) -> AngleNoise:
        k = self._noise_scale.get(tag, 1.0)
        return replace(self.noise, white_deg=self.noise.white_deg * k, slow_deg=self.noise.slow_deg * k)

    def _restart_point(self, restart: Consensus, old: np.ndarray, height: float | None) -> tuple[np.ndarray, np.ndarray]:
        """The consensus as a 3-D start: the tag's height, or the old height kept in the extent."""
        z = height if height is not None else float(self.extent.clamp(old)[2])
        cov = np.zeros((3, 3))
        cov[:2, :2] = restart.covariance
        if height is None or self.height_sigma is not None:
            cov[2, 2] = 1.0 if height is None else self.height_sigma**2  # type: ignore[operator]
        return np.array([restart.point[0], restart.point[1], z]), cov

    def _start(self, tag: str, t: float, t_start: float, start: tuple[np.ndarray, np.ndarray],
               used: tuple[str, ...], rejected: tuple[str, ...]) -> Position:
        """A new track of ``tag`` at ``start`` (point, covariance) as of ``t_start``; its position at ``t``."""
        info = self.site.tag(tag)
        height = info.height if info else None
        tracker: AngleTracker | TrackerBank | BearingEkf
        if self.tracker == "ekf":
            tracker = self._ekfs[tag] = BearingEkf(self.accel_psd)
        else:
            tracker = self._angle_trackers[tag] = self._new_angle_tracker(height, self._noise(tag))
        tracker.start(t_start, *start)
        point, cov = tracker.predicted(t)
        self._guards[tag].record(t, point)
        return Position(t, tag, point, self._honest(tag, cov), used, rejected, True)

    def _honest(self, tag: str, cov: np.ndarray) -> np.ndarray:
        """The tracker's position covariance with FLOOR_M added (the angles tracker's; the ekf's as it is)."""
        if self.tracker != "angles":
            return cov
        out = cov.copy()
        out[[0, 1], [0, 1]] += (FLOOR_M * self._noise_scale.get(tag, 1.0)) ** 2
        return out

    def _new_angle_tracker(self, height: float | None, noise: AngleNoise) -> AngleTracker | TrackerBank:
        anchors = self.site.anchors

        def one(q: float) -> AngleTracker:
            return AngleTracker([a.position for a in anchors], [self.rotations[a.id] for a in anchors],
                                [a.angle_model for a in anchors], noise, q, height, self.height_sigma,
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


def _circular_median(degrees: list[float]) -> float:
    """The median of angles about their circular mean, in (-180, 180]: readings either side of
    +-180 (a board that sees all round, the tag behind it) are not averaged to 0."""
    if max(degrees) - min(degrees) <= 180.0:
        return float(statistics.median(degrees))
    r = np.radians(degrees)
    mean = math.degrees(math.atan2(float(np.sin(r).sum()), float(np.cos(r).sum())))
    m = mean + statistics.median((d - mean + 180.0) % 360.0 - 180.0 for d in degrees)
    return (m + 180.0) % 360.0 - 180.0 if abs(m) > 180.0 else m


def _gap(window: deque[tuple[float, ...]]) -> float:
    """An anchor's usual time between reports: the mean over its last RATE_REPORTS (inf: one report)."""
    n = min(len(window) - 1, RATE_REPORTS)
    return float(usual_gap(window[-1][0], window[-1 - n][0], n))


def _between(window: deque[tuple[float, ...]], first: float, last: float) -> list[tuple[float, ...]]:
    """The window's entries with first < t <= last, oldest first (scanned from the newest end)."""
    out = []
    for w in reversed(window):
        if w[0] <= first:
            break
        if w[0] <= last:
            out.append(w)
    return out[::-1]


def _uncalibrated(anchor: Anchor) -> Anchor:
    return replace(anchor, calibration=Calibration())
