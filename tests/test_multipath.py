"""Wall reflections (emulator/multipath.py): image-source geometry, S2's dishes and the
XPLR-AOA's bearing behind a wall, and determinism per seed."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings, strategies as st

from rfhoming.emulator.devices import arrivals
from rfhoming.emulator.multipath import CELL_M, Reflections
from rfhoming.emulator.radio import PathLossModel
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.emulator.world import Obstacle, Pose, World
from rfhoming.firmware.at86rf212_node import At86rf212NodeFirmware
from rfhoming.protocol.frames import AntennaSet, FrameDecoder

EMITTER = (2.0, 0.0)
BLOCK = Obstacle.rect(0.9, -0.6, 1.1, 0.6)  # between the robot at (0, 0) and the emitter
MIRROR = Obstacle.rect(-2.0, 1.5, 6.0, 1.7)  # a side wall to the robot's left
MODEL = PathLossModel(p0_dbm=-40.0, n=2.0, wall_loss_db=20.0, reflections=True)


def world(*obstacles: Obstacle) -> World:
    return World(Pose(0.0, 0.0, 0.0), [], list(obstacles), (-5.0, -5.0, 8.0, 5.0))


def test_a_side_wall_reflects_by_its_image() -> None:
    paths = world(BLOCK, MIRROR).reflected_paths(EMITTER, (0.0, 0.0))
    assert len(paths) == 1
    (p,) = paths
    image = (2.0, 3.0)  # the emitter mirrored in the wall's face y = 1.5
    assert p.distance_m == pytest.approx(math.dist(image, (0.0, 0.0)))
    assert p.direction_rad == pytest.approx(math.atan2(3.0, 2.0))
    assert (p.walls, p.reflections) == (0, 1)


def test_no_reflection_from_behind_a_face_or_past_its_end() -> None:
    w = world(MIRROR)
    assert not w.reflected_paths(EMITTER, (0.0, 2.5))  # receiver on the far side of the wall
    short = world(Obstacle.rect(-2.0, 1.5, 0.5, 1.7))  # the reflection point (1, 1.5) is off its end
    assert not short.reflected_paths(EMITTER, (0.0, 0.0))


def test_a_reflected_leg_through_a_wall_counts_it() -> None:
    # a wall between the mirror and the emitter: the reflected path crosses it on its first leg
    through = world(MIRROR, Obstacle.rect(1.6, 0.3, 1.8, 1.0))
    (p,) = through.reflected_paths(EMITTER, (0.0, 0.0))
    assert p.walls == 1


def test_bounds_reflect_only_when_asked() -> None:
    w = world()
    assert not w.reflected_paths(EMITTER, (0.0, 0.0))
    assert len(w.reflected_paths(EMITTER, (0.0, 0.0), bounds_reflect=True)) == 4


@settings(max_examples=60, deadline=None)
@given(st.floats(-4.5, 7.5), st.floats(-4.5, 1.4), st.integers(-90, 150), st.integers(-90, 28))
def test_every_reflected_path_obeys_the_mirror_law(sx: float, sy: float, i: int, j: int) -> None:
    """A reflected path is never shorter than the direct one, and it arrives from a point on
    the reflecting face (receiver-image line meets y = 1.5 between the wall's ends). Receivers
    on the 5 cm grid, where paths are traced from."""
    rx, ry = i * CELL_M, j * CELL_M
    for p in Reflections([MIRROR], None).paths((sx, sy), (rx, ry)):
        assert p.distance_m >= math.dist((sx, sy), (rx, ry)) - 1e-9
        assert math.sin(p.direction_rad) > 0
        x_at_face = rx + (1.5 - ry) * math.cos(p.direction_rad) / math.sin(p.direction_rad)
        assert -2.0 - 1e-6 <= x_at_face <= 6.0 + 1e-6


def test_paths_are_traced_once_per_receiver_cell() -> None:
    r = Reflections([BLOCK, MIRROR], None)
    here = r.paths(EMITTER, (0.0, 0.0))
    assert r.paths(EMITTER, (0.01, -0.01)) is here  # the same 5 cm cell
    assert r.paths(EMITTER, (0.2, 0.0)) != here


HEADING = math.radians(-20)  # the emitter 20° to the robot's left, the reflection 76°


def strongest_dish(reflections: bool) -> int:
    model = replace(MODEL, reflections=reflections)
    paths = arrivals(world(BLOCK, MIRROR), model, EMITTER, (0.0, 0.0), 0.0, walls=1)
    powers = At86rf212NodeFirmware(1).dish_powers([(d - HEADING, p) for d, p in paths])
    return max(range(4), key=powers.__getitem__)


def test_behind_a_wall_the_dish_facing_the_reflection_is_strongest() -> None:
    assert strongest_dish(reflections=False) == 0  # x1 faces the emitter through the wall
    assert strongest_dish(reflections=True) == 2  # y1 faces the side wall's reflection


def test_aoa_bearing_is_the_strongest_paths() -> None:
    model = replace(MODEL, reflections=True)
    behind = arrivals(world(BLOCK, MIRROR), model, EMITTER, (0.0, 0.0), 0.0, walls=1)
    assert max(behind, key=lambda p: p[1])[0] == pytest.approx(math.atan2(3.0, 2.0))
    clear = arrivals(world(MIRROR), model, EMITTER, (0.0, 0.0), 0.0, walls=0)
    assert max(clear, key=lambda p: p[1])[0] == pytest.approx(0.0)  # line of sight wins


def test_walled_scenarios_reflect_free_space_ones_do_not() -> None:
    assert load("s0-house").path_loss.reflections
    assert load("s2-d").path_loss.reflect_bounds
    assert not load("s0-open").path_loss.reflections
    assert not load("s2-a").path_loss.reflections
    assert not load("s4-survey").path_loss.reflections


async def dish_sets(seed: int) -> list[tuple[int, ...]]:
    em = Emulator(load("s2-d", seed=seed), transport="pipe", seed=seed, speed=math.inf)
    await em.start()
    await em.run(2.0)
    data = b""
    end = em.device("rss").link.host
    while end.pending():
        data += await end.read()
    await em.close()
    return [tuple(a.ed for a in f.antennas) for f in FrameDecoder().feed(data) if isinstance(f, AntennaSet)]


async def test_reflections_are_deterministic_per_seed() -> None:
    first, again, other = await dish_sets(3), await dish_sets(3), await dish_sets(4)
    assert len(first) > 20
    assert first == again != other
