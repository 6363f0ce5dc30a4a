"""Every demo scenario in real time inside a CPU budget: does the robot still home on a small computer?

Each run is a real homing at robot time (the emulator's ``--speed 1``, as ``rfhoming demo
--speed 1`` runs it: the emulator in its own process on ptys, the host's one run assembly on
the paths it printed); the anchors run is ``rfhoming emulate kit-home --speed 1`` with the
anchors homing ``rfhoming run --controller anchors --site docs/sites/kit-home.toml`` makes (the
site's ports rewritten to the run's own folder). The runs are s0-open, s0-house, s1-dock, s2-a ... s2-e, s3-arena with
each BLE receiver it serves (esp32, esp-at, hci) and kit-home/anchors.

Host and emulator of each run share one CPU quota (``--quotas``, in % of one core):

- ``cgroup-v1``: a cpu cgroup under /sys/fs/cgroup/cpu with ``cpu.cfs_period_us`` 10000 and
  ``cpu.cfs_quota_us`` 100 x the quota (25 % -> 2500 us of CPU each 10 ms), and a cpuacct cgroup
  for the CPU it used. Needs root.
- ``cgroup-v2``: the same in the unified hierarchy (``cpu.max`` "2500 10000"), where it has
  the cpu controller.
- ``duty``: when no cgroup can be written. Every process of the run is pinned to one core
  (sched_setaffinity: at most 100 % of it) and, below 100 %, its process group is stopped
  and continued (SIGSTOP/SIGCONT) in a 100 ms cycle: 25 % runs 25 ms and stops 75 ms. That
  is ten times coarser than the cgroup's 10 ms period: a stall of up to 75 ms in every
  100 ms, which a real slow core does not have -- read its latencies as an upper bound.

For each run and quota it reports: arrival (``success``: arrived within 1 m of the target),
stale-data stops, the reading-to-command latency p50/p99 (ms, wall clock), the longest
event-loop stall (``loop_stall_ms_max`` from the run's summary; null where the host does not
measure it) and the CPU seconds host and emulator used per simulated second, counted from
the start of the homing to its end (the cgroup's cpuacct usage; with ``duty``, the two
processes' utime+stime from /proc). Then the targets, pass/fail:

- at 25 %: every run arrives, 0 stale stops, control p99 <= 50 ms;
- at 100 %: control p99 <= 10 ms and loop stalls <= 20 ms.

The machine's load (``os.getloadavg``) before and after is part of the report. A quota alone is
a ceiling, not a reservation: on a busy machine a run would get less, and the figures would
measure the machine. So the cgroup also gets the scheduler's largest weight (v1 ``cpu.shares``
262144, v2 ``cpu.weight`` 10000): the run gets its quota first, as rfhoming would on a robot
computer whose other nodes have the rest (``--no-reserve`` leaves the default weight). The cgroups it makes are
removed when it ends, on Ctrl-C and on SIGTERM too.

    python bench/budget_bench.py --json                       # everything, ~25 min
    python bench/budget_bench.py --runs s0-open,s1-dock --quotas 25
    python bench/budget_bench.py --mechanism duty --runs s2-a  # the fallback, to compare
    python bench/budget_bench.py --runs locate/replay --quotas 25   # rfhoming locate live on a real recording

``locate/replay`` is not a homing: ``rfhoming locate`` reads a real four-anchor recording
(``--capture FILE``, e.g. the Girolami et al. recordings' uc1_run1, ~150 +UUDF lines/s; docs/RESULTS.md,
"Real recordings"; without it the default set of runs leaves this one out) at its
recorded pace (``--from capture:FILE,speed=1``: the live drivers, the bytes when they came); its
latency is each position line's arrival less its tick, less that of the first lines (the
recording's clock is not the machine's), and its targets are LOCATE_TARGETS.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

RUNS = ["s0-open", "s0-house", "s1-dock", "s2-a", "s2-b", "s2-c", "s2-d", "s2-e",
        "s3-arena/esp32", "s3-arena/esp-at", "s3-arena/hci", "kit-home/anchors", "locate/replay"]
TARGETS = {25: {"success": True, "stale_stops": 0, "latency_ms_p99": 50.0},
           100: {"latency_ms_p99": 10.0, "loop_stall_ms_max": 20.0}}
LOCATE_TARGETS = {25: {"success": True, "latency_ms_p99": 100.0}, 100: {"latency_ms_p99": 50.0}}
"""locate/replay: its latency is how much later after its tick a position line arrives than the
first lines did (the recording's clock is not the machine's: a locate that keeps up stays near 0,
one that falls behind grows); success: positions over the whole recording, none a second late."""
PERIOD_US = 10_000  # the cgroup's period: the quota is spent in slices of at most this
DUTY_PERIOD_S = 0.1
SITE = Path(__file__).resolve().parent.parent / "docs" / "sites" / "kit-home.toml"
NAME = f"rfhoming-budget-{os.getpid()}"


# ---------------------------------------------------------------- the CPU quota


class Quota:
    """Host and emulator of one run inside ``percent`` of one core; ``usage_s()`` is the CPU
    they used so far, in seconds (None where the worker counts it itself)."""

    mechanism = ""

    def __init__(self, percent: float, reserve: bool = True) -> None:
        self.percent = percent
        self.reserve = reserve  # the most weight the scheduler gives: the quota is then also a reservation

    def admit(self, proc: subprocess.Popen) -> None:
        """Put the just-started worker (and so every child it starts later) in the quota."""

    def usage_file(self) -> str | None:
        return None

    def close(self) -> None:
        """Undo what admit made; the run's processes have ended (or are killed here)."""


