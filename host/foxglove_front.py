"""A loopback front for foxglove-sdk's WebSocket server: it takes both names of the protocol,
and no client behind it can stop the server, the run or Ctrl-C.

Both names: foxglove-sdk accepts only the subprotocol ``foxglove.sdk.v1`` (HTTP 400 for anything
else, no option); Foxglove's own ``FoxgloveClient`` (npm ``@foxglove/ws-protocol``) and Lichtblick
1.21 and older offer ``foxglove.websocket.v1``, the same protocol under its published name
(github.com/foxglove/ws-protocol ``docs/spec.md``). The front reads a client's HTTP upgrade
request, offers the SDK ``foxglove.sdk.v1`` in place of ``foxglove.websocket.v1``, answers the
client with the name it offered, and from then on copies bytes both ways untouched. The key and
its accept pass as they are: the accept hashes the key alone (RFC 6455 §4.2.2), so the
rewritten handshake is still the client's. The SDK's schemas and bounds (its per-client
backlog, its 16 MiB message limit) apply as before.

No client can stop it: foxglove-sdk's ``stop()`` waits forever for a client that reads nothing
(it cannot flush to it), and a client the SDK cannot write to holds its connection task. So the
SDK only ever talks to this front, which always reads what the SDK sends: it holds at most
``CLIENT_BUFFER`` bytes for a client and cuts off a client that takes none of them for
``STALL_S``; a handshake must come within ``HANDSHAKE_S`` and ``MAX_HEAD`` bytes; past
``MAX_CLIENTS`` connections a new one is closed. A client that has sent nothing since its
handshake (no subscription, no request) is idle: one address keeps at most ``max_idle`` idle
clients, and another closes the one idle longest (host/idle_clients.py). :meth:`Front.close`
aborts every connection before the SDK is stopped, so the SDK has nobody left to wait for. The
front runs its own event loop in a thread: a run's loop never waits on it, nor it on the run.

Only the front reaches the SDK: given the SDK listener's key (host/loopback_key.py), it signs
its connections with it, and the kernel drops any other's.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading

from rfhoming.host.idle_clients import IdleClients
from rfhoming.host.loopback_key import keyed_socket

log = logging.getLogger(__name__)

SDK_PROTOCOL = b"foxglove.sdk.v1"  # the only name foxglove-sdk's server accepts
SPEC_PROTOCOL = b"foxglove.websocket.v1"  # the spec's name, which Foxglove's clients offer
MAX_HEAD = 16 * 1024  # the longest HTTP request or response head
HANDSHAKE_S = 10.0  # a client has this long to send its upgrade request
CHUNK = 64 * 1024
CLIENT_BUFFER = 4 * 1024 * 1024  # bytes from the SDK held for one client that has not taken them
STALL_S = 5.0  # a client that takes nothing of its buffer for this long is cut off
MAX_CLIENTS = 64
MAX_IDLE = 8  # clients of one address that have sent nothing since their handshake, at most
CLOSE_S = 5.0  # what close() waits for the front's thread


def offer_sdk(head: bytes) -> tuple[bytes, bytes | None]:
    """The upgrade request to pass to the SDK, and the subprotocol to answer the client with
    (None: the SDK's answer stands). Only a request that offers the spec's name and not the
    SDK's is changed: its offer becomes the SDK's name."""
    lines = head.split(b"\r\n")
    offers = [i for i, line in enumerate(lines) if line.lower().startswith(b"sec-websocket-protocol:")]
    offered = {p.strip() for i in offers for p in lines[i].split(b":", 1)[1].split(b",")}
    if SDK_PROTOCOL in offered or SPEC_PROTOCOL not in offered:
        return head, None
    lines[offers[0]] = b"Sec-WebSocket-Protocol: " + SDK_PROTOCOL
    return b"\r\n".join(line for i, line in enumerate(lines) if i not in offers[1:]), SPEC_PROTOCOL


def answer_as(head: bytes, protocol: bytes | None) -> bytes:
    """The SDK's response head, its subprotocol renamed to the one the client offered."""
    if protocol is None:
        return head
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(b"sec-websocket-protocol:"):
            lines[i] = b"Sec-WebSocket-Protocol: " + protocol
    return b"\r\n".join(lines)


class Front:
    """Listens on ``host:port`` (0: any free port; :attr:`port` is the one taken) and passes
    each client to the SDK's server on ``127.0.0.1:upstream``, signing those connections with
    ``key`` (the listener's TCP-MD5 key; None: plain connections)."""

    def __init__(self, upstream: int, host: str = "127.0.0.1", port: int = 0, *, key: bytes | None = None,
                 max_idle: int = MAX_IDLE) -> None:
        self.upstream = upstream
        self.key = key
        self.counters = {"clients": 0, "renamed": 0, "refused": 0, "stalled": 0, "bad_handshakes": 0, "idle_closed": 0}
        self._transports: set[asyncio.WriteTransport] = set()
        self._idle: IdleClients[asyncio.WriteTransport] = IdleClients(max_idle)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="foxglove-front", daemon=True)
        self._thread.start()
        try:
            self._server = asyncio.run_coroutine_threadsafe(
                asyncio.start_server(self._accept, host, port, limit=MAX_HEAD), self._loop).result(HANDSHAKE_S)
        except BaseException:
            self._loop.call_soon_threadsafe(self._loop.stop)
            raise
        self.port: int = self._server.sockets[0].getsockname()[1]

    def close(self) -> None:
        """Stop listening and abort every connection (both sides), then end the thread."""
        if self._loop.is_closed():
            return

        async def shut() -> None:
            self._server.close()
            for transport in list(self._transports):
                transport.abort()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        with contextlib.suppress(Exception):  # a front already gone has nothing to close
            asyncio.run_coroutine_threadsafe(shut(), self._loop).result(CLOSE_S)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(CLOSE_S)
        if not self._thread.is_alive():
            self._loop.close()

    # -- one connection ------------------------------------------------------------------
    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(asyncio.CancelledError):  # close() ends it: nothing to report
            await self._pass(reader, writer)

    async def _pass(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        client = writer.transport
        if len(self._transports) >= 2 * MAX_CLIENTS:  # each client holds two: its own and the SDK's
            self.counters["refused"] += 1
            client.abort()
            return
        self._transports.add(client)
        source = str(writer.get_extra_info("peername")[0])
        longest = self._idle.arrived(source, client)
        if longest is not None:
            self.counters["idle_closed"] += 1
            log.warning("Foxglove view: more than %d clients from %s sent nothing; closing the one idle longest",
                        self._idle.per_source, source)
            longest.abort()
        upstream: asyncio.StreamWriter | None = None
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_S)
                request, rename = offer_sdk(head)
                up_reader, up_writer = await asyncio.wait_for(self._connect(), HANDSHAKE_S)
                upstream = up_writer  # closed at the end
                self._transports.add(up_writer.transport)
                up_writer.write(request)
                response = await asyncio.wait_for(up_reader.readuntil(b"\r\n\r\n"), HANDSHAKE_S)
            except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError, OSError):
                self.counters["bad_handshakes"] += 1
                return
            self.counters["clients"] += 1
            self.counters["renamed"] += rename is not None
            writer.transport.set_write_buffer_limits(high=CLIENT_BUFFER)
            writer.write(answer_as(response, rename))
            pipes = [asyncio.ensure_future(self._to_sdk(reader, up_writer, client)),
                     asyncio.ensure_future(self._to_client(up_reader, writer))]
            try:
                await asyncio.wait(pipes, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for pipe in pipes:
                    pipe.cancel()
                await asyncio.gather(*pipes, return_exceptions=True)
        finally:
            self._idle.left(client)
            for side in (writer, upstream):
                if side is not None:
                    self._transports.discard(side.transport)
                    side.transport.abort()  # both ends go at once: nothing is left to wait for

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """A connection to the SDK's listener, signed with its key when there is one."""
        if self.key is None:
            return await asyncio.open_connection("127.0.0.1", self.upstream, limit=MAX_HEAD)
        sock = keyed_socket(self.key)
        try:
            await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", self.upstream))
        except BaseException:
            sock.close()
            raise
        return await asyncio.open_connection(sock=sock, limit=MAX_HEAD)

    async def _to_sdk(self, reader: asyncio.StreamReader, upstream: asyncio.StreamWriter,
                      client: asyncio.WriteTransport) -> None:
        """What the client sends, as it comes; the SDK bounds and judges it. A client that sends
        anything is idle no more."""
        with contextlib.suppress(OSError):
            while data := await reader.read(CHUNK):
                self._idle.spoke(client)
                upstream.write(data)
                await upstream.drain()

    async def _to_client(self, up_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """What the SDK sends, always read; a client that leaves CLIENT_BUFFER bytes untaken
        for STALL_S is cut off."""
        with contextlib.suppress(OSError):
            while data := await up_reader.read(CHUNK):
                writer.write(data)
                try:
                    await asyncio.wait_for(writer.drain(), STALL_S)
                except TimeoutError:
                    self.counters["stalled"] += 1
                    log.warning("Foxglove view: a client took nothing for %.0f s; cutting it off", STALL_S)
                    return
