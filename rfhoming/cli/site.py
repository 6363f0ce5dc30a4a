"""``rfhoming gateway`` and ``rfhoming locate SITE --from mqtt://``: a site's angle events over an MQTT broker.

The gateway is its own command, not ``serve --mqtt``: a gateway box runs nothing else, and serve
stays the robot's tool. The worker is ``locate`` with a broker for its source (the issue's form):
the same command whether the angles come from the site's ports, a capture or the site bus, with
the worker's few options added to it (docs/usage.md, "Site").
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from rfhoming.cli.args import broker_url, bus_name, duration, flush_s, nonempty, path, rate_hz, reorder_s, seed
from rfhoming.cli.io import add_port_defaults
from rfhoming.host import site as site_file
from rfhoming.host.site import Anchor, Site
from rfhoming.protocol import sitebus

if TYPE_CHECKING:
    from rfhoming.host.sitebus import Publisher  # paho-mqtt: the "site" extra, imported when used

GATEWAY_HELP = """\
A site gateway: the XPLR-AOA anchors on this machine's ports (--device SPEC, repeatable, or the
ports of a site file's anchors with --site FILE), opened and set up by the normal driver, their
decoded angle events published to the broker as the site bus of docs/protocol.md (batches every
--flush seconds, one topic per partition; buffered boundedly while the broker is away). Or
--emulate site-NxM: every gateway of an emulated site (emulator/site.py: N ceiling anchors, four
per gateway, M moving tags, each gateway with its own clock offset) -- no ptys, no devices.
On exit one "gateway" JSON line of counters.

examples:
  rfhoming gateway --site docs/sites/kit-room.toml --broker mqtt://broker.local/8 --name gw-east
  rfhoming gateway --device xplr-aoa:/dev/ttyUSB0 --device xplr-aoa:/dev/ttyUSB1 --site-name hall --broker mqtt://broker.local/8
  rfhoming gateway --emulate site-64x1000 --broker mqtt://127.0.0.1:1883/8 --duration 60
"""

WORKER_HELP = """\
With --from mqtt://BROKER[:PORT][/PARTITIONS] (mqtts:// = TLS, mqtt://user:pw@... a login),
locate is a site worker: it subscribes to the partitions it owns among the live workers
(rendezvous hashing; a worker that goes, its will tells the others, who take its partitions),
measures each gateway's clock offset, fixes every tag per tick with the batched engine and
publishes each position as JSON on rfhoming/SITE/positions/TAG; on exit it prints one "worker"
line of counters. SITE is then a site file or an emulated site name (site-64x1000).

  rfhoming locate site-64x1000 --from mqtt://127.0.0.1:1883/8 --id w1
  rfhoming locate docs/sites/kit-room.toml --from mqtts://user:pw@broker.example/8 --ca ca.pem
"""


def emulated_site(name: str, seed: int) -> Site:
    """The host's view of an emulated site: where the anchors are, nothing of their errors."""
    from rfhoming.emulator.site import SiteScenario

    sc = SiteScenario.named(name, seed=seed)
    return Site(name, tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg) for a in sc.anchors),
                sigma_deg=sc.sigma_deg)


def resolve_site(text: str, seed: int) -> Site:
    return site_file.load(text) if Path(text).suffix == ".toml" else emulated_site(text, seed)


STOP_CHECK_S = 0.2
"""How long a gateway waits on its socket before it looks at the stop event again."""


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def cmd_gateway(args: argparse.Namespace) -> int:
    if (args.emulate is None) == (args.device is None and args.site is None):
        print("rfhoming gateway: give the anchors (--device SPEC ... or --site FILE) or --emulate site-NxM",
              file=sys.stderr)
        return 2
    return _emulated_gateways(args) if args.emulate else _device_gateway(args)


