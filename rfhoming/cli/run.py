"""``rfhoming run``, ``demo`` and ``config``: homing against real devices or the emulator."""

from __future__ import annotations

import argparse
import contextlib
import asyncio
import json
import sys
from pathlib import Path

from rfhoming.cli.args import nonempty, output_file, output_folder, path, seed, speed, xy
from rfhoming.cli.io import add_port_defaults
from rfhoming.cli.live import (
    ExtraMissing,
    add_foxglove_option,
    add_ros2_option,
    add_watch_options,
    linger,
    ros2_publisher,
    start_foxglove,
    wait_for_viewer,
)
from rfhoming.host import site as sites
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import CHOOSE_TAG_S, METHODS, Device, Homing, replay_plan, run_record
from rfhoming.host.homing.config import DEFAULT_TOML, Config, load
from rfhoming.host.homing.loop import RunLog
from rfhoming.host.portspec import SETTINGS, PortSpec, PortSpecError
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.host.sink import Sink
from rfhoming.host.site import Site

CONTROLLERS = tuple(METHODS)


def cmd_config(args: argparse.Namespace) -> int:
    if args.print_default:
        print(DEFAULT_TOML, end="")
        return 0
    load(args.check)
    print(f"{args.check}: OK")
    return 0


def _tags(values: list[str]) -> tuple[str, ...]:
    """--tag values (each one id or ids joined by +) -> upper-case ids; PortSpecError explains."""
    try:
        return tuple(dict.fromkeys(t for v in values for t in SETTINGS["tags"](v)))
    except ValueError as exc:
        raise PortSpecError(f"--tag takes {exc}") from None


def _devices(args: argparse.Namespace, config: Config, role: str) -> tuple[list[Device], Site | None]:
    """The run's devices by role: the command line's specs over the config's [devices.ROLE];
    fixed anchors come from the site file."""
    def spec(r: str) -> PortSpec:
        given = getattr(args, r, None)
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
        sensors = [Device(role, spec=spec(role))]
    return [*sensors, Device("base", spec=spec("base"))], site


def cmd_run(args: argparse.Namespace) -> int:
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
        plan.runlog = RunLog(opened.enter_context(open(args.log, "w")) if args.log else None)
        if args.capture:
            record = run_record(plan, args.site.read_text() if site is not None else None)
            plan.capture = opened.enter_context(contextlib.closing(CaptureWriter(args.capture, comment=record)))
        try:
            outcome = asyncio.run(assembly.run(plan))
        except KeyboardInterrupt:
            print("rfhoming run: interrupted; the base was told to stop", file=sys.stderr)
            return 130
    print(json.dumps(outcome.summary()))
    return 0 if outcome.arrived else 1


def replay_run(args: argparse.Namespace) -> int:
    """``rfhoming replay CAPTURE --run``: the recorded homing loop again, on the capture's bytes."""
    plan = replay_plan(args.capture, controller=args.controller, config=load(args.config) if args.config else None)
    runlog = open(args.log, "w") if args.log else None
    plan.runlog = RunLog(runlog)
    try:
        outcome = asyncio.run(assembly.run(plan))
    finally:
        if runlog:
            runlog.close()
    ports = [device.port for device in plan.devices]
    firsts = [p.first_divergence for p in ports if p.first_divergence is not None]
    first = min(firsts, key=lambda d: d["t"]) if firsts else None
    replay = {"diverged": sum(p.counters["diverged"] for p in ports),
              "unanswered": sum(p.counters["unanswered"] for p in ports), "first_divergence": first}
    if first is not None:
        print(f"rfhoming replay: the replayed loop first wrote otherwise than the recording at t = {first['t']:.6f} "
              f"on {first['device']} (wrote {first['wrote']}, the recording has {first['recorded']}); it went on "
              "from the recorded inputs", file=sys.stderr)
    summary = {k: v for k, v in outcome.summary().items()
               if not k.startswith(("latency_ms", "loop_stall_ms"))}  # no wall time here
    print(json.dumps({**summary, "replay": replay}))
    return 0 if outcome.arrived else 1


def mcap_recorder(path: Path) -> Sink:
    """The MCAP recorder sink; an Error naming the extra when its packages are missing."""
    try:
        from rfhoming.host.export.recorder import McapRecorder
    except ImportError as exc:
        raise ExtraMissing(f"--mcap needs the ros extra ({exc.name} is missing): pip install 'rfhoming[ros]'") from None
    return McapRecorder(path)


