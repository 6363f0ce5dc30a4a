"""The site bus: MQTT topics and JSON payloads between gateways and locate workers (sans-IO).

A site's gateways (a small computer per few anchors) publish the angle events they decode; locate
workers subscribe, fix every tag and publish positions (docs/protocol.md, "Site bus (MQTT)").

- ``rfhoming/SITE/angles/PARTITION``: a gateway's batch of angle events for the tags of one
  partition, ``crc32(tag id) mod partitions``, so every anchor's events of one tag reach the same
  worker whichever gateway heard them.
- ``rfhoming/SITE/positions/TAG``: one position per tag and output tick.
- ``rfhoming/SITE/workers/WORKER``: a worker's claim (retained), made again every heartbeat while
  it lives, its MQTT will "offline" when it goes; the live set decides who owns which partitions
  (:func:`owner`). A claim older than its heartbeats allow counts for nothing (:func:`decode_claim`).

Nothing here does I/O: the host's client (host/sitebus.py) and the emulated gateways use it.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import zlib
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from rfhoming.protocol.errors import Error

VERSION = 2
"""Angle-batch payload version written: 2 is columnar; version 1 (one list per event) is still
read, for gateways not yet upgraded. A worker drops (and counts) a batch of any other version."""

POSITION_VERSION = 2
"""Position payload version: 2 names its site, frame, units and UTC time, the anchors by the ids
the angle batches use, and its quality ``chi2_per_dof`` (version 1: none of that, ``quality``)."""

FRAME = "map"
"""The frame of a position: the site's world-fixed frame, REP 105's ``map`` (REP 103: x, y on the
floor, z up, metres)."""

UNITS = {"x": "m", "y": "m", "z": "m", "cov": "m^2", "t": "s", "latency_s": "s"}
"""Each position's units, in the payload itself (``t``: Unix time, UTC, ``time`` the same instant)."""

DEFAULT_PARTITIONS = 8
MAX_PARTITIONS = 1024
"""A site's partition count is 1..1024: a worker subscribes to each partition it owns, one topic each."""

MAX_PAYLOAD = 4_000_000
"""Bytes of an angle batch a worker parses at most (a gateway splits its batches well below:
MAX_BATCH_EVENTS). JSON's nesting and numbers are unbounded, its parser recursive: a bound on
the bytes bounds what one message can cost."""

MAX_BATCH_EVENTS = 20_000
"""Events a gateway puts in one batch at most (about 300 kB); more go in further batches."""

MAX_ID = 256
"""Characters of a gateway, anchor, tag, worker or site name at most (a board's ids are 12)."""

MAX_SPAN_US = 3_600_000_000
"""A batch's events lie within an hour of its ``t0`` (a flush spans 20 ms): a larger ``dt_us`` is
refused, so every time the worker builds fits int64 and stays finite."""

MAX_SECONDS = 1e10
"""``sent``, ``offset_s`` and ``t0`` are refused beyond +-1e10 s (year 2286 as a Unix time), so the
worker's sums of them stay finite."""

MAX_SEQ = 2**63
"""``seq`` is a whole number in 0..2^63-1 (an int64)."""


class PayloadError(Error, ValueError):
    """A site-bus message that is not what docs/protocol.md describes (dropped and counted)."""


class TopicNameError(Error, ValueError):
    """A site, worker or gateway name that cannot be an MQTT topic level."""


_NOT_IN_A_LEVEL = re.compile("[/+#\x00\ud800-\udfff]")
"""What an MQTT topic level cannot hold: the level separator, the wildcards (a publish to a topic
with them is refused), U+0000 (MQTT 3.1.1 section 1.5.3) and lone surrogates (not UTF-8)."""


def is_level(name: object) -> bool:
    """Whether ``name`` can be one level of a topic: a non-empty string of at most MAX_ID
    characters, none of ``/ + #``, U+0000 or a lone surrogate."""
    return isinstance(name, str) and 0 < len(name) <= MAX_ID and _NOT_IN_A_LEVEL.search(name) is None


