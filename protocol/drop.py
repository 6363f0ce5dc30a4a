"""The one shape every decoder uses for rejected input: a counted, explained drop."""

from __future__ import annotations

from typing import NamedTuple

from rfhoming.protocol.jsonable import as_dict


class Drop(NamedTuple):
    """Input that was rejected: never half-parsed, always counted under ``reason``.

    ``reason`` is a short stable key for counters (``crc``, ``overlong``, ``uudf_range`` …);
    ``detail`` says what was wrong in words; ``raw`` holds the offending bytes (bounded).
    """

    reason: str
    detail: str
    raw: bytes

    kind = "drop"
    to_dict = as_dict
