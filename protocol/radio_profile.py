"""Radio profiles: how badly the emulator's radios behave, as fitted to real recordings.

A profile is one TOML file (docs/emulator.md, "Radio profiles", has the schema):

- ``[profile]``: its name and what it is;
- ``[recordings.ID]``: each recording a figure came from (the capture and its truth);
- ``[aoa]``: the XPLR-AOA's angle error process, ``[aoa.azimuth]`` and ``[aoa.elevation]``
  (:class:`AngleError`), ``[aoa.missing]`` (:class:`Missing`), optionally ``[aoa.person]``
  (:class:`Person`: a tag a person carries and stops with), and for every figure in them an
  entry in ``[aoa.sources]`` (the recordings it came from and how) or ``[aoa.assumed]`` (why
  no recording could give it);
- ``[rssi.NAME]``: the RSSI radios' tables, read by their own module; kept here as plain tables.

``rfhoming radio-fit`` writes profiles (host/radio_fit.py), every scenario reads one with
``--radio PROFILE``; the project's own, ``measured``, is package data (``profiles/``). ``ideal``
is no profile: each scenario's own, idealised noise (each paper's set-up). The host writes
profiles and the emulator reads them, so the format sits here, below both.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from rfhoming.protocol.errors import Error
from rfhoming.protocol.rssi_profile import RssiProfile, RssiProfileError, sections
from rfhoming.protocol.schema import DEG, M, S, ConfigError, build, setting
from rfhoming.protocol.textfile import parse_toml, read_text, read_toml

FORMAT = 1
"""The profile format this module reads and writes (``[profile] format``)."""

IDEAL = "ideal"
"""``--radio ideal``: no profile, the scenario's own idealised noise."""

SHIPPED = ("measured", "carried")
"""Profiles that ship with rfhoming (``protocol/profiles/NAME.toml``), by name."""

RADIOS = (IDEAL, *SHIPPED)
"""What ``--radio`` takes by name; anything else is a profile file's path."""


