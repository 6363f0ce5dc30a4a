"""What wall reflections cost the emulator: the radio device's step per simulated second, with
the scenario's reflections on and off, the robot driving a straight line at 0.4 m/s.

- ``s2-d``: S2's four-dish node (20 frames/s, each combined over every reflected path, per dish);
- ``s0-house``: the XPLR-AOA board (50 events/s, bearing of the strongest of up to ~30 paths).

    python bench/radio_bench.py [--seconds 20] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from dataclasses import replace

from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load

CASES = (("s2-d", "rss", (0.0, 0.0), (1.0, 0.0)), ("s0-house", "aoa", (-4.5, -4.5), (1.0, 0.6)))
STEP_S = 0.01


def per_second(scenario: str, device: str, start: tuple[float, float], heading: tuple[float, float],
               reflections: bool, seconds: float) -> float:
    """Wall seconds of the device's step per simulated second (best of three)."""
    norm = math.hypot(*heading)
    best = math.inf
    for _ in range(3):  # a fresh session each time: its transmission schedule starts at 0
        sc = load(scenario, seed=1)
        sc.path_loss = replace(sc.path_loss, reflections=reflections)
        em = Emulator(sc, transport="pipe", seed=1, speed=math.inf)
        runner = em.device(device)
        t, used = 0.0, 0.0
        while t < seconds:
            s = (0.4 * t) % 8.0  # back and forth over 4 m, so the receiver keeps entering new cells
            s = s if s < 4.0 else 8.0 - s
            em.world.robot.x = start[0] + s * heading[0] / norm
            em.world.robot.y = start[1] + s * heading[1] / norm
            t0 = time.perf_counter()
            runner.step(em.world, t, t + STEP_S)
            used += time.perf_counter() - t0
            t += STEP_S
        best = min(best, used / seconds)
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per case (default 20)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    out = {"python": platform.python_version(), "seconds": args.seconds, "cases": {}}
    for scenario, device, start, heading in CASES:
        off = per_second(scenario, device, start, heading, False, args.seconds)
        on = per_second(scenario, device, start, heading, True, args.seconds)
        out["cases"][scenario] = {"device": device, "off_ms_per_s": round(1e3 * off, 3),
                                  "on_ms_per_s": round(1e3 * on, 3), "ratio": round(on / off, 2)}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for name, c in out["cases"].items():
            print(f"{name:9} {c['device']:4} reflections off {c['off_ms_per_s']:7.3f} ms, on {c['on_ms_per_s']:7.3f} ms"
                  f" per simulated second ({c['ratio']}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
