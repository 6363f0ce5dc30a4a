"""Site files (TOML): where a deployment's fixed AoA anchors are, how each is mounted and
calibrated, and which tags to locate.

::

    [site]
    name = "kit-room"
    rate_hz = 10          # fixes per second per tag
    window_s = 0.3        # each anchor's angles for a fix: its last window_s seconds
    stale_s = 1.0         # an anchor silent this long about a tag is left out
    sigma_deg = 3.0       # one angle's error at boresight (grows toward +-90)
    az_compression = 0.2  # the boards' shared |azimuth| compression (default: XPLR-AOA's, measured)
    extent = [[0.0, 0.0], [12.0, 6.0]]  # where tags can be: [[x0, y0], [x1, y1]] (or with z); default:
                          # the anchors' box (docs/estimation.md, "Guards")
    margin_m = 2.0        # positions farther outside the extent are withheld (the track is lost)

    [anchors.north]
    id = "CCF9578E0D01"               # its +UUDF anchor id (AT+UDFCFG tag 4; default its MAC)
    port = "xplr-aoa:/dev/ttyUSB0"   # a port spec (docs/usage.md)
    position = [6.0, 6.0, 2.2]        # metres, world frame, z up
    yaw_deg = -90                     # boresight heading, CCW from +x
    pitch_deg = -20                   # boresight tilt, negative = down (ceiling: -90)
    roll_deg = 0
    two_sided = false                 # true when tags can be behind it (a pole, not a wall)
    fov_deg = 180                     # the azimuths it reports (XPLR-AOA: 180; a circular array: 360)
    elevation = true                  # false: a board that reports no elevation (its readings' is dropped)
    angle_model = "cone"              # or "spherical" (atan2 angles); `calibrate` may choose it
    [anchors.north.calibration]       # written by `rfhoming calibrate`
    yaw_offset_deg = 0.0
    az_scale = 1.0
    az_bias_deg = 0.0
    el_scale = 1.0
    el_bias_deg = 0.0

    [tags.CCF9578E0D8A]
    name = "cart"
    height = 0.9                      # metres, when known (else solved in 3-D)
    role = "target"                   # homing: "robot" (its own tag) or "target" (to reach)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from rfhoming.host import outputs, portspec
from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.anchors3d import ANGLE_MODELS, rotation
from rfhoming.host.estimation.extent import MARGIN_M, Extent, from_anchors
from rfhoming.host.portspec import PortSpecError
from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error
from rfhoming.protocol.settings import TAG_ID
from rfhoming.protocol.textfile import read_toml


class SiteError(Error, ValueError):
    """A site file that cannot be used; the message names the table and key to fix."""


@dataclass(frozen=True)
class Calibration:
    """Per-anchor correction of the reported angles; the yaw offset turns the board.

    Reported = scale * compress(true) + bias, where compress(a) = a * (1 - c (a / 90)^2) reads
    |azimuth| short toward +-90 by the fraction ``az_compression`` (c) at 90 degrees."""

    yaw_offset_deg: float = 0.0
    az_scale: float = 1.0
    az_bias_deg: float = 0.0
    el_scale: float = 1.0
    el_bias_deg: float = 0.0
    az_compression: float = 0.0

    def correct(self, azimuth_deg: float, elevation_deg: float) -> tuple[float, float]:
        """The true (azimuth, elevation) of reported ones (compress() undone: :func:`uncompress`)."""
        u = (azimuth_deg - self.az_bias_deg) / self.az_scale
        a = float(uncompress(u, self.az_compression)) if self.az_compression else u
        return a, (elevation_deg - self.el_bias_deg) / self.el_scale

    def log_stretch(self, azimuth_deg: float) -> float:
        """log |d reported / d corrected| at a corrected azimuth: what a density of the corrected
        angles gains over one of the reported angles (to compare sites with different calibrations)."""
        slope = self.az_scale * (1 - 3 * self.az_compression * (azimuth_deg / 90) ** 2)
        return math.log(max(abs(slope), 1e-6)) + math.log(abs(self.el_scale))


def uncompress(u: Any, c: float) -> Any:
    """The true azimuth(s) (degrees, a float or an array) whose ``compress`` is ``u``, by Newton
    steps (compress is monotonic on +-90 for |c| < 1/3, which the limits keep). compress maps +-90
    to +-90 (1 - c): a reading beyond that (noise at the edge of a board that reads short) has no
    true azimuth on the board's half-space and is taken as +-90 -- Newton from there runs off
    past 90 degrees, or back toward the middle."""
    edge = 90.0 * (1.0 - c)
    u = np.clip(u, -edge, edge)
    a = u
    for _ in range(6):  # 1e-9 deg at the limits' c = +-0.3, from a = u
        a = a - (a * (1 - c * (a / 90) ** 2) - u) / (1 - 3 * c * (a / 90) ** 2)
    return np.clip(a, -90.0, 90.0)


@dataclass(frozen=True)
class Anchor:
    name: str
    id: str
    port: str | None
    position: tuple[float, float, float]
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    two_sided: bool = False
    calibration: Calibration = Calibration()
    angle_model: str = "cone"
    fov_deg: float = 180.0
    """The azimuths it can report, centred on its boresight (degrees; 360: the whole circle)."""
    elevation: bool = True
    """Whether its board reports elevation (a circular array in one plane does not)."""

    def rotation(self) -> np.ndarray:
        """Board -> world, the calibrated yaw offset included."""
        return rotation(self.yaw_deg + self.calibration.yaw_offset_deg, self.pitch_deg, self.roll_deg)

    def admit(self, reading: Bearing) -> Bearing | None:
        """``reading`` as this anchor gives it: None outside its field of view (a board cannot
        report that: a decoding or mapping error), its elevation dropped if it has none."""
        if abs(reading.azimuth) > math.radians(self.fov_deg) / 2 + 1e-9:
            return None
        return reading if self.elevation or reading.elevation is None else reading._replace(elevation=None)


CALIBRATION_LIMITS = {"yaw_offset_deg": (-45.0, 45.0), "az_scale": (0.5, 2.0), "az_bias_deg": (-45.0, 45.0),
                      "el_scale": (0.5, 2.0), "el_bias_deg": (-45.0, 45.0), "az_compression": (-0.3, 0.3)}
"""What a site file accepts in [anchors.NAME.calibration]; `calibrate` keeps its fits inside."""

DEFAULT_ANGLE_MODEL = "cone"
"""An anchor's angle model when its table gives none: real XPLR-AOA boards' angles fit the
direction cosines of a planar array (docs/estimation.md, "Real angles")."""

BOARD_COMPRESSION = 0.2
"""The boards' shared |azimuth| compression when [site] gives none: real XPLR-AOA boards read
|azimuth| short toward +-90 beyond what the cone model explains (az (1 - c (az / 90)^2));
chosen by cross-validation on real walks (docs/estimation.md). Per-anchor calibrations are
fitted on top of it (self-calibration cannot tell a compression all boards share from the
positions)."""

MAX_COORD_M = 10_000.0
"""Anchor coordinates beyond this (metres) are a typo, not a site: the solver would lose its precision."""

MIN_SEPARATION_M = 0.1
"""Anchors nearer each other than this see a tag along the same ray: no fix from them."""

ROLES = ("", "robot", "target")
"""A tag's role for `rfhoming run --controller anchors`: the robot's own tag, the one to reach."""


@dataclass(frozen=True)
class TagInfo:
    id: str
    name: str = ""
    height: float | None = None
    role: str = ""


@dataclass(frozen=True)
class Site:
    name: str
    anchors: tuple[Anchor, ...]
    tags: tuple[TagInfo, ...] = ()
    rate_hz: float = 10.0
    window_s: float = 0.3
    stale_s: float = 1.0
    sigma_deg: float = 3.0
    path: Path | None = field(default=None, compare=False)
    az_compression: float = BOARD_COMPRESSION
    extent: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    """The site file's [site] extent (lo, hi corners; None: the anchors' box)."""
    margin_m: float = MARGIN_M

    def anchor_by_id(self) -> dict[str, Anchor]:
        return {a.id: a for a in self.anchors}

    def bounds(self) -> Extent:
        """Where tags can be: the site file's extent, or the anchors' box (estimation/extent.py)."""
        if self.extent is not None:
            return Extent(self.extent[0], self.extent[1], self.margin_m)
        return from_anchors([a.position for a in self.anchors], [a.rotation()[:, 0] for a in self.anchors],
                            [a.two_sided for a in self.anchors], self.margin_m)

    def tag(self, tag_id: str) -> TagInfo | None:
        return next((t for t in self.tags if t.id == tag_id), None)

    def tag_with_role(self, role: str) -> TagInfo:
        """The one tag with ``role``; SiteError when there is none or several."""
        found = [t for t in self.tags if t.role == role]
        if len(found) != 1:
            raise SiteError(f"{self.path or self.name}: homing on the anchors needs exactly one tag with "
                            f"role = \"{role}\" in [tags.ID], found {len(found)}")
        return found[0]


UNITS = {"_hz": " Hz", "_s": " s", "_deg": " degrees", "height": " m", "scale": " (a factor)"}
"""The unit a key's name ends in, for the messages."""


