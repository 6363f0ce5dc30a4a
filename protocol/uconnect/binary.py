"""u-locateEmbed binary output (``AT+UDFCFG=7,2``): frames ``FE <type> <len16 LE> <payload>``.

No u-blox document describes it. The only public parser (docs/protocol.md, "Binary output")
reads type 0x01 as an angle with the azimuth as a signed byte at payload offset 6. Everything
else in :data:`ANGLE_LAYOUT` -- the 6-byte tag id before it, elevation, RSSI, channel,
timestamp and counter after it -- is *assumed* (the emulator's convention), so only the
azimuth of a decoded event is vouched for.
"""

from __future__ import annotations

import struct

from rfhoming.protocol.uconnect.items import AngleEvent, Drop

SYNC = 0xFE
ANGLE = 0x01
MAX_PAYLOAD = 64
"""Longer lengths are taken as a false sync (the public parser's buffer is 128 bytes)."""
ANGLE_LAYOUT = struct.Struct("<6sbbbBiH")
"""id (assumed), azimuth (offset 6, public parser), elevation, rssi, channel, timestamp, seq (assumed)."""


class BinaryDecoder:
    """Sans-IO: ``feed(bytes) -> [AngleEvent | Drop]``; resyncs on the next ``FE``, bounded."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.counters: dict[str, int] = {"frames": 0, "drop.binary_type": 0, "drop.binary_length": 0}

    def feed(self, data: bytes) -> list[AngleEvent | Drop]:
        self._buf += data
        out: list[AngleEvent | Drop] = []
        buf = self._buf
        while True:
            start = buf.find(SYNC)
            if start < 0:
                buf.clear()
                break
            del buf[:start]
            if len(buf) < 4:
                break
            kind, length = buf[1], int.from_bytes(buf[2:4], "little")
            if length > MAX_PAYLOAD:
                del buf[:1]  # a false sync: try the next FE
                continue
            if len(buf) < 4 + length:
                break
            payload = bytes(buf[4:4 + length])
            del buf[:4 + length]
            if kind != ANGLE:
                self.counters["drop.binary_type"] += 1
                out.append(Drop("binary_type", f"frame type 0x{kind:02X}", payload))
            elif length < ANGLE_LAYOUT.size:
                self.counters["drop.binary_length"] += 1
                out.append(Drop("binary_length", f"angle frame of {length} bytes", payload))
            else:
                tag, az, el, rssi, channel, ts, seq = ANGLE_LAYOUT.unpack_from(payload)
                if not (-90 <= az <= 90 and -90 <= el <= 90):
                    self.counters["drop.binary_length"] += 1
                    out.append(Drop("binary_length", f"angle {az}/{el} out of range", payload))
                    continue
                self.counters["frames"] += 1
                out.append(AngleEvent(tag.hex().upper(), rssi, az, el, 0, channel, "", "", ts, seq))
        return out
