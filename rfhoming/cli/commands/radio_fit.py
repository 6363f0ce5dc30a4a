"""``rfhoming radio-fit``: a radio profile from a site's recordings, each with its walk (or a
stand-in for it), for the emulator's ``--radio PROFILE``; the fit is calibrated through the
emulator's own board (emulator/aoa_error.py's ``simulated_errors``, handed to the host here,
where the layers meet: host/aoa_calibrate.py)."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from dataclasses import replace
from pathlib import Path

from rfhoming.cli.site_sources import gather, load_site
from rfhoming.emulator.aoa_error import simulated_errors
from rfhoming.host.bearing import Bearing
from rfhoming.host.groundtruth import area_of, load_waypoints
from rfhoming.host.radio_fit import PROXY, Recording, RadioFitError, fit, track_truth, write
from rfhoming.protocol.radio_profile import ProfileError, load

NONE = "none"
"""``--truth none``: that recording stands in for its own truth."""


def run(args: argparse.Namespace) -> int:
    site = load_site(args.site, "radio-fit")
    if site is None:
        return 2
    try:  # before the recordings are read: a wrong name fails at once
        rssi = load(args.rssi_from).rssi if args.rssi_from else None
    except ProfileError as exc:
        print(f"rfhoming radio-fit: --rssi-from: {exc}", file=sys.stderr)
        return 2
    if len(args.truth) > len(args.sources):
        print(f"rfhoming radio-fit: {len(args.truth)} --truth for {len(args.sources)} --from: the i-th --truth is the "
              "i-th --from's walk; give at most one --truth per --from", file=sys.stderr)
        return 2
    truths = [None if t == NONE else Path(t) for t in args.truth] + [None] * (len(args.sources) - len(args.truth))
    area = area_of(a.position for a in site.anchors)
    walks = [load_waypoints(t, area) if t is not None else None for t in truths]  # a bad file fails before any reading
    recordings: list[list[Bearing]] = []
    for source in args.sources:
        events: list[Bearing] = []
        # an error names the capture it is of; each device's counters are left out (losses still warned)
        code = asyncio.run(gather(f"radio-fit: {source}", site, [source], events.append, counters=False))
        if code:
            return code
        recordings.append(events)
    missing = [k for k, w in enumerate(walks) if w is None]
    if missing:
        print(f"radio-fit: {len(missing)} recording(s) without --truth: self-calibrating and locating them to stand "
              "in for it", file=sys.stderr)
        proxies = track_truth(site, [recordings[k] for k in missing], tag=args.tag, height=args.height,
                              progress=lambda text: print(text, end="", file=sys.stderr, flush=True))
        for k, path in zip(missing, proxies):
            walks[k] = path
    ids = _ids(args.sources)
    fitted = [Recording(ids[k], source, recordings[k], walk, str(truths[k]) if truths[k] is not None else PROXY)
              for k, (source, walk) in enumerate(zip(args.sources, walks)) if walk is not None]
    try:
        profile, report = fit(site, fitted, args.name or args.output.stem, tag=args.tag, height=args.height,
                              description=args.description or "", board=simulated_errors,
                              progress=lambda text: print(text, end="", file=sys.stderr, flush=True))
    except RadioFitError as exc:
        print(f"rfhoming radio-fit: {exc}", file=sys.stderr)
        return 2
    if rssi is not None:
        profile = replace(profile, rssi=rssi)
    write(profile, args.output)
    warned = report.get("warnings")
    for line in warned if isinstance(warned, list) else []:  # a figure the recordings did not determine
        print(f"rfhoming radio-fit: warning: {line}", file=sys.stderr)
    print(json.dumps({"kind": "radio-fit", "profile": str(args.output), "recordings": ids, **report}))
    print(f"wrote radio profile {profile.name!r} ({len(fitted)} recording(s)) to {args.output}: "
          f"rfhoming demo --radio {args.output}", file=sys.stderr)
    return 0


def _ids(sources: list[str]) -> list[str]:
    """Each recording's id in the profile: its file's stem, numbered where two share one."""
    out: list[str] = []
    for source in sources:
        stem = Path(source.partition(":")[2] or source).stem or "recording"
        name, k = stem, 2
        while name in out:
            name, k = f"{stem}_{k}", k + 1
        out.append(name)
    return out
