"""Fail fast: watch the drivers a command or a homing run uses and end it, with a message
naming the device, when one cannot go on -- its port never opened, its set-up failed on a port
that said nothing, it was not ready within its deadline (the device table's ``setup_timeout_s`` for its kind, or the
spec's ``timeout=``), or several tags are in view and none was chosen.

A deadline counts from the device's first bytes, or from its port's open while it says
nothing -- only a port whose open has not returned (a ROS 2 base's returns at its first
odometry) is timed from the start: on a loaded machine the time before a device's first answer
is the machine's, not the device's. A port that stays silent still fails fast, through its
driver's own first set-up command."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

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
    """Set up (a kind with set-up commands), or open (one without)."""
    return driver.state == "streaming" if driver.sets_up else driver.connected.is_set()


def hopeless(driver: Driver) -> bool:
    """A failed set-up on a port that has said nothing at all: waiting cannot help (wiring, baud).
    A device that talks but failed once -- a busy machine, a board that booted under the host --
    gets the set-up's retries until its deadline."""
    return driver.state == "setup_failed" and driver.port.counters.get("bytes_in", 0) == 0


async def supervise(deadlines: dict[Driver, float], *, clock: Callable[[], float] = time.monotonic,
                    period: float = 0.05) -> None:
    """Raise PortError or DeviceNotReady as soon as a driver cannot go on; runs until cancelled
    (returns at once when there is nothing to watch, e.g. a replay). ``clock`` must be the
    drivers' own (:attr:`Driver.contact_clock`)."""
    if not deadlines:
        return
    waiting = dict(deadlines)
    start = clock()
    while True:
        await asyncio.sleep(period)
        for driver in deadlines:
            if driver.error is not None:
                if isinstance(driver.error, PortError):
                    raise PortError(str(driver.error))
                if isinstance(driver.error, Error):
                    raise DeviceNotReady(f"{driver.port.name}: {driver.error}")
                raise driver.error  # a bug in the driver, not the user's to fix
            stuck = driver.cannot_go_on()
            if stuck is not None:
                raise DeviceNotReady(f"{driver.port.name}: {stuck}")
        for driver, limit in list(waiting.items()):
            since = start if driver.contact_at is None else driver.contact_at
            if ready(driver):
                del waiting[driver]
            elif hopeless(driver) or clock() - since > limit:
                why = getattr(driver, "problem", None) or f"still {driver.state}"
                if driver.opened_at is not None and driver.port.counters.get("bytes_in", 0) == 0 \
                        and driver.state != "setup_failed":
                    raise DeviceNotReady(f"{driver.port.name} ({driver.kind}) said nothing within {limit:g} s of its "
                                         f"port opening: {driver.problem or driver.silent_hint()}")
                if driver.state == "setup_failed":
                    raise DeviceNotReady(f"{driver.port.name} ({driver.kind}): set-up failed: {why}")
                raise DeviceNotReady(f"{driver.port.name} ({driver.kind}) was not ready within {limit:g} s of its "
                                     f"first answer: {why}; "
                                     "a longer wait: timeout=SECONDS in its port spec")
