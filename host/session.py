"""Port specs -> drivers: the one place where a spec string becomes a running device.

A spec (:mod:`rfhoming.host.portspec`) names its kind -- a device kind of the device table
(:mod:`rfhoming.protocol.devices`: ``xplr-aoa``, ``rss-node``, ``esp-at``, ``hci``, ``base``) --
or leaves it out to have the protocol sniffed from what the port says; ``capture:FILE``
replays a recording as the devices it holds; ``serve://HOST:PORT`` is a client of ``rfhoming
serve``, which owns the devices. Used by ``listen``, ``capture``, ``replay``, the run assembly
and the Python API alike.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

from rfhoming.host import portspec
from rfhoming.host.discovery import resolve_auto
from rfhoming.host.drivers.common import DEFAULT_BAUD, Driver, Wiring
from rfhoming.host.losses import with_losses
from rfhoming.host.ports import HostPort, PortError, Tap
from rfhoming.host.portspec import PortSpec, PortSpecError
from rfhoming.host.replay import ReplayPort, Sequencer, load_capture
from rfhoming.host.replay import describe as describe_interface
from rfhoming.protocol import devices
from rfhoming.protocol.devices import DeviceKind

SNIFF_SECONDS = 1.5

log = logging.getLogger(__name__)


def driver_class(record: DeviceKind) -> type[Driver]:
    """The driver of a device kind, imported when first used (HCI's needs bumble)."""
    try:
        cls: type[Driver] = devices.load(record.driver)
    except ImportError as exc:
        extra = f"; install it with pip install 'rfhoming[{record.extra}]'" if record.extra else ""
        raise PortError(f"{record.name}: ports need {exc.name or exc}{extra}") from None
    return cls


def sniffable() -> list[tuple[DeviceKind, type[Driver]]]:
    """The kinds a port's bytes can tell, with their drivers, in the order the device table's
    ``sniff`` gives."""
    return [(k, driver_class(k)) for k in sorted(devices.KINDS.values(), key=lambda k: k.sniff) if k.sniff]


def what_speaks(data: bytes) -> str | None:
    """The first sniffable kind whose driver recognises ``data`` (:meth:`Driver.speaks`), else None."""
    return next((k.name for k, cls in sniffable() if cls.speaks(data)), None)


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
        poke = b"".join(cls.poke for _, cls in sniffable())
        if what_speaks(data) is None and poke:
            port.write(poke)
            data += await gather(1.0)
    finally:
        await port.close()
    found = what_speaks(data)
    if found is None:
        named = " or ".join(f"{k.name}:{spec.where}" for k in devices.KINDS.values() if k.sniff)
        raise PortError(f"could not tell what speaks on {spec.where} ({len(data)} bytes, none valid): "
                        f"name it, e.g. {named}; if it is garbage, the baud rate is probably wrong (add ,baud=RATE)")
    return found


def make_driver(spec: PortSpec, taps: list[Tap], **options: Any) -> Driver:
    """The driver for a spec whose kind is known (``options`` go to the driver)."""
    record = spec.device
    assert record is not None, spec
    return driver_class(record).from_spec(spec, list(taps), **options)


async def resolve(text: str | PortSpec, *, baud: int | None = None, flow: str | None = None,
                  taps: Sequence[Tap] = (), kind: str | None = None,
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
        usb = devices.kind(spec.kind or devices.ROLES["aoa"].default_kind).usb
        if usb is None:
            raise PortSpecError(f"{spec}: a {spec.kind} device cannot be found by auto; name it")
        spec = replace(spec, where=resolve_auto(usb.name))
    sniffed: list[tuple[str, str, float, bytes]] = []
    if spec.kind is None:
        spec = spec.with_kind(await sniff(spec, lambda *event: sniffed.append(event)))
    if describe is not None:
        assert spec.kind is not None  # named, or sniffed just now
        record = devices.kind(spec.kind)
        describe(spec.name or spec.where, protocol=record.protocol, kind=record.name, label=label(spec.where, spec.name),
                 **driver_class(record).describe_spec(spec))  # e.g. a ROS 2 base's topics
    for name, direction, t, data in sniffed:
        for tap in taps:
            tap(name, f"sniffed-{direction}", t, data)
    return spec


async def open_drivers(specs: Sequence[str | PortSpec], *, baud: int | None = None, flow: str | None = None,
                       taps: Sequence[Tap] = (), describe: Callable[..., None] | None = None,
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
        assert spec.device is not None, spec
        options = driver_class(spec.device).options(Wiring(probe_baud=probe_baud))
        drivers.append(make_driver(spec, list(taps), **options))
    return drivers


def serve_driver(spec: PortSpec, **options: Any) -> Driver:
    """A client of ``rfhoming serve`` (``serve://HOST:PORT``, ``device=`` keeps one device)."""
    from rfhoming.host.drivers.serve_client import ServeDriver

    where = spec.where.removeprefix("//")
    if not where.rpartition(":")[2].isdigit():
        raise PortSpecError(f"{spec} names no server: write serve://HOST:PORT, e.g. serve://127.0.0.1:2947")
    return ServeDriver(HostPort(f"socket://{where}", name=spec.name or f"serve://{where}"),
                       device=spec.settings.get("device"), **options)


def replay_drivers(spec: PortSpec, partial: Callable[[Exception], None] | None = None) -> list[Driver]:
    """One driver per device recorded in a capture (``device=`` picks one), released in the
    recorded global order; CaptureFormatError / OSError when the file cannot be read, or, given
    ``partial``, the error goes there and what came before the damage is replayed."""
    interfaces, packets, torn = load_capture(spec.where, partial=partial)
    if torn and partial is None:
        log.warning("%s ends in a torn block (%d bytes, a killed writer); replaying up to the last "
                    "complete block", spec.where, torn)
    wanted = spec.settings.get("device")
    chosen = [i for i, iface in enumerate(interfaces) if wanted is None or wanted in names_of(iface)]
    if not chosen:
        held = "; ".join(" = ".join(names_of(iface)) for iface in interfaces) or "none"
        raise PortSpecError(f"{spec.where} has no device {wanted!r}; it holds: {held}")
    sequencer = Sequencer({interfaces[i].name: packets[i] for i in chosen}, lead=True)  # no loop to feed
    drivers = []
    for i in chosen:
        record = recorded_kind(interfaces[i])
        port = ReplayPort(interfaces[i].name, packets[i], speed=spec.settings.get("speed") or None,
                          sequencer=sequencer, match_writes=not record.commanded)
        drivers.append(driver_class(record)(port))
    return drivers


def names_of(interface: Any) -> list[str]:
    """What ``device=`` may call a recorded device: its path, its short label and its role in a run."""
    fields = describe_interface(interface)
    return list(dict.fromkeys(n for n in (interface.name, fields.get("label"), fields.get("role")) if n))


def label(where: str, name: str | None = None) -> str:
    """A device's short, stable name for a capture: its spec's ``name=``, else the last part of
    its path (``aoa`` for /tmp/rfhoming-demo-x1y2/aoa, ``ttyUSB0`` for /dev/ttyUSB0)."""
    return name or where.rstrip("/").rpartition("/")[2].rpartition(":")[2] or where


def recorded_kind(interface: Any) -> DeviceKind:
    """The device kind of a capture's interface: the ``kind=`` it recorded (older captures'
    names are aliases), else its link type's."""
    return devices.recorded_kind(describe_interface(interface), interface.linktype)


def health(drivers: list[Driver]) -> list[dict[str, Any]]:
    """Each driver's counters, its nonzero losses under ``losses`` (each warned of once)."""
    return [with_losses(d.health()) for d in drivers]
