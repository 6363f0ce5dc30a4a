"""Reading the user's text files (config, site, points, scenario, radio profile, ground truth) so that
bad bytes give one line: which file, what is wrong with it, and where -- never a traceback.

Every file is bounded before it is parsed: at most :data:`MAX_BYTES` are read (a 100 MB profile took
122 s and 1 GB to refuse), and TOML nested deeper than :data:`MAX_DEPTH` is refused (10^5 brackets
overflowed tomllib's recursion). Each caller passes its own :class:`~rfhoming.protocol.errors.Error`
subclass, so the message reaches the user through the same path as the file's other problems.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from rfhoming.protocol.errors import Error

MAX_BYTES = 1 << 20
"""The largest text file read: 1 MiB, 45x the shipped measured profile (23 kB), the largest input."""
MAX_DEPTH = 16
"""The deepest nesting of tables and arrays in a TOML file; ours use at most 4."""


def read_text(path: Path | str, what: str, error: type[Error], limit: int = MAX_BYTES) -> str:
    """The file as UTF-8 text, refused past ``limit`` bytes; ``error`` names it (``what``: "config" ...)."""
    try:
        with open(path, "rb") as file:
            data = file.read(limit + 1)
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise error(f"{what} {path} is larger than {limit:,} bytes, the most rfhoming reads: is it the right file?")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{what} {path} is not UTF-8 text (line {line}, byte {exc.start} is 0x{data[exc.start]:02x}): "
                    "save it as UTF-8") from None
    if "\0" in text:  # UTF-16 without its byte-order mark decodes, one NUL beside each ASCII letter
        line = text.count("\n", 0, text.index("\0")) + 1
        raise error(f"{what} {path} is not UTF-8 text (line {line} holds a NUL byte: UTF-16?): save it as UTF-8")
    return text


def parse_toml(text: str, where: str, error: type[Error]) -> dict[str, Any]:
    """``text`` parsed as TOML, no deeper than :data:`MAX_DEPTH`; ``where`` names it in the error."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{where} is not valid TOML: {exc}") from None
    except RecursionError:
        table = None
    if table is None or _depth(table) > MAX_DEPTH:
        raise error(f"{where} nests tables or arrays more than {MAX_DEPTH} deep: is it the right file?")
    return table


def read_toml(path: Path | str, what: str, error: type[Error]) -> dict[str, Any]:
    """The file parsed as TOML; the error gives the line and column of a syntax error."""
    return parse_toml(read_text(path, what, error), f"{what} {path}", error)


def _depth(value: Any) -> int:
    """How deep tables and arrays nest in ``value``, walked without recursion (1 for a flat table)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else None
        if children is not None:
            deepest = max(deepest, depth)
            if depth <= MAX_DEPTH:
                stack.extend((child, depth + 1) for child in children)
    return deepest