class CgroupV1(Quota):
    mechanism = "cgroup-v1"
    CPU, ACCT = Path("/sys/fs/cgroup/cpu"), Path("/sys/fs/cgroup/cpuacct")

    def __init__(self, percent: float, reserve: bool = True) -> None:
        super().__init__(percent, reserve)
        self.dirs = [self.CPU / NAME] + ([self.ACCT / NAME] if self.ACCT.resolve() != self.CPU.resolve() else [])
        for d in self.dirs:
            d.mkdir()
        (self.dirs[0] / "cpu.cfs_period_us").write_text(str(PERIOD_US))
        (self.dirs[0] / "cpu.cfs_quota_us").write_text(str(round(PERIOD_US * percent / 100)))
        if reserve:
            (self.dirs[0] / "cpu.shares").write_text("262144")  # v1's largest

    @classmethod
    def usable(cls) -> bool:
        return os.access(cls.CPU / "cpu.cfs_quota_us", os.W_OK) and (cls.ACCT / "cpuacct.usage").exists()

    def admit(self, proc: subprocess.Popen) -> None:
        for d in self.dirs:
            (d / "cgroup.procs").write_text(str(proc.pid))

    def usage_file(self) -> str:
        return str(self.dirs[-1] / "cpuacct.usage")  # nanoseconds

    def close(self) -> None:
        _kill_and_remove(self.dirs)


class CgroupV2(Quota):
    mechanism = "cgroup-v2"

    def __init__(self, percent: float, reserve: bool = True) -> None:
        super().__init__(percent, reserve)
        root = self.root()
        assert root is not None
        if "cpu" not in (root / "cgroup.subtree_control").read_text().split():
            (root / "cgroup.subtree_control").write_text("+cpu")
        self.dirs = [root / NAME]
        self.dirs[0].mkdir()
        (self.dirs[0] / "cpu.max").write_text(f"{round(PERIOD_US * percent / 100)} {PERIOD_US}")
        if reserve:
            (self.dirs[0] / "cpu.weight").write_text("10000")  # v2's largest

    @staticmethod
    def root() -> Path | None:
        for line in Path("/proc/self/mounts").read_text().splitlines():
            _, where, kind, *_ = line.split()
            if kind == "cgroup2" and "cpu" in (Path(where) / "cgroup.controllers").read_text().split():
                return Path(where)
        return None

    @classmethod
    def usable(cls) -> bool:
        root = cls.root()
        return root is not None and os.access(root, os.W_OK)

    def admit(self, proc: subprocess.Popen) -> None:
        (self.dirs[0] / "cgroup.procs").write_text(str(proc.pid))

    def usage_file(self) -> str:
        return str(self.dirs[0] / "cpu.stat")  # usage_usec

    def close(self) -> None:
        _kill_and_remove(self.dirs)


