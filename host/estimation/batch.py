"""The batched locate engine: every tag with fresh rays fixed at once per output tick (numpy).

The per-tag path (host/locate.py over :func:`anchors3d.locate`) spends most of its time in Python
per ray and per tag. Here the rays of all tags sit in flat arrays sorted by tag; the weighted
normal equations are segment sums (``np.bincount``), the 3x3 (or 2x2 with a known height) inverse
is by cofactors over all tags at once, and the IRLS of :func:`anchors3d._fit` (range weights,
Huber, behind-the-anchor penalty) runs on every tag together. What stays per tag is rare and is
handed to the reference :func:`anchors3d.locate` itself, so the answer is the same by construction:
a tag whose rays disagree (4+ rays and one beyond 2 sigma: the leave-one-out consensus) and a tag
seen by a two-sided anchor (the +-90 fold). tests/test_batch.py compares the two paths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfhoming.host.estimation.anchors3d import (
    HUBER_K,
    MIN_RANGE_M,
    SUSPECT_CHI2,
    Degenerate,
    Fix,
    Ray,
    locate,
    make_ray,
)
from rfhoming.host.estimation.spans import RATE_REPORTS, ray_span, stale_after, usual_gap
from rfhoming.host.site import Site, uncompress

SYSTEMATIC = 0.6
"""As host/locate.py: the part of an angle's error (of sigma_deg) a median does not average away."""

SLOTS = RATE_REPORTS + 4
"""Angles kept per (tag, anchor): the median is over the newest of them inside the window; the
usual gap (estimation/spans.py) wants RATE_REPORTS + 1 of them at or before the tick, the rest
are room for events stamped after it."""

INCONSISTENT_CHI2_PER_DOF = 25.0
"""A fix whose rays' chi-square per degree of freedom exceeds this is inconsistent (a site worker's
gate, ``BatchLocator(gate=...)``): its anchors disagree far beyond their sigmas -- an anchor moved,
a strong reflection on several, or a publisher sending false angles (a rogue gateway's made
6 x 10^5). Rays that agree give about 1 or below, a biased anchor several."""

MAX_PAIRS = 4_000_000
"""(tag, anchor) pairs tracked at most; events of a new pair beyond it are dropped and counted
(``overflow``). A tag becomes a row only with a pair, so this bounds the tags too."""


@dataclass(frozen=True)
class BatchFix:
    """All tags' fixes of one call: row k is tag k of the input (``ok`` False: no fix)."""

    points: np.ndarray  # (K, 3)
    covariances: np.ndarray  # (K, 3, 3)
    chi2: np.ndarray  # (K,)
    ok: np.ndarray  # (K,) bool
    suspect: np.ndarray  # (K,) bool: needs the reference's consensus (handed to locate())


def _segment_sums(values: np.ndarray, group: np.ndarray, k: int) -> np.ndarray:
    return np.bincount(group, weights=values, minlength=k)


