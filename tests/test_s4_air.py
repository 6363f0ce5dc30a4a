"""S4 from the air: a MAVLink copter carrying three BLE scanners flies S4's lawn-mower, localises
the beacons with S4's EKF and holds over one (`rfhoming demo --scenario s4-air`); the summary
holds S4's metric beside the thesis's."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.estimation.beacon import S4Model, jacobian, measure
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.s4_air import S4Params, SurveyController, lawnmower
from rfhoming.host.homing.types import ParamsError, Pose


def test_the_pattern_is_s4s_lawnmower() -> None:
    corners = lawnmower([0.0, 0.0, 4.0, 8.0], 0.8)
    assert len(corners) == 12 and corners[:4] == [(0.0, 0.0), (0.0, 8.0), (0.8, 8.0), (0.8, 0.0)]
    assert corners[-1] == pytest.approx((4.0, 0.0))


def test_the_receivers_ride_on_the_vehicle() -> None:
    survey = SurveyController(S4Params())
    facing_y = survey.receivers(Pose(1.0, 2.0, math.pi / 2))  # x ahead is +y, y left is -x
    assert facing_y[1] == pytest.approx((1.0 + 0.2, 2.0 + 0.4))  # node 2 at (0.4, -0.2) on the vehicle


@pytest.mark.parametrize("init", ["area", "circles"])
def test_the_survey_flies_the_pattern_then_holds_over_the_beacon_it_localised(init: str) -> None:
    """The controller alone on S4's model (a seeded simulation, no emulator): it flies every
    corner, localises the beacons within S4's 95 % bound, flies to the one asked for and holds;
    each beacon's filter starting at the area's centre or from S4's initialiser."""
    params = S4Params(home_on="BE0000000001", search_speed=0.4, hold_s=1.0, init=init)
    survey = SurveyController(params)
    rng = np.random.default_rng(4)
    beacons = {"BE0000000000": (1.2, 2.5), "BE0000000001": (3.1, 5.6)}
    bias = {(a, n): rng.choice([-2.0, 2.0]) for a in beacons for n in (1, 2, 3)}
    x, y, th, t, dt = 0.0, 0.0, math.pi / 2, 0.0, 0.1
    corners, decision = set(), None
    for _ in range(20_000):
        pose = Pose(x, y, th)
        for node, p in zip((1, 2, 3), survey.receivers(pose)):
            for address, b in beacons.items():
                d = math.sqrt(math.dist(p, b) ** 2 + params.height_m**2)
                if d < 4.0:
                    rssi = params.p0_dbm - 20 * math.log10(d) + bias[address, node] + rng.normal(0, math.sqrt(5))
                    survey.on_input(t, pose, BleRssi(t, node, address, round(rssi)))
        decision = survey.decide(pose)
        corners.add(survey.next_wp)
        if decision.arrived:
            break
        x, y, th = x + decision.v * math.cos(th) * dt, y + decision.v * math.sin(th) * dt, th + decision.w * dt
        t += dt
    assert decision is not None and decision.arrived and survey.phase == "holding"
    assert corners == set(range(1, len(survey.waypoints) + 1))  # every corner of the pattern (the first is the start)
    assert math.dist((x, y), beacons["BE0000000001"]) < 0.65
    found = survey.estimate()
    assert set(found["beacons"]) == set(found["smoothed"]) == set(beacons)
    assert all(math.dist(found["smoothed"][a], b) < 0.65 for a, b in beacons.items())