class Duty(Quota):
    """The fallback: one core by affinity, and SIGSTOP/SIGCONT of the run's process group in a
    100 ms cycle below 100 %."""

    mechanism = "duty"

    def __init__(self, percent: float, reserve: bool = True) -> None:
        super().__init__(percent, reserve)  # no weight to give: the duty cycle is not a reservation
        self.stop = threading.Event()
        self.thread: threading.Thread | None = None

    def admit(self, proc: subprocess.Popen) -> None:
        os.sched_setaffinity(proc.pid, {min(os.sched_getaffinity(0))})  # children inherit it
        if self.percent < 100:
            self.thread = threading.Thread(target=self._cycle, args=(proc.pid,), daemon=True)
            self.thread.start()

    def _cycle(self, pgid: int) -> None:
        on = DUTY_PERIOD_S * self.percent / 100
        try:
            while not self.stop.is_set():
                os.killpg(pgid, signal.SIGCONT)
                if self.stop.wait(on):
                    break
                os.killpg(pgid, signal.SIGSTOP)
                self.stop.wait(DUTY_PERIOD_S - on)
        except ProcessLookupError:
            return
        finally:
            try:
                os.killpg(pgid, signal.SIGCONT)
            except ProcessLookupError:
                pass

    def close(self) -> None:
        self.stop.set()
        if self.thread is not None:
            self.thread.join()


def _kill_and_remove(dirs: list[Path]) -> None:
    """Kill what is left in our cgroups (only the run's own processes can be there), then
    remove them."""
    for d in dirs:
        if not d.exists():
            continue
        for _ in range(50):
            pids = [int(p) for p in (d / "cgroup.procs").read_text().split()]
            if not pids:
                break
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            time.sleep(0.1)
        for _ in range(50):
            try:
                d.rmdir()
                break
            except OSError:  # the killed processes are still leaving
                time.sleep(0.1)


def choose(mechanism: str) -> type[Quota]:
    kinds: dict[str, type[Quota]] = {"cgroup-v1": CgroupV1, "cgroup-v2": CgroupV2, "duty": Duty}
    if mechanism != "auto":
        return kinds[mechanism]
    for kind in (CgroupV2, CgroupV1):
        if kind.usable():
            return kind
    return Duty


# ---------------------------------------------------------------- one run (in the worker)


def _cpu_now(usage_file: str | None, pids: list[int]) -> float:
    """CPU seconds: the cgroup's counter, or the listed processes' utime+stime."""
    if usage_file is not None:
        text = Path(usage_file).read_text()
        if usage_file.endswith("cpu.stat"):
            return int(dict(line.split() for line in text.splitlines())["usage_usec"]) / 1e6
        return int(text) / 1e9
    ticks = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for pid in pids:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / ticks  # utime, stime
    return total


def locate_worker(capture: Path, site: Path, out: Path, usage_file: str | None) -> dict[str, Any]:
    """``rfhoming locate`` on a recording replayed at its recorded pace (``--from
    capture:FILE,speed=1``: the same drivers as live, the bytes arriving when they were
    recorded), each position line timed as it arrives: its lag behind its tick, and the CPU
    per second of recording."""
    out.mkdir(parents=True, exist_ok=True)
    cpu0 = _cpu_now(usage_file, [os.getpid()])
    with (out / "locate.err").open("w") as err:
        locate = subprocess.Popen([sys.executable, "-m", "rfhoming", "locate", str(site), "--from",
                                   f"capture:{capture},speed=1"], stdout=subprocess.PIPE, stderr=err, text=True)
        lags, ticks, summary = [], [], {}
        for line in locate.stdout:  # type: ignore[union-attr]
            got = json.loads(line)
            if got.get("kind") == "position":
                lags.append(time.time() - got["t"])
                ticks.append(got["t"])
            elif got.get("kind") == "summary":
                summary = got
        locate.wait()
    cpu = _cpu_now(usage_file, [os.getpid()]) - cpu0 + (0.0 if usage_file else _children_cpu())
    span = ticks[-1] - ticks[0] if len(ticks) > 1 else 0.0
    # a capture's ticks are its recorded host times: the lag is counted from the first lines' (the
    # median of the first 50: no backlog yet); the last ticks, flushed at the end, come early
    lag = (np.array(lags) - float(np.median(lags[:50]))) * 1000 if lags else np.array([np.nan])
    return {"run": "locate/replay", "success": bool(lags) and span > 0 and float(lag.max()) < 1000.0,
            "reason": f"{len(ticks)} positions over {span:.1f} s of {capture.name}" if ticks else
                      "no position: " + " ".join((out / "locate.err").read_text().splitlines()[-1:]),
            "stale_stops": None, "latency_ms_p50": round(float(np.percentile(lag, 50)), 1),
            "latency_ms_p99": round(float(np.percentile(lag, 99)), 1),
            "loop_stall_ms_max": summary.get("loop_stall_ms_max"), "loop_stall_ms_p99": summary.get("loop_stall_ms_p99"),
            "simulated_time_s": round(span, 2), "wall_s": round(span, 2), "cpu_s": round(cpu, 2),
            "cpu_s_per_sim_s": round(cpu / span, 4) if span else None}


