"""``rfhoming gateway`` and ``rfhoming locate-worker``: a site's angle events over an MQTT broker.

Separate commands, not ``serve --mqtt`` or ``locate --from``: a site gateway or worker is its own
process on its own machine with its own lifetime (started per gateway box, several workers per
broker), and serve/locate stay the one-machine tools they are (docs/usage.md, "Site").
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time
from pathlib import Path

from rfhoming.cli.args import nonnegative_float, positive_float
from rfhoming.host import site as site_file
from rfhoming.host.site import Anchor, Site
from rfhoming.protocol import sitebus

GATEWAY_HELP = """\
Emulated gateways of a site scenario (emulator/site.py): N ceiling anchors, four per gateway, M
moving tags, each gateway with its own clock offset, publishing the angle events its anchors
hear in real time to the broker as the site bus of docs/protocol.md -- no ptys, no devices.

examples:
  rfhoming gateway --emulate site-64x1000 --broker mqtt://127.0.0.1:1883/8 --duration 60
  rfhoming gateway --emulate site-16x50 --broker mqtt://127.0.0.1 --tag-rate 5
"""

WORKER_HELP = """\
A locate worker: subscribes to the partitions it owns among the live workers (rendezvous
hashing; a worker that goes, its will tells the others, who take its partitions), measures each
gateway's clock offset, fixes every tag per tick with the batched engine and publishes each
position as JSON on rfhoming/SITE/positions/TAG. SITE is a site file or an emulated site name.

examples:
  rfhoming locate-worker site-64x1000 --from mqtt://127.0.0.1:1883/8 --id w1
  rfhoming locate-worker docs/sites/kit-room.toml --from mqtts://user:pw@broker.example/8 --ca ca.pem
"""


def emulated_site(name: str, seed: int) -> Site:
    """The host's view of an emulated site: where the anchors are, nothing of their errors."""
    from rfhoming.emulator.site import SiteScenario

    sc = SiteScenario.named(name, seed=seed)
    return Site(name, tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg) for a in sc.anchors),
                sigma_deg=sc.sigma_deg)


def resolve_site(text: str, seed: int) -> Site:
    return site_file.load(text) if Path(text).suffix == ".toml" else emulated_site(text, seed)


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def cmd_gateway(args: argparse.Namespace) -> int:
    from rfhoming.emulator.site import SiteScenario
    from rfhoming.host.sitebus import Broker, Gateway, Publisher

    broker = Broker.parse(args.broker)
    partitions = broker.partitions or sitebus.DEFAULT_PARTITIONS
    sc = SiteScenario.named(args.emulate, seed=args.seed, tag_rate_hz=args.tag_rate)
    site = args.site_name or args.emulate
    # one connection for all of them: they are one process here (a real gateway box has its own),
    # and 16 paho network threads cost more CPU than the emulation itself
    pub = Publisher(broker, f"rfhoming-gw-{site}-{args.seed}", ca_file=args.ca, threaded=False)
    gws = {g: Gateway(pub, site, g, partitions) for g in sc.gateways}
    stop = _stop_on_signals()
    pub.wait_connected(10)
    start = t0 = time.time()
    cpu0 = time.process_time()
    behind = 0
    try:
        while not stop.is_set() and (args.duration is None or t0 < start + args.duration):
            while (left := t0 + args.flush - time.time()) > 0 and not stop.is_set():
                pub.service(left)
            t1 = time.time()
            for g, (t, a, k, az, el) in sc.columns(t0, t1).items():
                gw = gws[g]
                gw.add_columns(t, sc.anchor_ids, a, sc.tags, k, az, el)
                gw.flush(t1 + sc.clock_offsets[g])
            if time.time() - t1 > args.flush:
                behind += 1
            t0 = t1
    finally:
        pub.close()
        total = {k: pub.counters[k] for k in ("published", "buffered", "dropped")}
        print(json.dumps({"kind": "gateways", "gateways": len(gws), "events": sum(g.events for g in gws.values()),
                          "behind": behind, "cpu_s": round(time.process_time() - cpu0, 3), **total}), flush=True)
    return 0


def cmd_worker(args: argparse.Namespace) -> int:
    from rfhoming.host.sitebus import Broker, Worker  # paho-mqtt: the "site" extra
    broker = Broker.parse(args.source)
    site = resolve_site(args.site, args.seed)
    partitions = broker.partitions or sitebus.DEFAULT_PARTITIONS
    worker = Worker(site, broker, worker_id=args.id, partitions=partitions, rate_hz=args.rate,
                    reorder_s=args.reorder, track=not args.fixes_only, ca_file=args.ca)
    stop = _stop_on_signals()
    try:
        worker.run(args.duration, stop)
    finally:
        worker.close()
        print(json.dumps({"kind": "worker", "id": args.id, **worker.health()}), flush=True)
    return 0


def add_parsers(sub: argparse._SubParsersAction) -> None:
    g = sub.add_parser("gateway", help="emulated site gateways publishing angle events to an MQTT broker",
                       description=GATEWAY_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    g.add_argument("--emulate", required=True, metavar="site-NxM", help="the site scenario (e.g. site-64x1000)")
    g.add_argument("--broker", required=True, metavar="URL", help="mqtt://HOST[:PORT][/PARTITIONS] (mqtts:// = TLS)")
    g.add_argument("--site-name", help="the SITE of the topics (default: the scenario name)")
    g.add_argument("--seed", type=int, default=1, help="the scenario's seed (default 1)")
    g.add_argument("--tag-rate", type=positive_float, default=10.0, metavar="HZ", help="each tag's rate (default 10)")
    g.add_argument("--flush", type=positive_float, default=0.02, metavar="S",
                   help="seconds between a gateway's batches (default 0.02)")
    g.add_argument("--duration", type=positive_float, help="stop after this many seconds")
    g.add_argument("--ca", metavar="PEM", help="CA certificate for mqtts:// (default: the system's)")
    g.set_defaults(func=cmd_gateway)
    w = sub.add_parser("locate-worker", help="locate tags from a site's MQTT angle events, publish positions",
                       description=WORKER_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    w.add_argument("site", metavar="SITE", help="site file (.toml) or emulated site name (site-64x1000)")
    w.add_argument("--from", dest="source", required=True, metavar="URL", help="mqtt://HOST[:PORT][/PARTITIONS]")
    w.add_argument("--id", default="w1", help="this worker's name among the site's workers (default w1)")
    w.add_argument("--rate", type=positive_float, metavar="HZ", help="output ticks per second (default: the site's)")
    w.add_argument("--reorder", type=nonnegative_float, default=0.02, metavar="S",
                   help="seconds a tick waits for late batches (default 0.02)")
    w.add_argument("--fixes-only", action="store_true",
                   help="publish each tick's fixes, without the constant-velocity tracker")
    w.add_argument("--seed", type=int, default=1, help="an emulated site's seed (default 1)")
    w.add_argument("--duration", type=positive_float, help="stop after this many seconds")
    w.add_argument("--ca", metavar="PEM", help="CA certificate for mqtts://")
    w.set_defaults(func=cmd_worker)

