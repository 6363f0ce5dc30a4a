"""``rfhoming emulate``: run a scenario and serve its devices on ptys or TCP until interrupted."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import sys
from typing import Any

from rfhoming.cli.parsers.common import IDEAL, MEASURED
from rfhoming.emulator.faults import Fault, FaultError
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import ScenarioError, load
from rfhoming.host import dds_guard
from rfhoming.host.outputs import Output
from rfhoming.protocol.errors import Error


def run(args: argparse.Namespace) -> int:
    target = tuple(float(v) for v in args.target.split(",")) if args.target else None
    radio = args.radio or (IDEAL if args.aoa_preset is not None else MEASURED)  # a preset is idealised noise
    try:
        scenario = load(args.scenario, seed=args.seed, target=target, aoa_preset=args.aoa_preset,
                        receiver=args.receiver, radio=radio)
        faults = [Fault.parse(spec) for spec in args.fault]
    except (ScenarioError, FaultError) as exc:
        print(f"rfhoming emulate: {exc}", file=sys.stderr)
        return 2
    if args.link_dir is not None and not args.link_dir.is_dir():
        print(f"rfhoming emulate: --link-dir {args.link_dir} is not a directory: create it "
              f"(mkdir -p {args.link_dir}) or leave --link-dir out for a new temporary one", file=sys.stderr)
        return 2
    truth = Output(args.truth) if args.truth else None  # TRUTH.part while it runs, TRUTH once it stops
    try:
        try:
            emulator = Emulator(
                scenario, transport="tcp" if args.tcp else "pty", seed=args.seed,
                speed=math.inf if args.speed == 0 else args.speed, lockstep=args.lockstep,
                faults=faults, truth=truth.file if truth else None, link_dir=args.link_dir, robot=args.robot,
                pose_from=args.pose_from,
            )
        except Error as exc:
            print(f"rfhoming emulate: {exc}", file=sys.stderr)
            return 2
        asyncio.run(_serve(emulator, args.duration, truth))
    finally:
        if truth is not None:
            truth.close()  # renamed into place once the emulator started, else the old truth file stays
    return 0


async def start(emulator: Emulator) -> list[dict[str, Any]]:
    """The emulator started, and the DDS sockets it opened on loopback domains (its ROS 2 robot,
    ``--pose-from``) kept to loopback traffic as the host's are (host/dds_guard.py)."""
    joiners: list[Any] = [*(d.link for d in emulator.devices), emulator.pose_from]  # those of DDS have a domain
    domains = {int(j.domain) for j in joiners if getattr(j, "discovery", None) == "localhost"}
    before = dds_guard.sockets() if domains else set()
    endpoints = await emulator.start()
    for domain in domains:
        try:
            dds_guard.guard(domain, before)
        except OSError as exc:
            print(f"rfhoming emulate: warning: ROS 2 domain {domain}: Cyclone DDS listens on every interface and its "
                  f"sockets could not be kept to loopback traffic ({exc.strerror or exc})", file=sys.stderr)
    return endpoints


async def _serve(emulator: Emulator, duration: float | None, truth: Output | None) -> None:
    for endpoint in await start(emulator):
        print(json.dumps(endpoint), flush=True)
    if truth is not None:
        truth.own()  # its devices are up: this run's truth replaces the old however it ends
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None  # run by asyncio.run
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    try:
        await emulator.run(duration)
    except asyncio.CancelledError:
        pass
    finally:
        await emulator.close()
        with contextlib.suppress(OSError):
            for d in emulator.devices:
                if hasattr(d.link, "symlink") and d.link.symlink is not None:
                    d.link.symlink.unlink(missing_ok=True)