def cmd_demo(args: argparse.Namespace) -> int:
    from rfhoming.demo import SUPPORTED, run_demo

    if args.scenario not in SUPPORTED:
        raise PortSpecError(f"scenario {args.scenario!r} is not wired to a controller yet; "
                            f"choose one of {sorted(SUPPORTED)}")
    config = load(args.config)
    if args.receiver and args.scenario != "s3-arena":
        raise PortSpecError("--receiver swaps the BLE RSSI receiver of --scenario s3-arena")
    speed = args.speed if args.speed is not None else (1.0 if args.foxglove is not None else 0.0)
    if not args.json:
        where = "in this process" if args.in_process else "on ptys"
        pace = "in lockstep" if speed == 0 or args.in_process else f"at {speed:g}x robot time"
        print(f"demo: emulating {args.scenario} (seed {args.seed}) {where} {pace}; homing ...", file=sys.stderr)
    sinks = [mcap_recorder(args.mcap)] if args.mcap else []
    view = start_foxglove(args, "demo")
    try:
        wait_for_viewer(view, args.wait_viewer)
        summary = run_demo(args.scenario, args.seed, args.out, config, args.target, args.receiver,
                           sinks=[*sinks, *([view] if view else [])], speed=speed, in_process=args.in_process)
    except BaseException:
        if view is not None:
            view.close()
        raise
    finally:
        for sink in sinks:
            sink.close()
    if args.mcap is not None:
        summary["files"]["mcap"] = str(args.mcap)
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        ok = "SUCCESS" if summary["success"] else "FAILED"
        print(f"{ok}: {summary['reason']} after {summary['simulated_time_s']} s simulated")
        for key in ("target", "goal_position_error_m", "final_position_error_m", "path_efficiency",
                    "net_velocity_m_s", "stale_stops", "latency_ms_p50", "latency_ms_p99", "loop_stall_ms_max",
                    "loop_stall_ms_p99"):
            if key in summary:
                print(f"  {key:<24} {summary[key]}")
        for name, counters in summary["links"].items():
            print(f"  link {name:<19} {counters}")
        for name, path in summary["files"].items():
            print(f"  {name:<24} {path}", flush=True)
    if view is not None:
        try:
            linger(view, args.linger)
        finally:
            view.close()
    return 0 if summary["success"] else 1


MCAP_HELP = ("also record the run as ROS 2 messages (odometry, scans, commands, estimates, readings) in "
             "this MCAP file, for Foxglove, rosbags or ros2 bag (needs the ros extra)")

