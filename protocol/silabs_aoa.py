"""Silicon Labs' AoA locator over MQTT: its angle topic and JSON payload (sans-IO).

The Gecko SDK's host application ``bt_aoa_host_locator`` publishes, per locator and asset tag,
each angle the RTL library estimates as a flat JSON object on ``silabs/aoa/angle/LOCATOR/TAG``
(docs/protocol.md, "Silicon Labs AoA locator (MQTT)", which cites the SDK's sources for every
name here). Ids are ``ble-pd-`` (public) or ``ble-sr-`` (static random) and the 12 hex digits
of the device's address. Angles are degrees. Nothing here does I/O: the host's source
(host/silabs_source.py) and the emulated locator (emulator/silabs_locator.py) use it.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

from rfhoming.protocol.errors import Error

PREFIX = "silabs/aoa"
"""The SDK's topic root (aoa_topics.h); a deployment may put its locators under another."""

MAX_PAYLOAD = 4096
"""Bytes of one angle message parsed at most: the SDK's is about 200 (seven numbers, cJSON_Print's
indentation); JSON's parser is recursive and its numbers unbounded, so the bytes bound the cost."""

MAX_KEYS = 32
"""Keys of one angle object at most (the SDK writes 5 to 7; newer releases may add some)."""

MAX_ID = 64
"""Characters of a locator or tag id (the SDK's aoa_id_t is char[64]; its topic scan reads 64)."""

_ID = re.compile(r"[A-Za-z0-9_.:-]{1,64}")
"""One topic level that is an id: no ``/``, ``+``, ``#``, spaces or controls."""

ID_FORMAT = re.compile(r"ble-(pd|sr)-[0-9A-F]{12}", re.IGNORECASE)
"""The SDK's own id form (aoa_address_to_id writes upper case; its parser and comparison take
any case); other ids are read too (a deployment's own)."""

LIMITS = {"azimuth": (-360.0, 360.0), "elevation": (-90.0, 90.0), "distance": (0.0, 1000.0),
          "azimuth_stdev": (-360.0, 360.0), "elevation_stdev": (-180.0, 180.0), "distance_stdev": (0.0, 1000.0),
          "quality": (0.0, 2.0**32 - 1), "sequence": (-(2.0**31), 2.0**31 - 1)}
"""Each number's plausible range: outside it a message is refused, not fed to a locator
(azimuth: the RTL library's degrees, written 0..360 or -180..180 by releases; distance: metres;
a stdev is negative when the library takes the estimate for non-line-of-sight)."""


class SilabsAoaError(Error, ValueError):
    """A topic or payload that is not a Silicon Labs locator's angle."""


@dataclass(frozen=True)
class Angle:
    """One angle message as the locator wrote it: degrees in its own frame (docs/protocol.md)."""

    locator: str
    tag: str
    azimuth_deg: float
    elevation_deg: float | None = None
    distance_m: float | None = None
    """The RTL library's distance from RSSI (sl_rtl_util_rssi2distance): coarse, not used to fix."""
    sequence: int | None = None
    azimuth_stdev_deg: float | None = None
    """Negative: the RTL library takes the estimate for non-line-of-sight (sl_rtl_clib_api.h)."""
    elevation_stdev_deg: float | None = None
    quality: int | None = None
    """Older releases' IQ-sample quality bits (0: all good); newer ones write the stdevs instead."""


def address(sdk_id: str) -> str:
    """The 12 hex digits of the device address in an id of the SDK's form (``ble-pd-`` or
    ``ble-sr-`` and them), which is how a site file names boards and tags; any other id as it is."""
    return sdk_id[7:].upper() if ID_FORMAT.fullmatch(sdk_id) else sdk_id


def angle_topic(locator: str, tag: str, prefix: str = PREFIX) -> str:
    return f"{prefix}/angle/{_checked_id(locator, 'locator')}/{_checked_id(tag, 'tag')}"


