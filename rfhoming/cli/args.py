"""Argument types shared by every command, in one place, so that a value no command can use --
``--duration nan``, ``--seed -1``, ``--workers 99999999999``, ``--id 'a/#'``, a fault spec with
``rate=2`` -- is refused by the parser (usage line, exit 2, the range in the message) before
anything is opened or started. Every number has an upper bound too: a value past it is a typo,
and would otherwise reach a timer or an allocation that overflows or never ends."""

from __future__ import annotations

import argparse
import importlib
import math
import re
from pathlib import Path
from typing import Any

MAX_SECONDS = 1e7
"""About four months: a longer --duration or wait is a typo (leave --duration out to run until
Ctrl-C), and timers past it overflow (``threading.Event.wait(1e308)``)."""


class Number:
    """A finite number within [low, high] (``above``: more than ``low``); ``whole``: an int.
    The message of a refused value says the range, e.g. ``expected a number more than 0 and at
    most 1e+07 (seconds)``."""

    def __init__(self, low: float, high: float, what: str, *, above: bool = False, whole: bool = False) -> None:
        self.low, self.high, self.what, self.above, self.whole = low, high, what, above, whole
        self.__name__ = what  # argparse names the type by it

    def range_text(self) -> str:
        kind = "a whole number" if self.whole else "a number"
        if self.above:
            return f"{kind} more than {_show(self.low)} and at most {_show(self.high)}"
        return f"{kind} from {_show(self.low)} to {_show(self.high)}"

    def __call__(self, text: str) -> Any:
        try:
            value: float = int(text) if self.whole else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {self.range_text()} ({self.what})") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number, {self.range_text()} ({self.what})")
        if value < self.low or (self.above and value == self.low) or value > self.high:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {self.range_text()} ({self.what})")
        return value


def _show(x: float) -> str:
    return f"{int(x):,}" if float(x).is_integer() else f"{x:g}"


duration = Number(0, MAX_SECONDS, "seconds", above=True)
"""--duration: leave it out to run until Ctrl-C."""
delay = Number(0, MAX_SECONDS, "seconds")
"""A wait where 0 means none: --wait-viewer, --linger, --start-delay."""
speed = Number(0, 1e6, "simulated seconds per wall second; 0 = as fast as possible")
rate_hz = Number(0, 1000, "per second", above=True)
flush_s = Number(1e-3, 60, "seconds between batches")
reorder_s = Number(0, 60, "seconds")
accel_psd = Number(0, 1e6, "m^2/s^3", above=True)
height_sigma = Number(0, 100, "metres", above=True)
tag_height = Number(0, 100, "metres above the floor, the site frame's z")
baud = Number(50, 12_000_000, "baud rate, e.g. 115200", whole=True)
runs = Number(1, 1_000_000, "runs", whole=True)
workers = Number(1, 256, "worker processes", whole=True)
queue_lines = Number(1, 1_000_000, "lines", whole=True)
clients = Number(1, 100_000, "clients", whole=True)
seed = Number(0, 2**32 - 1, "seed", whole=True)
tcp_port = Number(0, 65535, "TCP port; 0 = any free one", whole=True)


MAX_XY_M = 1000.0
"""A target this far (metres) is a typo: the emulator's worlds are tens of metres."""


def xy(text: str) -> str:
    """A position ``X,Y`` in metres, each finite and within ±1000 m; returned as written, since
    the demo hands it on to the emulator's command line."""
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if len(values) != 2 or not all(math.isfinite(v) and abs(v) <= MAX_XY_M for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: expected X,Y in metres (finite, within ±{MAX_XY_M:g}), "
                                         "e.g. --target=-6,4")
    return text


MAX_NAME = 64
_NAME = re.compile(r"[A-Za-z0-9._-]+")


def bus_name(text: str) -> str:
    """A name that becomes one level of an MQTT topic and part of a client id (a site, a
    gateway, a worker): letters, digits, ``.``, ``_``, ``-``; never ``/``, ``+`` or ``#``
    (topic levels and wildcards), never empty."""
    if not _NAME.fullmatch(text) or len(text) > MAX_NAME:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a name of 1 to {MAX_NAME} letters, digits, '.', '_' "
                                         "or '-' (no '/', '+', '#' or spaces: it is one level of the MQTT topics)")
    return text


