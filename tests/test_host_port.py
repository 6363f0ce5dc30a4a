"""A serial port whose device goes away under a write: one disconnect, no traceback."""

from __future__ import annotations

import asyncio
import os
from typing import Any

from rfhoming.host.ports import HostPort


async def test_a_write_to_a_device_that_went_away_is_a_disconnect_not_a_traceback() -> None:
    """A host stopping its base while the emulator's pty is already gone (both got SIGTERM at
    a shutdown) wrote into EIO: the transport handed that to the event loop's exception handler,
    which printed a traceback beside the port's own one-line disconnect."""
    master, slave = os.openpty()
    handled: list[dict[str, Any]] = []
    asyncio.get_running_loop().set_exception_handler(lambda loop, context: handled.append(context))
    port = HostPort(os.ttyname(slave))
    try:
        await port.open()
        os.close(master)
        port.write(b"\x00stop\x00")
        async with asyncio.timeout(10):
            while port.is_open:
                await asyncio.sleep(0.01)
    finally:
        os.close(slave)
        await port.close()
    assert handled == [] and port.counters["disconnects"] == 1
