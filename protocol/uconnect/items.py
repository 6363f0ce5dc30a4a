"""What the u-connectLocate decoder yields, one type per kind of line.

Items are NamedTuples: cheap to build on the hot path, immutable, comparable, and
``to_dict()`` gives the JSON form. ``kind`` is a class attribute, not a field: typed as a
``Literal`` on a subclass (NamedTuple bodies cannot hold typed class attributes), so
``match item.kind`` narrows the item.
"""

from __future__ import annotations

from typing import ClassVar, Literal, NamedTuple

from rfhoming.protocol.drop import Drop as Drop  # re-exported: an Item can be a Drop
from rfhoming.protocol.jsonable import as_dict


class _AngleEvent(NamedTuple):
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


class AngleEvent(_AngleEvent):
    """One ``+UUDF`` event: a tag's direction as seen by one anchor.

    Angles are integer degrees in the board's own frame (azimuth -90..90, negative = tag to
    the left seen from the antenna). ``seq`` exists from firmware 2.x on; the raw angles only
    on u-locateEmbed with ``AT+UDFCFG=121,1``.
    """

    __slots__ = ()
    kind: ClassVar[Literal["angle"]] = "angle"
    to_dict = as_dict


class _TagData(NamedTuple):
    instance_id: str
    payload: bytes


class TagData(_TagData):
    """``+UUDFP``: a tag's periodic-advertising payload (2.x), not an angle."""

    __slots__ = ()
    kind: ClassVar[Literal["tag_data"]] = "tag_data"
    to_dict = as_dict


class _Startup(NamedTuple):
    pass


class Startup(_Startup):
    """``+STARTUP``: the board booted; a host must send its set-up again."""

    __slots__ = ()
    kind: ClassVar[Literal["startup"]] = "startup"
    to_dict = as_dict


class _Echo(NamedTuple):
    text: str


class Echo(_Echo):
    """The board echoing a command the host sent (text without the CR)."""

    __slots__ = ()
    kind: ClassVar[Literal["echo"]] = "echo"
    to_dict = as_dict


class _InfoLine(NamedTuple):
    text: str


class InfoLine(_InfoLine):
    """An information line of a command answer, e.g. ``+UMLA:…`` or ``"u-blox"``."""

    __slots__ = ()
    kind: ClassVar[Literal["info"]] = "info"
    to_dict = as_dict


class _FinalCode(NamedTuple):
    ok: bool


class FinalCode(_FinalCode):
    """``OK`` or ``ERROR``: the end of a command answer."""

    __slots__ = ()
    kind: ClassVar[Literal["final"]] = "final"
    to_dict = as_dict


class _UnknownLine(NamedTuple):
    text: str
    note: str = ""


class UnknownLine(_UnknownLine):
    """A well-formed ASCII line we do not recognise; kept verbatim and counted."""

    __slots__ = ()
    kind: ClassVar[Literal["unknown"]] = "unknown"
    to_dict = as_dict


Item = AngleEvent | TagData | Startup | Echo | InfoLine | FinalCode | UnknownLine | Drop
