"""Fixed-anchor geometry against synthetic rays: exact rays give the point back, noise and one
bad anchor do not move it far, the fold is resolved from the geometry."""

from __future__ import annotations


import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rfhoming.host.estimation.anchors3d import (board_angles, board_direction, locate, make_ray, rotation)
from rfhoming.host.estimation.bearings import Degenerate

ROOM_ANCHORS = [  # (position, yaw): the four walls of a 12 x 6 m room, 2.4 m up, tilted down 20 deg
    ((0.0, 3.0, 2.4), 0.0), ((12.0, 3.0, 2.4), 180.0), ((6.0, 0.0, 2.4), 90.0), ((6.0, 6.0, 2.4), -90.0)]

angles = st.floats(-80, 80)


def observe(anchor_pos, yaw, pitch, tag, roll=0.0):
    """The board angles an ideal anchor reports for ``tag`` (the emulator's geometry, re-derived)."""
    rot = rotation(yaw, pitch, roll)
    d = rot.T @ (np.asarray(tag) - np.asarray(anchor_pos))
    return board_angles(d)


@given(angles, angles, st.floats(-180, 180), st.floats(-60, 60), st.floats(-30, 30))
def test_angles_round_trip_through_the_pose(az, el, yaw, pitch, roll):
    rot = rotation(yaw, pitch, roll)
    world = rot @ board_direction(az, el)
    assert np.linalg.norm(world) == pytest.approx(1.0)
    back = board_angles(rot.T @ world)
    assert back == pytest.approx((az, el), abs=1e-6)


def test_board_sign_negative_azimuth_is_left():
    # a board facing +x: a tag at +y (its left) reads a negative azimuth; above, positive elevation
    az, el = board_angles(rotation(0, 0, 0).T @ np.array([1.0, 1.0, 0.0]))
    assert az == pytest.approx(-45) and el == pytest.approx(0)
    assert board_angles(np.array([1.0, 0.0, 1.0]))[1] == pytest.approx(45)
    # a board tilted down 30 deg sees a point straight ahead at its own height 30 deg above boresight
    assert board_angles(rotation(0, -30).T @ np.array([1.0, 0.0, 0.0]))[1] == pytest.approx(30)


tags = st.tuples(st.floats(1.0, 11.0), st.floats(1.0, 5.0), st.floats(0.0, 1.5))


@settings(max_examples=60)
@given(tags, st.sampled_from([None, "height"]))
def test_exact_rays_give_the_tag_back(tag, mode):
    rays = []
    for pos, yaw in ROOM_ANCHORS:
        az, el = observe(pos, yaw, -20, tag)
        rays.append(make_ray(str(yaw), pos, rotation(yaw, -20), az, el, 2.0))
    fix = locate(rays, height=tag[2] if mode else None)
    assert np.allclose(fix.point, tag, atol=1e-4)
    assert fix.rejected == ()


@settings(max_examples=40, deadline=None)
@given(tags, st.integers(0, 2**31), st.integers(0, 3))
def test_one_bad_anchor_is_left_out(tag, seed, bad):
    rng = np.random.default_rng(seed)
    rays = []
    for k, (pos, yaw) in enumerate(ROOM_ANCHORS):
        az, el = observe(pos, yaw, -20, tag)
        az, el = az + rng.normal(0, 0.5), el + rng.normal(0, 0.5)
        if k == bad:  # a reflection: 35 deg off
            az = az + 35 if az < 0 else az - 35
        rays.append(make_ray(f"a{k}", pos, rotation(yaw, -20), az, el, 2.0))
    fix = locate(rays)
    assert np.linalg.norm(fix.point[:2] - np.array(tag[:2])) < 0.5
    assert f"a{bad}" not in fix.used


@settings(max_examples=40, deadline=None)
@given(tags, st.integers(0, 2**31))
def test_covariance_matches_the_scatter(tag, seed):
    """Fixes from 2-degree noise scatter about as the reported covariance says (within 3x)."""
    rng = np.random.default_rng(seed)
    errors, covs = [], []
    for _ in range(30):
        rays = []
        for pos, yaw in ROOM_ANCHORS:
            az, el = observe(pos, yaw, -20, tag)
            rays.append(make_ray(str(yaw), pos, rotation(yaw, -20), az + rng.normal(0, 2), el + rng.normal(0, 2), 2.0))
        fix = locate(rays, height=tag[2])
        errors.append(fix.point[:2] - np.array(tag[:2]))
        covs.append(np.trace(fix.covariance))
    mse = float(np.mean(np.sum(np.square(errors), axis=1)))
    assert mse < 3 * 3 * float(np.mean(covs)) + 1e-4  # 1/cos growth over-states sigma a little


def test_fold_resolved_for_two_sided_anchors():
    """A pole anchor in the middle of the room sees a tag behind it mirrored; the other anchors
    say which side it is on."""
    tag = (4.0, 3.0, 0.5)
    rays = []
    for k, (pos, yaw) in enumerate([((6.0, 3.0, 2.0), 0.0), ((6.0, 0.0, 2.4), 90.0), ((6.0, 6.0, 2.4), -90.0)]):
        az, el = observe(pos, yaw, 0, tag)
        d = rotation(yaw, 0).T @ (np.asarray(tag) - np.asarray(pos))
        if d[0] < 0:  # behind the board: it reports the front image
            az, el = board_angles(d * np.array([-1, 1, 1]))
        rays.append(make_ray(f"a{k}", pos, rotation(yaw, 0), az, el, 2.0, two_sided=(k == 0)))
    fix = locate(rays)
    assert np.allclose(fix.point, tag, atol=1e-3)


def test_too_few_or_parallel_rays_are_degenerate():
    ray = make_ray("a", (0, 0, 2), rotation(0), 0, 0, 2.0)
    with pytest.raises(Degenerate):
        locate([ray])
    with pytest.raises(Degenerate):
        locate([ray, make_ray("b", (0, 1, 2), rotation(0), 0, 0, 2.0)], height=None)
