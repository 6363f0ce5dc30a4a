"""``rfhoming devices``, ``listen``, ``capture`` and ``replay``: the host I/O commands."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rfhoming.host.capture import CaptureWriter
from rfhoming.host.discovery import candidates
from rfhoming.host.drivers.aoa import AoaDriver
from rfhoming.host.drivers.common import Driver
from rfhoming.host.ports import PortError
from rfhoming.host.replay import ReplayPort, describe, load_capture
from rfhoming.host.session import DRIVERS, health, open_drivers
from rfhoming.protocol.jsonable import as_dict
from rfhoming.protocol.pcapng import CaptureFormatError, Interface

log = logging.getLogger(__name__)

ENDPOINT_HELP = "PATH, socket://HOST:PORT or auto; prefix PROTOCOL= (ublox-aoa, rss, base) to skip sniffing"


def printer(json_lines: bool, out=sys.stdout) -> Callable[[str, float, Any], None]:
    def show(device: str, t: float, item: Any) -> None:
        if json_lines:
            out.write(json.dumps({"device": device, "t": t, **as_dict(item)}) + "\n")
        else:
            fields = " ".join(f"{k}={v}" for k, v in as_dict(item).items() if k != "kind")
            out.write(f"{t:.6f} {device} {item.kind} {fields}\n")
        out.flush()

    return show


def cmd_devices(args: argparse.Namespace) -> int:
    found = candidates()
    if args.json:
        for c in found:
            print(json.dumps({"device": c.device, "kind": c.kind, "reason": c.reason, "description": c.description}))
        return 0
    if not found:
        print("no serial ports found. Plugged in? On Linux, dmesg shows what the kernel saw.")
    for c in found:
        print(f"{c.device:<20} {c.kind or '-':<10} {c.reason}  {c.description}")
    return 0


HEALTH_PERIOD_S = 10.0


async def _log_health(drivers: list[Driver]) -> None:
    while True:
        await asyncio.sleep(HEALTH_PERIOD_S)
        for h in health(drivers):
            log.info("health %s", json.dumps(h))


async def _run_until(drivers: list[Driver], duration: float | None, extra: list[asyncio.Task] = ()) -> None:
    tasks = [asyncio.create_task(d.run()) for d in drivers] + list(extra)
    tasks.append(asyncio.create_task(_log_health(drivers)))
    main = asyncio.current_task()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, main.cancel)
    try:
        if duration is None:
            done, _ = await asyncio.wait(tasks[: len(drivers)], return_when=asyncio.FIRST_EXCEPTION)
        else:
            done, _ = await asyncio.wait(tasks[: len(drivers)], timeout=duration, return_when=asyncio.FIRST_EXCEPTION)
        for task in done:
            task.result()  # surface a PortError from a first open
    except asyncio.CancelledError:
        pass
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, PortError):
                await task
        for d in drivers:
            d.drain()
            await d.port.close()


async def _describe_dialects(drivers: list[Driver], capture: CaptureWriter) -> None:
    done: set[str] = set()
    while True:
        await asyncio.sleep(0.2)
        for d in drivers:
            if isinstance(d, AoaDriver) and d.dialect is not None and d.port.name not in done:
                capture.describe(d.port.name, dialect=d.dialect.value)
                done.add(d.port.name)


async def _listen(args: argparse.Namespace, show: bool) -> int:
    capture = CaptureWriter(args.output) if getattr(args, "output", None) else None
    try:
        drivers = await open_drivers(args.ports, baud=args.baud, taps=[capture.tap] if capture else [],
                                     describe=capture.describe if capture else None, flow=args.flow,
                                     probe_baud=args.probe_baud)
    except (PortError, ValueError) as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2
    if show:
        for d in drivers:
            d.listeners.append(printer(args.json))
    extra = [asyncio.create_task(_describe_dialects(drivers, capture))] if capture else []
    try:
        await _run_until(drivers, args.duration, extra)
    except PortError as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2
    finally:
        for h in health(drivers):
            print(json.dumps({"kind": "counters", **h}), file=sys.stdout if show else sys.stderr)
        if capture is not None:
            capture.close()
            print(f"captured {capture.packets} chunks to {capture.path}", file=sys.stderr)
    return 0


def cmd_listen(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(args, show=True))


def cmd_capture(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(args, show=args.show))


def _driver_for(fields: dict[str, Any], port: ReplayPort) -> Driver:
    kind = fields.get("kind")
    if kind == "xplr-aoa" or fields.get("protocol") == "ublox-aoa":
        return AoaDriver(port)
    return DRIVERS["base" if kind == "base" else "rss"](port)


async def _replay(args: argparse.Namespace) -> int:
    damaged: list[CaptureFormatError] = []

    def warn(exc: CaptureFormatError) -> None:
        damaged.append(exc)
        print(f"rfhoming replay: {args.capture}: {exc}; replaying what came before it (--partial)", file=sys.stderr)

    try:
        interfaces, packets, torn = load_capture(args.capture, partial=warn if args.partial else None)
    except (OSError, CaptureFormatError) as exc:
        readable = isinstance(exc, CaptureFormatError) and any(isinstance(i, Interface) for i in exc.items)
        hint = " (--partial replays what comes before it)" if readable and not args.partial else ""
        print(f"rfhoming replay: cannot read {args.capture}: {exc}{hint}", file=sys.stderr)
        return 2
    if torn and not damaged:
        print(f"rfhoming replay: the capture ends in a torn block ({torn} bytes, a killed writer); "
              "replaying up to the last complete block", file=sys.stderr)
    drivers = []
    for i, iface in enumerate(interfaces):
        port = ReplayPort(iface.name, packets[i], speed=args.speed or None)
        driver = _driver_for(describe(iface), port)
        driver.listeners.append(printer(args.json))
        drivers.append(driver)
    await _run_until(drivers, None)
    for h in health(drivers):
        print(json.dumps({"kind": "counters", **h}))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    if args.pty:
        from rfhoming.cli.main import serve_capture_on_ptys  # the CLI wires the emulator's pty server in

        return serve_capture_on_ptys(args)
    return asyncio.run(_replay(args))


LISTEN_HELP = """\
Open each device like the robot would -- set the XPLR-AOA up, follow reboots, reconnect
after an unplug -- and print every decoded item as it arrives (text, or --json lines).
On exit (Ctrl-C or --duration) one counters line per device.

