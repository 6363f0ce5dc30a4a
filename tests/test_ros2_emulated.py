"""`rfhoming emulate --robot ros2` + `rfhoming run --base ros2:` in their own processes: the
robot homes through DDS (checked on the emulator's truth), a base on another domain is a
one-line error, a second reader written with plain cyclonedds (tests/ros2_listener.py) hears
/odom, /tf and rfhoming's /cmd_vel, and the run's capture (DDS samples as sample records) replays to the same
run log."""

from __future__ import annotations

import json
from collections import Counter
import math
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

pytest.importorskip("cyclonedds")


def rfhoming(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rfhoming", *args], capture_output=True, text=True, timeout=timeout)


def commands_heard(tmp_path: Path) -> list[tuple[float, float]]:
    lines = (tmp_path / "heard.jsonl").read_text().splitlines()
    return [(h["v"], h["w"]) for h in map(json.loads, lines[1:] if lines else []) if h.get("topic") == "cmd_vel"]


def wait_for(test, what: str, proc: subprocess.Popen | None = None, seconds: float = 120.0) -> None:  # noqa: ANN001
    end = time.monotonic() + seconds  # hang guard only
    while not test():
        assert time.monotonic() < end, f"no {what} within {seconds} s"
        assert proc is None or proc.poll() is None, f"the run ended before {what}: {proc.stderr.read()}"
        time.sleep(0.05)


@pytest.mark.slow
def test_a_ros2_robot_homes_through_dds_and_its_capture_replays(tmp_path: Path) -> None:
    domain = random.SystemRandom().randint(154, 190)  # tests/test_ros2.py random_domain says why
    truth = tmp_path / "truth.jsonl"
    emulator = subprocess.Popen([sys.executable, "-m", "rfhoming", "emulate", "s0-open", "--robot", f"ros2:domain={domain}",
                                 "--truth", str(truth), "--link-dir", str(tmp_path)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        endpoints = [json.loads(emulator.stdout.readline()) for _ in range(2)]
        base = next(e for e in endpoints if e["device"] == "base")
        assert base["kind"] == "ros2" and base["path"] == f"ros2:domain={domain}"
        aoa = next(e["path"] for e in endpoints if e["device"] == "aoa")
        heard_file = (tmp_path / "heard.jsonl").open("w", buffering=1)
        listener = subprocess.Popen([sys.executable, str(Path(__file__).with_name("ros2_listener.py")), str(domain),
                                     "120"], stdin=subprocess.PIPE, stdout=heard_file, text=True)
        silent = rfhoming("run", "--aoa", aoa, "--base", f"ros2:domain={domain + 1},timeout=2")
        said = [line for line in silent.stderr.splitlines() if "event loop blocked" not in line]  # the loop's own
        assert silent.returncode == 2 and len(said) == 1, silent.stderr  # measure of a stall, logged as it happens
        assert "/odom" in silent.stderr and "not ready" in silent.stderr
        # Ctrl-C while driving: three zero commands go out before rfhoming exits
        interrupted = subprocess.Popen([sys.executable, "-m", "rfhoming", "run", "--aoa", aoa, "--base",
                                        f"ros2:domain={domain}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        wait_for(lambda: any(c[0] > 0.2 for c in commands_heard(tmp_path)), "a moving command", interrupted)
        interrupted.send_signal(signal.SIGINT)
        interrupted.wait(timeout=60)
        wait_for(lambda: commands_heard(tmp_path)[-3:] == [(0.0, 0.0)] * 3, "three zero commands after Ctrl-C")
        run = rfhoming("run", "--aoa", aoa, "--base", f"ros2:domain={domain}", "--capture", str(tmp_path / "run.pcapng"),
                       "--log", str(tmp_path / "run.jsonl"), "--mcap", str(tmp_path / "run.mcap"),
                       "--ros2", f"domain={domain}")
        listener.communicate(timeout=150)  # its stdin closed: it reads what is on its way, then ends
        heard_file.close()
        heard = [json.loads(line) for line in (tmp_path / "heard.jsonl").read_text().splitlines()][1:]
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=30)
    # the second reader (plain cyclonedds, its own types) heard the emulated robot and rfhoming
    topics = {h["topic"] for h in heard}
    # s0-open's base has no scanner; --ros2 adds the run's target, events and the commands' mirror, not a
    # second /odom; /cmd_vel is the driver's, to this robot
    assert topics == {"cmd_vel", "rfhoming/cmd_vel", "odom", "tf", "rfhoming/target", "rfhoming/events"}, topics
    assert next(h for h in heard if h["topic"] == "rfhoming/target")["frame"] == "odom"
    assert {"topic": "rfhoming/events", "what": "arrived"} in heard
    assert all(h["child"] == "base_link" and h["frame"] == "odom" for h in heard if h["topic"] == "odom")
    assert next(h for h in heard if h["topic"] == "odom")["child"] == "base_link"
    assert ["odom", "base_link"] in next(h for h in heard if h["topic"] == "tf")["frames"]
    commands = [(h["v"], h["w"]) for h in heard if h["topic"] == "cmd_vel"]
    assert any(v > 0.1 for v, _ in commands) and commands[-3:] == [(0.0, 0.0)] * 3
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["arrived"]
    last = json.loads(truth.read_text().splitlines()[-1])
    target = last["targets"][0]
    assert math.dist((last["robot"]["x"], last["robot"]["y"]), (target["x"], target["y"])) < 1.0
    with (tmp_path / "run.mcap").open("rb") as f:  # the MCAP recording has the ROS 2 base's odometry
        topics_recorded = Counter(channel.topic for _, channel, _ in make_reader(f).iter_messages())
    assert topics_recorded["/odom"] > 100 and topics_recorded["/tf"] > 100 and topics_recorded["/rfhoming/cmd_vel"] > 10
    replay_log = tmp_path / "replayed.jsonl"
    done = rfhoming("replay", str(tmp_path / "run.pcapng"), "--run", "--log", str(replay_log))
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["replay"] == {"diverged": 0, "unanswered": 0, "first_divergence": None}
    live = [line for line in (tmp_path / "run.jsonl").read_text().splitlines() if '"kind": "stall"' not in line]
    assert replay_log.read_text().splitlines() == live  # all but the live loop's stalls, which wall time made