def _device_gateway(args: argparse.Namespace) -> int:
    """The anchors of --device/--site through the normal drivers (locate's opening and errors)."""
    import asyncio
    import socket

    from rfhoming.cli.locate import _gather
    from rfhoming.host.sitebus import Broker, Gateway, Publisher

    broker = Broker.parse(args.broker)
    site = site_file.load(args.site) if args.site else Site(args.site_name or "", ())
    name = args.site_name or site.name
    if not name:
        print("rfhoming gateway: name the site of the topics with --site-name (or give --site FILE)", file=sys.stderr)
        return 2
    gw_name = args.name or socket.gethostname()
    sitebus.check_level("--site-name", name)
    sitebus.check_level("--name", gw_name)
    pub = Publisher(broker, f"rfhoming-gw-{name}-{gw_name}", ca_file=args.ca)
    gw = Gateway(pub, name, gw_name, broker.partitions or sitebus.DEFAULT_PARTITIONS)
    flushing = False

    def on_angle(t: float, event: object) -> None:
        nonlocal flushing
        gw.on_item("", t, event)
        if not flushing:  # the first event: from now on a batch every --flush seconds
            flushing = True
            loop = asyncio.get_running_loop()

            def flush() -> None:
                gw.flush(time.time())  # the ports' clock (host/ports.py): the events' times are on it
                loop.call_later(args.flush, flush)

            loop.call_later(args.flush, flush)

    gather = argparse.Namespace(command="gateway", sources=args.device, baud=args.baud, flow=args.flow,
                                duration=args.duration, capture=None)
    try:
        code = asyncio.run(_gather(gather, site, on_angle))
        gw.flush(time.time())
    finally:
        try:
            pub.close()
        finally:
            print(json.dumps({"kind": "gateway", "name": gw_name, "site": name, "events": gw.events,
                              **_publish_counters(pub)}), flush=True)
    return code


def _publish_counters(pub: Publisher) -> dict[str, int]:
    return {k: pub.counters[k] for k in ("published", "buffered", "dropped", "unsent", "connects")}


def _emulated_gateways(args: argparse.Namespace) -> int:
    from rfhoming.emulator.site import SiteScenario
    from rfhoming.host.sitebus import Broker, Gateway, Publisher

    broker = Broker.parse(args.broker)
    partitions = broker.partitions or sitebus.DEFAULT_PARTITIONS
    sc = SiteScenario.named(args.emulate, seed=args.seed, tag_rate_hz=args.tag_rate)
    site = sitebus.check_level("--site-name", args.site_name or args.emulate)
    # one connection for all of them: they are one process here (a real gateway box has its own),
    # and 16 paho network threads cost more CPU than the emulation itself
    pub = Publisher(broker, f"rfhoming-gw-{site}-{args.seed}", ca_file=args.ca, threaded=False)
    gws = {g: Gateway(pub, site, g, partitions) for g in sc.gateways}
    stop = _stop_on_signals()
    start = t0 = time.time()  # at once, broker or not: what it cannot take waits in the buffer
    cpu0 = time.process_time()
    behind = 0
    end = math.inf if args.duration is None else start + args.duration
    try:
        while not stop.is_set() and t0 < end:
            # the socket served in slices, so that --duration and a signal end the wait promptly
            while (left := min(t0 + args.flush, end) - time.time()) > 0 and not stop.is_set():
                pub.service(min(left, STOP_CHECK_S))
            t1 = time.time() if args.duration is None else min(time.time(), start + args.duration)
            for g, (t, a, k, az, el) in sc.columns(t0, t1).items():
                gw = gws[g]
                gw.add_columns(t, sc.anchor_ids, a, sc.tags, k, az, el)
                gw.flush(t1 + sc.clock_offsets[g])
            if time.time() - t1 > args.flush:
                behind += 1
            t0 = t1
    finally:
        try:
            pub.close()
        finally:
            print(json.dumps({"kind": "gateways", "gateways": len(gws), "events": sum(g.events for g in gws.values()),
                              "behind": behind, "cpu_s": round(time.process_time() - cpu0, 3),
                              **_publish_counters(pub)}), flush=True)
    return 0


def is_broker(spec: str) -> bool:
    return spec.startswith(("mqtt://", "mqtts://"))