examples:
  rfhoming listen /dev/ttyACM0
  rfhoming listen ublox-aoa=/tmp/rfhoming-x/aoa rss=socket://127.0.0.1:40123 --json
  rfhoming listen auto --duration 10
"""

REPLAY_HELP = """\
Feed a capture's recorded inbound bytes through the same decoders and drivers as live and
print the decoded items (the same output `rfhoming listen` printed when it was recorded).
With --pty, serve the capture on pseudo-terminals instead, paced by its timestamps, so any
program can consume it as if the devices were plugged in.

examples:
  rfhoming replay run.pcapng --json
  rfhoming replay run.pcapng --speed 1
  rfhoming replay run.pcapng --pty
  rfhoming replay damaged.pcapng --partial

A malformed capture gives one line naming the byte offset and the problem, and exit code 2;
with --partial, the blocks before it are replayed (exit 0) and the problem is reported.
"""


def add_parsers(sub: argparse._SubParsersAction) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("devices", help="list serial ports and what each seems to be")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_devices)

    for name, helptext in (("listen", "show live decoded records from devices"),
                           ("capture", "record every byte on devices to a pcapng file")):
        p = sub.add_parser(name, help=helptext, description=LISTEN_HELP if name == "listen" else
                           "Like listen, but record every byte both ways, raw, with µs timestamps, to a "
                           "pcapng file (one interface per device; opens in tshark/Wireshark).\n\n"
                           "example:\n  rfhoming capture /tmp/rfhoming-x/aoa rss=/tmp/rfhoming-x/base -o run.pcapng",
                           formatter_class=raw)
        p.add_argument("ports", nargs="+", metavar="PORT", help=ENDPOINT_HELP)
        p.add_argument("--baud", type=int, default=115200, help="serial rate (default 115200)")
        p.add_argument("--flow", choices=("auto", "on", "off"), default="auto",
                       help="RTS/CTS flow control: auto = on for the XPLR-AOA (its default), off for the others")
        p.add_argument("--probe-baud", action="store_true",
                       help="if an XPLR-AOA sends only garbage, try each rate it documents until it answers AT")
        p.add_argument("--duration", type=float, help="stop after this many seconds")
        p.add_argument("--json", action="store_true", help="one JSON object per item")
        if name == "capture":
            p.add_argument("-o", "--output", type=Path, required=True, help="pcapng file to write")
            p.add_argument("--show", action="store_true", help="also print the decoded items")
            p.set_defaults(func=cmd_capture)
        else:
            p.set_defaults(func=cmd_listen)

    p = sub.add_parser("replay", help="replay a pcapng capture through the drivers, or on ptys",
                       description=REPLAY_HELP, formatter_class=raw)
    p.add_argument("capture", type=Path)
    p.add_argument("--speed", type=float, default=0.0, help="1 = recorded pace, 0 = as fast as possible (default)")
    p.add_argument("--json", action="store_true", help="one JSON object per item")
    p.add_argument("--pty", action="store_true", help="serve the capture on pseudo-terminals")
    p.add_argument("--partial", action="store_true",
                   help="on a malformed block, replay what was readable before it instead of refusing")
    p.add_argument("--link-dir", type=Path, help="with --pty: directory for the pty symlinks")
    p.add_argument("--start-delay", type=float, default=1.0,
                   help="with --pty: seconds to wait before playing, so consumers can open the ptys (default 1)")
    p.set_defaults(func=cmd_replay)


def configure_logging(verbose: int) -> None:
    level = logging.WARNING - 10 * verbose
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
