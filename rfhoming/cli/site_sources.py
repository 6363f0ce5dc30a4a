"""A site's anchors as one stream of bearing readings (host/bearing.py): what ``locate``,
``calibrate``, ``radio-fit`` and ``gateway`` open and read (the site file's ports, or --from /
--device specs, or captures, or angles files, or Silicon Labs locators' broker: host/silabs_source.py)"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rfhoming.cli.args import is_silabs
from rfhoming.host import site as sites
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.angles_file import AnglesFileError, load_angles
from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import replayed_without_set_up
from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.ports import PortError
from rfhoming.host.run_until import run_until
from rfhoming.host.session import health, open_drivers
from rfhoming.protocol.errors import Error

if TYPE_CHECKING:
    from rfhoming.host.silabs_source import SilabsLocators

log = logging.getLogger(__name__)

ANGLES = "angles:"
"""A --from source that is an angles file, not a port spec."""


def load_site(path: Path, command: str) -> sites.Site | None:
    try:
        return sites.load(path)
    except sites.SiteError as exc:
        print(f"rfhoming {command}: {exc}", file=sys.stderr)
        return None


def _specs(site: sites.Site, given: list[str] | None) -> list[str]:
    if given:
        return given
    missing = [a.name for a in site.anchors if a.port is None]
    if missing:
        raise ValueError(f"anchor(s) {', '.join(missing)} have no port in the site file: add port = "
                         "\"xplr-aoa:WHERE\" to each, or give --from SPEC (e.g. --from capture:run.pcapng)")
    return [a.port for a in site.anchors if a.port is not None]


async def gather(command: str, site: sites.Site, sources: list[str] | None, on_angle: Callable[[Bearing], None],
                 on_lost: Callable[[float, set[str]], None] = lambda t, ids: None, *, baud: int | None = None,
                 flow: str | None = None, duration: float | None = None, capture_to: Path | None = None,
                 counters: bool = True, on_item: Callable[[float, Any], None] | None = None,
                 password_file: str | None = None, ca_file: str | None = None) -> int:
    """Open the site's anchors (or ``sources``, locate's --from), feed every reading to
    ``on_angle`` in arrival order until ``duration`` or the end of a capture (``on_item``: the
    board's own item it came from, for exports that show the board's fields), and tell
    ``on_lost`` the anchor ids of a device that went away; ``capture_to``: also record every
    byte there; ``counters``: print each device's counters on stderr at the end (losses are
    warned of either way). ``angles:FILE`` sources are angles files (host/angles_file.py), read
    whole and fed in time order; ``mqtt+silabs://`` sources are Silicon Labs' locators on their broker
    (``password_file``, ``ca_file``: its login and TLS), read until ``duration`` or Ctrl-C. 2 on a
    port/capture/file error, said in one line naming ``command``."""
    by_id = site.anchor_by_id()
    refused: dict[str, int] = {}

    def admit(reading: Bearing) -> None:  # an anchor the site does not know: the consumers count it
        anchor = by_id.get(reading.anchor)
        admitted = reading if anchor is None else anchor.admit(reading)
        if admitted is not None:
            on_angle(admitted)
        elif anchor is not None:
            refused[anchor.name] = refused.get(anchor.name, 0) + 1

    try:
        if sources and any(is_silabs(s) for s in sources):
            return await _from_silabs(command, sources, admit, duration, counters, password_file, ca_file)
        files = [s.removeprefix(ANGLES) for s in sources or [] if s.startswith(ANGLES)]
        if files:
            return _from_files(command, site, files, len(files) != len(sources or []), admit)
        return await _from_devices(command, site, sources, admit, on_lost, baud=baud, flow=flow, duration=duration,
                                   capture_to=capture_to, counters=counters, on_item=on_item)
    finally:
        if refused:
            print(f"rfhoming {command}: readings outside their anchor's field of view (fov_deg in the site file) "
                  f"refused: " + ", ".join(f"{n} {k}" for n, k in sorted(refused.items())), file=sys.stderr)


async def _from_devices(command: str, site: sites.Site, sources: list[str] | None, on_angle: Callable[[Bearing], None],
                        on_lost: Callable[[float, set[str]], None], *, baud: int | None, flow: str | None,
                        duration: float | None, capture_to: Path | None, counters: bool,
                        on_item: Callable[[float, Any], None] | None) -> int:
    specs = _specs(site, sources)
    capture = CaptureWriter(capture_to) if capture_to else None
    try:
        drivers: list[Driver] = await open_drivers(specs, baud=baud, flow=flow,
                                                   taps=[capture.tap] if capture else [],
                                                   describe=capture.describe if capture else None)
    except BaseException as exc:  # a port that does not open, or Ctrl-C while they open
        if capture is not None:
            capture.close()  # nothing came: the old file stays
        if not isinstance(exc, (OSError, Error)):
            raise
        said = f"cannot read {exc.filename}: {exc.strerror}" if isinstance(exc, OSError) else str(exc)
        print(f"rfhoming {command}: {said}", file=sys.stderr)
        return 2

    as_recorded = [d.port.name for d in drivers if d.sets_up and replayed_without_set_up(d.port)]
    if as_recorded:
        log.info("replayed angle streams with no set-up exchange (%s): angles taken as recorded",
                 ", ".join(as_recorded))
    heard: dict[str, set[str]] = {}  # device -> the anchor ids in its events

    def listening(d: Driver) -> Callable[[str, float, Any], None]:
        def listener(device: str, t: float, item: Any) -> None:
            reading = d.bearing(t, item)
            if reading is not None:
                heard.setdefault(device, set()).add(reading.anchor)
                if on_item is not None:
                    on_item(t, item)
                on_angle(reading)
        return listener

    def tap(device: str, direction: str, t: float, _data: bytes) -> None:
        if direction == "lost":
            on_lost(t, heard.get(device, set()))

    for d in drivers:
        d.listeners.append(listening(d))
        d.port.taps.append(tap)
    # the listener took every event already: empty the drivers' queues so they count no drops
    drains = [asyncio.create_task(_discard(d.out)) for d in drivers]
    try:
        await run_until(drivers, duration, drains)
    except PortError as exc:
        print(f"rfhoming {command}: {exc}", file=sys.stderr)
        return 2
    finally:
        for h in health(drivers):  # losses are warned of here, printed or not
            if counters:
                print(json.dumps({"kind": "counters", **h}), file=sys.stderr)
        if capture is not None:
            capture.close()
            print(capture.said(), file=sys.stderr)
    return 0


def _from_files(command: str, site: sites.Site, files: list[str], mixed: bool,
                on_angle: Callable[[Bearing], None]) -> int:
    if mixed:
        print(f"rfhoming {command}: --from {ANGLES}FILE cannot be mixed with ports or captures: give only angles "
              "files (or render the others into one)", file=sys.stderr)
        return 2
    ids = {a.id for a in site.anchors}
    try:
        readings = sorted((r for f in files for r in load_angles(Path(f), ids)), key=lambda r: r.t)
    except AnglesFileError as exc:
        print(f"rfhoming {command}: {exc}", file=sys.stderr)
        return 2
    for reading in readings:
        on_angle(reading)
    return 0


SILABS_POLL_S = 0.02
"""Seconds between takes of the locators' readings: the locator's 0.3 s windows see no gap."""


def _open_silabs(url: str, password_file: str | None, ca_file: str | None) -> SilabsLocators:
    """The locators' subscription (paho-mqtt, the "site" extra), opened off the event loop: the
    import and a password file's read would stall it."""
    from rfhoming.host.silabs_source import SilabsLocators, Source

    return SilabsLocators(Source.parse(url), password_file=password_file, ca_file=ca_file)


