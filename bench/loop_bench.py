"""The closed loop's speed: simulated seconds per wall second in lockstep, through ptys and
in-process, and the host's byte-in -> command-out latency (p50/p99).

    python bench/loop_bench.py [--scenario s0-house] [--runs 20] [--json]
    python bench/loop_bench.py --profile [--step-ms 20]   # in-process only: where the time goes

Each run is a full S0 homing on s0-open (a different seed and target each run) or, with
``--scenario s0-house``, in the four-room house (its own target per seed, with LIDAR scans, the
occupancy grid and the planner); the host is the
real stack (drivers, decoders, estimator, controller) and the emulator the real one. Through
ptys the emulator runs in its own process, as in `rfhoming demo` (wall time counted from the
loop's start, not the interpreter's); in-process both share one process and a byte pipe.
Simulated time is the robot's clock from its first odometry to the end of the run. Beside the
wall-clock real-time factor, ``cpu_realtime_factor`` divides simulated seconds by the CPU seconds
the host and the emulator spent over the same span (this process's, its threads' included, and
through ptys the emulator process's, from /proc): on a shared machine the wall clock measures the
other users too, CPU time much less so. In-process the loop takes a plan at its robot time, as
campaigns do (``plan.wait``), so a house run is the same run whatever the machine's load. The host
keeps its real fail-safes, the 0.5 s wall-clock odometry check included: a stop that check
makes when the machine stalls is counted as a stale-data stop (and logged).

``--profile`` runs the in-process homings under cProfile and prints each layer's share of the
own time (emulator and firmware models, host, wire codecs, asyncio) and the event-loop
iterations per world step; ``--step-ms`` sets the world's step for the in-process runs (10 ms
by default, as campaigns run), to see what a coarser step would buy.
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import json
import math
import os
import platform
import pstats
import signal
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.demo import read_truth, start_emulator
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Device, Homing
from rfhoming.host.homing.config import Config

TARGETS = [(6.0, 4.0), (-7.0, 3.0), (-5.0, -8.0), (8.0, -6.0), (3.0, 8.0), (-8.0, -2.0), (9.0, 1.0), (-2.0, 7.0)]


def child_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a live child process has used so far, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def pty_run(seed: int, target: tuple[float, float], scenario: str = "s0-open") -> dict:
    """As `rfhoming demo` does it: the emulator in its own process, the host here."""
    out = Path(tempfile.mkdtemp(prefix="rfhoming-bench-"))
    proc, endpoints = start_emulator(scenario, seed, out / "truth.jsonl", out,
                                     f"{target[0]},{target[1]}" if scenario == "s0-open" else None)
    try:
        plan = Homing("aoa", [Device("base", spec=f"base:{endpoints['base']['path']}"),
                              Device("aoa", spec=f"xplr-aoa:{endpoints['aoa']['path']}")])
        wall0, cpu0, child0 = time.perf_counter(), time.process_time(), child_cpu_s(proc.pid)
        outcome = await asyncio.wait_for(assembly.run(plan), 900)
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0 + child_cpu_s(proc.pid) - child0
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
    _, states = read_truth(out / "truth.jsonl")
    robot, goal = states[-1]["robot"], states[-1]["targets"][0]
    return {"arrived": outcome.arrived, "sim_s": outcome.robot_time_s, "wall_s": wall, "cpu_s": cpu,
            "final_error_m": math.hypot(robot["x"] - goal["x"], robot["y"] - goal["y"]),
            "latency_ms": outcome.latency_ms, "stale_stops": outcome.stale_stops, **outcome.stalls,
            "lockstep_timeouts": None}  # counted in the other process


async def pipe_run(seed: int, target: tuple[float, float], step_ms: int = 10, scenario: str = "s0-open") -> dict:
    """Emulator and host in this process, sharing the in-process byte pipe."""
    sc = load(scenario, seed=seed, target=target) if scenario == "s0-open" else load(scenario, seed=seed)
    em = Emulator(sc, transport="pipe", seed=seed, lockstep=True, lockstep_timeout=2.0, step_ms=step_ms)
    await em.start()
    world = asyncio.create_task(em.run())
    base, aoa = PipePort("base", em.device("base").link.host), PipePort("aoa", em.device("aoa").link.host)
    config = Config()
    config = replace(config, plan=replace(config.plan, wait=True))  # a plan at its robot time, as campaigns
    wall0, cpu0 = time.perf_counter(), time.process_time()
    outcome = await asyncio.wait_for(assembly.run(Homing("aoa", [Device("base", port=base), Device("aoa", port=aoa)],
                                                         config)), 900)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    world.cancel()
    await asyncio.gather(world, return_exceptions=True)
    await em.close()
    robot, goal = em.world.robot, sc.world.targets[0].position
    return {"arrived": outcome.arrived, "sim_s": outcome.robot_time_s, "wall_s": wall, "cpu_s": cpu,
            "final_error_m": math.hypot(robot.x - goal[0], robot.y - goal[1]),
            "latency_ms": outcome.latency_ms, "stale_stops": outcome.stale_stops, **outcome.stalls,
            "lockstep_timeouts": em.counters["lockstep_timeouts"], "steps": em.counters["steps"]}


LAYERS = (("emulator and firmware", ("/emulator/", "/firmware_py/", "/firmware/")), ("host", ("/host/",)),
          ("wire codecs", ("/protocol/",)), ("asyncio", ("asyncio", "selectors")))


def profile(runs: int, step_ms: int, scenario: str = "s0-open", top: int = 0) -> dict:
    """In-process homings under cProfile: each layer's share of the own time (a C builtin's time
    goes to the layer that called it) and event-loop iterations per world step."""
    prof = cProfile.Profile()
    prof.enable()
    done = [asyncio.run(pipe_run(seed, TARGETS[seed % len(TARGETS)], step_ms, scenario)) for seed in range(runs)]
    prof.disable()
    if top:
        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(top)
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]

    def layer(path: str) -> str:
        return next((name for name, parts in LAYERS if any(p in path for p in parts)), "other")

    shares: dict[str, float] = {}
    iterations = 0
    for (path, _, name), (_, calls, own, _, callers) in stats.items():
        if name == "_run_once" and "asyncio" in path:
            iterations += calls
        if path == "~":  # a builtin: split its time over its callers
            total = sum(c[2] for c in callers.values()) or 1.0
            for (cpath, _, _), c in callers.items():
                shares[layer(cpath)] = shares.get(layer(cpath), 0.0) + own * c[2] / total
        else:
            shares[layer(path)] = shares.get(layer(path), 0.0) + own
    total = sum(shares.values())
    return {"scenario": scenario, "runs": runs, "step_ms": step_ms, "wall_s": round(sum(r["wall_s"] for r in done), 2),
            "sim_s": round(sum(r["sim_s"] for r in done), 2),
            "own_time_share_pct": {k: round(100 * v / total, 1) for k, v in sorted(shares.items(), key=lambda kv: -kv[1])},
            "loop_iterations_per_step": round(iterations / sum(r["steps"] for r in done), 2)}


def summarise(runs: list[dict]) -> dict:
    lat = np.concatenate([r["latency_ms"] for r in runs])
    sim, wall, cpu = (sum(r[k] for r in runs) for k in ("sim_s", "wall_s", "cpu_s"))
    return {"runs": len(runs), "arrived": sum(r["arrived"] for r in runs), "sim_s": round(sim, 2),
            "wall_s": round(wall, 3), "realtime_factor": round(sim / wall, 1),
            "cpu_s": round(cpu, 3), "cpu_realtime_factor": round(sim / cpu, 1),
            "latency_ms_p50": round(float(np.percentile(lat, 50)), 3),
            "latency_ms_p99": round(float(np.percentile(lat, 99)), 3),
            "stale_stops": sum(r["stale_stops"] for r in runs),
            "loop_stall_ms_max": max(r["loop_stall_ms_max"] for r in runs),
            "loop_stall_ms_p99": round(float(np.percentile([r["loop_stall_ms_p99"] for r in runs], 50)), 1),
            "lockstep_timeouts": None if runs[0]["lockstep_timeouts"] is None
            else sum(r["lockstep_timeouts"] for r in runs)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=20, help="homing runs per transport (default 20)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--profile", action="store_true", help="in-process runs under cProfile: each layer's share")
    parser.add_argument("--step-ms", type=int, default=10, help="the world's step for in-process runs (default 10)")
    parser.add_argument("--scenario", choices=("s0-open", "s0-house"), default="s0-open")
    parser.add_argument("--top", type=int, default=0, help="with --profile: the N costliest functions, on stderr")
    parser.add_argument("--transports", default="pty,pipe", help="comma-separated: pty, pipe (default both)")
    args = parser.parse_args()
    result = {"python": platform.python_version(), "scenario": args.scenario}
    if args.profile:
        result["profile"] = profile(args.runs, args.step_ms, args.scenario, args.top)
        print(json.dumps(result, indent=1))
        return 0
    transports = args.transports.split(",")
    for transport in transports:
        if transport == "pty":
            runs = [asyncio.run(pty_run(seed, TARGETS[seed % len(TARGETS)], args.scenario)) for seed in range(args.runs)]
        else:
            runs = [asyncio.run(pipe_run(seed, TARGETS[seed % len(TARGETS)], args.step_ms, args.scenario))
                    for seed in range(args.runs)]
        result[transport] = summarise(runs)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    for transport in transports:
        r = result[transport]
        print(f"{transport:<5} {r['arrived']}/{r['runs']} arrived  {r['sim_s']:.1f} s simulated in {r['wall_s']:.2f} s wall: "
              f"{r['realtime_factor']:.0f}x real time ({r['cpu_s']:.2f} CPU s: {r['cpu_realtime_factor']:.0f}x)   byte-in -> command-out p50 {r['latency_ms_p50']:.2f} ms, "
              f"p99 {r['latency_ms_p99']:.2f} ms   loop stall max {r['loop_stall_ms_max']} ms   "
              f"stale-data stops {r['stale_stops']}   lockstep timeouts "
              f"{'n/a (other process)' if r['lockstep_timeouts'] is None else r['lockstep_timeouts']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
