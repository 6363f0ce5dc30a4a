"""Waiting for an unplugged device to come back, so that a short unplug costs its own length
and not the back-off's: a device path (or a pty's stable symlink) that has gone is polled every
:data:`POLL_S` and reopened as soon as it is there again; while the path is there and the open
still fails (a busy or half-enumerated device), the caller's exponential back-off applies.
"""

from __future__ import annotations

from asyncio import sleep
from os.path import exists

POLL_S = 0.2
"""How often a vanished device path is looked for: the reopen follows its return within this."""


def watchable(spec: str) -> bool:
    """A local device path (not socket://, loop:// or another pyserial URL, nor COM3)."""
    return spec.startswith("/")


async def wait_for_return(path: str, backoff_s: float) -> bool:
    """Wait before the next open of ``path``: ``backoff_s`` while the device is present, or --
    once it is absent -- until it is back, whatever the back-off. True when it came back (the
    caller starts its back-off over: this is a new device, not the one that failed)."""
    if not watchable(path):
        await sleep(backoff_s)
        return False
    left = backoff_s
    while exists(path):
        if left <= 0:
            return False
        step = min(POLL_S, left)
        await sleep(step)
        left -= step
    while not exists(path):
        await sleep(POLL_S)
    return True
