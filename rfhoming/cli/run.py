"""``rfhoming run``, ``demo`` and ``config``: homing against real devices or the emulator."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from dataclasses import replace
from pathlib import Path

from rfhoming.cli.io import add_port_defaults
from rfhoming.cli.supervise import DeviceNotReady, deadline, supervise
from rfhoming.host import portspec
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.aoa import AoaSetup
from rfhoming.host.homing.config import DEFAULT_TOML, Config, ConfigError, load
from rfhoming.host.homing.loop import RunLog, aoa_loop, dock_loop, rss_loop, trilat_loop
from rfhoming.host.ports import PortError
from rfhoming.host.session import make_driver, resolve

CONTROLLERS = ("aoa", "dock", "rss", "trilat")


def cmd_config(args: argparse.Namespace) -> int:
    if args.print_default:
        print(DEFAULT_TOML, end="")
        return 0
    try:
        load(args.check)
    except ConfigError as exc:
        print(f"rfhoming config: {exc}", file=sys.stderr)
        return 2
    print(f"{args.check}: OK")
    return 0


SENSOR_ROLE = {"aoa": "aoa", "dock": "aoa", "rss": "rss", "trilat": "ble"}
ROLE_KIND = {"aoa": "ublox-aoa", "base": "base", "rss": "rss", "ble": "rss"}
CHOOSE_TAG_S = 2.0
"""With no tag chosen, listen this long before homing on the only tag in view."""


def _tags(values: list[str]) -> tuple[str, ...]:
    """--tag values (each one id or ids joined by +) -> upper-case ids; ValueError explains."""
    try:
        return tuple(dict.fromkeys(t for v in values for t in portspec.KINDS["ublox-aoa"]["tags"](v)))
    except ValueError as exc:
        raise ValueError(f"--tag takes {exc}") from None


def cmd_run(args: argparse.Namespace) -> int:
    try:
        config = load(args.config)
    except ConfigError as exc:
        print(f"rfhoming run: {exc}", file=sys.stderr)
        return 2
    role = SENSOR_ROLE[args.controller]
    specs = {r: getattr(args, r) or config.devices.get(r) for r in (role, "base")}
    for r, spec in specs.items():
        if spec is None:
            print(f"rfhoming run: --controller {args.controller} needs --{r} PORT (or [devices.{r}] in the config)",
                  file=sys.stderr)
            return 2
    if args.tag and role != "aoa":
        print(f"rfhoming run: --tag chooses an XPLR-AOA tag; --controller {args.controller} has none", file=sys.stderr)
        return 2
    capture = CaptureWriter(args.capture) if args.capture else None
    runlog = open(args.log, "w") if args.log else None
    try:
        return asyncio.run(_run(args, config, role, specs, capture, runlog))
    except (PortError, ValueError, DeviceNotReady) as exc:
        print(f"rfhoming run: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rfhoming run: interrupted; the base was told to stop", file=sys.stderr)
        return 130
    finally:
        if runlog:
            runlog.close()
        if capture:
            capture.close()


async def _run(args: argparse.Namespace, config: Config, role: str, specs: dict, capture: CaptureWriter | None,
               runlog) -> int:
    taps = [capture.tap] if capture else []
    describe = capture.describe if capture else None
    resolved = {r: await resolve(spec, baud=args.baud, flow=args.flow, taps=taps, kind=ROLE_KIND[r], describe=describe)
                for r, spec in specs.items()}
    base = make_driver(resolved["base"], taps, command_timeout_ms=config.loop.command_timeout_ms)
    if role == "aoa":
        spec = resolved["aoa"]
        if args.tag:
            spec = replace(spec, settings={**spec.settings, "tags": _tags(args.tag)})
        sensor = make_driver(spec, taps, setup=AoaSetup(choose_tag_s=CHOOSE_TAG_S))
        make = aoa_loop if args.controller == "aoa" else dock_loop
    else:
        sensor = make_driver(resolved[role], taps, ed_scale_db=config.calibration.ed_scale_db)
        make = rss_loop if args.controller == "rss" else trilat_loop
    loop = make(base, sensor, config, RunLog(runlog))
    deadlines = {base: deadline(base, resolved["base"].timeout), sensor: deadline(sensor, resolved[role].timeout)}
    homing = asyncio.create_task(loop.run())
    watch = asyncio.create_task(supervise(deadlines))
    try:
        done, _ = await asyncio.wait({homing, watch}, return_when=asyncio.FIRST_COMPLETED)
        if watch in done:
            watch.result()  # raises: the run cannot go on
        outcome = homing.result()
    finally:
        for task in (homing, watch):
            task.cancel()
        await asyncio.gather(homing, watch, return_exceptions=True)
    print(json.dumps(outcome.summary()))
    return 0 if outcome.arrived else 1


def cmd_demo(args: argparse.Namespace) -> int:
    from rfhoming.demo import SUPPORTED, run_demo

    if args.scenario not in SUPPORTED:
        print(f"rfhoming demo: scenario {args.scenario!r} is not wired to a controller yet; "
              f"choose one of {sorted(SUPPORTED)}", file=sys.stderr)
        return 2
    try:
        config = load(args.config)
    except ConfigError as exc:
        print(f"rfhoming demo: {exc}", file=sys.stderr)
        return 2
    if not args.json:
        print(f"demo: emulating {args.scenario} (seed {args.seed}) on ptys in lockstep; homing ...", file=sys.stderr)
    summary = run_demo(args.scenario, args.seed, args.out, config, args.target)
    if args.json:
        print(json.dumps(summary))
    else:
        ok = "SUCCESS" if summary["success"] else "FAILED"
        print(f"{ok}: {summary['reason']} after {summary['simulated_time_s']} s simulated")
        for key in ("target", "goal_position_error_m", "final_position_error_m", "path_efficiency",
                    "net_velocity_m_s", "stale_stops", "latency_ms_p50", "latency_ms_p99"):
            print(f"  {key:<24} {summary[key]}")
        for name, counters in summary["links"].items():
            print(f"  link {name:<19} {counters}")
        for name, path in summary["files"].items():
            print(f"  {name:<24} {path}")
    return 0 if summary["success"] else 1


DEMO_HELP = """\
Start the emulator in its own process on pseudo-terminals (lockstep: fast and
deterministic), run the host's homing loop against it until arrival or failure, and
print a summary. It writes the trajectory plot, the capture, the run log and the
truth file to --out.

