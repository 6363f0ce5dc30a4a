"""One owner of the devices, any number of clients: decoded items as JSON lines over TCP.

In the spirit of gpsd: ``rfhoming serve`` opens the devices (port specs, set-up, reconnect,
capture) and :class:`ItemServer` fans every decoded item out to whoever connects. A line is
``{"n": N, "device": ..., "t": ..., "kind": ..., <fields>}`` (the form of ``listen --json``
plus ``n``, the server's item number, so clients can line their streams up); the first line a
client gets is ``{"kind": "hello", ...}``.

A slow or dead client never blocks the devices or the other clients: publishing only appends
to each client's bounded queue (``queue_lines`` lines and ``QUEUE_BYTES`` bytes), and each
client has its own writer task. When a client's queue is full its newest items are dropped and
counted; the next line it gets is ``{"kind": "dropped", "count": K, "total": T}``. A client
that takes nothing while ``max_drops`` items are dropped is disconnected, with a last
``dropped`` line saying so.

What a client sends is read in bounded chunks and discarded (the server takes no input); a
client that sends more than ``max_input`` bytes in all gets one line ``{"kind": "error", ...}``
and is disconnected (counted as ``disconnected_input``). Past ``max_clients`` connections a new
one gets the same kind of line and is closed (``refused``). So no client can make the server
hold more than its queue, its transport's 16 KiB and a 4 KiB read.

:class:`ServeDriver` is the other end: a driver whose port is a server's address, so
``serve://HOST:PORT`` works wherever a port spec does.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
from collections import deque
from typing import Any

from rfhoming.host.drivers.aoa import TimedAngle
from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.ports import HostPort
from rfhoming.protocol.jsonable import as_dict, from_dict

log = logging.getLogger(__name__)

QUEUE_LINES = 1000
WRITE_BUFFER = 16 * 1024  # bytes the transport may hold for a client before its writer waits
CLOSE_GRACE_S = 10.0  # a disconnected client has this long to take its last lines
MAX_LINE = 64 * 1024
QUEUE_BYTES = 256 * 1024  # encoded lines a client's queue holds at most
MAX_INPUT = 64 * 1024  # bytes a client may send in all (read and discarded)
READ_CHUNK = 4096
MAX_CLIENTS = 256
LINGER_S = 1.0  # a client cut off for its input has this long to read the error line


class _Client:
    """One connection: its bounded queue of encoded lines and its drop counters."""

    def __init__(self, writer: asyncio.StreamWriter, queue_lines: int) -> None:
        self.writer = writer
        self.peer = "%s:%s" % writer.get_extra_info("peername")[:2]
        self.queue: deque[bytes] = deque()
        self.queue_lines = queue_lines
        self.queued_bytes = 0
        self.received = 0  # bytes it sent, all discarded
        self.ready = asyncio.Event()
        self.dropped = 0  # since the last notice
        self.dropped_total = 0
        self.dropped_in_a_row = 0  # since it last took a line
        self.sent = 0
        self.closed = False


class ItemServer:
    """JSON lines of decoded items to any number of TCP clients; :meth:`publish` is a driver
    listener and never waits."""

    def __init__(self, *, queue_lines: int = QUEUE_LINES, max_drops: int | None = None,
                 hello: dict[str, Any] | None = None, max_input: int = MAX_INPUT,
                 max_clients: int = MAX_CLIENTS) -> None:
        self.queue_lines = queue_lines
        self.max_drops = queue_lines if max_drops is None else max_drops
        self.max_input = max_input
        self.max_clients = max_clients
        self.hello = {"kind": "hello", "server": "rfhoming", **(hello or {})}
        self.clients: set[_Client] = set()
        self.counters = {"items": 0, "clients": 0, "disconnected_slow": 0, "dropped": 0, "disconnected_input": 0,
                         "refused": 0}
        self._servers: list[asyncio.Server] = []
        self._tasks: set[asyncio.Task] = set()

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> list[str]:
        """Listen; returns the ``tcp://HOST:PORT`` addresses."""
        server = await asyncio.start_server(self._accept, host, port, limit=MAX_LINE)
        self._servers.append(server)
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
        """One decoded item to every client (a driver listener)."""
        self.counters["items"] += 1
        record = {"n": self.counters["items"], "device": device, "t": t, **as_dict(item)}
        line = (json.dumps(record) + "\n").encode()
        for client in list(self.clients):
            if len(client.queue) < client.queue_lines and client.queued_bytes + len(line) <= QUEUE_BYTES:
                client.queue.append(line)
                client.queued_bytes += len(line)
                client.ready.set()
                continue
            client.dropped += 1
            client.dropped_total += 1
            client.dropped_in_a_row += 1
            self.counters["dropped"] += 1
            if client.dropped_in_a_row >= self.max_drops:
                self.counters["disconnected_slow"] += 1
                log.warning("client %s took nothing while %d items were dropped: disconnecting it",
                            client.peer, client.dropped_in_a_row)
                self._drop_client(client, {"kind": "dropped", "count": client.dropped, "total": client.dropped_total,
                                           "disconnected": "too slow: took nothing while its queue overflowed"})

    def health(self) -> dict[str, Any]:
        return {**self.counters, "connected": len(self.clients),
                "per_client": {c.peer: {"sent": c.sent, "dropped": c.dropped_total, "queued": len(c.queue)}
                               for c in self.clients}}

    # -- connections -----------------------------------------------------------------------
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
        client = _Client(writer, self.queue_lines)
        self.clients.add(client)
        self.counters["clients"] += 1
        client.queue.append((json.dumps(self.hello) + "\n").encode())
        client.ready.set()
        task = asyncio.create_task(self._serve(client, reader))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _serve(self, client: _Client, reader: asyncio.StreamReader) -> None:
        """Send the client its queue until it leaves (EOF), is cut off, or sends too much."""
        eof = asyncio.create_task(self._discard_input(client, reader))
        try:
            while not client.closed:
                while not client.queue:
                    client.ready.clear()
                    waiter = asyncio.create_task(client.ready.wait())
                    done, _ = await asyncio.wait({waiter, eof}, return_when=asyncio.FIRST_COMPLETED)
                    if eof in done:
                        waiter.cancel()
                        return
                if client.dropped:
                    notice = {"kind": "dropped", "count": client.dropped, "total": client.dropped_total}
                    client.dropped = 0
                    client.writer.write((json.dumps(notice) + "\n").encode())
                line = client.queue.popleft()
                client.queued_bytes -= len(line)
                client.writer.write(line)
                client.sent += 1
                client.dropped_in_a_row = 0
                await client.writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            eof.cancel()
            self._drop_client(client)

    async def _discard_input(self, client: _Client, reader: asyncio.StreamReader) -> None:
        """Read what the client sends, READ_CHUNK bytes at a time, and forget it; returns at
        EOF, or after cutting off a client that sent more than ``max_input`` bytes."""
        while data := await _read(reader):
            client.received += len(data)
            if client.received > self.max_input:
                self.counters["disconnected_input"] += 1
                log.warning("client %s sent more than %d bytes: disconnecting it", client.peer, self.max_input)
                self._drop_client(client, {"kind": "error",
                                           "error": f"sent more than {self.max_input} bytes; this server takes no input"},
                                  linger=True)
                return

    def _drop_client(self, client: _Client, last: dict[str, Any] | None = None, linger: bool = False) -> None:
        """Forget the client and close its connection after what it was sent. ``linger``: it
        may still be sending, so end our side first and close LINGER_S later; closing with its
        bytes unread would reset the connection and could lose the last line."""
        if client.closed:
            return
        client.closed = True
        client.ready.set()
        client.queue.clear()  # what it will never take is not held for the close grace
        client.queued_bytes = 0
        self.clients.discard(client)
        transport = client.writer.transport
        if last is not None:
            transport.write((json.dumps(last) + "\n").encode())  # behind what it has not taken yet
        loop = asyncio.get_running_loop()
        if linger and transport.can_write_eof():
            transport.write_eof()  # after the buffered lines; its input, meanwhile, fills a bounded buffer
            loop.call_later(LINGER_S, transport.close)
        else:
            transport.close()  # flushes what the client will still take, then closes
        loop.call_later(CLOSE_GRACE_S, transport.abort)


