"""rfhoming node's view of a run without ROS 2 (host/ros2node/progress.py): the feedback read from
the loop's estimate records, the stand-off goal handed to Nav2, and when a firmer estimate is sent."""

from __future__ import annotations

import math

import pytest

from rfhoming.host.ros2node.progress import Progress, Resender, progress, stand_off


def test_an_estimate_record_gives_the_feedback_and_a_spread_where_there_are_two_estimates() -> None:
    p = progress({"kind": "estimate", "t": 3.5, "goal": [4.0, 3.0], "g_p": [4.0, 3.0], "g_v": [4.0, 3.6],
                  "phase": "homing", "pose": [0.0, 0.0, 0.1]})
    assert p is not None and p.goal == (4.0, 3.0) and p.phase == "homing"
    assert p.distance_m == pytest.approx(5.0) and p.uncertainty_m == pytest.approx(0.6)
    one = progress({"kind": "estimate", "t": 1.0, "goal": None, "phase": "disambiguating", "pose": [0, 0, 0]})
    assert one is not None and one.goal is None and one.distance_m is None and one.uncertainty_m is None
    assert progress({"kind": "command", "t": 1.0, "v": 0.2}) is None


def test_the_goal_stands_off_short_of_the_estimate_facing_it() -> None:
    p = Progress(0.0, (4.0, 3.0), None, (0.0, 0.0, 0.0), "homing")
    x, y, yaw = stand_off(p, 0.5)
    assert (x, y) == pytest.approx((4.0 - 0.4, 3.0 - 0.3)) and yaw == pytest.approx(math.atan2(3, 4))
    near = Progress(0.0, (1.0, 0.0), None, (0.8, 0.0, 2.0), "homing")
    assert stand_off(near, 0.5)[:2] == pytest.approx((0.8, 0.0))  # nearer than the stand-off: stay


def test_a_new_goal_goes_out_only_once_the_estimate_has_moved() -> None:
    resend = Resender(0.3, 1.0)
    at = [(0.0, (5.0, 0.0)), (1.0, (5.1, 0.1)), (2.0, (5.2, 0.2)), (3.0, (5.4, 0.0)), (3.5, (6.0, 0.0)),
          (4.0, (6.0, 0.0)), (4.1, (6.0, 0.0)), (5.0, (5.0, 0.0))]
    sent = [resend.due(Progress(t, g, None, (0.0, 0.0, 0.0), "homing")) for t, g in at]
    assert sent == [True, False, False, True, False, True, False, True] and resend.count == 4
    assert not Resender(0.3, 1.0).due(Progress(0.0, (1.0, 1.0), None, (0.0, 0.0, 0.0), "disambiguating"))
