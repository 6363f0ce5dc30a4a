"""Start-up cost of the command line: CPU and wall seconds of `rfhoming --version`, of `rfhoming
decode` on a small golden file and of `rfhoming replay --json` on a small capture, each run as a
user runs it (the installed `rfhoming` script, a fresh process), and which heavy modules each
loaded.

    python bench/startup_bench.py [--repeats 9] [--json]

Each command runs --repeats times; the figures are medians of the child's CPU (user + system,
from getrusage) and of its wall time. "python -c pass" is the interpreter alone on this machine
(its site-packages' .pth files included), the floor under every figure. The loaded modules are
read from sys.modules at the end of one more run of each command in-process of a fresh interpreter.
Targets: --version at most 0.15 s CPU; decode and replay --json at most 0.3 s; scipy loaded by
none of the three.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = ROOT / "tests" / "golden" / "xplr_aoa_session.raw"
HEAVY = ("scipy", "numpy", "mcap", "paho", "serial", "foxglove", "cyclonedds", "matplotlib", "rfhoming.emulator.runtime",
         "rfhoming.host.homing.assembly")
TARGETS = {"version": 0.15, "decode": 0.3, "replay --json": 0.3}

LOADED = """\
import contextlib, io, json, sys
from rfhoming.cli.main import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps(sorted(sys.modules)))
"""


def script() -> list[str]:
    """The `rfhoming` console script beside this interpreter (what a user runs), else -m."""
    found = Path(sys.executable).parent / "rfhoming"
    return [str(found)] if found.exists() else [sys.executable, "-m", "rfhoming"]


def small_capture(folder: Path) -> Path:
    """A capture of the golden XPLR-AOA session: its bytes inbound, 256 at a time, over 1 s."""
    from rfhoming.host.capture import CaptureWriter

    path = folder / "small.pcapng"
    writer = CaptureWriter(path)
    writer.describe("/dev/ttyUSB0", kind="xplr-aoa")
    data = GOLDEN.read_bytes()
    chunks = [data[k:k + 256] for k in range(0, len(data), 256)]
    for k, chunk in enumerate(chunks):
        writer.tap("/dev/ttyUSB0", "in", 1.0 + k / len(chunks), chunk)
    writer.close()
    return path


def once(argv: list[str]) -> tuple[float, float]:
    """One run: (CPU s, wall s) of the child."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, timeout=120)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"startup_bench: {' '.join(argv)} exited {done.returncode}: {done.stderr.decode().strip()}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def heavy_loaded(args: list[str]) -> list[str]:
    done = subprocess.run([sys.executable, "-c", LOADED, *args], capture_output=True, text=True, timeout=120)
    modules = set(json.loads(done.stdout.strip().splitlines()[-1]))
    return [m for m in HEAVY if m in modules]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="rfhoming-startup-bench-"))
    try:
        capture = small_capture(folder)
        commands = {"python -c pass": ([sys.executable, "-c", "pass"], None),
                    "version": ([*script(), "--version"], ["--version"]),
                    "decode": ([*script(), "decode", "--protocol", "uconnect", str(GOLDEN)],
                               ["decode", "--protocol", "uconnect", str(GOLDEN)]),
                    "replay --json": ([*script(), "replay", str(capture), "--json"], ["replay", str(capture), "--json"])}
        results = {}
        for name, (argv, inproc) in commands.items():
            runs = [once(argv) for _ in range(args.repeats)]
            cpu = statistics.median(r[0] for r in runs)
            row = {"command": " ".join(Path(a).name if a == argv[0] else a for a in argv),
                   "cpu_s": round(cpu, 3), "wall_s": round(statistics.median(r[1] for r in runs), 3),
                   "repeats": args.repeats}
            if inproc is not None:
                row["cpu_over_interpreter_s"] = round(cpu - results["python -c pass"]["cpu_s"], 3)
                row["heavy_modules"] = heavy_loaded(inproc)
                row["target_cpu_s"] = TARGETS[name]
                row["met"] = cpu <= TARGETS[name] and "scipy" not in row["heavy_modules"]
            results[name] = row
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    if args.json:
        print(json.dumps({"results": results, "python": sys.version.split()[0]}, indent=1))
        return
    for name, r in results.items():
        met = "" if "met" not in r else (f" ({r['cpu_over_interpreter_s']:+.3f} over the interpreter)  target "
                                         f"{r['target_cpu_s']} s: {'met' if r['met'] else 'MISSED'}")
        heavy = "" if "heavy_modules" not in r else f"  heavy: {', '.join(r['heavy_modules']) or 'none'}"
        print(f"{name:<16} {r['cpu_s']:.3f} s CPU  {r['wall_s']:.3f} s wall{met}{heavy}")


if __name__ == "__main__":
    main()
