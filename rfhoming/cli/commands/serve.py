"""``rfhoming serve``: one process owns the devices and fans their items out to many clients."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys

from rfhoming.cli.live import start_foxglove, start_ros2
from rfhoming.host import losses
from rfhoming.host.capture import CaptureWriter, describe_dialects
from rfhoming.host.loopstall import StallMonitor, watching
from rfhoming.host.ports import PortError
from rfhoming.host.run_until import run_until
from rfhoming.host.serve import ItemServer
from rfhoming.host.session import health, open_drivers
from rfhoming.protocol.errors import Error


async def _serve(args: argparse.Namespace) -> int:
    capture = CaptureWriter(args.output) if args.output else None
    try:
        return await _serve_into(args, capture)
    finally:
        if capture is not None:
            capture.close()  # renamed into place once a device gave it a packet, else the old file stays
            if capture.unanswered:
                print(f"rfhoming serve: {capture.said()}", file=sys.stderr)


async def _serve_into(args: argparse.Namespace, capture: CaptureWriter | None) -> int:
    try:
        drivers = await open_drivers(args.ports, baud=args.baud, flow=args.flow, taps=[capture.tap] if capture else [],
                                     describe=capture.describe if capture else None)
    except (Error, OSError) as exc:
        print(f"rfhoming serve: {exc}", file=sys.stderr)
        return 2
    server = ItemServer(queue_lines=args.queue, max_idle=args.max_idle, stall_s=args.stall_s, drivers=drivers)
    try:
        for host in args.bind or ["127.0.0.1"]:
            for address in await server.start(host, args.port):
                print(json.dumps({"kind": "listening", "address": address}), flush=True)
    except OSError as exc:
        print(f"rfhoming serve: cannot listen on {args.bind or '127.0.0.1'} port {args.port}: {exc.strerror}; "
              "choose another with --port", file=sys.stderr)
        return 2
    view = start_foxglove(args, "serve", out=sys.stdout, host=(args.bind or ["127.0.0.1"])[0])
    for d in drivers:
        d.listeners += [server.publish, *([view.on_item] if view else [])]
    ros2 = start_ros2(args, drivers)
    extra = [asyncio.create_task(describe_dialects(drivers, capture))] if capture else []
    stalls = StallMonitor()
    try:
        await watching(run_until(drivers, args.duration, extra), stalls)
    except PortError as exc:
        print(f"rfhoming serve: {exc}", file=sys.stderr)
        return 2
    finally:
        await server.close()
        if view is not None:
            view.close()
        if ros2 is not None:
            ros2.close()
        for h in health(drivers):
            print(json.dumps({"kind": "counters", **h}), flush=True)
        served = server.health()
        print(json.dumps({"kind": "server", **served, "losses": losses.WARNINGS.check("serve", served),
                          **stalls.summary()}), flush=True)
    return 0


def run(args: argparse.Namespace) -> int:
    return asyncio.run(_serve(args))
