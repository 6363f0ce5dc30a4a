"""u-connectLocate (u-blox XPLR-AOA) AT commands, answers and ``+UUDF`` angle events."""

from rfhoming.protocol.uconnect.commands import Command, CommandMatcher, Response
from rfhoming.protocol.uconnect.decoder import MAX_LINE, UConnectDecoder
from rfhoming.protocol.uconnect.encoder import Dialect, encode_angle_event, encode_answer, encode_startup
from rfhoming.protocol.uconnect.items import (
    AngleEvent,
    Drop,
    Echo,
    FinalCode,
    InfoLine,
    Item,
    Startup,
    TagData,
    UnknownLine,
)

__all__ = [
    "MAX_LINE",
    "AngleEvent",
    "Command",
    "CommandMatcher",
    "Dialect",
    "Drop",
    "Echo",
    "FinalCode",
    "InfoLine",
    "Item",
    "Response",
    "Startup",
    "TagData",
    "UConnectDecoder",
    "UnknownLine",
    "encode_angle_event",
    "encode_answer",
    "encode_startup",
]