def test_a_beacon_to_hold_over_is_an_address_and_ble_once_is_once() -> None:
    """A home_on with colons never matches what the scanners report: refused, not hovered on;
    and --ble more than once is a survey's alone (another controller would mix receivers)."""
    with pytest.raises(ParamsError, match="12 hex digits"):
        SurveyController(S4Params(home_on="BE:00:00:00:00:01"))
    done = subprocess.run([sys.executable, "-m", "rfhoming", "run", "--controller", "trilat", "--ble", "/dev/null",
                           "--ble", "/dev/null", "--base", "/dev/null"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.strip().count("\n") == 0 and "--ble is given once" in done.stderr


def test_receivers_that_fly_hear_the_beacon_at_the_3d_distance() -> None:
    model = S4Model(height_m=1.0)
    x = np.array([[0.0, 0.0, 3.0, 0.0, 0.0, 4.0, 0.0, 0.0]])  # receivers at (0,0), (3,0), (0,4); beacon at 0
    rssi = measure(model, x)[0, 6:]
    assert rssi == pytest.approx(model.p0_dbm - 20 * np.log10(np.sqrt(np.array([0.0, 9.0, 16.0]) + 1.0)))
    step = 1e-6 * np.eye(8)
    numeric = np.stack([(measure(model, x + step[i]) - measure(model, x - step[i]))[0] / 2e-6 for i in range(8)], 1)
    assert jacobian(model, x)[0] == pytest.approx(numeric, abs=1e-5)
    assert model.ground_range(rssi) == pytest.approx([0.0, 3.0, 4.0], abs=1e-6)


def test_the_scenario_flies_a_mavlink_copter_carrying_the_scanners() -> None:
    pytest.importorskip("pymavlink")
    from rfhoming.emulator.runtime import Emulator
    from rfhoming.emulator.scenario import load

    scenario = load("s4-air")
    assert scenario.vehicle == {"kind": "mavlink", "gcs": None,
                                "options": {"autopilot": "ardupilot", "vehicle": "copter", "mode": "GUIDED", "altitude": 1.0}}
    world = Emulator(scenario, transport="pipe")
    assert world.device("base").link.describe()["kind"] == "mavlink"  # no --robot needed
    scanners = [world.device(f"survey_ble{k}") for k in (1, 2, 3)]
    world.world.robot.x, world.world.robot.y, world.world.robot.theta = 1.0, 2.0, math.pi / 2
    expected = [(1.2, 1.8), (1.2, 2.4), (0.6, 1.8)]  # each scanner's (x, y) in the world
    assert [s.antenna(world.world) for s in scanners] == [pytest.approx(xy) for xy in expected]
    beacon = scenario.world.targets[0]
    world.world.robot.x, world.world.robot.y = beacon.position[0] - 0.2, beacon.position[1] + 0.2  # scanner 1 over it
    heard = [d for source, _, _, d, _ in scanners[0].transmissions(world.world, "ble_beacon", 0.0, 0.2)
             if source is beacon]
    assert heard and heard[0] == pytest.approx(1.0)  # straight down: the copter's height


def test_the_config_has_an_s4_section() -> None:
    assert Config().s4 == S4Params()


@pytest.mark.slow
def test_the_s4_air_demo_holds_over_the_beacon_and_reports_s4s_metric(tmp_path: Path) -> None:
    """In process and in lockstep: the emulated copter (the `mavlink:` base, armed because the
    demo says arm=1) flies the pattern over all of the area, arrives over the scenario's first
    beacon, and the summary holds the mean and 95th percentile of every beacon's error."""
    pytest.importorskip("pymavlink")
    done = subprocess.run([sys.executable, "-m", "rfhoming", "demo", "--scenario", "s4-air", "--in-process",
                           "--json", "--out", str(tmp_path)], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["success"] and summary["reason"] == "arrived", summary
    assert summary["final_position_error_m"] < 0.65
    assert "mavlink" in summary["links"] and sum(k.startswith("rss-node") for k in summary["links"]) == 3
    located = summary["localisation"]
    assert located["s4_paper"] == {"mean_m": 0.234, "p95_below_m": 0.65}
    for name in ("ekf", "ekf_smoothed"):
        assert located[name]["beacons"] == located[name]["of"] == 10
        assert all(math.isfinite(located[name][k]) for k in ("mean_m", "p95_m", "max_m"))
    states = [json.loads(line) for line in (tmp_path / "truth.jsonl").read_text().splitlines()[1:]]
    xs, ys = [s["robot"]["x"] for s in states], [s["robot"]["y"] for s in states]
    assert min(xs) < 0.2 and max(xs) > 3.8 and min(ys) < 0.2 and max(ys) > 7.8  # the whole 4 x 8 m area
