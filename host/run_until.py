"""Run opened drivers until a duration, Ctrl-C or SIGTERM, or a driver that cannot go on: what
``listen``, ``capture``, ``replay``, ``serve`` and the site commands share."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import signal
from collections.abc import Iterable
from typing import Any

from rfhoming.host import losses
from rfhoming.host.drivers.common import Driver
from rfhoming.host.ports import PortError
from rfhoming.host.session import health
from rfhoming.host.supervise import DeviceNotReady, live, supervise

log = logging.getLogger(__name__)

HEALTH_PERIOD_S = 10.0


async def log_health(drivers: list[Driver]) -> None:
    """Every HEALTH_PERIOD_S, each driver's counters at INFO (``-v``)."""
    while True:
        await asyncio.sleep(HEALTH_PERIOD_S)
        for h in health(drivers):
            log.info("health %s", json.dumps(h))


async def run_until(drivers: list[Driver], duration: float | None, extra: Iterable[asyncio.Task[Any]] = ()) -> None:
    """Run the drivers until ``duration`` or Ctrl-C; a driver that cannot go on (a port that
    never opened, a set-up that failed or timed out) ends it with PortError/DeviceNotReady.
    ``extra`` tasks are cancelled with the drivers; the drivers' ports are closed at the end."""
    tasks = [asyncio.create_task(d.run()) for d in drivers]
    tasks.append(asyncio.create_task(supervise(live(drivers))))
    tasks += list(extra)
    tasks.append(asyncio.create_task(log_health(drivers)))
    tasks.append(asyncio.create_task(losses.watch(lambda: health(drivers))))
    main = asyncio.current_task()
    assert main is not None, "run_until is awaited in a task"
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, main.cancel)
    try:
        if duration is None:
            done, _ = await asyncio.wait(tasks[: len(drivers) + 1], return_when=asyncio.FIRST_EXCEPTION)
        else:
            done, _ = await asyncio.wait(tasks[: len(drivers) + 1], timeout=duration,
                                         return_when=asyncio.FIRST_EXCEPTION)
        for task in done:
            task.result()  # surface a PortError from a first open
    except asyncio.CancelledError:
        pass
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, PortError, DeviceNotReady):
                await task
        for d in drivers:
            d.drain()
            await d.port.close()
