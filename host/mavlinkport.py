"""A MAVLink link, HostPort-shaped: any connection pymavlink's ``mavutil`` opens (``tcp:``,
``tcpin:``, a serial device with ``baud=``), and UDP (``udpin:``, ``udpout:``) on a socket of
its own, read by the event loop.

Each chunk is what one datagram or read carried, raw, through the taps: a capture holds the
MAVLink packets both ways and a replay feeds the same bytes. A socket binds to loopback unless
the user opts in (``expose=1``): a vehicle's commands are not offered to a network by default.

A UDP link talks to one vehicle (:class:`UdpLink`): ``udpout:`` to the address it was given,
``udpin:`` to the sender of the first vehicle HEARTBEAT it hears (of ``sysid=``, if given).
Datagrams from any other sender are dropped before the taps (counted as ``foreign_datagrams``)
and shown to ``on_foreign``, so the driver can tell a second vehicle from someone speaking as
its own; pymavlink's UDP link would take them all and answer every sender.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import time
from collections.abc import Callable
from typing import Any

from rfhoming.host.ports import Chunk, Disconnected, PortError, Tap
from rfhoming.protocol import mavlink as ml

log = logging.getLogger(__name__)

MAX_QUEUED = 1000  # chunks read and not yet decoded; more are dropped (counted)
LISTENING = ("udpin:", "tcpin:", "udp:")
UDP = ("udpin:", "udp:", "udpout:")  # handled here (UdpLink); the rest by pymavlink
NETWORK = ("udpbcast:", "mcast:")  # a broadcast or multicast link reaches the network whatever its address
Address = tuple[str, int]


def _loopback(host: str) -> bool:
    try:
        return all(ipaddress.ip_address(info[4][0]).is_loopback
                   for info in socket.getaddrinfo(host, None, proto=socket.IPPROTO_UDP))
    except (OSError, ValueError):
        return False


def check_where(where: str, expose: bool) -> None:
    """A connection string reaches only this machine (a loopback address to listen on or send
    to), unless ``expose``."""
    if expose:
        return
    host = where.partition(":")[2].rpartition(":")[0]
    if where.startswith(LISTENING) and not _loopback(host or "0.0.0.0"):
        prefix = where.partition(":")[0]
        raise PortError(f"mavlink:{where} listens on {host or 'every interface'}, which other machines reach: "
                        f"use {prefix}:127.0.0.1:PORT, or add ,expose=1 to accept a vehicle over the network")
    if where.startswith("udpout:") and not _loopback(host):
        raise PortError(f"mavlink:{where} sends to another machine, so its socket would take datagrams from the "
                        "network: add ,expose=1 to drive a vehicle over the network (rfhoming then listens to that "
                        "vehicle's address only)")
    if where.startswith(NETWORK):
        raise PortError(f"mavlink:{where} broadcasts to the network: add ,expose=1 if that is meant, or use "
                        "udpout:HOST:PORT / udpin:127.0.0.1:PORT")


def _address(where: str) -> tuple[str, Address]:
    """``udpin:HOST:PORT`` -> ("udpin", (IPv4 address, port)); PortError when it names none."""
    prefix, _, rest = where.partition(":")
    host, _, port = rest.rpartition(":")
    try:
        info = socket.getaddrinfo(host or "0.0.0.0", int(port), socket.AF_INET, socket.SOCK_DGRAM)
    except (OSError, ValueError) as exc:
        raise PortError(f"mavlink:{where}: {exc}; a UDP connection string is udpin:HOST:PORT or "
                        "udpout:HOST:PORT") from None
    return prefix, (str(info[0][4][0]), int(info[0][4][1]))


class UdpLink:
    """A UDP socket that talks to one vehicle (pymavlink's ``mavudp`` answers every sender)."""

    def __init__(self, where: str, *, sysid: int | None) -> None:
        prefix, address = _address(where)
        self.sysid = sysid
        self.listening = prefix != "udpout"
        self.peer: Address | None = None if self.listening else address  # the vehicle: only it is heard
        self.sender: Address | None = None  # udpin: who spoke last before the vehicle (answered until it)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(address if self.listening else (self._local_address(address), 0))
        except OSError:
            sock.close()
            raise
        sock.setblocking(False)
        self.sock = sock
        self.fd = sock.fileno()

    @staticmethod
    def _local_address(peer: Address) -> str:
        """The address of this machine's interface towards ``peer`` (loopback for a loopback peer):
        the only one the socket is bound to."""
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.connect(peer)  # no datagram is sent: the kernel only picks the route
            return str(probe.getsockname()[0])

    def recv(self) -> tuple[bytes, Address | None]:
        """The next datagram (b"" when there is none), and its sender if that is not the vehicle."""
        try:
            data, source = self.sock.recvfrom(65536)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return b"", None
        if self.peer is None:  # listening, and the vehicle has not spoken: the first HEARTBEAT of one decides
            self.sender = source
            if ml.has_vehicle_heartbeat(data, self.sysid):
                self.peer = source
                log.info("mavlink: locked on to the vehicle at %s:%d", *source)
            return data, None
        return data, (None if source == self.peer else source)

    def write(self, data: bytes) -> None:
        to = self.peer or self.sender
        if to is None:
            raise Disconnected("no vehicle has spoken yet")
        self.sock.sendto(data, to)

    def close(self) -> None:
        self.sock.close()


class MavlinkPort:
    def __init__(self, where: str, *, baud: int = 57600, name: str | None = None, taps: list[Tap] | None = None,
                 expose: bool = False, sysid: int | None = None) -> None:
        check_where(where, expose)
        self.spec = where
        self.name = name or where
        self.baud = baud
        self.sysid = sysid
        self.taps: list[Tap] = list(taps or [])
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0, "disconnects": 0,
                         "dropped_bytes": 0, "unsent_bytes": 0, "foreign_datagrams": 0}
        self.on_foreign: Callable[[Address, bytes], None] | None = None
        """Shown every datagram of a sender that is not the vehicle (a UDP link), after counting it."""
        self._conn: Any = None
        self._queue: asyncio.Queue[Chunk] = asyncio.Queue()
        self._loop: asyncio.AbstractEventLoop | None = None

    @staticmethod
    def speaks_first_on(where: str) -> bool:
        """Whether this end must speak first: it does not listen, so the vehicle cannot know it."""
        return not where.startswith(LISTENING)

    @staticmethod
    def datagrams_on(where: str) -> bool:
        """Whether each read is a datagram (no MAVLink packet spans two)."""
        return where.startswith((*UDP, *NETWORK))

    @property
    def speaks_first(self) -> bool:
        return self.speaks_first_on(self.spec)

    @property
    def is_open(self) -> bool:
        return self._conn is not None

    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        try:
            if self.spec.startswith(UDP):
                conn: Any = UdpLink(self.spec, sysid=self.sysid)
            else:
                from pymavlink import mavutil  # type: ignore[import-untyped]  # the mavlink extra

                conn = await asyncio.to_thread(mavutil.mavlink_connection, self.spec, baud=self.baud,
                                               autoreconnect=False)
        except (OSError, ValueError) as exc:
            raise PortError(f"cannot open mavlink:{self.spec}: {exc}; a connection string as pymavlink reads it: "
                            "udpin:127.0.0.1:14550, udpout:HOST:PORT, tcp:HOST:PORT or /dev/ttyACM0,baud=57600") from None
        self._conn = conn
        self._loop.add_reader(conn.fd, self._readable)
        self.counters["opens"] += 1

    def _readable(self) -> None:
        conn = self._conn
        try:
            if isinstance(conn, UdpLink):
                data, stranger = conn.recv()
                if stranger is not None:  # not the vehicle: counted, shown to the driver, never read as its bytes
                    self.counters["foreign_datagrams"] += 1
                    if self.on_foreign is not None:
                        self.on_foreign(stranger, data)
                    return
            else:
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
        """One or more MAVLink packets, to the vehicle. A ``udpin:`` link answers whoever spoke
        last until the vehicle's first HEARTBEAT, and the vehicle alone after it: before any
        packet there is nobody to send to (counted as unsent)."""
        if self._conn is None:
            raise Disconnected(f"{self.name} is not open")
        now = round(time.time() * 1e6) / 1e6
        try:
            self._conn.write(data)
        except Disconnected as exc:
            self.counters["unsent_bytes"] += len(data)
            raise Disconnected(f"{self.name}: {exc}") from None
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
