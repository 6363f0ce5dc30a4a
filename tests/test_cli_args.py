"""Command-line arguments that cannot work are refused by the parser -- exit 2 and the reason --
before any device is opened or emulator started: non-finite or negative numbers, a target that
is not X,Y, an output file that cannot be created."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import shutil
import signal
import socket
import socketserver
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rfhoming.cli.main import build_parser
from rfhoming.demo import DemoError, start_emulator
from rfhoming.host.outputs import part_of

RFHOMING = [sys.executable, "-m", "rfhoming"]
SITE = str(Path(__file__).resolve().parent.parent / "docs" / "sites" / "kit-room.toml")


@pytest.mark.parametrize("argv,message", [
    (["locate", SITE, "--duration", "nan"], "argument --duration: 'nan': expected a finite number"),
    (["locate", SITE, "--accel-psd", "nan"], "argument --accel-psd: 'nan': expected a finite number"),
    (["locate", SITE, "--rate", "0"], "argument --rate: '0': expected a number more than 0 and at most 1,000"),
    (["listen", "auto", "--duration", "-1"], "argument --duration: '-1': expected a number more than 0 and at most"),
    (["replay", "x.pcapng", "--speed", "inf"], "argument --speed: 'inf': expected a finite number"),
    (["emulate", "s0-open", "--duration", "x"], "argument --duration: 'x' is not a number more than 0"),
    (["emulate", "s0-open", "--target=1,nan"], "argument --target: '1,nan': expected X,Y in metres"),
    (["demo", "--target", "x"], "argument --target: 'x': expected X,Y in metres"),
    (["serve", "auto", "--queue", "0"], "argument --queue: '0': expected a whole number from 1 to 1,000,000"),
    (["capture", "-o", "/proc/forbidden.pcapng", "/dev/ttyNOPE"], "argument -o/--output: cannot write '/proc/forbidden"),
    (["run", "--log", "/no/such/folder/run.jsonl"], "argument --log: cannot write '/no/such/folder/run.jsonl'"),
])
def test_the_parser_refuses(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_a_writable_output_is_not_left_behind_by_the_check(tmp_path: Path) -> None:
    out = tmp_path / "run.pcapng"
    args = build_parser().parse_args(["capture", "-o", str(out), "/dev/ttyNOPE"])
    assert args.output == out and not out.exists()


def test_capture_to_a_forbidden_path_opens_no_device() -> None:
    done = subprocess.run([*RFHOMING, "capture", "-o", "/proc/forbidden.pcapng", "/dev/ttyNOPE"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "cannot write '/proc/forbidden.pcapng'" in done.stderr and "ttyNOPE" not in done.stderr.splitlines()[-1]


def test_an_emulator_that_does_not_start_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(DemoError, match=r"the emulator did not start: rfhoming emulate: no scenario 'nope'"):
        start_emulator("nope", 1, tmp_path / "truth.jsonl", tmp_path, None)


# -- every value a new user tried that the parser took, then crashed or hung on ---------------------
BROKER = "mqtt://127.0.0.1:9/4"  # no broker: the parser alone must refuse these


@pytest.mark.parametrize("argv,message", [
    # accepted, then a bug report (exit 1)
    (["emulate", "s0-open", "--seed", "-1"], "argument --seed: '-1': expected a whole number from 0 to 4,294,967,295"),
    (["demo", "--seed", "-1"], "argument --seed: '-1': expected a whole number from 0"),
    (["campaign", "s1-dock", "--seed", "-1"], "argument --seed: '-1': expected a whole number from 0"),
    (["demo", "--wait-viewer", "1e308"], "argument --wait-viewer: '1e308': expected a number from 0 to 10,000,000"),
    (["campaign", "s1-dock", "--workers", "99999999999"], "argument --workers: '99999999999': expected a whole "
                                                          "number from 1 to 256"),
    (["campaign", "s1-dock", "--dask", "a/#"], "argument --dask: 'a/#': expected a scheduler address HOST:PORT"),
    (["locate", SITE, "--id", "a/#"], "argument --id: 'a/#': expected a name of 1 to 64 letters"),
    (["gateway", "--broker", BROKER, "--emulate", "site-8x10", "--site-name", "a/+/#"],
     "argument --site-name: 'a/+/#': expected a name of 1 to 64 letters"),
    # hangs past --duration and through Ctrl-C
    (["emulate", "s0-open", "--fault", "garbage:every=0,len=1"],
     "argument --fault: every='0' in 'garbage:every=0,len=1': expected a number from 0.001"),
    (["locate", SITE, "--from", "mqtt://127.0.0.1:9/1000000000", "--duration", "3"],
     "argument --from: 'mqtt://127.0.0.1:9/1000000000': the path is the site's partition count, a whole number in 1..1024"),
    (["gateway", "--broker", BROKER, "--emulate", "site-8x10", "--flush", "1e308", "--duration", "4"],
     "argument --flush: '1e308': expected a number from 0.001 to 60"),
    # nonsense accepted with exit 0
    (["emulate", "s0-open", "--fault", "unplug:at=nan"], "argument --fault: at='nan' in 'unplug:at=nan': expected a "
                                                         "number from 0 to 1e+07"),
    (["emulate", "s0-open", "--fault", "unplug:at=1,for=inf"], "for='inf' in 'unplug:at=1,for=inf': expected"),
    (["emulate", "s0-open", "--fault", "ber:rate=nan"], "rate='nan' in 'ber:rate=nan': expected a number from 0 to 1"),
    (["emulate", "s0-open", "--fault", "ber:rate=2"], "rate='2' in 'ber:rate=2': expected a number from 0 to 1"),
    (["emulate", "s0-open", "--fault", "drop:rate=-1"], "rate='-1' in 'drop:rate=-1': expected a number from 0 to 1"),
    (["emulate", "s0-open", "--fault", "baud:at=1,rate=0"], "rate='0' in 'baud:at=1,rate=0': expected a whole number"),
    (["locate", SITE, "--from", "mqtt://127.0.0.1:9/0"], "the path is the site's partition count, a whole number in 1..1024"),
    (["locate", SITE, "--id", ""], "argument --id: '': expected a name"),
    (["gateway", "--broker", BROKER, "--emulate", "site-8x10", "--tag-rate", "1e308"],
     "argument --tag-rate: '1e308': expected a number more than 0 and at most 1,000"),
    (["demo", "--out", ""], "argument --out: an empty value"),
])
def test_what_was_taken_then_failed_is_refused_by_the_parser(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and message in err, err


def test_sane_fault_specs_still_parse() -> None:
    for spec in ("unplug@aoa:at=5,for=2", "unplug:at=0", "ber:rate=1e-5", "drop:rate=1", "garbage:every=0.5,len=16",
                 "reboot:at=3", "baud:at=2,rate=9600"):
        assert build_parser().parse_args(["emulate", "s0-open", "--fault", spec]).fault == [spec]


@pytest.mark.parametrize("argv", [
    ["emulate", "s0-open", "--tcp", "--fault", "garbage:every=0,len=1", "--duration", "1"],
    ["gateway", "--broker", BROKER, "--emulate", "site-8x10", "--flush", "1e308", "--duration", "1"],
    ["campaign", "s1-dock", "--runs", "1", "--workers", "99999999999", "--quiet"],
    ["demo", "--seed", "-1"],
])
def test_a_refused_value_is_one_line_and_exit_2(argv: list[str], tmp_path: Path) -> None:
    """The real command: the refusal happens before anything starts (a hang guard of 60 s, never a
    measure of speed)."""
    done = subprocess.run([*RFHOMING, *argv], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and done.stderr.splitlines()[-1].startswith(f"rfhoming {argv[0]}: error:")


# -- every option of every command, against hostile values ----------------------------------------
REQUIRED = {  # what each command needs besides the option under test, none of it opened by the parser
    "decode": ["--protocol", "frames"], "config": ["--print-default"], "listen": ["auto"], "serve": ["auto"],
    "capture": ["-o", "/tmp/never-written.pcapng", "auto"], "replay": ["x.pcapng"], "locate": [SITE],
    "calibrate": [SITE], "emulate": ["s0-open"], "campaign": ["s1-dock"], "gateway": ["--broker", BROKER],
    "export": ["run.jsonl", "-o", "/tmp/never-written.mcap"],
    "radio-fit": [SITE, "--from", "capture:walk.pcapng", "-o", "/tmp/never-written.toml"],
}
NAMES = {("locate", "--id"), ("gateway", "--site-name"), ("gateway", "--name")}
"""Options whose value is one level of an MQTT topic: nothing but [A-Za-z0-9._-]{1,64}."""
HOSTILE = ["nan", "inf", "-inf", "+inf", "-1", "0", "-0", "1e308", "-1e308", "99999999999", "1e-320", "", " ",
           "a/#", "a/+/#", "#", "+", "/", "x" * 300, "\x00"]


def _options() -> list[tuple[str, argparse.Action]]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return [(name, action) for name, parser in sub.choices.items() for action in parser._actions
            if action.option_strings and action.nargs != 0 and not isinstance(action, argparse._HelpAction)]


OPTIONS = _options()
PARSER = build_parser()


def _sane(value: object) -> bool:
    """What an accepted value must be: a number finite, 0 or more and within a 32-bit seed; text
    (a spec the command checks when it opens it) not blank; a path not empty."""
    if isinstance(value, list):
        return all(_sane(v) for v in value)
    if isinstance(value, bool) or value is None:
        return True
    if isinstance(value, (int, float)):
        return math.isfinite(value) and 0 <= value <= 2**32
    if isinstance(value, Path):
        return str(value) != "."  # what an empty path would be
    return bool(value.strip())


def test_every_option_is_walked() -> None:
    commands = {name for name, _ in OPTIONS}
    assert len(OPTIONS) > 80 and {"demo", "run", "emulate", "gateway", "locate", "serve", "campaign"} <= commands


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(option=st.sampled_from(OPTIONS),
       text=st.sampled_from(HOSTILE) | st.floats().map(repr) | st.integers(-2**70, 2**70).map(str) | st.text(max_size=80))
def test_every_option_refuses_or_takes_a_sane_value(option: tuple[str, argparse.Action], text: str, capsys,
                                                    tmp_path: Path, monkeypatch) -> None:
    """Each option given a hostile value: either the parser refuses it (exit 2, the last line
    naming the option) or what it took is sane: a finite number in range, text that is not
    empty, a bus name without '/', '+' or '#'. (An output file is tried, then removed: here.)"""
    monkeypatch.chdir(tmp_path)
    command, action = option
    flag = max(action.option_strings, key=len)
    argv = [command, *REQUIRED.get(command, []), f"{flag}={text}"]
    try:
        args = PARSER.parse_args(argv)
    except SystemExit as stop:
        err = capsys.readouterr().err.strip().split("\n")  # what a terminal shows as lines
        assert stop.code == 2 and err[-1].startswith(f"rfhoming {command}: error: argument "), err
        return
    value = getattr(args, action.dest)
    assert _sane(value), (argv, value)
    if (command, flag) in NAMES:
        assert re.fullmatch(r"[A-Za-z0-9._-]{1,64}", value), (argv, value)


# -- --duration, Ctrl-C and SIGTERM end every command and every child it started ---------------------
def _wait_for(condition, what: str, deadline_s: float = 120.0) -> None:
    end = time.monotonic() + deadline_s  # a hang guard, not a measure of speed
    while not condition():
        assert time.monotonic() < end, f"still waiting for {what} after {deadline_s:g} s"
        time.sleep(0.1)


def _terminate_and_check_no_child_survives(proc: subprocess.Popen, children: list[psutil.Process]) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout=60)
        _, alive = psutil.wait_procs(children, timeout=30)
        assert not alive, f"left behind: {alive}"
        assert code == 128 + signal.SIGTERM  # ended as by Ctrl-C (its clean-up ran), said as SIGTERM
    finally:
        for p in [proc, *children]:
            with contextlib.suppress(psutil.NoSuchProcess, ProcessLookupError):
                p.kill()


@pytest.mark.slow
def test_sigterm_to_demo_ends_its_emulator(tmp_path: Path) -> None:
    """Sent when the homing has begun (the run log exists) at robot time, where the demo would
    run for a minute more: the demo and its emulator child are both gone."""
    out = tmp_path / "demo"
    proc = subprocess.Popen([*RFHOMING, "demo", "--speed", "1", "--out", str(out)], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _wait_for(lambda: part_of(out / "run.jsonl").exists() or proc.poll() is not None,  # run.jsonl once it ended
              "the homing to start")
    children = psutil.Process(proc.pid).children(recursive=True)
    assert children and any("emulate" in c.cmdline() for c in children)
    _terminate_and_check_no_child_survives(proc, children)


@pytest.mark.slow
def test_sigterm_to_campaign_ends_its_workers(tmp_path: Path) -> None:
    proc = subprocess.Popen([*RFHOMING, "campaign", "s2-scenarios", "--workers", "2", "--quiet", "--out",
                             str(tmp_path)], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    me = psutil.Process(proc.pid)
    _wait_for(lambda: len(me.children(recursive=True)) >= 2 or proc.poll() is not None, "the workers to start")
    _terminate_and_check_no_child_survives(proc, me.children(recursive=True))


class _Dropper(socketserver.ThreadingTCPServer):
    """A TCP 'device' that accepts and at once drops every connection (as an endpoint another
    client holds does), counting them."""

    daemon_threads = True
    accepted = 0


class _Drop(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        type(self.server).accepted += 1  # type: ignore[attr-defined]


@pytest.mark.slow
def test_a_device_that_drops_at_once_is_reopened_with_back_off() -> None:
    """serve given one TCP device twice reopened the second in a busy loop (9,145 warnings in
    6 s). Counted, not timed: with back-off (0.2 s doubling to 5 s) a 4 s run opens it at most
    ~6 times however fast the machine; without, hundreds. One warning for the streak."""
    with _Dropper(("127.0.0.1", 0), _Drop) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"xplr-aoa:socket://127.0.0.1:{server.server_address[1]}"
        done = subprocess.run([*RFHOMING, "serve", url, "--port", "0", "--duration", "4"],
                              capture_output=True, text=True, timeout=120)
        server.shutdown()
    assert done.returncode == 0, done.stderr
    counters = [json.loads(line) for line in done.stdout.splitlines() if '"counters"' in line][0]
    assert 2 <= _Dropper.accepted <= 10 and counters["opens"] <= 10, (_Dropper.accepted, counters)
    assert done.stderr.count("disconnected") == 1, done.stderr


needs_mosquitto = pytest.mark.skipif(not shutil.which("mosquitto", path=f"{os.environ.get('PATH', '')}:/usr/sbin"),
                                     reason="mosquitto not installed (.ci/run installs it)")


@pytest.mark.slow
@needs_mosquitto
def test_emulated_gateways_end_at_duration_and_at_sigterm(tmp_path: Path) -> None:
    """--flush 60 --duration 2 waited the whole minute, and a signal did not end the wait."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    broker = subprocess.Popen([shutil.which("mosquitto", path=f"{os.environ.get('PATH', '')}:/usr/sbin"), "-c",
                               str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        gateway = [*RFHOMING, "gateway", "--emulate", "site-8x10", "--broker", f"mqtt://127.0.0.1:{port}/4",
                   "--flush", "60"]
        done = subprocess.run([*gateway, "--duration", "2"], capture_output=True, text=True, timeout=45)
        assert done.returncode == 0 and '"kind": "gateways"' in done.stdout, done.stderr
        proc = subprocess.Popen(gateway, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        me = psutil.Process(proc.pid)
        _wait_for(lambda: proc.poll() is not None or any(c.raddr and c.raddr.port == port for c in me.net_connections()),
                  "the gateway to connect")  # then it waits out its minute's flush, until SIGTERM
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=45)
        assert proc.returncode == 0 and '"kind": "gateways"' in out
    finally:
        broker.kill()
        broker.wait()
