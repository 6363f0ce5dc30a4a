"""``rfhoming locate SITE --from mqtt://...``: a site worker -- the tags of the partitions it owns
among the live workers, fixed per tick and published to the broker."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rfhoming.cli.signals import stop_on_signals
from rfhoming.host import site as site_file
from rfhoming.host.site import Anchor, Site
from rfhoming.protocol import sitebus


def emulated_site(name: str, seed: int) -> Site:
    """The host's view of an emulated site: where the anchors are, nothing of their errors."""
    from rfhoming.emulator.site import SiteScenario

    sc = SiteScenario.named(name, seed=seed)
    return Site(name, tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg, angle_model="spherical")
                            for a in sc.anchors), sigma_deg=sc.sigma_deg, az_compression=0.0)  # the emulator's boards


def resolve_site(text: str, seed: int) -> Site:
    return site_file.load(text) if Path(text).suffix == ".toml" else emulated_site(text, seed)


NOT_WITH_A_BROKER = {"capture": "--capture", "smooth": "--smooth", "output": "-o", "height_sigma": "--height-sigma"}
"""locate's options that a site worker does not take (it publishes to the broker, causally)."""


def run(args: argparse.Namespace) -> int:
    """``rfhoming locate SITE --from mqtt://...``."""
    from rfhoming.host.sitebus import Broker, Worker  # paho-mqtt: the "site" extra

    given = [flag for key, flag in NOT_WITH_A_BROKER.items() if getattr(args, key, None)]
    if args.tracker not in (None, "cv") or args.loss != "huber":
        given.append(f"--tracker {args.tracker}" if args.tracker not in (None, "cv") else f"--loss {args.loss}")
    if len(args.sources) > 1 or given:
        print("rfhoming locate: --from mqtt:// is the one source of a site worker, which tracks with the batched "
              f"cv filter and publishes to the broker; leave out {', '.join(given) or 'the other --from'}",
              file=sys.stderr)
        return 2
    broker = Broker.parse(args.sources[0]).login(args.password_file)
    site = resolve_site(str(args.site), args.seed)
    partitions = broker.partitions or sitebus.DEFAULT_PARTITIONS
    worker = Worker(site, broker, worker_id=args.id, partitions=partitions, rate_hz=args.rate,
                    reorder_s=args.reorder, track=not args.no_track, ca_file=args.ca)
    stop = stop_on_signals()
    try:
        worker.run(args.duration, stop)
    finally:
        try:
            worker.close()
        finally:
            print(json.dumps({"kind": "worker", "id": args.id, **worker.health()}), flush=True)
    return 0
