"""Port specs: one string names a device, where it is, and how to talk to it.

In the spirit of bumble's transport strings, ``KIND:WHERE[,key=value...]``::

    xplr-aoa:/dev/ttyUSB0,baud=1000000,flow=rtscts,tags=CCF9578E0D8A+CCF9578E0D8B
    rss-node:socket://127.0.0.1:5001
    esp-at:/dev/ttyUSB0,active=yes,interval=100,window=50
    hci:serial:/dev/ttyACM0,1000000,extended=auto     (any bumble transport: hci:usb:0, hci:tcp-client:H:P)
    base:/dev/ttyACM1,baud=115200
    auto                      (the one recognised device; xplr-aoa:auto for a kind)
    /dev/ttyACM0              (no KIND: the protocol is sniffed from what the port says)
    capture:run.pcapng        (a recorded capture, wherever a live port is accepted)
    serve://127.0.0.1:2947    (the devices an ``rfhoming serve`` owns, shared with other clients)

KIND is a device kind of the device table (rfhoming.protocol.devices: its canonical name or an
old alias such as ``ublox-aoa`` or ``rss``) or a source (``capture``, ``serve``). WHERE is a
device path, a pyserial URL (``socket://HOST:PORT``) or ``auto``; commas inside it that are not
followed by ``key=`` stay part of it. Unknown kinds and keys, and bad values, raise
:class:`PortSpecError`, whose one-line message names the key and the allowed values.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from rfhoming.protocol import devices, settings
from rfhoming.protocol.errors import Error
from rfhoming.protocol.settings import Parser


class PortSpecError(Error, ValueError):
    """A port spec that cannot be understood; the message says what is allowed."""


SOURCES: dict[str, Mapping[str, Parser]] = {
    "capture": {"device": settings.device, "speed": settings.speed},  # a pcapng capture replayed as live ports
    "serve": {"device": settings.name},  # the devices of an `rfhoming serve` at serve://HOST:PORT
}
"""Port spec kinds that are not devices: where recorded or shared devices come from. A device
kind's settings are its record's in the device table."""


def allowed(kind: str | None) -> Mapping[str, Parser]:
    """The settings a kind takes; without a kind (sniffed) those of every kind that can be sniffed."""
    if kind in SOURCES:
        return SOURCES[kind]
    if kind:
        return devices.kind(kind, notice=False).settings
    return {key: parse for k in devices.KINDS.values() if k.sniff for key, parse in k.settings.items()}


@dataclass(frozen=True)
class PortSpec:
    """A parsed port spec. ``kind`` is None when the protocol is to be sniffed."""

    kind: str | None
    where: str
    settings: Mapping[str, Any] = field(default_factory=dict)

    @property
    def baud(self) -> int | None:
        return self.settings.get("baud")

    @property
    def flow(self) -> str | None:
        return self.settings.get("flow")

    @property
    def tags(self) -> tuple[str, ...]:
        tags: tuple[str, ...] = self.settings.get("tags", ())
        return tags

    @property
    def name(self) -> str | None:
        return self.settings.get("name")

    @property
    def timeout(self) -> float | None:
        return self.settings.get("timeout")

    def with_defaults(self, **defaults: Any) -> PortSpec:
        """This spec with ``defaults`` filling the settings it does not give (None is skipped)."""
        filled = {k: v for k, v in defaults.items() if v is not None and k not in self.settings}
        return replace(self, settings={**filled, **self.settings}) if filled else self

    def over(self, base: PortSpec | None) -> PortSpec:
        """This spec (e.g. from the command line) over ``base`` (the config's): its kind, place
        and settings win; settings it leaves out come from ``base``."""
        if base is None:
            return self
        return replace(self, kind=self.kind or base.kind, settings={**base.settings, **self.settings})

    @property
    def device(self) -> devices.DeviceKind | None:
        """The device table's record of this spec's kind (None: sniffed, or a source)."""
        return devices.KINDS.get(self.kind or "")

    def with_kind(self, kind: str) -> PortSpec:
        """The spec once its protocol is known (sniffed); its settings must suit that kind."""
        takes = allowed(kind)
        bad = sorted(set(self.settings) - set(takes))
        if bad:
            raise PortSpecError(f"{self.where} speaks {kind}, which has no setting {', '.join(bad)}; "
                                f"its settings are {', '.join(sorted(takes))}")
        return replace(self, kind=kind)

    def __str__(self) -> str:
        head = f"{self.kind}:{self.where}" if self.kind else self.where
        tail = "".join(f",{k}={_text(v)}" for k, v in self.settings.items())
        return head + tail


def _text(value: Any) -> str:
    """A setting as the spec text writes it; a list's items are joined whatever their type
    (a config's ``baud = [1, 2]`` is then refused by the setting's own check, not a TypeError)."""
    if value == ():
        return "none"  # tags=none
    if isinstance(value, bool):
        return str(int(value))  # yes/no settings: what _yes_no reads back
    return "+".join(map(str, value)) if isinstance(value, tuple) else str(value)


def parse(text: str | PortSpec) -> PortSpec:
    """``KIND:WHERE[,key=value...]`` -> :class:`PortSpec`; PortSpecError says what is wrong."""
    if isinstance(text, PortSpec):
        return text
    text = text.strip()
    if not text:
        raise PortSpecError("an empty port spec; give a path, socket://HOST:PORT, auto or KIND:WHERE")
    head, eq, tail = text.partition("=")
    if eq and _known(head) and "," not in head:
        raise PortSpecError(f"{text!r}: write {head}:{tail} (KIND:WHERE) instead of {head}={tail}")
    named, colon, rest = text.partition(":")
    kind: str | None
    if colon and _known(named):
        kind, body = (named if named in SOURCES else devices.kind(named).name), rest
    elif colon and re.fullmatch(r"[a-z][a-z0-9-]*", named) and not rest.startswith("//") and len(named) > 1:
        raise PortSpecError(f"unknown device kind {named!r} in {text!r}; the kinds are "
                            f"{', '.join([*devices.KINDS, *SOURCES])} (or leave KIND: out to sniff the protocol)")
    else:
        kind, body = None, text
    default_where = devices.kind(kind, notice=False).default_where if kind and kind not in SOURCES else None
    if default_where is not None and (not body or re.match(r"[a-z_]+=", body)):
        body = default_where + ("," + body if body else "")
    where, settings = _split(body, text)
    if not where:
        raise PortSpecError(f"{text!r} names no device: give a path, socket://HOST:PORT or auto after the kind")
    takes = allowed(kind)
    values: dict[str, Any] = {}
    for key, raw in settings:
        if key not in takes:
            raise PortSpecError(f"unknown setting {key!r} in {text!r}; "
                                f"{kind or 'a serial port'} takes {', '.join(sorted(takes))}")
        try:
            values[key] = takes[key](raw)
        except ValueError as exc:
            raise PortSpecError(f"bad {key}={raw!r} in {text!r}: expected {exc}") from None
    return PortSpec(kind, where, values)


def _known(name: str) -> bool:
    return name in SOURCES or devices.is_kind(name)


def _split(body: str, text: str) -> tuple[str, list[tuple[str, str]]]:
    """WHERE, then the trailing ``key=value`` settings."""
    parts = body.split(",")
    where: list[str] = []
    settings: list[tuple[str, str]] = []
    for part in parts:
        key, eq, value = part.partition("=")
        if eq and re.fullmatch(r"[a-z_]+", key) and where:
            settings.append((key, value))
        elif settings:
            raise PortSpecError(f"{part!r} in {text!r} is not key=value; settings come after the device, "
                                "each as ,key=value")
        else:
            where.append(part)
    return ",".join(where), settings


def from_table(table: Mapping[str, Any], where: str = "config") -> PortSpec:
    """A ``[devices.NAME]`` table of the TOML config -> PortSpec (``port`` plus settings)."""
    if "port" not in table:
        raise PortSpecError(f"[{where}] needs port = \"KIND:WHERE\" (e.g. \"xplr-aoa:/dev/ttyUSB0\")")
    spec = parse(str(table["port"]))
    extra = ",".join(f"{k}={_text(tuple(v) if isinstance(v, list) else v)}" for k, v in table.items() if k != "port")
    if not extra:
        return spec
    merged = parse(f"{spec.kind}:{spec.where},{extra}" if spec.kind else f"{spec.where},{extra}")
    return replace(merged, settings={**merged.settings, **spec.settings})
