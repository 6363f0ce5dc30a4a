"""``rfhoming calibrate``: fit each fixed anchor's angle corrections, from known points or the
anchors' own recordings (--self), and write them into the site file."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from dataclasses import replace
from typing import Any

from rfhoming.cli.site_sources import gather, load_site
from rfhoming.host import outputs
from rfhoming.host import site as sites
from rfhoming.host.bearing import Bearing
from rfhoming.host.calibration import CalibrationError, assign_dwells, calibrate
from rfhoming.host.points_file import load_points


def run(args: argparse.Namespace) -> int:
    site = load_site(args.site, "calibrate")
    if site is None:
        return 2
    if not args.dry_run:
        outputs.check(args.site)  # it can be replaced (no site file's .part in the way) before any device opens
    if args.self_calibrate:
        return _self_calibrate(args, site)
    if args.points is None:
        print("rfhoming calibrate: give --points FILE (tags at known points) or --self (from a recording of "
              "tags moving over the room)", file=sys.stderr)
        return 2
    try:
        points = load_points(args.points)
    except CalibrationError as exc:
        print(f"rfhoming calibrate: {exc}", file=sys.stderr)
        return 2
    events: list[Bearing] = []
    print(f"recording angles of {len(points)} known point(s)"
          + (f" for {args.duration:g} s" if args.duration else "") + "...", file=sys.stderr)
    code = asyncio.run(gather("calibrate", site, args.sources, events.append,
                             baud=args.baud, flow=args.flow, duration=args.duration))
    if code:
        return code
    try:
        points, found = assign_dwells(events, points)
        for line in found:
            print(line, file=sys.stderr)
        fits = calibrate(site, events, points, azimuth_only=args.azimuth_only, angle_model=args.angle_model or "auto")
    except CalibrationError as exc:
        print(f"rfhoming calibrate: {exc}", file=sys.stderr)
        return 2
    for f in fits:
        c = f.calibration
        print(json.dumps({"kind": "calibration", "anchor": f.anchor, "points": f.points, "angle_model": f.angle_model,
                          "rms_before_deg": round(f.rms_before_deg, 2), "rms_after_deg": round(f.rms_after_deg, 2),
                          "yaw_offset_deg": round(c.yaw_offset_deg, 2), "az_scale": round(c.az_scale, 4),
                          "az_bias_deg": round(c.az_bias_deg, 2), "el_scale": round(c.el_scale, 4),
                          "el_bias_deg": round(c.el_bias_deg, 2),
                          "sigma": {k: round(v, 4) for k, v in f.sigma.items()}, "held": f.held,
                          "rms_by_model_deg": f.rms_by_model}))
    return _write(args, {f.anchor: f.calibration for f in fits}, {f.anchor: f.angle_model for f in fits})


def _self_calibrate(args: argparse.Namespace, site: sites.Site) -> int:
    """--self: each --from recording gathered on its own (their clocks need not line up). One
    progress line on stderr, one summary line on stdout (--verbose: each anchor's fit and each
    device's counters too)."""
    if args.points is not None:
        print("rfhoming calibrate: --self fits without known points; leave out --points", file=sys.stderr)
        return 2
    sources = args.sources or [None]
    print(f"rfhoming calibrate: reading {len(sources)} recording(s)", end="", file=sys.stderr, flush=True)
    recordings = []
    for source in sources:
        events: list[Bearing] = []
        named = f"calibrate: {source}" if source else "calibrate"  # an error names the recording
        code = asyncio.run(gather(named, site, [source] if source else None, events.append, baud=args.baud,
                                  flow=args.flow, duration=args.duration, counters=args.verbose))
        if code:
            return code
        recordings.append(events)
    from rfhoming.host.self_calibration import self_calibrate

    models = "auto"
    if args.angle_model in ("spherical", "cone"):
        models = "site"
        site = replace(site, anchors=tuple(replace(a, angle_model=args.angle_model) for a in site.anchors))
    try:
        result = self_calibrate(site, recordings, height=args.height, models=models, elevation=args.fit_elevation,
                                progress=lambda text: print(text if text.startswith(("\n", ";", ".")) else f"; {text}",
                                                            end="", file=sys.stderr, flush=True))
    except CalibrationError as exc:
        print(f"\nrfhoming calibrate: {exc}", file=sys.stderr)
        return 2
    anchors = [_self_fit(f, result.model_scores[f.anchor]) for f in result.fits]
    if args.verbose:
        for line in anchors:
            print(json.dumps(line))
    print(json.dumps({"kind": "self_calibration", "written": result.write and not args.dry_run, "epochs": result.epochs,
                      "verdict": result.verdict, "gauge": result.gauge, "held": result.held,
                      "anchors": {a["anchor"]: {k: a[k] for k in ("angle_model", "az_scale", "az_bias_deg",
                                                                  "az_compression", "el_scale", "el_bias_deg")}
                                  | {"held": sorted(a["held"])} for a in anchors}}))
    if not result.write:
        return 0
    return _write(args, {f.anchor: f.calibration for f in result.fits}, {f.anchor: f.angle_model for f in result.fits})


def _self_fit(f: Any, model_scores: dict[str, float]) -> dict[str, Any]:
    """One anchor's self-calibration as a JSON object: the fit, its sigmas, what was held and why."""
    c = f.calibration
    return {"kind": "calibration", "anchor": f.anchor, "self": True, "epochs": f.points, "angle_model": f.angle_model,
            "held_out_rms_before_deg": round(f.rms_before_deg, 2), "held_out_rms_after_deg": round(f.rms_after_deg, 2),
            "az_scale": round(c.az_scale, 4), "az_bias_deg": round(c.az_bias_deg, 2),
            "az_compression": round(c.az_compression, 4), "el_scale": round(c.el_scale, 4),
            "el_bias_deg": round(c.el_bias_deg, 2), "sigma": f.sigma, "held": f.held,
            "held_out_rms_by_model_deg": model_scores}


def _write(args: argparse.Namespace, calibrations: dict[str, Any], models: dict[str, str]) -> int:
    if args.dry_run:
        print("--dry-run: the site file is unchanged", file=sys.stderr)
        return 0
    sites.write_calibration(args.site, calibrations, models)
    print(f"wrote the calibration of {len(calibrations)} anchors into {args.site}", file=sys.stderr)
    return 0
