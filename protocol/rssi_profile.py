"""How a radio's RSSI really behaves: the ``[rssi.NAME]`` tables of a radio profile.

One table per kind of radio (:data:`RADIOS`; the device table's ``Board.radio`` says which a
board has), each fitted to real recordings (``python bench/fit_rssi.py``) and read by the
emulator's measured channel (emulator/measured_rssi.py; docs/emulator.md, "Measured RSSI").
A reading of a link (a transmitter heard by a receiver) is

    the scenario's mean power, turned about ``pivot_m`` to the link's own exponent
    + the link's offset + shadowing (a field over where the two ends are)
    + a correlated residual (Ornstein-Uhlenbeck) + white noise,

and some readings are lost, in bursts. Every group of figures carries ``source``: the recordings
and how the figure came from them, or, where no recording exists for the radio, ``assumed``: why
the figure was taken from elsewhere. The host writes profiles and the emulator reads them, so
the format sits here, below both.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, dataclass, fields
from typing import Any

from rfhoming.protocol.errors import Error
from rfhoming.protocol.schema import DB, M, S, ConfigError, build, setting

RADIOS = {
    "ble": "BLE scanners hearing a beacon's advertisements (ESP32 node, ESP-AT, HCI controllers)",
    "xplr": "the XPLR-AOA board's RSSI of a tag's CTE advertisements (both polarisations)",
    "subghz": "the AT86RF212 four-dish node hearing a 915 MHz emitter",
}
"""The ``[rssi.NAME]`` tables a profile may have, and the receivers each one covers."""


class RssiProfileError(Error, ValueError):
    """An ``[rssi.NAME]`` table that cannot be used; the message names the key and the fix."""


@dataclass(frozen=True)
class Exponent:
    """Each link's path-loss exponent, drawn once per link: N(``mean``, ``sd``) clipped to
    [``low``, ``high``]. The link's mean power equals the scenario's own law at ``pivot_m`` (the
    recordings' typical distance: their level there is what the scenario's transmitter power
    and P0 say) and falls with the link's exponent around it, from ``near_m`` to ``far_m`` (the
    distances the recordings span); nearer or farther, with the scenario's, as no recording
    shows what it does there."""

    mean: float = setting(low=-2.0, high=8.0)
    sd: float = setting(low=0.0, high=5.0)
    low: float = setting(low=-2.0, high=8.0)
    high: float = setting(low=-2.0, high=8.0)
    pivot_m: float = setting(low=0.0, above=True, high=1000.0, unit=M)
    near_m: float = setting(low=0.0, above=True, high=1000.0, unit=M)
    far_m: float = setting(low=0.0, above=True, high=1000.0, unit=M)
    source: str = ""
    assumed: str = ""


@dataclass(frozen=True)
class Offset:
    """Each link's level at the pivot, off the scenario's: N(0, ``sd_db``), drawn once per link
    (receivers' and transmitters' own gains, their antennas, their mounting)."""

    sd_db: float = setting(low=0.0, high=40.0, unit=DB)
    source: str = ""
    assumed: str = ""


@dataclass(frozen=True)
class Shadowing:
    """A Gaussian field over where the link's two ends are: sigma ``sd_db``, correlation
    exp(-(h / ``distance_m``)^2) between places h apart. The same place gives the same
    shadowing whenever a robot comes back to it."""

    sd_db: float = setting(low=0.0, high=40.0, unit=DB)
    distance_m: float = setting(low=0.0, above=True, high=1000.0, unit=M)
    source: str = ""
    assumed: str = ""


@dataclass(frozen=True)
class Residual:
    """What changes in time on a link: an Ornstein-Uhlenbeck process (``sd_db``, ``time_s``)
    plus white noise ``white_sd_db`` on every reading."""

    sd_db: float = setting(low=0.0, high=40.0, unit=DB)
    time_s: float = setting(low=0.0, above=True, high=3600.0, unit=S)
    white_sd_db: float = setting(low=0.0, high=40.0, unit=DB)
    source: str = ""
    assumed: str = ""


@dataclass(frozen=True)
class Loss:
    """Readings a receiver misses: each link's fraction drawn once, uniform from
    ``fraction_low`` to ``fraction_high``, lost in bursts ``burst_s`` long on average (a
    two-state Markov chain in time, so the fraction holds whatever the reading rate)."""

    fraction_low: float = setting(low=0.0, high=0.99)
    fraction_high: float = setting(low=0.0, high=0.99)
    burst_s: float = setting(low=0.0, above=True, high=3600.0, unit=S)
    source: str = ""
    assumed: str = ""


@dataclass(frozen=True)
class Polarisation:
    """The XPLR-AOA's second polarisation (field 5 of a 1.0 ``+UUDF`` line): the first one's
    RSSI plus N(``mean_db``, ``sd_db``) on every event."""

    mean_db: float = setting(low=-40.0, high=40.0, unit=DB)
    sd_db: float = setting(low=0.0, high=40.0, unit=DB)
    source: str = ""
    assumed: str = ""


GROUPS: dict[str, type] = {"exponent": Exponent, "offset": Offset, "shadowing": Shadowing,
                           "residual": Residual, "loss": Loss, "polarisation": Polarisation}
REQUIRED = ("exponent", "offset", "shadowing", "residual")
"""Groups every radio has. ``loss`` is left out where another table owns the radio's losses (the
XPLR-AOA's events are lost with their angles: ``[aoa.missing]``); ``polarisation`` is the XPLR-AOA's."""


@dataclass(frozen=True)
class RssiProfile:
    """One radio's measured RSSI (``[rssi.NAME]``)."""

    exponent: Exponent
    offset: Offset
    shadowing: Shadowing
    residual: Residual
    loss: Loss | None = None
    polarisation: Polarisation | None = None
    title: str = ""

    @classmethod
    def from_table(cls, table: Mapping[str, Any], where: str = "rssi", source: str = "radio profile") -> RssiProfile:
        """The profile of one ``[rssi.NAME]`` table (``where`` names it in messages);
        RssiProfileError, one line naming the key, when it is not one."""
        if not isinstance(table, Mapping):
            raise RssiProfileError(f"{source}: [{where}] must be a table of groups ({', '.join(GROUPS)})")
        unknown = sorted(set(table) - set(GROUPS) - {"title"})
        if unknown:
            raise RssiProfileError(f"{source}: [{where}] has unknown key {unknown[0]!r}; it holds title and the "
                                   f"groups {', '.join(GROUPS)}")
        for name in REQUIRED:
            if name not in table:
                raise RssiProfileError(f"{source}: [{where}] lacks [{where}.{name}]: every radio needs "
                                       f"{', '.join(REQUIRED)}")
        if not isinstance(table.get("title", ""), str):
            raise RssiProfileError(f"{source}: [{where}] title must be a string")
        groups = {name: _group(GROUPS[name], table[name], f"{where}.{name}", source) for name in GROUPS if name in table}
        profile = cls(**groups, title=str(table.get("title", "")))
        _check(profile, where, source)
        return profile

    def to_table(self) -> dict[str, Any]:
        """The ``[rssi.NAME]`` table (:meth:`from_table` reads it back), empty ``assumed`` left out."""
        out: dict[str, Any] = {"title": self.title} if self.title else {}
        for name in GROUPS:
            group = getattr(self, name)
            if group is not None:
                out[name] = {f.name: getattr(group, f.name) for f in fields(group)
                             if not (f.name == "assumed" and not group.assumed)}
        return out

    def assumed(self) -> dict[str, str]:
        """The groups no recording of this radio gave, and why."""
        return {name: g.assumed for name in GROUPS if (g := getattr(self, name)) is not None and g.assumed}


