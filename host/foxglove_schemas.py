"""JSON schemas of the live view's JSON channels, so Foxglove's Plot and Raw Messages panels
list their fields. Written out by hand from the items and run log records they carry
(protocol/uconnect/items.py AngleEvent, protocol/frames/records.py, host/homing/loop.py)."""

from __future__ import annotations

from typing import Any

NUM, INT, STR = {"type": "number"}, {"type": "integer"}, {"type": "string"}
NULLABLE_NUM = {"type": ["number", "null"]}
BLE_ADDRESS = {**STR, "pattern": "^[0-9A-F]{12}$", "description": "BLE address, MSB first, upper-case hex"}
XY = {"type": ["array", "null"], "items": NUM, "minItems": 2, "maxItems": 2, "description": "x, y (m)"}


def _object(title: str, description: str, properties: dict[str, Any], required: tuple[str, ...]) -> dict[str, Any]:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
            "type": "object", "properties": properties, "required": list(required)}


_DEVICE = {"device": {**STR, "description": "the port the item came from"},
           "t": {**NUM, "description": "the stamp of the message (s)"}, "kind": STR}
_FRAMED = {**_DEVICE, "node_id": INT, "seq": INT, "t_us": {**INT, "description": "the node's clock (µs)"}}

SCHEMAS: dict[str, dict[str, Any]] = {
    "/rfhoming/aoa": _object("rfhoming.AngleEvent", "A +UUDF angle event of an XPLR-AOA (board frame, degrees)", {
        **_DEVICE, "instance_id": STR, "anchor_id": STR, "azimuth": {**INT, "description": "deg, board frame"},
        "elevation": INT, "rssi1": {**INT, "description": "dBm"}, "reserved": INT, "channel": INT, "user_str": STR,
        "timestamp_ms": INT, "seq": {"type": ["integer", "null"]}, "azimuth_raw": {"type": ["integer", "null"]},
        "elevation_raw": {"type": ["integer", "null"]}}, ("device", "t", "azimuth", "rssi1")),
    "/rfhoming/ble": _object("rfhoming.AdvReport", "A BLE scan result (record 0x01)", {
        **_FRAMED, "address": BLE_ADDRESS, "addr_type": INT, "adv_props": INT,
        "rssi_dbm": INT, "tx_power_dbm": INT, "channel": INT, "ad": STR}, ("device", "t", "rssi_dbm")),
    "/rfhoming/antennas": _object("rfhoming.AntennaSet", "One emitter frame on the four dishes (record 0x03)", {
        **_FRAMED, "emitter_seq": INT, "channel": INT, "page": INT, "rssi_base_dbm": INT, "valid_mask": INT,
        "antennas": {"type": "array", "minItems": 4, "maxItems": 4, "items": {
            "type": "object", "properties": {"ed": INT, "lqi": INT, "dt_us": INT}}}}, ("device", "t", "antennas")),
    "/rfhoming/measurement": _object("rfhoming.Measurement", "A reading the homing loop used (run log)", {
        "kind": STR, "t": {**NUM, "description": "robot time (s)"}, "source": STR,
        "theta_s": {**NUM, "description": "S0 bearing, robot frame (rad)"}, "distance": NUM,
        "theta": {**NUM, "description": "S2 bearing (rad)"}, "range": NUM, "azimuth": NUM, "rssi": NUM,
        "address": BLE_ADDRESS},
        ("t", "source")),
    "/rfhoming/command": _object("rfhoming.Command", "A velocity command (run log)", {
        "kind": STR, "t": NUM, "v": {**NUM, "description": "m/s"}, "w": {**NUM, "description": "rad/s"},
        "note": STR}, ("t", "v", "w")),
    "/rfhoming/estimate": _object("rfhoming.Estimate", "The controller's estimate at a decision (run log)", {
        "kind": STR, "t": NUM, "phase": STR, "goal": XY, "g_p": XY, "g_v": XY, "fix": XY, "offset": XY,
        "pose": {"type": "array", "items": NUM, "minItems": 3, "maxItems": 3, "description": "x, y (m), theta (rad)"}},
        ("t",)),
}
