"""S3's survey at the goal: before it stands to confirm, the robot drives a square about the
goal so the self-calibration fits its offset over places around it, and surveys again while a
survey still moves that offset."""

from __future__ import annotations

import math

import numpy as np

from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.homing.s3_trilat import TrilatController, TrilatParams
from rfhoming.host.homing.types import Pose

P0, N = -64.3, 2.7
SQUARE = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0]])
TRUE_OFFSET = np.array([1.0, 1.0])  # the world is odometry plus this


def rssi_at(where: np.ndarray) -> np.ndarray:
    z: np.ndarray = P0 - 10 * N * np.log10(np.linalg.norm(SQUARE - where, axis=1))
    return z


def controller(**settings: float | bool) -> TrilatController:
    anchors = {f"AC000000000{k + 1}": list(map(float, xy)) for k, xy in enumerate(SQUARE)}
    return TrilatController(TrilatParams(anchors=anchors, goal=[2.5, 2.5], **settings))  # type: ignore[arg-type]


def run(ctrl: TrilatController, heard_at_start: tuple[float, float], seconds: float = 240.0,
        trail: list[tuple[str, float]] | None = None) -> tuple[list[str], Pose]:
    """The robot starts at odometry (1.5, 1.5) (the world's (2.5, 2.5), the goal) and follows the
    controller's commands in 0.1 s steps; every step it hears the four beacons, exactly, where
    it is, except for the first 2 s (its standing start), heard as at ``heard_at_start``.
    The notes in order (repeats dropped) and the last pose; ``trail`` gets each step's note
    and the odometry's distance from the goal's."""
    pose, t = Pose(1.5, 1.5, 0.0), 0.0
    notes: list[str] = []
    while t < seconds:
        where = np.array(heard_at_start) if t < 2.0 else np.array([pose.x, pose.y]) + TRUE_OFFSET
        for k, address in enumerate(ctrl.anchors):
            ctrl.on_input(t, pose, BleRssi(t, 1, address, round(float(rssi_at(where)[k]))))
        d = ctrl.decide(pose)
        if trail is not None:
            trail.append((d.note, math.dist((pose.x, pose.y), (1.5, 1.5))))
        if not notes or notes[-1] != d.note:
            notes.append(d.note)
        if d.arrived:
            break
        theta = pose.theta + d.w * 0.1
        pose = Pose(pose.x + d.v * 0.1 * math.cos(theta), pose.y + d.v * 0.1 * math.sin(theta), theta)
        t += 0.1
    return notes, pose


def test_the_robot_surveys_about_the_goal_before_it_stands() -> None:
    ctrl = controller(survey_m=1.0, survey_min=1)
    notes, pose = run(ctrl, heard_at_start=(2.5, 2.5))
    assert ctrl.arrived and ctrl.surveys == 1
    assert notes.index("surveying") < notes.index("confirming: standing")
    assert math.dist(np.array([pose.x, pose.y]) + TRUE_OFFSET, (2.5, 2.5)) < 0.35  # by the truth


def test_a_survey_that_moves_the_offset_is_followed_by_another() -> None:
    ctrl = controller(survey_m=1.0, survey_min=1, survey_grow_m=0.0)  # the standing start is heard 2.1 m off: the offset the first survey starts from is still 0.6 m off
    run(ctrl, heard_at_start=(4.0, 4.0))
    assert ctrl.arrived and ctrl.surveys == 2
    assert ctrl.offset is not None and np.linalg.norm(ctrl.offset - TRUE_OFFSET) < 0.3
    capped = controller(survey_m=1.0, survey_min=1, survey_max=1)
    run(capped, heard_at_start=(4.0, 4.0))
    assert capped.arrived and capped.surveys == 1


def test_without_a_survey_the_robot_stands_at_once() -> None:
    for settings in ({"survey_m": 0.0}, {"self_calibrate": False}):
        ctrl = controller(**settings)
        notes, _ = run(ctrl, heard_at_start=(2.5, 2.5))
        assert ctrl.arrived and ctrl.surveys == 0 and "surveying" not in notes


def test_the_second_survey_is_wider_and_made_even_when_the_first_moved_nothing() -> None:
    trail: list[tuple[str, float]] = []
    ctrl = controller(survey_m=1.0, survey_grow_m=1.0, survey_min=2)
    run(ctrl, heard_at_start=(2.5, 2.5), trail=trail)
    assert ctrl.arrived and ctrl.surveys == 2
    segments: list[float] = []  # the farthest from the goal in each survey
    for i, (note, far) in enumerate(trail):
        if note == "surveying":
            if i == 0 or trail[i - 1][0] != "surveying":
                segments.append(0.0)
            segments[-1] = max(segments[-1], far)
    assert len(segments) == 2
    assert 0.6 < segments[0] < 0.85 and 1.3 < segments[1] < 1.55  # corners 0.5 and 1.0 m out on each axis


def test_the_survey_stays_inside_the_beacons_box() -> None:
    """A square wider than the beacons' box is cut to it, survey_margin_m in: a beacon is often on
    a wall, and beyond the box the site is unknown."""
    trail: list[tuple[str, float]] = []
    ctrl = controller(survey_m=6.0, survey_min=1, survey_max=1, survey_margin_m=0.5)
    run(ctrl, heard_at_start=(2.5, 2.5), trail=trail)
    assert ctrl.arrived and ctrl.surveys == 1
    farthest = max(far for note, far in trail if note == "surveying")
    assert 2.0 * math.sqrt(2) - 0.35 < farthest < 2.0 * math.sqrt(2) + 0.05  # the corners (0.5, 0.5) .. (4.5, 4.5)
    wide = controller(survey_m=6.0, survey_min=1, survey_max=1, survey_margin_m=-10.0)
    trail.clear()
    run(wide, heard_at_start=(2.5, 2.5), trail=trail)
    assert max(far for note, far in trail if note == "surveying") > 3.9  # let out: the 6 m square's corners, 4.2 m
