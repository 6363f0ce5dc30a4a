"""``rfhoming devices``, ``listen``, ``capture`` and ``replay``: the host I/O commands."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import signal
import sys
from collections.abc import Callable, Iterable
from typing import Any, TextIO

from rfhoming.cli.args import baud, delay, duration, nonempty, output_file, path, speed
from rfhoming.cli.live import add_foxglove_option, add_ros2_option, start_foxglove, start_ros2
from rfhoming.host import losses
from rfhoming.host.capture import CaptureWriter, describe_dialects
from rfhoming.host.discovery import candidates
from rfhoming.host.drivers.common import Driver
from rfhoming.host.ports import PortError
from rfhoming.host.portspec import PortSpec
from rfhoming.host.homing.assembly import METHODS
from rfhoming.host.session import health, open_drivers, replay_drivers

from rfhoming.host.supervise import DeviceNotReady, live, supervise
from rfhoming.protocol.errors import Error
from rfhoming.protocol.jsonable import as_dict
from rfhoming.protocol.pcapng import CaptureFormatError, Interface

log = logging.getLogger(__name__)
CONTROLLERS = tuple(METHODS)

ENDPOINT_HELP = ("port spec [KIND:]WHERE[,key=value...]: WHERE is a path, socket://HOST:PORT or auto; KIND "
                 "(xplr-aoa, rss-node, esp-at, hci, base) skips sniffing; settings baud=, flow=rtscts|none, tags=ID+ID, name=; "
                 "capture:FILE replays a recording; serve://HOST:PORT is the devices of an `rfhoming serve` "
                 "(see docs/usage.md)")


def printer(json_lines: bool, out: TextIO = sys.stdout) -> Callable[[str, float, Any], None]:
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


async def _run_until(drivers: list[Driver], duration: float | None, extra: Iterable[asyncio.Task[Any]] = ()) -> None:
    """Run the drivers until ``duration`` or Ctrl-C; a driver that cannot go on (a port that
    never opened, a set-up that failed or timed out) ends it with PortError/DeviceNotReady."""
    tasks = [asyncio.create_task(d.run()) for d in drivers]
    tasks.append(asyncio.create_task(supervise(live(drivers))))
    tasks += list(extra)
    tasks.append(asyncio.create_task(_log_health(drivers)))
    tasks.append(asyncio.create_task(losses.watch(lambda: health(drivers))))
    main = asyncio.current_task()
    assert main is not None  # a coroutine run by asyncio.run
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, main.cancel)
    try:
        if duration is None:
            done, _ = await asyncio.wait(tasks[: len(drivers) + 1], return_when=asyncio.FIRST_EXCEPTION)
        else:
            done, _ = await asyncio.wait(tasks[: len(drivers) + 1], timeout=duration,
                                         return_when=asyncio.FIRST_EXCEPTION)
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
            with contextlib.suppress(asyncio.CancelledError, PortError, DeviceNotReady):
                await task
        for d in drivers:
            d.drain()
            await d.port.close()


async def _listen(args: argparse.Namespace, show: bool) -> int:
    capture = CaptureWriter(args.output) if getattr(args, "output", None) else None
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
        await _run_until(drivers, args.duration, extra)
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
            capture.close()
            print(f"captured {capture.packets} chunks to {capture.path}", file=sys.stderr)
    return 2 if capture is not None and capture.error else 0  # said when it happened


def cmd_listen(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(args, show=True))


def cmd_capture(args: argparse.Namespace) -> int:
    return asyncio.run(_listen(args, show=args.show))


async def _replay(args: argparse.Namespace) -> int:
    damaged: list[CaptureFormatError] = []

    def warn(exc: CaptureFormatError) -> None:
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
    await _run_until(drivers, None)
    for h in health(drivers):
        print(json.dumps({"kind": "counters", **h}))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    if args.run:
        from rfhoming.cli.run import replay_run

        return replay_run(args)
    if args.pty:
        from rfhoming.cli.main import (
            serve_capture_on_ptys,  # the CLI wires the emulator's pty server in
        )

        return serve_capture_on_ptys(args)
    return asyncio.run(_replay(args))


LISTEN_HELP = """\
Open each device like the robot would -- set the XPLR-AOA up, follow reboots, reconnect
after an unplug -- and print every decoded item as it arrives (text, or --json lines).
On exit (Ctrl-C or --duration) one counters line per device. Exit status 2, with a message
naming the device, when a port cannot be opened or a device's first set-up fails or takes
longer than 20 s (XPLR-AOA) / 5 s (others).

