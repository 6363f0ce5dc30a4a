"""rfhoming's binary records, declared once with construct (docs/protocol.md §2).

These declarations are the single source of truth. From them this module derives or checks:

- the record classes (NamedTuples: header fields ``node_id, seq, t_us``, then the body fields,
  without the length fields that only describe a tail), written out for type checkers and
  checked against the declarations at import,
- the ``struct`` layouts of the hot path (:mod:`rfhoming.protocol.frames.fast`), so the decoder never
  interprets a declaration per field,
- the reference parser and builder used by tests and benchmarks (:func:`parse_inner`,
  :func:`build_inner`).

Every integer is little-endian. ``inner = header | body | crc16`` with CRC-16/CCITT-FALSE over
header+body; on the wire ``00 | COBS(inner) | 00``.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, NamedTuple

from construct import (
    Array,
    Bytes,
    Checksum,
    FixedSized,
    GreedyBytes,
    GreedyString,
    Int8sl,
    Int8ul,
    Int16sl,
    Int16ul,
    Int32sl,
    Int32ul,
    RawCopy,
    Rebuild,
    Struct,
    Switch,
    len_,
    this,
)
from rfhoming.protocol.jsonable import as_dict

VERSION = 1
MAX_INNER = 1024
"""Largest inner frame (header + body + CRC) in bytes; larger is dropped as oversize."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF); the ESP32 ROM has the same."""
    return binascii.crc_hqx(data, 0xFFFF)


HEADER = Struct(
    "version" / Int8ul,
    "type" / Int8ul,
    "node_id" / Int8ul,
    "seq" / Int16ul,  # per-node record counter, for loss accounting
    "t_us" / Int32ul,  # node clock at reception; wraps every 71.6 min
)

ADV_REPORT = Struct(  # 0x01 ESP32 BLE scan result
    "addr" / Bytes(6),  # LSB first, as on the air
    "addr_type" / Int8ul,
    "adv_props" / Int8ul,
    "rssi_dbm" / Int8sl,  # 127 = not available
    "tx_power_dbm" / Int8sl,  # 127 = not available
    "channel" / Int8ul,  # 37..39, 255 unknown
    "ad_len" / Rebuild(Int8ul, len_(this.ad)),
    "ad" / Bytes(this.ad_len),
)

RF_FRAME = Struct(  # 0x02 AT86RF212 frame received on one antenna
    "antenna" / Int8ul,  # 0..3
    "channel" / Int8ul,
    "page" / Int8ul,
    "trx_ctrl_2" / Int8ul,
    "rssi_base_dbm" / Int8sl,  # RSSI_BASE_VAL the node used
    "ed" / Int8ul,  # 0..84, 255 = no measurement
    "lqi" / Int8ul,
    "rx_status" / Int8ul,  # bit 7 CRC valid, bits 6:4 TRAC status
    "emitter_seq" / Int16ul,
    "psdu_len" / Rebuild(Int8ul, len_(this.psdu)),
    "psdu" / Bytes(this.psdu_len),
)

ANTENNA = Struct(
    "ed" / Int8ul,
    "lqi" / Int8ul,
    "dt_us" / Int16sl,  # offset from the header's t_us
)

ANTENNA_SET = Struct(  # 0x03 one emitter frame as heard on all four antennas
    "emitter_seq" / Int16ul,
    "channel" / Int8ul,
    "page" / Int8ul,
    "rssi_base_dbm" / Int8sl,
    "valid_mask" / Int8ul,  # bit i = antenna i heard the frame
    "antennas" / Array(4, ANTENNA),
)

STATUS = Struct(  # 0x10 node status, 1 Hz
    "device_kind" / Int8ul,  # 1 ESP32 BLE scanner, 2 AT86RF212 node, 3 robot base
    "fw_major" / Int8ul,
    "fw_minor" / Int8ul,
    "fw_patch" / Int8ul,
    "uptime_ms" / Int32ul,
    "tx_dropped" / Int16ul,
    "rx_errors" / Int16ul,
)

ODOMETRY = Struct(  # 0x20 base -> host, 50 Hz
    "x_mm" / Int32sl,
    "y_mm" / Int32sl,
    "theta_urad" / Int32sl,  # within ±π·10⁶
    "v_mm_s" / Int16sl,
    "w_mrad_s" / Int16sl,
    "flags" / Int8ul,  # bit 0 watchdog stop, bit 1 contact, bit 2 motors enabled
)

VELOCITY_COMMAND = Struct(  # 0x21 host -> base
    "v_mm_s" / Int16sl,
    "w_mrad_s" / Int16sl,
    "timeout_ms" / Int16ul,  # the base stops when it expires
)

