"""Wiring shared by ``rfhoming listen``, ``capture`` and ``replay``: endpoints -> drivers.

An endpoint is ``PATH`` (its protocol sniffed from what it says) or ``PROTOCOL=PATH`` with
PROTOCOL one of ``ublox-aoa`` (XPLR-AOA), ``rss`` (ESP32/AT86RF212 node) or ``base``.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any

from rfhoming.host.discovery import resolve_auto
from rfhoming.host.drivers.aoa import AoaDriver, AoaSetup
from rfhoming.host.drivers.base import BaseDriver
from rfhoming.host.drivers.common import Driver
from rfhoming.host.drivers.rss import RssDriver
from rfhoming.host.ports import HostPort, PortError
from rfhoming.protocol.frames import FrameDecoder
from rfhoming.protocol.uconnect import UConnectDecoder

DRIVERS: dict[str, Callable[..., Driver]] = {"ublox-aoa": AoaDriver, "rss": RssDriver, "base": BaseDriver}
WIRE_PROTOCOL = {"ublox-aoa": "ublox-aoa", "rss": "rss", "base": "rss"}
AUTO_KIND = {"ublox-aoa": "xplr-aoa", "rss": "esp32", "base": "stm32"}
SNIFF_SECONDS = 1.5


def parse_endpoint(text: str) -> tuple[str | None, str]:
    head, eq, tail = text.partition("=")
    if eq and head in DRIVERS:
        return head, tail
    if eq:
        raise ValueError(f"unknown protocol {head!r} in {text!r}; use one of {', '.join(DRIVERS)}")
    return None, text


def what_speaks(data: bytes) -> str | None:
    """'rss' if a valid frame is in ``data``, 'ublox-aoa' if a valid AT/URC line is, else None."""
    frames = FrameDecoder().feed(data)
    if any(r.kind != "drop" for r in frames):
        return "rss"
    lines = UConnectDecoder().feed(data)
    if any(i.kind in ("angle", "startup", "final", "echo", "info", "tag_data") for i in lines):
        return "ublox-aoa"
    return None


async def sniff(spec: str, baud: int, seen: list[tuple[str, str, float, bytes]] | None = None) -> str:
    """Listen (and, if silent, say AT) to tell which protocol a port speaks.

    Every chunk read or written while sniffing is appended to ``seen`` as a tap call's
    arguments, so a capture started on this port can hold it too.
    """
    taps = [] if seen is None else [lambda *call: seen.append(call) if call[1] != "lost" else None]
    port = HostPort(spec, baud=baud, taps=taps)
    await port.open()
    data = b""
    try:
        async def gather(seconds: float) -> bytes:
            got = b""
            with contextlib.suppress(asyncio.TimeoutError):
                async with asyncio.timeout(seconds):
                    while what_speaks(got) is None:
                        got += (await port.read()).data
            return got

        data = await gather(SNIFF_SECONDS)
        if what_speaks(data) is None:
            port.write(b"AT\r")
            data += await gather(1.0)
    finally:
        await port.close()
    found = what_speaks(data)
    if found is None:
        raise PortError(f"could not tell what speaks on {spec} ({len(data)} bytes, none valid): "
                        f"name it, e.g. ublox-aoa={spec} or rss={spec}; if it is garbage, check --baud")
    return found


def flow_control(protocol: str, flow: str = "auto") -> bool:
    """RTS/CTS: 'auto' is on for the XPLR-AOA (its documented default) and off for the others."""
    return protocol == "ublox-aoa" if flow == "auto" else flow == "on"


async def open_drivers(endpoints: list[str], *, baud: int, taps: list, describe: Callable[..., None] | None = None,
                       flow: str = "auto", probe_baud: bool = False) -> list[Driver]:
    """Drivers for the endpoints, their protocols sniffed where not given.

    ``probe_baud``: an XPLR-AOA that sends only garbage is probed at every documented rate.
    The bytes that crossed a port while sniffing reach ``taps`` once the port is described:
    a capture holds everything, from the first byte on.
    """
    drivers = []
    for text in endpoints:
        protocol, spec = parse_endpoint(text)
        if spec == "auto":
            spec = resolve_auto(AUTO_KIND[protocol or "ublox-aoa"])
        seen: list[tuple[str, str, float, bytes]] = []
        if protocol is None:
            protocol = await sniff(spec, baud, seen)
        port = HostPort(spec, baud=baud, rtscts=flow_control(protocol, flow), taps=taps)
        if protocol == "ublox-aoa":
            driver: Driver = AoaDriver(port, AoaSetup(probe_baud=probe_baud))
        else:
            driver = DRIVERS[protocol](port)
        if describe is not None:
            describe(port.name, protocol=WIRE_PROTOCOL[protocol], kind=driver.kind)
        for _name, direction, t, data in seen:
            for tap in taps:
                tap(port.name, f"sniffed-{direction}", t, data)
        drivers.append(driver)
    return drivers


def health(drivers: list[Driver]) -> list[dict[str, Any]]:
    return [d.health() for d in drivers]
