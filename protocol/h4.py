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

H4 has no resynchronisation of its own (neither has bumble's ``transport/common.py`` parser:
it trusts every length). A byte that starts no packet -- no indicator, or an indicator whose
header no valid packet has -- is dropped (counted) and the splitter tries the next byte, so a
stream joined mid-packet recovers at the first packet that starts on a plausible header. A
header that passes those checks is trusted, and since its length is bounded (an event holds
at most 258 bytes, a data packet at most ``max_data`` + 5), junk that looks like a header
costs at most that many bytes of what follows.
"""

from __future__ import annotations

from collections import Counter

from rfhoming.protocol.drop import Drop

COMMAND, ACL, SCO, EVENT, ISO = 0x01, 0x02, 0x03, 0x04, 0x05
HEADERS = {COMMAND: (3, 2, 1), ACL: (4, 2, 2), SCO: (3, 2, 1), EVENT: (2, 1, 1), ISO: (4, 2, 2)}
"""indicator -> (header bytes, offset of the length field in the header, its size)."""

MAX_DATA = 1021
"""Longest data payload taken for real (*assumed*: a controller sends no data packet longer
than its ACL_Data_Packet_Length, HCI_Read_Buffer_Size, Vol 4 Part E 7.4.5; 1021, the 3-DH5
payload, is the largest common controllers report). A longer length is junk."""

MAX_HANDLE = 0x0EFF  # Connection_Handle range, Vol 4 Part E 5.4.2 (and 5.4.3, 5.4.5)
EVENT_CODES = frozenset(range(0x01, 0x5A)) | {0xFF}
"""Event codes of Vol 4 Part E 7.7 (up to 0x59 in v5.4; a few in the range are unassigned)
and 0xFF, vendor-specific."""
EVENT_LENGTHS = {0x0E: (3, 255), 0x0F: (4, 4), 0x10: (1, 1), 0x3E: (1, 255)}
"""Parameter lengths of the events a host waits on: Command Complete (7.7.14: 1 + 2 + return
parameters), Command Status (7.7.15), Hardware Error (7.7.16), LE Meta (7.7.65: subevent code
first)."""
COMMAND_OGFS = frozenset(range(0x01, 0x09)) | {0x3F}  # Vol 4 Part E 5.4.1, 7.1-7.8; 0x3F vendor
MAX_JUNK = 64  # junk bytes per drop item (and held at most)
TO_HOST = (EVENT, ACL, SCO, ISO)  # commands go only to a controller (Vol 4 Part E 5.4.1) ...
TO_CONTROLLER = (COMMAND, ACL, SCO, ISO)  # ... and events only to a host (5.4.4)


def _length(kind: int, header: bytes) -> int:
    _, at, size = HEADERS[kind]
    value = int.from_bytes(header[at : at + size], "little")
    return value & 0x3FFF if kind == ISO else value


def plausible(kind: int, header: bytes, max_data: int = MAX_DATA) -> bool:
    """Whether ``header`` (the bytes after the indicator) can begin a valid packet."""
    if kind == EVENT:
        code, n = header[0], header[1]
        lo, hi = EVENT_LENGTHS.get(code, (0, 255))
        return code in EVENT_CODES and lo <= n <= hi
    if kind == COMMAND:
        return header[1] >> 2 in COMMAND_OGFS
    handle = int.from_bytes(header[:2], "little")
    if handle & 0x0FFF > MAX_HANDLE:
        return False
    if kind == ACL:  # broadcast flag 0b11 is reserved
        return handle >> 14 != 0b11 and _length(ACL, header) <= max_data
    if kind == SCO:  # the two top bits are reserved
        return handle >> 14 == 0
    return handle >> 15 == 0 and header[3] >> 6 == 0 and _length(ISO, header) <= max_data  # ISO: RFU bits


class H4Splitter:
    """``feed(bytes) -> list[bytes | Drop]``: whole packets (indicator included) in order, the
    same items in any chunking. ``types`` are the indicators this end receives (a host gets
    no commands, a controller no events); any other indicator is junk."""

    def __init__(self, types: tuple[int, ...] = tuple(HEADERS), max_data: int = MAX_DATA) -> None:
        self.types = frozenset(types)
        self.max_data = max_data
        self._buf = bytearray()
        self._junk = bytearray()
        self.counters: Counter[str] = Counter()

    @property
    def pending(self) -> int:
        """Bytes held: at most one unfinished packet and ``MAX_JUNK`` - 1 junk bytes."""
        return len(self._buf) + len(self._junk)

    def feed(self, data: bytes) -> list[bytes | Drop]:
        self._buf += data
        out: list[bytes | Drop] = []
        buf, i, n = self._buf, 0, len(self._buf)
        while i < n:
            kind = buf[i]
            size = HEADERS[kind][0] if kind in self.types else 0
            if size and n - i < 1 + size:
                break  # the header is not all here yet
            if not size or not plausible(kind, bytes(buf[i + 1 : i + 1 + size]), self.max_data):
                self._junk.append(kind)
                i += 1
                if len(self._junk) == MAX_JUNK:
                    out.append(self._flush_junk())
                continue
            if self._junk:
                out.append(self._flush_junk())
            total = 1 + size + _length(kind, bytes(buf[i + 1 : i + 1 + size]))
            if n - i < total:
                break
            out.append(bytes(buf[i : i + total]))
            i += total
            self.counters["packet"] += 1
        del buf[:i]
        return out

    def _flush_junk(self) -> Drop:
        junk = bytes(self._junk)
        self._junk.clear()
        self.counters["drop.indicator"] += 1
        return Drop("indicator", f"{len(junk)} bytes that start no H4 packet", junk)