async def _from_silabs(command: str, sources: list[str], on_angle: Callable[[Bearing], None],
                       duration: float | None, counters: bool, password_file: str | None,
                       ca_file: str | None) -> int:
    if len(sources) > 1:
        print(f"rfhoming {command}: --from mqtt+silabs:// is one broker's locators; give it alone (every locator "
              "under its topic prefix is read)", file=sys.stderr)
        return 2
    try:
        locators = await asyncio.to_thread(_open_silabs, sources[0], password_file, ca_file)
    except Error as exc:
        print(f"rfhoming {command}: {exc}", file=sys.stderr)
        return 2
    loop = asyncio.get_running_loop()
    end = math.inf if duration is None else loop.time() + duration
    try:
        while loop.time() < end:
            await asyncio.sleep(min(SILABS_POLL_S, max(0.0, end - loop.time())))
            locators.check()
            for reading in locators.take():
                on_angle(reading)
    except Error as exc:  # the broker refused for good: a login, a certificate
        print(f"rfhoming {command}: {exc}", file=sys.stderr)
        return 2
    finally:
        await asyncio.to_thread(locators.close)  # joins paho's thread, which may be waiting to reconnect
        if counters:
            print(json.dumps({"kind": "counters", **locators.health()}), file=sys.stderr)
    return 0


async def _discard(stream: BoundedStream[Any]) -> None:
    async for _ in stream:
        pass
