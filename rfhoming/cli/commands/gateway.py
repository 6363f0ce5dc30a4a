"""``rfhoming gateway``: a site's angle events to an MQTT broker, from its anchors' ports or from
every gateway of an emulated site."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import TYPE_CHECKING

from rfhoming.cli.signals import stop_on_signals
from rfhoming.cli.site_sources import gather
from rfhoming.host import site as site_file
from rfhoming.host.site import Site
from rfhoming.protocol import sitebus

if TYPE_CHECKING:
    from rfhoming.host.bearing import Bearing
    from rfhoming.host.sitebus import Publisher  # paho-mqtt: the "site" extra, imported when used

STOP_CHECK_S = 0.2
"""How long a gateway waits on its socket before it looks at the stop event again."""


def run(args: argparse.Namespace) -> int:
    if (args.emulate is None) == (args.device is None and args.site is None):
        print("rfhoming gateway: give the anchors (--device SPEC ... or --site FILE) or --emulate site-NxM",
              file=sys.stderr)
        return 2
    return _emulated_gateways(args) if args.emulate else _device_gateway(args)


def _device_gateway(args: argparse.Namespace) -> int:
    """The anchors of --device/--site through the normal drivers (locate's opening and errors)."""
    import asyncio
    import contextlib
    import socket

    from rfhoming.host.sitebus import Broker, Gateway, Publisher

    broker = Broker.parse(args.broker).login(args.password_file)
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

    def on_angle(reading: Bearing) -> None:
        nonlocal flushing
        gw.on_bearing(reading)
        if not flushing:  # the first event: from now on a batch every --flush seconds
            flushing = True
            loop = asyncio.get_running_loop()

            def flush() -> None:
                gw.flush(time.time())  # the ports' clock (host/ports.py): the events' times are on it
                loop.call_later(args.flush, flush)

            loop.call_later(args.flush, flush)

    async def until_refused() -> int:
        """gather's run, ended early (as Ctrl-C ends it) if the broker refuses for good."""
        task = asyncio.create_task(gather("gateway", site, args.device, on_angle, baud=args.baud, flow=args.flow,
                                          duration=args.duration))
        loop = asyncio.get_running_loop()

        def cancel() -> None:  # on paho's thread
            with contextlib.suppress(RuntimeError):  # the run has ended, its loop closed
                loop.call_soon_threadsafe(task.cancel)

        pub.when_refused(cancel)
        try:
            return await task
        except asyncio.CancelledError:
            if pub.failure is None:
                raise
            return 2

    try:
        code = asyncio.run(until_refused())
        if pub.failure is not None:
            raise pub.failure
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

    broker = Broker.parse(args.broker).login(args.password_file)
    partitions = broker.partitions or sitebus.DEFAULT_PARTITIONS
    sc = SiteScenario.named(args.emulate, seed=args.seed, tag_rate_hz=args.tag_rate)
    site = sitebus.check_level("--site-name", args.site_name or args.emulate)
    # one connection for all of them: they are one process here (a real gateway box has its own),
    # and 16 paho network threads cost more CPU than the emulation itself
    pub = Publisher(broker, f"rfhoming-gw-{site}-{args.seed}", ca_file=args.ca, threaded=False)
    gws = {g: Gateway(pub, site, g, partitions) for g in sc.gateways}
    stop = stop_on_signals()
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
