"""One owner of the devices, any number of clients: a small versioned JSON-lines protocol over TCP.

In the spirit of gpsd: ``rfhoming serve`` opens the devices (port specs, set-up, reconnect,
capture) and :class:`ItemServer` fans every decoded item out to whoever connects.
docs/protocol.md, "serve: the JSON-lines protocol", is the reference for what goes over the
wire; in short:

- the first line a client gets is ``hello`` (the protocol version ``proto``, the release, and
  each device with its state); the gpsd-named fields (``class``, ``proto_major``, ...) make it
  a gpsd VERSION object too;
- then, while it watches (by default: every device, every kind but the devices' set-up
  chatter), one line per item, ``{"class": KIND, "n": N, "device": ..., "t": ..., "kind": ...,
  <fields>}`` (the form of ``listen --json`` plus ``n``, the server's item number, and gpsd's
  ``class``: the kind in upper case, as every line has one), and a ``device`` line
  whenever a device's state changes (``disconnected``, ``connected``, ``ready``, ``streaming``);
- a client may send commands, one JSON object a line (``{"cmd": "watch", ...}``, ``poll``,
  ``devices``, ``version``) or in gpsd's syntax (``?WATCH={...};``, ``?POLL;``, ``?DEVICES;``,
  ``?VERSION;``); what the server does not understand gets one ``error`` line, and the
  connection stays up.

Bounded everywhere: publishing only appends to each client's bounded queue (``queue_lines``
lines and ``QUEUE_BYTES`` bytes) and each client has its own writer task, so a slow or dead
client never blocks the devices or the other clients. Everything a client gets -- replies, error
lines, items, notices -- goes through that one queue, in order. When a client's queue is full
its newest lines are dropped and counted (a reply is not even built); the next line it gets is
``{"kind": "dropped", "count": K, "total": T}``, and a client that takes nothing while
``max_drops`` lines are dropped is disconnected. Input is read ``READ_CHUNK`` bytes at a time,
and the loop is let go between reads; a client's commands are carried out only while its queue
holds at most ``BACKLOG_LINES`` lines and ``BACKLOG_BYTES`` bytes (back-pressure: what it sends
meanwhile waits in the kernel's buffers), so a client that sends commands faster than it takes
the replies holds only itself up. A command line longer than ``MAX_COMMAND`` bytes, or with more
than ``MAX_LINE_COMMANDS`` commands, is an error (an over-long line's bytes are skipped to the
next newline, never held); at most ``ERRORS_PENDING`` error lines wait in a client's queue, the
errors past those are counted in the last one (``suppressed``). A client that sends more than
``max_input`` bytes the server does not understand, in all, is disconnected
(``disconnected_input``); past ``max_clients`` connections a new one is refused. A client that
takes nothing of what waits for it (its transport's 16 KiB and the kernel's buffers full) for
``stall_s`` seconds is disconnected (``disconnected_stalled``), as gpsd cuts a watcher that
stopped reading (its NOREAD_TIMEOUT). A client that has sent no command is *idle*: one address
keeps at most ``max_idle`` idle clients, and when another connects the one idle longest is
closed (``disconnected_idle``; host/idle_clients.py), so clients that connect and forget cannot
hold every slot. A client that half-closes (EOF) is sent what its queue holds, then closed. So
no client can make the server hold more than its queue, its transport's 16 KiB, a 4 KiB read
and one command line.

:class:`~rfhoming.host.drivers.serve_client.ServeDriver` is the other end: a driver whose port
is a server's address, so ``serve://HOST:PORT`` works wherever a port spec does.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from rfhoming.host.drivers.common import Driver
from rfhoming.host.idle_clients import IdleClients
from rfhoming.host.supervise import ready
from rfhoming.protocol.errors import Error
from rfhoming.protocol.jsonable import as_dict

log = logging.getLogger(__name__)

PROTO_MAJOR, PROTO_MINOR = 1, 0
"""The protocol's version: the minor grows with every addition a client may ignore (a field,
a message kind, a command), the major with every change that could break a client."""

QUEUE_LINES = 1000
WRITE_BUFFER = 16 * 1024  # bytes the transport may hold for a client before its writer waits
CLOSE_GRACE_S = 10.0  # a disconnected client has this long to take its last lines
MAX_LINE = 64 * 1024
QUEUE_BYTES = 256 * 1024  # encoded lines a client's queue holds at most
MAX_INPUT = 64 * 1024  # bytes a client may send that the server does not understand, in all
MAX_COMMAND = 4096  # the longest command line
MAX_LINE_COMMANDS = 16  # commands on one line (gpsd's clients send one or two)
READ_CHUNK = 4096
BACKLOG_LINES = 64  # a client's commands wait while its queue holds more lines than this ...
BACKLOG_BYTES = 64 * 1024  # ... or more bytes than this (or more than half of queue_lines)
MAX_CLIENTS = 256
MAX_IDLE = 16  # clients of one address that have sent no command, at most (the longest idle goes)
STALL_S = 30.0  # a client that takes nothing of what waits for it this long is disconnected
LINGER_S = 1.0  # a client cut off for its input has this long to read the error line
ERRORS_PENDING = 8  # error lines a client may have waiting; more are counted in the last one
STATE_POLL_S = 0.05  # how often the drivers' states are looked at (an item looks at once)

CHATTER = frozenset({"echo", "info", "final", "startup", "unknown", "event", "hci"})
"""Item kinds of a device's own dialogue with the host -- the XPLR-AOA's and ESP-AT's AT
commands echoed, their answers and final codes, +STARTUP and lines that are none of these,
ESP-AT's ``ready``, HCI's command replies: sent only to a client that asks (``chatter``)."""
NOT_POLLED = CHATTER | {"drop"}  # a poll answers with readings, not the dialogue or decode drops

STATES = ("disconnected", "connected", "ready", "streaming")
"""A device's states, each a step further: its port is not open (not yet, or no more); open,
being set up (after an open or a reboot); set up; its first reading since it was set up has come.
``ended``: a replayed capture that has run out (it does not come back)."""

GPSD_IGNORED = frozenset({"class", "scaled", "split24", "pps", "timing", "remote"})
"""gpsd WATCH fields that ask for nothing these devices have: accepted and ignored."""
GPSD_REFUSED = frozenset({"nmea", "raw"})
"""gpsd WATCH fields for data other than JSON: refused with an error unless false or 0."""


@cache  # the package metadata is read from disk: once, not per ?VERSION;
def _version_fields() -> dict[str, Any]:
    try:
        release = version("rfhoming")
    except PackageNotFoundError:  # run from a source tree that was never installed
        release = "0+unknown"
    return {"server": "rfhoming", "release": release, "rev": release,
            "proto": {"major": PROTO_MAJOR, "minor": PROTO_MINOR},
            "proto_major": PROTO_MAJOR, "proto_minor": PROTO_MINOR}


def item_class(kind: str) -> str:
    """An item line's gpsd ``class``: its kind in gpsd's upper case (``angle`` -> ``ANGLE``), so
    a gpsd client that dispatches on ``class`` gets one on every line."""
    return kind.upper()


def _line(record: dict[str, Any]) -> bytes:
    """One JSON line, ended CR LF as gpsd ends its own (gpsd_json(5), OVERVIEW; its Python
    client takes a line only so); a JSON-lines reader ignores the CR as white space."""
    return (json.dumps(record) + "\r\n").encode()


class CommandError(Error, ValueError):
    """A command line the server does not understand; the message says why (an error line)."""


class _ErrorLine:
    """An error line in a client's queue, encoded when it is taken: until then the errors
    after it that were only counted (past ERRORS_PENDING waiting) add to its ``suppressed``.
    Its length, for the queue's byte count, is its encoding's when it was queued."""

    __slots__ = ("message", "suppressed", "size")

    def __init__(self, message: str) -> None:
        self.message = message
        self.suppressed = 0
        self.size = len(bytes(self))

    def __bytes__(self) -> bytes:
        record: dict[str, Any] = {"kind": "error", "class": "ERROR", "message": self.message}
        if self.suppressed:
            record["suppressed"] = self.suppressed
        return _line(record)

    def __len__(self) -> int:
        return self.size


@dataclass(frozen=True)
class Watch:
    """What one client asked for; the default is what a client that sends nothing gets."""

    enable: bool = True
    json: bool = True
    devices: frozenset[str] | None = None  # None: every device
    kinds: frozenset[str] | None = None  # None: every kind but the chatter
    chatter: bool = False

    def wants_device(self, device: str) -> bool:
        return self.enable and (self.devices is None or device in self.devices)

    def wants(self, device: str, kind: str) -> bool:
        if not (self.json and self.wants_device(device)):
            return False
        if kind in CHATTER and self.chatter:
            return True
        return kind in self.kinds if self.kinds is not None else kind not in CHATTER

    def as_dict(self) -> dict[str, Any]:
        """The ``watch`` line: absent ``devices``/``kinds`` mean all (gpsd sends no nulls)."""
        record = {"kind": "watch", "class": "WATCH", "enable": self.enable, "json": self.json,
                  "chatter": self.chatter}
        if self.devices is not None:
            record["devices"] = sorted(self.devices)
        if self.kinds is not None:
            record["kinds"] = sorted(self.kinds)
        return record


@dataclass
class _Device:
    """What the server tells of one device: its names, its state and its latest readings."""

    name: str
    driver: Driver | None = None
    state: str = "disconnected"
    reconnects: int = 0
    latest: dict[str, dict[str, Any]] = field(default_factory=dict)  # kind -> its last item record

    def describe(self) -> dict[str, Any]:
        record = {"class": "DEVICE", "device": self.name, "driver": self.driver.kind if self.driver else None,
                  "path": getattr(self.driver.port, "spec", self.name) if self.driver else self.name,
                  "state": self.state}
        problem = getattr(self.driver, "problem", None)
        if problem:
            record["problem"] = problem
        return {k: v for k, v in record.items() if v is not None}


def _protocol_state(driver: Driver, was: str) -> str:
    """A driver's state in the protocol's words (``streaming`` is set by the first item)."""
    if driver.state == "ended":
        return "ended"
    if not driver.connected.is_set():
        return "disconnected"
    if ready(driver):
        return "streaming" if was == "streaming" else "ready"
    return "connected"


class _Client:
    """One connection: its bounded queue of encoded lines, its watch and its counters."""

    def __init__(self, writer: asyncio.StreamWriter, queue_lines: int) -> None:
        self.writer = writer
        peer = writer.get_extra_info("peername")
        self.source = str(peer[0])  # its address: what the idle bound counts by
        self.peer = ":".join(map(str, peer[:2]))
        self.queue: deque[bytes | _ErrorLine] = deque()
        self.queue_lines = queue_lines
        self.queued_bytes = 0
        self.watch = Watch()
        self.unheard = 0  # bytes it sent that were not understood
        self.partial = b""  # the start of a command line, at most MAX_COMMAND bytes
        self.skipping = False  # inside a command line that was too long
        self.errors_waiting = 0  # error lines in its queue, at most ERRORS_PENDING
        self.last_error: _ErrorLine | None = None  # the newest of them: it counts the errors past those
        self.errors = 0
        self.commands = 0
        self.ready = asyncio.Event()  # set when a line is queued (or it is dropped)
        self.taken = asyncio.Event()  # set when it takes a line (or it is dropped): room for replies
        self.dropped = 0  # since the last notice
        self.dropped_total = 0
        self.dropped_in_a_row = 0  # since it last took a line
        self.sent = 0
        self.closed = False


class ItemServer:
    """The serve protocol to any number of TCP clients; :meth:`publish` is a driver listener
    and never waits. ``drivers``: the devices it tells of (their states are followed from
    :meth:`start` on)."""

    def __init__(self, *, queue_lines: int = QUEUE_LINES, max_drops: int | None = None,
                 max_input: int = MAX_INPUT, max_clients: int = MAX_CLIENTS, max_idle: int = MAX_IDLE,
                 stall_s: float = STALL_S, drivers: Iterable[Driver] = ()) -> None:
        self.queue_lines = queue_lines
        self.max_drops = queue_lines if max_drops is None else max_drops
        self.max_input = max_input
        self.max_clients = max_clients
        self.idle: IdleClients[_Client] = IdleClients(max_idle)
        self.stall_s = stall_s
        self.drivers = list(drivers)
        self.devices: dict[str, _Device] = {d.port.name: _Device(d.port.name, d) for d in self.drivers}
        self.clients: set[_Client] = set()
        self.counters = {"items": 0, "clients": 0, "disconnected_slow": 0, "dropped": 0, "disconnected_input": 0,
                         "disconnected_stalled": 0, "disconnected_idle": 0, "refused": 0, "commands": 0,
                         "bad_commands": 0, "state_changes": 0}
        self._servers: list[asyncio.Server] = []
        self._tasks: set[asyncio.Task[Any]] = set()
        self._follower: asyncio.Task[Any] | None = None

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> list[str]:
        """Listen; returns the ``tcp://HOST:PORT`` addresses."""
        server = await asyncio.start_server(self._accept, host, port, limit=MAX_LINE)
        self._servers.append(server)
        if self._follower is None and self.drivers:
            self._follower = self._spawn(self._follow())
        return [f"tcp://{_host(s.getsockname()[0])}:{s.getsockname()[1]}" for s in server.sockets]

    async def close(self) -> None:
        for server in self._servers:
            server.close()
        for client in list(self.clients):
            self._drop_client(client)
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    def publish(self, device: str, t: float, item: Any) -> None:
        """One decoded item to every client that watches it (a driver listener)."""
        self.counters["items"] += 1
        fields = as_dict(item)
        kind = fields["kind"]
        record = {"class": item_class(kind), "n": self.counters["items"], "device": device, "t": t, **fields}
        dev = self.devices.get(device)
        if dev is None:  # an item of a device it was not told of (a test's): tell of it from now on
            dev = self.devices[device] = _Device(device, state="streaming")
        if kind not in NOT_POLLED:
            dev.latest[kind] = record
            if dev.state != "streaming":
                self._observe(dev)  # the set-up may have finished since the last look
                if dev.state == "ready":
                    self._set_state(dev, "streaming")
        line = _line(record)
        for client in list(self.clients):
            if client.watch.wants(device, kind):
                self._offer(client, line)

    def health(self) -> dict[str, Any]:
        return {**self.counters, "connected": len(self.clients),
                "per_client": {c.peer: {"sent": c.sent, "dropped": c.dropped_total, "queued": len(c.queue),
                                        "commands": c.commands, "errors": c.errors} for c in self.clients}}

    # -- device states -----------------------------------------------------------------------
    async def _follow(self) -> None:
        while True:
            for dev in self.devices.values():
                self._observe(dev)
            await asyncio.sleep(STATE_POLL_S)

    def _observe(self, dev: _Device) -> None:
        """Bring the device's state up to its driver's; a reopen since the last look (an unplug
        shorter than a look) still tells its clients ``disconnected`` first."""
        driver = dev.driver
        if driver is None:
            return
        reconnects = driver.counters.get("reconnects", 0)
        if reconnects != dev.reconnects:
            dev.reconnects = reconnects
            if dev.state not in ("disconnected", "ended"):
                self._set_state(dev, "disconnected")
        self._set_state(dev, _protocol_state(driver, dev.state))

    def _set_state(self, dev: _Device, state: str) -> None:
        """Tell the watching clients; a step up of more than one (a port that opened and was
        set up between two looks) is told step by step, so each state is seen in order."""
        if state == dev.state:
            return
        steps = [state]
        if dev.state in STATES and state in STATES and STATES.index(state) > STATES.index(dev.state) + 1:
            steps = list(STATES[STATES.index(dev.state) + 1:STATES.index(state) + 1])
        for step in steps:
            dev.state = step
            self.counters["state_changes"] += 1
            line = _line({"kind": "device", **dev.describe(), "t": round(time.time(), 6)})
            for client in list(self.clients):
                if client.watch.wants_device(dev.name):
                    self._offer(client, line)

    # -- what goes to a client -----------------------------------------------------------------
    def _offer(self, client: _Client, line: bytes | _ErrorLine) -> bool:
        """Append to the client's queue (True), or drop and count when it is full."""
        if client.closed:
            return False
        if len(client.queue) < client.queue_lines and client.queued_bytes + len(line) <= QUEUE_BYTES:
            client.queue.append(line)
            client.queued_bytes += len(line)
            client.ready.set()
            return True
        self._drop(client)
        return False

    def _reply(self, client: _Client, build: Callable[[], dict[str, Any]]) -> None:
        """A reply to a command, built only if the client's queue has room for a line."""
        if len(client.queue) < client.queue_lines and client.queued_bytes < QUEUE_BYTES:
            self._offer(client, _line(build()))
        elif not client.closed:
            self._drop(client)

    def _drop(self, client: _Client) -> None:
        """Count a line the client's queue had no room for; cut off a client that takes nothing."""
        client.dropped += 1
        client.dropped_total += 1
        client.dropped_in_a_row += 1
        self.counters["dropped"] += 1
        if client.dropped_in_a_row >= self.max_drops:
            self.counters["disconnected_slow"] += 1
            log.warning("client %s took nothing while %d lines were dropped: disconnecting it",
                        client.peer, client.dropped_in_a_row)
            self._drop_client(client, {"kind": "dropped", "class": "DROPPED", "count": client.dropped,
                                       "total": client.dropped_total,
                                       "disconnected": "too slow: took nothing while its queue overflowed"})

    def _error(self, client: _Client, message: str) -> None:
        """One error line, queued behind the replies before it; past ERRORS_PENDING waiting,
        only counted in the newest waiting one (``suppressed``)."""
        self.counters["bad_commands"] += 1
        client.errors += 1
        if client.errors_waiting >= ERRORS_PENDING and client.last_error is not None:
            client.last_error.suppressed += 1
            return
        error = _ErrorLine(message)
        if self._offer(client, error):
            client.errors_waiting += 1
            client.last_error = error

    def _take(self, client: _Client) -> bytes | None:
        """The next line the client is sent: a dropped notice if lines were dropped since the
        last, else the head of its queue; None when there is nothing."""
        if client.dropped:
            notice = {"kind": "dropped", "class": "DROPPED", "count": client.dropped, "total": client.dropped_total}
            client.dropped = 0
            return _line(notice)
        if not client.queue:
            return None
        entry = client.queue.popleft()
        client.queued_bytes -= len(entry)
        if isinstance(entry, _ErrorLine):
            client.errors_waiting -= 1
            if entry is client.last_error:
                client.last_error = None
        client.sent += 1
        client.dropped_in_a_row = 0
        client.taken.set()
        return bytes(entry)

    def _busy(self, client: _Client) -> bool:
        """Its commands wait: its queue holds more than BACKLOG_LINES (or half its length) or
        BACKLOG_BYTES. Never while the queue is empty, so a client that reads is never stuck."""
        return bool(client.queue) and (len(client.queue) > min(BACKLOG_LINES, client.queue_lines // 2)
                                       or client.queued_bytes > BACKLOG_BYTES)

    def _hello(self) -> dict[str, Any]:
        return {"kind": "hello", "class": "VERSION", **_version_fields(), "devices": self._device_list(),
                "watch": Watch().as_dict()}

    def _device_list(self) -> list[dict[str, Any]]:
        return [dev.describe() for dev in self.devices.values()]

    # -- commands ------------------------------------------------------------------------------
    def _on_command_line(self, client: _Client, line: bytes) -> bool:
        """Carry out one line's commands; False (and an error line) when it is not understood."""
        text = line.strip()
        if not text:
            return True
        try:
            commands = parse_commands(text)
            for name, args in commands:  # checked before any is carried out: a line does all or nothing
                if name == "watch":
                    self._new_watch(client.watch, args)
        except CommandError as exc:
            self._error(client, str(exc))
            return False
        self.idle.spoke(client)
        for name, args in commands:
            client.commands += 1
            self.counters["commands"] += 1
            getattr(self, f"_cmd_{name}")(client, args)
        return True

    def _cmd_version(self, client: _Client, args: dict[str, Any]) -> None:
        self._reply(client, lambda: {"kind": "version", "class": "VERSION", **_version_fields()})

    def _cmd_devices(self, client: _Client, args: dict[str, Any]) -> None:
        self._reply(client, lambda: {"kind": "devices", "class": "DEVICES", "devices": self._device_list()})

    def _cmd_watch(self, client: _Client, args: dict[str, Any]) -> None:
        """As gpsd answers ?WATCH: the device list, then the watch now in force; every line
        after the watch line follows it."""
        client.watch = self._new_watch(client.watch, args)
        self._cmd_devices(client, {})
        self._reply(client, client.watch.as_dict)

    def _cmd_poll(self, client: _Client, args: dict[str, Any]) -> None:
        """The latest reading of each kind of each device the client's watch names (watching
        enabled or not), as the item lines had them."""
        watch = replace(client.watch, enable=True, json=True)

        def build() -> dict[str, Any]:
            items = [record for dev in self.devices.values() for kind, record in dev.latest.items()
                     if watch.wants(dev.name, kind)]
            now = time.time()
            return {"kind": "poll", "class": "POLL", "t": round(now, 6),
                    "time": datetime.fromtimestamp(now, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z"),
                    "active": sum(1 for dev in self.devices.values() if dev.state in ("ready", "streaming")),
                    "items": sorted(items, key=lambda r: r["n"])}

        self._reply(client, build)

    def _new_watch(self, watch: Watch, args: dict[str, Any]) -> Watch:
        """``watch`` changed by a watch command's fields (those left out stay); CommandError
        names what is wrong."""
        changes: dict[str, Any] = {}
        for key, value in args.items():
            if key in ("enable", "json", "chatter"):
                if not isinstance(value, bool):
                    raise CommandError(f"watch: {key} is true or false, not {json.dumps(value)[:40]}")
                changes[key] = value
            elif key in ("devices", "kinds"):
                if value is not None and not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
                    raise CommandError(f"watch: {key} is a list of names, or null for all")
                changes[key] = None if value is None else frozenset(value)
            elif key == "device":  # gpsd's: watch this one device
                if not isinstance(value, str):
                    raise CommandError("watch: device is a device's name or path")
                changes["devices"] = frozenset([value])
            elif key in GPSD_REFUSED:
                if value not in (False, 0):
                    raise CommandError(f"watch: {key} is not offered; this server sends JSON lines only")
            elif key not in GPSD_IGNORED:
                raise CommandError(f"watch: unknown field {key!r}; the fields are enable, json, devices, device, "
                                   "kinds, chatter")
        if changes.get("devices") is not None:
            changes["devices"] = frozenset(self._device_name(d) for d in changes["devices"])
        return replace(watch, **changes)

    def _device_name(self, name: str) -> str:
        for dev in self.devices.values():
            if name in (dev.name, dev.describe()["path"]):
                return dev.name
        raise CommandError(f"watch: no device {name!r}; the devices are {', '.join(self.devices) or 'none'}")

    # -- connections -----------------------------------------------------------------------
    def _spawn(self, coro: Any) -> asyncio.Task[Any]:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, WRITE_BUFFER)
        writer.transport.set_write_buffer_limits(high=WRITE_BUFFER)
        if len(self.clients) >= self.max_clients:
            self.counters["refused"] += 1
            log.warning("refusing a client: %d are connected already", len(self.clients))
            writer.write(_error_line(f"too many clients ({self.max_clients}); try again later"))
            writer.transport.close()
            return
        for dev in self.devices.values():
            self._observe(dev)  # the hello tells each device's state as it is now
        client = _Client(writer, self.queue_lines)
        self.clients.add(client)
        self.counters["clients"] += 1
        longest = self.idle.arrived(client.source, client)
        if longest is not None:
            self.counters["disconnected_idle"] += 1
            log.warning("client %s sent no command and %d newer ones from %s are idle too: disconnecting it",
                        longest.peer, self.idle.per_source, client.source)
            self._drop_client(longest, {"kind": "error", "class": "ERROR", "message":
                                        f"more than {self.idle.per_source} clients from {client.source} sent no command; "
                                        "the one idle longest is closed (send a command, e.g. ?WATCH;, to stay)"})
        self._offer(client, _line(self._hello()))
        self._spawn(self._serve(client, reader))

    async def _serve(self, client: _Client, reader: asyncio.StreamReader) -> None:
        """Send the client its lines, in order, until it is dropped (the reader drops it at EOF,
        after what it has queued) or its connection breaks."""
        commands = self._spawn(self._read_commands(client, reader))
        try:
            while not client.closed:
                line = self._take(client)
                if line is None:
                    client.ready.clear()
                    await client.ready.wait()
                    continue
                client.writer.write(line)
                try:  # asyncio.timeout, not wait_for: no task per line sent
                    async with asyncio.timeout(self.stall_s):
                        await client.writer.drain()
                except TimeoutError:
                    self.counters["disconnected_stalled"] += 1
                    log.warning("client %s took nothing for %g s: disconnecting it", client.peer, self.stall_s)
                    return
        except (ConnectionError, OSError):
            pass
        finally:
            commands.cancel()
            self._drop_client(client)

    async def _read_commands(self, client: _Client, reader: asyncio.StreamReader) -> None:
        """Read what the client sends, READ_CHUNK bytes at a time, letting the loop go between
        reads, and carry out its command lines while its queue has room for their replies. At
        EOF (the client may only have half-closed) its queue is sent and its connection closed;
        a client that sent more than ``max_input`` bytes the server did not understand is cut off."""
        while not client.closed and (data := await _read(reader)):
            for line in self._lines(client, data):
                while self._busy(client) and not client.closed:
                    client.taken.clear()
                    await client.taken.wait()
                if client.closed:
                    return
                self._carry_out(client, line)
            if client.unheard > self.max_input:
                self.counters["disconnected_input"] += 1
                log.warning("client %s sent more than %d bytes not understood: disconnecting it",
                            client.peer, self.max_input)
                self._drop_client(client, {"kind": "error", "class": "ERROR",
                                           "message": f"sent more than {self.max_input} bytes this server does not "
                                                      "understand; disconnecting"}, linger=True, flush=True)
                return
            await asyncio.sleep(0)  # read() does not yield while the reader holds data: the devices go first
        self._drop_client(client, flush=True)

    def _feed(self, client: _Client, data: bytes) -> None:
        """Carry out every command line in ``data`` at once (no back-pressure)."""
        for line in self._lines(client, data):
            self._carry_out(client, line)

    def _lines(self, client: _Client, data: bytes) -> Iterator[bytes]:
        """The command lines ``data`` ends, after what came before; a line longer than
        MAX_COMMAND is an error, in its place among the lines, and is skipped to its end,
        never held."""
        *lines, rest = data.split(b"\n")
        for piece in lines:
            if client.skipping:
                client.skipping = False
                client.unheard += len(piece) + 1
                continue
            line, client.partial = client.partial + piece, b""
            if len(line) > MAX_COMMAND:
                self._error(client, f"a command line is at most {MAX_COMMAND} bytes; this one had {len(line)}")
                client.unheard += len(line) + 1
            else:
                yield line
        if client.skipping:
            client.unheard += len(rest)
            return
        client.partial += rest
        if len(client.partial) > MAX_COMMAND:
            self._error(client, f"a command line is at most {MAX_COMMAND} bytes; this one had more")
            client.unheard += len(client.partial)
            client.partial, client.skipping = b"", True

    def _carry_out(self, client: _Client, line: bytes) -> None:
        if not self._on_command_line(client, line):
            client.unheard += len(line) + 1

    def _drop_client(self, client: _Client, last: dict[str, Any] | None = None, linger: bool = False,
                     flush: bool = False) -> None:
        """Forget the client and close its connection after what it was sent. ``flush``: what
        its queue holds (at most QUEUE_BYTES) is sent first, else it is thrown away (a client
        that does not read would never take it). ``linger``: it may still be sending, so end
        our side first and close LINGER_S later; closing with its bytes unread would reset the
        connection and could lose the last line. Either way it is cut off CLOSE_GRACE_S later."""
        if client.closed:
            return
        client.closed = True
        client.ready.set()
        client.taken.set()
        self.clients.discard(client)
        self.idle.left(client)
        transport = client.writer.transport
        if flush:
            lines = []
            while (line := self._take(client)) is not None:
                lines.append(line)
            if lines:
                transport.write(b"".join(lines))
        client.queue.clear()  # unflushed: what it will never take is not held for the close grace
        client.queued_bytes = 0
        if last is not None:
            transport.write(_line(last))  # behind what it has not taken yet
        loop = asyncio.get_running_loop()
        if linger and transport.can_write_eof():
            transport.write_eof()  # after the buffered lines; its input, meanwhile, fills a bounded buffer
            loop.call_later(LINGER_S, transport.close)
        else:
            transport.close()  # flushes what the client will still take, then closes
        loop.call_later(CLOSE_GRACE_S, transport.abort)


def parse_commands(line: bytes) -> list[tuple[str, dict[str, Any]]]:
    """One command line -> its commands (name, arguments). Either one JSON object with a
    ``cmd`` (``{"cmd": "watch", "devices": ["aoa"]}``), or gpsd's syntax: ``?NAME;`` or
    ``?NAME={...};``, several on a line (gpsd_json(5), OVERVIEW). CommandError says what is wrong."""
    try:
        text = line.decode()
    except UnicodeDecodeError:
        raise CommandError("a command line is UTF-8 text; this one is not") from None
    if text.startswith("{"):
        try:
            record = json.loads(text)
        except (ValueError, RecursionError) as exc:  # RecursionError: nested deeper than json goes
            raise CommandError(f"not JSON: {exc}") from None
        if not isinstance(record, dict) or not isinstance(record.get("cmd"), str):
            raise CommandError('a JSON command is an object with "cmd": "watch", "poll", "devices" or "version"')
        name = record.pop("cmd")
        return [(_command_name(name), record)]
    if not text.startswith("?"):
        raise CommandError(f"not a command: {text[:40]!r}; send a JSON object with \"cmd\", or ?WATCH; ?POLL; "
                           "?DEVICES; ?VERSION; as gpsd takes them")
    commands: list[tuple[str, dict[str, Any]]] = []
    i, decoder = 0, json.JSONDecoder()
    while i < len(text):
        if text[i] in "; \t\r":
            i += 1
            continue
        if text[i] != "?":
            raise CommandError(f"expected ?COMMAND at {text[i:i + 20]!r}")
        j = i + 1
        while j < len(text) and text[j].isalpha():
            j += 1
        name = text[i + 1:j]
        args: dict[str, Any] = {}
        if j < len(text) and text[j] == "=":
            try:
                args, j = decoder.raw_decode(text, j + 1)
            except (ValueError, RecursionError) as exc:
                raise CommandError(f"?{name}= takes a JSON object: {exc}") from None
            if not isinstance(args, dict):
                raise CommandError(f"?{name}= takes a JSON object")
        if len(commands) == MAX_LINE_COMMANDS:
            raise CommandError(f"at most {MAX_LINE_COMMANDS} commands a line")
        commands.append((_command_name(name, gpsd=True), args))
        i = j
    return commands


COMMANDS = ("watch", "poll", "devices", "version")


def _command_name(name: str, gpsd: bool = False) -> str:
    wanted = name.lower() if gpsd else name
    if wanted not in COMMANDS:
        shown = f"?{name}" if gpsd else repr(name)
        raise CommandError(f"unknown command {shown}; the commands are watch, poll, devices, version "
                           "(or ?WATCH, ?POLL, ?DEVICES, ?VERSION)")
    return wanted


async def _read(reader: asyncio.StreamReader) -> bytes:
    """At most READ_CHUNK bytes; b"" at EOF or when the connection broke."""
    try:
        return await reader.read(READ_CHUNK)
    except (ConnectionError, OSError):
        return b""


def _error_line(text: str) -> bytes:
    return _line({"kind": "error", "class": "ERROR", "message": text})


def _host(address: str) -> str:
    return f"[{address}]" if ":" in address else address
