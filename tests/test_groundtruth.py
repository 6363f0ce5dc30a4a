"""Waypoint ground truth, the recordings' scoring rule, and angle residual statistics, on data made here."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rfhoming.host.angle_residuals import angle_stats, correlation_time, ks_distance, residuals, true_angles
from rfhoming.host.groundtruth import NO_ESTIMATE_M, GroundTruthError, load_waypoints, score
from rfhoming.host.site import Anchor, Site, TagInfo
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import AngleEvent


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "walk.csv"
    path.write_text(text)
    return path


def test_a_walk_is_straight_between_waypoints_and_held_during_a_stop(tmp_path: Path) -> None:
    path = load_waypoints(write(tmp_path, "1000,NaN,0,0\n3000,5000,200,0\n7000,NaN,200,400\n"))
    got = path.at([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 9.0])
    assert got.tolist() == [[0, 0], [0, 0], [1, 0], [2, 0], [2, 0], [2, 0], [2, 2], [2, 4], [2, 4]]
    assert path.moving([2.0, 4.0, 6.0]).tolist() == [True, False, True]


def test_the_score_takes_the_last_position_at_or_before_each_tick(tmp_path: Path) -> None:
    path = load_waypoints(write(tmp_path, "1000,NaN,0,0\n3000,NaN,200,0\n"))
    # ticks at 1.5, 2.0, 2.5, 3.0; truth x = 0.5, 1.0, 1.5, 2.0
    errors = score(path, [(2.0, 1.0, 0.0), (2.7, 1.5, 1.0)])
    assert errors.tolist() == [NO_ESTIMATE_M, 0.0, 0.5, pytest.approx(math.hypot(0.5, 1.0))]


def test_a_static_surveys_point_is_one_waypoint_with_a_dwell(tmp_path: Path) -> None:
    path = load_waypoints(write(tmp_path, "arrival_ms,leave_ms,x_cm,y_cm\n1000,61000,300,450\n"))
    assert path.last_s == 61.0 and path.at([0.0, 30.0, 90.0]).tolist() == [[3.0, 4.5]] * 3
    assert path.heading([30.0]).tolist() == [0.0] and not path.moving([30.0]).any()


@pytest.mark.parametrize("text, says", [
    ("1000,NaN,0,0\n", "two waypoints, or one with a dwell"),
    ("1000,NaN,0\n2000,NaN,0,0\n", "row 2: expected"),
    ("1000,NaN,0,0\n500,NaN,1,1\n", "time order"),
    ("1000,900,0,0\n2000,NaN,1,1\n", "leave_ms"),
    ("1000,NaN,x,0\n2000,NaN,1,1\n", "not four numbers"),
])
def test_a_bad_waypoint_file_is_named_with_its_row(tmp_path: Path, text: str, says: str) -> None:
    with pytest.raises(GroundTruthError, match=says):
        load_waypoints(write(tmp_path, "arrival_ms,leave_ms,x_cm,y_cm\n" + text))


def _site() -> Site:
    anchors = (Anchor("west", "A1", None, (0.0, 3.0, 2.0), yaw_deg=0.0), Anchor("south", "A2", None, (6.0, 0.0, 2.0), yaw_deg=90.0))
    return Site("test", anchors, (TagInfo("T", height=1.0),))


def test_residuals_are_the_reported_angles_less_the_true_ones(tmp_path: Path) -> None:
    site = _site()
    path = load_waypoints(write(tmp_path, "0,NaN,100,100\n10000,NaN,1100,500\n"))
    rng = np.random.default_rng(1)
    events, errors = [], []
    for k in range(1000):
        t = k * 0.01
        x, y = path.at([t])[0]
        for anchor in site.anchors:
            az, el = true_angles(anchor, np.array([[x, y, 1.0]]))[0]
            e = 3.0 + rng.normal(0, 2.0) if anchor.name == "west" else 0.0
            errors.append(e)
            events.append(bearing_of(t, AngleEvent("T", -50, round(az + e), round(el), 0, 37, anchor.id, "", 0)))
    res = residuals(site, events, path)
    assert set(res) == {"west", "south"}
    assert np.all(np.abs(res["south"].az_err) <= 0.5)  # integer degrees
    west = angle_stats([res], ["west"])
    assert west.az_bias == pytest.approx(3.0, abs=0.3)
    assert west.az_mad_sigma == pytest.approx(2.0, abs=0.3)
    assert west.az_tail == 0.0 and west.missing == 0.0


def test_an_error_that_stays_has_a_long_correlation_time() -> None:
    rng = np.random.default_rng(2)
    t = np.arange(0, 60, 0.02)
    white = rng.normal(0, 1, len(t))
    slow = np.repeat(rng.normal(0, 1, len(t) // 100 + 1), 100)[:len(t)]  # a new value every 2 s
    assert correlation_time(t, white) <= 0.1
    assert 0.8 <= correlation_time(t, slow) <= 1.2


def test_the_ks_distance_is_zero_for_one_sample_and_one_for_disjoint_ones() -> None:
    a = np.arange(100.0)
    assert ks_distance(a, a) == 0.0
    assert ks_distance(a, a + 1000) == 1.0
