"""``rfhoming run``: homing on a tag with real devices or emulator endpoints."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys

from rfhoming.cli.live import mcap_recorder, ros2_publisher, start_foxglove
from rfhoming.host import site as sites
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import CHOOSE_TAG_S, METHODS, Device, Homing, run_record
from rfhoming.host.homing.config import Config, load
from rfhoming.host.homing.loop import RunLog
from rfhoming.host.outputs import Output
from rfhoming.host.portspec import PortSpec, PortSpecError
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.host.sink import Sink
from rfhoming.host.site import Site
from rfhoming.protocol.settings import tags as tag_ids


def _tags(values: list[str]) -> tuple[str, ...]:
    """--tag values (each one id or ids joined by +) -> upper-case ids; PortSpecError explains."""
    try:
        return tuple(dict.fromkeys(t for v in values for t in tag_ids(v)))
    except ValueError as exc:
        raise PortSpecError(f"--tag takes {exc}") from None


def _devices(args: argparse.Namespace, config: Config, role: str) -> tuple[list[Device], Site | None]:
    """The run's devices by role: the command line's specs over the config's [devices.ROLE];
    fixed anchors come from the site file."""
    def spec(r: str, given: str | None = None) -> PortSpec:
        given = given or _one(getattr(args, r, None))
        found = parse_spec(given).over(config.devices.get(r)) if given else config.devices.get(r)
        if found is None:
            raise PortSpecError(f"--controller {args.controller} needs --{r} PORT (or [devices.{r}] in the config)")
        return found

    site = None
    if role == "anchor":
        if args.site is None:
            raise PortSpecError("--controller anchors needs --site SITE.toml (anchors, and tags with role = "
                                "\"robot\" / \"target\")")
        site = sites.load(args.site)
        site.tag_with_role("robot"), site.tag_with_role("target")
        if any(a.port is None for a in site.anchors):
            raise sites.SiteError(f"{args.site}: every anchor needs port = \"xplr-aoa:WHERE\" for run")
        sensors = [Device("anchor", spec=a.port) for a in site.anchors]
    else:
        given = getattr(args, role, None)
        several = given if isinstance(given, list) and len(given) > 1 else [None]  # --ble, once per receiver
        if several != [None] and args.controller != "survey":
            raise PortSpecError(f"--{role} is given once for --controller {args.controller}; only a survey takes "
                                "one per receiver")
        sensors = [Device(role, spec=spec(role, g)) for g in several]
    return [*sensors, Device("base", spec=spec("base"))], site


def _one(given: str | list[str] | None) -> str | None:
    """A role's one port from the command line (--ble may be given several times)."""
    return given[0] if isinstance(given, list) else given


def _say_if_unanswered(capture: CaptureWriter) -> None:
    """A run whose devices never answered what it sent leaves the old capture: said in one line."""
    if capture.unanswered:
        print(f"rfhoming run: {capture.said()}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    config = load(args.config)
    role = METHODS[args.controller].role
    devices, site = _devices(args, config, role)
    plan = Homing(args.controller, devices, config, site=site, tags=_tags(args.tag), choose_tag_s=CHOOSE_TAG_S,
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
