"""Done-when of the emulator: a program that knows nothing of it opens the printed ptys with
plain pyserial, as it would open /dev/ttyACM0, and the data agrees with --truth."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rigs
import serial

from rfhoming.protocol.frames import AntennaSet, FrameDecoder, Odometry, VelocityCommand, encode_frame
from rfhoming.protocol.uconnect import UConnectDecoder


def emulate(scenario: str, *args: str, devices: int) -> tuple[rigs.World, dict[str, dict]]:
    world = rigs.emulate(scenario, *args, devices=devices)
    return world, world.endpoints


def stop(proc: rigs.World) -> int:
    """Ctrl-C and its exit code; stopped harder if it does not end."""
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=10)
    finally:
        proc.stop()


def read_for(port: serial.Serial, seconds: float) -> bytes:
    data, end = b"", time.monotonic() + seconds
    while time.monotonic() < end:
        data += port.read(4096)
    return data


def command(port: serial.Serial, line: bytes, timeout: float = 5) -> bytes:
    port.write(line + b"\r")
    data, end = b"", time.monotonic() + timeout
    while b"OK\r\n" not in data and b"ERROR\r\n" not in data and time.monotonic() < end:
        data += port.read(4096)
    return data


def wake(port: serial.Serial) -> None:
    """Say AT until the board answers: it ignores the host for a second after +STARTUP."""
    end = time.monotonic() + 5
    while b"OK\r\n" not in command(port, b"AT", 0.3):
        assert time.monotonic() < end, "the board never answered AT"


@pytest.mark.slow
def test_plain_pyserial_at_session_and_angles_match_truth(tmp_path: Path) -> None:
    truth_file = tmp_path / "truth.jsonl"
    proc, endpoints = emulate("s0-open", "--pty", "--seed", "5", "--target", "3,2", "--radio", "ideal",
                              "--truth", str(truth_file), "--link-dir", str(tmp_path), devices=2)
    try:
        aoa = endpoints["aoa"]
        assert (aoa["kind"], aoa["protocol"]) == ("xplr-aoa", "uconnect") and Path(aoa["path"]).exists()
        port = serial.Serial(aoa["path"], 115200, rtscts=False, timeout=0.05)
        wake(port)
        assert b"NINA-B411-40B" in command(port, b"AT+GMM")
        assert b"OK\r\n" in command(port, b"AT+UDFENABLE=1")
        events = [i for i in UConnectDecoder().feed(read_for(port, 2.0)) if i.kind == "angle"]
        port.close()
    finally:
        assert stop(proc) == 0
    assert not Path(aoa["path"]).exists()  # symlinks removed on Ctrl-C
    truth = json.loads(truth_file.read_text().splitlines()[-1])
    robot, target = truth["robot"], truth["targets"][0]
    expected = -math.degrees(math.atan2(target["y"] - robot["y"], target["x"] - robot["x"]) - robot["theta"])
    errors = [e.azimuth - expected for e in events]
    assert len(errors) > 40
    assert abs(sum(errors) / len(errors)) < 1.5  # configured noise: σ = 3° at boresight
    assert max(map(abs, errors)) < 6 * 3.0 + 1


PROBES = [b'AT+UDFCFG=2,"a"b"', b'AT+UDFCFG=2,"\xff"', b"AT+UDFCFG=2", b"AT+UDFCFG?", b"AT+UDFFILT=2",
          b"x" * 512 + b"AT+GMM", b"AT+UDFCFG=1,1_000", b"AT+UDFCFG=1, 5", b"AT+UDFCFG=1,+5", b"AT+UDFCFG=1,0005",
          b'AT+UDFFILT=2,2,"GGGGGGGGGGGG"', b"AT+UDFCFG=1,", b"AT&W"]


@pytest.mark.slow
def test_hostile_at_commands_never_kill_the_emulator(tmp_path: Path) -> None:
    """Lines that once crashed the board model or got no answer (a quote or a non-ASCII byte in a
    string setting, then reads of it; an overflowed line; loose integers; non-hex tag ids): each gets a final result code; after AT&W and AT+CPWROFF the board
    boots and keeps sending angle events."""
    proc, endpoints = emulate("s0-open", "--pty", "--seed", "5", "--target", "3,2",
                              "--link-dir", str(tmp_path), devices=2)
    try:
        port = serial.Serial(endpoints["aoa"]["path"], 115200, rtscts=False, timeout=0.05)
        wake(port)
        for probe in PROBES:
            finals = [i.ok for i in UConnectDecoder().feed(command(port, probe)) if i.kind == "final"]
            assert finals == [probe in (b"AT+UDFCFG=2", b"AT+UDFCFG?", b"AT+UDFFILT=2", b"AT&W")], probe
        assert b"OK\r\n" in command(port, b"AT+CPWROFF")
        time.sleep(0.5)
        wake(port)
        events = [i for i in UConnectDecoder().feed(read_for(port, 1.5)) if i.kind == "angle"]
        assert proc.poll() is None and len(events) > 10
        port.close()
    finally:
        assert stop(proc) == 0


@pytest.mark.slow
def test_rss_node_and_base_over_their_framing(tmp_path: Path) -> None:
    truth_file = tmp_path / "truth.jsonl"
    proc, endpoints = emulate("s2-a", "--pty", "--seed", "2", "--truth", str(truth_file),
                              "--link-dir", str(tmp_path), devices=2)
    try:
        rss = serial.Serial(endpoints["rss"]["path"], 115200, timeout=0.05)
        base = serial.Serial(endpoints["base"]["path"], 115200, timeout=0.05)
        base.write(encode_frame(VelocityCommand(0, 1, 0, 200, 0, 3000)))
        sets = [r for r in FrameDecoder().feed(read_for(rss, 1.5)) if isinstance(r, AntennaSet)]
        odometry = [r for r in FrameDecoder().feed(read_for(base, 1.0)) if isinstance(r, Odometry)]
        rss.close()
        base.close()
    finally:
        assert stop(proc) == 0
    assert len(sets) > 10
    front = sum(s.antennas[0].ed for s in sets) / len(sets)
    assert all(front > sum(s.antennas[i].ed for s in sets) / len(sets) + 3 for i in (1, 2, 3))
    truth = [json.loads(line) for line in truth_file.read_text().splitlines()]
    assert odometry[-1].x_mm > 100
    moved = truth[-1]["robot"]["x"]
    assert odometry[-1].x_mm / 1000 == pytest.approx(moved, abs=0.1)


def test_bad_arguments_exit_2_with_a_message() -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "emulate", "s0-open", "--target", "x"],
                          capture_output=True, text=True, env={**os.environ}, timeout=60)
    assert done.returncode == 2 and "argument --target: 'x': expected X,Y in metres" in done.stderr


def test_missing_link_dir_is_a_clear_error(tmp_path: Path) -> None:
    missing = tmp_path / "no" / "such"
    done = subprocess.run([sys.executable, "-m", "rfhoming", "emulate", "s0-open", "--link-dir", str(missing),
                           "--duration", "1"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert f"--link-dir {missing} is not a directory" in done.stderr


def test_every_option_a_message_names_exists() -> None:
    """Messages telling the user to "use --x" (the baud mismatch says --probe-baud) name real options."""
    import re

    from rfhoming.cli.main import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if a.choices and "listen" in a.choices).choices
    options = {o for sub in commands.values() for a in sub._actions for o in a.option_strings}
    root = Path(__file__).parent.parent
    told = {m for folder in ("host", "rfhoming", "emulator") for f in (root / folder).rglob("*.py")
            for m in re.findall(r"use (--[a-z][a-z-]+)", f.read_text())}
    assert "--probe-baud" in told
    assert told <= options, told - options


def test_stopping_with_a_tcp_client_connected_prints_no_traceback() -> None:
    """The client's handler is cancelled at shutdown; Python 3.11's server callback logged that
    as an error with a traceback unless the handler ends normally."""
    import socket

    proc, endpoints = emulate("s0-open", "--tcp", devices=2)
    host, port = endpoints["base"]["url"].removeprefix("socket://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as client:
        assert client.recv(1)  # the base streams odometry: its handler is running
        code = stop(proc)
    stderr = proc.stderr()
    assert code == 0 and "Traceback" not in stderr and "CancelledError" not in stderr, stderr


def test_tcp_mode_prints_path_like_the_pty_mode() -> None:
    """docs/api.md reads ``["path"]``: it must work when a user switches to --tcp."""
    with rigs.emulate("s0-open", "--tcp", "--duration", "0.5", devices=1) as proc:
        endpoint = next(iter(proc.endpoints.values()))
    assert endpoint["path"].startswith("socket://127.0.0.1:") and endpoint["url"] == endpoint["path"]
