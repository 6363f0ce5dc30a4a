"""rfhoming's binary records, declared once with construct (protocols.md §3).

These declarations are the single source of truth. From them this module derives:

- the record classes (NamedTuples: header fields ``node_id, seq, t_us``, then the body fields,
  without the length fields that only describe a tail),
- the ``struct`` layouts of the hot path (:mod:`rfhoming.protocol.frames.fast`), so the decoder never
  interprets a declaration per field,
- the reference parser and builder used by tests and benchmarks (:func:`parse_inner`,
  :func:`build_inner`).

Every integer is little-endian. ``inner = header | body | crc16`` with CRC-16/CCITT-FALSE over
header+body; on the wire ``00 | COBS(inner) | 00``.
"""

from __future__ import annotations

import binascii
from collections import namedtuple
from dataclasses import dataclass
from typing import Any

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
    cls: type


HEADER_FIELDS = ("node_id", "seq", "t_us")

AntennaReading = namedtuple("AntennaReading", [sc.name for sc in ANTENNA.subcons])


def _body_fields(body: Struct) -> list[str]:
    """Body fields a record carries: every named field except tail lengths (Rebuild)."""
    return [sc.name for sc in body.subcons if not isinstance(sc.subcon, Rebuild)]


def _declare(code: int, kind: str, class_name: str, body: Struct) -> RecordType:
    base = namedtuple(class_name, [*HEADER_FIELDS, *_body_fields(body)])
    cls = type(class_name, (base,), {"__slots__": (), "kind": kind, "type_code": code, "to_dict": as_dict})
    return RecordType(code, kind, body, cls)


RECORD_TYPES: dict[int, RecordType] = {
    rt.code: rt
    for rt in (
        _declare(0x01, "adv_report", "AdvReport", ADV_REPORT),
        _declare(0x02, "rf_frame", "RfFrame", RF_FRAME),
        _declare(0x03, "antenna_set", "AntennaSet", ANTENNA_SET),
        _declare(0x10, "status", "Status", STATUS),
        _declare(0x20, "odometry", "Odometry", ODOMETRY),
        _declare(0x21, "velocity_command", "VelocityCommand", VELOCITY_COMMAND),
        _declare(0x22, "range_scan", "RangeScan", RANGE_SCAN),
        _declare(0x23, "range_scan_v2", "RangeScanV2", RANGE_SCAN_V2),
        _declare(0x7F, "log_text", "LogText", LOG_TEXT),
        _declare(0x80, "node_command", "NodeCommand", NODE_COMMAND),
    )
}

AdvReport = RECORD_TYPES[0x01].cls
RfFrame = RECORD_TYPES[0x02].cls
AntennaSet = RECORD_TYPES[0x03].cls
Status = RECORD_TYPES[0x10].cls
Odometry = RECORD_TYPES[0x20].cls
VelocityCommand = RECORD_TYPES[0x21].cls
RangeScan = RECORD_TYPES[0x22].cls
RangeScanV2 = RECORD_TYPES[0x23].cls
LogText = RECORD_TYPES[0x7F].cls
NodeCommand = RECORD_TYPES[0x80].cls

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
    return INNER.build({"fields": {"value": {"header": header, "body": body}}}, size=size)


