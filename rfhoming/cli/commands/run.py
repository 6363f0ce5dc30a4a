"""``rfhoming run``: homing on a tag with real devices or emulator endpoints."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys

from rfhoming.cli.live import mcap_recorder, ros2_publisher, start_foxglove
from rfhoming.cli.plans import plan_devices, tag_option
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import CHOOSE_TAG_S, METHODS, Homing, run_record
from rfhoming.host.homing.config import load
from rfhoming.host.homing.loop import RunLog
from rfhoming.host.outputs import Output
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.host.sink import Sink


def _say_if_unanswered(capture: CaptureWriter) -> None:
    """A run whose devices never answered what it sent leaves the old capture: said in one line."""
    if capture.unanswered:
        print(f"rfhoming run: {capture.said()}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    config = load(args.config)
    role = METHODS[args.controller].role
    devices, site = plan_devices(args, config, role)
    plan = Homing(args.controller, devices, config, site=site, tags=tag_option(args.tag), choose_tag_s=CHOOSE_TAG_S,
                  probe_baud=args.probe_baud, baud=args.baud, flow=args.flow)
    assembly.check(plan)  # before anything is opened or created
    with contextlib.ExitStack() as opened:  # whatever was opened is closed, however the run ends
        sinks: list[Sink] = []
        if args.mcap:
            sinks.append(opened.enter_context(contextlib.closing(mcap_recorder(args.mcap))))
        if args.ros2 is not None:
            bases = [parse_spec(d.spec) for d in devices if d.role == "base" and d.spec is not None]
            sinks.append(opened.enter_context(contextlib.closing(ros2_publisher(
                args.ros2, [b.settings.get("domain", 0) for b in bases if b.kind == "ros2"]))))
        view = start_foxglove(args, "run")
        if view is not None:
            sinks.append(opened.enter_context(contextlib.closing(view)))
        plan.sinks = sinks
        # each output is NAME.part until the run ends, then NAME (a run that never started leaves NAME)
        plan.runlog = RunLog(opened.enter_context(contextlib.closing(Output(args.log))) if args.log else None)
        if args.capture:
            record = run_record(plan, args.site.read_text() if site is not None else None)
            plan.capture = capture = CaptureWriter(args.capture, comment=record)
            opened.callback(_say_if_unanswered, capture)  # after its close (the stack unwinds last in, first out)
            opened.enter_context(contextlib.closing(capture))
        try:
            outcome = asyncio.run(assembly.run(plan))
        except KeyboardInterrupt:
            print("rfhoming run: interrupted; the base was told to stop", file=sys.stderr)
            return 130
    print(json.dumps(outcome.summary(), allow_nan=False))
    return 0 if outcome.arrived else 1
