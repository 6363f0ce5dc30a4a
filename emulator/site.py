"""A site at warehouse scale: N ceiling anchors on G gateways, M moving tags, seeded (no ptys).

``site-64x1000``: 64 anchors on an 8 x 8 grid 6 m apart, 6 m up, boresight straight down, four per
gateway (16 gateways), 1,000 tags at 1 m height walking at 0.5-1.5 m/s and bouncing off the walls,
each heard at ``tag_rate_hz`` by every anchor that sees it within ``max_off_boresight_deg``. Each
board gets its own error from the seed as in emulator/anchors.py (a fixed bias N(0, bias_deg) on each
angle) plus N(0, sigma_deg) noise per event, and reports integer degrees like the firmware. Each
gateway's clock is off the site's by a seeded offset (up to +-``clock_spread_s``): the worker has to
measure it.

Trajectories are closed-form (a triangle wave folds the straight walk into the hall), so the truth
at any time is :meth:`SiteScenario.truth` without stepping a world, and a generator can run at any
wall-clock rate. What the emulated gateways do with the rows (publish them) is the application's.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from rfhoming.protocol.errors import Error


class SiteScenarioError(Error, ValueError):
    """A site scenario name that is not ``site-NxM``."""


@dataclass(frozen=True)
class SiteAnchor:
    name: str
    id: str
    gateway: str
    position: tuple[float, float, float]
    pitch_deg: float


def _rotation_down(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Board -> world, Rz(yaw) Ry(-pitch) (roll 0): the convention of emulator/anchors.py."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    ry = np.array([[math.cos(p), 0, -math.sin(p)], [0, 1, 0], [math.sin(p), 0, math.cos(p)]])
    board_to_world: np.ndarray = rz @ ry
    return board_to_world


class SiteScenario:
    def __init__(self, anchors: int = 64, tags: int = 1000, *, seed: int = 1, spacing_m: float = 6.0,
                 ceiling_m: float = 6.0, tag_height_m: float = 1.0, anchors_per_gateway: int = 4,
                 tag_rate_hz: float = 10.0, sigma_deg: float = 2.0, bias_deg: float = 0.5,
                 max_off_boresight_deg: float = 65.0, clock_spread_s: float = 0.5) -> None:
        rng = np.random.default_rng(seed)
        cols = math.ceil(math.sqrt(anchors))
        rows = math.ceil(anchors / cols)
        self.size = (cols * spacing_m, rows * spacing_m)
        self.anchors = [SiteAnchor(f"a{i:03d}", f"A{i:05d}", f"gw{i // anchors_per_gateway:02d}",
                                   ((i % cols + 0.5) * spacing_m, (i // cols + 0.5) * spacing_m, ceiling_m), -90.0)
                        for i in range(anchors)]
        self.anchor_ids = [a.id for a in self.anchors]
        self.gateways = sorted({a.gateway for a in self.anchors})
        self.clock_offsets = {g: float(rng.uniform(-clock_spread_s, clock_spread_s)) for g in self.gateways}
        self.tags = [f"T{i:05d}" for i in range(tags)]
        self.tag_height_m = tag_height_m
        self.tag_rate_hz = tag_rate_hz
        self.sigma_deg = sigma_deg
        self._cos_limit = math.cos(math.radians(max_off_boresight_deg))
        self._o = np.array([a.position for a in self.anchors])
        self._rt = np.array([_rotation_down(0.0, a.pitch_deg).T for a in self.anchors])  # world -> board
        self._bias = rng.normal(0.0, bias_deg, (anchors, 2))
        self._start = rng.uniform([0, 0], self.size, (tags, 2))
        speed = rng.uniform(0.5, 1.5, tags)
        heading = rng.uniform(0, 2 * math.pi, tags)
        self._v = np.stack([speed * np.cos(heading), speed * np.sin(heading)], 1)
        self._phase = rng.uniform(0, 1 / tag_rate_hz, tags)
        self._rng = rng
        self._gw_of = np.array([self.gateways.index(a.gateway) for a in self.anchors])

    @classmethod
    def named(cls, name: str, **kw: float) -> SiteScenario:
        """``site-64x1000`` = 64 anchors, 1,000 tags."""
        m = re.fullmatch(r"site-(\d+)x(\d+)", name)
        if not m or int(m[1]) < 3 or int(m[2]) < 1:
            raise SiteScenarioError(f"{name!r} is not a site scenario: write site-NxM (N >= 3 anchors, M >= 1 tags)")
        return cls(int(m[1]), int(m[2]), **kw)  # type: ignore[arg-type]

    def truth(self, t: float, which: np.ndarray | None = None) -> np.ndarray:
        """Tag positions (M, 3) at site time ``t`` (or only rows ``which``)."""
        rows = np.arange(len(self.tags)) if which is None else np.asarray(which)
        return self._at(np.full(len(rows), t), rows)

    def _at(self, times: np.ndarray, rows: np.ndarray) -> np.ndarray:
        size = np.array(self.size)
        raw = np.mod(self._start[rows] + self._v[rows] * times[:, None], 2 * size)
        xy = np.where(raw > size, 2 * size - raw, raw)
        return np.concatenate([xy, np.full((len(xy), 1), self.tag_height_m)], axis=1)

    def columns(self, t0: float, t1: float) -> dict[str, tuple[np.ndarray, ...]]:
        """Every angle event of site time [t0, t1) per gateway as columns (time on that gateway's
        clock, anchor row of :attr:`anchor_ids`, tag row of :attr:`tags`, azimuth, elevation), in
        time order."""
        period = 1 / self.tag_rate_hz
        k0 = np.ceil((t0 - self._phase) / period)
        k1 = np.ceil((t1 - self._phase) / period)
        reps = (k1 - k0).astype(int)
        empty = (np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        if reps.sum() == 0:
            return {g: empty for g in self.gateways}
        who = np.repeat(np.arange(len(self.tags)), reps)
        first = np.repeat(k0, reps)
        step = np.arange(len(who)) - np.repeat(np.cumsum(reps) - reps, reps)
        times = self._phase[who] + (first + step) * period
        p = self._at(times, who)
        d = p[:, None, :] - self._o[None]  # (E, N, 3)
        board = np.einsum("nij,enj->eni", self._rt, d)
        dist = np.linalg.norm(board, axis=2)
        seen = board[:, :, 0] / dist >= self._cos_limit
        e_idx, a_idx = np.nonzero(seen)
        b = board[e_idx, a_idx]
        az = -np.degrees(np.arctan2(b[:, 1], b[:, 0]))
        el = np.degrees(np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1])))
        noise = self._rng.normal(0.0, self.sigma_deg, (len(az), 2))
        ang = np.clip(np.rint(np.stack([az, el], 1) + self._bias[a_idx] + noise), -90, 90)
        gw = self._gw_of[a_idx]
        offsets = np.array([self.clock_offsets[g] for g in self.gateways])
        stamp = times[e_idx] + offsets[gw]
        order = np.argsort(times[e_idx], kind="stable")
        e_idx, a_idx, gw, stamp, ang = e_idx[order], a_idx[order], gw[order], stamp[order], ang[order]
        out: dict[str, tuple[np.ndarray, ...]] = {}
        for i, g in enumerate(self.gateways):
            k = gw == i
            out[g] = (stamp[k], a_idx[k], who[e_idx[k]], ang[k, 0], ang[k, 1])
        return out

    def events(self, t0: float, t1: float) -> dict[str, list[tuple[float, str, str, float, float]]]:
        """:meth:`columns` as rows (time, anchor id, tag id, azimuth, elevation) per gateway."""
        return {g: [(t, self.anchor_ids[a], self.tags[k], int(az), int(el)) for t, a, k, az, el in
                    zip(*(c.tolist() for c in cols))] for g, cols in self.columns(t0, t1).items()}
