"""Port specs -> drivers: the one place where a spec string becomes a running device.

A spec (:mod:`rfhoming.host.portspec`) names its kind -- ``ublox-aoa`` (XPLR-AOA), ``rss``
(ESP32/AT86RF212 node), ``base`` -- or leaves it out to have the protocol sniffed from what the
port says; ``capture:FILE`` replays a recording as the devices it holds; ``serve://HOST:PORT``
is a client of ``rfhoming serve``, which owns the devices. Used by ``listen``,
``capture``, ``replay``, ``run`` and the Python API alike.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from rfhoming.host import portspec
from rfhoming.host.discovery import resolve_auto
from rfhoming.host.drivers.aoa import AoaDriver, AoaSetup
from rfhoming.host.drivers.base import BaseDriver
from rfhoming.host.drivers.common import Driver
from rfhoming.host.drivers.espat import EspAtDriver, EspAtSetup
from rfhoming.host.drivers.rss import RssDriver
from rfhoming.host.portspec import PortSpec, PortSpecError
from rfhoming.host.ports import HostPort, PortError, Tap
from rfhoming.host.replay import ReplayPort, Sequencer, load_capture
from rfhoming.host.replay import describe as describe_interface
from rfhoming.protocol.frames import FrameDecoder
from rfhoming.protocol.uconnect import UConnectDecoder



def hci_driver(port: HostPort, **options: Any) -> Driver:
    """The HCI driver, imported only when used: it needs bumble (``pip install rfhoming[hci]``)."""
    try:
        from rfhoming.host.drivers.hci import HciDriver
    except ImportError as exc:
        raise PortError(f"hci: ports need bumble ({exc}); install it with pip install 'rfhoming[hci]'") from None
    return HciDriver(port, **options)


hci_driver.kind = "hci"  # type: ignore[attr-defined]

DRIVERS: dict[str, Callable[..., Driver]] = {"ublox-aoa": AoaDriver, "rss": RssDriver, "base": BaseDriver,
                                             "esp-at": EspAtDriver, "hci": hci_driver}
WIRE_PROTOCOL = {"ublox-aoa": "ublox-aoa", "rss": "rss", "base": "rss", "esp-at": "esp-at", "hci": "hci"}
AUTO_KIND = {"ublox-aoa": "xplr-aoa", "rss": "esp32", "base": "stm32", "esp-at": "esp32", "hci": "bluetooth-hci"}
SNIFF_SECONDS = 1.5
DEFAULT_BAUD = 115200

log = logging.getLogger(__name__)


def what_speaks(data: bytes) -> str | None:
    """'rss' if a valid frame is in ``data``, 'ublox-aoa' if a valid AT/URC line is, else None."""
    frames = FrameDecoder().feed(data)
    if any(r.kind != "drop" for r in frames):
        return "rss"
    lines = UConnectDecoder().feed(data)
    if any(i.kind in ("angle", "startup", "final", "echo", "info", "tag_data") for i in lines):
        return "ublox-aoa"
    return None


async def sniff(spec: PortSpec, tap: Tap) -> str:
    """Listen (and, if silent, say AT) to tell which protocol a port speaks; every byte both
    ways passes ``tap``, so that a capture can hold them too."""
    port = HostPort(spec.where, baud=spec.baud or DEFAULT_BAUD, name=spec.name or spec.where, taps=[tap])
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
        raise PortError(f"could not tell what speaks on {spec.where} ({len(data)} bytes, none valid): "
                        f"name it, e.g. ublox-aoa:{spec.where} or rss:{spec.where}; if it is garbage, "
                        "the baud rate is probably wrong (add ,baud=RATE)")
    return found


def flow_control(protocol: str, flow: str | None = "auto") -> bool:
    """RTS/CTS: 'auto' is on for the XPLR-AOA (its documented default) and off for the others."""
    return protocol == "ublox-aoa" if flow in (None, "auto") else flow in ("rtscts", "on")


def make_driver(spec: PortSpec, taps: list[Tap], **options: Any) -> Driver:
    """The driver for a spec whose kind is known (``options`` go to the driver)."""
    kind = spec.kind
    assert kind in DRIVERS, kind
    if kind == "hci":
        return hci_driver(hci_port(spec, taps), setup=hci_setup(spec, options.pop("setup", None)), **options)
    port = HostPort(spec.where, baud=spec.baud or DEFAULT_BAUD, rtscts=flow_control(kind, spec.flow),
                    name=spec.name or spec.where, taps=taps)
    if kind == "ublox-aoa":
        setup = options.pop("setup", AoaSetup())
        if spec.tags:
            setup = replace(setup, host_filter=frozenset(spec.tags))
        if spec.timeout:
            setup = replace(setup, command_timeout=spec.timeout)
        return AoaDriver(port, setup, **options)
    if kind == "esp-at":
        return EspAtDriver(port, esp_at_setup(spec, options.pop("setup", EspAtSetup())), **options)
    return DRIVERS[kind](port, **options)


def hci_port(spec: PortSpec, taps: list[Tap]) -> HostPort:
    from rfhoming.host.drivers.hci import open_port

    try:
        return open_port(spec.where, name=spec.name, taps=taps)
    except ValueError as exc:
        raise PortSpecError(str(exc)) from None


def hci_setup(spec: PortSpec, setup: Any = None) -> Any:
    """The spec's scan settings over ``setup`` (an HciSetup; default settings if None)."""
    from rfhoming.host.drivers.hci import HciSetup

    setup = setup or HciSetup()
    s = spec.settings
    interval = s.get("interval", setup.interval_ms)
    try:
        return replace(setup, active=s.get("active", setup.active), interval_ms=interval,
                       window_ms=s.get("window", min(setup.window_ms, interval)),
                       extended=s.get("extended", setup.extended), filter_duplicates=s.get("dedup", setup.filter_duplicates),
                       addresses=frozenset([s["mac"].replace(":", "")]) if "mac" in s else setup.addresses,
                       name=s.get("adname", setup.name), content=s.get("content", setup.content),
                       command_timeout=spec.timeout or setup.command_timeout)
    except ValueError as exc:
        raise PortSpecError(f"{spec}: {exc}") from None


