"""``rfhoming locate``: tag positions from a site's fixed AoA anchors."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from dataclasses import replace

import numpy as np

from rfhoming.cli.live import ros2_publisher
from rfhoming.cli.site_sources import gather, load_site
from rfhoming.host import losses
from rfhoming.host import site as sites
from rfhoming.host.bearing import Bearing
from rfhoming.host.locate import Locator, Position, smooth
from rfhoming.host.loopstall import StallMonitor, watching
from rfhoming.host.outputs import Output


def run(args: argparse.Namespace) -> int:
    site = load_site(args.site, "locate")
    if site is None:
        return 2
    if args.rate:
        site = replace(site, rate_hz=args.rate)
    if args.smooth and not (args.sources and all(s.startswith(("capture:", "angles:")) for s in args.sources)):
        print("rfhoming locate: --smooth needs a whole recording (--from capture:FILE or angles:FILE); a live run "
              "stays causal",
              file=sys.stderr)
        return 2
    print(f"rfhoming locate: {_calibration_in_use(site)}", file=sys.stderr)
    tracker = args.tracker or "angles"
    locator = Locator(site, track=not (args.no_track or args.smooth), tracker=tracker,
                      accel_psd=args.accel_psd, loss=args.loss, height_sigma=args.height_sigma)
    # --ros2: the anchors' angles (in anchor_<id>, placed in map by /tf_static) and the fixes
    ros2 = (ros2_publisher(args.ros2, source="anchors", site=site, robot=False)
            if args.ros2 is not None else None)
    out = Output(args.output) if args.output else sys.stdout  # OUTPUT.part while it runs (tail -f that), then OUTPUT
    per_tag: dict[str, list[float]] = {}
    fixes: list[Position] = []

    def show(positions: list[Position]) -> None:
        if args.smooth:  # held for the smoother at the end
            fixes.extend(positions)
            return
        for p in positions:
            per_tag.setdefault(p.tag, []).append(float(np.trace(p.covariance)))
            out.write(json.dumps({"kind": "position", **p.as_dict()}) + "\n")
            if ros2 is not None:
                ros2.on_position(p)
        if positions:
            out.flush()

    def feed(reading: Bearing) -> None:
        show(locator.feed(reading))

    try:
        smoothed = args.smooth
        stalls = StallMonitor()
        code = asyncio.run(watching(gather("locate", site, args.sources, feed, locator.disconnected, baud=args.baud,
                                           flow=args.flow, duration=args.duration, capture_to=args.capture,
                                           password_file=args.password_file, ca_file=args.ca,
                                           on_item=(lambda t, item: ros2.on_item("", t, item)) if ros2 else None),
                                    stalls))
        if code:
            return code
        show(locator.flush())
        if args.smooth:
            args.smooth = False
            show(smooth(fixes, 1.0 if args.accel_psd is None else args.accel_psd))
        if ros2 is not None:
            ros2.close()
        names = {a.id: a.name for a in site.anchors}
        summary = {"kind": "summary", "site": site.name,
                   "estimate": "smoothed (RTS over the whole recording)" if smoothed else
                   "raw fixes" if args.no_track else f"causal ({tracker} tracker)",
                   "tags": {tag: {"positions": len(v), "mean_sigma_m": round(float(np.sqrt(np.mean(v))), 3)}
                            for tag, v in sorted(per_tag.items())},
                   "anchors": sorted(names.values()), **locator.counters,
                   "losses": losses.WARNINGS.check("locate", locator.counters), **stalls.summary()}
        out.write(json.dumps(summary) + "\n")
        return code
    finally:
        if isinstance(out, Output):
            out.close()  # renamed into place once it got a line (however the command ended), else the old file stays


def _calibration_in_use(site: sites.Site) -> str:
    """One line: which anchors the site file calibrates (and how much), which it leaves raw."""
    plain = sites.Calibration()
    done = [f"{a.name} ({a.angle_model}, az_scale {a.calibration.az_scale:.3f}, az_bias {a.calibration.az_bias_deg:+.1f} deg)"
            for a in site.anchors if a.calibration != plain]
    raw = [a.name for a in site.anchors if a.calibration == plain]
    where = site.path or site.name
    if not done:
        return f"no calibration in {where}: angles used as the boards report them (rfhoming calibrate --help)"
    return f"calibration from {where}: " + ", ".join(done) + (f"; uncalibrated: {', '.join(raw)}" if raw else "")
