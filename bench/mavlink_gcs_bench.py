"""A ground station beside `rfhoming run` on the emulated MAVLink vehicle's port: does the run
keep its telemetry (a ground station on the printed port once halved it and the run stopped on
stale odometry again and again)?

Each run starts ``rfhoming emulate s0-open --robot mavlink`` and, on the vehicle's port, the
pymavlink ground station of tests/test_mavlink_gcs.py (a HEARTBEAT each second, every
LOCAL_POSITION_NED kept), then ``rfhoming run --aoa AOA --base mavlink:udpout:...,arm=1`` with a
capture. Per run: the exit code, the reason, robot time, stale stops and "odometry stale"
events, the LOCAL_POSITION_NED rfhoming took (from its capture) and how many of them the ground
station took too.

    python bench/mavlink_gcs_bench.py --runs 1 --json

Run it against another checkout from that checkout's directory (``python -m rfhoming`` takes the
working directory's package first): ``cd OTHER && PYTHONPATH=OTHER/src python THIS/bench/...``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import rigs  # noqa: E402
from test_mavlink_gcs import GroundStation  # noqa: E402

from rfhoming.host.replay import read_capture  # noqa: E402
from rfhoming.protocol import mavlink as ml  # noqa: E402
from rfhoming.protocol import pcapng  # noqa: E402


def one(tmp: Path, seed: int) -> dict[str, Any]:
    log, capture = tmp / "run.jsonl", tmp / "run.pcapng"
    with rigs.emulate("s0-open", "--robot", "mavlink", "--seed", str(seed), link_dir=tmp, devices=2) as world:
        port = int(world.endpoints["base"]["mavlink"]["vehicle"].rpartition(":")[2])
        with GroundStation(port) as gcs:
            gcs.wait(lambda: gcs.positions, "the vehicle's telemetry")
            done = rigs.run("run", "--aoa", world.path("aoa"), "--base", f"{world.path('base')},arm=1",
                            "--log", str(log), "--capture", str(capture), timeout_s=300)
        base = world.path("base").removeprefix("mavlink:")
    result: dict[str, Any] = {"exit": done.returncode, "odometry_stale_events": done.stderr.count("odometry stale")}
    if done.stdout.strip():
        summary = json.loads(done.stdout)
        result.update(reason=summary["reason"], robot_time_s=summary["robot_time_s"], stale_stops=summary["stale_stops"])
    else:
        result["error"] = done.stderr.strip().splitlines()[-1]
    interfaces, packets, _, _ = read_capture(capture)
    k = next(i for i, iface in enumerate(interfaces) if iface.name == base)
    taken = {m.time_boot_ms for p in packets[k] if p.direction == pcapng.INBOUND
             for m in ml.Codec(1, 1).feed(p.data) if m.get_type() == "LOCAL_POSITION_NED"}
    result.update(rfhoming_positions=len(taken), ground_station_too=len(taken & {ms for ms, _, _ in gcs.positions}))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.runs):
            (Path(tmp) / str(k)).mkdir()
            runs.append(one(Path(tmp) / str(k), 3 + k))
    if args.json:
        print(json.dumps({"runs": runs}))
    else:
        for run in runs:
            print(run)


if __name__ == "__main__":
    main()