def _number(table: dict[str, Any], key: str, where: str, default: float | None = None,
            low: float = -math.inf, high: float = math.inf) -> float:
    value = table.get(key, default)
    if value is None:
        raise SiteError(f"[{where}] needs {key} = <number>")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        unit = next((u for suffix, u in UNITS.items() if key.endswith(suffix)), "")
        raise SiteError(f"[{where}] {key} = {value!r}: expected a number from {low:g} to {high:g}{unit}")
    return float(value)


def _check_keys(table: dict[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise SiteError(f"[{where}] has unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")


def _anchor(name: str, table: Any) -> Anchor:
    where = f"anchors.{name}"
    if not isinstance(table, dict):
        raise SiteError(f"[{where}] must be a table")
    _check_keys(table, {"id", "port", "position", "yaw_deg", "pitch_deg", "roll_deg", "two_sided", "calibration",
                        "angle_model", "fov_deg", "elevation"}, where)
    anchor_id = table.get("id")
    if not isinstance(anchor_id, str) or not 0 < len(anchor_id) <= 30:
        raise SiteError(f"[{where}] needs id = \"<its +UUDF anchor id>\" (1-30 characters; by default the board's MAC)")
    port = table.get("port")
    if port is not None:
        try:
            spec = portspec.parse(str(port))
        except PortSpecError as exc:
            raise SiteError(f"[{where}] port: {exc}") from None
        if spec.kind not in (None, "capture") and "anchor" not in devices.kind(spec.kind).roles:
            raise SiteError(f"[{where}] port {port!r} is a {spec.kind} port; an anchor is xplr-aoa:WHERE")
    pos = table.get("position")
    if (not isinstance(pos, list) or len(pos) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= MAX_COORD_M for v in pos)):
        raise SiteError(f"[{where}] needs position = [x, y, z] in metres, each a finite number within "
                        f"+-{MAX_COORD_M:g} m; got {pos!r}")
    cal = table.get("calibration", {})
    if not isinstance(cal, dict):
        raise SiteError(f"[{where}.calibration] must be a table")
    known = {f.name for f in fields(Calibration)}
    _check_keys(cal, known, f"{where}.calibration")
    calibration = Calibration(**{k: _number(cal, k, f"{where}.calibration", getattr(Calibration(), k),
                                            *CALIBRATION_LIMITS[k]) for k in known})
    model = table.get("angle_model", DEFAULT_ANGLE_MODEL)
    if model not in ANGLE_MODELS:
        raise SiteError(f"[{where}] angle_model = {model!r}: expected \"spherical\" (atan2 angles) or \"cone\" "
                        "(direction cosines of the array's axes; docs/estimation.md)")
    two_sided, elevation = table.get("two_sided", False), table.get("elevation", True)
    if not isinstance(two_sided, bool) or not isinstance(elevation, bool):
        raise SiteError(f"[{where}] two_sided and elevation must be true or false")
    return Anchor(name, anchor_id, None if port is None else str(port), tuple(float(v) for v in pos),  # type: ignore[arg-type]
                  _number(table, "yaw_deg", where, 0.0, -360, 360), _number(table, "pitch_deg", where, 0.0, -90, 90),
                  _number(table, "roll_deg", where, 0.0, -180, 180), two_sided, calibration, model,
                  _number(table, "fov_deg", where, 180.0, 1, 360), elevation)


def _tag(tag_id: str, table: Any) -> TagInfo:
    where = f"tags.{tag_id}"
    if not TAG_ID.fullmatch(tag_id):
        raise SiteError(f"[{where}]: a tag id is 12 upper-case hex digits, e.g. [tags.CCF9578E0D8A]")
    if not isinstance(table, dict):
        raise SiteError(f"[{where}] must be a table")
    _check_keys(table, {"name", "height", "role"}, where)
    height = table.get("height")
    role = table.get("role", "")
    if role not in ROLES:
        raise SiteError(f"[{where}] role = {role!r}: expected \"robot\" (the robot's own tag) or \"target\"")
    return TagInfo(tag_id, str(table.get("name", "")),
                   None if height is None else _number(table, "height", where, low=-10, high=100), role)


def parse(raw: dict[str, Any], where: str = "site") -> Site:
    """A site from its TOML table; SiteError names what is wrong."""
    _check_keys(raw, {"site", "anchors", "tags"}, where)
    head = raw.get("site", {})
    tags = raw.get("tags", {})
    if not isinstance(head, dict) or not isinstance(tags, dict):
        raise SiteError(f"{where}: [site] and [tags.ID] must be tables (see the site file example in docs/usage.md)")
    _check_keys(head, {"name", "rate_hz", "window_s", "stale_s", "sigma_deg", "az_compression", "extent", "margin_m"},
                "site")
    anchors = raw.get("anchors")
    if not isinstance(anchors, dict) or len(anchors) < 2:
        raise SiteError(f"{where} needs two or more [anchors.NAME] tables (each with id, port, position)")
    parsed = tuple(_anchor(name, table) for name, table in anchors.items())
    ids = [a.id for a in parsed]
    if len(set(ids)) != len(ids):
        raise SiteError(f"{where}: two anchors share an id; each board needs its own (AT+UDFCFG=4,\"NAME\")")
    for i, a in enumerate(parsed):
        for b in parsed[i + 1:]:
            if math.dist(a.position, b.position) < MIN_SEPARATION_M:
                raise SiteError(f"{where}: anchors {a.name} and {b.name} are {math.dist(a.position, b.position):.3f} m "
                                f"apart; rays from one point cannot cross: give each anchor its own position "
                                f"(at least {MIN_SEPARATION_M:g} m apart, in metres)")
    return Site(str(head.get("name", where)), parsed, tuple(_tag(k, v) for k, v in tags.items()),
                _number(head, "rate_hz", "site", 10.0, 0.1, 1000), _number(head, "window_s", "site", 0.3, 0.01, 60),
                _number(head, "stale_s", "site", 1.0, 0.01, 600), _number(head, "sigma_deg", "site", 3.0, 0.1, 45),
                az_compression=_number(head, "az_compression", "site", BOARD_COMPRESSION,
                                       *CALIBRATION_LIMITS["az_compression"]),
                extent=_extent(head.get("extent"), parsed), margin_m=_number(head, "margin_m", "site", MARGIN_M, 0.0, 100))


def _extent(raw: Any, anchors: tuple[Anchor, ...]) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
    """[site] extent = [[x0, y0], [x1, y1]] (or [x, y, z] corners; z by default from the floor,
    z = 0, to the highest anchor); SiteError naming the fix."""
    if raw is None:
        return None
    ok = (isinstance(raw, list) and len(raw) == 2 and all(isinstance(c, list) and len(c) == len(raw[0]) in (2, 3)
                                                          for c in raw)
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= MAX_COORD_M
                  for c in raw for v in c))
    if not ok or not all(a < b for a, b in zip(raw[0], raw[1])):
        raise SiteError(f"[site] extent = {raw!r}: expected [[x0, y0], [x1, y1]] (or [x, y, z] corners) in metres, "
                        f"each within +-{MAX_COORD_M:g} m, the first corner below the second on every axis")
    zs = [a.position[2] for a in anchors]
    lo = (*(float(v) for v in raw[0][:2]), float(raw[0][2]) if len(raw[0]) == 3 else min(0.0, *zs))
    hi = (*(float(v) for v in raw[1][:2]), float(raw[1][2]) if len(raw[1]) == 3 else max(zs))
    return (lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2])


def load(path: str | Path) -> Site:
    """Read and validate a site file."""
    path = Path(path)
    return replace(parse(read_toml(path, "site file", SiteError), str(path)), path=path)


def write_calibration(path: str | Path, calibrations: dict[str, Calibration],
                      models: dict[str, str] | None = None) -> None:
    """Write each anchor's calibration (by anchor name), and its angle model if given, into the
    site file, keeping the rest of it -- comments and order -- as it was. The file is replaced
    whole (host/outputs.py): a command killed while it writes leaves the old one."""
    import tomlkit

    path = Path(path)
    doc = tomlkit.parse(path.read_text())
    for name, model in (models or {}).items():
        doc["anchors"][name]["angle_model"] = model
    for name, cal in calibrations.items():
        table = tomlkit.table()
        for f in fields(Calibration):
            table[f.name] = round(float(getattr(cal, f.name)), 4)
        doc["anchors"][name]["calibration"] = table
    outputs.replace_text(path, tomlkit.dumps(doc))
