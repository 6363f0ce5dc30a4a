"""`rfhoming emulate --robot mavlink` + `rfhoming run --base mavlink:udpin:127.0.0.1:PORT` in their
own processes: a silent address and a disarmed vehicle are one-line errors (rfhoming never arms
unasked), the run with arm=1 drives the emulated rover to the tag (checked on the emulator's
truth), its capture holds the MAVLink packets on their own interface, and `replay --run` of it
gives the same run log."""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pymavlink")

from stalls import reproducible

from rfhoming.host.replay import read_capture  # noqa: E402
from rfhoming.protocol import mavlink as ml  # noqa: E402
from rfhoming.protocol import pcapng  # noqa: E402


def rfhoming(*args: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rfhoming", *args], capture_output=True, text=True, timeout=timeout)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def said(done: subprocess.CompletedProcess[str]) -> list[str]:
    return [line for line in done.stderr.splitlines() if "event loop blocked" not in line]


@pytest.mark.slow
def test_a_mavlink_rover_homes_and_its_capture_replays(tmp_path: Path, emulated) -> None:  # noqa: ANN001
    port = free_udp_port()
    truth = tmp_path / "truth.jsonl"
    world = emulated("s0-open", "--robot", f"mavlink:udpout:127.0.0.1:{port}", "--truth", str(truth),
                     link_dir=tmp_path, devices=2)
    try:
        base, aoa = world.path("base"), world.path("aoa")
        assert base == f"mavlink:udpin:127.0.0.1:{port}"
        silent = rfhoming("run", "--aoa", aoa, "--base", f"mavlink:udpin:127.0.0.1:{free_udp_port()},timeout=2")
        assert silent.returncode == 2 and len(said(silent)) == 1, silent.stderr
        assert "HEARTBEAT" in silent.stderr
        disarmed = rfhoming("run", "--aoa", aoa, "--base", base)
        assert disarmed.returncode == 2 and "arm=1" in said(disarmed)[-1], disarmed.stderr
        assert sum("rfhoming run:" in line for line in said(disarmed)) == 1
        run = rfhoming("run", "--aoa", aoa, "--base", f"{base},arm=1", "--capture", str(tmp_path / "run.pcapng"),
                       "--log", str(tmp_path / "run.jsonl"))
    finally:
        world.stop()  # the truth file is whole once it has ended
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["arrived"]
    last = json.loads(truth.read_text().splitlines()[-1])
    target = last["targets"][0]
    assert math.dist((last["robot"]["x"], last["robot"]["y"]), (target["x"], target["y"])) < 1.0
    interfaces, packets, _, _ = read_capture(tmp_path / "run.pcapng")
    k = next(i for i, iface in enumerate(interfaces) if iface.name == base.removeprefix("mavlink:"))
    assert interfaces[k].linktype == pcapng.LINKTYPE_MAVLINK == 152
    inbound = {m.get_type() for p in packets[k] if p.direction == pcapng.INBOUND for m in ml.Codec(1, 1).feed(p.data)}
    outbound = [m for p in packets[k] if p.direction == pcapng.OUTBOUND for m in ml.Codec(1, 1).feed(p.data)]
    assert {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "COMMAND_ACK"} <= inbound
    setpoints = [m for m in outbound if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert any(m.vx > 0.1 for m in setpoints) and (setpoints[-1].vx, setpoints[-1].yaw_rate) == (0.0, 0.0)
    assert outbound[-1].get_type() == "COMMAND_LONG" and outbound[-1].param2 == ml.ARDUPILOT_ROVER.hold  # left in HOLD
    replay_log = tmp_path / "replayed.jsonl"
    done = rfhoming("replay", str(tmp_path / "run.pcapng"), "--run", "--log", str(replay_log))
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["replay"] == {"diverged": 0, "unanswered": 0, "first_divergence": None}
    assert reproducible(replay_log.read_text()) == reproducible((tmp_path / "run.jsonl").read_text())
