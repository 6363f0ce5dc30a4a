"""Port specs: parsing, errors that name the key, the config's [devices], and per-port settings
used for real against the emulator (tags on `listen`, two baud rates on `run`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import rigs
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.host.homing.config import ConfigError, load
from rfhoming.host.portspec import PortSpec, PortSpecError, allowed, parse

RFHOMING = [sys.executable, "-m", "rfhoming"]


def test_the_issue_examples_parse() -> None:
    spec = parse("xplr-aoa:/dev/ttyUSB0,baud=1000000,flow=rtscts,tags=CCF9578E0D8A+ccf9578e0d8b")
    assert (spec.kind, spec.where, spec.baud, spec.flow) == ("xplr-aoa", "/dev/ttyUSB0", 1000000, "rtscts")
    assert spec.tags == ("CCF9578E0D8A", "CCF9578E0D8B")
    assert parse("rss-node:socket://127.0.0.1:5001") == PortSpec("rss-node", "socket://127.0.0.1:5001", {})
    assert parse("base:/dev/ttyACM1,baud=115200").baud == 115200
    assert parse("auto") == PortSpec(None, "auto", {})
    assert parse("socket://127.0.0.1:5001,baud=9600") == PortSpec(None, "socket://127.0.0.1:5001", {"baud": 9600})
    assert parse("capture:run.pcapng,device=aoa").settings == {"device": "aoa"}


@pytest.mark.parametrize(("text", "says"), [
    ("xplr-aoa:/dev/x,bauds=1", "unknown setting 'bauds'"),
    ("xplr-aoa:/dev/x,baud=fast", "bad baud='fast'"),
    ("xplr-aoa:/dev/x,flow=on", "rtscts"),
    ("xplr-aoa:/dev/x,tags=XYZ", "12-hex-digit"),
    ("base:/dev/x,tags=CCF9578E0D8A", "unknown setting 'tags'"),
    ("ublox-aoa=/dev/x", "write ublox-aoa:/dev/x"),
    ("bluetooth:/dev/x", "unknown device kind 'bluetooth'"),
    ("xplr-aoa:", "names no device"),
    ("/dev/x,baud=9600,oops", "not key=value"),
    ("", "empty port spec"),
])
def test_bad_specs_say_what_is_allowed(text: str, says: str) -> None:
    with pytest.raises(PortSpecError, match=says.replace("(", r"\(")):
        parse(text)


SETTINGS = st.fixed_dictionaries({}, optional={
    "baud": st.integers(300, 4_000_000),
    "flow": st.sampled_from(["rtscts", "none", "auto"]),
    "tags": st.lists(st.text("0123456789ABCDEF", min_size=12, max_size=12), min_size=1, max_size=3).map(tuple),
    "name": st.from_regex(r"[A-Za-z0-9_.-]{1,32}", fullmatch=True),
    "timeout": st.floats(0.01, 3000, allow_nan=False).map(lambda x: round(x, 3)),
})
WHERE = st.sampled_from(["/dev/ttyUSB0", "COM3", "socket://127.0.0.1:5001", "auto", "/tmp/x,y/aoa"])


@given(WHERE, SETTINGS)
def test_str_and_parse_round_trip(where: str, settings: dict) -> None:
    spec = PortSpec("xplr-aoa", where, settings)
    assert parse(str(spec)) == spec
    assert set(settings) <= set(allowed("xplr-aoa"))


def test_config_devices_tables(tmp_path: Path) -> None:
    good = tmp_path / "robot.toml"
    good.write_text('[devices.aoa]\nport = "xplr-aoa:/dev/ttyUSB0"\nbaud = 1000000\ntags = ["CCF9578E0D8A"]\n'
                    '[devices.base]\nport = "base:/dev/ttyACM0,baud=57600"\nbaud = 115200\n')
    devices = load(good).devices
    assert devices["aoa"] == PortSpec("xplr-aoa", "/dev/ttyUSB0", {"baud": 1000000, "tags": ("CCF9578E0D8A",)})
    assert devices["base"].baud == 57600  # the port string's own setting wins over the table's
    bad = tmp_path / "bad.toml"
    bad.write_text('[devices.aoa]\nport = "xplr-aoa:/dev/ttyUSB0"\nflow = "maybe"\n')
    with pytest.raises(ConfigError, match=r"\[devices.aoa\].*bad flow='maybe'"):
        load(bad)
    bad.write_text('[devices.lidar]\nport = "/dev/x"\n')
    with pytest.raises(ConfigError, match="the devices are aoa, base, rss, ble"):
        load(bad)


TWO_TAGS = """\
name = "two-tags"
description = "two AoA tags in view, the XPLR-AOA at 1 Mbd and the base at 57600 Bd"
bounds = [-10.0, -10.0, 10.0, 10.0]

