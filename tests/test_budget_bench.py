"""bench/budget_bench.py's own behaviour: its arguments, its verdicts, and its cgroups gone after
Ctrl-C. No speed is asserted here -- the figures are the bench's, in docs/BENCHMARKS.md."""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench" / "budget_bench.py"
CPU = Path("/sys/fs/cgroup/cpu")


def load_bench():
    spec = importlib.util.spec_from_file_location("budget_bench", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("args", "words"), [
    (["--runs", "s9-moon"], "unknown run s9-moon; the runs are s0-open"),
    (["--quotas", "0"], "each must be above 0 and at most 100"),
    (["--quotas", "half"], "give percentages of one core"),
])
def test_bad_arguments_say_what_is_allowed(args: list[str], words: str) -> None:
    done = subprocess.run([sys.executable, str(BENCH), *args], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and words in done.stderr


def test_verdicts_follow_the_targets() -> None:
    bench = load_bench()
    row = {"quota_percent": 25.0, "success": True, "stale_stops": 0, "latency_ms_p99": 49.0}
    assert bench.verdict(row) == {"checks": {"success": True, "stale_stops": True, "latency_ms_p99": True},
                                  "pass": True}
    assert bench.verdict(row | {"stale_stops": 1})["pass"] is False
    unmeasured = bench.verdict({"quota_percent": 100.0, "latency_ms_p99": 3.0, "loop_stall_ms_max": None})
    assert unmeasured["checks"]["loop_stall_ms_max"] is None and unmeasured["pass"] is False
    assert bench.verdict({"quota_percent": 25.0, "run": "s0-open", "error": "boom"})["pass"] is False
    assert bench.verdict({"quota_percent": 50.0, "success": False})["pass"] is None  # no target at 50 %


def test_the_locate_row_is_judged_by_its_own_targets() -> None:
    """rfhoming locate on a recording has no stale stops to count: its row passes on keeping up."""
    bench = load_bench()
    row = {"quota_percent": 25.0, "run": "locate/replay", "success": True, "stale_stops": None, "latency_ms_p99": 20.0}
    assert bench.verdict(row) == {"checks": {"success": True, "latency_ms_p99": True}, "pass": True}
    assert bench.verdict(row | {"latency_ms_p99": 150.0})["pass"] is False
    assert "locate/replay" in bench.RUNS


@pytest.mark.skipif(not os.access(CPU / "cpu.cfs_quota_us", os.W_OK), reason="needs root and cgroup v1's cpu controller")
@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, -signal.SIGTERM)])
def test_ctrl_c_and_sigterm_end_the_run_and_remove_its_cgroups(sig: int, status: int) -> None:
    proc = subprocess.Popen([sys.executable, str(BENCH), "--runs", "s2-a", "--quotas", "25", "--mechanism", "cgroup-v1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    group = CPU / f"rfhoming-budget-{proc.pid}"
    try:
        end = time.monotonic() + 60  # a hang guard: the test waits for the worker to be in the group
        while not (group.exists() and (group / "cgroup.procs").read_text().split()):
            assert proc.poll() is None and time.monotonic() < end, proc.communicate(timeout=30)[1] if proc.poll() is not None else ""
            time.sleep(0.05)
        inside = [int(p) for p in (group / "cgroup.procs").read_text().split()]
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == status and "Traceback" not in stderr, stderr
    assert not group.exists() and not (Path("/sys/fs/cgroup/cpuacct") / group.name).exists()
    for pid in inside:
        assert not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]
