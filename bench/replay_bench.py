"""Replay speed: how long `rfhoming replay CAPTURE` takes on a homing run's capture, start-up
included, and whether it is clean (0 diverged, 0 unanswered, nothing on stderr).

    python bench/replay_bench.py [--scenario s0-house] [--seed 1] [--repeats 3] [--json]

The capture is made first by `rfhoming demo --in-process` (the same bytes for the same seed).
Two replays are timed, each as a user runs it, in its own process: the drivers alone
(`replay CAPTURE --json`, what `listen` would have printed) and the whole homing loop
(`replay CAPTURE --run`, which must write the live run log line for line). Figures: the
capture's recorded span (wall time of the recording: an in-process demo's is short), wall
seconds per replay (best of --repeats) and per 60 s of capture, and the real-time factors: the
robot time the run covers (the replayed run's ``robot_time_s``) over the wall seconds, and over
the CPU seconds the replay's process used (user + system, from the kernel's accounting of a
waited-for child; start-up included), the figure a loaded machine disturbs least.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rfhoming.host.replay import load_capture


def rfhoming(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rfhoming", *args], capture_output=True, text=True, timeout=900)


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed(*args: str, repeats: int) -> tuple[float, float, subprocess.CompletedProcess]:
    """The best wall and the best CPU seconds over ``repeats`` runs, and the last run."""
    best, best_cpu, done = float("inf"), float("inf"), None
    for _ in range(repeats):
        t0, cpu0 = time.perf_counter(), children_cpu_s()
        done = rfhoming(*args)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, children_cpu_s() - cpu0)
    assert done is not None
    return best, best_cpu, done


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="s0-house")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    out = Path(tempfile.mkdtemp(prefix="rfhoming-replay-bench-"))
    demo = rfhoming("demo", "--in-process", "--scenario", args.scenario, "--seed", str(args.seed), "--json",
                    "--out", str(out))
    if demo.returncode not in (0, 1):
        sys.exit(f"replay_bench: the demo failed: {demo.stderr.strip()}")
    capture = out / "capture.pcapng"
    _, packets, _ = load_capture(capture)
    times = [p.t for ps in packets.values() for p in ps]
    span = max(times) - min(times)
    drivers_s, drivers_cpu, drivers = timed("replay", str(capture), "--json", repeats=args.repeats)
    counters = [json.loads(line) for line in drivers.stdout.splitlines() if '"kind": "counters"' in line]
    items = sum(1 for line in drivers.stdout.splitlines() if '"kind": "counters"' not in line)
    if drivers.returncode != 0:
        sys.exit(f"replay_bench: replay --json failed: {drivers.stderr.strip()}")
    run_s, run_cpu, run = timed("replay", str(capture), "--run", "--log", str(out / "replayed.jsonl"), repeats=args.repeats)
    if run.returncode not in (0, 1):
        sys.exit(f"replay_bench: replay --run failed: {run.stderr.strip()}")
    same_log = (out / "replayed.jsonl").read_text() == (out / "run.jsonl").read_text()
    robot_s = float(json.loads(run.stdout)["robot_time_s"])
    result = {
        "scenario": args.scenario, "seed": args.seed, "capture_span_s": round(span, 2),
        "robot_time_s": robot_s,
        "drivers": {"wall_s": round(drivers_s, 3), "wall_s_per_60s": round(drivers_s * 60 / span, 3),
                    "cpu_s": round(drivers_cpu, 3), "realtime_factor": round(robot_s / drivers_s, 2),
                    "cpu_realtime_factor": round(robot_s / drivers_cpu, 2), "items": items,
                    "diverged": sum(c["diverged"] for c in counters),
                    "unanswered": sum(c["unanswered"] for c in counters), "stderr": drivers.stderr.strip()},
        "run": {"wall_s": round(run_s, 3), "wall_s_per_60s": round(run_s * 60 / span, 3), "cpu_s": round(run_cpu, 3),
                "realtime_factor": round(robot_s / run_s, 2), "cpu_realtime_factor": round(robot_s / run_cpu, 2),
                "replay": json.loads(run.stdout)["replay"], "same_run_log": same_log, "stderr": run.stderr.strip()},
    }
    if args.json:
        print(json.dumps(result))
        return
    d, r = result["drivers"], result["run"]
    print(f"{args.scenario} seed {args.seed}: a capture of {robot_s:.1f} s of robot time ({span:.1f} s recorded)")
    print(f"  replay --json  {d['wall_s']:.2f} s wall ({d['wall_s_per_60s']:.2f} s per 60 s of capture; "
          f"{d['realtime_factor']:.1f}x real time, {d['cpu_realtime_factor']:.1f}x per CPU second), {items} items, "
          f"diverged {d['diverged']}, unanswered {d['unanswered']}, stderr {d['stderr'] or 'empty'}")
    print(f"  replay --run   {r['wall_s']:.2f} s wall ({r['wall_s_per_60s']:.2f} s per 60 s; {r['realtime_factor']:.1f}x "
          f"real time, {r['cpu_realtime_factor']:.1f}x per CPU second), run log "
          f"{'identical' if same_log else 'DIFFERENT'}, {r['replay']}, stderr {r['stderr'] or 'empty'}")


if __name__ == "__main__":
    main()
