"""A ground station beside `rfhoming run` on the emulated vehicle's port, as a user would put
MAVProxy or QGroundControl there: pymavlink (not rfhoming's code) speaks to the vehicle from its
own socket. Both get the whole telemetry (every LOCAL_POSITION_NED rfhoming took, the ground
station took too) and the run has no stale stop; when the ground station switches the vehicle
to RTL, the run ends "taken over" (its summary and run.jsonl say RTL) and the vehicle drives
back to where it was armed. Before the fix the vehicle answered only its last sender: the
ground station's HEARTBEAT each second took the telemetry from rfhoming, and RTL stopped where
the vehicle was. The run's capture replays to the same run log, takeover and all."""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("pymavlink")

import rigs  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from stalls import reproducible  # noqa: E402

from rfhoming.host.replay import read_capture  # noqa: E402
from rfhoming.protocol import mavlink as ml  # noqa: E402
from rfhoming.protocol import pcapng  # noqa: E402

ROVER_RTL = 11  # ArduPilot Rover's custom mode (Rover/mode.h)
MOVED_M = 1.5  # the ground station takes over once the vehicle has driven this far
HANG_S = 180.0  # hang guards, not speed checks


class GroundStation:
    """pymavlink's ``udpout:`` link to the vehicle on a thread: a HEARTBEAT each second, every
    LOCAL_POSITION_NED kept (time_boot_ms, north, east), RTL on :meth:`rtl`."""

    def __init__(self, port: int) -> None:
        self.link: Any = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=254,
                                                    source_component=190)
        self.positions: list[tuple[int, float, float]] = []
        self.modes: list[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ground-station", daemon=True)

    def __enter__(self) -> GroundStation:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)
        self.link.close()

    def rtl(self) -> None:
        self.link.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0,
                                        mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ROVER_RTL, 0, 0, 0, 0, 0)

    def wait(self, ok: Any, what: str) -> None:
        deadline = time.monotonic() + HANG_S
        while not ok():
            assert time.monotonic() < deadline, f"the ground station never saw {what}"
            time.sleep(0.05)

    def _run(self) -> None:
        beat = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= beat:
                beat = time.monotonic() + 1.0
                self.link.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID,
                                             0, 0, 0)
            message = self.link.recv_match(blocking=True, timeout=0.1)
            if message is None or message.get_srcSystem() != 1:
                continue
            if message.get_type() == "LOCAL_POSITION_NED":
                self.positions.append((message.time_boot_ms, message.x, message.y))
            elif message.get_type() == "HEARTBEAT":
                self.modes.append(message.custom_mode)


@pytest.mark.slow
def test_a_ground_station_beside_the_run_gets_all_telemetry_and_its_rtl_goes_home(tmp_path: Path, emulated) -> None:  # noqa: ANN001
    world = emulated("s0-open", "--robot", "mavlink", "--seed", "3", link_dir=tmp_path, devices=2)
    vehicle = world.endpoints["base"]["mavlink"]["vehicle"]
    port = int(vehicle.rpartition(":")[2])
    log, capture = tmp_path / "run.jsonl", tmp_path / "run.pcapng"
    with GroundStation(port) as gcs:
        gcs.wait(lambda: gcs.positions, "the vehicle's telemetry")
        _, north0, east0 = gcs.positions[-1]  # where it stands, disarmed: it is armed there
        argv = [*rigs.RFHOMING, "run", "--aoa", world.path("aoa"), "--base", f"{world.path('base')},arm=1",
                "--log", str(log), "--capture", str(capture)]
        with rigs.Child(argv) as run:
            gcs.wait(lambda: math.dist(gcs.positions[-1][1:], (north0, east0)) > MOVED_M, "the vehicle driven")
            gcs.rtl()
            assert run.wait(HANG_S) == 1, run.stderr()
            summary = json.loads(run.stdout())
        gcs.wait(lambda: gcs.modes and gcs.modes[-1] == ROVER_RTL
                 and math.dist(gcs.positions[-1][1:], (north0, east0)) < 0.3, "the vehicle back where it was armed")
    assert summary["reason"] == "taken over" and summary["taken_over"]["mode"] == "RTL", summary
    assert summary["stale_stops"] == 0, summary
    records = [json.loads(line) for line in log.read_text().splitlines()]
    events = [r["what"] for r in records if r["kind"] == "event"]
    assert not any("stale" in e for e in events) and events[-1] == "taken over", events
    assert [r["mode"] for r in records if r.get("what") == "taken over"] == ["RTL"]
    interfaces, packets, _, _ = read_capture(capture)
    k = next(i for i, iface in enumerate(interfaces) if iface.name == world.path("base").removeprefix("mavlink:"))
    taken = {m.time_boot_ms for p in packets[k] if p.direction == pcapng.INBOUND for m in ml.Codec(1, 1).feed(p.data)
             if m.get_type() == "LOCAL_POSITION_NED"}
    seen = {ms for ms, _, _ in gcs.positions}
    assert len(taken) > 100 and len(taken - seen) <= len(taken) // 100, (len(taken), len(taken - seen))
    replayed = tmp_path / "replayed.jsonl"  # the takeover is in the capture's bytes: a replay ends alike
    done = rigs.run("replay", str(capture), "--run", "--log", str(replayed))
    assert done.returncode == 1 and json.loads(done.stdout)["taken_over"]["mode"] == "RTL", done.stderr
    assert reproducible(replayed.read_text()) == reproducible(log.read_text())


@pytest.mark.slow
def test_the_s4_air_demo_says_where_its_vehicle_is(tmp_path: Path) -> None:
    """`demo --scenario s4-air` prints the emulated copter's address as soon as it is up, and a
    ground station there hears the copter (stopped before the survey ends)."""
    with rigs.Child([*rigs.RFHOMING, "demo", "--scenario", "s4-air", "--json", "--out", str(tmp_path)]) as demo:
        line = demo.until("emulated MAVLink vehicle is at", stream="stderr")
        assert line is not None, demo.stderr()
        address = line.split(" is at ")[1].split()[0]
        assert f"udpout:{address}" in line and address.startswith("127.0.0.1:")
        with GroundStation(int(address.rpartition(":")[2])) as gcs:
            gcs.wait(lambda: gcs.modes, "the vehicle's HEARTBEAT")
            gcs.wait(lambda: gcs.positions, "the vehicle's telemetry")
