"""``rfhoming devices``, ``listen``, ``capture`` and ``replay``: the host I/O commands."""

from __future__ import annotations

import argparse

from rfhoming.cli.args import delay, duration, nonempty, output_file, path, speed
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import ENDPOINT_HELP, GROWING, add_foxglove_option, add_port_defaults, add_ros2_option

CONTROLLERS = ("aoa", "dock", "rss", "trilat", "survey", "anchors")
"""The homing methods, host/homing/assembly.py's METHODS (a test holds them equal): named here
so that building the parsers does not load the homing loop."""

LISTEN_HELP = """\
Open each device like the robot would -- set the XPLR-AOA up, follow reboots, reconnect
after an unplug -- and print every decoded item as it arrives (text, or --json lines).
On exit (Ctrl-C or --duration) one counters line per device. Exit status 2, with a message
naming the device, when a port cannot be opened or a device's first set-up fails or takes
longer than 20 s (XPLR-AOA) / 5 s (others).

examples:
  rfhoming listen /dev/ttyACM0
  rfhoming listen xplr-aoa:/dev/ttyUSB0,baud=1000000,tags=CCF9578E0D8A
  rfhoming listen xplr-aoa:/tmp/rfhoming-x/aoa rss-node:socket://127.0.0.1:40123 --json
  rfhoming listen auto --duration 10
  rfhoming listen capture:run.pcapng --json
  rfhoming listen serve://127.0.0.1:2948 --json     # beside other clients of `rfhoming serve`
  rfhoming listen /dev/ttyACM0 --foxglove           # and watch the readings in Foxglove
"""

REPLAY_HELP = """\
Feed a capture's recorded inbound bytes through the same decoders and drivers as live and
print the decoded items (the same output `rfhoming listen` printed when it was recorded).
With --pty, serve the capture on pseudo-terminals instead, paced by its timestamps, so any
program can consume it as if the devices were plugged in.

examples:
  rfhoming replay run.pcapng --json
  rfhoming replay run.pcapng --speed 1
  rfhoming replay run.pcapng --pty
  rfhoming replay damaged.pcapng --partial
  rfhoming replay rfhoming-demo/capture.pcapng --run --log replayed.jsonl   # the homing run again
  rfhoming replay run.pcapng --run --config other.toml     # another config on the same bytes

With --run, a capture of `rfhoming run` or `demo` runs its homing loop again: every device's
recorded inbound bytes in their recorded global order, the loop's writes matched against the
recording, with the controller and config the capture recorded (or --controller/--config).
The run log is the live run's, line for line; where the replayed loop first writes otherwise
than the recording, one line says where and what, and the replay goes on from the recorded
inputs. The summary is `run`'s, with a "replay" object (diverged, unanswered, first_divergence).

A malformed capture gives one line naming the byte offset and the problem, and exit code 2;
with --partial, the blocks before it are replayed (exit 0) and the problem is reported.
"""


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("devices", help="list serial ports and what each seems to be",
                       description="List the serial ports this machine sees and what each probably is, from "
                                   "its USB ids (the XPLR-AOA's FTDI bridge, ESP32 bridges, ST's VCP).")
    p.add_argument("--json", action="store_true", help="one JSON object per port (or kind)")
    p.add_argument("--kinds", action="store_true",
                   help="list the device kinds and what each reports instead (AoA boards: azimuths, elevation, "
                        "RSSI, rate)")
    p.set_defaults(func=command("devices"))

    for name, helptext in (("listen", "show live decoded records from devices"),
                           ("capture", "record every byte on devices to a pcapng file")):
        p = sub.add_parser(name, help=helptext, description=LISTEN_HELP if name == "listen" else
                           "Like listen, but record every byte both ways, raw, with µs timestamps, to a "
                           "pcapng file (one interface per device; opens in tshark/Wireshark).\n\n"
                           "example:\n  rfhoming capture /tmp/rfhoming-x/aoa base:/tmp/rfhoming-x/base -o run.pcapng",
                           formatter_class=raw)
        p.add_argument("ports", type=nonempty, nargs="+", metavar="PORT", help=ENDPOINT_HELP)
        add_port_defaults(p)
        p.add_argument("--duration", type=duration, help="stop after this many seconds")
        p.add_argument("--json", action="store_true", help="one JSON object per item")
        add_ros2_option(p, "the decoded readings")
        if name == "capture":
            p.add_argument("-o", "--output", type=output_file, required=True, help="pcapng file to write" + GROWING)
            p.add_argument("--show", action="store_true", help="also print the decoded items")
            p.set_defaults(func=command("listen", "run_capture"))
        else:
            add_foxglove_option(p)
            p.set_defaults(func=command("listen"))

    p = sub.add_parser("replay", help="replay a pcapng capture through the drivers, or on ptys",
                       description=REPLAY_HELP, formatter_class=raw)
    p.add_argument("capture", type=path, help="the pcapng file (from rfhoming capture or run --capture)")
    p.add_argument("--speed", type=speed, default=0.0, help="1 = recorded pace, 0 = as fast as possible (default)")
    p.add_argument("--json", action="store_true", help="one JSON object per item")
    p.add_argument("--pty", action="store_true", help="serve the capture on pseudo-terminals")
    p.add_argument("--partial", action="store_true",
                   help="on a malformed block, replay what was readable before it instead of refusing")
    p.add_argument("--link-dir", type=path, help="with --pty: directory for the pty symlinks")
    p.add_argument("--start-delay", type=delay, default=1.0,
                   help="with --pty: seconds to wait before playing, so consumers can open the ptys (default 1)")
    p.add_argument("--run", action="store_true", help="run the recorded homing loop again on the capture's bytes")
    p.add_argument("--config", type=path, help="with --run: this config instead of the recorded one")
    p.add_argument("--controller", choices=CONTROLLERS, help="with --run: this controller instead of the recorded one")
    p.add_argument("--log", type=output_file, help="with --run: write the replayed run log here" + GROWING)
    p.set_defaults(func=command("replay"))