def check_level(what: str, name: str) -> str:
    """``name`` as one level of the site bus's topics, or a one-line error saying why not."""
    if not is_level(name):
        raise TopicNameError(f"{what} {name!r}: a site-bus name is 1..{MAX_ID} characters without '/', '+', '#' "
                         "(MQTT's level separator and wildcards) or NUL")
    return name


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


Row = tuple[float, str, str, float, float]
"""One angle event: (host receive time s, anchor id, tag id, azimuth deg, elevation deg)."""


def encode_angles(gateway: str, seq: int, sent: float, offset_s: float, rows: list[Row]) -> bytes:
    """A version-2 angle batch: columns, each tag and anchor id once. Times are whole
    microseconds after ``t0`` (integers parse fastest), angles integers when whole (the firmware
    reports whole degrees), else to 0.001 degree. ``offset_s`` is the gateway's own estimate of its
    clock minus site time (0 when it has none: the worker measures the rest, docs/protocol.md),
    ``sent`` its clock at publishing, ``seq`` counts its batches on this partition (a gap is a loss)."""
    anchors: dict[str, int] = {}
    tags: dict[str, int] = {}
    t0 = min(r[0] for r in rows) if rows else 0.0
    cols = ([round((r[0] - t0) * 1e6) for r in rows], [anchors.setdefault(r[1], len(anchors)) for r in rows],
            [tags.setdefault(r[2], len(tags)) for r in rows])
    ang = ([_number(r[3]) for r in rows], [_number(r[4]) for r in rows])
    return json.dumps({"v": VERSION, "gw": gateway, "seq": seq, "sent": round(sent, 6), "offset_s": round(offset_s, 6),
                       "anchors": list(anchors), "tags": list(tags), "t0": t0, "i": cols, "ang": ang},
                      separators=(",", ":")).encode()


def _number(x: float) -> float | int:
    return int(x) if x == int(x) else round(float(x), 3)


@dataclass(frozen=True)
class AngleBatch:
    """A decoded angle batch, as columns of plain lists: event k at ``t0 + dt_us[k] * 1e-6`` s
    (the gateway's clock) from anchor ``anchors[a[k]]`` of tag ``tags[g[k]]``, azimuth ``az[k]``,
    elevation ``el[k]`` degrees. Lists, not arrays: a batch holds tens of events, and a worker
    joins thousands of batches into one set of arrays per tick (numpy's cost per call, not per batch)."""

    gateway: str
    seq: int
    sent: float
    offset_s: float
    anchors: list[str]
    tags: list[str]
    t0: float
    dt_us: list[int]
    a: list[int]
    g: list[int]
    az: list[float]
    el: list[float]

    @property
    def events(self) -> list[Row]:
        """The rows again (tests and debugging; the worker takes the columns)."""
        return [(self.t0 + d * 1e-6, self.anchors[a], self.tags[g], az, el)
                for d, a, g, az, el in zip(self.dt_us, self.a, self.g, self.az, self.el)]


_NUMBER = (int, float)


def _whole(col: object, n: int | None, what: str, below: int) -> list[int]:
    """A column of whole numbers in 0..below-1: an index within its table, a time within the batch's
    span. Unbounded, JSON's integers reach numpy as OverflowError (10**23 is valid JSON)."""
    if not isinstance(col, list) or (n is not None and len(col) != n) or not all(type(x) is int for x in col):
        raise PayloadError(f"{what} is not a column of whole numbers of the batch's length")
    if col and not (min(col) >= 0 and max(col) < below):
        raise PayloadError(f"{what}: a value is outside 0..{below - 1}")
    return col


def _seconds(raw: dict[str, Any], key: str) -> float:
    x = raw[key]
    if not (type(x) in _NUMBER and abs(x) <= MAX_SECONDS):  # NaN fails it too; so do "1e3" and true
        raise PayloadError(f"{key} is not a number of seconds within +-{MAX_SECONDS:g}")
    return float(x)


def _seq(raw: dict[str, Any]) -> int:
    x = raw["seq"]
    if type(x) is not int or not 0 <= x < MAX_SEQ:
        raise PayloadError(f"seq is not a whole number in 0..{MAX_SEQ - 1}")
    return x


