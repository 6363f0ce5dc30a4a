"""A lying vehicle, in processes: ``rfhoming run --base mavlink:udpout:...,arm=1`` against a
vehicle that lies (tests/hostile_vehicle.py, on UDP loopback; the AoA board is the emulator's).
A vehicle sending NaN, one whose HEARTBEAT stops, someone speaking as it from another port, a
refused (also of a vehicle already in GUIDED) or unanswered arming: the run stops (or refuses to start) with one line and exit 2, and
the vehicle was last told HOLD. A pilot's mode change ends it as taken over (exit 1, in its summary and log), and the pilot's mode stands.
SIGTERM and the run's own end leave it in HOLD as well. Before the fix the vehicle stayed in
GUIDED after a refusal, NaN, a lost HEARTBEAT and another port's packets were driven on for
as long as the run lasted, and an error came out as two lines."""

from __future__ import annotations

import json
import math
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("pymavlink")

import rigs  # noqa: E402
from hostile_vehicle import HostileVehicle  # noqa: E402
from pymavlink.dialects.v20 import common as mav  # noqa: E402

DRIVEN_S = 120.0  # hang guards, not speed checks
ENDED_S = 240.0


@pytest.fixture(scope="module")
def aoa(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with rigs.emulate("s0-open", "--seed", "3", link_dir=tmp_path_factory.mktemp("links")) as world:
        yield world.path("aoa")


def said(child: rigs.Child) -> list[str]:
    """stderr without the event loop's stall warnings (a loaded machine's, not the run's)."""
    return [line for line in child.stderr().splitlines() if "event loop blocked" not in line]


def nan(vehicle: HostileVehicle, run: rigs.Child) -> None:
    vehicle.position = (math.nan, 0.0)


def heartbeat_stops(vehicle: HostileVehicle, run: rigs.Child) -> None:
    vehicle.heartbeats = False


def another_port(vehicle: HostileVehicle, run: rigs.Child) -> None:
    vehicle.impostor(vehicle.system, "MANUAL", north=40.0)


def pilot(vehicle: HostileVehicle, run: rigs.Child) -> None:
    vehicle.switch_to("MANUAL")


def sigterm(vehicle: HostileVehicle, run: rigs.Child) -> None:
    run.send_signal(signal.SIGTERM)


Case = tuple[str, dict[str, Any], Callable[[HostileVehicle, rigs.Child], None] | None, int, str | None]
CASES: list[Any] = [
    pytest.param("nan", {}, nan, 2, "LOCAL_POSITION_NED.x = nan", id="nan"),
    pytest.param("heartbeat", {}, heartbeat_stops, 2, "no HEARTBEAT", id="heartbeat-stops", marks=pytest.mark.slow),
    pytest.param("port", {}, another_port, 2, "speaks as the vehicle", id="another-port", marks=pytest.mark.slow),
    pytest.param("arm", {"refuse_arm": True}, None, 2, "refused arming", id="refused-arm", marks=pytest.mark.slow),
    pytest.param("arm-guided", {"refuse_arm": True, "mode": 15}, None, 2, "refused arming", id="refused-arm-in-guided",
                 marks=pytest.mark.slow),
    pytest.param("ack", {"unanswered": {mav.MAV_CMD_COMPONENT_ARM_DISARM}}, None, 2, "no COMMAND_ACK", id="no-ack",
                 marks=pytest.mark.slow),
    pytest.param("pilot", {}, pilot, 1, "left GUIDED for MANUAL", id="pilot-mode", marks=pytest.mark.slow),
    pytest.param("sigterm", {}, sigterm, 128 + signal.SIGTERM, "the base was told to stop", id="sigterm", marks=pytest.mark.slow),
    pytest.param("end", {}, None, 1, None, id="end-of-run", marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("name", "lies", "fault", "code", "line"), CASES)
def test_every_exit_is_one_line_and_leaves_the_vehicle_holding(
        tmp_path: Path, aoa: str, name: str, lies: dict[str, Any],
        fault: Callable[[HostileVehicle, rigs.Child], None] | None, code: int, line: str | None) -> None:
    log, config = tmp_path / "run.jsonl", tmp_path / "run.toml"
    config.write_text(f"[loop]\nmax_time_s = {2.0 if name == 'end' else 600.0}\n")
    with HostileVehicle() as vehicle:
        for key, value in lies.items():
            setattr(vehicle, key, value)
        argv = [*rigs.RFHOMING, "run", "--aoa", aoa, "--base", f"mavlink:udpout:127.0.0.1:{vehicle.port},arm=1",
                "--config", str(config), "--log", str(log)]
        with rigs.Child(argv) as run:
            if fault is not None:
                assert vehicle.driven.wait(DRIVEN_S), "the run never drove the vehicle"
                fault(vehicle, run)
            assert run.wait(ENDED_S) == code, run.stderr()
            lines = said(run)
    if line is None:
        assert lines == [] and json.loads(run.stdout())["reason"]
    elif name == "pilot":  # taken over: not an error but the run's end, in its summary and log
        summary = json.loads(run.stdout())
        assert summary["reason"] == "taken over" and summary["taken_over"]["mode"] == "MANUAL", summary
        assert len(lines) == 1 and line in lines[0] and "WARNING" in lines[0], lines
        ends = [json.loads(r) for r in log.read_text().splitlines() if '"taken over"' in r]
        assert [(e["what"], e["mode"]) for e in ends] == [("taken over", "MANUAL")]
    else:
        assert len(lines) == 1 and line in lines[0] and lines[0].startswith("rfhoming run: "), lines
    asked = vehicle.modes_asked()
    if name == "pilot":
        assert asked == ["GUIDED"] and vehicle.mode == 0  # nothing over the pilot's MANUAL
    elif name == "arm-guided":  # already in GUIDED: no switch asked, and still left holding
        assert asked == ["HOLD"] and vehicle.mode == 4, asked
    else:
        assert asked[0] == "GUIDED" and asked[-1] == "HOLD" and vehicle.mode == 4, asked
    began = name not in ("arm", "arm-guided", "ack")  # arming refused or unanswered: the run never began, no log replaced
    assert log.exists() == began and not log.with_name("run.jsonl.part").exists(), name
    if began:  # strict JSON: no bare NaN or Infinity, whatever the vehicle sent
        for record in log.read_text().splitlines():
            json.loads(record, parse_constant=lambda token: pytest.fail(f"{token} in the run log"))
