"""``rfhoming serve``: one process owns the devices and fans their items out to many clients."""

from __future__ import annotations

import argparse

from rfhoming.cli.args import clients, duration, nonempty, output_file, queue_lines, tcp_port
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import ENDPOINT_HELP, GROWING, add_foxglove_option, add_port_defaults, add_ros2_option

QUEUE_LINES = 1000
MAX_IDLE = 16
STALL_S = 30.0
"""host/serve.py's defaults (a test holds them equal), named here so that building the parsers
does not load the server."""
DEFAULT_PORT = 2948  # beside gpsd's 2947

SERVE_HELP = f"""\
Own the devices -- set them up, follow reboots, reconnect, capture -- and send every decoded
item to any number of clients as JSON lines over TCP (the form of `listen --json`, plus "n",
the item's number), after a "hello" line (protocol version, devices and their states), with a
"device" line whenever a device's state changes (disconnected, connected, ready, streaming).
Clients may send commands: {{"cmd": "watch", "devices": [...], "kinds": [...], "chatter": true}},
{{"cmd": "poll"}} (the latest readings), {{"cmd": "devices"}}, {{"cmd": "version"}}, or gpsd's
?WATCH={{...}}; ?POLL; ?DEVICES; ?VERSION; (docs/protocol.md, "serve"). The devices' AT set-up
chatter goes only to clients that ask for it. A client that reads too slowly loses items
(counted; it is sent a "dropped" line) and never holds up the devices or the other clients; one
that takes nothing while its queue overflows, or for --stall-s seconds, is disconnected. A
client that has sent no command is idle: one address keeps at most --max-idle of them (every
program on this machine is one address, 127.0.0.1), and another closes the one idle longest.
Listens on 127.0.0.1:{DEFAULT_PORT} unless told; prints each address it listens on as a JSON
line when it starts.

Clients: `rfhoming listen serve://127.0.0.1:{DEFAULT_PORT}`, the Python API with the same port
spec, or anything that reads lines from a socket (`nc 127.0.0.1 {DEFAULT_PORT}`).

examples:
  rfhoming serve xplr-aoa:/dev/ttyUSB0
  rfhoming serve /dev/ttyUSB0 base:/dev/ttyACM0 -o session.pcapng
  rfhoming serve auto --bind 0.0.0.0 --port 3000      # reachable from the network
  rfhoming serve /dev/ttyUSB0 --foxglove              # and the Foxglove WebSocket on :8765
  rfhoming listen serve://127.0.0.1:{DEFAULT_PORT} --json
"""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("serve", help="own the devices and serve their items to many clients (gpsd-style)",
                       description=SERVE_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("ports", type=nonempty, nargs="+", metavar="PORT", help=ENDPOINT_HELP)
    add_port_defaults(p)
    p.add_argument("--bind", type=nonempty, action="append", metavar="ADDR",
                   help="address to listen on (default 127.0.0.1; repeat for several, 0.0.0.0 for all)")
    p.add_argument("--port", type=tcp_port, default=DEFAULT_PORT, help=f"TCP port (default {DEFAULT_PORT}; 0 = any free)")
    p.add_argument("--queue", type=queue_lines, default=QUEUE_LINES, metavar="LINES",
                   help=f"items held for a slow client before its newest are dropped (default {QUEUE_LINES})")
    p.add_argument("--max-idle", type=clients, default=MAX_IDLE, metavar="N",
                   help=f"clients of one address that have sent no command, at most (default {MAX_IDLE}); "
                        "another one closes the one idle longest")
    p.add_argument("--stall-s", type=duration, default=STALL_S, metavar="S",
                   help=f"a client that takes nothing of what waits for it this long is disconnected (default {STALL_S:g})")
    p.add_argument("-o", "--output", type=output_file,
                   help="also capture every byte of the devices to this pcapng file" + GROWING)
    p.add_argument("--duration", type=duration, help="stop after this many seconds")
    add_foxglove_option(p)
    add_ros2_option(p, "the devices' readings")
    p.set_defaults(func=command("serve"))
