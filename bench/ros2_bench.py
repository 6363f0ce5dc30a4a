"""The DDS path of a ROS 2 base: latency from an odometry sample to the command it causes, and
CPU per second of a live run at 50 Hz odometry and 10 Hz scans.

One process holds the emulator (s0-open, real time, its base scanning 181 beams at 10 Hz) and
the host's homing loop. With ``--base ros2`` the base is the emulated ROS 2 robot
(emulator/ros2robot.py) on a random loopback domain and the host's ``ros2:`` base; the
latency is timed at the robot: from publishing an odometry sample to receiving the next
command (the loop decides on odometry, once per 0.1 s control period), so it holds both DDS
hops and the loop's work. ``--base serial`` runs the same over the in-process byte pipe, for
the CPU baseline: the difference is what DDS costs.

``--robot-process``: the emulated ROS 2 robot runs in a process of its own (this script again,
the XPLR-AOA on a pty), so that the emulator's work -- ray casting the scans, the radio model --
no longer shares the host's event loop, and the latency is the DDS path and the loop alone;
the CPU is then given for each process, and the host's own part of the latency (odometry in
-> command out, the loop's run-log figure) beside it.

    python bench/ros2_bench.py [--seconds 20] [--base ros2|serial] [--robot-process] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

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


def emulator(domain: int | None, transport: str = "pipe", link_dir: Path | None = None) -> Emulator:
    scenario = load("s0-open", seed=1, target=(40.0, 0.5))  # far: it drives the whole time
    base_spec = next(d for d in scenario.devices if d.type == "base")
    base_spec.options["scan"] = True
    return Emulator(scenario, transport=transport, seed=1, link_dir=link_dir,
                    robot=None if domain is None else {"domain": domain})


def timed(em: Emulator, published: list[float], latencies: list[float]) -> None:
    """Time the emulated ROS 2 robot: each odometry published, each command received."""
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


def latency_figures(latencies: list[float]) -> dict:
    lat = latencies[5:]  # the first commands answer the loop's start, not an odometry sample
    return {"latency_ms_p50": round(statistics.median(lat), 3), "latency_ms_p99": round(quantile(lat, 0.99), 3),
            "latency_samples": len(lat)} if lat else {}


async def robot_process(domain: int, link_dir: Path) -> None:
    """The child of --robot-process: the emulated robot until stdin closes, then its figures."""
    em = emulator(domain, "pty", link_dir)
    published: list[float] = []
    latencies: list[float] = []
    timed(em, published, latencies)
    await em.start()
    world = asyncio.create_task(em.run())
    print(json.dumps({"aoa": str(link_dir / "aoa")}), flush=True)
    me = psutil.Process()
    cpu0, wall0 = me.cpu_times(), time.monotonic()
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    cpu1, wall1 = me.cpu_times(), time.monotonic()
    world.cancel()
    await asyncio.gather(world, return_exceptions=True)
    await em.close()
    print(json.dumps({"robot_cpu_s_per_s": round((cpu1.user - cpu0.user + cpu1.system - cpu0.system)
                                                 / (wall1 - wall0), 3),
                      "odometry_published": len(published), **latency_figures(latencies)}), flush=True)


async def separate(seconds: float) -> dict:
    """--robot-process: the host's loop here, the emulated ROS 2 robot in a child process."""
    domain = random.SystemRandom().randint(1, 230)
    link_dir = Path(tempfile.mkdtemp(prefix="rfhoming-ros2-bench-"))
    child = subprocess.Popen([sys.executable, __file__, "--robot-child", str(domain), str(link_dir)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        aoa = json.loads(child.stdout.readline())["aoa"]
        config = Config()
        config = replace(config, loop=replace(config.loop, max_time_s=seconds))
        me = psutil.Process()
        cpu0, wall0 = me.cpu_times(), time.monotonic()
        outcome = await asyncio.wait_for(assembly.run(Homing(
            "aoa", [Device("base", spec=f"ros2:domain={domain}"), Device("aoa", spec=f"xplr-aoa:{aoa}")], config)),
            seconds + 120)
        cpu1, wall1 = me.cpu_times(), time.monotonic()
        robot, _ = child.communicate("", timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    return {"base": "ros2", "robot": "own process", "seconds": round(wall1 - wall0, 2), "reason": outcome.reason,
            "commands": outcome.commands, "host_odometry_to_command_ms_p50": outcome.summary()["latency_ms_p50"],
            "host_odometry_to_command_ms_p99": outcome.summary()["latency_ms_p99"],
            "host_cpu_s_per_s": round((cpu1.user - cpu0.user + cpu1.system - cpu0.system) / (wall1 - wall0), 3),
            **json.loads(robot.splitlines()[-1])}


async def one(seconds: float, over: str) -> dict:
    domain = random.SystemRandom().randint(1, 230)
    em = emulator(domain if over == "ros2" else None)
    published: list[float] = []
    latencies: list[float] = []
    if over == "ros2":
        timed(em, published, latencies)
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
    return {**out, **latency_figures(latencies)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--base", choices=("ros2", "serial"), default="ros2")
    p.add_argument("--robot-process", action="store_true",
                   help="with --base ros2: the emulated robot in a process of its own")
    p.add_argument("--json", action="store_true")
    p.add_argument("--robot-child", nargs=2, metavar=("DOMAIN", "LINK_DIR"), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.robot_child:
        asyncio.run(robot_process(int(args.robot_child[0]), Path(args.robot_child[1])))
        return 0
    if args.robot_process and args.base != "ros2":
        p.error("--robot-process is for --base ros2")
    result = asyncio.run(separate(args.seconds) if args.robot_process else one(args.seconds, args.base))
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