def _solve(o: np.ndarray, u: np.ndarray, w: np.ndarray, g: np.ndarray, k: int, heights: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every tag's weighted LS point, inverse normal matrix and a non-degenerate flag (as _solve, _inverse)."""
    sw = _segment_sums(w, g, k)
    uu = {(i, j): _segment_sums(w * u[:, i] * u[:, j], g, k) for i in range(3) for j in range(i, 3)}
    a = np.empty((k, 3, 3))
    for (i, j), s in uu.items():
        a[:, i, j] = a[:, j, i] = -s
    for i in range(3):
        a[:, i, i] += sw
    uo = (u * o).sum(axis=1)
    b = np.stack([_segment_sums(w * o[:, i], g, k) - _segment_sums(w * u[:, i] * uo, g, k) for i in range(3)], 1)
    known = ~np.isnan(heights)
    h = np.where(known, heights, 0.0)
    # 3-D: cofactor inverse of every 3x3 at once
    co = np.empty((k, 3, 3))
    for r in range(3):
        for c in range(3):
            r1, r2 = [x for x in range(3) if x != c]
            c1, c2 = [x for x in range(3) if x != r]
            co[:, r, c] = (-1) ** (r + c) * (a[:, r1, c1] * a[:, r2, c2] - a[:, r1, c2] * a[:, r2, c1])
    det3 = (a[:, 0, :] * co[:, :, 0]).sum(axis=1)
    scale3 = np.max(np.abs(a[:, [0, 1, 2], [0, 1, 2]]), axis=1) ** 3
    ok3 = det3 > 1e-10 * scale3
    cov = co / np.where(ok3, det3, 1.0)[:, None, None]
    q = np.einsum("kij,kj->ki", cov, b)
    # known height: p = (x, y, h), the 2x2 system in x, y
    if known.any():
        b2 = b[:, :2] - a[:, :2, 2] * h[:, None]
        det2 = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        scale2 = np.maximum(np.abs(a[:, 0, 0]), np.abs(a[:, 1, 1])) ** 2
        ok2 = det2 > 1e-10 * scale2
        inv2 = np.stack([np.stack([a[:, 1, 1], -a[:, 0, 1]], 1), np.stack([-a[:, 1, 0], a[:, 0, 0]], 1)], 1)
        inv2 = inv2 / np.where(ok2, det2, 1.0)[:, None, None]
        q2 = np.einsum("kij,kj->ki", inv2, b2)
        cov2 = np.zeros((k, 3, 3))
        cov2[:, :2, :2] = inv2
        q = np.where(known[:, None], np.concatenate([q2, h[:, None]], axis=1), q)
        cov = np.where(known[:, None, None], cov2, cov)
        ok3 = np.where(known, ok2, ok3)
    return q, cov, ok3


def _residuals(point: np.ndarray, o: np.ndarray, u: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = point[g] - o
    along = (d * u).sum(axis=1)
    perp = np.sqrt(np.maximum((d * d).sum(axis=1) - along**2, 0.0))
    return along, perp


def fix_batch(o: np.ndarray, u: np.ndarray, sigma: np.ndarray, g: np.ndarray, heights: np.ndarray,
              iterations: int = 2) -> BatchFix:
    """Fix K tags at once from R rays: origins ``o`` (R, 3), unit directions ``u`` (R, 3), angle
    sigmas (R,) radians, ``g`` (R,) the tag row of each ray in 0..K-1, ``heights`` (K,) a known
    height or NaN. Rays without a fold (one-sided anchors); the same IRLS as anchors3d._fit."""
    k = len(heights)
    point, cov, ok = _solve(o, u, 1 / sigma**2, g, k, heights)
    for _ in range(iterations):
        along, perp = _residuals(point, o, u, g)
        ranges = np.maximum(along, MIN_RANGE_M)
        z = perp / (ranges * sigma)
        robust = np.where(z > HUBER_K, HUBER_K / np.maximum(z, 1e-12), 1.0)
        robust = np.where(along < 0, 1e-3, robust)
        point, cov, ok_i = _solve(o, u, robust / (ranges * sigma) ** 2, g, k, heights)
        ok &= ok_i
    along, perp = _residuals(point, o, u, g)
    z2 = (perp / (np.maximum(along, MIN_RANGE_M) * sigma)) ** 2 + np.where(along < 0, 1e6, 0.0)
    n = np.bincount(g, minlength=k)
    chi2 = _segment_sums(z2, g, k)
    z2max = np.zeros(k)
    np.maximum.at(z2max, g, z2)
    suspect = (n >= 4) & (z2max > SUSPECT_CHI2)
    dof = np.maximum(1, 2 * n - np.where(np.isnan(heights), 3, 2))
    cov = cov * np.maximum(1.0, chi2 / dof)[:, None, None]
    ok &= n >= 2
    return BatchFix(point, cov, chi2, ok, suspect)


def _median(values: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Per row the median over axis 1 of its first ``count`` finite values (the rest +inf): as
    statistics.median, the mean of the two middle ones for an even count."""
    ordered = np.sort(values, axis=1)
    rows = np.arange(len(count))
    middle: np.ndarray = (ordered[rows, (count - 1) // 2] + ordered[rows, count // 2]) / 2
    return middle


@dataclass(frozen=True)
class TagFix:
    """One tag's fix at tick ``t``; ``newest`` = the site time of the newest angle it rests on."""

    t: float
    tag: str
    fix: Fix
    newest: float
    quality: float
    tracked: bool = False
    new: bool = True  # rests on an angle no earlier tick of this tag had
    inconsistent: bool = False  # quality beyond the locator's gate: the raw fix, kept out of the track


class BatchLocator:
    """Angle events in (site time, anchor id, tag id, azimuth, elevation), all tags' fixes out per tick.

    The windowing of host/locate.py (per (tag, anchor) the median of the angles within ``window_s``
    of its newest, widened to RAY_REPORTS for a slow anchor, anchors heard within ``stale_s`` or a
    few of their usual gaps: estimation/spans.py, the same ray sigma), kept in flat arrays so a
    tick costs numpy calls, not Python per tag. Events must come in time order per (tag, anchor)
    (one gateway hears one anchor); tags not listed in the site are located too (a warehouse's
    tags come and go), without a known height. With ``gate`` (a chi-square per degree of freedom) a
    fix beyond it is returned raw and flagged ``inconsistent``, and never moves the tag's track."""

    def __init__(self, site: Site, calibrated: bool = True, track: bool = False, accel_psd: float = 1.0,
                 gate: float | None = None) -> None:
        self.site = site
        self.gate = math.inf if gate is None else gate
        self.tracker = BatchConstantVelocity(accel_psd) if track else None
        anchors = site.anchors
        self.anchor_index = {a.id: i for i, a in enumerate(anchors)}
        self.anchor_names = [a.name for a in anchors]
        self._anchors = anchors
        self.origins = np.array([a.position for a in anchors], float)
        self.rotations = np.array([a.rotation() for a in anchors])
        cal = [a.calibration if calibrated else None for a in anchors]
        self._bias = np.array([[c.az_bias_deg, c.el_bias_deg] if c else [0.0, 0.0] for c in cal])
        self._scale = np.array([[c.az_scale, c.el_scale] if c else [1.0, 1.0] for c in cal])
        self._compression = np.array([c.az_compression if c else 0.0 for c in cal])
        self.two_sided = np.array([a.two_sided for a in anchors], bool)
        self.tag_index: dict[str, int] = {}
        self.tags: list[str] = []
        self._heights: list[float] = []
        self._reported: list[float] = []  # per tag the newest angle time a tick has used
        self._n = 0  # (tag, anchor) pairs so far
        self._keys = np.zeros(0, np.int64)  # tag row * anchors + anchor index, sorted ...
        self._key_pair = np.zeros(0, np.int64)  # ... and the pair of each
        cap = 1024
        self._t = np.full((cap, SLOTS), -np.inf)
        self._ang = np.zeros((cap, SLOTS, 2))
        self._pos = np.zeros(cap, np.int64)
        self._ptag = np.zeros(cap, np.int64)
        self._panchor = np.zeros(cap, np.int64)
        self.counters = {"events": 0, "unknown_anchor": 0, "overflow": 0, "fixes": 0, "no_fix": 0,
                         "consensus": 0, "rejected_anchor": 0, "gated": 0, "inconsistent": 0, "outside": 0,
                         "restarts": 0}
        """outside, restarts: as Locator's -- fixes (and tracks, which then start again) withheld
        beyond the site's extent plus its margin."""
        self.extent = site.bounds()
        self._known = {t.id: t for t in site.tags}

    def _tag(self, tag: str) -> int:
        i = self.tag_index.get(tag)
        if i is None:
            i = self.tag_index[tag] = len(self.tags)
            self._reported.append(-math.inf)
            if self.tracker is not None:
                self.tracker.grow(i + 1)
            self.tags.append(tag)
            info = self._known.get(tag)
            self._heights.append(info.height if info is not None and info.height is not None else math.nan)
        return i

    def _new_pairs(self, keys: np.ndarray) -> None:
        """Pairs for these new (sorted, unique) keys, as many as MAX_PAIRS leaves room for."""
        keys = keys[:max(0, MAX_PAIRS - self._n)]
        n, m = self._n, len(keys)
        while n + m > len(self._pos):
            self._t = np.concatenate([self._t, np.full_like(self._t, -np.inf)])
            self._ang = np.concatenate([self._ang, np.zeros_like(self._ang)])
            self._pos, self._ptag, self._panchor = (np.concatenate([x, np.zeros_like(x)])
                                                    for x in (self._pos, self._ptag, self._panchor))
        ids = np.arange(n, n + m)
        self._ptag[ids], self._panchor[ids] = np.divmod(keys, len(self._anchors))
        keys_all, pairs_all = np.r_[self._keys, keys], np.r_[self._key_pair, ids]
        order = np.argsort(keys_all, kind="stable")
        self._keys, self._key_pair = keys_all[order], pairs_all[order]
        self._n = n + m

    def _lookup(self, keys: np.ndarray) -> np.ndarray:
        """The pair of each key, -1 where there is none."""
        if not len(self._keys):
            return np.full(len(keys), -1, np.int64)
        at = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
        return np.where(self._keys[at] == keys, self._key_pair[at], -1)

    def feed(self, rows: list[tuple[float, str, str, float, float]]) -> None:
        """Take angle events (site time, anchor id, tag id, azimuth deg, elevation deg)."""
        if not rows:
            return
        anchors: dict[str, int] = {}
        tags: dict[str, int] = {}
        a = [anchors.setdefault(r[1], len(anchors)) for r in rows]
        g = [tags.setdefault(r[2], len(tags)) for r in rows]
        self.feed_columns(np.array([r[0] for r in rows], float), list(anchors), np.array(a), list(tags), np.array(g),
                          np.array([r[3] for r in rows], float), np.array([r[4] for r in rows], float))

    def feed_columns(self, t: np.ndarray, anchors: list[str], a: np.ndarray, tags: list[str], g: np.ndarray,
                     az: np.ndarray, el: np.ndarray) -> None:
        """Take angle events as columns: event k at site time ``t[k]`` from anchor ``anchors[a[k]]``
        of tag ``tags[g[k]]`` (a site-bus batch as it is decoded); no Python per event."""
        if not len(t):
            return
        anc = np.array([self.anchor_index.get(x, -1) for x in anchors], np.int64)[a]
        known = anc >= 0
        self.counters["unknown_anchor"] += int((~known).sum())
        if not known.all():
            t, anc, g, az, el = t[known], anc[known], g[known], az[known], el[known]
            if not len(t):
                return
        used, g = np.unique(g, return_inverse=True)
        index, n_tags = self.tag_index, len(self.tags)
        new: dict[str, int] = {}  # the rows new tags will have if they get a pair (an id may come twice)
        rows = np.array([index[x] if x in index else new.setdefault(x, n_tags + len(new))
                         for x in map(tags.__getitem__, used.tolist())], np.int64)
        keys = rows[g] * len(self._anchors) + anc
        pid = self._lookup(keys)
        if (pid < 0).any():
            before = self._n
            self._new_pairs(np.unique(keys[pid < 0]))
            # only a tag with a pair becomes a row (heard by a known anchor, within MAX_PAIRS): the
            # pairs made are the lowest keys, so those tags are the first of the new ones
            made = self._ptag[before:self._n]
            for name in list(new)[:max(0, int(made.max()) + 1 - n_tags) if len(made) else 0]:
                self._tag(name)
            pid = self._lookup(keys)
            kept = pid >= 0
            self.counters["overflow"] += int((~kept).sum())
            if not kept.all():
                pid, t, az, el = pid[kept], t[kept], az[kept], el[kept]
                if not len(pid):
                    return
        self.counters["events"] += len(pid)
        ai = self._panchor[pid]
        ang = (np.stack([az, el], 1) - self._bias[ai]) / self._scale[ai]
        compressed = self._compression[ai] != 0  # as Calibration.correct, so a worker places tags as locate does
        if compressed.any():
            ang[compressed, 0] = uncompress(ang[compressed, 0], self._compression[ai][compressed])
        # the slot of each event: its pair's next, plus its rank among the batch's events of that pair
        order = np.argsort(pid, kind="stable")
        sp = pid[order]
        first = np.r_[0, np.flatnonzero(sp[1:] != sp[:-1]) + 1]
        counts = np.diff(np.r_[first, len(sp)])
        rank = np.arange(len(sp)) - np.repeat(first, counts)
        slot = (self._pos[sp] + rank) % SLOTS
        self._t[sp, slot] = np.asarray(t, float)[order]
        self._ang[sp, slot] = ang[order]
        self._pos[sp[first]] += counts

    def tick(self, t: float, only_new: bool = False) -> list[TagFix]:
        """Every tag with enough fresh anchors fixed at site time ``t``; with ``only_new`` only the
        tags with an angle no earlier tick used (a worker ticking faster than its tags talk)."""
        site = self.site
        n = self._n
        if n == 0:
            return []
        times = self._t[:n]
        upto = np.where(times <= t, times, -np.inf)
        last = upto.max(axis=1)
        # a pair's ring is in time order: its newest at or before t is `after` slots behind its
        # newest, and the usual gap (as Locator's) reaches `back` reports behind that
        after = (times > t).sum(axis=1)
        back = np.minimum(np.isfinite(upto).sum(axis=1) - 1, RATE_REPORTS).clip(0)
        gap = usual_gap(last, times[np.arange(n), (self._pos[:n] - 1 - after - back) % SLOTS], back)
        fresh: np.ndarray = last >= t - stale_after(gap, site.stale_s)
        if only_new:
            reported_np = np.array(self._reported)
            tag_newest = np.full(len(self.tags), -np.inf)
            np.maximum.at(tag_newest, self._ptag[:n], np.where(fresh, last, -np.inf))
            fresh &= (tag_newest > reported_np)[self._ptag[:n]]
        fresh = np.flatnonzero(fresh)
        if len(fresh) == 0:
            return []
        tt = upto[fresh]
        inside = tt > (last[fresh] - ray_span(gap[fresh], site.window_s))[:, None]
        count = inside.sum(axis=1)
        mean_t = np.where(inside, tt, 0.0).sum(axis=1) / count
        med = _median(np.where(inside[:, :, None], self._ang[fresh], np.inf), count)
        tag = self._ptag[fresh]
        anc = self._panchor[fresh]
        order = np.lexsort((anc, tag))  # by tag, then anchor in site order (as the per-tag path)
        fresh, med, count, tag, anc, mean_t = (x[order] for x in (fresh, med, count, tag, anc, mean_t))
        heights_all = np.array(self._heights)
        nrays = np.bincount(tag, minlength=len(self.tags))
        need = np.where(np.isnan(heights_all), 3, 2)
        enough = nrays >= need
        folded = np.zeros(len(self.tags), bool)
        folded[tag[self.two_sided[anc]]] = True
        keep = enough[tag]
        fresh, med, count, tag, anc, mean_t = (x[keep] for x in (fresh, med, count, tag, anc, mean_t))
        self.counters["no_fix"] += int(((nrays > 0) & ~enough).sum())
        if len(tag) == 0:
            return []
        sigma0 = site.sigma_deg
        sig_deg = np.hypot(sigma0 * 1.25 / np.sqrt(count), sigma0 * SYSTEMATIC)
        a = np.radians(-med[:, 0])
        e = np.radians(med[:, 1])
        c = np.cos(med[:, 0] * math.pi / 180) * np.cos(e)
        sigma = np.radians(sig_deg / np.maximum(c, 1 / 6))
        d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], 1)
        u = np.einsum("rij,rj->ri", self.rotations[anc], d)
        o = self.origins[anc]
        rows, g = np.unique(tag, return_inverse=True)  # the tags being fixed, ray -> row
        heights = heights_all[rows]
        result = fix_batch(o, u, sigma, g, heights)
        newest = np.full(len(rows), -np.inf)
        np.maximum.at(newest, g, last[fresh])
        t_fix = np.bincount(g, weights=mean_t) / np.bincount(g)  # the fix's time: its angles' mean
        starts = np.r_[0, np.flatnonzero(g[1:] != g[:-1]) + 1, len(g)]
        fixes: list[tuple[int, Fix, float, float, float]] = []
        names = [self.anchor_names[i] for i in anc.tolist()]
        rows_l = rows.tolist()
        hlist, suspect, ok = heights.tolist(), (result.suspect | folded[rows]).tolist(), result.ok.tolist()
        inside = self.extent.contains(result.points).tolist()  # beyond extent + margin: withheld, as Locator's
        newest_l, t_fix_l, chi2_l, starts_l = newest.tolist(), t_fix.tolist(), result.chi2.tolist(), starts.tolist()
        for k in range(len(rows)):
            lo, hi = starts_l[k], starts_l[k + 1]
            height = None if math.isnan(hlist[k]) else hlist[k]
            if suspect[k]:  # the reference does the rare cases itself
                self.counters["consensus"] += 1
                rays = [self._ray(int(anc[r]), med[r], float(sig_deg[r])) for r in range(lo, hi)]
                try:
                    fix = locate(rays, height=height)
                except Degenerate:
                    self.counters["no_fix"] += 1
                    continue
                inside[k] = self.extent.inside(fix.point)
            elif ok[k]:
                fix = Fix(result.points[k], result.covariances[k], tuple(names[lo:hi]), (), chi2_l[k])
            else:
                self.counters["no_fix"] += 1
                continue
            self.counters["fixes"] += 1
            self.counters["rejected_anchor"] += len(fix.rejected)
            if not inside[k]:
                self.counters["outside"] += 1
                continue
            dof = max(1, 2 * len(fix.used) - (3 if height is None else 2))
            fixes.append((k, fix, newest_l[k], t_fix_l[k], fix.chi2 / dof))
        reported = self._reported
        new = []
        for k, _, newest_k, _, _ in fixes:
            row = rows_l[k]
            new.append(newest_k > reported[row])
            reported[row] = max(reported[row], newest_k)
        bad = [f[4] > self.gate for f in fixes]
        self.counters["inconsistent"] += sum(bad)
        raw = [TagFix(t, self.tags[rows_l[k]], fix, newest_k, qual, False, is_new, is_bad)
               for (k, fix, newest_k, _, qual), is_new, is_bad in zip(fixes, new, bad)
               if self.tracker is None or is_bad]
        if self.tracker is None:
            return raw
        new = [is_new for is_new, is_bad in zip(new, bad) if not is_bad]
        fixes = [f for f, is_bad in zip(fixes, bad) if not is_bad]
        if not fixes:
            return raw
        which = np.array([rows[k] for k, *_ in fixes])
        ok = self.tracker.update(which, np.array([f[3] for f in fixes]), np.array([f.point for _, f, *_ in fixes]),
                                 np.array([f.covariance for _, f, *_ in fixes]))
        self.counters["gated"] += int((~ok).sum())
        live = ~np.isnan(self.tracker.t[which])
        points, covs = self.tracker.predicted(which[live], t)
        out = []
        kept = [(f, is_new) for f, is_new, keep in zip(fixes, new, live) if keep]
        at = np.array([k for (k, *_), _ in kept], np.int64)
        points = np.where(np.isnan(heights[at])[:, None], points, np.c_[points[:, :2], heights[at]])
        inside = self.extent.contains(points).tolist()
        for ((k, fix, newest_k, _, qual), is_new), point, cov, within in zip(kept, points, covs, inside):
            if not within:  # withheld, and the track starts again (as Locator's)
                self.counters["outside"] += 1
                self.counters["restarts"] += 1
                self.tracker.restart(rows[k])
                continue
            out.append(TagFix(t, self.tags[rows_l[k]], Fix(point, cov, fix.used, fix.rejected, fix.chi2), newest_k,
                              qual, True, is_new))
        return out + raw

    def _ray(self, ai: int, med: np.ndarray, sigma_deg: float) -> Ray:
        """The anchor's ray from its median angles: the boards' shared compression undone and
        read in its angle model, as locate's Locator does."""
        a = self._anchors[ai]
        az = float(uncompress(float(med[0]), self.site.az_compression))
        return make_ray(a.name, a.position, self.rotations[ai], az, float(med[1]), sigma_deg, a.two_sided,
                        a.angle_model)


class BatchConstantVelocity:
    """tracking.ConstantVelocity for every tag at once: rows of flat state arrays, the same
    transition, gate, restart after ``max_misses`` refusals and first-fix start."""

    def __init__(self, accel_psd: float = 1.0, gate: float = 25.0, max_misses: int = 3) -> None:
        self.q, self.gate, self.max_misses = accel_psd, gate, max_misses
        self.t = np.zeros(0)
        self.x = np.zeros((0, 6))
        self.p = np.zeros((0, 6, 6))
        self.misses = np.zeros(0, np.int64)

    def grow(self, n: int) -> None:
        if n > len(self.t):
            extra = max(n - len(self.t), len(self.t))
            self.t = np.r_[self.t, np.full(extra, np.nan)]
            self.x = np.concatenate([self.x, np.zeros((extra, 6))])
            self.p = np.concatenate([self.p, np.zeros((extra, 6, 6))])
            self.misses = np.r_[self.misses, np.zeros(extra, np.int64)]

    def restart(self, row: int) -> None:
        """Forget this row's track: its next fix starts it again."""
        self.t[row] = np.nan
        self.misses[row] = 0

    def _predict(self, rows: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt = np.maximum(0.0, t - self.t[rows])
        n = len(rows)
        f = np.tile(np.eye(6), (n, 1, 1))
        f[:, [0, 1, 2], [3, 4, 5]] = dt[:, None]
        q = np.zeros((n, 6, 6))
        for i in range(3):
            q[:, i, i] = dt**3 / 3 * self.q
            q[:, i, i + 3] = q[:, i + 3, i] = dt**2 / 2 * self.q
            q[:, i + 3, i + 3] = dt * self.q
        x = np.einsum("nij,nj->ni", f, self.x[rows])
        p = f @ self.p[rows] @ f.transpose(0, 2, 1) + q
        return x, p

    def predicted(self, rows: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        x, p = self._predict(rows, np.full(len(rows), t))
        return x[:, :3], p[:, :3, :3]

    def update(self, rows: np.ndarray, t: np.ndarray, z: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Fixes ``z`` (K, 3) with covariances ``r`` (K, 3, 3) made at ``t`` (K,) for tag rows ``rows``
        (each once); True where taken, False where gated out."""
        diag = np.diagonal(r, axis1=1, axis2=2)
        r = r + np.einsum("ni,ij->nij", np.where(diag <= 0, 1e-6, 0.0), np.eye(3))
        ok = np.ones(len(rows), bool)
        new = np.isnan(self.t[rows])
        if new.any():
            nr = rows[new]
            self.x[nr] = np.concatenate([z[new], np.zeros((len(nr), 3))], axis=1)
            self.p[nr] = 0.0
            self.p[nr, :3, :3] = r[new]
            self.p[nr, 3:, 3:] = np.eye(3)
            self.t[nr] = t[new]
        old = ~new
        if not old.any():
            return ok
        o = rows[old]
        x, p = self._predict(o, t[old])
        s = p[:, :3, :3] + r[old]
        innovation = z[old] - x[:, :3]
        d2 = np.einsum("ni,ni->n", innovation, np.linalg.solve(s, innovation[:, :, None])[:, :, 0])
        self.t[o] = np.maximum(t[old], self.t[o])
        gated = d2 > self.gate
        k = p[:, :, :3] @ np.linalg.inv(s)
        x_new = x + np.einsum("nij,nj->ni", k, innovation)
        p_new = p - k @ p[:, :3, :]
        self.x[o] = np.where(gated[:, None], x, x_new)
        self.p[o] = np.where(gated[:, None, None], p, p_new)
        self.misses[o] = np.where(gated, self.misses[o] + 1, 0)
        restart = o[gated & (self.misses[o] >= self.max_misses)]
        self.t[restart] = np.nan
        self.misses[restart] = 0
        ok[old] = ~gated
        return ok
