"""``rfhoming demo``: the emulator in its own process on ptys, the host homing against it.

The host side is exactly ``rfhoming run``: the one run assembly, on the pty paths the emulator
printed, with a capture. On ptys the emulator is a subprocess (``rfhoming emulate``), as a
user would start it, and its truth file gives the summary and the plot; only ``--in-process``
imports the emulator, to join it and the host by its in-process byte pipe.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from collections.abc import Callable
from typing import Any

from rfhoming.host import outputs
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.outputs import Output, part_of
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import CHOOSE_TAG_S, Device, Homing, run_record, sensors_of
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import Outcome, RunLog
from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error


log = logging.getLogger(__name__)

FILES = ("trajectory.png", "capture.pcapng", "run.jsonl", "truth.jsonl")
"""What a demo writes in its folder (each NAME.part until it is done: host/outputs.py)."""


class DemoError(Error):
    """The emulator child did not start; the message is its own last line of explanation."""


SUPPORTED = {"s0-open", "s0-house", "s1-dock", "s2-a", "s2-b", "s2-c", "s2-d", "s2-e", "s3-arena", "s4-air"}  # S0–S4
SURVEYS = {"s4-air"}
"""Scenarios of S4's survey: the vehicle is told which beacon to hold over (the scenario's first,
as the other demos home on it), and the summary holds S4's localisation metric."""
S4_PAPER = {"mean_m": 0.234, "p95_below_m": 0.65}
"""S4's EKF over 10,000 simulated beacons: mean error 0.234 m, 95 % below 0.65 m."""
SURVEY_TIME_S = 600.0
"""S4's pattern takes 260 s at 0.2 m/s: a survey run's time limit is at least this."""
ARRIVED_M = 1.0
"""A run succeeds with the robot this near the tag (and in its line of sight)."""
ARM = ",arm=1"
"""The demo arms the emulated MAVLink vehicle: rfhoming never arms one unless told (arm=1), and
the demo tells it for the emulator's vehicle only."""


def start_emulator(scenario: str, seed: int, truth: Path, link_dir: Path, target: str | None,
                   receiver: str | None = None, speed: float = 0.0,
                   radio: str = "ideal") -> tuple[subprocess.Popen[str], dict[str, Any]]:
    """The emulator's process and every device it printed, by the scenario's device name (the
    truth file's header says how many). ``speed`` 0: lockstep (as fast as the host answers,
    deterministic); else the emulator's ``--speed`` (1 = robot time, for a person watching);
    ``radio``: its ``--radio``."""
    pace = ["--lockstep"] if speed == 0 else ["--speed", str(speed)]
    cmd = [sys.executable, "-m", "rfhoming", "emulate", scenario, "--pty", *pace, "--seed", str(seed),
           "--truth", str(truth), "--link-dir", str(link_dir), "--radio", radio]
    if receiver:
        cmd += ["--receiver", receiver]
    if target:
        cmd.append(f"--target={target}")  # "=": a negative X would read as an option
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None  # both piped
    endpoints: dict[str, dict[str, Any]] = {}
    devices_ = 2
    try:
        while len(endpoints) < devices_:
            line = proc.stdout.readline()
            if not line:
                why = proc.stderr.read().strip().splitlines() or [f"it exited with status {proc.wait()}"]
                raise DemoError(f"the emulator did not start: {why[-1]}")
            endpoint = json.loads(line)
            endpoints[endpoint["device"]] = endpoint
            devices_ = len(read_truth(part_of(truth))[0].get("devices", ())) or 2  # written before the first endpoint
    except BaseException:  # Ctrl-C or SIGTERM while it starts: it goes too
        stop_emulator(proc, grace_s=INTERRUPTED_GRACE_S)
        raise
    return proc, endpoints


INTERRUPTED_GRACE_S = 1.0
"""After Ctrl-C or SIGTERM the emulator has this long to close before it is killed: the demo and
every child it started are gone within 2 s."""


