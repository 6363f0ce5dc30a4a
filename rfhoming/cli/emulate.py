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

from rfhoming.cli.args import duration, fault, nonempty, output_file, path, seed, speed, xy
from rfhoming.emulator.faults import Fault, FaultError
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import BLE_RECEIVERS, ScenarioError, load, presets
from rfhoming.host import portspec
from rfhoming.protocol.errors import Error

HELP = """\
Run an emulated world and serve each device where a host opens it like real hardware:
a pseudo-terminal per device (default; a stable symlink path) or TCP on 127.0.0.1
(pyserial URL socket://127.0.0.1:PORT). One JSON line per device endpoint is printed,
then the world runs until Ctrl-C.

examples:
  rfhoming emulate s0-open --seed 3 --truth truth.jsonl
  rfhoming emulate s2-c --tcp --speed 10
  rfhoming emulate s3-arena --receiver esp-at     (the robot's scanner is an ESP32 with ESP-AT)
  rfhoming emulate s3-arena --receiver hci        (... a Bluetooth controller: hci:serial:PATH)
  rfhoming emulate s0-open --lockstep --fault unplug@aoa:at=5,for=2 --fault ber:rate=1e-5

faults (repeatable): KIND[@DEVICE][:key=value,...]
  ber:rate=R  drop:rate=R  garbage:every=S,len=N  unplug:at=S,for=S  reboot:at=S  baud:at=S,rate=B
  after_bytes=N instead of at=S: once the host has written to the device (set it up) and the
  device has sent N bytes since, whatever the clock says -- e.g. unplug@aoa:after_bytes=4000,for=1
"""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("emulate", help="run an emulated world with devices on ptys or TCP",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", type=nonempty, help=f"a preset ({', '.join(presets())}) or a .toml file")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="a pseudo-terminal per device (default)")
    where.add_argument("--tcp", action="store_true", help="TCP on 127.0.0.1 per device")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=speed, default=1.0, help="simulated seconds per wall second (default 1; 0 = as fast as possible)")
    pace.add_argument("--lockstep", action="store_true", help="advance a control period only after the host's velocity command")
    p.add_argument("--seed", type=seed, default=0, help="seed of every random stream (default 0)")
    p.add_argument("--target", type=xy, help="first target's position X,Y in metres, e.g. --target=-3.5,2 "
                   "(default: the scenario's, random per seed)")
    p.add_argument("--receiver", choices=BLE_RECEIVERS,
                   help="serve every BLE RSSI receiver as this device: esp32 (rfhoming frames), esp-at "
                   "(Espressif's AT firmware) or hci (a Bluetooth controller over H4, needs rfhoming[hci])")
    p.add_argument("--aoa-preset", type=int, choices=range(1, 6), help="S0 Table 2 noise configuration 1-5")
    p.add_argument("--fault", type=fault, action="append", default=[], metavar="SPEC", help="inject a fault (see above)")
    p.add_argument("--truth", type=output_file, help="write the true robot pose and target positions as JSON lines")
    p.add_argument("--duration", type=duration, help="stop after this many simulated seconds")
    p.add_argument("--robot", type=ros2_robot, metavar="ros2[:domain=N,ns=NS,discovery=subnet,stamped=1]",
                   help="the robot base as a ROS 2 robot over DDS (/odom, /scan, /tf out, /cmd_vel in), not a "
                        "serial port; this machine only unless discovery=subnet (docs/hardware.md, Robots)")
    p.add_argument("--link-dir", type=path, help="directory for the pty symlinks (default: a new temp dir)")
    p.set_defaults(func=cmd_emulate)


def ros2_robot(text: str) -> dict[str, Any]:
    """``ros2[:domain=N,ns=NS,discovery=localhost|subnet,stamped=0|1]`` -> Ros2Link's arguments."""
    kind, _, rest = text.partition(":")
    if kind != "ros2":
        raise argparse.ArgumentTypeError(f"{text!r}: the robot can be ros2[:domain=N,ns=NS]")
    try:
        spec = portspec.parse("ros2:" + rest)
    except portspec.PortSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if set(spec.settings) - {"domain", "ns", "discovery", "stamped"}:
        raise argparse.ArgumentTypeError(f"{text!r}: --robot ros2 takes domain=, ns=, discovery= and stamped=")
    return {"domain": spec.settings.get("domain", 0), "ns": str(spec.settings.get("ns", spec.where)).strip("/"),
            "discovery": spec.settings.get("discovery", "localhost"),
            "stamped": spec.settings.get("stamped", False) in (True, "1")}


def cmd_emulate(args: argparse.Namespace) -> int:
    target = tuple(float(v) for v in args.target.split(",")) if args.target else None
    try:
        scenario = load(args.scenario, seed=args.seed, target=target, aoa_preset=args.aoa_preset,
                        receiver=args.receiver)
        faults = [Fault.parse(spec) for spec in args.fault]
    except (ScenarioError, FaultError) as exc:
        print(f"rfhoming emulate: {exc}", file=sys.stderr)
        return 2
    if args.link_dir is not None and not args.link_dir.is_dir():
        print(f"rfhoming emulate: --link-dir {args.link_dir} is not a directory: create it "
              f"(mkdir -p {args.link_dir}) or leave --link-dir out for a new temporary one", file=sys.stderr)
        return 2
    truth = open(args.truth, "w") if args.truth else None
    try:
        emulator = Emulator(
            scenario, transport="tcp" if args.tcp else "pty", seed=args.seed,
            speed=math.inf if args.speed == 0 else args.speed, lockstep=args.lockstep,
            faults=faults, truth=truth, link_dir=args.link_dir, robot=args.robot,
        )
    except Error as exc:
        print(f"rfhoming emulate: {exc}", file=sys.stderr)
        return 2
    try:
        asyncio.run(_serve(emulator, args.duration))
    finally:
        if truth is not None:
            truth.close()
    return 0


async def _serve(emulator: Emulator, duration: float | None) -> None:
    for endpoint in await emulator.start():
        print(json.dumps(endpoint), flush=True)
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None  # a coroutine run by asyncio.run
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
