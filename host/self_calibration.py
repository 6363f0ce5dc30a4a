"""Self-calibration of fixed AoA anchors from tags walked over the room: no known points, and
never a calibration that makes the site worse.

Each anchor's reported azimuth is modelled as ``scale * compress(true) + bias`` (and elevation
as ``el_scale * true + el_bias``), fitted jointly with every epoch's tag position by a robust
sparse least-squares fit (soft-L1). What keeps it honest on real rooms:

- **Places, not reports.** A board's error stays put at a place, so the epochs are grouped by
  place (:func:`_clusters`: CELL_M squares; a stop is one place however long). Each
  parameter's uncertainty is a sandwich over places (:func:`_uncertainty`).
- **Only what the data determine.** A parameter is written only when its uncertainty is at
  most DATA_OVER_PRIOR of its prior's (PRIOR_SD: biases toward 0, scales toward 1) and its
  value Z_WRITE uncertainties from its default; the rest is held, its value and uncertainty
  said. The written ones are refitted with the prior, so each shrinks as far as it is unsure.
- **Held out, and of another kind.** The places are dealt into ``FOLDS`` folds; each fold is
  fitted on the others and scored on itself (its positions re-solved with the parameters
  fixed); and a fit to the walking is judged on the stops, and the reverse (:func:`_cross_kind`).
  A calibration that does not beat the uncalibrated site on held-out places, or is worse on
  either kind, is not written.
- **Elevation held unless asked for** (``elevation=True``, ``--fit-elevation``). From anchors
  high on the walls a tag's elevation changes little over the room, and its bias trades
  against the tag's height and range: on real walks the fitted elevation biases were the walk's
  multipath and made the other walk worse. Asked for, it is fitted only when tags of known
  height see elevation over ``MIN_EL_SPAN_DEG``, and the calibration must also make locate's
  tracker foresee the recordings' reports better (``_foresight``).
- **The angle model on unseen data.** Spherical, cone, and each with |azimuth| compression
  are scored per anchor on the held-out residual; a model replaces the site's only when it
  wins by ``MODEL_MARGIN``.
- **Seconds.** Epochs are thinned to ``MAX_FIT_EPOCHS`` per fit and the Jacobian is sparse
  (each residual touches its anchor's parameters and its epoch's position).

Gauge: an overall azimuth scale is not observable (scaling every anchor up while pulling the
positions to the middle barely changes the residuals): the free scales' geometric mean is 1.
A yaw offset moves a near-level board's azimuths like its bias: it is fitted as the bias.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from rfhoming.host.bearing import Bearing
from rfhoming.host.calibration import AnchorFit, CalibrationError
from rfhoming.host.estimation.anchors3d import Degenerate, locate, make_ray
from rfhoming.host.site import CALIBRATION_LIMITS, Anchor, Calibration, Site

SELF_EPOCH_S = 0.5
"""One epoch per tag every this many seconds (each anchor's median angle of the window before)."""

SELF_MIN_EPOCHS = 40
"""Epochs a self-calibration needs at the least."""

MIN_REPORTS = 3
"""Reports of an anchor an epoch takes the median of, at the least ..."""

MAX_EPOCH_WINDOW_S = 10.0
"""... over the site's window, or longer for a slow anchor, up to this."""

STAND_WINDOW_S = 5.0
STAND_M = 0.6
"""An epoch is standing when the median uncalibrated fix of the STAND_WINDOW_S before it and that
of those after it are within STAND_M (a walking tag moves 2-5 m in that time)."""

CELL_M = 2.5
"""The room is cut into squares this wide (about the length over which real boards' errors
change with the tag's place: 2.7 m on the shared recordings' profile)..."""

MIN_CLUSTERS = 6
"""... and a calibration needs the tags in this many of them: errors stay put at a place, so a
long stop, or the same path walked again, is one sample of it, not many."""

SELF_MIN_SPREAD = 0.2
"""The epochs' positions must spread (standard deviation along their narrowest direction) over
at least this fraction of the anchors' extent: a dwell cannot separate scale from position."""

SELF_MIN_AZ_SPAN_DEG = 40.0
"""Azimuth span each anchor must see over the epochs (5th to 95th percentile)."""

MIN_EL_SPAN_DEG = 10.0
"""Elevation span (5th to 95th percentile) an anchor must see of known-height tags to fit elevation."""

ELEVATION_NOISIER = 2.0
"""Elevation's sigma as a multiple of azimuth's (the weaker axis)."""

FOLDS = 3
"""Held-out folds: the places (:func:`_clusters`) dealt round-robin."""

MAX_FIT_EPOCHS = 400
"""Epochs per fit at most (evenly thinned): neighbours 0.5 s apart add little but time."""

MIN_GAIN = 0.02
"""A calibration is written only when it cuts the held-out azimuth residual by this fraction."""

MODEL_MARGIN = 0.03
"""A candidate angle model must cut an anchor's held-out residual by this fraction to replace the site's."""

OUTLIER_DEG = 20.0
"""Held-out residuals beyond this are reflections, not calibration: left out of the figures."""

UNKNOWN_HEIGHT = (1.0, 0.5)
"""The prior (mean, sigma, metres) of a tag whose height neither the site nor --height gives."""

PARAMS = ("log_az_scale", "az_bias_deg", "az_compression", "log_el_scale", "el_bias_deg")
"""Per-anchor parameters, in the fit's column order (scales as logs: the gauge is a sum)."""

PRIOR_SD = (0.05, 3.0, 0.1, 0.1, 5.0)
"""The prior each parameter is shrunk with, about its default (scales 1, the rest 0): real boards'
azimuth errors are within +-3 deg and their scale 1 to a few per cent (the 2026-12 field report)."""

DATA_OVER_PRIOR = 0.5
"""A parameter is written only when its uncertainty is at most this fraction of its prior's ..."""

Z_WRITE = 2.0
"""... and its value this many uncertainties from its default: otherwise the data do not determine it."""

NAMES = ("az_scale", "az_bias_deg", "az_compression", "el_scale", "el_bias_deg")
LIMITS = np.array([[math.log(CALIBRATION_LIMITS["az_scale"][0]), math.log(CALIBRATION_LIMITS["az_scale"][1])],
                   CALIBRATION_LIMITS["az_bias_deg"], CALIBRATION_LIMITS["az_compression"],
                   [math.log(CALIBRATION_LIMITS["el_scale"][0]), math.log(CALIBRATION_LIMITS["el_scale"][1])],
                   CALIBRATION_LIMITS["el_bias_deg"]])

CANDIDATES = (("spherical", False), ("cone", False), ("spherical", True), ("cone", True))
"""(angle model, |azimuth| compression fitted) pairs scored per anchor."""


@dataclass(frozen=True)
class HeldOut:
    """Figures on epochs no fit saw: azimuth residual rms (degrees) and the rays' miss at the
    re-solved position (metres, rms), before (uncalibrated) and after."""

    az_rms_before_deg: float
    az_rms_after_deg: float
    miss_before_m: float
    miss_after_m: float

    @property
    def improves(self) -> bool:
        return (self.az_rms_after_deg <= (1 - MIN_GAIN) * self.az_rms_before_deg
                and self.miss_after_m <= self.miss_before_m)

    @property
    def not_worse(self) -> bool:
        return self.az_rms_after_deg <= self.az_rms_before_deg and self.miss_after_m <= self.miss_before_m

    def said(self) -> str:
        return (f"azimuth rms {self.az_rms_before_deg:.2f} -> {self.az_rms_after_deg:.2f} deg, ray miss "
                f"{self.miss_before_m:.3f} -> {self.miss_after_m:.3f} m")


@dataclass(frozen=True)
class SelfCalibration:
    fits: list[AnchorFit]
    epochs: int
    rms_before_deg: float
    rms_after_deg: float
    held_out: HeldOut
    verdict: str  # one line: why it is (or is not) written
    model_scores: dict[str, dict[str, float]] = field(default_factory=dict)  # anchor -> candidate -> held-out rms
    gauge: str = "the anchors' free azimuth scales have geometric mean 1 (an overall scale is not observable)"
    foresight: tuple[float, float] = (math.nan, math.nan)
    """locate's tracker on the recordings, uncalibrated and calibrated: the mean predictive log
    density of the reports (higher: the reports foreseen better); nan when not asked (no
    elevation fitted)."""
    held: dict[str, str] = field(default_factory=dict)
    """Parameters held on every anchor for one reason (name -> reason): elevation by default."""
    cross_kind: dict[str, HeldOut] = field(default_factory=dict)
    """Kind of motion (standing, moving) -> a calibration fitted on the other kind, judged on
    this one; empty when the recordings hold one kind only."""
    changes: bool = True
    """Whether it changes anything (a parameter determined, or an angle model)."""

    @property
    def elevation_fitted(self) -> bool:
        return any("el_scale" in f.sigma or "el_bias_deg" in f.sigma for f in self.fits)

    @property
    def write(self) -> bool:
        return (self.changes and self.held_out.improves and all(h.not_worse for h in self.cross_kind.values())
                and (not self.elevation_fitted or self.foresight[1] > self.foresight[0]))


@dataclass
class _Epochs:
    """Every epoch's rows: which anchor, the measured angles, and the epoch's facts."""

    row_e: np.ndarray  # (R,) epoch index of each row
    row_a: np.ndarray  # (R,) anchor index
    az: np.ndarray  # (R,) measured azimuth, degrees (board sign)
    el: np.ndarray
    height: np.ndarray  # (E,) known height or nan
    start: np.ndarray  # (E, 3) the uncalibrated fix
    t: np.ndarray  # (E,) seconds
    series: np.ndarray  # (E,) which recording and tag
    standing: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # (E,) :func:`_standing`
    cluster: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # (E,) :func:`_clusters`

    @property
    def fold(self) -> np.ndarray:
        """(E,) held-out fold: the clusters dealt round-robin (a stop stays whole)."""
        return self.cluster % FOLDS

    def subset(self, keep: np.ndarray) -> _Epochs:
        """The epochs where ``keep`` (E,) is true, renumbered."""
        new = np.full(len(keep), -1)
        new[keep] = np.arange(int(keep.sum()))
        rows = keep[self.row_e]
        return _Epochs(new[self.row_e[rows]], self.row_a[rows], self.az[rows], self.el[rows], self.height[keep],
                       self.start[keep], self.t[keep], self.series[keep], self.standing[keep], self.cluster[keep])


def _windows(site: Site, series: dict[tuple[str, str], np.ndarray]) -> dict[tuple[str, str], float]:
    """Each (tag, anchor) stream's epoch window: the site's, or long enough to hold MIN_REPORTS
    of a slow anchor's reports (0.5-3 a second on some boards), up to MAX_EPOCH_WINDOW_S."""
    out = {}
    for key, v in series.items():
        interval = float(np.median(np.diff(v[:, 0]))) if len(v) >= 2 else math.inf
        out[key] = min(max(site.window_s, MIN_REPORTS * interval), MAX_EPOCH_WINDOW_S)
    return out


def _streams(site: Site, recording: Sequence[Bearing]) -> dict[tuple[str, str], np.ndarray]:
    """(tag, anchor id) -> (N, 3) rows of t, azimuth, elevation of the site's anchors' reports."""
    series: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
    wanted = {a.id for a in site.anchors}
    for r in recording:
        if r.anchor in wanted:
            series.setdefault((r.tag, r.anchor), []).append((r.t, r.clockwise_deg, r.elevation_deg or 0.0))
    return {k: np.array(sorted(v), float) for k, v in series.items()}


def _epoch_angles(site: Site, recording: Sequence[Bearing]
                  ) -> list[tuple[float, str, dict[str, tuple[float, float]]]]:
    """(t, tag, {anchor id: (median az, median el)}) every SELF_EPOCH_S per tag, 3+ anchors with
    MIN_REPORTS+ reports in their window (:func:`_windows`)."""
    series = _streams(site, recording)
    windows = _windows(site, series)
    out = []
    for tag in sorted({tag for tag, _ in series}):
        per = {a: v for (tg, a), v in series.items() if tg == tag}
        t_lo = min(v[0, 0] for v in per.values())
        t_hi = max(v[-1, 0] for v in per.values())
        lead = min(windows[(tag, a)] for a in per)
        for t in np.arange(t_lo + lead, t_hi + 1e-9, SELF_EPOCH_S):
            angles = {}
            for a, v in per.items():
                i, j = np.searchsorted(v[:, 0], [t - windows[(tag, a)], t], side="right")
                if j - i >= MIN_REPORTS:
                    angles[a] = (float(np.median(v[i:j, 1])), float(np.median(v[i:j, 2])))
            if len(angles) >= 3:
                out.append((float(t), tag, angles))
    return out


def _too_few(site: Site, recordings: Sequence[Sequence[Bearing]], n_e: int) -> str:
    """Why the recordings give only ``n_e`` epochs: the real reason, and what to do."""
    head = (f"self-calibration needs {SELF_MIN_EPOCHS}+ epochs (a tag heard by 3+ anchors, each with "
            f"{MIN_REPORTS}+ reports in its window, one every {SELF_EPOCH_S:g} s); the recordings give {n_e}")
    names = {a.id: a.name for a in site.anchors}
    streams = [_streams(site, rec) for rec in recordings]
    heard = sorted({names[a] for st in streams for _, a in st})
    if len(heard) < 3:
        return (f"{head}: only {len(heard)} of the site's anchors ({', '.join(heard) or 'none'}) reported a tag; "
                "3+ must hear it (check the anchors' ids in the site file)")
    intervals = {names[a]: float(np.median(np.diff(v[:, 0]))) for st in streams for (_, a), v in st.items()
                 if len(v) >= 2}
    slow = {n: i for n, i in intervals.items() if MIN_REPORTS * i > MAX_EPOCH_WINDOW_S}
    if len(intervals) - len(slow) < 3:
        worst = ", ".join(f"{n} every {i:.1f} s" for n, i in sorted(slow.items()))
        return (f"{head}: the anchors report too slowly ({worst}): a window of {MAX_EPOCH_WINDOW_S:g} s at most "
                f"(the site's is {site.window_s:g} s) holds fewer than {MIN_REPORTS} of their reports; raise their "
                "report rate (the tag's advertising interval), or calibrate on known points (--points)")
    span = sum(float(max(v[-1, 0] for v in st.values()) - min(v[0, 0] for v in st.values()))
               for st in streams if st)
    return (f"{head}: the recordings span {span:.0f} s in all with the anchors reporting every "
            f"{min(intervals.values()):.2f}-{max(intervals.values()):.2f} s; record at least "
            f"{SELF_MIN_EPOCHS * SELF_EPOCH_S + MAX_EPOCH_WINDOW_S:.0f} s of tags heard by 3+ anchors")


def _gather(site: Site, recordings: Sequence[Sequence[Bearing]], height: float | None
            ) -> _Epochs:
    anchors = list(site.anchors)
    index = {a.id: k for k, a in enumerate(anchors)}
    raw = [replace(a, calibration=Calibration()) for a in anchors]
    rots = [a.rotation() for a in raw]
    heights: list[float] = []
    row_e, row_a, az, el, start, times, series = [], [], [], [], [], [], []
    tags: dict[tuple[int, str], int] = {}
    for r, rec in enumerate(recordings):
        for t, tag, angles in _epoch_angles(site, rec):
            info = site.tag(tag)
            h = info.height if info and info.height is not None else height
            rays = [make_ray(anchors[index[a]].name, anchors[index[a]].position, rots[index[a]], m_az, m_el,
                             site.sigma_deg, model=anchors[index[a]].angle_model) for a, (m_az, m_el) in angles.items()]
            try:
                fix = locate(rays, height=h)
            except Degenerate:
                continue
            e = len(heights)
            for a, (m_az, m_el) in angles.items():
                row_e.append(e)
                row_a.append(index[a])
                az.append(m_az)
                el.append(m_el)
            heights.append(np.nan if h is None else h)
            start.append(fix.point)
            times.append(t)
            series.append(tags.setdefault((r, tag), len(tags)))
    ep = _Epochs(np.array(row_e, int), np.array(row_a, int), np.array(az, float), np.array(el, float),
                 np.array(heights, float), np.array(start, float).reshape(-1, 3), np.array(times, float),
                 np.array(series, int))
    ep.standing = _standing(ep)
    ep.cluster = _clusters(ep)
    return ep


def _standing(ep: _Epochs) -> np.ndarray:
    """(E,) whether the tag stood at each epoch (STAND_M): judged from the uncalibrated fixes,
    since a calibration must not be judged on the kind of motion it was fitted on alone."""
    out = np.zeros(len(ep.t), bool)
    for s in np.unique(ep.series):
        idx = np.flatnonzero(ep.series == s)
        t, xy = ep.t[idx], ep.start[idx, :2]
        lo = np.searchsorted(t, t - STAND_WINDOW_S, side="left")
        hi = np.searchsorted(t, t + STAND_WINDOW_S, side="right")
        for i, e in enumerate(idx):
            before, after = np.median(xy[lo[i]:i + 1], axis=0), np.median(xy[i:hi[i]], axis=0)
            out[e] = float(np.hypot(*(before - after))) < STAND_M
    return out


def _clusters(ep: _Epochs) -> np.ndarray:
    """(E,) each epoch's cluster: the CELL_M square of the room its uncalibrated fix falls in (a
    stop's: the stop's median fix). A board's error is a field over where the tag is, so epochs
    at one place -- a long stop, or the same place walked again -- are one sample of it, not
    many; the uncertainties and the held-out folds take clusters whole."""
    xy = ep.start[:, :2].copy()
    for s in np.unique(ep.series):
        idx = np.flatnonzero(ep.series == s)
        edges = np.flatnonzero(np.diff(np.r_[0, ep.standing[idx].astype(int), 0]))
        for lo, hi in zip(edges[::2], edges[1::2]):
            xy[idx[lo:hi]] = np.median(xy[idx[lo:hi]], axis=0)
    cells = np.floor(xy / CELL_M).astype(int)
    _, out = np.unique(cells, axis=0, return_inverse=True)
    return np.asarray(out).ravel()


class _Model:
    """The forward model of every anchor under one configuration: which angle model, which
    parameters are free (the columns of the fit), and the values of the held ones."""

    def __init__(self, site: Site, models: Sequence[str], free: np.ndarray):
        self.origins = np.array([a.position for a in site.anchors], float)
        self.rots = np.array([replace(a, calibration=Calibration()).rotation() for a in site.anchors])
        self.models = list(models)
        self.free = free  # (A, 5) bool
        self.sigma = site.sigma_deg
        self.board_compression = site.az_compression  # shared by every board: the fit's is on top of it
        scales = np.flatnonzero(free[:, 0])
        self.gauge = int(scales[-1]) if len(scales) else None  # its log scale is minus the sum of the others
        own = free.copy()
        if self.gauge is not None:
            own[self.gauge, 0] = False
        self.column = np.full(free.shape, -1)  # (A, 5) -> column of the free vector, -1 when held
        self.column[own] = np.arange(int(own.sum()))
        self.n_params = int(own.sum())
        self.base = np.zeros(free.shape)  # the held parameters' values
        self.prior_info = 0.0  # the prior's weight (PRIOR_SD's information times this), 0: none

    def mapping(self) -> np.ndarray:
        """(A * 5, P): the parameter table (flattened) by the free vector (the gauge's scale too)."""
        m = np.zeros((self.free.size, self.n_params))
        own = self.column.ravel()
        has = own >= 0
        m[np.flatnonzero(has), own[has]] = 1.0
        if self.gauge is not None:
            m[self.gauge * 5, self.column[:, 0][self.column[:, 0] >= 0]] = -1.0
        return m

    def prior_weights(self) -> np.ndarray:
        """(A * 5,) each free parameter's prior information (0 where held): every default is 0."""
        sd = np.tile(np.array(PRIOR_SD), self.free.shape[0])
        return np.asarray(self.prior_info / sd**2 * self.free.ravel())

    def fixed_at(self, p: np.ndarray) -> _Model:
        """This model with every parameter held at ``p``: the fit then moves the positions only."""
        held = copy.copy(self)
        held.free = np.zeros(self.free.shape, bool)
        held.column = np.full(self.free.shape, -1)
        held.n_params, held.gauge, held.base, held.prior_info = 0, None, p, 0.0
        return held

    def params(self, x: np.ndarray) -> np.ndarray:
        """(A, 5) parameter table from the free vector (held ones at their values)."""
        p = self.base.copy()
        p[self.column >= 0] = x[self.column[self.column >= 0]]
        if self.gauge is not None:
            p[self.gauge, 0] = -p[:, 0].sum()
        return p

    def predict(self, p: np.ndarray, ep: _Epochs, pos: np.ndarray, with_jacobian: bool = False
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Every row's residuals (R, 2: azimuth, elevation, in sigmas), horizontal range (m) and
        predicted reported azimuth (R,); with ``with_jacobian`` the residuals' derivatives by the
        epoch's position (R, 2, 3) and by the anchor's parameters (R, 2, 5)."""
        rot = self.rots[ep.row_a]
        d = np.einsum("nji,nj->ni", rot, pos[ep.row_e] - self.origins[ep.row_a])
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        ang = np.empty((len(d), 2))
        dang = np.zeros((len(d), 2, 3))  # by the board-frame vector
        deg = 180 / np.pi
        cone = np.array([self.models[k] == "cone" for k in range(len(self.models))])[ep.row_a]
        r2 = x * x + y * y + z * z
        r = np.sqrt(r2)
        rho2 = np.maximum(x * x + y * y, 1e-12)
        rho = np.sqrt(rho2)
        u, v = np.clip(y / r, -1 + 1e-12, 1 - 1e-12), np.clip(z / r, -1 + 1e-12, 1 - 1e-12)
        ang[:, 0] = np.where(cone, -np.degrees(np.arcsin(u)), -np.degrees(np.arctan2(y, x)))
        ang[:, 1] = np.where(cone, np.degrees(np.arcsin(v)), np.degrees(np.arctan2(z, rho)))
        q = p[ep.row_a]
        s, c, se = np.exp(q[:, 0]), q[:, 2], np.exp(q[:, 3])
        c0 = self.board_compression
        board = 1 - 3 * c0 * (ang[:, 0] / 90) ** 2  # d(board reading) / d(true azimuth)
        a = ang[:, 0] * (1 - c0 * (ang[:, 0] / 90) ** 2)
        az = s * a * (1 - c * (a / 90) ** 2) + q[:, 1]
        el = se * ang[:, 1] + q[:, 4]
        res = np.stack([(az - ep.az) / self.sigma, (el - ep.el) / (ELEVATION_NOISIER * self.sigma)], axis=1)
        if not with_jacobian:
            return res, rho, az, None, None
        if cone.any():
            ku = -deg / np.sqrt(1 - u * u) / r2
            kv = deg / np.sqrt(1 - v * v) / r2
            dang[cone, 0] = (ku[:, None] * np.stack([-u * x, r - u * y, -u * z], axis=1))[cone]
            dang[cone, 1] = (kv[:, None] * np.stack([-v * x, -v * y, r - v * z], axis=1))[cone]
        sph = ~cone
        if sph.any():
            dang[sph, 0] = (deg * np.stack([y / rho2, -x / rho2, np.zeros_like(x)], axis=1))[sph]
            dang[sph, 1] = (deg * np.stack([-z * x / (rho * r2), -z * y / (rho * r2), rho / r2], axis=1))[sph]
        by_pos = np.einsum("nkj,nij->nki", dang, rot)  # the board vector is rot^T (world - origin)
        scale_az = s * (1 - 3 * c * (a / 90) ** 2) * board / self.sigma
        scale_el = se / (ELEVATION_NOISIER * self.sigma)
        by_pos[:, 0] *= scale_az[:, None]
        by_pos[:, 1] *= scale_el[:, None]
        by_par = np.zeros((len(d), 2, 5))
        by_par[:, 0, 0] = s * a * (1 - c * (a / 90) ** 2) / self.sigma
        by_par[:, 0, 1] = 1 / self.sigma
        by_par[:, 0, 2] = -s * a * (a / 90) ** 2 / self.sigma
        by_par[:, 1, 3] = se * ang[:, 1] / (ELEVATION_NOISIER * self.sigma)
        by_par[:, 1, 4] = 1 / (ELEVATION_NOISIER * self.sigma)
        return res, rho, az, by_pos, by_par

    def by_vector(self, by_par: np.ndarray, row_a: np.ndarray) -> np.ndarray:
        """(R, 2, P): the rows' derivatives by the free vector (the gauge spread over the scales)."""
        out = np.zeros((len(row_a), 2, self.n_params))
        for k in range(5):
            col = self.column[row_a, k]
            has = col >= 0
            out[np.flatnonzero(has), :, col[has]] = by_par[has, :, k]
        if self.gauge is not None:
            mine = np.flatnonzero(row_a == self.gauge)
            for col in self.column[:, 0][self.column[:, 0] >= 0]:
                out[mine, :, col] -= by_par[mine, :, 0]
        return out


ROBUST = 1.5
"""Soft-L1 scale of the residuals, in sigmas: a reflected ray is down-weighted, not obeyed."""


def _cost(res: np.ndarray, pos: np.ndarray, free_z: np.ndarray) -> float:
    z = (pos[free_z, 2] - UNKNOWN_HEIGHT[0]) / UNKNOWN_HEIGHT[1]
    return float(2 * ROBUST**2 * (np.sqrt(1 + (res / ROBUST) ** 2) - 1).sum() + (z * z).sum())


@dataclass
class _System:
    """The robust fit's normal equations at one point, the epochs' position blocks apart."""

    res: np.ndarray  # (R, 2) residuals, sigmas
    w: np.ndarray  # (R, 2) IRLS weights
    jp: np.ndarray  # (R, 2, P) by the free vector
    v: np.ndarray  # (E, 3, 3) each epoch's position block
    g_e: np.ndarray  # (E, 3)
    u: np.ndarray  # (P, P) the parameters' block (with the prior)
    g_p: np.ndarray  # (P,)
    w_e: np.ndarray  # (E, P, 3) the coupling


def _system(model: _Model, ep: _Epochs, x: np.ndarray, pos: np.ndarray, free_z: np.ndarray) -> _System:
    n_e, n_p = len(ep.height), model.n_params
    z0, z_sigma = UNKNOWN_HEIGHT
    res, _, _, by_pos, by_par = model.predict(model.params(x), ep, pos, with_jacobian=True)
    assert by_pos is not None and by_par is not None
    by_pos[~free_z[ep.row_e], :, 2] = 0.0
    w = 1.0 / np.sqrt(1.0 + (res / ROBUST) ** 2)
    jp = model.by_vector(by_par, ep.row_a)
    v_blocks = np.einsum("rki,rk,rkj->rij", by_pos, w, by_pos).reshape(-1, 9)
    v = np.stack([np.bincount(ep.row_e, v_blocks[:, k], n_e) for k in range(9)], axis=1).reshape(n_e, 3, 3)
    g_e = np.stack([np.bincount(ep.row_e, np.einsum("rki,rk,rk->r", by_pos[:, :, [k]], w, res), n_e)
                    for k in range(3)], axis=1)
    v[free_z, 2, 2] += 1 / z_sigma**2
    g_e[free_z, 2] += (pos[free_z, 2] - z0) / z_sigma**2
    v[~free_z, 2, 2] = 1.0
    g_e[~free_z, 2] = 0.0
    u = np.einsum("rki,rk,rkj->ij", jp, w, jp)
    g_p = np.einsum("rki,rk,rk->i", jp, w, res)
    w_rows = np.einsum("rki,rk,rkj->rij", jp, w, by_pos).reshape(len(res), -1)
    w_flat = np.zeros((n_e, n_p * 3))
    np.add.at(w_flat, ep.row_e, w_rows)
    if n_p and model.prior_info > 0:
        m, d = model.mapping(), model.prior_weights()
        u += m.T @ (d[:, None] * m)
        g_p += m.T @ (d * model.params(x).ravel())
    return _System(res, w, jp, v, g_e, u, g_p, w_flat.reshape(n_e, n_p, 3))


def _prior_cost(model: _Model, x: np.ndarray) -> float:
    if not model.n_params or model.prior_info <= 0:
        return 0.0
    return float((model.prior_weights() * model.params(x).ravel() ** 2).sum())


def _adjust(model: _Model, ep: _Epochs, x: np.ndarray, iterations: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """(free vector, positions) minimising the robust cost (and the prior, :attr:`_Model.prior_info`):
    a bundle adjustment -- Levenberg-Marquardt on iteratively reweighted normal equations, the
    epochs' 3 x 3 blocks eliminated by their Schur complement, so each step costs a small P x P
    solve. With no free parameters it re-solves the positions alone."""
    n_p = model.n_params
    free_z = np.isnan(ep.height)
    pos = ep.start.copy()
    pos[~free_z, 2] = ep.height[~free_z]
    lo = np.array([LIMITS[k, 0] for _, k in zip(*np.nonzero(model.column >= 0))])
    hi = np.array([LIMITS[k, 1] for _, k in zip(*np.nonzero(model.column >= 0))])
    order = np.argsort(model.column[model.column >= 0])
    lo, hi = lo[order], hi[order]
    lam = 1e-3
    res, *_ = model.predict(model.params(x), ep, pos)
    cost = _cost(res, pos, free_z) + _prior_cost(model, x)
    for _ in range(iterations):
        sy = _system(model, ep, x, pos, free_z)
        v_damped = sy.v + lam * np.einsum("nii->ni", sy.v)[:, :, None] * np.eye(3) + 1e-9 * np.eye(3)
        v_inv = np.linalg.inv(v_damped)
        if n_p:
            w_vinv = np.einsum("npi,nij->npj", sy.w_e, v_inv)
            schur = (sy.u + lam * np.diag(np.diag(sy.u)) + 1e-9 * np.eye(n_p)
                     - np.einsum("npj,nqj->pq", w_vinv, sy.w_e))
            rhs = -sy.g_p + np.einsum("npj,nj->p", w_vinv, sy.g_e)
            dx = np.linalg.solve(schur, rhs)
            de = -np.einsum("nij,nj->ni", v_inv, sy.g_e + np.einsum("npj,p->nj", sy.w_e, dx))
        else:
            dx = np.zeros(0)
            de = -np.einsum("nij,nj->ni", v_inv, sy.g_e)
        x_new = np.clip(x + dx, lo, hi)
        pos_new = pos + de
        res_new, *_ = model.predict(model.params(x_new), ep, pos_new)
        cost_new = _cost(res_new, pos_new, free_z) + _prior_cost(model, x_new)
        if cost_new < cost:
            done = cost - cost_new < 1e-7 * cost
            x, pos, cost, lam = x_new, pos_new, cost_new, max(lam / 3, 1e-7)
            if done:
                break
        else:
            lam *= 8
            if lam > 1e8:
                break
    return x, pos


@dataclass(frozen=True)
class _Posterior:
    """What the places say of each parameter, (A, 5) tables: the mean and sd after the prior
    (0 where held), and how many times the reports' own information overstates the places'."""

    mean: np.ndarray
    sd: np.ndarray
    overstated: float


def _posterior(model: _Model, ep: _Epochs, x: np.ndarray, pos: np.ndarray) -> _Posterior:
    """The fit ``x`` (no prior) shrunk, parameter by parameter, by the prior (PRIOR_SD), each
    one's variance from a sandwich over the places (:func:`_clusters`) -- their errors are
    correlated within, so a long stop counts as one sample of its place, not hundreds of
    reports -- with every other parameter free beside it: one the places cannot tell from
    another (a bias from a scale seen on one side of boresight) stays as uncertain as that."""
    n_p = model.n_params
    if not n_p:
        zero = np.zeros(model.free.shape)
        return _Posterior(zero, zero, 1.0)
    sy = _system(model, ep, x, pos, np.isnan(ep.height))
    v_inv = np.linalg.inv(sy.v + 1e-9 * np.eye(3))
    bread = sy.u - np.einsum("npi,nij,nqj->pq", sy.w_e, v_inv, sy.w_e) + 1e-9 * np.eye(n_p)
    rows = np.einsum("rkp,rk,rk->rp", sy.jp, sy.w, sy.res)
    ids, which = np.unique(ep.cluster[ep.row_e], return_inverse=True)
    scores = np.zeros((len(ids), n_p))
    np.add.at(scores, np.asarray(which).ravel(), rows)
    meat = scores.T @ scores * (len(ids) / max(len(ids) - 1, 1))
    inv = np.linalg.inv(bread)
    m = model.mapping()
    honest = np.maximum(np.diag(m @ inv @ meat @ inv.T @ m.T), 1e-18)
    naive = np.diag(m @ inv @ m.T)
    prior = np.tile(np.array(PRIOR_SD), model.free.shape[0]) ** 2
    sd = np.sqrt(1 / (1 / honest + 1 / prior))
    mean = (m @ x) * prior / (prior + honest)
    free = model.free.ravel() & (naive > 0)
    ratio = float(np.median(honest[free] / naive[free])) if free.any() else 1.0
    return _Posterior((mean * model.free.ravel()).reshape(model.free.shape),
                      (sd * model.free.ravel()).reshape(model.free.shape), max(ratio, 1.0))


def _fit(model: _Model, ep: _Epochs) -> np.ndarray:
    """The (A, 5) parameters that fit ``ep`` (positions free)."""
    x, _ = _adjust(model, ep, np.zeros(model.n_params))
    return model.params(x)


def _score(model: _Model, p: np.ndarray, ep: _Epochs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions re-solved with ``p`` fixed: (azimuth residual, ray miss m, anchor) of every row."""
    _, pos = _adjust(model.fixed_at(p), ep, np.zeros(0))
    res, rho, az, _, _ = model.predict(p, ep, pos)
    r = az - ep.az
    return r, rho * np.radians(r), ep.row_a


def _rms(values: np.ndarray, r: np.ndarray) -> float:
    keep = np.abs(r) <= OUTLIER_DEG
    return float(np.sqrt(np.mean(values[keep] ** 2))) if keep.any() else math.inf


def _thin(ep: _Epochs) -> _Epochs:
    n = len(ep.height)
    if n <= MAX_FIT_EPOCHS:
        return ep
    keep = np.zeros(n, bool)
    keep[np.linspace(0, n - 1, MAX_FIT_EPOCHS).round().astype(int)] = True
    return ep.subset(keep)


@dataclass
class _CrossValidated:
    folds: list[np.ndarray]  # (A, 5) of each fold's fit
    r: np.ndarray  # held-out azimuth residual of every row
    miss: np.ndarray
    row_a: np.ndarray


def _cross_validate(model: _Model, ep: _Epochs, progress: Callable[[str], None]) -> _CrossValidated:
    folds, rs, misses, anchors = [], [], [], []
    for k in range(FOLDS):
        p = _fit(model, _thin(ep.subset(ep.fold != k)))
        folds.append(p)
        r, miss, row_a = _score(model, p, ep.subset(ep.fold == k))
        rs.append(r)
        misses.append(miss)
        anchors.append(row_a)
        progress(".")
    return _CrossValidated(folds, np.concatenate(rs), np.concatenate(misses), np.concatenate(anchors))


def _check_coverage(ep: _Epochs, anchors: Sequence[Anchor]) -> None:
    """CalibrationError unless the tags covered the room and each anchor saw a span of azimuth."""
    origins = np.array([a.position for a in anchors], float)
    extent = float(min(np.ptp(origins[:, 0]), np.ptp(origins[:, 1])) or max(np.ptp(origins[:, :2], axis=0)))
    narrowest = float(np.sqrt(max(np.linalg.eigvalsh(np.cov(ep.start[:, :2].T))[0], 0.0)))
    if narrowest < SELF_MIN_SPREAD * extent:
        raise CalibrationError(
            f"the tags did not cover the room: their positions spread {narrowest:.2f} m across their narrowest "
            f"direction, {SELF_MIN_SPREAD * extent:.2f} m needed ({SELF_MIN_SPREAD:g} of the anchors' extent); "
            "a dwell at one point cannot tell an anchor's scale from the tag's position: walk the tags over the "
            "whole room, or calibrate on known points (--points)")
    for k, a in enumerate(anchors):
        seen = ep.az[ep.row_a == k]
        span = float(np.percentile(seen, 95) - np.percentile(seen, 5)) if len(seen) else 0.0
        if span < SELF_MIN_AZ_SPAN_DEG:
            raise CalibrationError(f"anchor {a.name} saw the tags over {span:.0f} deg of azimuth, "
                                   f"{SELF_MIN_AZ_SPAN_DEG:g}+ needed to tell its scale: walk the tags across its view")


ELEVATION_HELD = ("held by default: from anchors high on the walls its bias trades against the tag's height and "
                  "range, and fitted it followed one walk's multipath (--fit-elevation fits it)")


def _observable(ep: _Epochs, n_a: int, elevation: bool) -> tuple[np.ndarray, list[dict[str, str]]]:
    """(A, 5) which parameters the geometry (and ``elevation``: fit it at all) lets a fit
    determine, and why the rest are held."""
    held: list[dict[str, str]] = [{"yaw_offset_deg": "moves a near-level board's azimuths like its bias: fitted "
                                                     "as the bias"} for _ in range(n_a)]
    base_free = np.zeros((n_a, 5), bool)
    base_free[:, :2] = True
    known = ~np.isnan(ep.height)
    for k in range(n_a):
        if not elevation:
            held[k]["el_scale"] = held[k]["el_bias_deg"] = ELEVATION_HELD
            continue
        el_seen = ep.el[(ep.row_a == k) & known[ep.row_e]]
        el_span = float(np.percentile(el_seen, 95) - np.percentile(el_seen, 5)) if len(el_seen) >= SELF_MIN_EPOCHS else 0.0
        if el_span >= MIN_EL_SPAN_DEG:
            base_free[k, 3:] = True
        else:
            held[k]["el_scale"] = held[k]["el_bias_deg"] = (
                f"not observable: {len(el_seen)} angles of tags with a known height spanning {el_span:.0f} deg of "
                f"elevation ({MIN_EL_SPAN_DEG:g}+ over {SELF_MIN_EPOCHS}+ needed; give the tags' heights in the site "
                "file or --height)")
    return base_free, held


def _hold_undetermined(mean: np.ndarray, sd: np.ndarray, free: np.ndarray, held: list[dict[str, str]],
                       fitted: np.ndarray) -> None:
    """Hold (in ``free`` and ``held``, with its value and uncertainty) every parameter whose fit
    without the prior ran to its bound, whose uncertainty is over DATA_OVER_PRIOR of its
    prior's, or whose value is within Z_WRITE uncertainties of its default."""
    for k, j in zip(*np.nonzero(free)):
        lo, hi = LIMITS[j]
        value, prior = float(mean[k, j]), PRIOR_SD[j]
        got = f"{_show(j, value)} +- {_show_sd(j, float(sd[k, j]))}"
        if min(fitted[k, j] - lo, hi - fitted[k, j]) < 0.01 * (hi - lo):
            why = f"ran to its bound ({_show(j, float(fitted[k, j]))}): the data do not determine it"
        elif sd[k, j] > DATA_OVER_PRIOR * prior:
            why = (f"not determined: {got}, more than {DATA_OVER_PRIOR:g} of the prior's +- {_show_sd(j, prior)} "
                   "(the places the tags were do not pin it)")
        elif abs(value) < Z_WRITE * sd[k, j]:
            why = f"not determined: {got}, within {Z_WRITE:g} sd of its default"
        else:
            continue
        free[k, j] = False
        held[k][NAMES[j]] = why


def self_calibrate(site: Site, recordings: Sequence[Sequence[Bearing]], *,
                   height: float | None = None, models: str = "auto", elevation: bool = False,
                   hold: Collection[str] = (), progress: Callable[[str], None] = lambda _: None) -> SelfCalibration:
    """Each anchor's angle corrections from tags moving over the room (module docstring).

    ``height``: the height (m) of tags the site gives none (else each epoch's height is free
    about 1 +- 0.5 m); ``models``: "auto" scores the candidates per anchor on held-out epochs,
    "site" keeps the site's angle models (compression still scored); ``elevation``: fit each
    anchor's elevation scale and bias where observable (default: held), and then write only if
    locate's tracker foresees the recordings better with the calibration; ``hold``: parameters
    (NAMES) held on every anchor whatever the data say (bench/selfcal_parts.py: which parts
    help). CalibrationError when the epochs do not spread over the room or an anchor sees too
    narrow a span of azimuth."""
    unknown = set(hold) - set(NAMES)
    if unknown:
        raise ValueError(f"hold: unknown parameters {sorted(unknown)} (of {', '.join(NAMES)})")
    progress("gathering epochs")
    ep = _gather(site, recordings, height)
    anchors = list(site.anchors)
    n_a, n_e = len(anchors), len(ep.height)
    if n_e < SELF_MIN_EPOCHS:
        raise CalibrationError(_too_few(site, recordings, n_e))
    _check_coverage(ep, anchors)
    clusters = len(np.unique(ep.cluster))
    if clusters < MIN_CLUSTERS:
        raise CalibrationError(
            f"the tags were in {clusters} of the room's {CELL_M:g} m squares (each place is one sample however long "
            f"the tag stood there: its errors stay put), {MIN_CLUSTERS}+ needed to tell a board's error from a "
            "place's: take the tags to more places, or calibrate on known points (--points)")
    base_free, held = _observable(ep, n_a, elevation)
    for name in hold:
        base_free[:, NAMES.index(name)] = False
        for h in held:
            h[name] = "held by the caller"
    site_models = [a.angle_model for a in anchors]
    candidates = [c for c in _candidates(models, site_models, n_a) if not (c[2] and "az_compression" in hold)]
    # the uncalibrated site, scored on every epoch (each is held out of the fits that score it)
    plain = _Model(site, site_models, np.zeros((n_a, 5), bool))
    progress(f"{n_e} epochs ({int(ep.standing.sum())} standing) at {clusters} places, {FOLDS} folds; "
             "the uncalibrated site")
    r0, miss0, _ = _score(plain, plain.base, ep)
    scores = _model_scores(site, candidates, base_free, ep, progress)
    chosen_models, chosen_comp = _choose(anchors, scores, candidates, models, site_models)
    free = base_free.copy()
    free[:, 2] = chosen_comp
    for k in range(n_a):
        if not chosen_comp[k] and "az_compression" not in hold:
            held[k]["az_compression"] = "the angle model without compression won on held-out epochs"
    model, p, sd, cv = _final_fit(site, chosen_models, free, held, ep, progress)
    cross = _cross_kind(model, ep, r0, miss0, progress)
    held_out = HeldOut(_rms(r0, r0), _rms(cv.r, cv.r), _rms(miss0, r0), _rms(cv.miss, cv.r))
    fits = [_anchor_fit(k, a, p, sd, free, ep, cv, r0, chosen_models[k], held[k]) for k, a in enumerate(anchors)]
    changes = bool(free.any()) or chosen_models != site_models
    foresight = (math.nan, math.nan)
    el_fitted = bool(free[:, 3:].any())
    if held_out.improves and el_fitted:
        progress("; locate on the recordings")
        foresight = (_foresight(site, [Calibration()] * n_a, site_models, recordings),
                     _foresight(site, [f.calibration for f in fits], [f.angle_model for f in fits], recordings))
    progress("\n")
    return SelfCalibration(fits, n_e, held_out.az_rms_before_deg, held_out.az_rms_after_deg, held_out,
                           _verdict(held_out, cross, foresight, el_fitted, changes, clusters), scores,
                           foresight=foresight, held=_held_everywhere(held), cross_kind=cross, changes=changes)


def _held_everywhere(held: list[dict[str, str]]) -> dict[str, str]:
    """The parameters every anchor holds for one and the same reason (name -> reason)."""
    if not held:
        return {}
    return {name: why for name, why in held[0].items() if all(h.get(name) == why for h in held[1:])}


def _foresight(site: Site, calibrations: Sequence[Calibration], models: Sequence[str],
               recordings: Sequence[Sequence[Bearing]]) -> float:
    """The mean predictive log density of the recordings' reports under locate's tracker with
    these calibrations. The tracker carries each anchor's slow error as a state, so a
    calibration raises it only by explaining what persists (a board's scale, a mounting), not
    one walk's multipath, which the fit's own residuals cannot tell apart."""
    from rfhoming.host.locate import Locator

    calibrated = replace(site, anchors=tuple(replace(a, calibration=c, angle_model=m)
                                             for a, c, m in zip(site.anchors, calibrations, models)))
    total, count = 0.0, 0
    for recording in recordings:
        locator = Locator(calibrated)
        for reading in recording:
            locator.feed(reading)
        locator.flush()
        total += locator.log_density
        count += locator.reports_scored
    return total / count if count else -math.inf


Candidate = tuple[str, list[str], bool]
"""A candidate calibration: its label, each anchor's angle model, whether |azimuth| compression is fitted."""


def _candidates(models: str, site_models: list[str], n_a: int) -> list[Candidate]:
    if models == "site":
        return [("site", site_models, False), ("site+compression", site_models, True)]
    return [(m + ("+compression" if comp else ""), [m] * n_a, comp) for m, comp in CANDIDATES]


def _model_scores(site: Site, candidates: list[Candidate], base_free: np.ndarray, ep: _Epochs,
                  progress: Callable[[str], None]) -> dict[str, dict[str, float]]:
    """Anchor name -> candidate label -> its azimuth rms (deg) on held-out epochs."""
    scores: dict[str, dict[str, float]] = {a.name: {} for a in site.anchors}
    for label, names, comp in candidates:
        progress(f"; {label}")
        free = base_free.copy()
        free[:, 2] = comp
        cv = _cross_validate(_Model(site, names, free), ep, progress)
        for k, a in enumerate(site.anchors):
            mine = cv.row_a == k
            scores[a.name][label] = round(_rms(cv.r[mine], cv.r[mine]), 3)
    return scores


def _choose(anchors: list[Anchor], scores: dict[str, dict[str, float]], candidates: list[Candidate], models: str,
            site_models: list[str]) -> tuple[list[str], list[bool]]:
    """Each anchor's angle model and compression: its best candidate, if that beats the site's
    by MODEL_MARGIN, else the site's."""
    chosen_models, chosen_comp = [], []
    for k, a in enumerate(anchors):
        own = scores[a.name]
        site_label = "site" if models == "site" else site_models[k]
        best = min(own, key=own.__getitem__)
        pick = best if site_label not in own or own[best] < (1 - MODEL_MARGIN) * own[site_label] else site_label
        label, names, comp = next(c for c in candidates if c[0] == pick)
        chosen_models.append(names[k])
        chosen_comp.append(comp)
    return chosen_models, chosen_comp


def _final_fit(site: Site, chosen_models: list[str], free: np.ndarray, held: list[dict[str, str]], ep: _Epochs,
               progress: Callable[[str], None]) -> tuple[_Model, np.ndarray, np.ndarray, _CrossValidated]:
    """The chosen models fitted on every epoch, every parameter free; each one the places do not
    determine held (in ``free`` and ``held``: :func:`_posterior`, :func:`_hold_undetermined`);
    the rest fitted again with the prior (its weight raised by how much the reports overstate
    the places) and cross-validated. Returns the model, its parameters on every epoch, their
    uncertainties and the cross-validation."""
    progress("; final")
    thin = _thin(ep)
    model = _Model(site, chosen_models, free)
    x, pos = _adjust(model, thin, np.zeros(model.n_params))
    post = _posterior(model, thin, x, pos)
    _hold_undetermined(post.mean, post.sd, free, held, model.params(x))
    model = _Model(site, chosen_models, free)
    model.prior_info = post.overstated
    x, _ = _adjust(model, thin, np.zeros(model.n_params))
    progress("; held out")
    return model, model.params(x), np.where(free, post.sd, 0.0), _cross_validate(model, ep, progress)


def _kinds(ep: _Epochs, origins: np.ndarray) -> dict[str, np.ndarray]:
    """Kinds of data a calibration is judged on when fitted on the rest: standing and moving,
    and each half of the room (west/east, south/north of the anchors' middle), where a wall
    anchor sees its azimuths on the other side of boresight: an error odd in the angle, seen on
    one side only, is not a bias."""
    mid = (origins[:, :2].min(axis=0) + origins[:, :2].max(axis=0)) / 2
    x, y = ep.start[:, 0], ep.start[:, 1]
    return {"standing": ep.standing, "moving": ~ep.standing, "west half": x < mid[0], "east half": x >= mid[0],
            "south half": y < mid[1], "north half": y >= mid[1]}


def _cross_kind(model: _Model, ep: _Epochs, r0: np.ndarray, miss0: np.ndarray,
                progress: Callable[[str], None]) -> dict[str, HeldOut]:
    """Kind (:func:`_kinds`) -> the calibration fitted on the rest, judged on that kind; only
    kinds with SELF_MIN_EPOCHS / 2 epochs and two places or more, the rest as well."""
    out: dict[str, HeldOut] = {}
    if not model.n_params:
        return out
    for name, mine in _kinds(ep, model.origins).items():
        if not all(m.sum() >= SELF_MIN_EPOCHS // 2 and len(np.unique(ep.cluster[m])) >= 2 for m in (mine, ~mine)):
            continue
        progress(f"; {name}")
        p = _fit(model, _thin(ep.subset(~mine)))
        r, miss, _ = _score(model, p, ep.subset(mine))
        rows = mine[ep.row_e]
        out[name] = HeldOut(_rms(r0[rows], r0[rows]), _rms(r, r), _rms(miss0[rows], r0[rows]), _rms(miss, r))
    return out


def _anchor_fit(k: int, a: Anchor, p: np.ndarray, sd: np.ndarray, free: np.ndarray, ep: _Epochs, cv: _CrossValidated,
                r0: np.ndarray, model: str, held: dict[str, str]) -> AnchorFit:
    """Anchor ``k``'s calibration from the fit on every epoch ``p``, with its standard deviations
    and its held-out azimuth rms before and after."""
    cal = Calibration(0.0, float(math.exp(p[k, 0])), float(p[k, 1]), float(math.exp(p[k, 3])), float(p[k, 4]),
                      float(p[k, 2]))
    sigma = {NAMES[j]: round(float(sd[k, j] * (math.exp(p[k, j]) if j in (0, 3) else 1.0)), 4)
             for j in range(5) if free[k, j]}  # a log scale's sd times the scale: the scale's
    mine_before, mine_after = ep.row_a == k, cv.row_a == k
    return AnchorFit(a.name, cal, int(mine_before.sum()), _rms(r0[mine_before], r0[mine_before]),
                     _rms(cv.r[mine_after], cv.r[mine_after]), model, sigma, held)


def _verdict(held_out: HeldOut, cross: dict[str, HeldOut], foresight: tuple[float, float], el_fitted: bool,
             changes: bool, clusters: int) -> str:
    figures = f"held-out {held_out.said()}"
    for kind, h in cross.items():
        figures += f"; {kind}, fitted on the rest: {h.said()}"
    if not cross:
        figures += "; no other kind of data to judge it on (held-out places alone)"
    if not changes:
        return (f"not written: no parameter is determined by the data (the tags at {clusters} places, each a "
                f"{CELL_M:g} m square; each anchor's fit and why it is held: --verbose); take the tags over more of "
                "the room, or calibrate on known points (--points)")
    worse = [kind for kind, h in cross.items() if not h.not_worse]
    if held_out.improves and worse:
        return (f"not written: {figures}: worse on {' and '.join(worse)} than the uncalibrated site -- what it "
                "fitted belongs to one walk or one part of the room, not to the boards; walk the whole room, stand "
                "at places too, or calibrate on known points (--points)")
    if held_out.improves and not el_fitted:
        return f"{figures} (elevation held)"
    if held_out.improves and foresight[1] > foresight[0]:
        return f"{figures}; locate's tracker foresees the reports better ({foresight[0]:.3f} -> {foresight[1]:.3f})"
    if held_out.improves:
        return (f"not written: {figures}, but locate's tracker foresees the recordings' reports worse with it "
                f"(mean log density {foresight[0]:.3f} -> {foresight[1]:.3f}): what it fitted is this walk's "
                "multipath, which the tracker follows anyway, not the boards'; leave out --fit-elevation (elevation "
                "held), or calibrate on known points (--points)")
    return (f"not written: on held-out epochs it does not beat the uncalibrated site ({figures}; "
            f"{MIN_GAIN:.0%} cut needed): walk the tags over more of the room, or calibrate on known points (--points)")


def _show(j: int, value: float) -> str:
    return f"{math.exp(value):.3f}" if j in (0, 3) else f"{value:.3f}"


def _show_sd(j: int, sd: float) -> str:
    return f"{100 * sd:.1f} %" if j in (0, 3) else f"{sd:.2f}"