DEMO_HELP = """\
Start the emulator in its own process on pseudo-terminals (in lockstep: its world waits
for the host), run the host's homing loop against it until arrival or failure, and print
a summary. It writes the trajectory plot, the capture, the run log and the truth file to
--out; `rfhoming replay OUT/capture.pcapng --run` runs the same loop again on its bytes.

What varies from run to run with the same seed: on ptys the XPLR-AOA's and the base's bytes
reach the host in whatever order the operating system delivers two ports, so a reading
can meet a different odometry record and the simulated time and errors move by a few
hundredths; the latencies are wall-clock figures. --in-process joins the emulator and the
host by the emulator's in-process byte pipe (as the campaigns run) and gives the same
summary, line for line, for the same seed, without the latency lines.

examples:
  rfhoming demo
  rfhoming demo --seed 7 --json
  rfhoming demo --in-process               # the same summary for the same seed, every time
  rfhoming demo --scenario s0-open --target=-6,4 --out /tmp/demo
  rfhoming demo --scenario s3-arena --receiver hci     (S3 on HCI advertising reports)
  rfhoming demo --mcap run.mcap            # and a ROS 2 log of the run
  rfhoming demo --foxglove                 # watch it live at robot time: Foxglove -> ws://127.0.0.1:8765
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
  rfhoming run --config robot.toml --mcap run.mcap   # and a ROS 2 log for Foxglove / rosbags
  rfhoming run --config robot.toml --foxglove        # and a live view in Foxglove
  rfhoming run --controller rss --rss /dev/ttyACM1 --base /dev/ttyACM0
  rfhoming run --controller anchors --site site.toml --base /dev/ttyACM0
  rfhoming run --aoa serve://127.0.0.1:2948 --base /dev/ttyACM0   # share the XPLR-AOA with viewers
"""


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("demo", help="emulator + host: a full homing run, a summary and a plot",
                       description=DEMO_HELP, formatter_class=raw)
    p.add_argument("--scenario", type=nonempty, default="s0-open", help="scenario preset (default s0-open)")
    p.add_argument("--seed", type=seed, default=1, help="seed of the world (default 1)")
    p.add_argument("--target", type=xy, help="tag position X,Y, e.g. --target=-6,4 (default: random per seed)")
    p.add_argument("--out", type=output_folder, default=Path("rfhoming-demo"), help="output folder (default ./rfhoming-demo)")
    p.add_argument("--config", type=path, help="TOML config (see rfhoming config --print-default)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--receiver", choices=("esp32", "esp-at", "hci"),
                   help="s3-arena: the robot's BLE RSSI receiver -- esp32 (rfhoming frames, default), esp-at "
                   "(ESP32 with Espressif's AT firmware) or hci (a Bluetooth controller, needs rfhoming[hci])")
    p.add_argument("--mcap", type=output_file, metavar="FILE", help=MCAP_HELP)
    p.add_argument("--in-process", action="store_true",
                   help="the emulator in this process on its byte pipe: the same summary for the same seed")
    p.add_argument("--speed", type=speed, metavar="N", help="simulated seconds per wall second (0: lockstep, as "
                   "fast as the host answers); default 1 with --foxglove, else 0")
    add_foxglove_option(p)
    add_watch_options(p)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="home on a tag with real devices or emulator endpoints",
                       description=RUN_HELP, formatter_class=raw)
    p.add_argument("--aoa", type=nonempty, metavar="SPEC", help="the XPLR-AOA, for --controller aoa and dock: a port spec "
                   "WHERE[,baud=,flow=,tags=] (e.g. /dev/ttyUSB0,baud=1000000); settings it leaves out come "
                   "from the config's [devices.aoa]")
    p.add_argument("--rss", type=nonempty, metavar="SPEC", help="the four-dish AT86RF212 node, for --controller rss")
    p.add_argument("--ble", type=nonempty, metavar="SPEC", help="the BLE RSSI receiver, for --controller trilat: an ESP32 "
                   "scanner (rss-node:PATH), an ESP32 with ESP-AT (esp-at:PATH) or an HCI controller (hci:usb:0)")
    p.add_argument("--base", type=nonempty, metavar="SPEC", help="the robot base (e.g. /dev/ttyACM0,baud=115200)")
    p.add_argument("--controller", choices=CONTROLLERS, default="aoa",
                   help="homing method: aoa (S0, XPLR-AOA bearings), dock (S1, the station's AoA/RSSI of "
                        "the robot's tag, given with --aoa), rss (S2, four dishes + particle filter), "
                        "trilat (S3, BLE beacons at the places in [trilat.anchors], to [trilat] goal), "
                        "anchors (fixed XPLR-AOA anchors of --site locate the robot's own tag and the target's)")
    p.add_argument("--tag", type=nonempty, action="append", default=[], metavar="ID",
                   help="the tag to home on (12 hex digits; repeat or join with + for several ids of one "
                        "target). Without it, run listens for 2 s and homes on the only tag in view, or "
                        "stops and lists the tags it hears. Same as tags= in the --aoa spec")
    p.add_argument("--site", type=path, help="site file for --controller anchors (see rfhoming locate --help)")
    p.add_argument("--config", type=path, help="TOML config (see rfhoming config --print-default)")
    add_port_defaults(p)
    p.add_argument("--log", type=output_file, help="JSON-lines run log of every measurement, estimate and command")
    p.add_argument("--capture", type=output_file, help="pcapng capture of every byte")
    p.add_argument("--mcap", type=output_file, metavar="FILE", help=MCAP_HELP)
    add_ros2_option(p, "what the run senses (a ROS 2 base's own /odom, /scan and /tf are left to it)")
    add_foxglove_option(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("config", help="print the default config, or check a config file")
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--print-default", action="store_true", help="print the commented default TOML")
    group.add_argument("--check", type=path, metavar="FILE", help="check a config file")
    p.set_defaults(func=cmd_config)
