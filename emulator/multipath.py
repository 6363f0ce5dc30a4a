"""First-order specular reflections by image sources, for the radio models' NLOS paths.

A wall segment reflects a source into its mirror image; the reflected ray reaches a receiver
from the image's direction, over the image's distance, if the receiver and the source are both
on the segment's reflecting side and the line receiver-image meets the segment. Each reflected
path also crosses walls of its own (source to the reflection point, and on to the receiver).

Reflecting segments are the obstacles' edges (their outer faces) and, if asked, the world's
bounds (their inner faces, as a room's walls). Sources are static or slow, receivers move: the
images are kept per source position, and the reflected paths themselves per 5 cm cell of the
receiver (traced from the cell's centre: a direction off by at most 2° at 1 m), both in bounded
dicts, so a sample mostly costs a dict look-up; the direct path stays exact.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:  # world imports this module
    from rfhoming.emulator.world import Obstacle

CELL_M = 0.05
"""Receiver cell: its reflected paths are traced once, from its centre."""
CACHE_LIMIT = 4096


class Path(NamedTuple):
    distance_m: float
    direction_rad: float  # world angle, from the receiver toward where the path arrives from
    walls: int  # obstacles crossed
    reflections: int  # 0 direct, 1 reflected


class _Segment(NamedTuple):
    ax: float
    ay: float
    bx: float
    by: float
    nx: float  # unit normal toward the reflecting side
    ny: float
    owner: int  # obstacle index, −1 for a bound


def _segments(obstacles: list[Obstacle], bounds: tuple[float, float, float, float] | None) -> list[_Segment]:
    out = []
    for k, o in enumerate(obstacles):
        p = o.polygon
        area2 = sum(x1 * y2 - x2 * y1 for (x1, y1), (x2, y2) in zip(p, p[1:] + p[:1]))
        sign = 1.0 if area2 > 0 else -1.0  # counter-clockwise: the outer side is on the right
        for (ax, ay), (bx, by) in o.edges():
            length = math.hypot(bx - ax, by - ay)
            if length > 1e-9:
                out.append(_Segment(ax, ay, bx, by, sign * (by - ay) / length, -sign * (bx - ax) / length, k))
    if bounds is not None:
        x0, y0, x1, y1 = bounds
        for ax, ay, bx, by, nx, ny in ((x0, y0, x1, y0, 0, 1), (x1, y0, x1, y1, -1, 0),
                                        (x1, y1, x0, y1, 0, -1), (x0, y1, x0, y0, 1, 0)):
            out.append(_Segment(ax, ay, bx, by, float(nx), float(ny), -1))
    return out


class Reflections:
    """The first-order reflected paths between a source and a receiver in one static world."""

    def __init__(self, obstacles: list[Obstacle], bounds: tuple[float, float, float, float] | None) -> None:
        self.segments = _segments(obstacles, bounds)
        edges = [(e, k) for k, o in enumerate(obstacles) for e in o.edges()]
        self._a = np.array([e[0] for e, _ in edges], dtype=float).reshape(-1, 2)
        self._e = np.array([e[1] for e, _ in edges], dtype=float).reshape(-1, 2) - self._a
        self._owner = np.array([k for _, k in edges], dtype=int)
        self._images: dict[tuple[float, float], list[tuple[_Segment, float, float]]] = {}
        self._one_hot = np.zeros((len(edges), len(obstacles)), dtype=np.int32)
        self._one_hot[np.arange(len(edges)), self._owner] = 1
        self._paths: dict[tuple[int, int, int, int], tuple[Path, ...]] = {}

    def images(self, source: tuple[float, float]) -> list[tuple[_Segment, float, float]]:
        """(segment, image x, image y) for each segment whose reflecting side holds the source."""
        cached = self._images.get(source)
        if cached is None:
            if len(self._images) >= CACHE_LIMIT:
                self._images.clear()
            sx, sy = source
            cached = []
            for s in self.segments:
                h = (sx - s.ax) * s.nx + (sy - s.ay) * s.ny
                if h > 1e-6:
                    cached.append((s, sx - 2 * h * s.nx, sy - 2 * h * s.ny))
            self._images[source] = cached
        return cached

    def paths(self, source: tuple[float, float], receiver: tuple[float, float]) -> tuple[Path, ...]:
        """Every valid first-order reflected path (the direct path is the caller's), as seen from
        the centre of the receiver's cell."""
        key = (round(source[0] / CELL_M), round(source[1] / CELL_M),
               round(receiver[0] / CELL_M), round(receiver[1] / CELL_M))
        paths = self._paths.get(key)
        if paths is None:
            if len(self._paths) >= CACHE_LIMIT:
                self._paths.clear()
            paths = self._paths[key] = self._trace(source, (key[2] * CELL_M, key[3] * CELL_M))
        return paths

    def _trace(self, source: tuple[float, float], receiver: tuple[float, float]) -> tuple[Path, ...]:
        rx, ry = receiver
        valid = []
        for s, ix, iy in self.images(source):
            if (rx - s.ax) * s.nx + (ry - s.ay) * s.ny <= 1e-6:
                continue  # the receiver is behind the reflecting face
            u = _meet(rx, ry, ix, iy, s)
            if u is not None:
                valid.append((s, ix, iy, (s.ax + u * (s.bx - s.ax), s.ay + u * (s.by - s.ay))))
        if not valid:
            return ()
        walls = self._legs_walls(source, receiver, valid)
        return tuple(Path(math.hypot(ix - rx, iy - ry), math.atan2(iy - ry, ix - rx), w, 1)
                     for (s, ix, iy, _), w in zip(valid, walls))

    def _legs_walls(self, source: tuple[float, float], receiver: tuple[float, float],
                    valid: list[tuple[_Segment, float, float, tuple[float, float]]]) -> list[int]:
        """Obstacles each reflected path crosses (source to reflection point, and on to the
        receiver), apart from the one it reflects off: one vectorised pass over all legs."""
        if not len(self._a):
            return [0] * len(valid)
        starts = np.array([q for _, _, _, p in valid for q in (source, p)], dtype=float)
        ends = np.array([q for _, _, _, p in valid for q in (p, receiver)], dtype=float)
        owners = np.repeat([s.owner for s, _, _, _ in valid], 2)
        d = ends - starts
        w = self._a[None, :, :] - starts[:, None, :]
        e = self._e[None, :, :]
        denom = d[:, None, 0] * e[..., 1] - d[:, None, 1] * e[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
            v = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / denom
        hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (t < 1 - 1e-9) & (v >= 0) & (v <= 1)
        hit &= self._owner[None, :] != owners[:, None]
        crossed = (hit.astype(np.int32) @ self._one_hot) > 0  # legs × obstacles
        per_leg = crossed.sum(axis=1)
        return [int(per_leg[2 * i] + per_leg[2 * i + 1]) for i in range(len(valid))]


def _meet(rx: float, ry: float, ix: float, iy: float, s: _Segment) -> float | None:
    """Where on segment ``s`` (0..1) the line receiver-image crosses it; None off the segment."""
    dx, dy = ix - rx, iy - ry
    ex, ey = s.bx - s.ax, s.by - s.ay
    denom = dx * ey - dy * ex
    if abs(denom) < 1e-12:
        return None
    u = ((s.ax - rx) * dy - (s.ay - ry) * dx) / denom
    return u if 0.0 <= u <= 1.0 else None
