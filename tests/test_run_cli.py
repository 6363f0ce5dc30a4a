"""`rfhoming run` end to end: the emulator and the run command in their own processes, as a
user would start them on real hardware (tag selection and failing fast)."""

from __future__ import annotations

import json
import math
import os
import pty
import re
import subprocess
import sys
from pathlib import Path

import pytest

from rfhoming.host.outputs import part_of

CHOSEN, OTHER = "CCF9578E0D8B", "CCF9578E0D8A"

TWO_TAGS = f"""\
name = "two-tags"
description = "open 20 x 20 m, two AoA tags in view"
bounds = [-10.0, -10.0, 10.0, 10.0]

[robot]
start = [0.0, 0.0, 0.0]

[aoa]
kind = "gaussian"
angle_deg = 3.0

[[targets]]
id = "{OTHER}"
kind = "aoa_tag"
position = [-7.0, 3.0]
interval_ms = 20

[[targets]]
id = "{CHOSEN}"
kind = "aoa_tag"
position = [8.0, -6.0]
interval_ms = 50

[devices.aoa]
type = "xplr-aoa"
dialect = "1.2"

[devices.base]
type = "base"
"""

LOCKSTEP_CONFIG = "[loop]\nodometry_wall_timeout_s = inf  # lockstep: wall time means nothing\n"


def rfhoming(*args: str) -> list[str]:
    return [sys.executable, "-m", "rfhoming", *args]


@pytest.fixture
def two_tags(tmp_path: Path, emulated) -> Path:
    """The emulator on ptys in lockstep with two tags in view; its truth file as it runs
    (truth.jsonl.part until the emulator stops: host/outputs.py)."""
    scenario = tmp_path / "two-tags.toml"
    scenario.write_text(TWO_TAGS)
    (tmp_path / "robot.toml").write_text(LOCKSTEP_CONFIG)
    truth = tmp_path / "truth.jsonl"
    emulated(scenario, "--pty", "--lockstep", "--seed", "4", "--truth", str(truth), link_dir=tmp_path)
    return part_of(truth)


