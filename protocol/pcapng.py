"""pcapng, the capture format Wireshark and tshark read: a sans-IO writer and reader.

rfhoming stores raw serial bytes: one interface per device (if_name = the port, if_description
= protocol and dialect), one Enhanced Packet Block per chunk exactly as read or written,
microsecond timestamps, and the direction in epb_flags (1 inbound, 2 outbound). Link types are
the user-defined ones: 147 (USER0) for u-connectLocate text, 148 (USER1) for COBS records,
149 (USER2) for ESP-AT text, 150 (USER3) for an HCI H4 byte stream (chunks as read, so a chunk
need not hold whole HCI packets -- the reason it is not LINKTYPE_BLUETOOTH_HCI_H4), 151 (USER4)
for ROS 2 DDS samples, one sample record (topic, type, CDR; rfhoming.protocol.ros2) per packet.

Spec: IETF draft-ietf-opsawg-pcapng. Little-endian sections; the reader also reads big-endian.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

from rfhoming.protocol.errors import Error

SHB, IDB, EPB = 0x0A0D0D0A, 0x00000001, 0x00000006
BYTE_ORDER_MAGIC = 0x1A2B3C4D
LINKTYPE_UCONNECT = 147
LINKTYPE_FRAMES = 148
LINKTYPE_ESP_AT = 149
LINKTYPE_H4_STREAM = 150
LINKTYPE_ROS2_SAMPLES = 151
OPT_END, OPT_COMMENT, OPT_SHB_USERAPPL = 0, 1, 4
OPT_IF_NAME, OPT_IF_DESCRIPTION, OPT_IF_TSRESOL = 2, 3, 9
OPT_EPB_FLAGS = 2
INBOUND, OUTBOUND = 1, 2


def _pad(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


def _options(options: list[tuple[int, bytes]]) -> bytes:
    if not options:
        return b""
    body = b"".join(struct.pack("<HH", code, len(value)) + _pad(value) for code, value in options)
    return body + struct.pack("<HH", OPT_END, 0)


def _block(kind: int, body: bytes) -> bytes:
    length = 12 + len(body)
    return struct.pack("<II", kind, length) + body + struct.pack("<I", length)


def section_header(application: str = "rfhoming", comment: str = "") -> bytes:
    """The section header; ``comment`` (opt_comment, which tshark and capinfos show) carries
    what a whole capture is, e.g. the homing run it recorded."""
    opts = [(OPT_SHB_USERAPPL, application.encode())] + ([(OPT_COMMENT, comment.encode())] if comment else [])
    body = struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1) + _options(opts)
    return _block(SHB, body)


def interface(name: str, description: str, linktype: int) -> bytes:
    opts = [(OPT_IF_NAME, name.encode()), (OPT_IF_DESCRIPTION, description.encode()), (OPT_IF_TSRESOL, b"\x06")]
    return _block(IDB, struct.pack("<HHI", linktype, 0, 0) + _options(opts))


def packet(interface_id: int, t: float, data: bytes, direction: int, comment: str = "") -> bytes:
    us = round(t * 1e6)
    opts = [(OPT_EPB_FLAGS, struct.pack("<I", direction))]
    if comment:
        opts.append((OPT_COMMENT, comment.encode()))
    head = struct.pack("<IIIII", interface_id, us >> 32, us & 0xFFFFFFFF, len(data), len(data))
    return _block(EPB, head + _pad(data) + _options(opts))


@dataclass(frozen=True)
class Interface:
    name: str
    description: str
    linktype: int  # which protocol it is: rfhoming.protocol.devices.by_linktype


@dataclass(frozen=True)
class Packet:
    interface_id: int
    t: float
    data: bytes
    direction: int  # INBOUND, OUTBOUND or 0 (unknown)
    comment: str = ""


class CaptureFormatError(Error, ValueError):
    """A capture that is not readable from ``offset`` on; ``items`` are what was read before it
    in the failing :meth:`Reader.feed` call (earlier calls already returned theirs)."""

    def __init__(self, offset: int, problem: str, items: list[Interface | Packet] | None = None) -> None:
        super().__init__(f"offset {offset}: {problem}")
        self.offset, self.problem = offset, problem
        self.items: list[Interface | Packet] = items or []


def _parse_options(data: bytes, endian: str) -> dict[int, bytes]:
    """Options of a block body; ValueError names an option that overruns the block."""
    out: dict[int, bytes] = {}
    i = 0
    while i + 4 <= len(data):
        code, length = struct.unpack_from(endian + "HH", data, i)
        if code == OPT_END:
            break
        if i + 4 + length > len(data):
            raise ValueError(f"option {code} ({length} bytes) overruns its block")
        out.setdefault(code, data[i + 4 : i + 4 + length])
        i += 4 + length + (-length % 4)
    return out


class Reader:
    """Incremental reader: ``feed(bytes)`` -> complete Interface and Packet items.

    A truncated last block (a killed writer) simply never completes: everything before it
    is read. ``pending`` says how many bytes wait for the rest of a block. Anything else that
    is not pcapng raises :class:`CaptureFormatError` naming the byte offset; the reader is then
    spent (it does not guess where the next good block starts).

    Interface ids are per section: a second section (``cat a.pcapng b.pcapng``) declares its
    own interfaces, which are appended to :attr:`interfaces`; every Packet's ``interface_id``
    indexes :attr:`interfaces`, so packets always go with their own section's interfaces.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._endian: str | None = None
        self.interfaces: list[Interface] = []
        self._resolution: list[int] = []  # ticks per second, per entry of ``interfaces``
        self._section: list[int] = []  # this section's interface ids -> index in ``interfaces``
        self.offset = 0  # file offset of the first byte in the buffer
        self.sections = 0
        self.comments: list[str] = []  # each section header's opt_comment ("" for none)
        self._error: CaptureFormatError | None = None

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[Interface | Packet]:
        if self._error is not None:
            raise self._error
        self._buf += data
        out: list[Interface | Packet] = []
        try:
            while len(self._buf) >= 12:
                item_or_none = self._block()
                if item_or_none is False:
                    break
                if item_or_none is not None:
                    out.append(item_or_none)
        except (ValueError, struct.error) as exc:  # struct.error is a bug guard: every read is checked
            problem = exc.problem if isinstance(exc, CaptureFormatError) else str(exc)
            self._error = CaptureFormatError(self.offset, problem, out)
            raise self._error from None
        return out

    def _block(self) -> Interface | Packet | None | Literal[False]:
        """Consume one complete block; False if it is not complete yet."""
        kind = struct.unpack_from("<I", self._buf)[0]
        if kind == SHB:
            magic = struct.unpack_from("<I", self._buf, 8)[0]
            if magic == BYTE_ORDER_MAGIC:
                endian = "<"
            elif struct.unpack_from(">I", self._buf, 8)[0] == BYTE_ORDER_MAGIC:
                endian = ">"
            else:
                raise ValueError("not a pcapng file (bad byte-order magic)")
        elif self._endian is None:
            raise ValueError("not a pcapng file (no section header block first)")
        else:
            endian = self._endian
        kind, length = struct.unpack_from(endian + "II", self._buf)
        if length < 12 or length % 4:
            raise ValueError(f"corrupt block length {length}")
        if len(self._buf) < length:
            return False
        trailer = struct.unpack_from(endian + "I", self._buf, length - 4)[0]
        if trailer != length:
            raise ValueError(f"block length {length} does not match its trailing copy {trailer}")
        body = bytes(self._buf[8 : length - 4])
        if kind == SHB:
            if len(body) < 16:
                raise ValueError(f"section header body is {len(body)} bytes, needs 16")
            self._endian, self._section = endian, []
            self.sections += 1
            self.comments.append(_parse_options(body[16:], endian).get(OPT_COMMENT, b"").decode(errors="replace"))
            item: Interface | Packet | None = None
        elif kind == IDB:
            item = self._interface(body, endian)
        elif kind == EPB:
            item = self._packet(body, endian)
        else:
            item = None  # a block type we do not use (statistics, name resolution, ...)
        del self._buf[:length]
        self.offset += length
        return item

    def _interface(self, body: bytes, e: str) -> Interface:
        if len(body) < 8:
            raise ValueError(f"interface description body is {len(body)} bytes, needs 8")
        linktype = struct.unpack_from(e + "H", body)[0]
        opts = _parse_options(body[8:], e)
        tsresol = opts.get(OPT_IF_TSRESOL, b"\x06")
        if len(tsresol) != 1:
            raise ValueError(f"if_tsresol option is {len(tsresol)} bytes, needs 1")
        res = tsresol[0]
        iface = Interface(opts.get(OPT_IF_NAME, b"").decode(errors="replace"),
                          opts.get(OPT_IF_DESCRIPTION, b"").decode(errors="replace"), linktype)
        self._section.append(len(self.interfaces))
        self.interfaces.append(iface)
        self._resolution.append(2 ** (res & 0x7F) if res & 0x80 else 10**res)
        return iface

    def _packet(self, body: bytes, e: str) -> Packet:
        if len(body) < 20:
            raise ValueError(f"enhanced packet body is {len(body)} bytes, needs 20")
        local, hi, lo, caplen, _ = struct.unpack_from(e + "IIIII", body)
        if 20 + caplen > len(body):
            raise ValueError(f"captured length {caplen} exceeds its block ({len(body) - 20} bytes of data)")
        if local >= len(self._section):
            raise ValueError(f"packet on interface {local}, which this section has not declared "
                             f"({len(self._section)} interfaces)")
        opts = _parse_options(body[20 + caplen + (-caplen % 4) :], e)
        flags = 0
        if OPT_EPB_FLAGS in opts:
            if len(opts[OPT_EPB_FLAGS]) != 4:
                raise ValueError(f"epb_flags option is {len(opts[OPT_EPB_FLAGS])} bytes, needs 4")
            flags = struct.unpack(e + "I", opts[OPT_EPB_FLAGS])[0] & 3
        iface = self._section[local]
        t = ((hi << 32) | lo) / self._resolution[iface]  # exact for µs: replay == live
        return Packet(iface, t, body[20 : 20 + caplen], flags, opts.get(OPT_COMMENT, b"").decode(errors="replace"))


def read_all(data: bytes) -> tuple[list[Interface], list[Packet], int]:
    """Every interface and packet in ``data``, and how many trailing bytes were a torn block.

    Raises CaptureFormatError for a file that is not pcapng from some offset on, including an
    empty one or one shorter than a section header; its ``items`` then hold everything read
    before that offset.
    """
    return read_sections(data, Reader())


def read_sections(data: bytes, reader: Reader) -> tuple[list[Interface], list[Packet], int]:
    """:func:`read_all` with the caller's reader, which keeps the section headers' comments."""
    items = reader.feed(data)
    if reader.sections == 0:
        what = "empty file" if not data else f"only {len(data)} bytes, no complete section header"
        raise CaptureFormatError(0, f"{what}: not a pcapng capture (a capture killed before it wrote anything?)")
    if not reader.interfaces:
        raise CaptureFormatError(reader.offset, "no interface declared after the section header: nothing to read")
    return reader.interfaces, [i for i in items if isinstance(i, Packet)], reader.pending
