"""``emulate --pose-from ros2:TOPIC`` speaks up: no pose within ``wait`` seconds (a mistyped
topic: it names the writers it saw), poses refused with a count (not finite, another
``header.frame_id``), and a publisher gone stale (``stale`` seconds): said, and the radios then
hear nothing until poses come again. Before, a mistyped topic left the robot at the start with
nothing on stderr, NaN poses were dropped without a word and the radios reported from the last
pose for ever. The follower runs on a clock the test holds; one test runs the command."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

pytest.importorskip("cyclonedds")

import rigs  # noqa: E402
from test_ros2 import pose_sample, random_domain  # noqa: E402

from rfhoming.emulator.ros2pose import REPEAT_S, PoseFollower  # noqa: E402
from rfhoming.protocol import ros2  # noqa: E402

START = (1.0, 2.0, 0.0)


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def follower(**settings: Any) -> tuple[PoseFollower, Clock]:
    clock = Clock()
    f = PoseFollower("/gt", domain=3, frame="world", clock=clock, **settings)
    f._publications = SimpleNamespace(take=lambda n: [])  # no DDS: no writer announces anything
    return f, clock


def said(caplog: pytest.LogCaptureFixture, words: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if words in r.getMessage() and r.levelname == "WARNING"]


def test_no_pose_is_said_after_wait_and_again_while_none_comes(caplog: pytest.LogCaptureFixture) -> None:
    f, clock = follower(wait=2.0)
    clock.now = 1.9
    assert f.pose(START) is None and said(caplog, "no pose") == []
    clock.now = 2.5
    f.pose(START)
    (line,) = said(caplog, "no pose")
    assert "--pose-from /gt: no pose in 2 s" in line and "no writer of /gt on ROS 2 domain 3" in line
    clock.now = 2.5 + REPEAT_S - 1
    f.pose(START)
    assert len(said(caplog, "no pose")) == 1  # not every step
    clock.now = 2.5 + REPEAT_S
    f.pose(START)
    assert len(said(caplog, "no pose")) == 2  # periodically while it holds


def test_refused_poses_are_said_with_a_count(caplog: pytest.LogCaptureFixture) -> None:
    f, clock = follower()
    f.type = ros2.POSE_STAMPED
    f._on_sample(pose_sample(ros2.POSE_STAMPED, 3.0, 4.0, 0.5))  # frame "world": the expected one from now on
    for _ in range(3):
        f._on_sample(pose_sample(ros2.POSE_STAMPED, math.nan, 0.0, 0.0))
    odom = pose_sample(ros2.POSE_STAMPED, 9.0, 9.0, 0.0)
    odom.header.frame_id = "odom"  # type: ignore[attr-defined]
    f._on_sample(odom)
    assert f.pose(START) == pytest.approx((3.0, 4.0, 0.5))  # neither moved the robot
    assert said(caplog, "refused") == [
        "--pose-from /gt: 3 pose(s) refused so far, with a value that is not finite (NaN, inf)",
        "--pose-from /gt: 1 pose(s) refused so far, in frame 'odom', not 'world' (the first pose's, or frame_id=)"]
    f._on_sample(pose_sample(ros2.POSE_STAMPED, math.inf, 0.0, 0.0))
    clock.now = REPEAT_S
    f.pose(START)
    assert said(caplog, "refused")[-1].startswith("--pose-from /gt: 4 pose(s) refused so far")


def test_frame_id_names_the_frame_poses_must_be_in(caplog: pytest.LogCaptureFixture) -> None:
    f, _ = follower(frame_id="map")
    f.type = ros2.ODOMETRY
    f._on_sample(pose_sample(ros2.ODOMETRY, 3.0, 4.0, 0.5))  # in "world"
    assert f.pose(START) is None and f.counters["wrong_frame"] == 1
    assert "in frame 'world', not 'map'" in said(caplog, "refused")[0]


async def test_a_stale_publisher_is_said_and_its_radios_hear_nothing_until_poses_return(
        caplog: pytest.LogCaptureFixture) -> None:
    from rfhoming.emulator.runtime import Emulator
    from rfhoming.emulator.scenario import load

    f, clock = follower(stale=1.0)
    f.type = ros2.POSE_STAMPED
    emulator = Emulator(load("s0-open"), transport="pipe", pose_from={"topic": "/gt", "domain": random_domain()})
    emulator.pose_from = f
    heard: list[int] = []
    for d in emulator._others:
        d.step = lambda world, t0, t1: heard.append(len(world.targets))  # type: ignore[method-assign]

    async def step_at(now: float, pose: bool = False) -> int:
        clock.now = now
        if pose:
            f._on_sample(pose_sample(ros2.POSE_STAMPED, 3.0, 4.0, 0.0))
        heard.clear()
        await emulator.step()
        return min(heard)

    targets = len(emulator.world.targets)
    assert await step_at(0.0, pose=True) == targets and not f.stale
    assert await step_at(0.9) == targets
    assert await step_at(1.2) == 0 and f.stale  # no pose for 1.2 s: the radios hear nothing
    stale = said(caplog, "no pose for")
    assert len(stale) == 1 and "radios hear nothing" in stale[0]
    assert await step_at(5.0) == 0 and len(said(caplog, "no pose for")) == 1
    assert await step_at(5.1, pose=True) == targets and not f.stale
    assert len(said(caplog, "poses again")) == 1 and emulator.world.targets


@pytest.mark.slow
def test_a_mistyped_topic_is_said_on_stderr(tmp_path: Path) -> None:
    """The command as a user runs it, on a domain nobody publishes on: one warning within
    wait=, naming the topic and the domain."""
    domain = random_domain()
    argv = [*rigs.RFHOMING, "emulate", "s0-open", "--link-dir", str(tmp_path),
            "--pose-from", f"ros2:/ground_truht/pose,domain={domain},wait=1"]
    with rigs.Child(argv) as world:
        line = world.until("no pose in", stream="stderr")
    assert line is not None and f"no writer of /ground_truht/pose on ROS 2 domain {domain}" in line