def esp_at_setup(spec: PortSpec, setup: EspAtSetup) -> EspAtSetup:
    """The spec's scan settings (active, interval, window, mac, adname) over ``setup``."""
    s = spec.settings
    interval = s.get("interval", setup.interval_ms)
    try:
        return replace(setup, active=s.get("active", setup.active), interval_ms=interval,
                       window_ms=s.get("window", min(setup.window_ms, interval)),
                       filter_mac=s.get("mac", setup.filter_mac), filter_name=s.get("adname", setup.filter_name),
                       command_timeout=spec.timeout or setup.command_timeout)
    except ValueError as exc:
        raise PortSpecError(f"{spec}: {exc}") from None


async def resolve(text: str | PortSpec, *, baud: int | None = None, flow: str | None = None,
                  taps: list[Tap] = (), kind: str | None = None,
                  describe: Callable[..., None] | None = None) -> PortSpec:
    """A spec made concrete: ``auto`` found, the protocol sniffed where not given, defaults
    (``baud``, ``flow`` from the command line) under the spec's own settings.

    ``describe(name, protocol=, kind=)`` is told what the port is (a capture's interface), and
    only then do the bytes that sniffing exchanged reach ``taps``: nothing that crossed the
    port is missing from a capture, and its interface carries the right protocol."""
    spec = portspec.parse(text).with_defaults(baud=baud, flow=flow)
    if kind is not None and spec.kind is None:
        spec = spec.with_kind(kind)
    elif kind is not None and spec.kind != kind:
        raise PortSpecError(f"{spec} is a {spec.kind} port where a {kind} port is wanted")
    if spec.where == "auto":
        spec = replace(spec, where=resolve_auto(AUTO_KIND[spec.kind or "ublox-aoa"]))
    sniffed: list[tuple[str, str, float, bytes]] = []
    if spec.kind is None:
        spec = spec.with_kind(await sniff(spec, lambda *event: sniffed.append(event)))
    if describe is not None:
        describe(spec.name or spec.where, protocol=WIRE_PROTOCOL[spec.kind], kind=DRIVERS[spec.kind].kind)
    for name, direction, t, data in sniffed:
        for tap in taps:
            tap(name, f"sniffed-{direction}", t, data)
    return spec


