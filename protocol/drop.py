"""The one shape every decoder uses for rejected input: a counted, explained drop."""

from __future__ import annotations

from typing import ClassVar, Literal, NamedTuple

from rfhoming.protocol.jsonable import as_dict


class _Drop(NamedTuple):
    reason: str
    detail: str
    raw: bytes


class Drop(_Drop):
    """Input that was rejected: never half-parsed, always counted under ``reason``.

    ``reason`` is a short stable key for counters (``crc``, ``overlong``, ``uudf_range`` …);
    ``detail`` says what was wrong in words; ``raw`` holds the offending bytes (bounded).
    """

    __slots__ = ()
    kind: ClassVar[Literal["drop"]] = "drop"
    to_dict = as_dict