def _angles(col: object, n: int, what: str) -> list[float]:
    if not isinstance(col, list) or len(col) != n or not all(
            type(x) in _NUMBER and -90.0 <= x <= 90.0 for x in col):  # NaN fails the comparison
        raise PayloadError(f"{what} is not a column of angles within -90..90 degrees of the batch's length")
    return col


def _names(raw: dict[str, Any], key: str) -> list[str]:
    """Ids that become topic levels (a tag's position topic) or payload text: each one a level."""
    v = raw[key]
    if not isinstance(v, list) or not all(is_level(x) for x in v):
        raise PayloadError(f"{key} is not a list of ids (1..{MAX_ID} characters, none of / + # or NUL)")
    return v


def _gateway(raw: dict[str, Any]) -> str:
    gw: str = raw["gw"]
    if not is_level(gw):
        raise PayloadError(f"gw is not a gateway name (1..{MAX_ID} characters, none of / + # or NUL)")
    return gw


def _decode_v2(raw: dict[str, Any]) -> AngleBatch:
    anchors, tags = _names(raw, "anchors"), _names(raw, "tags")
    i, ang = raw["i"], raw["ang"]
    if not (isinstance(i, list) and len(i) == 3 and isinstance(ang, list) and len(ang) == 2):
        raise PayloadError("i is not [dt_us, anchor, tag] or ang not [azimuth, elevation]")
    dt = _whole(i[0], None, "dt_us", MAX_SPAN_US)
    n = len(dt)
    a, g = _whole(i[1], n, "anchor", len(anchors)), _whole(i[2], n, "tag", len(tags))
    return AngleBatch(_gateway(raw), _seq(raw), _seconds(raw, "sent"), _seconds(raw, "offset_s"), anchors, tags,
                      _seconds(raw, "t0"), dt, a, g, _angles(ang[0], n, "azimuth"), _angles(ang[1], n, "elevation"))


def _decode_v1(raw: dict[str, Any]) -> AngleBatch:
    events = raw["events"]
    if not isinstance(events, list):
        raise PayloadError("events is not a list")
    rows = []
    for t, a, tag, az, el in events:
        if not (isinstance(a, str) and isinstance(tag, str) and all(type(x) in _NUMBER for x in (t, az, el))
                and math.isfinite(t) and -90.0 <= az <= 90.0 and -90.0 <= el <= 90.0):
            raise PayloadError("an event row is not [time, anchor, tag, azimuth, elevation] (numbers, ids)")
        rows.append((float(t), a, tag, float(az), float(el)))
    return _decode_v2(json.loads(encode_angles(_gateway(raw), _seq(raw), _seconds(raw, "sent"),
                                               _seconds(raw, "offset_s"), rows)))


def decode_angles(payload: bytes) -> AngleBatch:
    """An angle batch from its JSON (version 2, or the older version 1); PayloadError for anything
    else, whatever the bytes: any message costs at most its own parse (bench/fuzz.py, target sitebus)."""
    if len(payload) > MAX_PAYLOAD:
        raise PayloadError(f"an angle batch of {len(payload):,} bytes (at most {MAX_PAYLOAD:,})")
    try:
        raw = json.loads(payload)
        if not isinstance(raw, dict) or type(raw.get("v")) is not int or raw["v"] not in (1, 2):
            raise PayloadError("not a version-1 or version-2 angle batch")
        batch = _decode_v2(raw) if raw["v"] == 2 else _decode_v1(raw)
    except PayloadError:
        raise
    except (ValueError, TypeError, KeyError, OverflowError, RecursionError) as exc:
        # RecursionError: json's parser recurses per nesting level ("[" * 1000 is enough)
        raise PayloadError(f"malformed angle batch ({type(exc).__name__}: {str(exc)[:100]})") from None
    return batch


HEARTBEAT_S = 1.0
"""A worker makes its claim again every second it lives."""

CLAIM_HEARTBEATS = 5
"""A claim counts for five of its heartbeats after it was made (a worker stalled for a few seconds
on a loaded machine keeps its partitions), then for nothing: a retained claim of a worker that
died without its will, or a fake one published once, holds no partition for longer."""

