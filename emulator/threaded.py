"""An emulator on an event loop of its own, in a thread: for a caller that is not asyncio (a test,
a bench) and must act on the world -- unplug a link, replug it -- exactly when it chooses."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Coroutine
from typing import Any

from rfhoming.emulator.runtime import Emulator


class EmulatorThread:
    """Starts ``emulator`` in a thread and runs it until :meth:`close`; ``endpoints`` are what
    its start gave, by device name. ``timeout_s`` bounds every wait (a hang guard)."""

    def __init__(self, emulator: Emulator, timeout_s: float = 60.0) -> None:
        self.emulator, self.timeout_s = emulator, timeout_s
        self.loop = asyncio.new_event_loop()
        self.endpoints: dict[str, dict[str, Any]] = {}
        self._task: asyncio.Task[None] | None = None
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.endpoints = {e["device"]: e for e in self.call(emulator.start())}
        self._task = asyncio.run_coroutine_threadsafe(self._spawn(), self.loop).result(timeout_s)

    async def _spawn(self) -> asyncio.Task[None]:
        return asyncio.get_running_loop().create_task(self.emulator.run())

    def call(self, coro: Coroutine[Any, Any, Any]) -> Any:
        """Run ``coro`` on the emulator's loop and wait for its result."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(self.timeout_s)

    def close(self) -> None:
        async def stop() -> None:
            if self._task is not None:
                self._task.cancel()
                await asyncio.gather(self._task, return_exceptions=True)
            await self.emulator.close()

        self.call(stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(self.timeout_s)
        self.loop.close()
