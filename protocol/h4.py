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

H4 has no resynchronisation marker (neither has bumble's ``transport/common.py`` parser: it
trusts every length). The Core Specification's recovery is a reset: on a bad indicator or an
out-of-range length the host sends HCI_Reset and resynchronises on that command's Command
Complete event, and the controller resynchronises on the HCI_Reset command itself (Vol 4
Part A, "Error recovery"). The driver resets on every open; the splitter takes both packets
at once (:func:`resync_point`), and otherwise resynchronises on its own:

- A byte that starts no packet -- no indicator, or an indicator whose header no valid packet
  has -- is dropped (counted) and the splitter tries the next byte ("hunting").
- While hunting, a plausible header is trusted only when the bytes just after the packet it
  claims begin a plausible header too. A lone plausible header inside junk or inside another
  packet's payload (advertising reports are full of bytes 0x01-0x05) would otherwise be
  trusted, and the bytes it claims land the splitter inside the next packet, where the same
  can happen again: a misframing that can run on far past the junk.
- Once a packet is taken, headers are trusted as a host trusts them, until one is implausible.

Cost: while hunting, a packet waits for the next one's header (after a resynchronisation
point or one confirmed packet, packets come out as soon as they are whole). Held at most: one
claimed packet (``max_hold`` bytes), the next header (5) and ``MAX_JUNK`` - 1 junk bytes. Loss
is bounded in bytes, not in packets: any payload may hold a chain of plausible headers, so no
H4 parser can promise the first real packet after junk. What is promised, and what
bench/fuzz.py's ``h4`` target checks: a packet comes out when these rules take it from every
state the splitter can be in as it leaves the junk.
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


def max_hold(max_data: int = MAX_DATA) -> int:
    """The most bytes one plausible header can claim: an event (258) or a data packet."""
    return max(1 + 2 + 255, 1 + 4 + max_data)


def resync_point(buf: bytes | bytearray, i: int) -> bool:
    """Whether the packet at ``i`` is one the spec resynchronises on, taken while hunting
    without waiting for the next header: the HCI_Reset command (opcode 0x0C03, Vol 4 Part E
    7.3.2), for a controller, and its Command Complete event (7.7.14), for a host."""
    return (buf[i : i + 4] == b"\x01\x03\x0c\x00"
            or (buf[i : i + 3] == b"\x04\x0e\x04" and buf[i + 4 : i + 6] == b"\x03\x0c"))


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
        self._hunting = False  # a fresh stream is taken as in step (the driver resets the controller first)
        self.counters: Counter[str] = Counter()

    @property
    def pending(self) -> int:
        """Bytes held: at most one unfinished packet, the next header while hunting, and
        ``MAX_JUNK`` - 1 junk bytes."""
        return len(self._buf) + len(self._junk)

    def _header_at(self, buf: bytearray, i: int, n: int) -> bool | None:
        """Whether a plausible header starts at ``i``; None: not all of it is here yet."""
        kind = buf[i]
        size = HEADERS[kind][0] if kind in self.types else 0
        if not size:
            return False
        if n - i < 1 + size:
            return None
        return plausible(kind, bytes(buf[i + 1 : i + 1 + size]), self.max_data)

    def feed(self, data: bytes) -> list[bytes | Drop]:
        self._buf += data
        out: list[bytes | Drop] = []
        buf, i, n = self._buf, 0, len(self._buf)
        while i < n:
            ok = self._header_at(buf, i, n)
            if ok is None:
                break  # the header is not all here yet
            if ok:
                kind = buf[i]
                total = 1 + HEADERS[kind][0] + _length(kind, bytes(buf[i + 1 : i + 1 + HEADERS[kind][0]]))
                if n - i < total:
                    break
                if self._hunting and not resync_point(buf, i):
                    if i + total >= n:
                        break  # the next header decides
                    ok = self._header_at(buf, i + total, n)
                    if ok is None:
                        break
            if not ok:
                self._hunting = True
                self._junk.append(buf[i])
                i += 1
                if len(self._junk) == MAX_JUNK:
                    out.append(self._flush_junk())
                continue
            if self._junk:
                out.append(self._flush_junk())
            out.append(bytes(buf[i : i + total]))
            i += total
            self._hunting = False
            self.counters["packet"] += 1
        del buf[:i]
        return out

    def _flush_junk(self) -> Drop:
        junk = bytes(self._junk)
        self._junk.clear()
        self.counters["drop.indicator"] += 1
        return Drop("indicator", f"{len(junk)} bytes that start no H4 packet", junk)
