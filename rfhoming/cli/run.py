"""``rfhoming run``, ``demo`` and ``config``: homing against real devices or the emulator."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.aoa import AoaDriver, AoaSetup
from rfhoming.host.drivers.base import BaseDriver
from rfhoming.host.drivers.rss import RssDriver
from rfhoming.host.homing.config import DEFAULT_TOML, ConfigError, load
from rfhoming.host.homing.loop import RunLog, aoa_loop, dock_loop, rss_loop, trilat_loop
from rfhoming.host.ports import HostPort, PortError
from rfhoming.host.session import flow_control

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


def cmd_run(args: argparse.Namespace) -> int:
    try:
        config = load(args.config)
    except ConfigError as exc:
        print(f"rfhoming run: {exc}", file=sys.stderr)
        return 2
    flag = {"rss": "rss", "trilat": "ble"}.get(args.controller, "aoa")
    sensor_port = getattr(args, flag)
    if sensor_port is None:
        print(f"rfhoming run: --controller {args.controller} needs --{flag} PORT", file=sys.stderr)
        return 2
    capture = CaptureWriter(args.capture) if args.capture else None
    taps = [capture.tap] if capture else []
    base = BaseDriver(HostPort(args.base, baud=args.baud, taps=taps), command_timeout_ms=config.loop.command_timeout_ms)
    if args.controller in ("aoa", "dock"):
        sensor = AoaDriver(HostPort(sensor_port, baud=args.baud, rtscts=flow_control("ublox-aoa", args.flow), taps=taps),
                           AoaSetup(probe_baud=args.probe_baud))
        make, protocol = (aoa_loop if args.controller == "aoa" else dock_loop), "ublox-aoa"
    else:
        sensor = RssDriver(HostPort(sensor_port, baud=args.baud, rtscts=flow_control("rss", args.flow), taps=taps),
                           ed_scale_db=config.calibration.ed_scale_db)
        make, protocol = (rss_loop if args.controller == "rss" else trilat_loop), "rss"
    runlog = open(args.log, "w") if args.log else None
    try:
        loop = make(base, sensor, config, RunLog(runlog))
    except ValueError as exc:
        print(f"rfhoming run: {exc}", file=sys.stderr)
        if runlog:
            runlog.close()
        return 2
    if capture:
        capture.describe(base.port.name, protocol="rss", kind="base")
        capture.describe(sensor.port.name, protocol=protocol, kind=sensor.kind)
    try:
        outcome = asyncio.run(loop.run())
    except PortError as exc:
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
arrival, on any error and on Ctrl-C. Exit status: 0 arrived, 1 did not, 2 usage/port errors.

examples:
  rfhoming run --aoa /dev/ttyUSB0 --base /dev/ttyACM0 --log run.jsonl --capture run.pcapng
  rfhoming run --aoa socket://127.0.0.1:40123 --base socket://127.0.0.1:40124 --config robot.toml
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
    p.add_argument("--aoa", metavar="PORT", help="the XPLR-AOA (path, socket:// URL), for --controller aoa")
    p.add_argument("--rss", metavar="PORT", help="the four-dish AT86RF212 node, for --controller rss")
    p.add_argument("--ble", metavar="PORT", help="the ESP32 BLE scanner, for --controller trilat")
    p.add_argument("--base", required=True, metavar="PORT", help="the robot base")
    p.add_argument("--controller", choices=CONTROLLERS, default="aoa",
                   help="homing method: aoa (S0, XPLR-AOA bearings), dock (S1, the station's AoA/RSSI of "
                        "the robot's tag, given with --aoa), rss (S2, four dishes + particle filter), "
                        "trilat (S3, BLE beacons at the places in [trilat.anchors], to [trilat] goal)")
    p.add_argument("--config", type=Path, help="TOML config (see rfhoming config --print-default)")
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("--probe-baud", action="store_true",
                   help="if the XPLR-AOA sends only garbage, try each rate it documents until it answers AT")
    p.add_argument("--flow", choices=("auto", "on", "off"), default="auto",
                   help="RTS/CTS on the XPLR-AOA port (auto = on, its documented default)")
    p.add_argument("--log", type=Path, help="JSON-lines run log of every measurement, estimate and command")
    p.add_argument("--capture", type=Path, help="pcapng capture of every byte")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("config", help="print the default config, or check a config file")
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--print-default", action="store_true", help="print the commented default TOML")
    group.add_argument("--check", type=Path, metavar="FILE", help="check a config file")
    p.set_defaults(func=cmd_config)
