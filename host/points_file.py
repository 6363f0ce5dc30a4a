"""A calibration's known points: the points file of ``rfhoming calibrate --points`` (docs/usage.md,
"Fixed anchors"), read into :class:`~rfhoming.host.calibration.Point` values."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from rfhoming.host.calibration import CalibrationError, Point
from rfhoming.protocol.textfile import read_toml


def _position(value: Any, where: str) -> tuple[float, float, float]:
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise CalibrationError(f"{where} = {value!r} must be [x, y, z], finite numbers in metres")
    return (float(value[0]), float(value[1]), float(value[2]))


def load_points(path: Path) -> list[Point]:
    """The known points: [points] TAGID = [x, y, z] (a tag at one point all recording) and
    [[dwell]] tables (one tag carried from point to point); CalibrationError names what to fix."""
    raw = read_toml(path, "points file", CalibrationError)
    unknown = sorted(set(raw) - {"points", "dwell"})
    if unknown:
        raise CalibrationError(f"{path}: unknown table(s) {', '.join(unknown)}; known: [points], [[dwell]]")
    points = raw.get("points", {})
    dwells = raw.get("dwell", [])
    if not isinstance(points, dict) or not isinstance(dwells, list) or not (points or dwells):
        raise CalibrationError(f"{path} needs a [points] table (TAGID = [x, y, z], one line per tag at a known "
                               "point) or [[dwell]] tables (tag, position, optional from_s and to_s)")
    out = [Point(tag.upper(), _position(value, f"{path}: point {tag}")) for tag, value in points.items()]
    for k, d in enumerate(dwells, 1):
        where = f"{path}: [[dwell]] number {k}"
        if not isinstance(d, dict) or not isinstance(d.get("tag"), str):
            raise CalibrationError(f"{where} needs tag = \"TAGID\" and position = [x, y, z]")
        extra = sorted(set(d) - {"tag", "position", "from_s", "to_s"})
        if extra:
            raise CalibrationError(f"{where} has unknown key(s) {', '.join(extra)}; known: tag, position, from_s, to_s")
        window = [d.get("from_s"), d.get("to_s")]
        start, end = (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None for v in window)
        if window != [None, None] and not (start is not None and end is not None and start < end):
            raise CalibrationError(f"{where}: from_s and to_s must both be given, seconds from the first angle "
                                   f"event with from_s < to_s (or both left out: dwells are found); got {window}")
        out.append(Point(d["tag"].upper(), _position(d.get("position"), f"{where} position"),
                         *(None if v is None else float(v) for v in window)))
    return out
