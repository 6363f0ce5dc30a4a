"""pcapng, the capture format Wireshark and tshark read: a sans-IO writer and reader.

rfhoming stores raw serial bytes: one interface per device (if_name = the port, if_description
= protocol and dialect), one Enhanced Packet Block per chunk exactly as read or written,
microsecond timestamps, and the direction in epb_flags (1 inbound, 2 outbound). Link types are
the user-defined ones: 147 (USER0) for u-connectLocate text, 148 (USER1) for COBS records,
149 (USER2) for ESP-AT text, 150 (USER3) for an HCI H4 byte stream (chunks as read, so a chunk
need not hold whole HCI packets -- the reason it is not LINKTYPE_BLUETOOTH_HCI_H4).

Spec: IETF draft-ietf-opsawg-pcapng. Little-endian sections; the reader also reads big-endian.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

SHB, IDB, EPB = 0x0A0D0D0A, 0x00000001, 0x00000006
BYTE_ORDER_MAGIC = 0x1A2B3C4D
LINKTYPE_UCONNECT = 147
LINKTYPE_FRAMES = 148
LINKTYPE_ESP_AT = 149
LINKTYPE_H4_STREAM = 150
LINKTYPES = {"ublox-aoa": LINKTYPE_UCONNECT, "rss": LINKTYPE_FRAMES, "esp-at": LINKTYPE_ESP_AT,
             "hci": LINKTYPE_H4_STREAM}
PROTOCOLS = {v: k for k, v in LINKTYPES.items()}
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


def section_header(application: str = "rfhoming") -> bytes:
    body = struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1) + _options([(OPT_SHB_USERAPPL, application.encode())])
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
    linktype: int

    @property
    def protocol(self) -> str | None:
        return PROTOCOLS.get(self.linktype)


@dataclass(frozen=True)
class Packet:
    interface_id: int
    t: float
    data: bytes
    direction: int  # INBOUND, OUTBOUND or 0 (unknown)
    comment: str = ""


class CaptureFormatError(ValueError):
    pass


def _parse_options(data: bytes, endian: str) -> dict[int, bytes]:
    out: dict[int, bytes] = {}
    i = 0
    while i + 4 <= len(data):
        code, length = struct.unpack_from(endian + "HH", data, i)
        if code == OPT_END:
            break
        out.setdefault(code, data[i + 4 : i + 4 + length])
        i += 4 + length + (-length % 4)
    return out


class Reader:
    """Incremental reader: ``feed(bytes)`` -> complete Interface and Packet items.

    A truncated last block (a killed writer) simply never completes: everything before it
    is read. ``pending`` says how many bytes wait for the rest of a block.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._endian: str | None = None
        self.interfaces: list[Interface] = []
        self._resolution: list[int] = []

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[Interface | Packet]:
        self._buf += data
        out: list[Interface | Packet] = []
        while len(self._buf) >= 12:
            kind = struct.unpack_from("<I", self._buf)[0]
            if kind == SHB:
                magic = struct.unpack_from("<I", self._buf, 8)[0]
                self._endian = "<" if magic == BYTE_ORDER_MAGIC else ">"
                if self._endian == ">" and struct.unpack_from(">I", self._buf, 8)[0] != BYTE_ORDER_MAGIC:
                    raise CaptureFormatError("not a pcapng file (bad byte-order magic)")
                self.interfaces, self._resolution = [], []
            elif self._endian is None:
                raise CaptureFormatError("not a pcapng file (no section header block first)")
            e = self._endian
            kind, length = struct.unpack_from(e + "II", self._buf)
            if length < 12 or length % 4:
                raise CaptureFormatError(f"corrupt block length {length}")
            if len(self._buf) < length:
                break
            body = bytes(self._buf[8 : length - 4])
            del self._buf[:length]
            if kind == IDB:
                linktype = struct.unpack_from(e + "H", body)[0]
                opts = _parse_options(body[8:], e)
                res = opts.get(OPT_IF_TSRESOL, b"\x06")[0]
                self._resolution.append(2 ** (res & 0x7F) if res & 0x80 else 10**res)  # ticks per second
                iface = Interface(opts.get(OPT_IF_NAME, b"").decode(errors="replace"),
                                  opts.get(OPT_IF_DESCRIPTION, b"").decode(errors="replace"), linktype)
                self.interfaces.append(iface)
                out.append(iface)
            elif kind == EPB:
                iface, hi, lo, caplen, _ = struct.unpack_from(e + "IIIII", body)
                data_ = body[20 : 20 + caplen]
                opts = _parse_options(body[20 + caplen + (-caplen % 4) :], e)
                flags = struct.unpack(e + "I", opts[OPT_EPB_FLAGS])[0] & 3 if OPT_EPB_FLAGS in opts else 0
                if iface >= len(self.interfaces):
                    raise CaptureFormatError(f"packet on undeclared interface {iface}")
                t = ((hi << 32) | lo) / self._resolution[iface]  # exact for µs: replay == live
                out.append(Packet(iface, t, data_, flags, opts.get(OPT_COMMENT, b"").decode(errors="replace")))
        return out


def read_all(data: bytes) -> tuple[list[Interface], list[Packet], int]:
    """Every interface and packet in ``data``, and how many trailing bytes were a torn block."""
    reader = Reader()
    items = reader.feed(data)
    return reader.interfaces, [i for i in items if isinstance(i, Packet)], reader.pending