async def _read(reader: asyncio.StreamReader) -> bytes:
    """At most READ_CHUNK bytes; b"" at EOF or when the connection broke."""
    try:
        return await reader.read(READ_CHUNK)
    except (ConnectionError, OSError):
        return b""


def _error_line(text: str) -> bytes:
    return (json.dumps({"kind": "error", "error": text}) + "\n").encode()


def _host(address: str) -> str:
    return f"[{address}]" if ":" in address else address


class ServeDriver(Driver):
    """A client of ``rfhoming serve``: the items of the server's devices, as if local.

    Each item is rebuilt from its JSON form and shown to the listeners under its own device's
    name and time; angle events also go to :attr:`out` (as from an AoaDriver). ``device``
    keeps only one device's items. Bad lines are counted, never fatal; the server's ``dropped``
    notices add up in ``counters["server_dropped"]``."""

    kind = "serve"

    def __init__(self, port: HostPort, *, device: str | None = None, queue_size: int = 1000,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.device = device
        self.counters.update(items=0, bad_lines=0, server_dropped=0)
        self.hello: dict[str, Any] = {}
        self._partial = b""

    def on_chunk(self, data: bytes, t_host: float) -> None:
        lines = (self._partial + data).split(b"\n")
        self._partial = lines.pop()
        if len(self._partial) > MAX_LINE:
            self.counters["bad_lines"] += 1
            self._partial = b""
        for line in lines:
            self._on_line(line)

    def _on_line(self, line: bytes) -> None:
        try:
            record = json.loads(line)
            kind = record["kind"]
        except (ValueError, KeyError, TypeError):
            self.counters["bad_lines"] += 1
            return
        if kind == "hello":
            self.hello = record
            return
        if kind == "dropped":
            self.counters["server_dropped"] += int(record.get("count", 0))
            log.warning("%s: the server dropped %s items for this client (it read too slowly)",
                        self.port.name, record.get("count"))
            return
        if self.device is not None and record.get("device") != self.device:
            return
        try:
            item = from_dict(record)
            device, t = str(record["device"]), float(record["t"])
        except (ValueError, KeyError, TypeError):
            self.counters["bad_lines"] += 1
            return
        self.counters["items"] += 1
        for listener in self.listeners:
            listener(device, t, item)
        if kind == "angle":
            self.out.put(TimedAngle(t, item))

    async def session(self) -> None:
        self._partial = b""
        await super().session()
