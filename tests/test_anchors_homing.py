"""Done-when of homing on fixed anchors: a robot carrying its own tag, located by the kit's four
biased wall anchors (through the emulator's bytes, in lockstep), drives to the target tag."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from loops import loop_on
from synthetic_angles import walk

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.emulator import scenario as scenarios
from rfhoming.emulator.runtime import Emulator
from rfhoming.host import site as sites
from rfhoming.host.homing.anchors import AnchorsController, align
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.types import Pose

SITE = Path(__file__).resolve().parents[1] / "docs" / "sites" / "kit-home.toml"


@settings(max_examples=30)
@given(st.floats(-3.1, 3.1), st.floats(-5, 5), st.floats(-5, 5), st.integers(0, 2**31))
def test_align_recovers_a_rotated_shifted_frame(phi, tx, ty, seed):
    rng = np.random.default_rng(seed)
    odo = rng.uniform(-2, 2, (20, 2))
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    world = odo @ rot.T + np.array([tx, ty])
    got_phi, got_tau = align(odo, world)
    assert abs(math.remainder(got_phi - phi, 2 * math.pi)) < 1e-9
    assert np.allclose(got_tau, [tx, ty], atol=1e-9)


def test_the_controller_locates_on_the_loops_clock_not_the_drivers_stamp():
    """A Bearing carries the host time its bytes arrived; in lockstep (and with any host delay)
    that is not the robot time the loop runs on, so the controller's fixes, and the poses it pairs
    them with, must be on the loop's clock: the target's fix is at a loop time."""
    site = sites.load(SITE)
    standing = walk(1, waypoints=[(9.5, 4.2), (9.5, 4.2)], dwell_s=3.0, white_deg=1.0, slow_deg=0.0, outliers=0.0,
                    site=site)
    controller = AnchorsController(site)
    for b in standing.events:
        controller.on_input(b.t, Pose(0.0, 0.0, 0.0), b._replace(t=b.t + 1000.0))  # the host clock far ahead
    assert controller.target_world is not None
    assert controller.target_t <= standing.events[-1].t


async def _home(seed: int):
    sc = scenarios.load("kit-home", seed=seed)
    em = Emulator(sc, transport="pipe", seed=seed, lockstep=True, lockstep_timeout=2.0)
    await em.start()
    world = asyncio.create_task(em.run())
    site = sites.load(SITE)
    anchors = [PipePort(a.name, em.device(a.name).link.host) for a in site.anchors]
    base = PipePort("base", em.device("base").link.host)
    try:
        outcome = await asyncio.wait_for(loop_on("anchors", base, anchors, Config().for_lockstep(), site=site).run(), 300)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    return outcome, em.world.robot, sc.world.targets[0].position


@pytest.mark.parametrize("seed", [1, pytest.param(3, marks=pytest.mark.slow)])
def test_robot_homes_on_the_target_located_by_the_anchors(seed):
    """Uncalibrated anchors: the goal is off by their bias (0.1-0.6 m over seeds 1-4)."""
    outcome, robot, target = asyncio.run(_home(seed))
    assert outcome.arrived, outcome.summary()
    assert math.dist((robot.x, robot.y), target) < 0.8
    assert outcome.robot_time_s < 60 and outcome.stale_stops == 0


RFHOMING = [sys.executable, "-m", "rfhoming"]


@pytest.mark.slow
def test_run_controller_anchors_homes_through_the_emulators_ptys(tmp_path, emulated, cli):
    links = tmp_path / "links"
    links.mkdir()
    site = tmp_path / "site.toml"
    site.write_text(SITE.read_text().replace("/tmp/rfhoming-kit/", f"{links}/"))
    with emulated("kit-home", "--seed", "1", "--lockstep", "--radio", "ideal", link_dir=links):  # off by the bias alone
        run = cli("run", "--controller", "anchors", "--site", str(site), "--base", f"base:{links}/base", timeout_s=180)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout.splitlines()[-1])
    assert summary["arrived"] and math.dist(summary["pose"][:2], (9.5, 4.2)) < 0.8


def test_run_controller_anchors_says_what_is_missing(tmp_path):
    no_site = subprocess.run([*RFHOMING, "run", "--controller", "anchors", "--base", "base:/dev/null"],
                             capture_output=True, text=True, timeout=60)
    assert no_site.returncode == 2 and "--site SITE.toml" in no_site.stderr
    roleless = tmp_path / "site.toml"
    roleless.write_text(SITE.read_text().replace('role = "target"\n', ""))
    missing = subprocess.run([*RFHOMING, "run", "--controller", "anchors", "--site", str(roleless),
                              "--base", "base:/dev/null"], capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and 'role = "target"' in missing.stderr
