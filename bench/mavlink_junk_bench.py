"""A MAVLink vehicle whose link carries junk: how long the set-up takes, and how often the homing
loop stops on stale odometry (a hostile-peer trial on loopback saw junk datagrams make the set-up take 5 s, not 2, and
the brake toggle 25 times).

Each run starts ``rfhoming emulate s0-open`` (for its AoA board), the vehicle of
tests/hostile_vehicle.py (an ArduPilot Rover on UDP loopback, written on pymavlink alone) and
``rfhoming run --aoa AOA --base mavlink:udpout:127.0.0.1:PORT,arm=1`` with ``[loop] max_time_s``
= ``--seconds`` and a run log. With ``--junk N`` the vehicle sends N datagrams of junk from its
own socket after each telemetry datagram (50 a second: random bytes, a start marker with a long
length at a datagram's end, one of its packets with a bad CRC; seeded by the run's number).
Per run: ``set_up_s`` (the ground station's first datagram to its first setpoint, wall clock),
``brake_on`` (the run log's "brake mode on" events), ``stale_stops`` (its "stale: stop" events),
the setpoints the vehicle got and the exit code.

``--codec`` measures the cause alone, with no process and no clock: ``--datagrams`` of the
vehicle's telemetry (ATTITUDE and LOCAL_POSITION_NED), each followed by ``--junk`` junk
datagrams, fed one datagram at a time to rfhoming's MAVLink decoder as the driver feeds it; it
counts the positions decoded.

    python bench/mavlink_junk_bench.py --runs 3 --seconds 10 --junk 3 --json
    python bench/mavlink_junk_bench.py --codec --datagrams 3000 --junk 1 --json

Run it against another checkout with ``PYTHONPATH=OTHER/src`` (the children inherit it).
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import rigs  # noqa: E402
from hostile_vehicle import HostileVehicle  # noqa: E402

DEADLINE_S = 120.0  # hang guard for each wait


def one(aoa: str, folder: Path, n: int, seconds: float, junk: int) -> dict[str, Any]:
    config, log = folder / "bench.toml", folder / f"run{n}.jsonl"
    config.write_text(f"[loop]\nmax_time_s = {seconds}\n")
    with HostileVehicle() as vehicle:
        vehicle.junk, vehicle.junk_each = (random.Random(n) if junk else None), junk
        argv = [*rigs.RFHOMING, "run", "--aoa", aoa, "--base", f"mavlink:udpout:127.0.0.1:{vehicle.port},arm=1",
                "--config", str(config), "--log", str(log)]
        with subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) as run:
            if not vehicle.spoken.wait(DEADLINE_S):
                raise SystemExit(f"the ground station never spoke: {' '.join(argv)}")
            spoke = time.monotonic()
            driven = vehicle.driven.wait(DEADLINE_S)
            set_up = time.monotonic() - spoke
            _, err = run.communicate(timeout=DEADLINE_S + seconds * 4)
        events = [json.loads(line) for line in log.read_text().splitlines() if '"kind": "event"' in line]
        return {"set_up_s": round(set_up, 3) if driven else None, "returncode": run.returncode,
                "brake_on": sum(e["what"] == "brake mode on" for e in events),
                "stale_stops": sum(e["what"].endswith("stale: stop") for e in events),
                "setpoints": vehicle.setpoints, "modes_asked": vehicle.modes_asked(),
                "stderr_tail": err.strip().splitlines()[-1:] if err.strip() else []}


def codec(datagrams: int, junk: int) -> dict[str, Any]:
    from pymavlink.dialects.v20 import common as mav

    from hostile_vehicle import local_position, packets
    from rfhoming.protocol import mavlink as ml

    decoder, rng, vehicle = ml.Codec(), random.Random(0), HostileVehicle()
    whole = "datagram" in ml.Codec.feed.__code__.co_varnames  # the driver says where a datagram ends
    positions = junk_bytes = 0
    for i in range(datagrams):
        feed = [packets(1, 1, mav.MAVLink_attitude_message(i, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), local_position(i, 0.0, 0.0))]
        feed += [vehicle.garbage(rng) for _ in range(junk)]
        junk_bytes += sum(len(d) for d in feed[1:])
        for data in feed:
            out = decoder.feed(data, datagram=True) if whole else decoder.feed(data)
            positions += sum(getattr(m, "get_type", lambda: "")() == "LOCAL_POSITION_NED" for m in out)
    return {"decoder": ml.__file__, "datagrams": datagrams, "junk_each": junk, "junk_bytes": junk_bytes,
            "positions_decoded": positions}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0, help="each run's max_time_s (robot time)")
    parser.add_argument("--junk", type=int, default=0, metavar="N", help="junk datagrams after each telemetry datagram")
    parser.add_argument("--codec", action="store_true", help="the decoder alone (no process): positions decoded")
    parser.add_argument("--datagrams", type=int, default=3000, help="--codec: telemetry datagrams")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.codec:
        print(json.dumps(codec(args.datagrams, args.junk)))
        return
    with tempfile.TemporaryDirectory() as tmp, rigs.emulate("s0-open", link_dir=Path(tmp)) as world:
        runs = [one(world.path("aoa"), Path(tmp), n, args.seconds, args.junk) for n in range(args.runs)]
    set_ups = [r["set_up_s"] for r in runs if r["set_up_s"] is not None]
    summary = {"junk": args.junk, "runs": runs, "set_up_s_median": statistics.median(set_ups) if set_ups else None,
               "brake_on_total": sum(r["brake_on"] for r in runs), "stale_stops_total": sum(r["stale_stops"] for r in runs)}
    print(json.dumps(summary) if args.json else json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
