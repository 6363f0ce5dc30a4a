"""Plain JSON-ready dicts for decoded items: ``kind`` first, bytes as hex."""

from __future__ import annotations

from typing import Any


def _plain(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray)):
        return value.hex()
    if isinstance(value, tuple) and hasattr(value, "_asdict"):
        return {k: _plain(v) for k, v in value._asdict().items()}
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def as_dict(item: Any) -> dict[str, Any]:
    """``{"kind": ..., <fields>}`` for any decoded item or drop of either protocol."""
    return {"kind": item.kind, **{k: _plain(v) for k, v in item._asdict().items()}}


def from_dict(fields: dict[str, Any]) -> Any:
    """The item :func:`as_dict` made ``fields`` from (``kind`` picks the type; extra keys such as
    a server's ``device``/``t``/``n`` are ignored). ValueError when the kind is unknown or the
    fields do not fit it."""
    from construct import Bytes, GreedyBytes

    from rfhoming.protocol.drop import Drop
    from rfhoming.protocol.frames.records import RECORD_TYPES, AntennaReading
    from rfhoming.protocol.uconnect import items

    kind = fields.get("kind")
    text_types = {cls.kind: cls for cls in (items.AngleEvent, items.TagData, items.Startup, items.Echo,
                                            items.InfoLine, items.FinalCode, items.UnknownLine, Drop)}
    record_types = {rt.kind: rt for rt in RECORD_TYPES.values()}
    try:
        if kind in text_types:
            cls = text_types[kind]
            values = {k: fields[k] for k in cls._fields if k in fields}
            for name in ("payload", "raw"):  # the bytes fields
                if name in values:
                    values[name] = bytes.fromhex(values[name])
            return cls(**values)
        if kind in record_types:
            rt = record_types[kind]
            binary = {sc.name for sc in rt.body.subcons if isinstance(sc.subcon, Bytes) or sc.subcon is GreedyBytes}
            values = {k: fields[k] for k in rt.cls._fields}
            for name in binary & set(values):
                values[name] = bytes.fromhex(values[name])
            if "antennas" in values:
                values["antennas"] = tuple(AntennaReading(**a) for a in values["antennas"])
            for name, value in values.items():  # arrays decode as tuples
                if isinstance(value, list):
                    values[name] = tuple(value)
            return rt.cls(**values)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"fields do not make a {kind}: {exc}") from None
    raise ValueError(f"unknown item kind {kind!r}")


H4_PACKETS = {0x01: "command", 0x02: "acl", 0x03: "sco", 0x04: "event", 0x05: "iso"}
"""H4 indicator -> packet type (Bluetooth Core Specification v5.4, Vol 4, Part A, 2)."""


def decoded_as_dict(item: Any) -> dict[str, Any]:
    """:func:`as_dict`, and a JSON form for the three decoders of the device table whose items are
    not kind-named tuples: an H4 packet (bytes: ``h4_packet`` with its type and bytes), a MAVLink
    message (``mavlink_message`` with its type, sender and fields) and a ROS 2 sample (``(record, message)``: ``ros2_sample`` with its topic, type and fields, or
    ``message: null`` for a type rfhoming does not read)."""
    if isinstance(item, (bytes, bytearray)):
        return {"kind": "h4_packet", "type": H4_PACKETS.get(item[0], "unknown"), "raw": item.hex()}
    if hasattr(item, "get_type") and hasattr(item, "to_dict"):  # a MAVLink message (pymavlink's)
        fields = {k: v for k, v in item.to_dict().items() if k != "mavpackettype"}
        return {"kind": "mavlink_message", "type": item.get_type(), "system": item.get_srcSystem(),
                "component": item.get_srcComponent(), "fields": _plain(fields)}
    if isinstance(item, tuple) and not hasattr(item, "kind") and len(item) == 2:
        record, message = item
        return {"kind": "ros2_sample", "topic": record.topic, "type": record.type,
                "message": None if message is None else _plain(message)}
    return as_dict(item)
