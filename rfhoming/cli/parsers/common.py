"""Options that several commands share: the ports' defaults, --foxglove, --ros2, the demo's
watch options, the site bus's broker login."""

from __future__ import annotations

import argparse
import math

from rfhoming.cli.args import baud, delay, expanded, nonempty, tcp_port
from rfhoming.protocol.credentials import PASSWORD_ENV

KINDS = ("xplr-aoa", "rss-node", "esp-at", "hci", "base", "ros2", "mavlink")
"""The device table's kinds (a test holds them equal), named here so the parsers load no table."""
ENDPOINT_HELP = ("port spec [KIND:]WHERE[,key=value...]: WHERE is a path, socket://HOST:PORT or auto; KIND "
                 f"({', '.join(KINDS)}) skips sniffing; settings baud=, flow=rtscts|none, tags=ID+ID, name=; "
                 "capture:FILE replays a recording; serve://HOST:PORT is the devices of an `rfhoming serve` "
                 "(see docs/usage.md)")

GROWING = " (FILE.part while it runs -- tail -f that -- renamed to FILE when it ends)"
"""Said of every output that grows as a command runs (host/outputs.py, docs/usage.md "Output files")."""
FOXGLOVE_PORT = 8765  # Foxglove's own default (rfhoming.host.foxglove_view.DEFAULT_PORT)
FOXGLOVE_HELP = (f"also serve a live view on ws://127.0.0.1:PORT (default {FOXGLOVE_PORT}, 0 = any free port) to "
                 "Foxglove or Lichtblick (subprotocol foxglove.websocket.v1 or foxglove.sdk.v1); "
                 "in Foxglove open a WebSocket connection to it and import the layout "
                 "rfhoming/host/foxglove_layout.json; needs the foxglove extra")
WAIT_S = 60.0

IDEAL, MEASURED = "ideal", "measured"
RADIOS = (IDEAL, MEASURED, "carried")
"""protocol/radio_profile.py's RADIOS (a test holds them equal), named here so the parsers load no profile."""
RADIO_HELP = ("the emulated radios' errors: measured (the project's profile, fitted to real recordings: "
              "docs/emulator.md, \"Radio profiles\"), carried (a tag a person carries and stands with: long "
              "stops, errors that stay put while they stand, built from the 2026-12 field report's statistics), ideal (each scenario's own idealised noise, its paper's "
              "set-up) or a profile file that `rfhoming radio-fit` wrote from your own room's recordings; default: {}")


def add_port_defaults(p: argparse.ArgumentParser) -> None:
    """--baud, --flow and --probe-baud: defaults for every port whose spec does not set its own."""
    p.add_argument("--baud", type=baud, metavar="RATE",
                   help="serial rate for ports whose spec gives no baud= (default 115200)")
    p.add_argument("--flow", choices=("auto", "rtscts", "none"),
                   help="RTS/CTS for ports whose spec gives no flow=: auto (default) = on for the XPLR-AOA "
                        "(its documented default), off for the others")
    p.add_argument("--probe-baud", action="store_true",
                   help="if an XPLR-AOA sends only garbage, try each rate it documents until it answers AT")


def add_watch_options(p: argparse.ArgumentParser) -> None:
    """The demo's options for a person watching: wait for the viewer, stay up after the run."""
    p.add_argument("--wait-viewer", type=delay, default=WAIT_S, metavar="S",
                   help=f"with --foxglove: start the run when a viewer subscribes, or after S seconds "
                   f"(default {WAIT_S:g}; 0 = at once)")
    p.add_argument("--linger", type=delay, default=math.inf, metavar="S",
                   help="with --foxglove: keep the view up S seconds after the run (default: until Ctrl-C)")


def add_foxglove_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--foxglove", nargs="?", const=FOXGLOVE_PORT, type=tcp_port, metavar="PORT", help=FOXGLOVE_HELP)


def add_ros2_option(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--ros2", type=nonempty, nargs="?", const="", metavar="domain=N[,discovery=subnet]",
                   help=f"publish {what} live on ROS 2 domain N (default 0): the MCAP recording's topics and "
                        "types, REP 105 frames, stamped on this host's clock; the loop's commands on "
                        "/rfhoming/cmd_vel; this machine only unless discovery=subnet; needs the ros and ros2 extras")


def add_login_arguments(p: argparse._ActionsContainer) -> None:
    """--password-file and --ca: the site bus's broker login and TLS (gateway, locate --from mqtt://)."""
    p.add_argument("--password-file", type=nonempty, metavar="FILE",
                   help="the broker login's password: the first line of FILE (the user is the URL's USER@). Or "
                        f"set ${PASSWORD_ENV}. Not in the URL: a command line is visible to every user in ps")
    p.add_argument("--ca", type=nonempty, metavar="PEM", help="CA certificate for mqtts:// (default: the system's)")


def radio(text: str) -> str:
    """``--radio``: a profile's name, or a profile file that exists (read when the scenario is built)."""
    if text in RADIOS:
        return text
    file = expanded(text)
    if not file.is_file():
        raise argparse.ArgumentTypeError(f"{text!r}: give {' or '.join(RADIOS)}, or a radio profile file "
                                         "(rfhoming radio-fit writes one)")
    return str(file)


def add_radio_option(p: argparse.ArgumentParser, default: str | None, said: str) -> None:
    """``--radio``: ``default`` (None: the command picks; ``said`` tells the user which)."""
    p.add_argument("--radio", type=radio, default=default, metavar="measured|carried|ideal|PROFILE",
                   help=RADIO_HELP.format(said))