RANGE_SCAN = Struct(  # 0x22 base -> host, version 1: still decoded, no longer sent
    "angle_min_mrad" / Int16sl,
    "angle_inc_mrad" / Int16sl,  # whole mrad: 181 beams over ±90° end at 85.3°, not 90°
    "count" / Rebuild(Int8ul, len_(this.ranges_mm)),
    "ranges_mm" / Array(this.count, Int16ul),  # 0 = no return
)

RANGE_SCAN_V2 = Struct(  # 0x23 base -> host: a range scan with its exact geometry
    "angle_min_urad" / Int32sl,  # the first beam, counter-clockwise from ahead
    "angle_max_urad" / Int32sl,  # the last beam; beams are evenly spaced between the two
    "range_max_mm" / Int16ul,  # the sensor's own maximum range
    "count" / Rebuild(Int8ul, len_(this.ranges_mm)),
    "ranges_mm" / Array(this.count, Int16ul),  # 0 = no return
)

LOG_TEXT = Struct("text" / GreedyString("utf8"))  # 0x7F firmware log line

NODE_COMMAND = Struct(  # 0x80 host -> node
    "command" / Int8ul,  # 1 set channel/page, 2 start, 3 stop, 4 request status
    "args" / GreedyBytes,  # command 1: <BB channel, page; others: none
)


@dataclass(frozen=True)
class RecordType:
    """One record type: its code, its name (the JSON ``kind``) and its body declaration."""

    code: int
    kind: str
    body: Struct
    cls: type[Any]


HEADER_FIELDS = ("node_id", "seq", "t_us")


class AntennaReading(NamedTuple):
    """One antenna of an :class:`AntennaSet` (``ANTENNA``)."""

    ed: int
    lqi: int
    dt_us: int


# The record classes are written out so that type checkers see their fields; _declare checks each
# against its construct declaration at import, so the two cannot drift apart. A record is a
# NamedTuple of the header and body fields, with ``kind``, ``type_code`` and ``to_dict()`` on a
# subclass (NamedTuple bodies cannot hold typed class attributes).