def subscription(prefix: str = PREFIX) -> str:
    """The filter for every locator's angles of every tag under ``prefix``."""
    return f"{prefix}/angle/+/+"


def check_prefix(prefix: str) -> str:
    """``prefix`` if it can root the topics (levels of ids, no wildcards), else an error."""
    levels = prefix.split("/")
    if not prefix or len(prefix) > 200 or not all(_ID.fullmatch(level) for level in levels):
        raise SilabsAoaError(f"topic prefix {prefix!r}: expected levels of letters, digits, '.', '_', ':' or '-' "
                             f"separated by '/' (the SDK's is {PREFIX}; no '+', '#' or empty levels)")
    return prefix


def parse_topic(topic: str, prefix: str = PREFIX) -> tuple[str, str]:
    """(locator id, tag id) of an angle topic under ``prefix``."""
    head = f"{prefix}/angle/"
    rest = topic[len(head):].split("/") if topic.startswith(head) else []
    if len(rest) != 2 or not all(_ID.fullmatch(level) for level in rest):
        raise SilabsAoaError(f"topic {topic[:120]!r}: expected {head}LOCATOR/TAG (ids of 1-{MAX_ID} characters)")
    return rest[0], rest[1]


def _checked_id(text: str, what: str) -> str:
    if not _ID.fullmatch(text):
        raise SilabsAoaError(f"{what} id {text[:80]!r}: 1-{MAX_ID} letters, digits, '.', '_', ':' or '-'")
    return text


def _refuse_constant(name: str) -> Any:
    raise SilabsAoaError(f"payload holds {name}: the locator writes finite numbers only")


def decode(topic: str, payload: bytes, prefix: str = PREFIX) -> Angle:
    """The angle of one message, or :class:`SilabsAoaError` naming what is wrong with it."""
    locator, tag = parse_topic(topic, prefix)
    if len(payload) > MAX_PAYLOAD:
        raise SilabsAoaError(f"{topic}: payload of {len(payload)} bytes (at most {MAX_PAYLOAD})")
    try:
        obj = json.loads(payload, parse_constant=_refuse_constant)
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        if isinstance(exc, SilabsAoaError):
            raise SilabsAoaError(f"{topic}: {exc}") from None
        raise SilabsAoaError(f"{topic}: payload is not JSON ({str(exc)[:80]})") from None
    if not isinstance(obj, dict) or len(obj) > MAX_KEYS or any(isinstance(v, (dict, list)) for v in obj.values()):
        raise SilabsAoaError(f"{topic}: payload must be one flat JSON object of at most {MAX_KEYS} keys")
    values: dict[str, float] = {}
    for key, (low, high) in LIMITS.items():
        v = obj.get(key)
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not low <= v <= high:
            raise SilabsAoaError(f"{topic}: {key} = {str(v)[:40]} is not a number in {low:g}..{high:g}")
        values[key] = float(v)
    if "azimuth" not in values:
        raise SilabsAoaError(f"{topic}: payload has no azimuth (keys: {', '.join(sorted(map(str, obj))[:8])})")

    def whole(key: str) -> int | None:
        return None if key not in values else int(values[key])

    return Angle(locator, tag, values["azimuth"], values.get("elevation"), values.get("distance"), whole("sequence"),
                 values.get("azimuth_stdev"), values.get("elevation_stdev"), whole("quality"))


def encode(angle: Angle) -> bytes:
    """The message the SDK's current releases write (aoa_serdes.c, aoa_serialize_angle), for
    the emulated locator; fields it has not are written 0, as the SDK writes a stdev it lacks."""
    obj = {"azimuth": angle.azimuth_deg, "azimuth_stdev": angle.azimuth_stdev_deg or 0.0,
           "elevation": angle.elevation_deg or 0.0, "elevation_stdev": angle.elevation_stdev_deg or 0.0,
           "distance": angle.distance_m or 0.0, "distance_stdev": 0.0, "sequence": angle.sequence or 0}
    return json.dumps(obj, indent="\t").encode()
