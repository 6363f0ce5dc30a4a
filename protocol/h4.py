"""HCI over UART (H4): the byte stream between a Bluetooth host and its controller, split
into packets. Sans-IO and bounded.

Each packet is one indicator byte, then the header of its type, then the payload whose length
the header gives (Bluetooth Core Specification v5.4, Vol 4, Part A, sections 2 and 5.4):

| indicator | packet | header after the indicator | length field |
|---|---|---|---|
| 0x01 | command | opcode (2), length (1) | u8 |
| 0x02 | ACL data | handle + flags (2), length (2) | u16 LE |
| 0x03 | SCO data | handle + flags (2), length (1) | u8 |
| 0x04 | event | event code (1), length (1) | u8 |
| 0x05 | ISO data | handle + flags (2), length (2) | low 14 bits LE |

H4 has no resynchronisation of its own: a byte that is no indicator is dropped (counted)
and the splitter tries the next one, so a stream joined mid-packet recovers at the first
packet that starts on a recognisable indicator.
"""

from __future__ import annotations

from collections import Counter

from rfhoming.protocol.drop import Drop

COMMAND, ACL, SCO, EVENT, ISO = 0x01, 0x02, 0x03, 0x04, 0x05
HEADERS = {COMMAND: (3, 2, 1), ACL: (4, 2, 2), SCO: (3, 2, 1), EVENT: (2, 1, 1), ISO: (4, 2, 2)}
"""indicator -> (header bytes, offset of the length field in the header, its size)."""


def _length(kind: int, header: bytes) -> int:
    _, at, size = HEADERS[kind]
    value = int.from_bytes(header[at : at + size], "little")
    return value & 0x3FFF if kind == ISO else value


class H4Splitter:
    """``feed(bytes) -> list[bytes | Drop]``: whole packets (indicator included) in order."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._junk = bytearray()
        self.counters: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[bytes | Drop]:
        self._buf += data
        out: list[bytes | Drop] = []
        buf = self._buf
        while buf:
            kind = buf[0]
            if kind not in HEADERS:
                self._junk.append(buf.pop(0))
                continue
            if self._junk:
                out.append(self._flush_junk())
            size = HEADERS[kind][0]
            if len(buf) < 1 + size:
                break
            total = 1 + size + _length(kind, bytes(buf[1 : 1 + size]))
            if len(buf) < total:
                break
            out.append(bytes(buf[:total]))
            del buf[:total]
            self.counters["packet"] += 1
        if len(self._junk) >= 64:
            out.append(self._flush_junk())
        return out

    def _flush_junk(self) -> Drop:
        junk = bytes(self._junk)
        self._junk.clear()
        self.counters["drop.indicator"] += 1
        return Drop("indicator", f"{len(junk)} bytes that start no H4 packet", junk)

