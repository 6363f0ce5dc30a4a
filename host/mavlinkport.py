"""A MAVLink link, HostPort-shaped: any connection pymavlink's ``mavutil`` opens (``udpin:``,
``udpout:``, ``tcp:``, ``tcpin:``, a serial device with ``baud=``), read by the event loop.

Each chunk is what one datagram or read carried, raw, through the taps: a capture holds the
MAVLink packets both ways and a replay feeds the same bytes. A socket that listens binds to
loopback unless the user opts in (``expose=1``): a vehicle's commands are not offered to a
network by default.
"""

from __future__ import annotations

import asyncio
import ipaddress
import socket
import time
from typing import Any

from rfhoming.host.ports import Chunk, Disconnected, PortError, Tap

MAX_QUEUED = 1000  # chunks read and not yet decoded; more are dropped (counted)
LISTENING = ("udpin:", "tcpin:", "udp:")


def _loopback(host: str) -> bool:
    try:
        return all(ipaddress.ip_address(info[4][0]).is_loopback
                   for info in socket.getaddrinfo(host, None, proto=socket.IPPROTO_UDP))
    except (OSError, ValueError):
        return False


def check_where(where: str, expose: bool) -> None:
    """A listening connection string names a loopback address, unless ``expose``."""
    for prefix in LISTENING:
        if where.startswith(prefix):
            host = where[len(prefix):].rpartition(":")[0]
            if not expose and not _loopback(host or "0.0.0.0"):
                raise PortError(f"mavlink:{where} listens on {host or 'every interface'}, which other machines reach: "
                                f"use {prefix}127.0.0.1:PORT, or add ,expose=1 to accept a vehicle over the network")


class MavlinkPort:
    def __init__(self, where: str, *, baud: int = 57600, name: str | None = None, taps: list[Tap] | None = None,
                 expose: bool = False) -> None:
        check_where(where, expose)
        self.spec = where
        self.name = name or where
        self.baud = baud
        self.taps: list[Tap] = list(taps or [])
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0, "disconnects": 0,
                         "dropped_bytes": 0, "unsent_bytes": 0}
        self._conn: Any = None
        self._queue: asyncio.Queue[Chunk] = asyncio.Queue()
        self._loop: asyncio.AbstractEventLoop | None = None

    @staticmethod
    def speaks_first_on(where: str) -> bool:
        """Whether this end must speak first: it does not listen, so the vehicle cannot know it."""
        return not where.startswith(LISTENING)

    @property
    def speaks_first(self) -> bool:
        return self.speaks_first_on(self.spec)

    @property
    def is_open(self) -> bool:
        return self._conn is not None

    async def open(self) -> None:
        from pymavlink import mavutil  # type: ignore[import-untyped]  # the mavlink extra

        self._loop = asyncio.get_running_loop()
        try:
            conn = await asyncio.to_thread(mavutil.mavlink_connection, self.spec, baud=self.baud, autoreconnect=False)
        except (OSError, ValueError) as exc:
            raise PortError(f"cannot open mavlink:{self.spec}: {exc}; a connection string as pymavlink reads it: "
                            "udpin:127.0.0.1:14550, udpout:HOST:PORT, tcp:HOST:PORT or /dev/ttyACM0,baud=57600") from None
        self._conn = conn
        self._loop.add_reader(conn.fd, self._readable)
        self.counters["opens"] += 1

    def _readable(self) -> None:
        conn = self._conn
        try:
            data = conn.recv(65536) if conn is not None else b""
        except OSError:
            self._lost()
            return
        if not data:
            return
        data = bytes(data) if not isinstance(data, str) else data.encode("latin-1")
        now = round(time.time() * 1e6) / 1e6
        for tap in self.taps:
            tap(self.name, "in", now, data)
        self.counters["bytes_in"] += len(data)
        self.counters["chunks_in"] += 1
        if self._queue.qsize() >= MAX_QUEUED:
            self.counters["dropped_bytes"] += len(data)
            return
        self._queue.put_nowait(Chunk(now, data))

    def _lost(self) -> None:
        self.counters["disconnects"] += 1
        self._queue.put_nowait(Chunk(-1.0, b""))  # read() raises Disconnected at it

    async def read(self) -> Chunk:
        if self._conn is None:
            raise Disconnected(f"{self.name} is not open")
        chunk = await self._queue.get()
        if chunk.t < 0:
            raise Disconnected(f"{self.name}: the MAVLink link went away")
        return chunk

    def take_pending(self) -> list[Chunk]:
        chunks = []
        while not self._queue.empty():
            chunk = self._queue.get_nowait()
            if chunk.t >= 0:
                chunks.append(chunk)
        return chunks

    def write(self, data: bytes) -> None:
        """One or more MAVLink packets. A ``udpin:`` link answers whoever spoke last: before the
        vehicle's first packet there is nobody to send to (counted as unsent)."""
        if self._conn is None:
            raise Disconnected(f"{self.name} is not open")
        if getattr(self._conn, "udp_server", False) and not self._conn.clients:  # pymavlink's mavudp
            self.counters["unsent_bytes"] += len(data)
            raise Disconnected(f"{self.name}: no vehicle has spoken yet")
        now = round(time.time() * 1e6) / 1e6
        try:
            self._conn.write(data)
        except OSError as exc:
            raise Disconnected(f"{self.name}: {exc}") from None
        for tap in self.taps:
            tap(self.name, "out", now, data)
        self.counters["bytes_out"] += len(data)

    async def close(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            if self._loop is not None and not self._loop.is_closed():
                self._loop.remove_reader(conn.fd)
            conn.close()
