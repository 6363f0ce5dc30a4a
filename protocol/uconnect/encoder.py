"""Write what the XPLR-AOA board writes, byte for byte, in each firmware dialect.

Used by the firmware model and by tests; the host never encodes events. Every URC is framed
``\\r\\n<URC>\\r\\n``; a command answer is ``\\r\\n`` + information lines each ending ``\\r\\n`` +
``OK\\r\\n`` or ``ERROR\\r\\n`` (the echo of the command comes before it, written by the caller
as received).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence

from rfhoming.protocol.uconnect.decoder import (
    AZIMUTH_RANGE,
    CHANNEL_RANGE,
    MAX_STRING,
    RSSI_RANGE,
    SEQ_RANGE,
    TIMESTAMP_RANGE,
)
from rfhoming.protocol.uconnect.items import AngleEvent


class Dialect(enum.Enum):
    """How a firmware generation writes ``+UUDF`` (see docs/protocol.md)."""

    V1_0 = "1.0"
    """9 fields; field 5 is the second polarisation's RSSI; channel 37..39."""
    V1_2 = "1.2"
    """9 fields; field 5 is "reserved" (real 9-field lines carry 6, 8 there, not 0)."""
    V2 = "2.x"
    """10 fields: adds the periodic-advertising event counter; channel 0..36; field 5
    "reserved" (real logs show -43, 6, 8)."""
    EMBED = "embed"
    """u-locateEmbed with AT+UDFCFG=121,1: 12 fields, the unsmoothed angles appended."""

    @property
    def field_count(self) -> int:
        return {Dialect.V1_0: 9, Dialect.V1_2: 9, Dialect.V2: 10, Dialect.EMBED: 12}[self]


def _check(value: int, name: str, valid: range) -> int:
    if value not in valid:
        raise ValueError(f"{name} {value} out of range {valid.start}..{valid.stop - 1}")
    return value


def _quoted(text: str, name: str) -> str:
    if len(text) > MAX_STRING or '"' in text or not text.isascii():
        raise ValueError(f"{name} must be ASCII, without quotes, at most {MAX_STRING} chars")
    return f'"{text}"'


def encode_angle_event(event: AngleEvent, dialect: Dialect) -> bytes:
    """One ``+UUDF`` URC as ``dialect`` writes it; raises ValueError on out-of-range fields."""
    if len(event.instance_id) != 12 or not all(c in "0123456789ABCDEF" for c in event.instance_id):
        raise ValueError("instance_id must be 12 upper-case hex digits")
    fields = [
        event.instance_id,
        str(_check(event.rssi1, "rssi1", RSSI_RANGE)),
        str(_check(event.azimuth, "azimuth", AZIMUTH_RANGE)),
        str(_check(event.elevation, "elevation", AZIMUTH_RANGE)),
        str(_check(event.reserved, "reserved", RSSI_RANGE)),
        str(_check(event.channel, "channel", CHANNEL_RANGE)),
        _quoted(event.anchor_id, "anchor_id"),
        _quoted(event.user_str, "user_str"),
        str(_check(event.timestamp_ms, "timestamp_ms", TIMESTAMP_RANGE)),
    ]
    if dialect in (Dialect.V2, Dialect.EMBED):
        if event.seq is None:
            raise ValueError(f"dialect {dialect.value} needs the event counter (seq)")
        fields.append(str(_check(event.seq, "seq", SEQ_RANGE)))
    if dialect is Dialect.EMBED:
        raw_az = event.azimuth if event.azimuth_raw is None else event.azimuth_raw
        raw_el = event.elevation if event.elevation_raw is None else event.elevation_raw
        fields.append(str(_check(raw_az, "azimuth_raw", AZIMUTH_RANGE)))
        fields.append(str(_check(raw_el, "elevation_raw", AZIMUTH_RANGE)))
    return b"\r\n+UUDF:" + ",".join(fields).encode("ascii") + b"\r\n"


def encode_tag_data(instance_id: str, payload: bytes) -> bytes:
    """A ``+UUDFP`` URC (2.x): the tag's periodic-advertising payload in upper-case hex."""
    return f"\r\n+UUDFP:{instance_id},{payload.hex().upper()}\r\n".encode("ascii")


def encode_answer(info_lines: Sequence[str] = (), ok: bool = True) -> bytes:
    """The answer that follows a command's echo: info lines, then ``OK`` or ``ERROR``."""
    body = "".join(line + "\r\n" for line in info_lines)
    return ("\r\n" + body + ("OK" if ok else "ERROR") + "\r\n").encode("ascii")


def encode_startup() -> bytes:
    """The boot banner after power-up, reset or ``AT+CPWROFF``."""
    return b"\r\n+STARTUP\r\n"
