"""``rfhoming replay``: a capture through the drivers (the items ``listen`` printed), its homing
run again (``--run``), or served on ptys (``--pty``)."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys

from rfhoming.cli.printer import printer
from rfhoming.host.portspec import PortSpec
from rfhoming.host.run_until import run_until
from rfhoming.host.session import health, replay_drivers
from rfhoming.protocol.errors import Error
from rfhoming.protocol.pcapng import CaptureFormatError, Interface


def run(args: argparse.Namespace) -> int:
    if args.run:
        return replay_run(args)
    if args.pty:
        return serve_capture_on_ptys(args)
    return asyncio.run(_replay(args))


async def _replay(args: argparse.Namespace) -> int:
    damaged: list[Exception] = []

    def warn(exc: Exception) -> None:
        damaged.append(exc)
        print(f"rfhoming replay: {args.capture}: {exc}; replaying what came before it (--partial)", file=sys.stderr)

    try:
        drivers = replay_drivers(PortSpec("capture", str(args.capture), {"speed": args.speed}),
                                 partial=warn if args.partial else None)
    except (OSError, CaptureFormatError) as exc:
        readable = isinstance(exc, CaptureFormatError) and any(isinstance(i, Interface) for i in exc.items)
        hint = " (--partial replays what comes before it)" if readable and not args.partial else ""
        print(f"rfhoming replay: cannot read {args.capture}: {exc}{hint}", file=sys.stderr)
        return 2
    for driver in drivers:
        driver.listeners.append(printer(args.json))
    await run_until(drivers, None)
    for h in health(drivers):
        print(json.dumps({"kind": "counters", **h}))
    return 0


def replay_run(args: argparse.Namespace) -> int:
    """``rfhoming replay CAPTURE --run``: the recorded homing loop again, on the capture's bytes."""
    from rfhoming.host.homing import assembly
    from rfhoming.host.homing.config import load
    from rfhoming.host.homing.loop import RunLog
    from rfhoming.host.outputs import Output

    plan = assembly.replay_plan(args.capture, controller=args.controller,
                                config=load(args.config) if args.config else None)
    runlog = Output(args.log) if args.log else None  # LOG.part until the run ends, then LOG
    plan.runlog = RunLog(runlog)
    try:
        outcome = asyncio.run(assembly.run(plan))
    finally:
        if runlog:
            runlog.close()
    ports = [device.port for device in plan.devices]
    firsts = [p.first_divergence for p in ports if p.first_divergence is not None]
    first = min(firsts, key=lambda d: d["t"]) if firsts else None
    replay = {"diverged": sum(p.counters["diverged"] for p in ports),
              "unanswered": sum(p.counters["unanswered"] for p in ports), "first_divergence": first}
    if first is not None:
        print(f"rfhoming replay: the replayed loop first wrote otherwise than the recording at t = {first['t']:.6f} "
              f"on {first['device']} (wrote {first['wrote']}, the recording has {first['recorded']}); it went on "
              "from the recorded inputs", file=sys.stderr)
    summary = {k: v for k, v in outcome.summary().items()
               if not k.startswith(("latency_ms", "loop_stall_ms"))}  # no wall time here
    print(json.dumps({**summary, "replay": replay}))
    return 0 if outcome.arrived else 1


def serve_capture_on_ptys(args: argparse.Namespace) -> int:
    """``rfhoming replay --pty``: the emulator's pty links serve a recording (the CLI wires the
    emulator's pty server in)."""
    import tempfile
    from pathlib import Path

    from rfhoming.emulator.playback import serve

    def warn(exc: Exception) -> None:
        print(f"rfhoming replay: {args.capture}: {exc}; serving what came before it (--partial)", file=sys.stderr)

    link_dir = args.link_dir or Path(tempfile.mkdtemp(prefix="rfhoming-replay-"))
    try:
        stats = asyncio.run(serve(args.capture, link_dir, speed=args.speed or 1.0, start_delay=args.start_delay,
                                  out=sys.stdout, partial=warn if args.partial else None))
    except (OSError, Error) as exc:
        print(f"rfhoming replay: cannot serve {args.capture}: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"kind": "counters", **stats}))
    return 0