def _checked(text: str, parser: str) -> str:
    """``text`` checked by the site extra's ``parser`` (``MODULE:CLASS``, its ``parse``), returned
    as written; without the site extra (paho-mqtt) it is left to the command, which names the extra."""
    module, _, name = parser.partition(":")
    try:
        parse = getattr(importlib.import_module(module), name).parse
        from rfhoming.host.sitebus import BrokerError
    except ImportError:
        return text
    try:
        parse(text)
    except BrokerError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def broker_url(text: str) -> str:
    """``mqtt://HOST[:PORT][/PARTITIONS]`` checked by the site bus's own parser (its partition
    count, host and port ranges)."""
    return _checked(text, "rfhoming.host.sitebus:Broker")


def is_broker(spec: str) -> bool:
    """A site bus's broker URL, not a port spec."""
    return spec.startswith(("mqtt://", "mqtts://"))


def is_silabs(spec: str) -> bool:
    """Silicon Labs' locators on their MQTT broker (host/silabs_source.py), not a port spec."""
    return spec.startswith(("mqtt+silabs://", "mqtts+silabs://"))


def silabs_url(text: str) -> str:
    """``mqtt+silabs://HOST[:PORT][/PREFIX]`` checked by its source's parser."""
    return _checked(text, "rfhoming.host.silabs_source:Source")


def from_spec(text: str) -> str:
    """locate's --from: a port spec (checked when opened), or a broker URL (checked now)."""
    if is_broker(text):
        return broker_url(text)
    if is_silabs(text):
        return silabs_url(text)
    return nonempty(text)


_ADDRESS = re.compile(r"(?:[a-z]+://)?\[?[\w.:-]+?\]?:(\d{1,5})")


def dask_address(text: str) -> str:
    """A Dask scheduler's address, ``[tcp://]HOST:PORT``."""
    m = _ADDRESS.fullmatch(text)
    if not m or not 0 < int(m[1]) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a scheduler address HOST:PORT, e.g. tcp://10.0.0.5:8786")
    return text


def nonempty(text: str) -> str:
    """Free text checked later by the command (a port spec, an address), but never empty."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty value: give one (see --help)")
    return text


def expanded(text: str) -> Path:
    """``text`` as a path, ``~`` and ``~USER`` expanded: a user the system does not know is refused."""
    try:
        return Path(text).expanduser()
    except RuntimeError:  # pathlib: "Could not determine home directory."
        raise argparse.ArgumentTypeError(f"{text!r}: no such user's home folder; give the path without ~") from None


def path(text: str) -> Path:
    """A file or folder to read or create; an empty one would mean the current folder."""
    return expanded(nonempty(text))


def fault(text: str) -> str:
    """An emulator fault spec, parsed by the emulator's own parser (its ranges are there)."""
    from rfhoming.emulator.faults import Fault, FaultError

    try:
        Fault.parse(text)
    except FaultError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def output_file(text: str) -> Path:
    """A file the command will write (as FILE.part, renamed to FILE when done: host/outputs.py),
    tried at once, so that a path that cannot be written -- or whose FILE.part is there, left by
    a killed command or being written by another -- is refused before any device is opened."""
    from rfhoming.host.outputs import WriteFailed, check

    file = expanded(nonempty(text))
    try:
        check(file)
    except WriteFailed as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"cannot write {text!r}: {exc.strerror or exc}; give a path in a folder "
                                         "that exists and that you may write") from None
    return file


def output_folder(text: str) -> Path:
    """A folder the command will create or fill; not empty text, not an existing file."""
    folder = path(text)
    try:
        is_file = folder.exists() and not folder.is_dir()
    except OSError as exc:  # a name too long, say
        raise argparse.ArgumentTypeError(f"{text!r}: {exc.strerror or exc}") from None
    if is_file:
        raise argparse.ArgumentTypeError(f"{text!r} is a file, not a folder; give a folder (it is created if missing)")
    return folder