examples:
  rfhoming demo
  rfhoming demo --seed 7 --json
  rfhoming demo --scenario s0-open --target=-6,4 --out /tmp/demo
"""

RUN_HELP = """\
Home on a tag with real devices or emulator endpoints. The XPLR-AOA gives bearings; the base
takes velocity commands and gives odometry. The robot stops when data goes stale, on
arrival, on any error and on Ctrl-C. Exit status: 0 arrived, 1 did not, 2 usage/port errors
(a port that cannot be opened, a device not set up within its timeout=, several tags in view
and none chosen with --tag).

examples:
  rfhoming run --aoa /dev/ttyUSB0 --base /dev/ttyACM0 --log run.jsonl --capture run.pcapng
  rfhoming run --aoa /dev/ttyUSB0 --base /dev/ttyACM0 --tag CCF9578E0D8A
  rfhoming run --aoa /dev/ttyUSB0,baud=1000000,tags=CCF9578E0D8A --base /dev/ttyACM0,baud=115200
  rfhoming run --aoa socket://127.0.0.1:40123 --base socket://127.0.0.1:40124 --config robot.toml
  rfhoming run --config robot.toml          # ports from its [devices.aoa] and [devices.base]
  rfhoming run --controller rss --rss /dev/ttyACM1 --base /dev/ttyACM0
"""


def add_parsers(sub: argparse._SubParsersAction) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("demo", help="emulator + host: a full homing run, a summary and a plot",
                       description=DEMO_HELP, formatter_class=raw)
    p.add_argument("--scenario", default="s0-open", help="scenario preset (default s0-open)")
    p.add_argument("--seed", type=int, default=1, help="seed of the world (default 1)")
    p.add_argument("--target", help="tag position X,Y, e.g. --target=-6,4 (default: random per seed)")
    p.add_argument("--out", type=Path, default=Path("rfhoming-demo"), help="output folder (default ./rfhoming-demo)")
    p.add_argument("--config", type=Path, help="TOML config (see rfhoming config --print-default)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="home on a tag with real devices or emulator endpoints",
                       description=RUN_HELP, formatter_class=raw)
    p.add_argument("--aoa", metavar="SPEC", help="the XPLR-AOA, for --controller aoa and dock: a port spec "
                   "WHERE[,baud=,flow=,tags=] (e.g. /dev/ttyUSB0,baud=1000000)")
    p.add_argument("--rss", metavar="SPEC", help="the four-dish AT86RF212 node, for --controller rss")
    p.add_argument("--ble", metavar="SPEC", help="the ESP32 BLE scanner, for --controller trilat")
    p.add_argument("--base", metavar="SPEC", help="the robot base (e.g. /dev/ttyACM0,baud=115200)")
    p.add_argument("--controller", choices=CONTROLLERS, default="aoa",
                   help="homing method: aoa (S0, XPLR-AOA bearings), dock (S1, the station's AoA/RSSI of "
                        "the robot's tag, given with --aoa), rss (S2, four dishes + particle filter), "
                        "trilat (S3, BLE beacons at the places in [trilat.anchors], to [trilat] goal)")
    p.add_argument("--tag", action="append", default=[], metavar="ID",
                   help="the tag to home on (12 hex digits; repeat or join with + for several ids of one "
                        "target). Without it, run listens for 2 s and homes on the only tag in view, or "
                        "stops and lists the tags it hears. Same as tags= in the --aoa spec")
    p.add_argument("--config", type=Path, help="TOML config (see rfhoming config --print-default)")
    add_port_defaults(p)
    p.add_argument("--log", type=Path, help="JSON-lines run log of every measurement, estimate and command")
    p.add_argument("--capture", type=Path, help="pcapng capture of every byte")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("config", help="print the default config, or check a config file")
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--print-default", action="store_true", help="print the commented default TOML")
    group.add_argument("--check", type=Path, metavar="FILE", help="check a config file")
    p.set_defaults(func=cmd_config)