def _children_cpu() -> float:
    """CPU seconds of this process's waited-for children (where no cgroup counts them)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def worker(run: str, seed: int, out: Path, usage_file: str | None) -> dict[str, Any]:
    """One homing at robot time, as ``rfhoming demo --speed 1`` (or emulate + run for the
    anchors) makes it; the CPU counted over the homing only (not the interpreters' start or
    the demo's plot)."""
    import asyncio

    from rfhoming import demo
    from rfhoming.host import site as sites
    from rfhoming.host.homing.assembly import Device, Homing
    from rfhoming.host.homing.config import Config

    scenario, _, kind = run.partition("/")
    config = Config()
    out.mkdir(parents=True, exist_ok=True)
    truth = out / "truth.jsonl"
    proc, endpoints = (_start_kit_home(seed, truth, out) if kind == "anchors" else
                       demo.start_emulator(scenario, seed, truth, out, None, kind or None, 1.0))
    try:
        if kind == "anchors":
            site_file = out / "site.toml"
            site_file.write_text(SITE.read_text().replace("/tmp/rfhoming-kit/", f"{out}/"))
            site = sites.load(site_file)
            plan = Homing("anchors", [*(Device("anchor", spec=a.port) for a in site.anchors),
                                      Device("base", spec=f"base:{out}/base")], config, site=site)
        else:
            if scenario == "s3-arena":
                config = demo.trilat_config(config, truth, None)
            plan = demo.plan(endpoints, out, config)
        cpu0, wall0 = _cpu_now(usage_file, [os.getpid(), proc.pid]), time.monotonic()
        try:
            outcome = asyncio.run(asyncio.wait_for(demo.home(plan, out), config.loop.max_time_s + 60))
        except TimeoutError:  # the loop stalled so long that its robot-time limit never came
            return {"run": run, "success": False, "reason": f"no end in {config.loop.max_time_s + 60:g} s of wall time",
                    "stale_stops": None, "latency_ms_p50": None, "latency_ms_p99": None, "loop_stall_ms_max": None,
                    "loop_stall_ms_p99": None, "simulated_time_s": None, "wall_s": round(time.monotonic() - wall0, 2),
                    "cpu_s": round(_cpu_now(usage_file, [os.getpid(), proc.pid]) - cpu0, 2), "cpu_s_per_sim_s": None}
        cpu = _cpu_now(usage_file, [os.getpid(), proc.pid]) - cpu0
        wall = time.monotonic() - wall0
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
    summary = demo.summarise(outcome, truth, outcome.links, config.trilat.goal if scenario == "s3-arena" else None)
    summary.update({k: v for k, v in outcome.summary().items() if k.startswith("loop_stall") and k not in summary})
    sim = summary["simulated_time_s"]
    return {"run": run, "success": summary["success"], "reason": summary["reason"],
            "stale_stops": summary["stale_stops"], "latency_ms_p50": summary["latency_ms_p50"],
            "latency_ms_p99": summary["latency_ms_p99"], "loop_stall_ms_max": summary.get("loop_stall_ms_max"),
            "loop_stall_ms_p99": summary.get("loop_stall_ms_p99"), "simulated_time_s": sim,
            "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "cpu_s_per_sim_s": round(cpu / sim, 4) if sim else None}


def _start_kit_home(seed: int, truth: Path, out: Path) -> tuple[subprocess.Popen, dict]:
    cmd = [sys.executable, "-m", "rfhoming", "emulate", "kit-home", "--radio", "ideal", "--pty", "--speed", "1", "--seed", str(seed),
           "--truth", str(truth), "--link-dir", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    endpoints = {}
    while len(endpoints) < 5:  # four anchors and the base
        line = proc.stdout.readline()  # type: ignore[union-attr]
        if not line:
            raise SystemExit(f"the kit-home emulator did not start: {proc.stderr.read().strip()[-300:]}")  # type: ignore[union-attr]
        endpoint = json.loads(line)
        endpoints[endpoint["device"]] = endpoint
    return proc, endpoints


# ---------------------------------------------------------------- the bench (parent)


def run_one(run: str, percent: float, kind: type[Quota], seed: int, out: Path, reserve: bool = True,
            capture: Path | None = None) -> dict[str, Any]:
    quota = kind(percent, reserve)
    try:
        cmd = [sys.executable, __file__, "--worker", run, "--seed", str(seed), "--out", str(out),
               *(["--capture", str(capture)] if capture else [])]
        if quota.usage_file() is not None:
            cmd += ["--usage-file", str(quota.usage_file())]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)  # its own process group: the duty cycle's, and Ctrl-C's
        try:
            quota.admit(proc)
            stdout, stderr = proc.communicate(timeout=400)  # a hang guard: max_time_s 180 + set-up, at 25 %
        except BaseException:
            _end(proc)
            raise
    finally:
        quota.close()
    if proc.returncode != 0 or not stdout.strip():
        why = (stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
        return {"run": run, "quota_percent": percent, "error": why}
    return {"quota_percent": percent, **json.loads(stdout.strip().splitlines()[-1])}


def _end(proc: subprocess.Popen) -> None:
    """Ctrl-C or a hang: the worker's group gets SIGCONT and SIGINT (the demo's own clean stop),
    then SIGKILL."""
    for sig in (signal.SIGCONT, signal.SIGINT):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def verdict(row: dict[str, Any]) -> dict[str, Any]:
    """Each target of the row's quota: True, False or None (not measured)."""
    checks: dict[str, bool | None] = {}
    targets = LOCATE_TARGETS if row.get("run") == "locate/replay" else TARGETS
    for key, want in targets.get(int(row["quota_percent"]), {}).items():
        got = row.get(key)
        if got is None and key != "success":
            checks[key] = None
        elif isinstance(want, bool):
            checks[key] = got is want
        else:
            checks[key] = got <= want
    if "error" in row:
        checks = {"ran": False}
    known = [v for v in checks.values() if v is not None]
    return {"checks": checks, "pass": all(known) and len(known) == len(checks) if checks else None}


def table(rows: list[dict[str, Any]]) -> str:
    def cell(v: Any) -> str:
        return "n/a" if v is None else ("yes" if v is True else "no" if v is False else str(v))
    head = ["run", "quota %", "arrived", "stale", "p50 ms", "p99 ms", "stall max ms", "cpu s / sim s", "sim s",
            "target"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['run']} | {r['quota_percent']:g} | error: {r['error']} |")
            continue
        failed = [k for k, ok in r["verdict"]["checks"].items() if ok is False]
        unknown = [k for k, ok in r["verdict"]["checks"].items() if ok is None]
        mark = ("pass" if r["verdict"]["pass"] else "FAIL " + ", ".join(failed) if failed else
                "n/a: " + ", ".join(unknown)) if r["verdict"]["checks"] else ""
        lines.append("| " + " | ".join(cell(v) for v in (
            r["run"], f"{r['quota_percent']:g}", r["success"], r["stale_stops"], r["latency_ms_p50"],
            r["latency_ms_p99"], r["loop_stall_ms_max"], r["cpu_s_per_sim_s"], r["simulated_time_s"], mark)) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", default=",".join(RUNS),
                   help=f"comma-separated runs (default all: {', '.join(RUNS)})")
    p.add_argument("--quotas", default="25,100", help="CPU quotas in %% of one core (default 25,100)")
    p.add_argument("--mechanism", choices=["auto", "cgroup-v1", "cgroup-v2", "duty"], default="auto",
                   help="how the quota is held (default auto: cgroup v2 with cpu, else v1, else duty)")
    p.add_argument("--no-reserve", dest="reserve", action="store_false",
                   help="leave the cgroup the default scheduler weight (by default it gets the largest, so "
                        "that other work on this machine does not take its quota)")
    p.add_argument("--seed", type=int, default=1, help="the worlds' seed (default 1)")
    p.add_argument("--out", type=Path, help="keep each run's capture, run log and truth here (default: a "
                   "temporary folder, removed)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--capture", type=Path,
                   help="locate/replay's recording: a real four-anchor capture in a folder laid out as "
                        "bench/real_aoa.py --help says (site.toml beside captures/); the run needs it")
    p.add_argument("--worker", metavar="RUN", help=argparse.SUPPRESS)
    p.add_argument("--usage-file", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker == "locate/replay":
        assert args.capture is not None  # the parent passes its --capture (checked there)
        print(json.dumps(locate_worker(args.capture, args.capture.parent.parent / "site.toml", args.out,
                                       args.usage_file)))
        return 0
    if args.worker:
        print(json.dumps(worker(args.worker, args.seed, args.out, args.usage_file)))
        return 0
    runs = args.runs.split(",")
    unknown = [r for r in runs if r not in RUNS]
    if unknown:
        p.error(f"unknown run {', '.join(unknown)}; the runs are {', '.join(RUNS)}")
    if "locate/replay" in runs and args.capture is None:
        if args.runs != ",".join(RUNS):
            p.error("locate/replay needs --capture FILE: a real four-anchor recording (docs/RESULTS.md, "
                    "\"Real recordings\")")
        runs.remove("locate/replay")
        print("[budget] locate/replay left out: give --capture FILE (a real four-anchor recording) to run it",
              file=sys.stderr)
    try:
        quotas = [float(q) for q in args.quotas.split(",")]
    except ValueError:
        p.error(f"--quotas {args.quotas}: give percentages of one core, e.g. 25,100")
    if any(not 0 < q <= 100 for q in quotas):
        p.error(f"--quotas {args.quotas}: each must be above 0 and at most 100 (% of one core)")
    kind = choose(args.mechanism)
    if kind in (CgroupV1, CgroupV2) and not kind.usable():
        p.error(f"--mechanism {args.mechanism}: cannot write its cgroup files (run as root, or use duty)")
    terminated = []

    def on_term(*_: object) -> None:
        terminated.append(True)
        raise KeyboardInterrupt  # the same clean-up as Ctrl-C

    signal.signal(signal.SIGTERM, on_term)
    out = args.out or Path(tempfile.mkdtemp(prefix="rfhoming-budget-"))
    load0 = os.getloadavg()
    rows = []
    try:
        for q in quotas:
            for run in runs:
                print(f"[budget] {run} at {q:g} % of one core ({kind.mechanism}) ...", file=sys.stderr, flush=True)
                row = run_one(run, q, kind, args.seed, out / f"{q:g}" / run.replace("/", "-"), args.reserve, args.capture)
                row["verdict"] = verdict(row)
                print(f"[budget]   {json.dumps({k: v for k, v in row.items() if k != 'verdict'})}",
                      file=sys.stderr, flush=True)
                rows.append(row)
    except KeyboardInterrupt:
        print("[budget] interrupted; its cgroups are removed", file=sys.stderr)
        if terminated:  # cleaned up: now end as SIGTERM ends a process
            if args.out is None:
                shutil.rmtree(out, ignore_errors=True)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
        return 130
    finally:
        if args.out is None:
            shutil.rmtree(out, ignore_errors=True)
    report = {"mechanism": kind.mechanism, "reserved": args.reserve and kind is not Duty, "period_us": PERIOD_US if kind is not Duty else DUTY_PERIOD_S * 1e6,
              "targets": {f"{q}%": t for q, t in TARGETS.items()}, "seed": args.seed,
              "loadavg_before": [round(x, 2) for x in load0],
              "loadavg_after": [round(x, 2) for x in os.getloadavg()], "cpus": os.cpu_count(),
              "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
              "runs": rows, "all_pass": all(r["verdict"]["pass"] for r in rows)}
    if args.json:
        print(json.dumps(report))
    else:
        print(table(rows))
        print(f"mechanism {report['mechanism']}; load average before {report['loadavg_before']}, after "
              f"{report['loadavg_after']}; all targets met: {report['all_pass']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
