"""Sans-IO incremental decoder for the u-connectLocate text stream.

Bytes in any chunking go in through :meth:`UConnectDecoder.feed`; decoded items come out in
arrival order. Lines end in CR, LF or CRLF; blank lines (the ones around every URC) are
skipped. A line is at most :data:`MAX_LINE` bytes: a longer one is discarded up to the next
line end and counted once, so memory never grows without bound. A line with NUL or
non-ASCII bytes, or a ``+UUDF`` with a field out of range, becomes a :class:`Drop` with a
reason -- never a half-parsed event.

The ``+UUDF`` hot path splits on quotes and commas and converts the small integers with
dictionary look-ups that are also the range checks (a value ``%d`` would never print, such as
``+5`` or ``020``, is not in the table and is rejected). Anything the fast path refuses goes
to :func:`parse_angle_event`, the strict quote-aware parser that also says why. Where the C
accelerator is built (:mod:`rfhoming.protocol.accel`), its ``scan_uudf`` does the splitting and the
common ``+UUDF`` lines and hands every other line back here as bytes.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from rfhoming.protocol.accel import ACCEL
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

MAX_LINE = 512
"""Longest accepted line in bytes, without its terminator."""

MAX_STRING = 30
"""Longest anchor id or user string (AT+UDFCFG tags 2 and 4)."""

AZIMUTH_RANGE = range(-90, 91)
RSSI_RANGE = range(-127, 21)
CHANNEL_RANGE = range(0, 40)
SEQ_RANGE = range(0, 1 << 16)
TIMESTAMP_RANGE = range(-(1 << 31), 1 << 31)

_ANGLE = {b"%d" % i: i for i in AZIMUTH_RANGE}
_RSSI = {b"%d" % i: i for i in RSSI_RANGE}
_CHANNEL = {b"%d" % i: i for i in CHANNEL_RANGE}
_HEX = b"0123456789ABCDEFabcdef"

#: ``+XXX:`` prefixes that only ever answer a command (never unsolicited).
ANSWER_PREFIXES = frozenset(
    {b"+UMLA", b"+UDFCFG", b"+UDFFILT", b"+UMRS", b"+GMI", b"+GMM", b"+GMR", b"+CGMR"}
)

_new = tuple.__new__


def _is_hex_id(raw: bytes) -> bool:
    return len(raw) == 12 and not raw.translate(None, _HEX)


def _fast_angle_event(line: bytes) -> AngleEvent | None:
    """The common case, fast; ``None`` for anything unusual (the strict parser decides)."""
    q = line.split(b'"')
    if len(q) != 5 or q[2] != b",":
        return None
    h = q[0].split(b",")
    t = q[4].split(b",")
    if len(h) != 7 or h[6] or t[0] or len(q[1]) > MAX_STRING or len(q[3]) > MAX_STRING:
        return None
    idb = h[0][6:]
    if len(idb) != 12 or idb.translate(None, _HEX):
        return None
    r1 = _RSSI.get(h[1])
    az = _ANGLE.get(h[2])
    el = _ANGLE.get(h[3])
    r2 = _RSSI.get(h[4])
    ch = _CHANNEL.get(h[5])
    if r1 is None or az is None or el is None or r2 is None or ch is None:
        return None
    n = len(t)
    if n not in (2, 3, 5):  # 9, 10 or 12 fields
        return None
    ts_text = t[1]
    if ts_text.isdigit() and ts_text[0] != 48 and len(ts_text) < 10:  # common case: positive, < 1e9 ms
        ts: int | None = int(ts_text)
    else:
        ts = _strict_int(ts_text)
        if ts is None or ts not in TIMESTAMP_RANGE:
            return None
    seq = az_raw = el_raw = None
    if n >= 3:
        seq = _strict_int(t[2])
        if seq is None or seq not in SEQ_RANGE:
            return None
        if n == 5:
            az_raw = _ANGLE.get(t[3])
            el_raw = _ANGLE.get(t[4])
            if az_raw is None or el_raw is None:
                return None
    return _new(
        AngleEvent,
        (idb.decode(), r1, az, el, r2, ch, q[1].decode(), q[3].decode(), ts, seq, az_raw, el_raw),
    )


def _strict_int(raw: bytes) -> int | None:
    """A decimal integer exactly as printf ``%d`` writes it (no '+', spaces, leading zeros)."""
    digits = raw[1:] if raw[:1] == b"-" else raw
    if not digits.isdigit() or (digits[:1] == b"0" and (len(digits) > 1 or raw != digits)):
        return None
    return int(raw)


def _split_fields(body: bytes) -> list[bytes] | str:
    """Split on commas outside double quotes; quoted fields keep their quotes."""
    fields: list[bytes] = []
    start = 0
    quoted = False
    for i, c in enumerate(body):
        if c == 0x22:
            quoted = not quoted
        elif c == 0x2C and not quoted:
            fields.append(body[start:i])
            start = i + 1
    if quoted:
        return "unterminated quoted string"
    fields.append(body[start:])
    return fields


def _int_field(raw: bytes, name: str, valid: range) -> int | str:
    """A strict decimal integer as printf %d writes it, inside ``valid``; else an error text."""
    value = _strict_int(raw)
    if value is None:
        return f"{name} {raw.decode(errors='replace')!r} is not an integer"
    if value not in valid:
        return f"{name} {value} out of range {valid.start}..{valid.stop - 1}"
    return value


def _string_field(raw: bytes, name: str) -> str | tuple[str]:
    """A quoted string field; a 1-tuple holds the error text."""
    if len(raw) < 2 or raw[:1] != b'"' or raw[-1:] != b'"' or b'"' in raw[1:-1]:
        return (f"{name} must be a double-quoted string",)
    if len(raw) - 2 > MAX_STRING:
        return (f"{name} longer than {MAX_STRING} characters",)
    return raw[1:-1].decode("ascii")


def parse_angle_event(line: bytes) -> AngleEvent | Drop:
    """Strictly parse one ``+UUDF:`` line (no terminator); a :class:`Drop` says what is wrong."""
    fields = _split_fields(line[6:])
    if isinstance(fields, str):
        return Drop("uudf_syntax", fields, line)
    if len(fields) not in (9, 10, 12):
        return Drop("uudf_fields", f"{len(fields)} fields, expected 9, 10 or 12", line)
    if not _is_hex_id(fields[0]):
        return Drop("uudf_range", "instance id must be 12 hex digits", line)
    ints: list[int] = []
    specs = (
        (1, "rssi1", RSSI_RANGE),
        (2, "azimuth", AZIMUTH_RANGE),
        (3, "elevation", AZIMUTH_RANGE),
        (4, "reserved", RSSI_RANGE),
        (5, "channel", CHANNEL_RANGE),
        (8, "timestamp", TIMESTAMP_RANGE),
    )
    for index, name, valid in specs:
        value = _int_field(fields[index], name, valid)
        if isinstance(value, str):
            return Drop("uudf_range", value, line)
        ints.append(value)
    strings: list[str] = []
    for index, name in ((6, "anchor id"), (7, "user string")):
        text = _string_field(fields[index], name)
        if isinstance(text, tuple):
            return Drop("uudf_range", text[0], line)
        strings.append(text)
    extra: list[int | None] = [None, None, None]
    extra_specs = (
        (9, "seq", SEQ_RANGE),
        (10, "azimuth_raw", AZIMUTH_RANGE),
        (11, "elevation_raw", AZIMUTH_RANGE),
    )
    for slot, (index, name, valid) in enumerate(extra_specs):
        if index < len(fields):
            value = _int_field(fields[index], name, valid)
            if isinstance(value, str):
                return Drop("uudf_range", value, line)
            extra[slot] = value
    rssi1, azimuth, elevation, reserved, channel, timestamp = ints
    return AngleEvent(
        fields[0].decode(), rssi1, azimuth, elevation, reserved, channel,
        strings[0], strings[1], timestamp, *extra,
    )


def parse_tag_data(line: bytes) -> TagData | Drop:
    """``+UUDFP:<instance_id>,<hex payload>`` (the payload may be quoted)."""
    fields = _split_fields(line[7:])
    if isinstance(fields, str) or len(fields) != 2:
        return Drop("uudfp_syntax", "expected <instance_id>,<hex>", line)
    idb, payload = fields
    if not _is_hex_id(idb):
        return Drop("uudfp_syntax", "instance id must be 12 hex digits", line)
    payload = payload.strip(b'"')
    if len(payload) % 2 or payload.translate(None, _HEX):
        return Drop("uudfp_syntax", "payload must be an even number of hex digits", line)
    return TagData(idb.decode(), bytes.fromhex(payload.decode()))


def _overlong(head: bytes) -> Drop:
    return Drop("overlong", f"line longer than {MAX_LINE} bytes discarded", head)


class UConnectDecoder:
    """Incremental decoder: ``feed(bytes) -> list[Item]`` in arrival order, bounded memory.

    ``counters`` counts every item by kind and every drop as ``drop.<reason>``.
    """

    def __init__(self, *, pure: bool = False) -> None:
        """``pure=True`` keeps to the Python path even where the C accelerator is built."""
        self._rest = b""
        self._discarding = False
        self._in_answer = False
        self._scan = None if pure or ACCEL is None else ACCEL.scan_uudf
        self.counters: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[Item]:
        """Decode every complete line that ``data`` finishes; keep the unfinished tail."""
        if self._scan is None or self._discarding:
            return self._feed_python(data)
        scanned = self._scan(self._rest, data, AngleEvent)
        if scanned is None:  # the held line grows past MAX_LINE
            return self._feed_python(data)
        out: list[Any]  # events, or lines left to us as bytes
        out, angles, self._rest = scanned
        if angles:
            self.counters["angle"] += angles
        if angles != len(out):  # lines the C path left to us, in order
            out = [x if x.__class__ is not bytes else self._count(self._classify(x)) for x in out]
        if len(self._rest) > MAX_LINE:
            out.extend(self._hold(b""))
        return out

    def _feed_python(self, data: bytes) -> list[Item]:
        cut = max(data.rfind(b"\n"), data.rfind(b"\r")) + 1
        if not cut:
            return self._hold(data)
        segment = self._rest + data[:cut] if self._rest else data[:cut]
        self._rest = data[cut:]
        if self._discarding:
            segment = self._after_overlong(segment)
        out: list[Item] = []
        append = out.append
        clean = segment.isascii() and b"\0" not in segment
        fast = _fast_angle_event
        angles = 0
        for line in segment.splitlines():
            if clean and line.startswith(b"+UUDF:"):
                event = fast(line)
                if event is not None:
                    append(event)
                    angles += 1
                    continue
            if line:
                append(self._count(self._classify(line)))
        if angles:
            self.counters["angle"] += angles
        if len(self._rest) > MAX_LINE:
            out.extend(self._hold(b""))
        return out

    def flush(self) -> list[Item]:
        """End of input: decode a last line that has no terminator."""
        if self._discarding or not self._rest:
            self._rest, self._discarding = b"", False
            return []
        return self.feed(b"\n")

    def _hold(self, data: bytes) -> list[Item]:
        """Keep an unfinished line; past MAX_LINE drop it and skip to its end."""
        if self._discarding:
            return []
        self._rest += data
        if len(self._rest) <= MAX_LINE:
            return []
        head, self._rest, self._discarding = self._rest[:MAX_LINE], b"", True
        return [self._count(_overlong(head))]

    def _after_overlong(self, segment: bytes) -> bytes:
        """Skip what is left of a line already reported as overlong, up to its end."""
        self._discarding = False
        ends = [i for i in (segment.find(b"\r"), segment.find(b"\n")) if i >= 0]
        return segment[min(ends):]

    def _count(self, item: Item) -> Item:
        self.counters["drop." + item.reason if item.kind == "drop" else item.kind] += 1
        return item

    def _classify(self, line: bytes) -> Item:
        if len(line) > MAX_LINE:
            return _overlong(line[:MAX_LINE])
        if b"\0" in line:
            return Drop("nul", "line contains a NUL byte", line)
        if not line.isascii():
            return Drop("non_ascii", "line contains non-ASCII bytes", line)
        if line[:6] == b"+UUDF:":
            return parse_angle_event(line)
        if line[:7] == b"+UUDFP:":
            return parse_tag_data(line)
        text = line.decode("ascii")
        if line == b"+STARTUP":
            self._in_answer = False
            return Startup()
        if line in (b"OK", b"ERROR"):
            self._in_answer = False
            return FinalCode(line == b"OK")
        if line[:2].upper() == b"AT":
            self._in_answer = True
            return Echo(text)
        if line[:1] == b"+" and line.split(b":", 1)[0] in ANSWER_PREFIXES:
            return InfoLine(text)
        if line[:5] == b"$MEAS":
            return UnknownLine(text, "unsupported output format ($MEAS, AT+UDFCFG=7,1)")
        if self._in_answer:
            return InfoLine(text)
        return UnknownLine(text)
