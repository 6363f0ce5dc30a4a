"""An angles file: any direction-finding board's reports as CSV or JSON lines (``--from
angles:FILE``, docs/usage.md "An angles file"), read into :class:`~rfhoming.host.bearing.Bearing`
readings.

CSV with the header ``t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm``, or one JSON object a
line with those keys (a file whose first character is ``{``). ``t`` in epoch seconds, ``anchor``
a site anchor's id, azimuth in degrees over the whole circle counter-clockwise from the anchor's
boresight (REP 103), elevation up positive; elevation and RSSI empty (CSV), null or absent (JSON)
where the board gives none. Bounded: the file's size, each line's length; a value that is not a
finite number in its range is refused with the file and row.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rfhoming.host.bearing import Bearing, wrap
from rfhoming.protocol.errors import Error
from rfhoming.protocol.textfile import read_text

COLUMNS = ("t", "anchor", "tag", "azimuth_deg", "elevation_deg", "rssi_dbm")
MAX_BYTES = 256 * 1024 * 1024
"""An angles file's size at most (about 4 million rows: hours of a site's reports)."""
MAX_LINE = 512
"""A line's length at most: a row is under 100 characters."""
MAX_ID = 64
LIMITS = {"t": (0.0, 1e10), "azimuth_deg": (-360.0, 360.0), "elevation_deg": (-90.0, 90.0),
          "rssi_dbm": (-150.0, 30.0)}
"""Each number's range: t in epoch seconds (0 .. year 2286), angles in degrees, RSSI in dBm."""


class AnglesFileError(Error):
    """An angles file that cannot be read as one (the message names file and row)."""


def load_angles(path: Path, anchors: set[str]) -> list[Bearing]:
    """Every row of ``path`` as a reading, in time order (stable); ``anchors``: the site's anchor
    ids, the only ones a row may name."""
    try:
        size = os.stat(path).st_size
    except OSError as exc:
        raise AnglesFileError(f"cannot read angles file {path}: {exc.strerror or exc}") from None
    if size > MAX_BYTES:
        raise AnglesFileError(f"angles file {path} is {size} bytes, over the {MAX_BYTES} a file may have: "
                              "split it and give each with its own --from")
    text = read_text(path, "angles file", AnglesFileError)
    lines = text.splitlines()
    for row, line in enumerate(lines, 1):
        if len(line) > MAX_LINE:
            raise AnglesFileError(f"{path} row {row}: {len(line)} characters, over the {MAX_LINE} a row may have")
    rows = _json_rows(path, lines) if text.lstrip().startswith("{") else _csv_rows(path, lines)
    out = [_reading(path, row, fields, anchors) for row, fields in rows]
    if not out:
        raise AnglesFileError(f"angles file {path} has no rows: one per report, "
                              f"under the header {','.join(COLUMNS)}")
    return sorted(out, key=lambda r: r.t)


def _csv_rows(path: Path, lines: list[str]) -> Iterator[tuple[int, dict[str, Any]]]:
    reader = csv.reader(lines)
    try:
        header = next(reader, [])
        if tuple(h.strip() for h in header) != COLUMNS:
            raise AnglesFileError(f"{path} row 1: the header is {','.join(header)!r}, not {','.join(COLUMNS)} "
                                  "(or give JSON lines, one object a line with those keys)")
        for cells in reader:
            if not cells:
                continue  # a blank line
            if len(cells) != len(COLUMNS):
                raise AnglesFileError(f"{path} row {reader.line_num}: {len(cells)} fields, not the header's "
                                      f"{len(COLUMNS)} ({','.join(COLUMNS)}; empty where a board gives nothing)")
            yield reader.line_num, {k: v.strip() or None for k, v in zip(COLUMNS, cells)}
    except csv.Error as exc:
        raise AnglesFileError(f"{path} row {reader.line_num}: not CSV ({exc})") from None


def _json_rows(path: Path, lines: list[str]) -> Iterator[tuple[int, dict[str, Any]]]:
    for row, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line, parse_constant=lambda c: c)  # NaN, Infinity: kept as text, refused below
        except (json.JSONDecodeError, RecursionError):
            raise AnglesFileError(f"{path} row {row}: not a JSON object (one a line: "
                                  f"{{\"t\": ..., \"anchor\": ..., ...}})") from None
        if not isinstance(obj, dict):
            raise AnglesFileError(f"{path} row {row}: a JSON {type(obj).__name__}, not an object")
        extra = sorted(set(obj) - set(COLUMNS))
        if extra:
            raise AnglesFileError(f"{path} row {row}: unknown key(s) {', '.join(extra)}; known: {', '.join(COLUMNS)}")
        yield row, {k: None if obj.get(k) is None else obj[k] if isinstance(obj[k], str) else json.dumps(obj[k])
                    for k in COLUMNS}


def _reading(path: Path, row: int, fields: dict[str, Any], anchors: set[str]) -> Bearing:
    where = f"{path} row {row}"
    for key in ("t", "anchor", "tag", "azimuth_deg"):
        if fields[key] is None:
            raise AnglesFileError(f"{where}: {key} is missing; t, anchor, tag and azimuth_deg are needed in every row")
    anchor, tag = fields["anchor"], fields["tag"]
    for key, value in (("anchor", anchor), ("tag", tag)):
        if len(value) > MAX_ID or not value.isprintable():
            raise AnglesFileError(f"{where}: {key} {value[:MAX_ID]!r} is not an id (printable, at most {MAX_ID} "
                                  "characters)")
    if anchor not in anchors:
        raise AnglesFileError(f"{where}: anchor {anchor!r} is not in the site file (its anchors: "
                              f"{', '.join(sorted(anchors))}): name each anchor by its id")
    t, az, el, rssi = (_number(where, k, fields[k]) for k in ("t", "azimuth_deg", "elevation_deg", "rssi_dbm"))
    assert t is not None and az is not None
    return Bearing(t, anchor, tag, wrap(math.radians(az)), None if el is None else math.radians(el), rssi)


def _number(where: str, key: str, text: str | None) -> float | None:
    if text is None:
        return None
    lo, hi = LIMITS[key]
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and lo <= value <= hi):
        raise AnglesFileError(f"{where}: {key} = {text[:20]!r}: expected a finite number in {lo:g} .. {hi:g}")
    return value
