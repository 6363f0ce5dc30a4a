"""The kit scenario recorded in-process: every anchor's +UUDF bytes through the emulator's pipe
and the host's decoder, stamped with the emulator's clock (so truth lines up exactly), and the
tags' true 3-D positions. Used by bench/locate_bench.py and the locate tests."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfhoming.emulator import scenario as scenarios
from rfhoming.emulator.anchors import FixedAnchorRunner
from rfhoming.emulator.links import pipe_end
from rfhoming.emulator.runtime import Emulator
from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import UConnectDecoder

CALIBRATION_POINTS: dict[str, tuple[float, float, float]] = {
    "CCF9578E0C01": (2.0, 1.5, 0.8), "CCF9578E0C02": (6.0, 3.0, 0.3), "CCF9578E0C03": (10.0, 4.5, 1.2),
    "CCF9578E0C04": (3.5, 4.8, 0.5), "CCF9578E0C05": (9.0, 1.2, 1.0), "CCF9578E0C06": (6.0, 5.0, 1.5),
}
"""The kit-room-cal scenario's static tags (x, y, z), as docs/sites/kit-room-points.toml."""


@dataclass
class Recording:
    events: list[Bearing]
    truth: Callable[[str, float], np.ndarray]  # (tag, t) -> (x, y, z)
    tags: list[str]
    anchors_truth: list[dict[str, Any]]


async def _record(sc: scenarios.Scenario, seed: int, duration: float) -> Recording:
    em = Emulator(sc, transport="pipe", seed=seed, speed=float("inf"))
    await em.start()
    decoders = {d.name: UConnectDecoder() for d in em.devices}
    events: list[Bearing] = []
    while em.t < duration:
        await em.step()
        for d in em.devices:
            end = pipe_end(d.link)
            while end.pending():
                for item in decoders[d.name].feed(await end.read()):
                    if item.kind == "angle":
                        events.append(bearing_of(round(em.t, 6), item))
    await em.close()
    targets = {t.id: t for t in sc.world.targets}

    def truth(tag: str, t: float) -> np.ndarray:
        target = targets[tag]
        x, y = target.position_at(t)
        return np.array([x, y, target.height])

    return Recording(events, truth, sorted(targets), [d.truth() for d in em.devices if isinstance(d, FixedAnchorRunner)])


HARD_BOARDS = {"angle_model": "cone", "az_compression": 0.15, "slow_bias_deg": 2.0, "slow_bias_s": 10.0,
               "elevation_sigma_deg": 8.0}
"""The emulated anchors' harder options (emulator/anchors.py, each *assumed*): boards at least as
hard as real ones were on four-anchor recordings with ground truth that the repository does not hold."""


WALL_ROOM = {"anchor_height_m": 2.3, "tag_height_m": 1.1}
"""A room that fails like a real one (*assumed*: what a real four-anchor site shows, no public
recording of it is in this repository): the anchors 2.3 m up at the walls' middles and every
walking tag carried at one height, 1.1 m, so that elevation is poorly observed unless the
height is known. The surveyed points keep their own heights."""


def record(seed: int = 0, duration: float = 30.0, calibration: bool = False,
           boards: dict[str, Any] | None = None, room: dict[str, Any] | None = None,
           radio: str = "ideal") -> Recording:
    """A run of the kit scenario (or, with ``calibration``, kit-room-cal: the same anchors --
    same seed, same hidden errors -- with static tags at :data:`CALIBRATION_POINTS`); ``boards``:
    error-model options set on every anchor (e.g. :data:`HARD_BOARDS`); ``room``: the room's
    geometry changed as :data:`WALL_ROOM`; ``radio``: the boards' errors from a radio profile
    instead (``measured`` or a file: docs/emulator.md)."""
    sc = scenarios.load("kit-room-cal" if calibration else "kit-room", seed=seed, radio=radio)
    for device in sc.devices:
        device.options.update(boards or {})
        if room:
            device.options["position"] = [*device.options["position"][:2], room["anchor_height_m"]]
    if room and not calibration:
        for target in sc.world.targets:
            target.height = room["tag_height_m"]
    return asyncio.run(_record(sc, seed, duration))