MAX_HEARTBEAT_S = 60.0
"""A claim's ``heartbeat_s`` is in (0, 60]: more would let one claim hold partitions for minutes."""

MAX_CLAIM = 1024
"""Bytes of a claim a worker parses at most (a real one is about 60)."""

OFFLINE = b'{"v":1,"state":"offline"}'
"""A worker's will, and what it says when it stops."""


def encode_claim(t: float, heartbeat_s: float = HEARTBEAT_S) -> bytes:
    """A worker's claim made at Unix time ``t``: it is live until ``CLAIM_HEARTBEATS`` x
    ``heartbeat_s`` later unless it makes it again."""
    return json.dumps({"v": 1, "state": "online", "t": round(t, 3), "heartbeat_s": heartbeat_s},
                      separators=(",", ":")).encode()


def decode_claim(payload: bytes) -> tuple[float, float] | None:
    """A claim's (time made, seconds it counts for), or None for "offline"; PayloadError for
    anything else -- a claim without a time (a retained message of unknown age counts for
    nothing), a time or heartbeat that is not a finite number in range."""
    if len(payload) > MAX_CLAIM:
        raise PayloadError(f"a worker claim of {len(payload):,} bytes (at most {MAX_CLAIM})")
    try:
        raw = json.loads(payload)
    except (ValueError, RecursionError):
        raise PayloadError("a worker claim that is not JSON") from None
    if not (isinstance(raw, dict) and type(raw.get("v")) is int and raw["v"] == 1
            and raw.get("state") in ("online", "offline")):
        raise PayloadError('not a worker claim: {"v":1,"state":"online"|"offline",...}')
    if raw["state"] == "offline":
        return None
    t: Any = raw.get("t")
    beat: Any = raw.get("heartbeat_s")
    if not (type(t) in _NUMBER and 0 <= t <= MAX_SECONDS):  # NaN fails it too
        raise PayloadError(f"a worker claim's t is not a Unix time in 0..{MAX_SECONDS:g} s")
    if not (type(beat) in _NUMBER and 0 < beat <= MAX_HEARTBEAT_S):
        raise PayloadError(f"a worker claim's heartbeat_s is not in (0, {MAX_HEARTBEAT_S:g}] s")
    return float(t), CLAIM_HEARTBEATS * float(beat)


def utc(t: float) -> str:
    """Unix time ``t`` as ISO 8601 UTC to the microsecond (``2026-12-02T00:45:02.500000Z``)."""
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def position_payload(site: str, t: float, tag: str, point: np.ndarray, covariance: np.ndarray, anchors: list[str],
                     rejected: list[str], chi2_per_dof: float, worker: str, latency_s: float | None = None,
                     inconsistent: str | None = None) -> bytes:
    """A position as JSON that says what it is (docs/schemas/position.schema.json): its site, frame
    (FRAME) and units (UNITS) in it, ``t`` Unix time with ``time`` the same instant in ISO 8601 UTC,
    ``anchors``/``rejected`` by the ids the angle batches carry, ``chi2_per_dof`` the rays'
    chi-square about the fix per degree of freedom (about 1 or below: they agree as their sigmas
    say), ``worker`` the worker that made it, ``latency_s`` its age: publishing time minus the
    newest angle's; ``inconsistent``, only on a fix the worker's gate flagged, says why."""
    x, y, z = (round(v, 3) for v in point.tolist())
    t = round(t, 6)
    body: dict[str, Any] = {
        "v": POSITION_VERSION, "site": site, "frame": FRAME, "units": UNITS, "t": t, "time": utc(t), "tag": tag,
        "x": x, "y": y, "z": z, "cov": covariance.round(5).tolist(), "anchors": anchors, "rejected": rejected,
        "chi2_per_dof": round(chi2_per_dof, 3), "worker": worker}
    if latency_s is not None:
        body["latency_s"] = round(latency_s, 4)
    if inconsistent is not None:
        body["inconsistent"] = inconsistent
    return json.dumps(body, separators=(",", ":")).encode()
