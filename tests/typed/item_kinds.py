"""A user's program over rfhoming's items, type-checked (never run) by tests/test_typing.py:
``match item.kind`` narrows an item to the types of that kind, and a match that covers every
kind leaves nothing for ``assert_never``. Were ``kind`` a plain ``str`` (or ``Any``), every
``assert_type`` below would fail."""

from typing import assert_never, assert_type

import rfhoming
from rfhoming.api import Item
from rfhoming.protocol.espat import Final, Info
from rfhoming.protocol.frames import Odometry
from rfhoming.protocol.uconnect import AngleEvent, Drop, Echo, FinalCode, InfoLine, Startup, TagData, UnknownLine
from rfhoming.protocol.uconnect import Item as UConnectItem


def describe(item: UConnectItem) -> str:
    """Every kind the u-connectLocate decoder yields, each with its own fields."""
    match item.kind:
        case "angle":
            assert_type(item, AngleEvent)
            return f"{item.anchor_id} sees {item.instance_id} at {item.azimuth} deg"
        case "tag_data":
            assert_type(item, TagData)
            return item.payload.hex()
        case "startup":
            assert_type(item, Startup)
            return "booted"
        case "echo" | "info" | "unknown":
            assert_type(item, Echo | InfoLine | UnknownLine)
            return item.text
        case "final":
            assert_type(item, FinalCode)
            return "OK" if item.ok else "ERROR"
        case "drop":
            assert_type(item, Drop)
            return item.reason
        case _:
            assert_never(item)


def kinds_shared_by_two_protocols(item: Item) -> str | None:
    """``final`` and ``info`` are both u-connectLocate's and ESP-AT's: the kind narrows to both."""
    match item.kind:
        case "final":
            assert_type(item, FinalCode | Final)
            return "OK" if item.ok else "ERROR"
        case "info":
            assert_type(item, InfoLine | Info)
            return None
        case "odometry":
            assert_type(item, Odometry)
            return f"{item.x_mm} mm"
    return None


def azimuths(path: str) -> list[int]:
    """As the API reads a recording: ``got.item.kind`` narrows ``got.item``."""
    out = []
    for got in rfhoming.read(path):
        if got.item.kind == "angle":
            out.append(got.item.azimuth)
    return out
