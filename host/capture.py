"""Capture: everything that crosses any port, both directions, raw, to a pcapng file.

Use :meth:`CaptureWriter.tap` as a :class:`~host.ports.HostPort` tap. Blocks go to the file as
they come and are flushed at least once a second, so a killed process loses at most the last
second and the file stays readable (a torn last block is skipped by every reader). The section
header and each interface block are flushed the moment they are written: a capture killed at
any time holds a whole header. While it records, the file is ``NAME.part`` (host/outputs.py);
:meth:`CaptureWriter.close` renames it to NAME once a device gave it a packet (an inbound one:
what rfhoming sent before that stays in it), and removes it (NAME as it was) when none came:
a command whose ports never opened, or whose devices never answered its heartbeats and
commands, leaves the old capture.

A write that fails (a full disk) does not stop the devices: the capture ends there, one error
names the file and what it kept (``error``), and the command reports it at its end.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from rfhoming.host import outputs
from rfhoming.protocol import devices, pcapng

log = logging.getLogger(__name__)

FLUSH_INTERVAL = 1.0
DISCONNECTED = "disconnected"
SNIFFED = "sniffed"  # bytes seen while the protocol was sniffed: in the file, not for the driver
NOTE = "rfhoming-note"  # what the host did on the wall clock that a replay must repeat: not for the driver


class CaptureWriter:
    def __init__(self, path: Path | str, descriptions: dict[str, dict[str, str]] | None = None,
                 comment: str = "") -> None:
        """``comment`` goes in the section header: what the capture is (a homing run's record)."""
        self.path = Path(path)
        self._out = outputs.Output(self.path, binary=True)
        self._file: IO[bytes] = self._out.file
        try:
            self._file.write(pcapng.section_header(comment=comment))
            self._file.flush()
        except OSError as exc:
            error = outputs.failed(self._out, exc, "it is no capture (a torn header)")
            self._out.discard()
            raise error from None
        self.error: outputs.WriteFailed | None = None  # why the capture ended early (a full disk)
        self.t_last: float | None = None  # of the last packet written
        self._ids: dict[str, int] = {}
        self.descriptions = dict(descriptions or {})
        self._comments: dict[str, str] = {}
        self._last_flush = time.monotonic()
        self._timer: asyncio.TimerHandle | None = None
        self.packets = 0

    def describe(self, port: str, **fields: str) -> None:
        """Set ``kind``, ``dialect`` … of a port's interface; once its interface is written,
        later facts (the dialect found at set-up) ride on the next packet's comment. A ``kind``
        is recorded by its canonical name in the device table, with its wire ``protocol``."""
        if "kind" in fields:
            record = devices.kind(fields["kind"])
            fields = {**fields, "kind": record.name, "protocol": record.protocol}
        self.descriptions.setdefault(port, {}).update(fields)
        if port in self._ids:
            self._comments[port] = " ".join(f"{k}={v}" for k, v in fields.items())
        elif "protocol" in fields:  # the interface is known: on disk now, before any data
            self._interface(port)

    def _interface(self, port: str) -> int:
        fields = self.descriptions.get(port, {})
        linktype = devices.protocol(fields["protocol"]).linktype if "protocol" in fields else pcapng.LINKTYPE_FRAMES
        text = " ".join(f"{k}={v}" for k, v in fields.items())
        iface = self._ids[port] = len(self._ids)
        if not self._file.closed:
            with self._writing():
                self._file.write(pcapng.interface(port, text, linktype))
                self._file.flush()
        return iface

    def tap(self, port: str, direction: str, t: float, data: bytes) -> None:
        if self._file.closed:  # a port still delivering after the capture ended
            return
        iface = self._ids.get(port)
        if iface is None:
            iface = self._interface(port)
        with self._writing():
            if direction == "lost":  # an empty packet marks where the device went away
                self._file.write(pcapng.packet(iface, t, b"", 0, DISCONNECTED))
            elif direction.startswith(SNIFFED):
                flag = pcapng.INBOUND if direction.endswith("in") else pcapng.OUTBOUND
                self._file.write(pcapng.packet(iface, t, data, flag, SNIFFED))
            else:
                flag = pcapng.INBOUND if direction == "in" else pcapng.OUTBOUND
                self._file.write(pcapng.packet(iface, t, data, flag, self._comments.pop(port, "")))
            if data and direction in ("in", f"{SNIFFED}-in"):  # a device answered: the capture is the run's
                self._out.own()
            self.packets += 1
            self.t_last = t
        self._schedule_flush()

    def note(self, port: str, t: float, record: dict[str, Any]) -> None:
        """A fact of the run that its bytes cannot show (a plan that took effect late, on the
        wall clock), on ``port``'s interface, for a replay to repeat."""
        if self._file.closed:
            return
        iface = self._ids.get(port)
        if iface is None:
            iface = self._interface(port)
        with self._writing():
            self._file.write(pcapng.packet(iface, t, json.dumps(record).encode(), pcapng.OUTBOUND, NOTE))
        self._schedule_flush()

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """A failed write ends the capture (never the caller, a port's reader), said once."""
        try:
            yield
        except OSError as exc:
            with contextlib.suppress(OSError):
                self._file.close()
            until = f" up to t = {self.t_last:.6f}" if self.t_last is not None else ""
            self.error = outputs.failed(self._out, exc, f"it holds about {self.packets} packets{until}, flushed at "
                                        "least a second before; replay and Wireshark read up to the last whole block")
            log.error("capture: %s", self.error)

    def _schedule_flush(self) -> None:
        if time.monotonic() - self._last_flush >= FLUSH_INTERVAL:
            self.flush()
            return
        if self._timer is None:
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:
                self.flush()
                return
            self._timer = loop.call_later(FLUSH_INTERVAL, self.flush)

    def flush(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if not self._file.closed:
            with self._writing():
                self._file.flush()
        self._last_flush = time.monotonic()

    @property
    def kept(self) -> bool:
        """A device gave the capture a packet: :meth:`close` renames it over NAME."""
        return self._out.owned

    @property
    def unanswered(self) -> bool:
        """rfhoming wrote to the capture but no device answered: it is dropped at :meth:`close`."""
        return bool(self.packets) and not self.kept

    def said(self) -> str:
        """What a command tells of it at its end (after :meth:`close`)."""
        if not self.packets:
            return f"captured nothing: {self.path} is as it was"
        if not self.kept:
            sent = f"{self.packets} chunk{'s' if self.packets > 1 else ''}"
            return f"no device answered: {self.path} is as it was (the {sent} rfhoming sent are not kept)"
        return f"captured {self.packets} chunks to {self.path}"

    def close(self) -> None:
        """The capture renamed into place if a device gave it a packet, else removed (NAME as it was)."""
        self.flush()
        try:
            self._out.close()
        except outputs.WriteFailed as exc:
            self.error = self.error or exc
            log.error("capture: %s", exc)


async def describe_dialects(drivers: list[Any], capture: CaptureWriter) -> None:
    """Record each XPLR-AOA's u-connectLocate dialect on its interface once its set-up found it
    (what ``rfhoming capture`` and the API's ``capture=`` both do); runs until cancelled."""
    done: set[str] = set()
    while True:
        await asyncio.sleep(0.2)
        for d in drivers:
            dialect = getattr(d, "dialect", None)
            if dialect is not None and d.port.name not in done:
                capture.describe(d.port.name, dialect=dialect.value)
                done.add(d.port.name)


def parse_description(text: str) -> dict[str, str]:
    """``protocol=rss kind=base`` -> dict (what CaptureWriter writes)."""
    return dict(item.split("=", 1) for item in text.split() if "=" in item)
