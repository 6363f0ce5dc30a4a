"""What watches a run without steering it (an MCAP recorder, a live view).

A sink sees every decoded item (as a driver listener) and every run log record (as a RunLog
listener). It must never raise into a driver or the loop: a failure goes to ``_failed``, which
counts and logs it.
"""

from __future__ import annotations

from typing import Any


class Sink:
    def on_item(self, device: str, t_host: float, item: Any) -> None:
        """A driver listener: one decoded record or line of ``device``; never raises."""
        try:
            self._on_item(device, t_host, item)
        except Exception as exc:  # noqa: BLE001 - a watcher must not stop the devices
            self._failed(getattr(item, "kind", type(item).__name__), exc)

    def on_runlog(self, record: dict[str, Any]) -> None:
        """A RunLog listener: one run log record (robot time ``t``); never raises."""
        try:
            self._on_runlog(record)
        except Exception as exc:  # noqa: BLE001 - a watcher must not stop the loop
            self._failed(str(record.get("kind")), exc)

    def watch(self, loop: Any) -> None:
        """The homing loop, for sinks that draw its state (the live view); others ignore it."""

    def show_anchors(self, anchors: dict[str, list[float]]) -> None:
        """Beacons at surveyed places (S3's ``[trilat.anchors]``), for sinks that draw them."""

    def close(self) -> None:
        """Flush and release what the sink holds (a file, a server); called once, at the end."""
        raise NotImplementedError

    def _on_item(self, device: str, t_host: float, item: Any) -> None:
        raise NotImplementedError

    def _on_runlog(self, record: dict[str, Any]) -> None:
        raise NotImplementedError

    def _failed(self, kind: str, exc: Exception) -> None:
        raise NotImplementedError