def run_on(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(rfhoming("run", "--aoa", f"xplr-aoa:{tmp_path / 'aoa'}", "--base", f"base:{tmp_path / 'base'}",
                                   "--config", str(tmp_path / "robot.toml"), *extra),
                          capture_output=True, text=True, timeout=240)


def test_with_two_tags_in_view_the_robot_homes_on_the_chosen_one(tmp_path: Path, two_tags: Path) -> None:
    done = run_on(tmp_path, "--tag", CHOSEN)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["arrived"]
    last = json.loads(two_tags.read_text().splitlines()[-1])
    robot = (last["robot"]["x"], last["robot"]["y"])
    where = {t["id"]: (t["x"], t["y"]) for t in last["targets"]}
    assert math.dist(robot, where[CHOSEN]) < 1.0 < math.dist(robot, where[OTHER])


@pytest.mark.slow
def test_a_run_whose_spec_chooses_the_tag_replays_to_the_same_run_log(tmp_path: Path, two_tags: Path) -> None:
    """tags= in the --aoa spec is part of the run: the capture's run record keeps every device's
    spec, so the replayed driver filters as the live one did (it once replayed unfiltered)."""
    done = subprocess.run(rfhoming("run", "--aoa", f"xplr-aoa:{tmp_path / 'aoa'},tags={CHOSEN}", "--base",
                                   f"base:{tmp_path / 'base'}", "--config", str(tmp_path / "robot.toml"),
                                   "--capture", str(tmp_path / "run.pcapng"), "--log", str(tmp_path / "run.jsonl")),
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    replay = subprocess.run(rfhoming("replay", str(tmp_path / "run.pcapng"), "--run", "--log",
                                     str(tmp_path / "replayed.jsonl")), capture_output=True, text=True, timeout=240)
    assert json.loads(replay.stdout)["replay"]["diverged"] == 0, replay.stderr
    assert (tmp_path / "replayed.jsonl").read_text() == (tmp_path / "run.jsonl").read_text()


def test_with_two_tags_in_view_and_none_chosen_run_refuses_and_lists_them(tmp_path: Path, two_tags: Path) -> None:
    done = run_on(tmp_path)
    assert done.returncode == 2
    assert "2 tags in view" in done.stderr and CHOSEN in done.stderr and OTHER in done.stderr
    assert "--tag" in done.stderr
    last = json.loads(two_tags.read_text().splitlines()[-1])
    assert math.hypot(last["robot"]["x"], last["robot"]["y"]) < 0.05  # it never moved


def test_an_unopenable_port_fails_fast_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "no-such-tty"
    done = subprocess.run(rfhoming("run", "--aoa", f"xplr-aoa:{missing}", "--base", f"base:{tmp_path / 'no-base'}"),
                          capture_output=True, text=True, timeout=10)  # the old code hung here for ever
    assert done.returncode == 2 and str(tmp_path) in done.stderr


SITE = Path(__file__).resolve().parents[1] / "docs" / "sites" / "kit-home.toml"


@pytest.mark.parametrize("controller", ["aoa", *(pytest.param(c, marks=pytest.mark.slow) for c in ("dock", "rss", "trilat", "survey")),
                                        "anchors"])  # the quick loop: a sensor controller and the site one
def test_every_controller_fails_fast_naming_an_unopenable_base(tmp_path: Path, controller: str) -> None:
    """The sensors' ports open (a plain pty), the base's does not: one line naming it, exit 2,
    for every controller (the anchors run once waited on the failed base for ever)."""
    _, device = pty.openpty()
    sensor = os.ttyname(device)
    if controller == "anchors":
        site = tmp_path / "site.toml"
        site.write_text(re.sub(r'port = "[^"]*"', f'port = "xplr-aoa:{sensor}"', SITE.read_text()))
        args = ["--site", str(site)]
    else:
        args = [f"--{ {'aoa': 'aoa', 'dock': 'aoa', 'rss': 'rss', 'trilat': 'ble', 'survey': 'ble'}[controller]}", sensor]
    config = tmp_path / "robot.toml"
    config.write_text('[trilat]\ngoal = [1.0, 1.0]\n[trilat.anchors]\nA = [0.0, 0.0]\nB = [4.0, 0.0]\nC = [0.0, 4.0]\n')
    base = tmp_path / "no-base"
    done = subprocess.run(rfhoming("run", "--controller", controller, *args, "--base", f"base:{base}",
                                   "--config", str(config)), capture_output=True, text=True, timeout=60)
    os.close(device)
    assert done.returncode == 2, done.stderr
    # the loop's watchdog may log a stall on a loaded machine: a diagnostic, not a second error line
    said = [line for line in done.stderr.splitlines() if "rfhoming.host.homing.loop: event loop blocked" not in line]
    assert len(said) == 1 and str(base) in said[0], done.stderr


def test_a_controller_the_config_cannot_make_is_a_one_line_error(tmp_path: Path) -> None:
    _, device = pty.openpty()
    done = subprocess.run(rfhoming("run", "--controller", "trilat", "--ble", os.ttyname(device), "--base",
                                   f"base:{tmp_path / 'b'}"), capture_output=True, text=True, timeout=60)
    os.close(device)
    assert done.returncode == 2 and "[trilat.anchors]" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.slow
def test_a_board_that_never_answers_fails_by_its_timeout_with_a_hint() -> None:
    """Both ports open (plain ptys nobody serves), the board never answers AT: the AoA spec's
    timeout= bounds the wait and the message names the port and says what to check."""
    ends = [pty.openpty() for _ in range(2)]
    aoa, base = (os.ttyname(device) for _, device in ends)
    try:
        done = subprocess.run(rfhoming("run", "--aoa", f"xplr-aoa:{aoa},timeout=1.5", "--base", f"base:{base}"),
                              capture_output=True, text=True, timeout=20)
    finally:
        for fds in ends:
            for fd in fds:
                os.close(fd)
    assert done.returncode == 2
    assert aoa in done.stderr and "1.5 s" in done.stderr and "RTS/CTS" in done.stderr


@pytest.mark.slow
def test_listen_fails_fast_when_the_board_never_answers() -> None:
    """Every command, not only run: the board's first set-up fails (no answer to AT) -> exit 2."""
    controller, device = pty.openpty()
    aoa = os.ttyname(device)
    try:
        done = subprocess.run(rfhoming("listen", f"xplr-aoa:{aoa}"), capture_output=True, text=True, timeout=30)
    finally:
        os.close(controller)
        os.close(device)
    assert done.returncode == 2 and aoa in done.stderr and "RTS/CTS" in done.stderr
