"""Transports between a device model and the host: pty, TCP on loopback, in-process pipe.

Each link carries raw bytes both ways, exactly as a USB serial port would: ``send`` is the
device writing, ``on_receive`` is called with what the host wrote. ``unplug``/``replug`` make
the endpoint vanish and come back (a pty's stable symlink comes back at the same path).
``host_baud`` is what the host has set, where the transport can tell (a pty's termios).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import termios
import tty
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

MAX_BACKLOG = 1 << 20
"""Bytes a link holds for a slow or absent host before it drops (counted)."""

_BAUD = {getattr(termios, f"B{b}"): b for b in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600, 1000000)}


def not_plain(name: str) -> str | None:
    """Why ``name`` cannot be a link's file name in the link folder, or None when it can: a
    name with a separator, ``..``, ``.``, NUL or nothing would put the link (and the unlink
    before it) outside the folder, or nowhere."""
    if not name:
        return "it is empty"
    if name in (".", ".."):
        return f"{name!r} names a folder"
    for char, what in (("/", "'/'"), ("\\", "'\\'"), ("\0", "NUL")):
        if char in name:
            return f"it holds {what}"
    return None


class Link:
    """Base: counts what crosses and what had to be dropped."""

    def __init__(self) -> None:
        self.on_receive: Callable[[bytes], None] = lambda data: None
        self.counters = {"tx_bytes": 0, "rx_bytes": 0, "dropped_bytes": 0, "unplugs": 0}
        self.plugged = False

    def describe(self) -> dict[str, Any]:
        raise NotImplementedError

    def host_baud(self) -> int | None:
        return None

    async def start(self) -> None:
        raise NotImplementedError

    def send(self, data: bytes) -> None:
        raise NotImplementedError

    async def unplug(self) -> None:
        raise NotImplementedError

    async def replug(self) -> None:
        await self.start()

    async def close(self) -> None:
        if self.plugged:
            await self.unplug()


class PtyLink(Link):
    """A pseudo-terminal: the host opens ``path`` (a stable symlink) like /dev/ttyACM0."""

    def __init__(self, symlink: Path | None = None) -> None:
        super().__init__()
        self.symlink = symlink
        self.master = self.slave = -1
        self.tty_name = ""
        self._backlog = bytearray()

    def describe(self) -> dict[str, Any]:
        return {"path": str(self.symlink or self.tty_name)}

    async def start(self) -> None:
        self.master, self.slave = os.openpty()
        for fd in (self.master, self.slave):
            tty.setraw(fd)
        attrs = termios.tcgetattr(self.slave)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
        os.set_blocking(self.master, False)
        self.tty_name = os.ttyname(self.slave)
        if self.symlink is not None:
            with contextlib.suppress(FileNotFoundError):
                self.symlink.unlink()
            self.symlink.symlink_to(self.tty_name)
        asyncio.get_running_loop().add_reader(self.master, self._readable)
        self.plugged = True

    def host_baud(self) -> int | None:
        if not self.plugged:
            return None
        return _BAUD.get(termios.tcgetattr(self.master)[5])

    def _readable(self) -> None:
        try:
            data = os.read(self.master, 65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # EIO: nobody has the slave open
            return
        if data:
            self.counters["rx_bytes"] += len(data)
            self.on_receive(data)

    def send(self, data: bytes) -> None:
        if not self.plugged:
            self.counters["dropped_bytes"] += len(data)
            return
        self._backlog += data
        try:
            written = os.write(self.master, self._backlog)
        except BlockingIOError:
            written = 0
        self.counters["tx_bytes"] += written
        del self._backlog[:written]
        if len(self._backlog) > MAX_BACKLOG:
            self.counters["dropped_bytes"] += len(self._backlog)
            self._backlog.clear()

    async def unplug(self) -> None:
        if not self.plugged:
            return
        asyncio.get_running_loop().remove_reader(self.master)
        if self.symlink is not None:
            with contextlib.suppress(FileNotFoundError):
                self.symlink.unlink()
        os.close(self.master)
        os.close(self.slave)
        self._backlog.clear()
        self.plugged = False
        self.counters["unplugs"] += 1


class TcpLink(Link):
    """TCP on 127.0.0.1; the host opens ``socket://127.0.0.1:PORT`` with pyserial."""

    def __init__(self, port: int = 0) -> None:
        super().__init__()
        self.port = port
        self._server: asyncio.AbstractServer | None = None
        self._writer: asyncio.StreamWriter | None = None
        self.assumed_host_baud = 115200

    def describe(self) -> dict[str, Any]:
        """``path`` as the pty mode prints it (a port spec takes socket:// URLs), so a client
        reads the same key in both modes; ``url`` kept for clients that read it."""
        url = f"socket://127.0.0.1:{self.port}"
        return {"path": url, "url": url}

    def host_baud(self) -> int | None:
        return self.assumed_host_baud

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._client, "127.0.0.1", self.port)
        self.port = self._server.sockets[0].getsockname()[1]
        self.plugged = True

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:  # one host at a time, like a serial port
            writer.close()
            return
        self._writer = writer
        try:
            while data := await reader.read(65536):
                self.counters["rx_bytes"] += len(data)
                self.on_receive(data)
        except (ConnectionError, asyncio.CancelledError):  # cancelled: the emulator is stopping. Ending
            pass  # normally, since 3.11's server callback logs a traceback for a cancelled handler
        finally:
            if self._writer is writer:
                self._writer = None
            writer.close()

    def send(self, data: bytes) -> None:
        writer = self._writer
        if writer is None or not self.plugged:
            self.counters["dropped_bytes"] += len(data)
            return
        if writer.transport.get_write_buffer_size() > MAX_BACKLOG:
            self.counters["dropped_bytes"] += len(data)
            return
        writer.write(data)
        self.counters["tx_bytes"] += len(data)

    async def unplug(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
        self.plugged = False
        self.counters["unplugs"] += 1


class PipeLink(Link):
    """In-process: the host side is :attr:`host`, with ``write(bytes)`` and ``await read()``."""

    def __init__(self) -> None:
        super().__init__()
        self.host = PipeEnd(self)
        self.assumed_host_baud = 115200

    def describe(self) -> dict[str, Any]:
        return {"pipe": id(self)}

    def host_baud(self) -> int | None:
        return self.assumed_host_baud

    async def start(self) -> None:
        self.plugged = True

    def send(self, data: bytes) -> None:
        if not self.plugged or self.host.pending() > MAX_BACKLOG:
            self.counters["dropped_bytes"] += len(data)
            return
        self.counters["tx_bytes"] += len(data)
        self.host.deliver(data)

    async def unplug(self) -> None:
        self.plugged = False
        self.counters["unplugs"] += 1
        self.host.deliver(b"")


def pipe_end(link: Link) -> PipeEnd:
    """The host's end of an in-process link (an emulator started with ``transport="pipe"``)."""
    if not isinstance(link, PipeLink):
        raise TypeError(f"{type(link).__name__} is not an in-process link: start the emulator with transport='pipe'")
    return link.host


class PipeEnd:
    """The host's end of a :class:`PipeLink`; ``read()`` returns b"" while unplugged.

    Chunks wait in a deque with one waiter future (an asyncio.Queue's bookkeeping showed in the
    lockstep profile). Each read returns one delivered chunk, as a port read would."""

    def __init__(self, link: PipeLink) -> None:
        self._link = link
        self._chunks: deque[bytes] = deque()
        self._waiter: asyncio.Future[None] | None = None
        self._size = 0

    def pending(self) -> int:
        return self._size

    def deliver(self, data: bytes) -> None:
        self._size += len(data)
        self._chunks.append(data)
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)

    async def read(self) -> bytes:
        while not self._chunks:
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None
        data = self._chunks.popleft()
        self._size -= len(data)
        return data

    def write(self, data: bytes) -> None:
        if self._link.plugged:
            self._link.counters["rx_bytes"] += len(data)
            self._link.on_receive(data)
