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
