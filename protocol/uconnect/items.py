"""What the u-connectLocate decoder yields, one type per kind of line.

Items are NamedTuples: cheap to build on the hot path, immutable, comparable, and
``to_dict()`` gives the JSON form. ``kind`` is a class attribute, not a field.
"""

from __future__ import annotations

from typing import NamedTuple

from rfhoming.protocol.drop import Drop
from rfhoming.protocol.jsonable import as_dict


class AngleEvent(NamedTuple):
    """One ``+UUDF`` event: a tag's direction as seen by one anchor.

    Angles are integer degrees in the board's own frame (azimuth -90..90, negative = tag to
    the left seen from the antenna). ``seq`` exists from firmware 2.x on; the raw angles only
    on u-locateEmbed with ``AT+UDFCFG=121,1``.
    """

    instance_id: str
    rssi1: int
    azimuth: int
    elevation: int
    reserved: int
    """Field 5: the second polarisation's RSSI on 1.0 ([UG-R02] A.4.3), "reserved" from 1.2 on
    ([UG-R10] section 6); real lines carry -43, 6, 8 there. Never an RSSI, never a dialect sign."""
    channel: int
    anchor_id: str
    user_str: str
    timestamp_ms: int
    seq: int | None = None
    azimuth_raw: int | None = None
    elevation_raw: int | None = None

    kind = "angle"
    to_dict = as_dict


class TagData(NamedTuple):
    """``+UUDFP``: a tag's periodic-advertising payload (2.x), not an angle."""

    instance_id: str
    payload: bytes

    kind = "tag_data"
    to_dict = as_dict


class Startup(NamedTuple):
    """``+STARTUP``: the board booted; a host must send its set-up again."""

    kind = "startup"
    to_dict = as_dict


class Echo(NamedTuple):
    """The board echoing a command the host sent (text without the CR)."""

    text: str

    kind = "echo"
    to_dict = as_dict


class InfoLine(NamedTuple):
    """An information line of a command answer, e.g. ``+UMLA:…`` or ``"u-blox"``."""

    text: str

    kind = "info"
    to_dict = as_dict


class FinalCode(NamedTuple):
    """``OK`` or ``ERROR``: the end of a command answer."""

    ok: bool

    kind = "final"
    to_dict = as_dict


class UnknownLine(NamedTuple):
    """A well-formed ASCII line we do not recognise; kept verbatim and counted."""

    text: str
    note: str = ""

    kind = "unknown"
    to_dict = as_dict


Item = AngleEvent | TagData | Startup | Echo | InfoLine | FinalCode | UnknownLine | Drop
