"""``rfhoming gateway``: a site's angle events to an MQTT broker.

The gateway is its own command, not ``serve --mqtt``: a gateway box runs nothing else, and serve
stays the robot's tool. The worker is ``locate`` with a broker for its source (parsers/locate.py):
the same command whether the angles come from the site's ports, a capture or the site bus, with
the worker's few options added to it (docs/usage.md, "Site").
"""

from __future__ import annotations

import argparse

from rfhoming.cli.args import broker_url, bus_name, duration, flush_s, nonempty, path, rate_hz, seed
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import add_login_arguments, add_port_defaults

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
  rfhoming gateway --site hall.toml --broker mqtts://gw-east@broker.local/8 --password-file gw.pass --ca ca.pem

A broker that refuses (a login, a certificate, TLS against a plaintext port) ends the gateway
at once with one line and exit 2; one that is away is tried again, 0.1 s doubling to 5 s.
"""

def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    g = sub.add_parser("gateway", help="a site gateway: its anchors' angle events to an MQTT broker",
                       description=GATEWAY_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    g.add_argument("--device", type=nonempty, action="append", metavar="SPEC",
                   help="an anchor's port, e.g. xplr-aoa:/dev/ttyUSB0 (repeatable; docs/usage.md, port specs)")
    g.add_argument("--site", type=path, metavar="FILE", help="a site file: its anchors' ports (unless --device), "
                   "its name for the topics")
    g.add_argument("--emulate", type=nonempty, metavar="site-NxM", help="every gateway of an emulated site (e.g. site-64x1000)")
    g.add_argument("--broker", type=broker_url, required=True, metavar="URL",
                   help="mqtt://[USER@]HOST[:PORT][/PARTITIONS] (mqtts:// = TLS)")
    g.add_argument("--site-name", type=bus_name, help="the SITE of the topics (default: the site file's or scenario's name)")
    g.add_argument("--name", type=bus_name, help="this gateway's name on the bus (default: the host name)")
    g.add_argument("--seed", type=seed, default=1, help="--emulate: the scenario's seed (default 1)")
    g.add_argument("--tag-rate", type=rate_hz, default=10.0, metavar="HZ",
                   help="--emulate: each tag's rate (default 10)")
    g.add_argument("--flush", type=flush_s, default=0.02, metavar="S",
                   help="seconds between a gateway's batches (default 0.02)")
    g.add_argument("--duration", type=duration, help="stop after this many seconds")
    add_login_arguments(g)
    add_port_defaults(g)
    g.set_defaults(func=command("gateway"))

