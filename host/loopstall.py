"""How long the event loop was blocked: a heartbeat that measures its own lateness, and a
timer on every callback the loop runs that names any over a threshold.

Cheap enough for every run (asyncio's debug mode is not): one task waking every ``period_s``,
two clock reads per callback. ``loop_stall_ms_max`` is the longest the heartbeat was late or
one callback ran, whichever is longer; ``loop_stall_ms_p99`` the heartbeat's 99th percentile.
A stall delays every reading and command behind it: a control period of 0.1 s cannot hold
with stalls of that size.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

T = TypeVar("T")

THRESHOLD_MS = 25.0
"""A callback running longer than this is reported, with what it was."""
MAX_REPORTED = 100
"""Stalls reported one by one per run at most (then counted)."""

_watched: dict[asyncio.AbstractEventLoop, StallMonitor] = {}
_handle_run = asyncio.Handle._run


def _timed_run(handle: asyncio.Handle) -> None:
    monitor = _watched.get(handle._loop)  # type: ignore[attr-defined]
    if monitor is None:
        _handle_run(handle)
        return
    start = time.perf_counter()
    try:
        _handle_run(handle)
    finally:
        took = (time.perf_counter() - start) * 1000
        if took > monitor.longest_callback_ms:
            monitor.longest_callback_ms = took
        if took > monitor.threshold_ms:
            monitor.callback_over(took, handle)


def _describe(handle: asyncio.Handle) -> str:
    """What a handle ran: a task's coroutine, or the callback's name."""
    callback = handle._callback  # type: ignore[attr-defined]
    task = getattr(callback, "__self__", None)
    if isinstance(task, asyncio.Task):
        coro = task.get_coro()
        return f"task {task.get_name()}: {getattr(coro, '__qualname__', coro)}"
    return getattr(callback, "__qualname__", repr(callback))


class StallMonitor:
    """``async with StallMonitor() as stalls:`` around a run; ``on_stall`` hears each callback
    over the threshold (milliseconds, what ran) as it ends."""

    def __init__(self, period_s: float = 0.01, threshold_ms: float = THRESHOLD_MS,
                 on_stall: Callable[[float, str], None] | None = None) -> None:
        self.period_s, self.threshold_ms, self.on_stall = period_s, threshold_ms, on_stall
        self.late_ms: deque[float] = deque(maxlen=50_000)  # bounded: the latest heartbeats
        self.late_max_ms = 0.0
        self.longest_callback_ms = 0.0
        self.over: list[dict[str, Any]] = []
        self.over_count = 0
        self._task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> StallMonitor:
        loop = asyncio.get_running_loop()
        if loop in _watched:  # one monitor per loop: a nested run is measured by the outer one
            return _watched[loop]
        _watched[loop] = self
        asyncio.Handle._run = _timed_run  # type: ignore[method-assign,assignment]
        self._task = asyncio.create_task(self._beat(), name="loop-stall heartbeat")
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._task is None:
            return
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)
        _watched.pop(asyncio.get_running_loop(), None)
        if not _watched:
            asyncio.Handle._run = _handle_run  # type: ignore[method-assign]

    async def _beat(self) -> None:
        clock = time.perf_counter
        while True:
            start = clock()
            await asyncio.sleep(self.period_s)
            late = max(0.0, (clock() - start - self.period_s) * 1000)
            self.late_ms.append(late)
            self.late_max_ms = max(self.late_max_ms, late)

    def callback_over(self, took_ms: float, handle: asyncio.Handle) -> None:
        self.over_count += 1
        if len(self.over) >= MAX_REPORTED:
            return
        ran = _describe(handle)
        self.over.append({"ms": round(took_ms, 1), "ran": ran})
        if self.on_stall is not None:
            self.on_stall(took_ms, ran)

    def summary(self) -> dict[str, Any]:
        late = sorted(self.late_ms)
        p99 = late[min(len(late) - 1, int(0.99 * len(late)))] if late else 0.0
        return {"loop_stall_ms_max": round(max(self.late_max_ms, self.longest_callback_ms), 1),
                "loop_stall_ms_p99": round(p99, 1)}


async def watching(awaitable: Awaitable[T], monitor: StallMonitor) -> T:
    """``awaitable``'s result, with ``monitor`` measuring the loop while it runs."""
    async with monitor:
        return await awaitable
