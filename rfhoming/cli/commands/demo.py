"""``rfhoming demo``: the emulator and the host, a full homing run, a summary and a plot."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from rfhoming.cli.live import linger, mcap_recorder, start_foxglove, wait_for_viewer
from rfhoming.host.homing.config import load
from rfhoming.host.portspec import PortSpecError


def run(args: argparse.Namespace) -> int:
    from rfhoming.demo import SUPPORTED, check_outputs, run_demo

    if args.scenario not in SUPPORTED:
        raise PortSpecError(f"scenario {args.scenario!r} is not wired to a controller yet; "
                            f"choose one of {sorted(SUPPORTED)}")
    config = load(args.config)
    if args.receiver and args.scenario != "s3-arena":
        raise PortSpecError("--receiver swaps the BLE RSSI receiver of --scenario s3-arena")
    check_outputs(args.out)  # a killed demo's NAME.part files, all named, before a view or an emulator starts
    speed = args.speed if args.speed is not None else (1.0 if args.foxglove is not None else 0.0)
    if not args.json:
        where = "in this process" if args.in_process else "on ptys"
        pace = "in lockstep" if speed == 0 or args.in_process else f"at {speed:g}x robot time"
        print(f"demo: emulating {args.scenario} (seed {args.seed}, {args.radio} radios) {where} {pace}; homing ...",
              file=sys.stderr)
    sinks = []
    view = None
    try:
        sinks += [mcap_recorder(args.mcap)] if args.mcap else []
        view = start_foxglove(args, "demo")  # a view that cannot start leaves no MCAP.part behind
        wait_for_viewer(view, args.wait_viewer)
        summary = run_demo(args.scenario, args.seed, args.out, config, args.target, args.receiver,
                           sinks=[*sinks, *([view] if view else [])], speed=speed, in_process=args.in_process,
                           radio=args.radio, announce=say_vehicle)
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
        for key in ("radio", "target", "goal_position_error_m", "final_position_error_m", "path_efficiency",
                    "net_velocity_m_s", "stale_stops", "latency_ms_p50", "latency_ms_p99", "loop_stall_ms_max",
                    "loop_stall_ms_p99"):
            if key in summary:
                print(f"  {key:<24} {summary[key]}")
        if "localisation" in summary:
            print_localisation(summary["localisation"])
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


def say_vehicle(address: str) -> None:
    """Where a ground station joins the emulated vehicle beside the demo (stderr, --json too:
    the summary comes only at the end)."""
    print(f"demo: the emulated MAVLink vehicle is at {address} (UDP); a ground station joins it beside the run with "
          f"udpout:{address}, e.g. mavproxy.py --master=udpout:{address}", file=sys.stderr, flush=True)


def print_localisation(located: dict[str, Any] | None) -> None:
    """S4's metric beside the thesis's: every beacon's final error, mean and 95th percentile."""
    if located is None:
        print("  localisation             no beacon localised")
        return
    paper = located["s4_paper"]
    for name, title in (("ekf", "S4's EKF"), ("ekf_smoothed", "EKF + smoother")):
        if name in located:
            e = located[name]
            print(f"  localisation, {title:<14} mean {e['mean_m']} m, p95 {e['p95_m']} m, max {e['max_m']} m "
                  f"({e['beacons']} of {e['of']} beacons; S4: mean {paper['mean_m']} m, 95 % below "
                  f"{paper['p95_below_m']} m)")
