"""The site bus: MQTT topics and JSON payloads between gateways and locate workers (sans-IO).

A site's gateways (a small computer per few anchors) publish the angle events they decode; locate
workers subscribe, fix every tag and publish positions (docs/protocol.md, "Site bus (MQTT)").

- ``rfhoming/SITE/angles/PARTITION``: a gateway's batch of angle events for the tags of one
  partition, ``crc32(tag id) mod partitions``, so every anchor's events of one tag reach the same
  worker whichever gateway heard them.
- ``rfhoming/SITE/positions/TAG``: one position per tag and output tick.
- ``rfhoming/SITE/workers/WORKER``: "online" (retained) while a worker lives, its MQTT will
  "offline" when it goes; the live set decides who owns which partitions (:func:`owner`).

Nothing here does I/O: the host's client (host/sitebus.py) and the emulated gateways use it.
"""

from __future__ import annotations

import hashlib
import json
import math
import zlib
from dataclasses import dataclass
from typing import Any

from rfhoming.protocol.errors import Error

VERSION = 1
"""Payload version; a worker drops (and counts) a batch of another version."""

DEFAULT_PARTITIONS = 8


class PayloadError(Error, ValueError):
    """A site-bus message that is not what docs/protocol.md describes (dropped and counted)."""


def partition(tag: str, partitions: int) -> int:
    """The partition of a tag: CRC-32 (zlib's, the same on every machine) of its id, mod the count."""
    return zlib.crc32(tag.encode()) % partitions


def angles_topic(site: str, part: int | str) -> str:
    return f"rfhoming/{site}/angles/{part}"


def positions_topic(site: str, tag: str) -> str:
    return f"rfhoming/{site}/positions/{tag}"


def workers_topic(site: str, worker: str) -> str:
    return f"rfhoming/{site}/workers/{worker}"


def owner(part: int, workers: list[str] | set[str]) -> str | None:
    """Which live worker owns a partition: rendezvous (highest-random-weight) hashing, so every
    worker computes the same answer from the same live set, and a worker that goes moves only
    its own partitions."""
    if not workers:
        return None
    return max(workers, key=lambda w: hashlib.blake2b(f"{w}/{part}".encode(), digest_size=8).digest())


@dataclass(frozen=True)
class AngleBatch:
    """One gateway's angle events for one partition since its last flush.

    ``events`` rows: (host receive time s, anchor id, tag id, azimuth deg, elevation deg), times on
    the gateway's clock; ``offset_s`` is the gateway's own estimate of its clock minus site time (0
    when it has none: the worker measures the rest, docs/protocol.md); ``sent`` is the gateway's
    clock at publishing; ``seq`` counts the gateway's batches on this partition, so a gap is a loss."""

    gateway: str
    seq: int
    sent: float
    offset_s: float
    events: list[tuple[float, str, str, float, float]]

    def encode(self) -> bytes:
        return json.dumps({"v": VERSION, "gw": self.gateway, "seq": self.seq, "sent": round(self.sent, 6),
                           "offset_s": round(self.offset_s, 6),
                           "events": [[round(t, 6), a, tag, az, el] for t, a, tag, az, el in self.events]},
                          separators=(",", ":")).encode()


def decode_angles(payload: bytes) -> AngleBatch:
    """An angle batch from its JSON; PayloadError for anything else."""
    try:
        raw = json.loads(payload)
        if not isinstance(raw, dict) or raw.get("v") != VERSION:
            raise PayloadError(f"not a version-{VERSION} angle batch")
        events = raw["events"]
        if not isinstance(events, list):
            raise PayloadError("events is not a list")
        rows = []
        for t, a, tag, az, el in events:
            t, az, el = float(t), float(az), float(el)
            if not (isinstance(a, str) and isinstance(tag, str) and math.isfinite(t)
                    and -90.0 <= az <= 90.0 and -90.0 <= el <= 90.0):
                raise PayloadError("an event row is not [time, anchor, tag, azimuth, elevation]")
            rows.append((t, a, tag, az, el))
        batch = AngleBatch(str(raw["gw"]), int(raw["seq"]), float(raw["sent"]), float(raw["offset_s"]), rows)
    except PayloadError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise PayloadError(f"malformed angle batch ({type(exc).__name__}: {exc})") from None
    if not (math.isfinite(batch.sent) and math.isfinite(batch.offset_s)):
        raise PayloadError("sent or offset_s is not a finite number")
    return batch


def position_payload(t: float, tag: str, point: Any, covariance: Any, anchors: list[str], rejected: list[str],
                     quality: float, worker: str, latency_s: float | None = None) -> bytes:
    """A position as JSON: metres, site frame (REP 103: x, y on the floor, z up), covariance m^2,
    ``quality`` = chi-square of the rays about the fix per degree of freedom (about 1 = as expected),
    ``worker`` the worker that made it, ``latency_s`` its age: publishing time minus the newest angle's."""
    body: dict[str, Any] = {
        "v": VERSION, "t": round(t, 6), "tag": tag,
        "x": round(float(point[0]), 3), "y": round(float(point[1]), 3), "z": round(float(point[2]), 3),
        "cov": [[round(float(v), 5) for v in row] for row in covariance],
        "anchors": anchors, "rejected": rejected, "quality": round(quality, 3), "worker": worker}
    if latency_s is not None:
        body["latency_s"] = round(latency_s, 4)
    return json.dumps(body, separators=(",", ":")).encode()

