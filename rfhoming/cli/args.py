"""Argument types shared by every command, so that ``--duration nan`` or ``--target x`` is
refused by the parser (usage line, exit 2) before anything is opened or started."""

from __future__ import annotations

import argparse
import math
from pathlib import Path


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number ({what})") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number ({what})")
    return value


def positive_float(text: str) -> float:
    """A finite number above 0: durations, rates, noise densities."""
    value = _number(text, "more than 0")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number more than 0, e.g. 10")
    return value


def nonnegative_float(text: str) -> float:
    """A finite number, 0 or more: where 0 means something (as fast as possible, no delay)."""
    value = _number(text, "0 or more")
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number, 0 or more, e.g. 1")
    return value


def positive_int(text: str) -> int:
    """A whole number above 0: baud rates, run and worker counts, queue lengths."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number more than 0")
    return value


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


def output_file(text: str) -> Path:
    """A file the command will write, tried at once (and removed again if it was not there), so
    that a path that cannot be written is refused before any device is opened."""
    path = Path(text).expanduser()
    existed = path.exists()
    try:
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"cannot write {text}: {exc.strerror or exc}; give a path in a folder "
                                         "that exists and that you may write") from None
    if not existed:
        path.unlink(missing_ok=True)
    return path
