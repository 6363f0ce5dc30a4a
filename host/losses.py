"""Losses: the counters that mean data was lost, said out loud.

A counter is seen only by whoever reads it. So every counter below, the first time it rises
on a device, logs one warning naming the device and what to do, and every end-of-run summary
carries the nonzero ones (``"losses"`` in each device's counters line: :func:`with_losses`).
A counter of input that was malformed when it came (a CRC mismatch, a garbled line) is not here:
the host lost nothing it could have kept.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable
from typing import Any

log = logging.getLogger(__name__)

SLOW_CONSUMER = "its consumer takes readings slower than they come: fewer devices or tags, a lower rate, a faster machine"
LOSSES: dict[str, str] = {
    "queue_dropped": SLOW_CONSUMER,
    "dropped_bytes": "the host read the port too slowly and its buffer overflowed: a less loaded machine, "
                     "or a lower baud rate / report rate on the device",
    "samples_dropped": "the host took the ROS 2 samples too slowly: a less loaded machine or a lower publish rate",
    "lost_records": "records the node numbered never arrived: check the cable, baud= and flow control",
    "partial_dropped": "more advertisers sent fragments at once than are held: fewer devices in range, or "
                       "a passive scan (active=no)",
    "server_dropped": "rfhoming serve dropped items this client read too slowly: a less loaded client machine",
    "overflow": "more angle events waited for reordering than are held: a smaller site or a lower tag rate",
    "dropped": "a buffer overflowed: a publisher's while its broker was slow or away (check the broker), "
               "or rfhoming serve's for a client that reads too slowly",
    "lost_batches": "batches a gateway numbered never arrived: check the broker and the gateways' links",
    "inbox_dropped": "the worker took batches slower than they came: more workers (partitions) or a faster machine",
    "decoder.drop.overlong": "lines past the decoder's bound were discarded: check baud= (garbage has no line ends)",
    "decoder.drop.oversize": "frames or lines past the decoder's bound were discarded: check baud= and the cable",
}
"""Counter -> what to do about it. ``decoder.drop.*`` are the decoders' counters as a driver's
health shows them."""


def losses(counters: dict[str, Any]) -> dict[str, int]:
    """The nonzero loss counters of a health snapshot or a counters dict."""
    return {k: v for k, v in counters.items() if k in LOSSES and isinstance(v, int) and v > 0}


class LossWarnings:
    """One warning per (device, counter), the first time the counter is nonzero."""

    def __init__(self) -> None:
        self._said: set[tuple[str, str]] = set()

    def check(self, device: str, counters: dict[str, Any]) -> dict[str, int]:
        """Warn of what is newly lost on ``device``; the nonzero losses."""
        found = losses(counters)
        for counter, count in found.items():
            if (device, counter) not in self._said:
                self._said.add((device, counter))
                log.warning("%s lost data: %s = %d and counting; %s", device, counter, count, LOSSES[counter])
        return found


WARNINGS = LossWarnings()
"""The process's: a device's loss is said once however many places look at it."""


def with_losses(snapshot: dict[str, Any], warnings: LossWarnings = WARNINGS) -> dict[str, Any]:
    """A device's health snapshot with its nonzero losses under ``losses`` (warned of once)."""
    return {**snapshot, "losses": warnings.check(str(snapshot.get("device", "?")), snapshot)}


async def watch(snapshots: Callable[[], Iterable[dict[str, Any]]], period: float = 0.5,
                warnings: LossWarnings = WARNINGS) -> None:
    """Look at the snapshots every ``period`` seconds and warn of new losses; until cancelled."""
    while True:
        await asyncio.sleep(period)
        for snapshot in snapshots():
            with_losses(snapshot, warnings)