class ProfileError(Error, ValueError):
    """A radio profile that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class AngleError:
    """One angle's error (degrees) at one board for one tag (docs/emulator.md, "Radio
    profiles"). Curves over the true |azimuth| off boresight (knots ``curve_at_deg``, straight
    lines between, flat beyond the ends) shape it: ``compression_deg``, a shift of this angle
    outward (+) or inward (-), times a factor per board, 1 + N(0, ``compression_spread``);
    ``offset_deg``, a shift of this angle whatever its sign; and ``spread``, a factor on
    everything random below. The error is the shifts, plus

    - a bias, ``bias_deg`` plus N(0, ``bias_sigma_deg``) drawn per board, tag and run;
    - a field over where the board and the tag are and which way each faces: N(0,
      ``field_sigma_deg``) with correlation exp(-D / ``field_length_m``), D the distance between
      two such poses, a turn counting as ``field_heading_m`` times the chord it sweeps on the unit
      circle (180 degrees: twice that; the body that carries a tag shadows it), so the error stays
      put while they stand and comes back where, and as, they come back;
    - a slow wander in time: Ornstein-Uhlenbeck, ``slow_sigma_deg`` and ``slow_time_s``;
    - white noise, ``white_sigma_deg``; the sum of these three stretched by 1 + ``skew`` where it
      points outward (away from boresight) and 1 - ``skew`` where inward (a curve over the
      knots: wide angles err further inward than outward; the median is kept);
    - bursts (the heavy tail, a mixture): starting at ``burst_rate_hz``, lasting
      ``burst_duration_s`` on average (exponential), each adding one offset,
      ``burst_offset_min_deg`` plus an exponential excess of mean ``burst_offset_excess_deg``,
      outward with probability ``burst_outward``.
    """

    bias_deg: float = setting(0.0, low=-90.0, high=90.0, unit=DEG)
    bias_sigma_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    field_sigma_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    field_length_m: float = setting(1.0, low=0.0, above=True, high=1000.0, unit=M)
    field_heading_m: float = setting(0.0, low=0.0, high=1000.0, unit=M)
    slow_sigma_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    slow_time_s: float = setting(1.0, low=0.0, above=True, high=3600.0, unit=S)
    white_sigma_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    burst_rate_hz: float = setting(0.0, low=0.0, high=100.0, unit="Hz")
    burst_duration_s: float = setting(0.1, low=0.0, above=True, high=3600.0, unit=S)
    burst_offset_min_deg: float = setting(20.0, low=0.0, high=180.0, unit=DEG)
    burst_offset_excess_deg: float = setting(0.0, low=0.0, high=180.0, unit=DEG)
    burst_outward: float = setting(0.5, low=0.0, high=1.0)
    curve_at_deg: tuple[float, ...] = setting((), low=0.0, high=90.0, unit=DEG)
    compression_deg: tuple[float, ...] = setting((), low=-90.0, high=90.0, unit=DEG)
    compression_spread: float = setting(0.0, low=0.0, high=10.0)
    offset_deg: tuple[float, ...] = setting((), low=-90.0, high=90.0, unit=DEG)
    spread: tuple[float, ...] = setting((), low=0.0, high=100.0)
    skew: tuple[float, ...] = setting((), low=-0.9, high=0.9)

    def compression(self, azimuth_abs_deg: float) -> float:
        """The outward shift (degrees) at a true |azimuth| off boresight (0 without a curve)."""
        return _interpolate(self.curve_at_deg, self.compression_deg, azimuth_abs_deg, 0.0)

    def offset(self, azimuth_abs_deg: float) -> float:
        """The shift (degrees) at a true |azimuth| off boresight (0 without a curve)."""
        return _interpolate(self.curve_at_deg, self.offset_deg, azimuth_abs_deg, 0.0)

    def spread_at(self, azimuth_abs_deg: float) -> float:
        """The factor on the random parts at a true |azimuth| off boresight (1 without a curve)."""
        return _interpolate(self.curve_at_deg, self.spread, azimuth_abs_deg, 1.0)

    def skew_at(self, azimuth_abs_deg: float) -> float:
        """The outward stretch at a true |azimuth| off boresight (0 without a curve)."""
        return _interpolate(self.curve_at_deg, self.skew, azimuth_abs_deg, 0.0)


def _interpolate(at: tuple[float, ...], values: tuple[float, ...], x: float, default: float) -> float:
    if not at or not values:
        return default
    if x <= at[0]:
        return values[0]
    for (a0, v0), (a1, v1) in zip(zip(at, values), zip(at[1:], values[1:])):
        if x <= a1:
            return v0 + (v1 - v0) * (x - a0) / (a1 - a0)
    return values[-1]


@dataclass(frozen=True)
class Missing:
    """Events a board does not report: each board's loss rate is drawn per run, uniform from
    ``rate_low`` to ``rate_high``, in runs of ``burst_events`` on average (a two-state chain)."""

    rate_low: float = setting(0.0, low=0.0, high=0.99, unit="")
    rate_high: float = setting(0.0, low=0.0, high=0.99, unit="")
    burst_events: float = setting(1.0, low=1.0, high=10_000.0, unit="events")


@dataclass(frozen=True)
class Person:
    """A tag carried by a person (``[aoa.person]``; every figure 0, the default, is off): what a
    board sees of a tag a person holds and stops with. While the tag stands (slower than
    ``stance_speed_m_s``) each board's error carries a stance offset, held until it moves on:
    a field over where the tag stands and which way its carrier faces (N(0, ``stance_*_field_deg``),
    the axis's own ``field_length_m`` and ``field_heading_m``; the same at the same place in
    every walk through the room) plus a draw redrawn at every stop (N(0, ``stance_*_sigma_deg``):
    the same place differs from walk to walk) plus a wander through the stop (Ornstein-Uhlenbeck,
    ``stance_wander_deg`` on both axes, ``stance_wander_s``: a person shifts as they stand). The body shadows a board behind its carrier: the
    random parts of the error (the stance offset too) are stretched by 1 + ``shadow_gain`` x
    max(0, -cos a), a the angle between the way the carrier faces and the way to the board."""

    stance_az_sigma_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    stance_az_field_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    stance_el_sigma_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    stance_el_field_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    stance_wander_deg: float = setting(0.0, low=0.0, high=90.0, unit=DEG)
    stance_wander_s: float = setting(10.0, low=0.0, above=True, high=3600.0, unit=S)
    stance_speed_m_s: float = setting(0.1, low=0.0, above=True, high=10.0, unit="m/s")
    shadow_gain: float = setting(0.0, low=0.0, high=10.0)


@dataclass(frozen=True)
class Source:
    """Where one figure came from: the recordings (ids of ``[recordings]``) and how."""

    recordings: tuple[str, ...] = setting(())
    how: str = ""


@dataclass(frozen=True)
class AoaProfile:
    """The XPLR-AOA's angle errors (``[aoa]``)."""

    azimuth: AngleError = field(default_factory=AngleError)
    elevation: AngleError = field(default_factory=AngleError)
    missing: Missing = field(default_factory=Missing)
    sources: dict[str, Source] = field(default_factory=dict)
    assumed: dict[str, str] = field(default_factory=dict)
    person: Person = field(default_factory=Person)  # all 0 (off) unless a profile has [aoa.person]


