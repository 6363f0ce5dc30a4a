"""``rfhoming locate`` and ``rfhoming calibrate``: tag positions from a site's fixed anchors."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rfhoming.cli.args import accel_psd, duration, from_spec, height_sigma, output_file, path, rate_hz, tag_height
from rfhoming.cli.io import _run_until, add_port_defaults
from rfhoming.host import losses
from rfhoming.cli.live import add_ros2_option, ros2_publisher
from rfhoming.host import site as sites
from rfhoming.host.calibration import CalibrationError, Point, assign_dwells, calibrate
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.aoa import AoaDriver, replayed_without_set_up
from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.locate import Locator, Position, smooth
from rfhoming.host.loopstall import StallMonitor, watching
from rfhoming.host.ports import PortError
from rfhoming.host.session import health, open_drivers
from rfhoming.protocol.errors import Error
from rfhoming.protocol.textfile import read_toml

log = logging.getLogger(__name__)

LOCATE_HELP = """\
Locate tags from a site's fixed XPLR-AOA anchors (a site file: docs/usage.md, "Fixed anchors").
Every anchor's angle events are merged by host arrival time; at --rate (default: the site's
rate_hz) each tag seen by enough fresh anchors gets a fix (3-D rays, weighted, one bad anchor
left out) that a constant-velocity filter tracks. Output: one JSON line per position
(kind "position": t, tag, x, y, z in metres, cov 3x3 in m^2, anchors used, rejected,
chi2_per_dof = the fix's quality, as on the site bus), and on exit one "summary" line (its
"estimate" says causal or smoothed). A capture of the anchors gives the same lines as the live run did; --smooth on a capture gives
RTS-smoothed positions instead, each marked "smoothed": true.

examples:
  rfhoming locate site.toml                                # the anchors' ports from the site
  rfhoming locate site.toml --duration 30 --capture run.pcapng
  rfhoming locate site.toml --from capture:run.pcapng      # the same positions, from the capture
  rfhoming locate site.toml --from capture:run.pcapng --smooth --loss cauchy   # after the fact
  rfhoming locate site-64x1000 --from mqtt://127.0.0.1:1883/8 --id w1      # a site worker (below)

the kit room of docs/sites, emulated (its first line printed, every link exists):
  mkdir -p /tmp/rfhoming-kit
  rfhoming emulate kit-room --link-dir /tmp/rfhoming-kit --duration 15 | { read -r _; rfhoming locate docs/sites/kit-room.toml --duration 10; }
"""

CALIBRATE_HELP = """\
Fit each anchor's angle corrections and write them, with its angle model, into the site file's
[anchors.NAME] tables (the rest of the file is kept as it was); report each anchor's angle
error before and after, each fitted parameter's standard deviation, and which parameters were
held and why (only what the points determine is fitted: e.g. no elevation when every point is
at one height). Results stay within the site file's limits, or nothing is written.

With known points (--points FILE):

  [points]                           # tags that stay at one point all the recording
  CCF9578E0C01 = [2.0, 1.5, 0.8]     # x, y, z in metres, the site's frame

  [[dwell]]                          # one tag carried from point to point
  tag = "CCF9578E0D8A"
  position = [2.0, 1.5, 0.8]
  from_s = 10                        # seconds from the first angle event; leave both out and
  to_s = 40                          # the dwells (5 s or more still) are found, in order

Every anchor must see three or more points (spread out, not on one line through it).

Without (--self): tags walked over the whole room; each anchor's azimuth scale and bias (and
elevation, |azimuth| compression, where the data determine them) are fitted jointly with every
epoch's position (the scales' geometric mean is fixed to 1: an overall scale is not
observable). The epochs are cut into 10 s blocks dealt into three folds, each scored by a fit
of the others: the calibration is written only when it beats the uncalibrated site on these
held-out epochs, else nothing is written and one line says why. A parameter that runs to its
bound or that the folds do not agree on is held at its default ("held", with the reason).
Refused when the tags did not cover the room.

examples:
  rfhoming calibrate site.toml --points points.toml --duration 20
  rfhoming calibrate site.toml --points points.toml --from capture:cal.pcapng --dry-run
  rfhoming calibrate site.toml --points points.toml --azimuth-only --from capture:cal.pcapng
  rfhoming calibrate site.toml --self --from capture:walk1.pcapng --from capture:walk2.pcapng
