"""Espressif ESP-AT firmware, BLE scanning subset: sans-IO line decoder and line encoders.

Formats follow Espressif's ESP-AT documentation for the ESP32 (docs/protocol.md section 5
cites the pages): commands end in CR LF, the firmware echoes them (``ATE1`` is the default),
every answer is a line ending in CR LF, and a scan result is one line::

    +BLESCAN:"5b:3b:6c:51:90:49",-87,02011a020a0c0aff4c001005071c3024dc,,1

(address, RSSI in dBm, advertising data in hex, scan response data in hex -- empty unless
active scanning -- and the advertiser's address type). :class:`EspAtDecoder` turns bytes in
any chunking into :class:`ScanReport`, :class:`Final` (``OK``/``ERROR``), :class:`Info` (any
other ``+NAME:`` line), :class:`Event` (``ready``, ``+BLESCANDONE``, an echoed command) and
:class:`~rfhoming.protocol.drop.Drop` items; every bad line is a counted drop, never an error.
"""

from __future__ import annotations

import re
from collections import Counter
from typing import Any, ClassVar, Literal, NamedTuple

from rfhoming.protocol.drop import Drop

MAX_LINE = 700
"""Longest line kept (two 119-byte extended advertising payloads in hex fit); longer is dropped."""

SCAN_PREFIX = b"+BLESCAN:"
_ADDR = re.compile(r'"?([0-9a-fA-F]{2}(?::[0-9a-fA-F]{2}){5})"?')
_HEX = re.compile(r'"?((?:[0-9a-fA-F]{2})*)"?')


class _ScanReport(NamedTuple):
    address: str
    rssi_dbm: int
    adv_data: bytes
    scan_rsp: bytes
    addr_type: int


class ScanReport(_ScanReport):
    """One ``+BLESCAN:`` line. ``address`` is printed MSB first, upper-case, no colons
    (the form the S3 anchors use); ``adv_data``/``scan_rsp`` are the raw AD bytes."""

    __slots__ = ()
    kind: ClassVar[Literal["scan_report"]] = "scan_report"


class _Final(NamedTuple):
    ok: bool


class Final(_Final):
    """``OK`` or ``ERROR``: the end of a command's answer."""

    __slots__ = ()
    kind: ClassVar[Literal["final"]] = "final"


class _Info(NamedTuple):
    name: str
    value: str


class Info(_Info):
    """An information line ``+NAME:value`` (e.g. ``+BLEINIT:1``)."""

    __slots__ = ()
    kind: ClassVar[Literal["info"]] = "info"


class _Event(NamedTuple):
    what: str
    text: str


class Event(_Event):
    """``ready`` (the board booted), ``+BLESCANDONE`` (a timed scan ended) or ``echo``."""

    __slots__ = ()
    kind: ClassVar[Literal["event"]] = "event"


def parse_scan(line: bytes) -> ScanReport | Drop:
    """One ``+BLESCAN:`` line (without CR LF) -> ScanReport, or a Drop that says why."""
    try:
        text = line[len(SCAN_PREFIX):].decode("ascii")
    except UnicodeDecodeError:
        return Drop("scan", "non-ASCII byte in a +BLESCAN line", line)
    fields = text.split(",")
    if len(fields) not in (5, 6):  # some builds add <adv_type> after <addr_type>
        return Drop("scan", f"{len(fields)} fields, a +BLESCAN line has 5", line)
    addr, rssi, adv, rsp, addr_type = fields[:5]
    m_addr, m_adv, m_rsp = _ADDR.fullmatch(addr), _HEX.fullmatch(adv), _HEX.fullmatch(rsp)
    if m_addr is None:
        return Drop("scan", f"address {addr!r} is not aa:bb:cc:dd:ee:ff", line)
    if m_adv is None or m_rsp is None:
        return Drop("scan", "advertising or scan response data is not hex", line)
    if not re.fullmatch(r"-?\d{1,3}", rssi) or not -128 <= int(rssi) <= 20:
        return Drop("scan", f"RSSI {rssi!r} not a whole dBm in -128..20", line)
    if addr_type not in ("0", "1", "2", "3"):
        return Drop("scan", f"address type {addr_type!r} not 0..3", line)
    return ScanReport(m_addr.group(1).replace(":", "").upper(), int(rssi), bytes.fromhex(m_adv.group(1)),
                      bytes.fromhex(m_rsp.group(1)), int(addr_type))


def encode_scan(report: ScanReport) -> bytes:
    """The line the firmware prints for ``report`` (CR LF included)."""
    a = report.address.lower()
    addr = ":".join(a[i : i + 2] for i in range(0, 12, 2))
    return (f'+BLESCAN:"{addr}",{report.rssi_dbm},{report.adv_data.hex()},{report.scan_rsp.hex()},'
            f"{report.addr_type}\r\n").encode()


class EspAtDecoder:
    """Bytes in any chunking -> items, in order. ``counters`` counts items by kind and drops
    as ``drop.<reason>`` (``scan``: a malformed report; ``oversize``: a line past MAX_LINE;
    ``garbage``: a line that is none of the above, e.g. after a baud mismatch)."""

    def __init__(self) -> None:
        self._rest = b""
        self._discarding = False
        self.counters: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[Any]:
        out: list[Any] = []
        if self._discarding:  # the tail of an oversize line, skipped to its end and never held
            end = data.find(b"\n")
            if end < 0:
                return out
            data, self._discarding = data[end + 1 :], False
        lines = (self._rest + data).split(b"\n")
        rest = lines.pop().lstrip(b"\r")  # a line is judged without its CRs (_line strips them)
        for raw in lines:
            item = self._line(raw.strip(b"\r"))
            if item is not None:
                out.append(item)
        if len(rest.rstrip(b"\r")) > MAX_LINE:  # the same test _line makes, whatever the chunking
            out.append(Drop("oversize", f"line longer than {MAX_LINE} bytes", rest[:64]))
            rest, self._discarding = b"", True
        # Past MAX_LINE + 1 only CRs are held: one is enough to make any further byte but LF an
        # oversize, and LF gives the same line whatever their number.
        self._rest = rest[: MAX_LINE + 1]
        for item in out:
            self.counters["drop." + item.reason if item.kind == "drop" else item.kind] += 1
        return out

    def _line(self, line: bytes) -> Any:
        if not line.strip():
            return None
        if len(line) > MAX_LINE:
            return Drop("oversize", f"line longer than {MAX_LINE} bytes", line[:64])
        if line.startswith(SCAN_PREFIX):
            return parse_scan(line)
        try:
            text = line.decode("ascii").strip()
        except UnicodeDecodeError:
            return Drop("garbage", "non-ASCII line", line[:64])
        if text in ("OK", "ERROR", "FAIL", "SEND FAIL"):
            return Final(text == "OK")
        if text in ("ready", "+BLESCANDONE", "busy p..."):
            return Event(text.lstrip("+").lower(), text)
        if text.upper().startswith("AT"):
            return Event("echo", text)
        m = re.fullmatch(r"\+([A-Z0-9_]+):(.*)", text)
        if m:
            return Info(m.group(1), m.group(2))
        return Drop("garbage", "not an ESP-AT line", line[:64])
