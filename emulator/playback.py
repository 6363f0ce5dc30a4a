"""Serve a capture on pseudo-terminals, paced by its recorded timestamps (gpsd's gpsfake idea).

Each interface of the capture becomes a pty (a stable symlink); its recorded inbound bytes are
written at their recorded times relative to the first packet (scaled by ``speed``), so any
program can consume the capture as if the devices were plugged in. What programs write is
read and counted, not answered: a recording cannot react.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

from rfhoming.emulator.links import PtyLink, not_plain
from rfhoming.protocol import devices, pcapng


async def serve(capture: Path, link_dir: Path, *, speed: float = 1.0, start_delay: float = 1.0,
                out: IO[str], partial: Callable[[pcapng.CaptureFormatError], None] | None = None) -> dict[str, int]:
    """Play ``capture`` on ptys under ``link_dir``; ``start_delay`` gives consumers time to open them.

    A malformed capture raises CaptureFormatError; given ``partial``, the error goes to it and
    the blocks before the bad one are played (if they declare an interface).
    """
    try:
        interfaces, packets, _torn = pcapng.read_all(capture.read_bytes())
    except pcapng.CaptureFormatError as exc:
        interfaces = [i for i in exc.items if isinstance(i, pcapng.Interface)]
        if partial is None or not interfaces:
            raise
        partial(exc)
        packets = [i for i in exc.items if isinstance(i, pcapng.Packet)]
    inbound = [p for p in packets if p.direction != pcapng.OUTBOUND]
    links = []
    for i, iface in enumerate(interfaces):
        name = Path(iface.name).name  # a recorded path's last part; a name that is no plain name is not used
        link = PtyLink(link_dir / (name if not_plain(name) is None else f"if{i}"))
        await link.start()
        links.append(link)
        wire = devices.by_linktype(iface.linktype)
        out.write(json.dumps({"device": iface.name, "protocol": wire.name if wire else None, "path": str(link.symlink)}) + "\n")
    out.flush()
    await asyncio.sleep(start_delay)
    written = {"packets": 0, "bytes": 0}
    if inbound:
        t0, wall0 = inbound[0].t, time.monotonic()
        for p in inbound:
            due = wall0 + (p.t - t0) / speed
            await asyncio.sleep(max(0.0, due - time.monotonic()))
            links[p.interface_id].send(p.data)
            written["packets"] += 1
            written["bytes"] += len(p.data)
    for link in links:
        await link.close()
    return written