def stop_emulator(proc: subprocess.Popen[str], grace_s: float) -> None:
    """Ctrl-C to the emulator (it closes its links and writes the last truth line), then kill it
    if it has not gone within ``grace_s``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def plan(endpoints: dict[str, dict[str, Any]], out: Path, config: Config, sinks: tuple[Any, ...] = ()) -> Homing:
    """The same homing run ``rfhoming run`` makes, on the ptys the emulator printed: each
    device by its port spec (the kind it printed and its path), with a capture of every byte."""
    named = {e["device"]: e for e in endpoints.values()}
    controller, role, sensors = sensors_of(list(named))
    plan = Homing(controller, [*(Device(role, spec=_spec(named[n])) for n in sensors), Device("base", spec=_spec(named["base"]))],
                  config, sinks=sinks, choose_tag_s=CHOOSE_TAG_S)
    plan.capture = CaptureWriter(out / "capture.pcapng", comment=run_record(plan))
    return plan


def vehicle_of(endpoint: dict[str, Any]) -> str | None:
    """The emulated MAVLink vehicle's UDP address (HOST:PORT) a ground station connects to
    (``udpout:HOST:PORT``) beside the demo's run; None for another base."""
    return endpoint.get("mavlink", {}).get("vehicle") if endpoint.get("kind") == "mavlink" else None


def _spec(endpoint: dict[str, Any]) -> str:
    """The port spec of a device the emulator printed (a MAVLink vehicle's path is a whole spec:
    the demo arms it)."""
    path: str = endpoint["path"]
    if path.startswith(f"{endpoint['kind']}:"):
        return path + (ARM if endpoint["kind"] == "mavlink" else "")
    return f"{endpoint['kind']}:{path}"


async def home(plan: Homing, out: Path) -> Outcome:
    """The run, its log in OUT/run.jsonl; the plan's capture is closed however it ends (a run
    log that cannot be opened too: its capture's .part is not left behind)."""
    try:
        with contextlib.closing(Output(out / "run.jsonl")) as runlog:
            plan.runlog = RunLog(runlog)
            return await assembly.run(plan)
    finally:
        if plan.capture is not None:
            plan.capture.close()


def trilat_config(config: Config, truth: Path, target: str | None) -> Config:
    """The arena's beacons as anchors, and the goal (--target, or (4, 4))."""
    _, states = read_truth(_started(truth))
    anchors = {t["id"]: [t["x"], t["y"]] for t in states[0]["targets"]}
    goal = [float(v) for v in target.split(",")] if target else [4.0, 4.0]
    return replace(config, trilat=replace(config.trilat, anchors=anchors, goal=goal))


def _started(truth: Path) -> Path:
    """The truth file of an emulator that runs (TRUTH.part until it stops: host/outputs.py),
    once it holds the header and the first state."""
    live = part_of(truth)
    for _ in range(50):  # the emulator writes the truth file as it starts
        if live.exists() and len(live.read_text().splitlines()) >= 2:
            break
        time.sleep(0.05)
    return live


