"""The DDS path of a ROS 2 base: latency from an odometry sample to the command it causes, and
CPU per second of a live run at 50 Hz odometry and 10 Hz scans.

One process holds the emulator (s0-open, real time, its base scanning 181 beams at 10 Hz) and
the host's homing loop. With ``--base ros2`` the base is the emulated ROS 2 robot
(emulator/ros2robot.py) on a random loopback domain and the host's ``ros2:`` base; the
latency is timed at the robot: from publishing an odometry sample to receiving the next
command (the loop decides on odometry, once per 0.1 s control period), so it holds both DDS
hops and the loop's work. ``--base serial`` runs the same over the in-process byte pipe, for
the CPU baseline: the difference is what DDS costs.

    python bench/ros2_bench.py [--seconds 20] [--base ros2|serial] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import sys
import time
from dataclasses import replace

import psutil

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Device, Homing
from rfhoming.host.homing.config import Config


def quantile(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


async def one(seconds: float, over: str) -> dict:
    scenario = load("s0-open", seed=1, target=(40.0, 0.5))  # far: it drives the whole time
    base_spec = next(d for d in scenario.devices if d.type == "base")
    base_spec.options["scan"] = True
    domain = random.SystemRandom().randint(1, 230)
    em = Emulator(scenario, transport="pipe", seed=1, robot={"domain": domain} if over == "ros2" else None)
    published: list[float] = []
    latencies: list[float] = []
    if over == "ros2":
        link = em.device("base").link
        publish, command = link._publish_odometry, link._command

        def timed_publish(record):  # noqa: ANN001
            published.append(time.perf_counter())
            publish(record)

        def timed_command(v: float, w: float) -> None:
            if published:
                latencies.append((time.perf_counter() - published[-1]) * 1000)
            command(v, w)

        link._publish_odometry, link._command = timed_publish, timed_command
    await em.start()
    world = asyncio.create_task(em.run())
    config = Config()
    config = replace(config, loop=replace(config.loop, max_time_s=seconds))
    aoa = PipePort("aoa", em.device("aoa").link.host)
    base = (Device("base", spec=f"ros2:domain={domain}") if over == "ros2"
            else Device("base", port=PipePort("base", em.device("base").link.host)))
    me = psutil.Process()
    cpu0, wall0 = me.cpu_times(), time.monotonic()
    try:
        outcome = await asyncio.wait_for(assembly.run(Homing("aoa", [base, Device("aoa", port=aoa)], config)),
                                         seconds + 120)
    finally:
        cpu1, wall1 = me.cpu_times(), time.monotonic()
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    cpu = (cpu1.user - cpu0.user + cpu1.system - cpu0.system) / (wall1 - wall0)
    out = {"base": over, "seconds": round(wall1 - wall0, 2), "reason": outcome.reason, "commands": outcome.commands,
           "cpu_s_per_s": round(cpu, 3), "odometry_published": len(published)}
    if latencies:
        # the first commands answer the loop's start, not an odometry sample
        lat = latencies[5:]
        out.update(latency_ms_p50=round(statistics.median(lat), 3), latency_ms_p99=round(quantile(lat, 0.99), 3),
                   latency_samples=len(lat))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--base", choices=("ros2", "serial"), default="ros2")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    result = asyncio.run(one(args.seconds, args.base))
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