NOT_WITH_A_BROKER = {"capture": "--capture", "smooth": "--smooth", "output": "-o", "height_sigma": "--height-sigma"}
"""locate's options that a site worker does not take (it publishes to the broker, causally)."""


def cmd_worker(args: argparse.Namespace) -> int:
    """``rfhoming locate SITE --from mqtt://...``."""
    from rfhoming.host.sitebus import Broker, Worker  # paho-mqtt: the "site" extra

    given = [flag for key, flag in NOT_WITH_A_BROKER.items() if getattr(args, key, None)]
    if args.tracker != "cv" or args.loss != "huber":
        given.append(f"--tracker {args.tracker}" if args.tracker != "cv" else f"--loss {args.loss}")
    if len(args.sources) > 1 or given:
        print("rfhoming locate: --from mqtt:// is the one source of a site worker, which tracks with the batched "
              f"cv filter and publishes to the broker; leave out {', '.join(given) or 'the other --from'}",
              file=sys.stderr)
        return 2
    broker = Broker.parse(args.sources[0])
    site = resolve_site(str(args.site), args.seed)
    partitions = broker.partitions or sitebus.DEFAULT_PARTITIONS
    worker = Worker(site, broker, worker_id=args.id, partitions=partitions, rate_hz=args.rate,
                    reorder_s=args.reorder, track=not args.no_track, ca_file=args.ca)
    stop = _stop_on_signals()
    try:
        worker.run(args.duration, stop)
    finally:
        try:
            worker.close()
        finally:
            print(json.dumps({"kind": "worker", "id": args.id, **worker.health()}), flush=True)
    return 0


def add_worker_arguments(p: argparse.ArgumentParser) -> None:
    """The worker's options on ``locate`` (used with --from mqtt:// only)."""
    w = p.add_argument_group("site worker (with --from mqtt://BROKER[/PARTITIONS])", WORKER_HELP)
    w.add_argument("--id", type=bus_name, default="w1", help="this worker's name among the site's workers (default w1)")
    w.add_argument("--reorder", type=reorder_s, default=0.02, metavar="S",
                   help="seconds a tick waits for late batches (default 0.02)")
    w.add_argument("--seed", type=seed, default=1, help="an emulated site's seed (default 1)")
    w.add_argument("--ca", type=nonempty, metavar="PEM", help="CA certificate for mqtts:// (default: the system's)")


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    g = sub.add_parser("gateway", help="a site gateway: its anchors' angle events to an MQTT broker",
                       description=GATEWAY_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    g.add_argument("--device", type=nonempty, action="append", metavar="SPEC",
                   help="an anchor's port, e.g. xplr-aoa:/dev/ttyUSB0 (repeatable; docs/usage.md, port specs)")
    g.add_argument("--site", type=path, metavar="FILE", help="a site file: its anchors' ports (unless --device), "
                   "its name for the topics")
    g.add_argument("--emulate", type=nonempty, metavar="site-NxM", help="every gateway of an emulated site (e.g. site-64x1000)")
    g.add_argument("--broker", type=broker_url, required=True, metavar="URL", help="mqtt://HOST[:PORT][/PARTITIONS] (mqtts:// = TLS)")
    g.add_argument("--site-name", type=bus_name, help="the SITE of the topics (default: the site file's or scenario's name)")
    g.add_argument("--name", type=bus_name, help="this gateway's name on the bus (default: the host name)")
    g.add_argument("--seed", type=seed, default=1, help="--emulate: the scenario's seed (default 1)")
    g.add_argument("--tag-rate", type=rate_hz, default=10.0, metavar="HZ",
                   help="--emulate: each tag's rate (default 10)")
    g.add_argument("--flush", type=flush_s, default=0.02, metavar="S",
                   help="seconds between a gateway's batches (default 0.02)")
    g.add_argument("--duration", type=duration, help="stop after this many seconds")
    g.add_argument("--ca", type=nonempty, metavar="PEM", help="CA certificate for mqtts:// (default: the system's)")
    add_port_defaults(g)
    g.set_defaults(func=cmd_gateway)

