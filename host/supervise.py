"""Fail fast: watch the drivers a command or a homing run uses and end it, with a message
naming the device, when one cannot go on -- its port never opened, its set-up failed on a port
that said nothing, it was not ready within its deadline (the device table's ``setup_timeout_s`` for its kind, or the
spec's ``timeout=``), or several tags are in view and none was chosen."""

from __future__ import annotations

import asyncio
import time

from rfhoming.host.drivers.aoa import AoaDriver
from rfhoming.host.drivers.common import Driver
from rfhoming.host.ports import HostPort, PortError
from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error

DEFAULT_SETUP_TIMEOUT_S = 5.0
"""For what is not a device kind of the table (a client of ``rfhoming serve``)."""


class DeviceNotReady(Error):
    """A device the command needs cannot be used; the message names it and says why."""


def deadline(driver: Driver, timeout: float | None = None) -> float:
    """How long ``driver`` may take to open and be set up: ``timeout`` (a spec's ``timeout=``)
    or its kind's ``setup_timeout_s``."""
    if timeout is not None:
        return timeout
    record = devices.KINDS.get(driver.kind)
    return record.setup_timeout_s if record else DEFAULT_SETUP_TIMEOUT_S


def live(drivers: list[Driver]) -> dict[Driver, float]:
    """Deadlines for the drivers on real ports (a replayed capture has nothing to set up)."""
    return {d: deadline(d) for d in drivers if isinstance(d.port, HostPort)}


def ready(driver: Driver) -> bool:
    return driver.state == "streaming" if isinstance(driver, AoaDriver) else driver.connected.is_set()


def hopeless(driver: Driver) -> bool:
    """A failed set-up on a port that has said nothing at all: waiting cannot help (wiring, baud).
    A device that talks but failed once -- a busy machine, a board that booted under the host --
    gets the set-up's retries until its deadline."""
    return driver.state == "setup_failed" and driver.port.counters.get("bytes_in", 0) == 0


async def supervise(deadlines: dict[Driver, float]) -> None:
    """Raise PortError or DeviceNotReady as soon as a driver cannot go on; runs until cancelled
    (returns at once when there is nothing to watch, e.g. a replay)."""
    if not deadlines:
        return
    start = time.monotonic()
    waiting = dict(deadlines)
    while True:
        await asyncio.sleep(0.05)
        for driver in deadlines:
            if driver.error is not None:
                if isinstance(driver.error, PortError):
                    raise PortError(str(driver.error))
                if isinstance(driver.error, Error):
                    raise DeviceNotReady(f"{driver.port.name}: {driver.error}")
                raise driver.error  # a bug in the driver, not the user's to fix
            if isinstance(driver, AoaDriver) and driver.ambiguous_tags:
                raise DeviceNotReady(f"{driver.port.name}: {driver.problem}")
        for driver, limit in list(waiting.items()):
            if ready(driver):
                del waiting[driver]
            elif hopeless(driver) or time.monotonic() - start > limit:
                why = getattr(driver, "problem", None) or f"still {driver.state}"
                if driver.state == "setup_failed":
                    raise DeviceNotReady(f"{driver.port.name} ({driver.kind}): set-up failed: {why}")
                raise DeviceNotReady(f"{driver.port.name} ({driver.kind}) was not ready within {limit:g} s: {why}; "
                                     "a longer wait: timeout=SECONDS in its port spec")
