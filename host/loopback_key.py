"""A loopback listener of this process that only connections carrying a key can reach.

foxglove-sdk's WebSocket server listens on TCP and takes any client: it binds ``host:port``
and no other kind of socket, and its handshake checks only the subprotocol (foxglove-sdk 0.30,
``rust/foxglove/src/websocket/server.rs`` ``start`` and ``handshake.rs``; the Python
``start_server`` has no authentication option). Its listener sits behind the Foxglove front
(host/foxglove_front.py), whose limits a client that connected to the listener directly
would pass by. So the listener gets a TCP-MD5 key (RFC 2385, Linux's ``TCP_MD5SIG_EXT``, no
privilege needed): the kernel then drops every segment that is not signed with the key,
from any IPv4 source (0.0.0.0/0: a local program may bind its end to this machine's own LAN
address and still reach 127.0.0.1, so a key for 127.0.0.0/8 alone would let it by) -- a
connection without it never opens (the SYN is dropped and counted as ``TcpExtTCPMD5NotFound``
in /proc/net/netstat) -- and the front signs its own connections. The key is random, made for each server, and never leaves this process.

The listening socket is the SDK's: it is found among this process's own descriptors by its
address, and every descriptor of it is keyed, or none is (a listener keyed in part would take
neither a plain client nor, unknowing, the front). A connection that opened in the instant
between the SDK's ``listen`` and the key is looked for in /proc/net/tcp afterwards (:func:`lock`
raises ListenerExposed). Where the key cannot be set -- not Linux (no ``TCP_MD5SIG_EXT``), no
/proc to find the listener in, a kernel without TCP-MD5 -- :func:`lock` raises NotLocked
saying which, and the listener stays open to local programs, as it was.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import socket
import stat
import struct
import sys

from rfhoming.protocol.errors import Error

TCP_MD5SIG_EXT = 32  # linux/tcp.h: a key for an address prefix (Linux 4.13)
TCP_MD5SIG_FLAG_PREFIX = 1
KEY_BYTES = 32  # at most TCP_MD5SIG_MAXKEYLEN, 80
EVERY_SOURCE = ("0.0.0.0", 0)  # the key is asked of every IPv4 peer, whatever its address
_OPEN_STATES = frozenset({"01", "03"})  # /proc/net/tcp: ESTABLISHED, SYN_RECV (closing ones may be an older server's)


class ListenerExposed(Error):
    """A connection reached the listener before its key was set; the message says what to do."""


class NotLocked(Exception):
    """The listener could not be keyed and is as it was (open to local programs); the message says why."""


def _md5sig(key: bytes, address: str, prefix: int) -> bytes:
    """struct tcp_md5sig: a sockaddr_storage (an AF_INET address), flags, prefix length, key length,
    interface index, the key."""
    where = struct.pack("=H2s4s", socket.AF_INET, b"\0\0", socket.inet_aton(address)).ljust(128, b"\0")
    return where + struct.pack("=BBHi", TCP_MD5SIG_FLAG_PREFIX, prefix, len(key), 0) + key.ljust(80, b"\0")


def _listening(port: int) -> list[int]:
    """This process's descriptors of TCP sockets listening on 127.0.0.1:``port``."""
    found = []
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        with contextlib.suppress(OSError):
            if not stat.S_ISSOCK(os.fstat(fd).st_mode):
                continue
            with socket.socket(fileno=os.dup(fd)) as sock:
                if (sock.family == socket.AF_INET and sock.type == socket.SOCK_STREAM
                        and sock.getsockname() == ("127.0.0.1", port)
                        and sock.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN)):
                    found.append(fd)
    return found


def connections_to(port: int) -> int:
    """Connections to this process's listener at 127.0.0.1:``port``, open or opening: those in
    its queue (no inode yet: only a listener at that address takes them) and those this process
    accepted (their inode is one of its descriptors'). Another process's socket at the same
    address (an older connection kept by SO_REUSEADDR, which a listener on port 0 may share)
    is not counted."""
    address = struct.unpack("=I", socket.inet_aton("127.0.0.1"))[0]  # /proc/net/tcp prints it in host order
    local = f"{address:08X}:{port:04X}"
    with open("/proc/net/tcp") as table:
        rows = [line.split() for line in table.readlines()[1:]]
    ours = _socket_inodes()
    return sum(1 for row in rows if len(row) > 9 and row[1] == local and row[3] in _OPEN_STATES
               and (row[9] == "0" or row[9] in ours))


def _socket_inodes() -> set[str]:
    """The inodes of this process's sockets (/proc/self/fd/N links to ``socket:[INODE]``)."""
    inodes = set()
    for name in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            link = os.readlink(f"/proc/self/fd/{name}")
            if link.startswith("socket:["):
                inodes.add(link[len("socket:["):-1])
    return inodes


def lock(port: int) -> bytes:
    """Set a new key on this process's listener at 127.0.0.1:``port`` for every source, on
    every descriptor of it or on none; the key (for :func:`keyed_socket`). NotLocked says why
    the system cannot (the listener is then as it was); ListenerExposed when a connection got
    in before the key."""
    if sys.platform != "linux":
        raise NotLocked(f"{sys.platform} has no TCP-MD5 keys for a prefix (Linux's TCP_MD5SIG_EXT)")
    try:
        fds = _listening(port)
    except OSError as exc:
        raise NotLocked(f"the listener cannot be found: /proc/self/fd cannot be read ({exc.strerror or exc})") from None
    if not fds:
        raise NotLocked("no listening socket of this process is at that address")
    key = secrets.token_bytes(KEY_BYTES)
    keyed: list[int] = []
    try:
        for fd in fds:
            _set_key(fd, key)
            keyed.append(fd)
    except OSError as exc:  # a kernel without TCP-MD5, or a descriptor that takes no key: none keeps one
        for fd in keyed:
            _set_key(fd, b"")
        raise NotLocked(f"the kernel refused a TCP-MD5 key ({exc.strerror or exc})") from None
    if connections_to(port):
        raise ListenerExposed(f"a program connected to 127.0.0.1:{port} (the Foxglove server's own listener) before "
                              "it was locked; start again (and look for a program that scans local ports)")
    return key


def _set_key(fd: int, key: bytes) -> None:
    """The listener's key for every source; an empty key removes it (linux/tcp.h: a key length of 0)."""
    with socket.socket(fileno=os.dup(fd)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, TCP_MD5SIG_EXT, _md5sig(key, *EVERY_SOURCE))


def keyed_socket(key: bytes) -> socket.socket:
    """A non-blocking TCP socket that signs its segments to 127.0.0.1 with ``key``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.IPPROTO_TCP, TCP_MD5SIG_EXT, _md5sig(key, "127.0.0.1", 32))
        sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    return sock