def sections(tables: Mapping[str, Any], source: str = "radio profile") -> dict[str, RssiProfile]:
    """Every ``[rssi.NAME]`` of a profile file (``tables`` is its ``[rssi]``), checked."""
    unknown = sorted(set(tables) - set(RADIOS))
    if unknown:
        raise RssiProfileError(f"{source}: unknown radio [rssi.{unknown[0]}]; the radios are {', '.join(RADIOS)}")
    return {name: RssiProfile.from_table(t, f"rssi.{name}", source) for name, t in tables.items()}


def _group(cls: type, table: Any, where: str, source: str) -> Any:
    if isinstance(table, Mapping):
        lacking = [f.name for f in fields(cls) if f.default is MISSING and f.name not in table]
        if lacking:
            raise RssiProfileError(f"{source}: [{where}] lacks {lacking[0]}: give every figure of the group "
                                   f"({', '.join(f.name for f in fields(cls) if f.default is MISSING)})")
    try:
        group = build(cls, dict(table) if isinstance(table, Mapping) else table, where, source)
    except ConfigError as exc:
        raise RssiProfileError(str(exc)) from None
    if not group.source.strip():
        raise RssiProfileError(f"{source}: [{where}] has no source: say which recordings the figures came from "
                               "(and, in assumed, why where none did)")
    return group


def _check(p: RssiProfile, where: str, source: str) -> None:
    """What the ranges alone cannot say."""
    e = p.exponent
    if not e.low <= e.mean <= e.high:
        raise RssiProfileError(f"{source}: [{where}.exponent] mean = {e.mean:g} must lie between low = {e.low:g} "
                               f"and high = {e.high:g}")
    if not e.near_m <= e.pivot_m <= e.far_m:
        raise RssiProfileError(f"{source}: [{where}.exponent] pivot_m = {e.pivot_m:g} must lie between near_m = "
                               f"{e.near_m:g} and far_m = {e.far_m:g}")
    if p.loss is not None and p.loss.fraction_high < p.loss.fraction_low:
        raise RssiProfileError(f"{source}: [{where}.loss] fraction_high = {p.loss.fraction_high:g} is below "
                               f"fraction_low = {p.loss.fraction_low:g}")
