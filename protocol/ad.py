"""Advertising Data (AD) structures, the payload of BLE advertisements: length, type, data
(Bluetooth Core Specification Supplement, Part A). Enough to filter receivers' reports by the
advertiser's local name, an iBeacon payload or an Eddystone service."""

from __future__ import annotations

from collections.abc import Iterator

LOCAL_NAME_SHORT, LOCAL_NAME = 0x08, 0x09
UUID16_INCOMPLETE, UUID16_COMPLETE, SERVICE_DATA_16, MANUFACTURER = 0x02, 0x03, 0x16, 0xFF
EDDYSTONE_UUID = 0xFEAA
APPLE, IBEACON_PREFIX = 0x004C, b"\x02\x15"


def structures(ad: bytes) -> Iterator[tuple[int, bytes]]:
    """(type, data) of each well-formed structure; stops at a zero length or a truncated one."""
    i = 0
    while i < len(ad):
        n = ad[i]
        if n == 0 or i + 1 + n > len(ad):
            return
        yield ad[i + 1], ad[i + 2 : i + 1 + n]
        i += 1 + n


def local_name(ad: bytes) -> str | None:
    for kind, data in structures(ad):
        if kind in (LOCAL_NAME, LOCAL_NAME_SHORT):
            return data.decode("utf-8", "replace")
    return None


def is_ibeacon(ad: bytes) -> bool:
    return any(kind == MANUFACTURER and len(data) >= 25 and int.from_bytes(data[:2], "little") == APPLE
               and data[2:4] == IBEACON_PREFIX for kind, data in structures(ad))


def is_eddystone(ad: bytes) -> bool:
    for kind, data in structures(ad):
        if kind in (UUID16_INCOMPLETE, UUID16_COMPLETE) and any(
                int.from_bytes(data[i : i + 2], "little") == EDDYSTONE_UUID for i in range(0, len(data) - 1, 2)):
            return True
        if kind == SERVICE_DATA_16 and len(data) >= 2 and int.from_bytes(data[:2], "little") == EDDYSTONE_UUID:
            return True
    return False