def read_truth(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The header and the states; a torn last line (an emulator killed while it wrote) is skipped."""
    text = path.read_text()
    lines = [json.loads(line) for line in text[:text.rfind("\n") + 1].splitlines() if line.strip()]
    return lines[0], [line for line in lines[1:] if "t" in line]


def survey_config(config: Config, truth: Path) -> Config:
    """A survey run on ptys: hold over the scenario's first beacon (by its address, as a user
    names the beacon to find), read from the truth file once the emulator has written it."""
    _, states = read_truth(_started(truth))
    return _surveying(config, states[0]["targets"][0]["id"])


def _surveying(config: Config, beacon: str) -> Config:
    return replace(config, s4=replace(config.s4, home_on=config.s4.home_on or beacon))


def localisation(runlog_path: Path, targets: list[dict[str, Any]]) -> dict[str, Any] | None:
    """S4's metric: each beacon's final estimate (the run log's last) against the truth; None
    for a run that localised none."""
    import numpy as np

    last = None
    with open(runlog_path) as log:
        for line in log:
            if '"beacons"' in line:
                last = line
    if last is None:
        return None
    record = json.loads(last)
    out: dict[str, Any] = {}
    for key, name in (("beacons", "ekf"), ("smoothed", "ekf_smoothed")):
        estimates = record.get(key, {})
        errors = [math.dist(estimates[t["id"]], (t["x"], t["y"])) for t in targets if t["id"] in estimates]
        if errors:
            out[name] = {"beacons": len(errors), "of": len(targets), "mean_m": round(float(np.mean(errors)), 3),
                         "p95_m": round(float(np.percentile(errors, 95)), 3), "max_m": round(max(errors), 3)}
    return {**out, "s4_paper": S4_PAPER} if out else None


def summarise(outcome: Outcome, truth_path: Path, links: dict[str, Any], goal: list[float] | None = None) -> dict[str, Any]:
    """The run against the truth file. Success: the host said it arrived and, by the truth,
    it did (:mod:`rfhoming.emulator.arrival`: within ``ARRIVED_M`` of the tag, in its line of
    sight)."""
    from rfhoming.emulator import arrival  # geometry only: no emulator runs for this

    header, states = read_truth(truth_path)
    target = states[-1]["targets"][0] if goal is None else {"x": goal[0], "y": goal[1]}
    start, end = states[0]["robot"], states[-1]["robot"]
    path = sum(math.dist((a["robot"]["x"], a["robot"]["y"]), (b["robot"]["x"], b["robot"]["y"]))
               for a, b in zip(states, states[1:]))
    straight = math.dist((start["x"], start["y"]), (end["x"], end["y"]))
    final_error = math.dist((end["x"], end["y"]), (target["x"], target["y"]))
    goal_error = None if outcome.goal is None else math.dist(outcome.goal, (target["x"], target["y"]))
    runlog = truth_path.parent / "run.jsonl"
    located = localisation(runlog, states[-1]["targets"]) if header["scenario"] in SURVEYS and runlog.exists() else None
    return {
        "scenario": header["scenario"],
        **({"localisation": located} if header["scenario"] in SURVEYS else {}),
        "success": outcome.arrived and arrival.arrived((end["x"], end["y"]), (target["x"], target["y"]), ARRIVED_M,
                                                       header.get("obstacles", [])),
        "reason": outcome.reason,
        "simulated_time_s": round(outcome.robot_time_s, 2),
        "target": [target["x"], target["y"]],
        "goal_position_error_m": None if goal_error is None else round(goal_error, 3),
        "final_position_error_m": round(final_error, 3),
        "path_efficiency": round(straight / path, 3) if path > 0 else None,
        "net_velocity_m_s": round(straight / outcome.robot_time_s, 3) if outcome.robot_time_s else None,
        "stale_stops": outcome.stale_stops,
        "latency_ms_p50": outcome.summary()["latency_ms_p50"],
        "latency_ms_p99": outcome.summary()["latency_ms_p99"],
        "loop_stall_ms_max": outcome.summary()["loop_stall_ms_max"],
        "loop_stall_ms_p99": outcome.summary()["loop_stall_ms_p99"],
        "links": {name: {k: h[k] for k in ("bytes_in", "bytes_out", "disconnects", "reconnects") if k in h}
                  | {k: v for k, v in h.items() if k.startswith("decoder.drop")} for name, h in links.items()},
    }


def plot(truth_path: Path, runlog_path: Path, out_png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    header, states = read_truth(truth_path)
    fig, ax = plt.subplots(figsize=(7, 7), dpi=110)
    for poly in header["obstacles"]:
        ax.fill(*zip(*poly), color="0.6", zorder=1)
    xs = [s["robot"]["x"] for s in states]
    ys = [s["robot"]["y"] for s in states]
    ax.plot(xs, ys, color="tab:blue", lw=2, label="robot (true path)", zorder=3)
    goals = [json.loads(line) for line in runlog_path.read_text().splitlines()]
    goals = [g["goal"] for g in goals if g.get("kind") == "estimate" and g.get("goal")]
    if goals:
        gx, gy = zip(*goals)
        ax.scatter(gx, gy, c=range(len(gx)), cmap="autumn_r", s=8, label="estimated target over time", zorder=2)
    located = [g for g in map(json.loads, runlog_path.read_text().splitlines()) if "beacons" in g]
    if located:  # a survey: every beacon, and where the run put each
        others = states[-1]["targets"][1:]
        ax.scatter([t["x"] for t in others], [t["y"] for t in others], marker="*", s=90, color="khaki", ec="k",
                   label="other beacons (truth)", zorder=4)
        final = located[-1].get("smoothed", located[-1]["beacons"])
        ax.scatter([p[0] for p in final.values()], [p[1] for p in final.values()], marker="x", s=40, color="tab:red",
                   label="beacons as localised", zorder=5)
    target = states[-1]["targets"][0]
    ax.plot(target["x"], target["y"], marker="*", ms=18, color="gold", mec="k",
            label="beacon held over (truth)" if located else "tag (truth)", zorder=4)
    ax.plot(xs[0], ys[0], "ko", label="start", zorder=4)
    x0, y0, x1, y1 = header["bounds"]
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"rfhoming demo: {header['scenario']}")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    outputs.save_figure(fig, out_png)
    plt.close(fig)


async def _in_process(scenario: str, seed: int, out: Path, config: Config, target: str | None,
                     receiver: str | None, sinks: tuple[Any, ...] = (), radio: str = "ideal",
                     announce: Callable[[str], None] = lambda address: None) -> tuple[Outcome, Config]:
    """The same run with the emulator in this process on its byte pipe, in lockstep: the host
    settles after every step, so the result depends on the seed alone (as in the campaigns)."""
    from rfhoming.campaigns.closed_loop import PipePort
    from rfhoming.emulator.links import pipe_end
    from rfhoming.emulator.runtime import Emulator
    from rfhoming.emulator.scenario import load

    xy = tuple(float(v) for v in target.split(",")) if target and scenario != "s3-arena" else None
    sc = load(scenario, seed=seed, target=xy, receiver=receiver, radio=radio)
    if scenario == "s3-arena":
        goal = [float(v) for v in target.split(",")] if target else [4.0, 4.0]
        beacons = {t.id: list(t.position) for t in sc.world.targets}
        config = replace(config, trilat=replace(config.trilat, anchors=beacons, goal=goal))
    if scenario in SURVEYS:
        config = _surveying(config, sc.world.targets[0].id)
    names = {d.name: d.type for d in sc.devices}
    controller, role, sensors = sensors_of(list(names))
    with contextlib.closing(Output(out / "truth.jsonl")) as truth:
        em = Emulator(sc, transport="pipe", seed=seed, lockstep=True, lockstep_timeout=2.0, truth=truth.file)
        await em.start()
        truth.own()  # its devices are up: this run's truth replaces the old however it ends
        world = asyncio.create_task(em.run())
        sensed = [Device(role, port=PipePort(n, pipe_end(em.device(n).link)), kind=devices.BOARDS[names[n]][0].name)
                  for n in sensors]
        base_link = em.device("base").link
        if (vehicle := vehicle_of(base_link.describe())) is not None:  # on UDP: the host connects as a ground station
            announce(vehicle)
            base = Device("base", spec=_spec(base_link.describe()))
        else:
            base = Device("base", port=PipePort("base", pipe_end(base_link)))
        plan = Homing(controller, [*sensed, base], config, sinks=sinks, choose_tag_s=CHOOSE_TAG_S)
        capture = plan.capture = CaptureWriter(out / "capture.pcapng", comment=run_record(plan))
        for device in plan.devices:
            if device.port is not None:  # a spec's port is described when it is resolved
                device.port.taps.append(capture.tap)
                capture.describe(device.port.name, kind=device.kind or "base", role=device.role)
        try:
            outcome = await home(plan, out)
        finally:
            world.cancel()
            await asyncio.gather(world, return_exceptions=True)
            await em.close()
        em.write_truth()  # the final pose
    return outcome, config


def check_outputs(out: Path) -> None:
    """The demo's folder made, and every file the demo writes there checked before anything
    starts: one WriteFailed names every NAME.part a killed demo left (and the ``rm`` that
    removes them), rather than one of them a run, after the emulator started."""
    out.mkdir(parents=True, exist_ok=True)
    outputs.check_all(out / name for name in FILES)


def run_demo(scenario: str, seed: int, out: Path, config: Config, target: str | None,
             receiver: str | None = None, sinks: list[Any] | tuple[Any, ...] = (), speed: float = 0.0,
             in_process: bool = False, radio: str = "ideal",
             announce: Callable[[str], None] = lambda address: None) -> dict[str, Any]:
    """One demo run. ``receiver`` (esp32, esp-at, hci) serves the robot's BLE scanner as that
    device; ``sinks`` (an MCAP recorder, a live view) see every item and run log record too,
    and stay open. ``speed``: 0 lockstep, else simulated seconds per wall second (on ptys);
    ``in_process``: the emulator in this process, in lockstep (the same summary for the same
    seed), instead of in its own on ptys; ``radio``: the emulated radios (``ideal``,
    ``measured`` or a profile file: docs/emulator.md, "Radio profiles"); ``announce`` is told
    the emulated MAVLink vehicle's address as soon as it is up (a ground station may join)."""
    check_outputs(out)
    if scenario in SURVEYS:
        config = replace(config, loop=replace(config.loop, max_time_s=max(config.loop.max_time_s, SURVEY_TIME_S)))
    if speed == 0 or in_process:
        config = config.for_lockstep()  # the emulator waits for the host: wall time means nothing
    truth = out / "truth.jsonl"
    if in_process:
        outcome, config = asyncio.run(asyncio.wait_for(
            _in_process(scenario, seed, out, config, target, receiver, tuple(sinks), radio, announce),
            config.loop.max_time_s + 60))
        summary = summarise(outcome, truth, outcome.links, config.trilat.goal if scenario == "s3-arena" else None)
        for key in ("latency_ms_p50", "latency_ms_p99", "loop_stall_ms_max", "loop_stall_ms_p99"):  # wall-clock figures
            summary.pop(key)
        return _finish({"radio": radio, **summary}, out)
    link_dir = Path(tempfile.mkdtemp(prefix="rfhoming-demo-"))
    proc, endpoints = start_emulator(scenario, seed, truth, link_dir, None if scenario == "s3-arena" else target,
                                     receiver, speed, radio)
    if "base" in endpoints and (vehicle := vehicle_of(endpoints["base"])) is not None:
        announce(vehicle)
    try:
        if scenario == "s3-arena":  # S3 localises on beacons at surveyed places: take them from the truth
            config = trilat_config(config, truth, target)
        elif scenario in SURVEYS:
            config = survey_config(config, truth)
        outcome = asyncio.run(asyncio.wait_for(_home_beside(proc, plan(endpoints, out, config, tuple(sinks)), out),
                                               config.loop.max_time_s + 60))
    except BaseException:
        stop_emulator(proc, grace_s=INTERRUPTED_GRACE_S)
        raise
    else:
        stop_emulator(proc, grace_s=10)
    finally:
        shutil.rmtree(link_dir, ignore_errors=True)
        if proc.poll() is not None:  # gone, however it ended (else it is still writing its truth)
            _truth_of_a_killed_emulator(truth)
    summary = summarise(outcome, truth, outcome.links, config.trilat.goal if scenario == "s3-arena" else None)
    return _finish({"radio": radio, **summary}, out)


def _truth_of_a_killed_emulator(truth: Path) -> None:
    """An emulator killed when it outlived its grace could not rename TRUTH.part: its lines
    (flushed one by one) are this run's truth, renamed into place and said, so that the summary
    and plot are never made from the old TRUTH."""
    if outputs.adopt(truth):
        log.warning("demo: the emulator did not stop within its grace and was killed; %s holds this run's truth up "
                    "to its last whole line", truth)


async def _home_beside(emulator: subprocess.Popen[str], plan: Homing, out: Path) -> Outcome:
    """``home``; when it is cancelled (Ctrl-C, SIGTERM) the emulator is told at once, so that it
    closes while the host does."""
    try:
        return await home(plan, out)
    except asyncio.CancelledError:
        emulator.send_signal(signal.SIGINT)
        raise


def _finish(summary: dict[str, Any], out: Path) -> dict[str, Any]:
    plot(out / "truth.jsonl", out / "run.jsonl", out / "trajectory.png")
    summary["files"] = {name: str(out / name) for name in FILES}
    return summary