@dataclass(frozen=True, eq=False)
class BoardWalk:
    """One board's view of one walk, as ``rfhoming radio-fit``'s calibration hands it to the
    emulator's board (host/aoa_calibrate.py, emulator/aoa_error.py's ``simulated_errors``): the
    board's name (its compression factor and field are drawn from it and the room's seed), where
    it is and faces (x, y, z in metres, yaw in radians), and per advertisement the time (s), the
    true board angles (board sign, degrees) and the tag's pose (N x 4: x, y, z, heading)."""

    board: str
    pose: tuple[float, float, float, float]
    t: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    tag: np.ndarray


Reported = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One board's reports of a walk: the indices of the advertisements it reported, and their
azimuths and elevations as it printed them (degrees)."""

Board = Callable[[AoaProfile, Sequence[BoardWalk], int, int], list[Reported]]
"""The emulator's board as a function: (profile, one walk's boards, seed, room seed) -> each
board's reports. The host fits profiles and cannot import the emulator, so whoever wires the
layers (the CLI) passes it in."""


@dataclass(frozen=True)
class Recording:
    """A recording a profile was fitted to: its capture and its truth (a waypoint file, or
    the self-calibrated track that stood in for one), as the fitter was given them."""

    capture: str = ""
    truth: str = ""


@dataclass(frozen=True)
class Header:
    """``[profile]``."""

    name: str = ""
    format: int = setting(FORMAT, choices=(FORMAT,))
    description: str = ""
    fitted_by: str = ""


@dataclass(frozen=True)
class RadioProfile:
    """A whole profile file: ``rssi`` its ``[rssi.NAME]`` tables (protocol/rssi_profile.py reads
    them), ``path`` where it was read from."""

    header: Header
    recordings: dict[str, Recording]
    aoa: AoaProfile | None = None
    rssi: dict[str, RssiProfile] = field(default_factory=dict)
    path: str = ""

    @property
    def name(self) -> str:
        return self.header.name


TABLES = ("profile", "recordings", "aoa", "rssi")
FIGURE_TABLES = {"azimuth": AngleError, "elevation": AngleError, "missing": Missing, "person": Person}
"""The [aoa] tables whose every key is a figure that needs a source (or an assumption)."""


def parse(raw: dict[str, Any], where: str) -> RadioProfile:
    """A profile from its parsed TOML; ProfileError names the key that is wrong."""
    try:
        unknown = sorted(set(raw) - set(TABLES))
        if unknown:
            raise ProfileError(f"{where}: unknown table [{unknown[0]}]; a profile has [profile], [recordings.ID], "
                               "[aoa] and [rssi.NAME]")
        if "profile" not in raw:
            raise ProfileError(f"{where}: no [profile] table: start the file with [profile] name = \"...\"")
        header = build(Header, raw["profile"], "profile", where)
        if not header.name:
            raise ProfileError(f"{where}: [profile] name is missing: give the profile a name")
        table = raw.get("recordings", {})
        if not isinstance(table, dict):
            raise ProfileError(f"{where}: recordings must be tables [recordings.ID] with capture and truth")
        recordings = {str(rid): build(Recording, rec, f"recordings.{rid}", where) for rid, rec in table.items()}
        aoa = build(AoaProfile, raw["aoa"], "aoa", where) if "aoa" in raw else None
        rssi = raw.get("rssi", {})
        if not isinstance(rssi, dict) or not all(isinstance(v, dict) for v in rssi.values()):
            raise ProfileError(f"{where}: [rssi] must hold tables [rssi.NAME], one per radio")
        radios = sections(rssi, where)
    except (ConfigError, RssiProfileError) as exc:
        raise ProfileError(str(exc)) from None
    if aoa is not None:
        _check_aoa(aoa, raw["aoa"], recordings, where)
    return RadioProfile(header, recordings, aoa, radios, where)


def _check_missing(m: Missing, where: str) -> None:
    """Refuse a loss rate runs of ``burst_events`` cannot give: losses in runs of mean B with kept events
    between them lose at most B / (B + 1) of all (0.5 for single losses), and the emulator would quietly
    lose less than asked (the house review of 2026-12: 0.99 asked, 0.53 lost)."""
    most = m.burst_events / (m.burst_events + 1.0)
    if m.rate_high > most:
        need = m.rate_high / (1.0 - m.rate_high)
        raise ProfileError(f"{where}: [aoa.missing] rate_high = {m.rate_high:g} with burst_events = {m.burst_events:g}: "
                           f"runs that long lose at most {most:.3g} of the events; set burst_events to at least "
                           f"{math.ceil(need * 1000) / 1000:g} or rate_high to at most {most:.3g}")


def _check_aoa(aoa: AoaProfile, raw: dict[str, Any], recordings: dict[str, Recording], where: str) -> None:
    """What the schema cannot say: the compression curve's shape, a source for every figure
    given, and sources that name recordings of this file."""
    for axis in ("azimuth", "elevation"):
        e: AngleError = getattr(aoa, axis)
        at = e.curve_at_deg
        for key in ("compression_deg", "offset_deg", "spread", "skew"):
            values = getattr(e, key)
            if values and len(values) != len(at):
                raise ProfileError(f"{where}: [aoa.{axis}] {key} has {len(values)} values for the {len(at)} knots of "
                                   "curve_at_deg: give one per knot")
        if any(b <= a for a, b in zip(at, at[1:])):
            raise ProfileError(f"{where}: [aoa.{axis}] curve_at_deg must rise: {list(at)}")
    if aoa.missing.rate_high < aoa.missing.rate_low:
        raise ProfileError(f"{where}: [aoa.missing] rate_high = {aoa.missing.rate_high} is below rate_low = "
                           f"{aoa.missing.rate_low}")
    _check_missing(aoa.missing, where)
    for table in FIGURE_TABLES:
        for key in raw.get(table, {}):
            figure = f"{table}.{key}"
            if key != "curve_at_deg" and figure not in aoa.sources and figure not in aoa.assumed:
                raise ProfileError(f"{where}: [aoa.{table}] {key} has no source: add \"{figure}\" to [aoa.sources] "
                                   "(the recordings it came from) or to [aoa.assumed] (why none could give it)")
    for figure, source in aoa.sources.items():
        missing = [r for r in source.recordings if r not in recordings]
        if missing:
            raise ProfileError(f"{where}: [aoa.sources] \"{figure}\" names recording {missing[0]!r}, which is not "
                               f"in [recordings]; add [recordings.{missing[0]}]")


def load(name_or_path: str | Path) -> RadioProfile:
    """A shipped profile by name (:data:`SHIPPED`) or a profile file, parsed once per process for the same
    text: a campaign's jobs each name the profile, and a worker runs many of them (31 ms each for
    the measured profile, up to seconds for a 1 MiB one)."""
    name = str(name_or_path)
    if name in SHIPPED:
        return _shipped(name)
    path = Path(name_or_path)
    if not path.is_file():
        raise ProfileError(f"no radio profile {name!r}: give {', '.join(RADIOS)} or a profile file "
                           "(rfhoming radio-fit writes one)")
    return _parsed(str(path), read_text(path, "radio profile", ProfileError))


@functools.lru_cache(maxsize=len(SHIPPED))
def _shipped(name: str) -> RadioProfile:
    resource = resources.files("rfhoming.protocol") / "profiles" / f"{name}.toml"
    with resources.as_file(resource) as path:
        return parse(read_toml(path, "radio profile", ProfileError), name)


@functools.lru_cache(maxsize=4)
def _parsed(shown: str, text: str) -> RadioProfile:
    """``text`` (the file ``shown`` as read now: an edited file is new text) parsed, once per process."""
    return parse(parse_toml(text, f"radio profile {shown}", ProfileError), shown)


def resolve(radio: str) -> RadioProfile | None:
    """What ``--radio`` names: None for :data:`IDEAL`, else the profile."""
    return None if radio == IDEAL else load(radio)


def describe(radio: str) -> str:
    """One line for a campaign's table or a run's summary: which radios, and what their profile
    holds (a radio without a table in it keeps the scenario's own noise)."""
    profile = resolve(radio)
    if profile is None:
        return "radios: ideal (each scenario's own idealised noise: its paper's set-up)"
    parts = [f"[aoa] fitted to {len(profile.recordings)} recording(s)" if profile.aoa is not None else "no [aoa]"]
    parts.append("[rssi] " + ", ".join(sorted(profile.rssi)) if profile.rssi else "no [rssi] tables")
    return f"radios: profile {profile.name!r} ({radio}; {'; '.join(parts)}: docs/emulator.md, \"Radio profiles\")"


def to_toml(profile: RadioProfile) -> dict[str, Any]:
    """The profile as TOML tables (for tomlkit), in the order a reader expects."""
    out: dict[str, Any] = {"profile": _table(profile.header),
                           "recordings": {k: _table(v) for k, v in profile.recordings.items()}}
    if profile.aoa is not None:
        a = profile.aoa
        out["aoa"] = {"azimuth": _table(a.azimuth), "elevation": _table(a.elevation), "missing": _table(a.missing),
                      **({"person": _table(a.person)} if a.person != Person() else {}),
                      "sources": {k: _table(v) for k, v in a.sources.items()}, "assumed": dict(a.assumed)}
    if profile.rssi:
        out["rssi"] = {name: radio.to_table() for name, radio in profile.rssi.items()}
    return out


def _table(obj: Any) -> dict[str, Any]:
    """A dataclass's fields as a TOML table; an empty list (no curve) is left out."""
    values = {}
    for f in fields(obj):
        v = getattr(obj, f.name)
        if v == ():
            continue
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{f.name} = {v} cannot be written")
        values[f.name] = list(v) if isinstance(v, tuple) else v
    return values
