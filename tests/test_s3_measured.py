"""S3 under real radios: the dB fit with one faded link, the offset fitted with the links'
constants along a path, and the standing confirmation before "arrived"."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.estimation.bearings import Degenerate
from rfhoming.host.estimation.lateration import multilaterate, offset_and_links, rssi_position
from rfhoming.host.homing.s3_trilat import TrilatController, TrilatParams
from rfhoming.host.homing.types import Pose

P0, N = -64.3, 2.7
SQUARE = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0]])


def rssi_at(where: np.ndarray, anchors: np.ndarray = SQUARE) -> np.ndarray:
    z: np.ndarray = P0 - 10 * N * np.log10(np.linalg.norm(anchors - where, axis=1))
    return z


def test_the_db_fit_holds_one_faded_link_where_squared_ranges_do_not() -> None:
    anchors = np.vstack([SQUARE, [[2.5, 6.0]]])
    truth = np.array([1.5, 2.0])
    z = rssi_at(truth, anchors)
    assert np.linalg.norm(rssi_position(anchors, z, P0, N) - truth) < 1e-3  # exact readings: exact
    z[2] -= 12.0  # the far corner's link behind a wall: its range reads 2.8 times long
    robust = rssi_position(anchors, z, P0, N)
    linear = multilaterate(anchors, 10 ** ((P0 - z) / (10 * N)))
    assert np.linalg.norm(robust - truth) < 0.4
    assert np.linalg.norm(linear - truth) > 2.0


def test_the_db_fit_refuses_collinear_anchors() -> None:
    with pytest.raises(Degenerate):
        rssi_position(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]), np.array([-60.0, -61.0, -62.0]), P0, N)


def test_the_offset_is_found_with_the_links_own_constants() -> None:
    links = np.array([2.0, -2.0, 1.5, -1.0])  # each beacon's own offset, dB
    offset = np.array([0.8, -0.5])  # odometry -> the anchors' frame
    path = [np.array([1.5 + 0.1 * k, 1.5]) for k in range(20)] + [np.array([3.5, 1.5 + 0.1 * k]) for k in range(20)]
    which, odo, z = [], [], []
    for o in path:
        for k, r in enumerate(rssi_at(o + offset) + links):
            which.append(k)
            odo.append(o)
            z.append(r)
    start = np.array([0.0, 0.0, P0, N, 0.0, 0.0, 0.0, 0.0])
    exact = offset_and_links(SQUARE, np.array(which), np.array(odo), np.array(z), start, P0, N, reading_sd_db=1.0,
                             independent=1.0, iterations=30)  # readings as sure as these
    assert np.linalg.norm(exact[:2] - offset) < 0.1
    assert np.allclose(exact[4:], links, atol=0.5)
    doubted = offset_and_links(SQUARE, np.array(which), np.array(odo), np.array(z), start, P0, N, reading_sd_db=5.0,
                               independent=1.0, iterations=30)  # the controller's weights: the priors pull a little
    assert np.linalg.norm(doubted[:2] - offset) < 0.25


def stand(ctrl: TrilatController, t0: float, seconds: float, odo: Pose, world: tuple[float, float]) -> float:
    """Readings of all four beacons every 0.1 s for ``seconds``, as heard at ``world``, the
    robot's odometry at ``odo``; the controller decides after each round. The time after."""
    t = t0
    z = rssi_at(np.array(world))
    while t < t0 + seconds:
        for k, address in enumerate(ctrl.anchors):
            ctrl.on_input(t, odo, BleRssi(t, 1, address, round(float(z[k]))))
        ctrl.decide(odo)
        t += 0.1
    return t


def controller(**settings: float | bool) -> TrilatController:
    anchors = {f"AC000000000{k + 1}": list(map(float, xy)) for k, xy in enumerate(SQUARE)}
    return TrilatController(TrilatParams(anchors=anchors, goal=[2.0, 2.0], self_calibrate=False, **settings))  # type: ignore[arg-type]


def test_arrival_waits_for_the_standing_readings_to_confirm() -> None:
    ctrl = controller()
    odo = Pose(0.0, 0.0, 0.0)
    t = stand(ctrl, 0.0, 1.0, odo, (2.0, 2.0))
    assert ctrl.decide(odo).note == "localising"  # localise_s: 2 s
    t = stand(ctrl, t, 1.2, odo, (2.0, 2.0))
    first = ctrl.decide(odo)
    assert first.note == "confirming: standing" and not first.arrived  # the fused estimate says "there": stand
    t = stand(ctrl, t, 1.0, odo, (3.5, 3.5))  # but the standing readings place it 2.1 m off
    assert ctrl.confirmations == 0
    t = stand(ctrl, t, 1.5, odo, (3.5, 3.5))
    assert ctrl.confirmations == 1 and not ctrl.arrived
    on = ctrl.decide(odo)
    assert not on.arrived and on.note == "homing"
    assert math.dist(ctrl.world(odo), (3.5, 3.5)) < 0.5  # it goes on from the standing fix (the fixes then pull it a little)


def test_confirmed_arrival_and_the_papers_instant_stop() -> None:
    ctrl = controller()
    odo = Pose(0.0, 0.0, 0.0)
    t = stand(ctrl, 0.0, 2.2, odo, (2.0, 2.0))
    assert not ctrl.decide(odo).arrived
    stand(ctrl, t, 2.5, odo, (2.1, 1.9))
    assert ctrl.arrived and ctrl.confirmations == 1 and ctrl.decide(odo).arrived
    paper = controller(localise_s=0.0, confirm_s=0.0, robust_fit=False)
    stand(paper, 0.0, 0.5, odo, (2.0, 2.0))
    assert paper.decide(odo).arrived and paper.confirmations == 0