class _AdvReport(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    addr: bytes
    addr_type: int
    adv_props: int
    rssi_dbm: int
    tx_power_dbm: int
    channel: int
    ad: bytes


class AdvReport(_AdvReport):
    """0x01: an ESP32 BLE scan result."""

    __slots__ = ()
    kind: ClassVar[Literal["adv_report"]] = "adv_report"
    type_code: ClassVar[int] = 0x01
    to_dict = as_dict


class _RfFrame(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    antenna: int
    channel: int
    page: int
    trx_ctrl_2: int
    rssi_base_dbm: int
    ed: int
    lqi: int
    rx_status: int
    emitter_seq: int
    psdu: bytes


class RfFrame(_RfFrame):
    """0x02: an AT86RF212 frame received on one antenna."""

    __slots__ = ()
    kind: ClassVar[Literal["rf_frame"]] = "rf_frame"
    type_code: ClassVar[int] = 0x02
    to_dict = as_dict


class _AntennaSet(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    emitter_seq: int
    channel: int
    page: int
    rssi_base_dbm: int
    valid_mask: int
    antennas: tuple[AntennaReading, ...]


class AntennaSet(_AntennaSet):
    """0x03: one emitter frame as heard on all four antennas."""

    __slots__ = ()
    kind: ClassVar[Literal["antenna_set"]] = "antenna_set"
    type_code: ClassVar[int] = 0x03
    to_dict = as_dict


class _Status(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    device_kind: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    uptime_ms: int
    tx_dropped: int
    rx_errors: int


class Status(_Status):
    """0x10: node status, 1 Hz."""

    __slots__ = ()
    kind: ClassVar[Literal["status"]] = "status"
    type_code: ClassVar[int] = 0x10
    to_dict = as_dict


class _Odometry(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    x_mm: int
    y_mm: int
    theta_urad: int
    v_mm_s: int
    w_mrad_s: int
    flags: int


class Odometry(_Odometry):
    """0x20: the base's pose and speeds, base -> host, 50 Hz."""

    __slots__ = ()
    kind: ClassVar[Literal["odometry"]] = "odometry"
    type_code: ClassVar[int] = 0x20
    to_dict = as_dict


class _VelocityCommand(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    v_mm_s: int
    w_mrad_s: int
    timeout_ms: int


class VelocityCommand(_VelocityCommand):
    """0x21: host -> base."""

    __slots__ = ()
    kind: ClassVar[Literal["velocity_command"]] = "velocity_command"
    type_code: ClassVar[int] = 0x21
    to_dict = as_dict


class _RangeScan(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    angle_min_mrad: int
    angle_inc_mrad: int
    ranges_mm: tuple[int, ...]


class RangeScan(_RangeScan):
    """0x22: base -> host."""

    __slots__ = ()
    kind: ClassVar[Literal["range_scan"]] = "range_scan"
    type_code: ClassVar[int] = 0x22
    to_dict = as_dict


class _RangeScanV2(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    angle_min_urad: int
    angle_max_urad: int
    range_max_mm: int
    ranges_mm: tuple[int, ...]


class RangeScanV2(_RangeScanV2):
    """0x23: base -> host, the scan's exact geometry."""

    __slots__ = ()
    kind: ClassVar[Literal["range_scan_v2"]] = "range_scan_v2"
    type_code: ClassVar[int] = 0x23
    to_dict = as_dict


class _LogText(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    text: str


class LogText(_LogText):
    """0x7F: a firmware log line."""

    __slots__ = ()
    kind: ClassVar[Literal["log_text"]] = "log_text"
    type_code: ClassVar[int] = 0x7F
    to_dict = as_dict


class _NodeCommand(NamedTuple):
    node_id: int
    seq: int
    t_us: int
    command: int
    args: bytes


class NodeCommand(_NodeCommand):
    """0x80: host -> node."""

    __slots__ = ()
    kind: ClassVar[Literal["node_command"]] = "node_command"
    type_code: ClassVar[int] = 0x80
    to_dict = as_dict


Record = (AdvReport | RfFrame | AntennaSet | Status | Odometry | VelocityCommand | RangeScan | RangeScanV2 | LogText
          | NodeCommand)
"""Any record the frame decoder yields."""


def _body_fields(body: Struct) -> list[str]:
    """Body fields a record carries: every named field except tail lengths (Rebuild)."""
    return [sc.name for sc in body.subcons if not isinstance(sc.subcon, Rebuild)]


def _declare(cls: type[Any], body: Struct) -> RecordType:
    """The record type of ``cls``, checked against its declaration ``body``."""
    fields = (*HEADER_FIELDS, *_body_fields(body))
    if cls._fields != fields:
        raise TypeError(f"{cls.__name__} has fields {cls._fields}, its declaration {fields}")
    return RecordType(cls.type_code, cls.kind, body, cls)


if AntennaReading._fields != tuple(sc.name for sc in ANTENNA.subcons):
    raise TypeError(f"AntennaReading has fields {AntennaReading._fields}, ANTENNA declares others")

RECORD_TYPES: dict[int, RecordType] = {
    rt.code: rt
    for rt in (
        _declare(AdvReport, ADV_REPORT),
        _declare(RfFrame, RF_FRAME),
        _declare(AntennaSet, ANTENNA_SET),
        _declare(Status, STATUS),
        _declare(Odometry, ODOMETRY),
        _declare(VelocityCommand, VELOCITY_COMMAND),
        _declare(RangeScan, RANGE_SCAN),
        _declare(RangeScanV2, RANGE_SCAN_V2),
        _declare(LogText, LOG_TEXT),
        _declare(NodeCommand, NODE_COMMAND),
    )
}

INNER = Struct(
    "fields"
    / RawCopy(
        FixedSized(
            this._params.size - 2,  # everything but the CRC, so greedy tails stop before it
            Struct(
                "header" / HEADER,
                "body"
                / Switch(this.header.type, {code: rt.body for code, rt in RECORD_TYPES.items()}),
            ),
        )
    ),
    "crc" / Checksum(Int16ul, crc16, this.fields.data),
)
"""The whole inner frame: the reference parser/builder (slow, interpreted; tests and benches).
Parse and build take ``size=`` (the inner frame's length)."""


def _to_python(value: Any) -> Any:
    """construct Containers/ListContainers -> the record's plain values."""
    if isinstance(value, list):
        if value and isinstance(value[0], dict):
            return tuple(AntennaReading(**{k: v[k] for k in AntennaReading._fields}) for v in value)
        return tuple(value)
    return value


def parse_inner(inner: bytes) -> Any:
    """Reference decode of an inner frame with construct (raises ConstructError on bad input)."""
    parsed = INNER.parse(inner, size=len(inner)).fields.value
    rt = RECORD_TYPES[parsed.header.type]
    header = parsed.header
    if header.version != VERSION:
        raise ValueError(f"version {header.version}")
    body = parsed.body
    values = [_to_python(body[name]) for name in rt.cls._fields[len(HEADER_FIELDS) :]]
    return rt.cls(header.node_id, header.seq, header.t_us, *values)


def build_inner(record: Any) -> bytes:
    """Reference encode of a record into an inner frame with construct."""
    body = record._asdict()
    header = {
        "version": VERSION,
        "type": record.type_code,
        "node_id": body.pop("node_id"),
        "seq": body.pop("seq"),
        "t_us": body.pop("t_us"),
    }
    if "antennas" in body:
        body["antennas"] = [a._asdict() for a in body["antennas"]]
    fields = Struct("header" / HEADER, "body" / RECORD_TYPES[record.type_code].body)
    size = len(fields.build({"header": header, "body": body})) + 2
    inner: bytes = INNER.build({"fields": {"value": {"header": header, "body": body}}}, size=size)
    return inner


