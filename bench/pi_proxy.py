"""How fast is one core of this machine against a Raspberry Pi 4's, for budget_bench's quota?

The Computer Language Benchmarks Game's n-body (5 bodies, 5,000,000 steps of 0.01), the same
program run on a Raspberry Pi 4 Model B (Cortex-A72 at 1.5 GHz, performance governor) by
C. Mehta, "Performance Analysis of Languages on Raspberry Pi"
(https://chaitanyamehta.github.io/projects/performance-analysis-of-programming-languages):
Python 158.26 s, C 1.743 s. This script times the same two programs here -- the pure-Python
one in this interpreter, the C one (bench/nbody.c) built with ``cc -O2`` where a compiler is
found -- in CPU seconds (process time: another process's load on the machine does not count,
a shared core's caches still do), and prints how many of this machine's cores a Pi 4 core is
worth. Published on the Pi: the Python version is not given (Raspberry Pi OS of 2020 shipped
3.7; 3.11 runs this kind of loop faster), so the C ratio is the interpreter-free one.

    python bench/pi_proxy.py --json                 # ~30 s of CPU
    python bench/pi_proxy.py --steps 500000         # a tenth, scaled to 5,000,000
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import tempfile
import time
from itertools import combinations
from pathlib import Path

PI4_S = {"python": 158.26, "c": 1.743}  # Mehta, Raspberry Pi 4 Model B, performance governor
STEPS = 5_000_000

PI = 3.14159265358979323
SOLAR_MASS = 4 * PI * PI
DAYS_PER_YEAR = 365.24
BODIES = {
    "sun": ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], SOLAR_MASS),
    "jupiter": ([4.84143144246472090e+00, -1.16032004402742839e+00, -1.03622044471123109e-01],
                [1.66007664274403694e-03 * DAYS_PER_YEAR, 7.69901118419740425e-03 * DAYS_PER_YEAR, -6.90460016972063023e-05 * DAYS_PER_YEAR],
                9.54791938424326609e-04 * SOLAR_MASS),
    "saturn": ([8.34336671824457987e+00, 4.12479856412430479e+00, -4.03523417114321381e-01],
               [-2.76742510726862411e-03 * DAYS_PER_YEAR, 4.99852801234917238e-03 * DAYS_PER_YEAR, 2.30417297573763929e-05 * DAYS_PER_YEAR],
               2.85885980666130812e-04 * SOLAR_MASS),
    "uranus": ([1.28943695621391310e+01, -1.51111514016986312e+01, -2.23307578892655734e-01],
               [2.96460137564761618e-03 * DAYS_PER_YEAR, 2.37847173959480950e-03 * DAYS_PER_YEAR, -2.96589568540237556e-05 * DAYS_PER_YEAR],
               4.36624404335156298e-05 * SOLAR_MASS),
    "neptune": ([1.53796971148509165e+01, -2.59193146099879641e+01, 1.79258772950371181e-01],
                [2.68067772490389322e-03 * DAYS_PER_YEAR, 1.62824170038242295e-03 * DAYS_PER_YEAR, -9.51592254519715870e-05 * DAYS_PER_YEAR],
                5.15138902046611451e-05 * SOLAR_MASS)}
SYSTEM = list(BODIES.values())
PAIRS = list(combinations(SYSTEM, 2))


def advance(dt: float, n: int, bodies=SYSTEM, pairs=PAIRS) -> None:
    for _ in range(n):
        for (([x1, y1, z1], v1, m1), ([x2, y2, z2], v2, m2)) in pairs:
            dx = x1 - x2
            dy = y1 - y2
            dz = z1 - z2
            mag = dt * ((dx * dx + dy * dy + dz * dz) ** (-1.5))
            b1m = m1 * mag
            b2m = m2 * mag
            v1[0] -= dx * b2m
            v1[1] -= dy * b2m
            v1[2] -= dz * b2m
            v2[0] += dx * b1m
            v2[1] += dy * b1m
            v2[2] += dz * b1m
        for (r, [vx, vy, vz], _m) in bodies:
            r[0] += dt * vx
            r[1] += dt * vy
            r[2] += dt * vz


def energy(bodies=SYSTEM, pairs=PAIRS) -> float:
    e = 0.0
    for (((x1, y1, z1), _v1, m1), ((x2, y2, z2), _v2, m2)) in pairs:
        e -= (m1 * m2) / ((x1 - x2) ** 2 + (y1 - y2) ** 2 + (z1 - z2) ** 2) ** 0.5
    for (_r, [vx, vy, vz], m) in bodies:
        e += m * (vx * vx + vy * vy + vz * vz) / 2.0
    return e


def offset_momentum(ref, bodies=SYSTEM) -> None:
    px = py = pz = 0.0
    for (_r, [vx, vy, vz], m) in bodies:
        px -= vx * m
        py -= vy * m
        pz -= vz * m
    ref[1][:] = [px / ref[2], py / ref[2], pz / ref[2]]


def python_s(steps: int) -> float:
    offset_momentum(BODIES["sun"])
    t0 = time.process_time()
    advance(0.01, steps)
    cpu = time.process_time() - t0
    if steps == 1000:  # the Benchmarks Game's check
        assert f"{energy():.9f}" == "-0.169087605"
    return cpu


def c_s(steps: int) -> float | None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        exe = Path(tmp) / "nbody"
        subprocess.run([cc, "-O2", "-o", str(exe), str(Path(__file__).with_name("nbody.c")), "-lm"], check=True)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([str(exe), str(steps)], check=True, capture_output=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=STEPS, help="n-body steps (default 5,000,000, as published; "
                   "fewer are scaled to it)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    args = p.parse_args()
    scale = STEPS / args.steps
    here = {"python": python_s(args.steps) * scale, "c": None if (c := c_s(args.steps)) is None else c * scale}
    report = {"steps": args.steps, "cpu_s_for_5M_steps": {k: None if v is None else round(v, 3) for k, v in here.items()},
              "pi4_s": PI4_S, "pi4_core_in_cores_here": {k: None if v is None else round(v / PI4_S[k], 3)
                                                          for k, v in here.items()},
              "python": platform.python_version(), "machine": platform.processor() or platform.machine(),
              "loadavg": [round(x, 2) for x in os.getloadavg()]}
    if args.json:
        print(json.dumps(report))
        return
    for k, v in here.items():
        if v is not None:
            print(f"{k:6} n-body 5M steps: {v:7.2f} CPU s here, {PI4_S[k]:7.2f} s on a Pi 4: "
                  f"a Pi 4 core is {v / PI4_S[k]:.0%} of one core here")


if __name__ == "__main__":
    main()
