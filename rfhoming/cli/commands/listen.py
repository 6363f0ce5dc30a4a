"""``rfhoming listen`` and ``capture``: live decoded items from devices, and every byte to a pcapng file."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys

from rfhoming.cli.live import start_foxglove, start_ros2
from rfhoming.cli.printer import printer
from rfhoming.host.capture import CaptureWriter, describe_dialects
from rfhoming.host.ports import PortError
from rfhoming.host.run_until import run_until
from rfhoming.host.session import health, open_drivers
from rfhoming.host.supervise import DeviceNotReady
from rfhoming.protocol.errors import Error


async def _listen(args: argparse.Namespace, show: bool) -> int:
    capture = CaptureWriter(args.output) if getattr(args, "output", None) else None
    try:
        code = await _listen_into(args, show, capture)
    finally:
        if capture is not None:
            capture.close()  # renamed into place once a device gave it a packet, else the old file stays
    return 2 if capture is not None and capture.error else code  # said when it happened


async def _listen_into(args: argparse.Namespace, show: bool, capture: CaptureWriter | None) -> int:
    try:
        drivers = await open_drivers(args.ports, baud=args.baud, flow=args.flow, taps=[capture.tap] if capture else [],
                                     describe=capture.describe if capture else None, probe_baud=args.probe_baud)
    except (Error, OSError) as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2
    if show:
        for d in drivers:
            d.listeners.append(printer(args.json))
    view = start_foxglove(args, args.command)
    if view is not None:
        for d in drivers:
            d.listeners.append(view.on_item)
    ros2 = start_ros2(args, drivers)
    extra = [asyncio.create_task(describe_dialects(drivers, capture))] if capture else []
    try:
        await run_until(drivers, args.duration, extra)
    except (PortError, DeviceNotReady) as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2
    finally:
        if view is not None:
            view.close()
        if ros2 is not None:
            ros2.close()
        for h in health(drivers):
            print(json.dumps({"kind": "counters", **h}), file=sys.stdout if show else sys.stderr)
        if capture is not None:
            print(capture.said(), file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(args, show=True))


def run_capture(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(args, show=args.show))
