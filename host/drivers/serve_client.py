"""A client of ``rfhoming serve`` as a driver: ``serve://HOST:PORT`` works wherever a port spec
does. The server and its protocol are host/serve.py's (docs/protocol.md, "serve")."""

from __future__ import annotations

import json
import logging
from typing import Any

from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.ports import HostPort
from rfhoming.host.serve import MAX_LINE
from rfhoming.protocol.jsonable import from_dict

log = logging.getLogger(__name__)


class ServeDriver(Driver):
    """A client of ``rfhoming serve``: the items of the server's devices, as if local.

    Each item is rebuilt from its JSON form and shown to the listeners under its own device's
    name and time; angle events also go to :attr:`out` (as from an AoaDriver). It asks the
    server to watch at once (so it is never an idle client); ``device`` keeps only one device's
    items: the server is asked to send only those (a server before protocol 1 ignores the
    request; the driver filters them itself too). The server's device
    states are kept in :attr:`devices`; bad lines are counted, never fatal; the server's
    ``dropped`` notices add up in ``counters["server_dropped"]``, its errors in ``server_errors``."""

    kind = "serve"

    def __init__(self, port: HostPort, *, device: str | None = None, queue_size: int = 1000,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.device = device
        self.counters.update(items=0, bad_lines=0, server_dropped=0, server_errors=0)  # bad_lines: logged once
        self.hello: dict[str, Any] = {}
        self.devices: dict[str, dict[str, Any]] = {}
        self._partial = b""

    def on_chunk(self, data: bytes, t_host: float) -> None:
        lines = (self._partial + data).split(b"\n")
        self._partial = lines.pop()
        if len(self._partial) > MAX_LINE:
            self._bad_line(f"a line longer than {MAX_LINE} bytes")
            self._partial = b""
        for line in lines:
            self._on_line(line)

    def _bad_line(self, why: str) -> None:
        """Count a line that is dropped; the first is logged as a warning, the rest at debug."""
        self.counters["bad_lines"] += 1
        level = logging.WARNING if self.counters["bad_lines"] == 1 else logging.DEBUG
        log.log(level, "%s: a line from the server dropped (%s)", self.port.name, why)

    def _on_line(self, line: bytes) -> None:
        try:
            record = json.loads(line)
            kind = record["kind"]
        except (ValueError, KeyError, TypeError, RecursionError):
            self._bad_line("not a JSON object with a kind")
            return
        if kind in ("hello", "devices"):
            devices = record.get("devices", [])
            if not isinstance(devices, list):
                self._bad_line(f"a {kind} line whose devices is not a list")
                return
            if kind == "hello":
                self.hello = record
            for dev in devices:
                if isinstance(dev, dict) and "device" in dev:
                    self.devices[str(dev["device"])] = dev
            return
        if kind == "device":
            self.devices[str(record.get("device"))] = record
            log.info("%s: %s is %s", self.port.name, record.get("device"), record.get("state"))
            return
        if kind in ("watch", "version", "poll"):
            return
        if kind == "error":
            self.counters["server_errors"] += 1
            log.warning("%s: the server says: %s", self.port.name, record.get("message", record.get("error")))
            return
        if kind == "dropped":
            count = record.get("count", 0)
            if not isinstance(count, int):
                self._bad_line("a dropped line whose count is not a number")
                return
            self.counters["server_dropped"] += count
            log.warning("%s: the server dropped %s items for this client (it read too slowly)",
                        self.port.name, record.get("count"))
            return
        if self.device is not None and record.get("device") != self.device:
            return
        try:
            item = from_dict(record)
            device, t = str(record["device"]), float(record["t"])
        except (ValueError, KeyError, TypeError):
            self._bad_line("an item line that is not an item")
            return
        self.counters["items"] += 1
        for listener in self.listeners:
            listener(device, t, item)
        if kind == "angle":
            self.out.put(bearing_of(t, item))

    def bearing(self, t: float, item: Any) -> Bearing | None:
        return bearing_of(t, item) if item.kind == "angle" else None

    async def session(self) -> None:
        self._partial = b""
        # a watch at once, so the server never counts this client idle (host/idle_clients.py);
        # one command line, ended CR LF as the server ends its own
        watch = {"cmd": "watch", **({"devices": [self.device]} if self.device is not None else {})}
        self.port.write((json.dumps(watch) + "\r\n").encode())
        await super().session()