"""


def _load_site(path: Path, command: str) -> sites.Site | None:
    try:
        return sites.load(path)
    except sites.SiteError as exc:
        print(f"rfhoming {command}: {exc}", file=sys.stderr)
        return None


def _specs(site: sites.Site, given: list[str] | None) -> list[str]:
    if given:
        return given
    missing = [a.name for a in site.anchors if a.port is None]
    if missing:
        raise ValueError(f"anchor(s) {', '.join(missing)} have no port in the site file: add port = "
                         "\"xplr-aoa:WHERE\" to each, or give --from SPEC (e.g. --from capture:run.pcapng)")
    return [a.port for a in site.anchors if a.port is not None]


async def _gather(args: argparse.Namespace, site: sites.Site, on_angle: Callable[[float, Any], None],
                  on_lost: Callable[[float, set[str]], None] = lambda t, ids: None) -> int:
    """Open the site's anchors (or --from), feed every angle event to ``on_angle`` in arrival
    order until --duration or the end of a capture, and tell ``on_lost`` the anchor ids of a
    device that went away; 2 on a port/capture error."""
    capture = CaptureWriter(args.capture) if getattr(args, "capture", None) else None
    try:
        drivers: list[Driver] = await open_drivers(_specs(site, args.sources), baud=args.baud, flow=args.flow,
                                                   taps=[capture.tap] if capture else [],
                                                   describe=capture.describe if capture else None)
    except OSError as exc:
        print(f"rfhoming {args.command}: cannot read {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    except Error as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2

    as_recorded = [d.port.name for d in drivers if isinstance(d, AoaDriver) and replayed_without_set_up(d.port)]
    if as_recorded:
        log.info("replayed angle streams with no set-up exchange (%s): angles taken as recorded",
                 ", ".join(as_recorded))
    heard: dict[str, set[str]] = {}  # device -> the anchor ids in its events

    def listener(device: str, t: float, item: Any) -> None:
        if item.kind == "angle":
            heard.setdefault(device, set()).add(item.anchor_id)
            on_angle(t, item)

    def tap(device: str, direction: str, t: float, _data: bytes) -> None:
        if direction == "lost":
            on_lost(t, heard.get(device, set()))

    for d in drivers:
        d.listeners.append(listener)
        d.port.taps.append(tap)
    # the listener took every event already: empty the drivers' queues so they count no drops
    drains = [asyncio.create_task(_discard(d.out)) for d in drivers if isinstance(d, AoaDriver)]
    try:
        await _run_until(drivers, args.duration, drains)
    except PortError as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2
    finally:
        for h in health(drivers):
            print(json.dumps({"kind": "counters", **h}), file=sys.stderr)
        if capture is not None:
            capture.close()
            print(f"captured {capture.packets} chunks to {capture.path}", file=sys.stderr)
    return 0


async def _discard(stream: BoundedStream[Any]) -> None:
    async for _ in stream:
        pass


def cmd_locate(args: argparse.Namespace) -> int:
    from rfhoming.cli import site as site_bus

    if args.sources and any(site_bus.is_broker(s) for s in args.sources):
        return site_bus.cmd_worker(args)
    site = _load_site(args.site, "locate")
    if site is None:
        return 2
    if args.rate:
        site = sites.Site(site.name, site.anchors, site.tags, args.rate, site.window_s, site.stale_s,
                          site.sigma_deg, site.path)
    if args.smooth and not (args.sources and all(s.startswith("capture:") for s in args.sources)):
        print("rfhoming locate: --smooth needs a whole recording (--from capture:FILE); a live run stays causal",
              file=sys.stderr)
        return 2
    print(f"rfhoming locate: {_calibration_in_use(site)}", file=sys.stderr)
    locator = Locator(site, track=not (args.no_track or args.smooth), tracker=args.tracker,
                      accel_psd=args.accel_psd, loss=args.loss, height_sigma=args.height_sigma)
    # --ros2: the anchors' angles (in anchor_<id>, placed in map by /tf_static) and the fixes
    ros2 = (ros2_publisher(args.ros2, source="anchors", site=site, robot=False)
            if args.ros2 is not None else None)
    out = args.output.open("w") if args.output else sys.stdout
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

    def feed(t: float, event: Any) -> None:
        if ros2 is not None:
            ros2.on_item("", t, event)
        show(locator.feed(t, event))

    smoothed = args.smooth
    stalls = StallMonitor()
    code = asyncio.run(watching(_gather(args, site, feed, locator.disconnected), stalls))
    if code:
        return code
    show(locator.flush())
    if args.smooth:
        args.smooth = False
        show(smooth(fixes, args.accel_psd))
    if ros2 is not None:
        ros2.close()
    names = {a.id: a.name for a in site.anchors}
    summary = {"kind": "summary", "site": site.name,
               "estimate": "smoothed (RTS over the whole recording)" if smoothed else
               "raw fixes" if args.no_track else f"causal ({args.tracker} tracker)",
               "tags": {tag: {"positions": len(v), "mean_sigma_m": round(float(np.sqrt(np.mean(v))), 3)}
                        for tag, v in sorted(per_tag.items())},
               "anchors": sorted(names.values()), **locator.counters,
               "losses": losses.WARNINGS.check("locate", locator.counters), **stalls.summary()}
    out.write(json.dumps(summary) + "\n")
    if out is not sys.stdout:
        out.close()
    return code


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


def _position(value: Any, where: str) -> tuple[float, float, float]:
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise CalibrationError(f"{where} = {value!r} must be [x, y, z], finite numbers in metres")
    return (float(value[0]), float(value[1]), float(value[2]))


def _load_points(path: Path) -> list[Point]:
    """The known points: [points] TAGID = [x, y, z] (a tag at one point all recording) and
    [[dwell]] tables (one tag carried from point to point); CalibrationError names what to fix."""
    raw = read_toml(path, "points file", CalibrationError)
    unknown = sorted(set(raw) - {"points", "dwell"})
    if unknown:
        raise CalibrationError(f"{path}: unknown table(s) {', '.join(unknown)}; known: [points], [[dwell]]")
    points = raw.get("points", {})
    dwells = raw.get("dwell", [])
    if not isinstance(points, dict) or not isinstance(dwells, list) or not (points or dwells):
        raise CalibrationError(f"{path} needs a [points] table (TAGID = [x, y, z], one line per tag at a known "
                               "point) or [[dwell]] tables (tag, position, optional from_s and to_s)")
    out = [Point(tag.upper(), _position(value, f"{path}: point {tag}")) for tag, value in points.items()]
    for k, d in enumerate(dwells, 1):
        where = f"{path}: [[dwell]] number {k}"
        if not isinstance(d, dict) or not isinstance(d.get("tag"), str):
            raise CalibrationError(f"{where} needs tag = \"TAGID\" and position = [x, y, z]")
        extra = sorted(set(d) - {"tag", "position", "from_s", "to_s"})
        if extra:
            raise CalibrationError(f"{where} has unknown key(s) {', '.join(extra)}; known: tag, position, from_s, to_s")
        window: list[Any] = [d.get("from_s"), d.get("to_s")]
        if window != [None, None] and not (
                all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in window) and window[0] < window[1]):
            raise CalibrationError(f"{where}: from_s and to_s must both be given, seconds from the first angle "
                                   f"event with from_s < to_s (or both left out: dwells are found); got {window}")
        out.append(Point(d["tag"].upper(), _position(d.get("position"), f"{where} position"),
                         *(None if v is None else float(v) for v in window)))
    return out


def cmd_calibrate(args: argparse.Namespace) -> int:
    site = _load_site(args.site, "calibrate")
    if site is None:
        return 2
    if args.self_calibrate:
        return _self_calibrate(args, site)
    if args.points is None:
        print("rfhoming calibrate: give --points FILE (tags at known points) or --self (from a recording of "
              "tags moving over the room)", file=sys.stderr)
        return 2
    try:
        points = _load_points(args.points)
    except CalibrationError as exc:
        print(f"rfhoming calibrate: {exc}", file=sys.stderr)
        return 2
    events: list[tuple[float, Any]] = []
    print(f"recording angles of {len(points)} known point(s)"
          + (f" for {args.duration:g} s" if args.duration else "") + "...", file=sys.stderr)
    code = asyncio.run(_gather(args, site, lambda t, event: events.append((t, event))))
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
    """--self: each --from recording gathered on its own (their clocks need not line up)."""
    if args.points is not None:
        print("rfhoming calibrate: --self fits without known points; leave out --points", file=sys.stderr)
        return 2
    recordings = []
    for source in args.sources or [None]:
        events: list[tuple[float, Any]] = []
        def collect(t: float, event: Any, into: list[tuple[float, Any]] = events) -> None:
            into.append((t, event))

        code = asyncio.run(_gather(argparse.Namespace(**{**vars(args), "sources": [source] if source else None}),
                                   site, collect))
        if code:
            return code
        recordings.append(events)
    from rfhoming.host.self_calibration import self_calibrate

    models = "auto"
    if args.angle_model in ("spherical", "cone"):
        models = "site"
        site = replace(site, anchors=tuple(replace(a, angle_model=args.angle_model) for a in site.anchors))
    try:
        result = self_calibrate(site, recordings, height=args.height, models=models,
                                progress=lambda text: print(text, end="", file=sys.stderr, flush=True))
    except CalibrationError as exc:
        print(f"rfhoming calibrate: {exc}", file=sys.stderr)
        return 2
    print(f"self-calibration: {result.epochs} epochs; gauge: {result.gauge}", file=sys.stderr)
    for f in result.fits:
        c = f.calibration
        print(json.dumps({"kind": "calibration", "anchor": f.anchor, "self": True, "epochs": f.points,
                          "angle_model": f.angle_model, "held_out_rms_before_deg": round(f.rms_before_deg, 2),
                          "held_out_rms_after_deg": round(f.rms_after_deg, 2), "az_scale": round(c.az_scale, 4),
                          "az_bias_deg": round(c.az_bias_deg, 2), "az_compression": round(c.az_compression, 4),
                          "el_scale": round(c.el_scale, 4), "el_bias_deg": round(c.el_bias_deg, 2),
                          "sigma": f.sigma, "held": f.held, "held_out_rms_by_model_deg": result.model_scores[f.anchor]}))
    print(f"self-calibration {result.verdict}", file=sys.stderr)
    if not result.write:
        return 0
    return _write(args, {f.anchor: f.calibration for f in result.fits}, {f.anchor: f.angle_model for f in result.fits})


def _write(args: argparse.Namespace, calibrations: dict[str, Any], models: dict[str, str]) -> int:
    if args.dry_run:
        print("--dry-run: the site file is unchanged", file=sys.stderr)
        return 0
    sites.write_calibration(args.site, calibrations, models)
    print(f"wrote the calibration of {len(calibrations)} anchors into {args.site}", file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    for name, helptext, description in (
            ("locate", "positions of tags from a site's fixed AoA anchors", LOCATE_HELP),
            ("calibrate", "fit each fixed anchor's angle corrections from known points", CALIBRATE_HELP)):
        p = sub.add_parser(name, help=helptext, description=description, formatter_class=raw)
        p.add_argument("site", type=path, help="site file (TOML): anchors, their poses and ports, tags")
        p.add_argument("--from", dest="sources", type=from_spec, action="append", metavar="SPEC",
                       help="read these ports instead of the site's (repeatable), e.g. capture:run.pcapng")
        p.add_argument("--duration", type=duration, help="stop after this many seconds (a capture ends by itself)")
        add_port_defaults(p)
        if name == "locate":
            p.add_argument("--capture", type=output_file, help="also record every anchor's bytes to this pcapng file")
            p.add_argument("-o", "--output", type=output_file, help="write the JSON lines here instead of stdout")
            p.add_argument("--rate", type=rate_hz, help="positions per second per tag (default: the site's rate_hz)")
            p.add_argument("--no-track", action="store_true", help="raw fixes, no tracking filter")
            p.add_argument("--tracker", choices=("cv", "ekf"), default="cv",
                           help="cv: constant-velocity filter on the fixes (default, cheaper); ekf: every angle "
                                "pair updates the track as it arrives (more accurate, ~3x the CPU: docs/BENCHMARKS.md)")
            p.add_argument("--accel-psd", type=accel_psd, default=1.0,
                           help="tracking process noise: white acceleration, m^2/s^3 (default 1: walking)")
            p.add_argument("--smooth", action="store_true",
                           help="recordings only (--from capture:): RTS-smooth each tag's fixes over the whole "
                                "recording; positions are labelled \"smoothed\" (not causal)")
            p.add_argument("--loss", choices=("huber", "cauchy"), default="huber",
                           help="the fix's robust loss: huber (default; one bad anchor left out) or cauchy "
                                "(every anchor kept, each down-weighted by its miss)")
            p.add_argument("--height-sigma", type=height_sigma, metavar="M",
                           help="a tag's known height is a prior of this sigma (m), not a constraint")
            from rfhoming.cli.site import add_worker_arguments

            add_worker_arguments(p)
            add_ros2_option(p, "the anchors' angles and each tag's position (PoseWithCovarianceStamped and "
                               "PointStamped on /rfhoming/tag_<ID>/pose and /point, in map)")
            p.set_defaults(func=cmd_locate)
        else:
            p.add_argument("--points", type=path, help="TOML: [points] TAGID = [x, y, z] and/or [[dwell]] tables")
            p.add_argument("--self", dest="self_calibrate", action="store_true",
                           help="no known points: fit each anchor's azimuth scale and bias from tags moving over "
                                "the whole room (give the recordings with --from capture:FILE)")
            p.add_argument("--azimuth-only", action="store_true",
                           help="fit azimuth (and yaw) only; elevation keeps scale 1 and bias 0")
            p.add_argument("--angle-model", choices=("auto", "spherical", "cone"),
                           help="the boards' angle model; auto (default): with --points the one with the smaller "
                                "residual, with --self each anchor's winner on held-out epochs (spherical, cone, "
                                "each with |azimuth| compression) if it beats the site file's by 3 percent")
            p.add_argument("--height", type=tag_height, metavar="M",
                           help="--self: the height (m) of tags the site file gives none (else free about 1 m); "
                                "elevation is fitted only from tags of known height")
            p.add_argument("--dry-run", action="store_true", help="report the fit, leave the site file alone")
            p.set_defaults(func=cmd_calibrate)
