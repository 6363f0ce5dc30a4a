"""Port spec settings: one parser per ``key=value`` a device kind takes (text -> value; a
ValueError says what is allowed).

The parsers are pure functions, so the device table (protocol/devices.py) can name the ones
each kind takes in its record; host/portspec.py applies them. The groups below are what
several kinds share.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

Parser = Callable[[str], Any]

TAG_ID = re.compile(r"[0-9A-F]{12}")
FLOWS = ("rtscts", "none", "auto")


def baud(text: str) -> int:
    if not text.isdigit() or not 300 <= int(text) <= 4_000_000:
        raise ValueError("a whole number of baud from 300 to 4000000, e.g. baud=115200")
    return int(text)


def flow(text: str) -> str:
    if text not in FLOWS:
        raise ValueError("rtscts (hardware flow control), none, or auto (on for the XPLR-AOA only)")
    return text


def tags(text: str) -> tuple[str, ...]:
    if text.lower() == "none":  # no filter: the XPLR-AOA's stored one is cleared
        return ()
    found = tuple(t.upper() for t in text.split("+") if t)
    if not found or not all(TAG_ID.fullmatch(t) for t in found):
        raise ValueError("12-hex-digit tag ids joined by +, e.g. tags=CCF9578E0D8A+CCF9578E0D8B, "
                         "or tags=none to clear the board's filter")
    return found


def seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 < value < 3600:
        raise ValueError("seconds, more than 0, e.g. timeout=5")
    return value


def speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if value < 0:
        raise ValueError("0 (as fast as possible) or a pace factor, e.g. speed=1")
    return value


def name(text: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,32}", text):
        raise ValueError("letters, digits, '_', '.' or '-', at most 32")
    return text


def scan_ms(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 2.5 <= value <= 10_240:
        raise ValueError("milliseconds from 2.5 to 10240, e.g. interval=100")
    return value


def yes_no(text: str) -> bool:
    if text not in ("yes", "no", "1", "0", "true", "false"):
        raise ValueError("yes or no")
    return text in ("yes", "1", "true")


def mac(text: str) -> str:
    if not re.fullmatch(r"[0-9A-Fa-f]{2}(:[0-9A-Fa-f]{2}){5}", text):
        raise ValueError("an address as aa:bb:cc:dd:ee:ff, e.g. mac=24:0a:c4:96:e6:88")
    return text.upper()


def device(text: str) -> str:
    if not 1 <= len(text) <= 200:
        raise ValueError("a device as `rfhoming replay` lists it: its path, its label or its role, e.g. device=aoa")
    return text


def ad_name(text: str) -> str:
    if not 1 <= len(text) <= 29 or '"' in text:
        raise ValueError("an advertised local name, 1 to 29 characters, no quotes")
    return text


def one_of(*choices: str, said: str) -> Parser:
    """A parser that takes one of ``choices``; ``said`` is its one-line explanation."""
    def parse(text: str) -> str:
        if text not in choices:
            raise ValueError(said)
        return text
    return parse


def domain(text: str) -> int:
    if not text.isdigit() or not 0 <= int(text) <= 232:
        raise ValueError("a ROS 2 domain id, 0 to 232 (ROS_DOMAIN_ID)")
    return int(text)


def ros_name(text: str) -> str:
    if not re.fullmatch(r"/?[A-Za-z_~][A-Za-z0-9_/]*|/", text) or "//" in text:
        raise ValueError("a ROS 2 name: letters, digits, _ and /, e.g. cmd_vel or /robot1")
    return text


def mav_id(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 255:
        raise ValueError("a MAVLink system or component id, 1 to 255, e.g. sysid=1")
    return int(text)


def mode_name(text: str) -> str:
    if not re.fullmatch(r"[A-Za-z][A-Za-z_.]{0,31}", text):
        raise ValueError("an autopilot's mode by name, e.g. end=LOITER")
    return text.upper()


SERIAL: dict[str, Parser] = {"baud": baud, "flow": flow, "name": name, "timeout": seconds}
"""A serial port's: its rate, flow control, a short name, the set-up commands' timeout."""

SCAN: dict[str, Parser] = {"active": yes_no, "interval": scan_ms, "window": scan_ms, "mac": mac, "adname": ad_name}
"""A BLE scan's: active or passive, its timing, and the filter on one advertiser."""

HCI_SCAN: dict[str, Parser] = {
    "extended": one_of("auto", "on", "off", said="auto (extended scanning where the controller has it), on or off"),
    "content": one_of("ibeacon", "eddystone", said="ibeacon or eddystone"),
    "dedup": yes_no,
}
"""A bumble controller's scan: extended advertising, what the beacons carry, duplicate filtering."""

ROS2: dict[str, Parser] = {
    "domain": domain, "ns": ros_name, "cmd_vel": ros_name, "odom": ros_name, "scan": ros_name, "stamped": yes_no,
    "discovery": one_of("localhost", "subnet",
                        said="localhost (this machine only: loopback, no multicast) or subnet (the network)"),
}
"""A ROS 2 base's: its domain, namespace, topic names, Twist or TwistStamped, and DDS discovery."""

MAVLINK: dict[str, Parser] = {"sysid": mav_id, "compid": mav_id, "arm": yes_no, "expose": yes_no, "end": mode_name}
"""A MAVLink vehicle's: its ids (else from its HEARTBEAT), arming when asked, a socket other
machines reach, the mode it is left in (else its holding mode)."""