examples:
  rfhoming listen /dev/ttyACM0
  rfhoming listen xplr-aoa:/dev/ttyUSB0,baud=1000000,tags=CCF9578E0D8A
  rfhoming listen xplr-aoa:/tmp/rfhoming-x/aoa rss-node:socket://127.0.0.1:40123 --json
  rfhoming listen auto --duration 10
  rfhoming listen capture:run.pcapng --json
  rfhoming listen serve://127.0.0.1:2948 --json     # beside other clients of `rfhoming serve`
  rfhoming listen /dev/ttyACM0 --foxglove           # and watch the readings in Foxglove
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
  rfhoming replay rfhoming-demo/capture.pcapng --run --log replayed.jsonl   # the homing run again
  rfhoming replay run.pcapng --run --config other.toml     # another config on the same bytes

With --run, a capture of `rfhoming run` or `demo` runs its homing loop again: every device's
recorded inbound bytes in their recorded global order, the loop's writes matched against the
recording, with the controller and config the capture recorded (or --controller/--config).
The run log is the live run's, line for line; where the replayed loop first writes otherwise
than the recording, one line says where and what, and the replay goes on from the recorded
inputs. The summary is `run`'s, with a "replay" object (diverged, unanswered, first_divergence).

A malformed capture gives one line naming the byte offset and the problem, and exit code 2;
with --partial, the blocks before it are replayed (exit 0) and the problem is reported.
"""


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("devices", help="list serial ports and what each seems to be",
                       description="List the serial ports this machine sees and what each probably is, from "
                                   "its USB ids (the XPLR-AOA's FTDI bridge, ESP32 bridges, ST's VCP).")
    p.add_argument("--json", action="store_true", help="one JSON object per port")
    p.set_defaults(func=cmd_devices)

    for name, helptext in (("listen", "show live decoded records from devices"),
                           ("capture", "record every byte on devices to a pcapng file")):
        p = sub.add_parser(name, help=helptext, description=LISTEN_HELP if name == "listen" else
                           "Like listen, but record every byte both ways, raw, with µs timestamps, to a "
                           "pcapng file (one interface per device; opens in tshark/Wireshark).\n\n"
                           "example:\n  rfhoming capture /tmp/rfhoming-x/aoa base:/tmp/rfhoming-x/base -o run.pcapng",
                           formatter_class=raw)
        p.add_argument("ports", type=nonempty, nargs="+", metavar="PORT", help=ENDPOINT_HELP)
        add_port_defaults(p)
        p.add_argument("--duration", type=duration, help="stop after this many seconds")
        p.add_argument("--json", action="store_true", help="one JSON object per item")
        add_ros2_option(p, "the decoded readings")
        if name == "capture":
            p.add_argument("-o", "--output", type=output_file, required=True, help="pcapng file to write")
            p.add_argument("--show", action="store_true", help="also print the decoded items")
            p.set_defaults(func=cmd_capture)
        else:
            add_foxglove_option(p)
            p.set_defaults(func=cmd_listen)

    p = sub.add_parser("replay", help="replay a pcapng capture through the drivers, or on ptys",
                       description=REPLAY_HELP, formatter_class=raw)
    p.add_argument("capture", type=path, help="the pcapng file (from rfhoming capture or run --capture)")
    p.add_argument("--speed", type=speed, default=0.0, help="1 = recorded pace, 0 = as fast as possible (default)")
    p.add_argument("--json", action="store_true", help="one JSON object per item")
    p.add_argument("--pty", action="store_true", help="serve the capture on pseudo-terminals")
    p.add_argument("--partial", action="store_true",
                   help="on a malformed block, replay what was readable before it instead of refusing")
    p.add_argument("--link-dir", type=path, help="with --pty: directory for the pty symlinks")
    p.add_argument("--start-delay", type=delay, default=1.0,
                   help="with --pty: seconds to wait before playing, so consumers can open the ptys (default 1)")
    p.add_argument("--run", action="store_true", help="run the recorded homing loop again on the capture's bytes")
    p.add_argument("--config", type=path, help="with --run: this config instead of the recorded one")
    p.add_argument("--controller", choices=CONTROLLERS, help="with --run: this controller instead of the recorded one")
    p.add_argument("--log", type=output_file, help="with --run: write the replayed run log here")
    p.set_defaults(func=cmd_replay)


def add_port_defaults(p: argparse.ArgumentParser) -> None:
    """--baud, --flow and --probe-baud: defaults for every port whose spec does not set its own."""
    p.add_argument("--baud", type=baud, metavar="RATE",
                   help="serial rate for ports whose spec gives no baud= (default 115200)")
    p.add_argument("--flow", choices=("auto", "rtscts", "none"),
                   help="RTS/CTS for ports whose spec gives no flow=: auto (default) = on for the XPLR-AOA "
                        "(its documented default), off for the others")
    p.add_argument("--probe-baud", action="store_true",
                   help="if an XPLR-AOA sends only garbage, try each rate it documents until it answers AT")


def configure_logging(verbose: int) -> None:
    level = logging.WARNING - 10 * verbose
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