[robot]
start = [0.0, 0.0, 0.0]

[aoa]
kind = "gaussian"
angle_deg = 3.0

[[targets]]
id = "CCF9578E0D8A"
kind = "aoa_tag"
position = [4.0, 1.5]
interval_ms = 20

[[targets]]
id = "CCF9578E0D8B"
kind = "aoa_tag"
position = [-5.0, 3.0]
interval_ms = 20

[devices.aoa]
type = "xplr-aoa"
baud = 1000000

[devices.base]
type = "base"
baud = 57600
"""


def emulate(emulated, tmp_path: Path, *extra: str) -> rigs.World:
    """The two-tag world (the fixture ``emulated`` stops it)."""
    scenario = tmp_path / "two-tags.toml"
    scenario.write_text(TWO_TAGS)
    return emulated(scenario, "--seed", "2", *extra, link_dir=tmp_path)


@pytest.mark.slow
def test_listen_with_tags_prints_only_the_chosen_tag(tmp_path: Path, emulated) -> None:
    with emulate(emulated, tmp_path) as world:
        ports = world.paths
        done = subprocess.run([*RFHOMING, "listen", f"xplr-aoa:{ports['aoa']},baud=1000000,tags=CCF9578E0D8B",
                               "--duration", "4", "--json"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    items = [json.loads(line) for line in done.stdout.splitlines()]
    angles = [i for i in items if i["kind"] == "angle"]
    counters = items[-1]
    assert len(angles) > 50, items[-1]  # the board at 1 Mbd understood the host at 1 Mbd
    assert {a["instance_id"] for a in angles} == {"CCF9578E0D8B"}  # printed: only the chosen tag
    # tags= set the board's own filter (AT+UDFFILT): the other tag stopped crowding the link,
    # only what was queued before the restart reached the host filter
    assert counters["filtered"] < 10 and counters["board_filter_leaks"] == 0


@pytest.mark.slow
def test_listen_at_the_wrong_rate_sees_no_angles(tmp_path: Path, emulated) -> None:
    """The per-port rate is real: at the --baud default the same board is garbage."""
    with emulate(emulated, tmp_path) as world:
        ports = world.paths
        done = subprocess.run([*RFHOMING, "listen", f"xplr-aoa:{ports['aoa']}", "--duration", "3", "--json"],
                              capture_output=True, text=True, timeout=60)
    items = [json.loads(line) for line in done.stdout.splitlines()]
    assert not [i for i in items if i["kind"] == "angle"] and items[-1].get("decoder.angle", 0) == 0
    assert items[-1]["bytes_in"] > 0  # it heard bytes, only none it could read


def test_run_with_two_ports_at_different_rates_homes(tmp_path: Path, emulated) -> None:
    world = emulate(emulated, tmp_path, "--lockstep", "--truth", str(tmp_path / "truth.jsonl"))
    ports = world.paths
    config = tmp_path / "robot.toml"
    config.write_text("[loop]\nodometry_wall_timeout_s = inf\n"  # lockstep: wall time means nothing
                      '[devices.aoa]\nport = "xplr-aoa:' + ports["aoa"] + '"\nbaud = 1000000\n')
    with world:
        done = subprocess.run([*RFHOMING, "run", "--config", str(config), "--base", f"base:{ports['base']},baud=57600",
                               "--aoa", f"{ports['aoa']},tags=CCF9578E0D8A", "--flow", "rtscts"],
                              capture_output=True, text=True, timeout=110)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout.splitlines()[-1])
    assert summary["arrived"], summary
    truth = [json.loads(line) for line in (tmp_path / "truth.jsonl").read_text().splitlines()]
    robot = truth[-1]["robot"]
    assert abs(robot["x"] - 4.0) < 1.0 and abs(robot["y"] - 1.5) < 1.0, robot  # at the chosen tag
