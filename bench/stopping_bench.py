"""Distance driven on stale data, measured on the emulator's true pose.

Each run homes toward a far tag in lockstep (s0-open, the real host stack on the emulator's
in-process byte pipe, so the machine's load cannot delay one device's bytes against the
other's); at
``--at`` seconds the XPLR-AOA is unplugged for good, so its last reading is then. The figure is
the true path length from that moment until the robot is at rest, with its true speed when the
data ended: the loop's own log is not consulted. The target is <= 0.25 m from full speed.

``--base ros2`` drives the same emulated base as a ROS 2 robot over DDS on loopback
(emulator/ros2robot.py; the host's ``ros2:`` base, a random domain per run): a ROS 2 base has
no brake mode, so the stop is the zero Twist at the base's normal deceleration, and the loop
bounds its speed to what stops within the target (``[loop] stop_within_m``). "Full speed" is
each run's own top speed: the controller's ``v_max``, or that bound when it is lower.

    python bench/stopping_bench.py [--runs 8] [--base serial|ros2] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import math
import random
import statistics
import sys
from dataclasses import replace

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.emulator.faults import Fault
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Device, Homing
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import RunLog

TARGETS = [(12.0, 0.5), (-11.0, 3.0), (2.0, 12.0), (9.0, -8.0)]


def driven_after(truth: str, t_from: float) -> tuple[float, float, float]:
    """(true speed at t_from, path length from t_from on, seconds until at rest)."""
    pts = [(r["t"], r["robot"]["x"], r["robot"]["y"]) for r in map(json.loads, truth.splitlines()) if "robot" in r]
    step = lambda k: math.hypot(pts[k][1] - pts[k - 1][1], pts[k][2] - pts[k - 1][2])  # noqa: E731
    i = next(k for k, p in enumerate(pts) if p[0] >= t_from - 1e-9)
    speed = step(i) / (pts[i][0] - pts[i - 1][0])
    rest = next((pts[k - 1][0] for k in range(i + 1, len(pts)) if step(k) < 1e-6), math.nan)
    return speed, sum(step(k) for k in range(i + 1, len(pts))), rest - t_from


async def one(seed: int, target: tuple[float, float], at: float, over: str = "serial") -> dict:
    truth = io.StringIO()
    domain = random.SystemRandom().randint(1, 230)
    em = Emulator(load("s0-open", seed=seed, target=target), transport="pipe", seed=seed, lockstep=True,
                  lockstep_timeout=2.0, truth=truth, robot={"domain": domain} if over == "ros2" else None,
                  faults=[Fault.parse(f"unplug@aoa:at={at},for=1000")])
    await em.start()
    world = asyncio.create_task(em.run())
    config = Config().for_lockstep()
    config = replace(config, loop=replace(config.loop, max_time_s=at + 3))
    runlog = io.StringIO()
    try:
        aoa = PipePort("aoa", em.device("aoa").link.host)
        base = (Device("base", spec=f"ros2:domain={domain}") if over == "ros2"
                else Device("base", port=PipePort("base", em.device("base").link.host)))
        await asyncio.wait_for(assembly.run(Homing("aoa", [base, Device("aoa", port=aoa)], config,
                                                    runlog=RunLog(runlog))), 120)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    speed, driven, rest = driven_after(truth.getvalue(), at)
    bound = next((r["v_max"] for r in map(json.loads, runlog.getvalue().splitlines())
                  if r.get("what") == "no brake mode: speed bounded"), math.inf)
    return {"seed": seed, "target": target, "at": at, "speed_m_s": round(speed, 3), "driven_m": round(driven, 3),
            "at_rest_after_s": round(rest, 3), "top_speed_m_s": min(config.s0.v_max, bound)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=8)
    p.add_argument("--base", choices=("serial", "ros2"), default="serial",
                   help="the base over rfhoming's framing (in-process pipe) or as a ROS 2 robot over DDS")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    runs = [asyncio.run(one(k + 1, TARGETS[k % len(TARGETS)], 4.0 + 0.37 * k, args.base)) for k in range(args.runs)]
    fast = [r for r in runs if r["speed_m_s"] >= 0.9 * r["top_speed_m_s"]]
    summary = {"runs": len(runs), "at_full_speed": len(fast),
               "driven_m_max": max(r["driven_m"] for r in runs),
               "driven_m_max_from_full_speed": max((r["driven_m"] for r in fast), default=None),
               "driven_m_median": statistics.median(r["driven_m"] for r in runs),
               "top_speed_m_s": max(r["top_speed_m_s"] for r in runs),
               "at_rest_after_s_max": max(r["at_rest_after_s"] for r in runs), "target_m": 0.25, "base": args.base}
    if args.json:
        print(json.dumps({"summary": summary, "runs": runs}))
    else:
        for r in runs:
            print(f"seed {r['seed']} at {r['at']:.2f} s: {r['speed_m_s']:.2f} m/s -> {r['driven_m']:.3f} m, "
                  f"at rest after {r['at_rest_after_s']:.2f} s")
        print(json.dumps(summary))
    return 0 if summary["driven_m_max"] <= 0.25 else 1


if __name__ == "__main__":
    sys.exit(main())