async def open_drivers(specs: list[str | PortSpec], *, baud: int | None = None, flow: str | None = None,
                       taps: list[Tap] = (), describe: Callable[..., None] | None = None,
                       probe_baud: bool = False) -> list[Driver]:
    """Drivers for the specs (a ``capture:`` spec gives one per recorded device).

    ``probe_baud``: an XPLR-AOA that sends only garbage is probed at every documented rate."""
    drivers: list[Driver] = []
    for text in specs:
        spec = portspec.parse(text)
        if spec.kind == "capture":
            drivers += replay_drivers(spec)
            continue
        if spec.kind == "serve":
            drivers.append(serve_driver(spec))
            continue
        spec = await resolve(spec, baud=baud, flow=flow, taps=taps, describe=describe)
        options = {"setup": AoaSetup(probe_baud=True)} if probe_baud and spec.kind == "ublox-aoa" else {}
        drivers.append(make_driver(spec, list(taps), **options))
    return drivers


def serve_driver(spec: PortSpec) -> Driver:
    """A client of ``rfhoming serve`` (``serve://HOST:PORT``, ``device=`` keeps one device)."""
    from rfhoming.host.serve import ServeDriver

    where = spec.where.removeprefix("//")
    if not where.rpartition(":")[2].isdigit():
        raise PortSpecError(f"{spec} names no server: write serve://HOST:PORT, e.g. serve://127.0.0.1:2947")
    return ServeDriver(HostPort(f"socket://{where}", name=spec.name or f"serve://{where}"),
                       device=spec.settings.get("device"))


def replay_drivers(spec: PortSpec, partial: Callable[[Exception], None] | None = None) -> list[Driver]:
    """One driver per device recorded in a capture (``device=`` picks one), released in the
    recorded global order; CaptureFormatError / OSError when the file cannot be read, or, given
    ``partial``, the error goes there and what came before the damage is replayed."""
    interfaces, packets, torn = load_capture(spec.where, partial=partial)
    if torn and partial is None:
        log.warning("%s ends in a torn block (%d bytes, a killed writer); replaying up to the last "
                    "complete block", spec.where, torn)
    chosen = [i for i, iface in enumerate(interfaces) if spec.settings.get("device") in (None, iface.name)]
    if not chosen:
        names = ", ".join(iface.name for iface in interfaces) or "none"
        raise PortSpecError(f"{spec.where} has no device {spec.settings['device']!r}; it holds: {names}")
    sequencer = Sequencer({interfaces[i].name: packets[i] for i in chosen})
    drivers = []
    for i in chosen:
        port = ReplayPort(interfaces[i].name, packets[i], speed=spec.settings.get("speed") or None,
                          sequencer=sequencer)
        drivers.append(DRIVERS[recorded_kind(interfaces[i])](port))
    return drivers


def recorded_kind(interface: Any) -> str:
    """The driver kind of a capture's interface, from its description."""
    fields = describe_interface(interface)
    if fields.get("kind") == "xplr-aoa" or fields.get("protocol") == "ublox-aoa":
        return "ublox-aoa"
    if fields.get("kind") == "base":
        return "base"
    return fields["protocol"] if fields.get("protocol") in DRIVERS else "rss"


def health(drivers: list[Driver]) -> list[dict[str, Any]]:
    return [d.health() for d in drivers]
