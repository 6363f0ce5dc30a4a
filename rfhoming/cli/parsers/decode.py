"""``rfhoming decode`` and ``dissector``: the wire formats, without devices."""

from __future__ import annotations

import argparse

from rfhoming.cli.args import nonempty
from rfhoming.cli.parsers import command

PROTOCOLS = ("uconnect", "ublox-aoa", "frames", "rss", "esp-at", "h4", "hci", "ros2", "mavlink")
"""The device table's wire protocols and their old names (a test holds them equal), named here
so that building the parser loads no table."""

DECODE_HELP = """\
Decode raw bytes -- a file, a raw capture of a serial port, or stdin -- and print one JSON
object per decoded item: "kind" plus its fields, or kind "drop" with the reason. The last
line (kind "counters") counts every item kind and every drop reason.

examples:
  rfhoming decode --protocol uconnect board.log
  cat /dev/ttyACM0 | rfhoming decode --protocol uconnect -
  rfhoming decode --protocol frames node.bin | grep '"kind": "drop"'
"""

DISSECTOR_HELP = """\
Write a Wireshark/tshark Lua dissector for rfhoming's pcapng captures. It is generated from the
record declarations, so it always matches this version's decoder. Interfaces with link type
148 (binary records) are reassembled per direction, COBS-decoded, CRC-checked and shown field
by field, with drops marked by reason; link type 147 (XPLR-AOA text) shows as text lines.

examples:
  rfhoming dissector -o ~/.local/lib/wireshark/plugins/rfhoming.lua   # install for Wireshark
  rfhoming dissector -o rfhoming.lua && tshark -X lua_script:rfhoming.lua -r run.pcapng -O rfhoming
"""


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    decode = sub.add_parser(
        "decode",
        help="decode raw device bytes to JSON lines",
        description=DECODE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    decode.add_argument(
        "--protocol",
        required=True,
        choices=PROTOCOLS,
        metavar="PROTOCOL",
        help="uconnect: XPLR-AOA u-connectLocate text; frames: rfhoming's COBS binary records (nodes and the "
        "robot base); esp-at: Espressif ESP-AT text; h4: Bluetooth HCI packets over UART; ros2: one ROS 2 "
        "sample record (as a capture's packet holds it); mavlink: MAVLink 2 packets; the older names ublox-aoa, rss and hci still work",
    )
    decode.add_argument("file", type=nonempty, nargs="?", default="-", help="input file, or - for stdin")
    decode.set_defaults(func=command("decode"))
    dissector = sub.add_parser(
        "dissector",
        help="write the Wireshark Lua dissector for the binary records",
        description=DISSECTOR_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    dissector.add_argument("-o", "--output", type=nonempty, default="-", help="file to write (default: stdout)")
    dissector.set_defaults(func=command("dissector"))
