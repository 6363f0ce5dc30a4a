"""What the optional C accelerator (_accel.c) exports, for type checkers: a compiled module has no
annotations of its own. Each scan returns None when Python must take the whole chunk."""

from typing import Any

Buffer = bytes | bytearray | memoryview

def crc16(data: Buffer, /) -> int: ...
def scan_uudf(rest: bytes, data: Buffer, cls: type[tuple[Any, ...]], /) -> tuple[list[Any], int, bytes] | None:
    """The chunk's complete lines: ``cls`` events, and lines left to Python as bytes; the events'
    count; the unfinished tail."""

def scan_frames(rest: bytes, data: Buffer, max_encoded: int, /) -> tuple[list[bytes | tuple[bytes]], bytes] | None:
    """The chunk's complete frames: inner bytes that passed COBS and CRC, or a 1-tuple of a raw frame
    left to Python; the unfinished tail."""
