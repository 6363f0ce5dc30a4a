"""The world's geometry queries skip work (far edges, far obstacles, numpy for a few edges) but
answer exactly as the plain vectorised tests over every edge do: a lockstep run must not change
by a bit. Each fast query is compared with that reference on random worlds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfhoming.emulator.scenario import load
from rfhoming.emulator.world import Obstacle, Pose, World


def reference_cast(world: World, origin: tuple[float, float], angles: np.ndarray, max_range: float) -> np.ndarray:
    """Every beam against every edge."""
    o = np.asarray(origin, float)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]
    e = (world._b - world._a)[None, :, :]
    w = (world._a - o)[None, :, :]
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / denom
    valid = (np.abs(denom) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    t = np.where(valid, t, np.inf).min(axis=1)
    return np.where(t <= max_range, t, np.inf)


def near(world: World, test: object) -> list[int]:
    return [k for k, box in enumerate(world._boxes) if test(box)]  # type: ignore[operator]


def reference_collides(world: World, x: float, y: float, radius: float) -> bool:
    """The disc test on every edge of the obstacles near, in numpy."""
    ks = near(world, lambda b: b[0] - radius <= x <= b[2] + radius and b[1] - radius <= y <= b[3] + radius)
    if not ks:
        return False
    if any(world.obstacles[k].contains(x, y) for k in ks):
        return True
    edges = np.isin(world._owner, ks)
    a, e = world._a[edges], world._b[edges] - world._a[edges]
    p = np.array([x, y])
    s = np.clip(np.einsum("ij,ij->i", p - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-12), 0, 1)
    return bool(np.min(np.hypot(*(a + s[:, None] * e - p).T)) < radius)


def reference_crossed(world: World, p: tuple[float, float], q: tuple[float, float]) -> int:
    """Distinct obstacles the segment crosses, every edge tested."""
    a, e, owner = world._a, world._b - world._a, world._owner
    d = np.subtract(q, p)
    denom = d[0] * e[:, 1] - d[1] * e[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = a - np.asarray(p, float)
        t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom
        u = (w[:, 0] * d[1] - w[:, 1] * d[0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    return len(set(owner[hit].tolist()))


def random_world(rng: np.random.Generator) -> World:
    obstacles = []
    for _ in range(int(rng.integers(3, 25))):
        x, y = rng.uniform(-15, 15, 2)
        if rng.random() < 0.5:
            w, h = rng.uniform(0.05, 4, 2)
            obstacles.append(Obstacle.rect(x, y, x + w, y + h))
        else:  # a convex polygon: points on a circle in order
            angles = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 7))))
            r = rng.uniform(0.2, 2)
            obstacles.append(Obstacle([(x + r * math.cos(a), y + r * math.sin(a)) for a in angles]))
    return World(Pose(0, 0, 0), [], obstacles, (-20, -20, 20, 20))


@pytest.mark.parametrize("seed", range(40))
def test_cast_equals_every_beam_against_every_edge(seed: int) -> None:
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    for _ in range(5):
        origin = tuple(rng.uniform(-18, 18, 2))
        angles = np.linspace(-math.pi / 2, math.pi / 2, 181) + rng.uniform(-math.pi, math.pi)
        max_range = float(rng.choice([0.5, 3.0, 8.0, 100.0]))
        got, want = world.cast(origin, angles, max_range), reference_cast(world, origin, angles, max_range)
        assert np.array_equal(got, want), (origin, max_range)


def test_cast_on_the_house_equals_the_reference_where_the_robot_goes() -> None:
    world = load("s0-house", seed=1).world
    rng = np.random.default_rng(7)
    for x, y, th in zip(rng.uniform(-5.8, 5.8, 300), rng.uniform(-5.8, 5.8, 300), rng.uniform(-3.2, 3.2, 300)):
        angles = np.linspace(-math.pi / 2, math.pi / 2, 181) + th
        assert np.array_equal(world.cast((x, y), angles, 8.0), reference_cast(world, (x, y), angles, 8.0))


@pytest.mark.parametrize("seed", range(20))
def test_collides_answers_as_the_vectorised_test(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    world = random_world(rng)
    radius = float(rng.uniform(0.1, 0.5))
    points = list(zip(rng.uniform(-18, 18, 400), rng.uniform(-18, 18, 400)))
    # and points right at the disc's reach from an edge, where rounding decides
    for o in world.obstacles[:5]:
        (ax, ay), (bx, by) = o.edges()[0]
        nx, ny = by - ay, ax - bx
        norm = math.hypot(nx, ny)
        for gap in (radius - 1e-12, radius, radius + 1e-12, radius * (1 + 1e-15)):
            mx, my = (ax + bx) / 2, (ay + by) / 2
            points += [(mx + nx / norm * gap, my + ny / norm * gap), (mx - nx / norm * gap, my - ny / norm * gap)]
    for x, y in points:
        assert world.collides(x, y, radius) == reference_collides(world, x, y, radius), (x, y, radius)


@pytest.mark.parametrize("seed", range(20))
def test_obstacles_crossed_counts_as_every_edge_tested(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    world = random_world(rng)
    for _ in range(300):
        p, q = tuple(rng.uniform(-18, 18, 2)), tuple(rng.uniform(-18, 18, 2))
        assert world.obstacles_crossed(p, q) == reference_crossed(world, p, q), (p, q)


def test_scan_ranges_in_wire_form_all_at_once_as_one_by_one() -> None:
    from rfhoming.emulator.devices import scan_mm

    rng = np.random.default_rng(3)
    ranges = np.concatenate([rng.uniform(0, 9, 2000), rng.integers(0, 9000, 500) / 1000 + 0.0005,  # halves
                             [0.0, 0.0004, 0.0005, 0.0015, 65.535, 65.5355, 1e9, np.inf, np.inf]])
    rng.shuffle(ranges)
    for chunk in np.array_split(ranges, 13):
        one_by_one = tuple(0 if not math.isfinite(r) else max(1, min(65535, round(float(r) * 1000))) for r in chunk[:255])
        assert scan_mm(chunk) == one_by_one
