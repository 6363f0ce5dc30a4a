"""Servers bounded by client: ``serve`` and the Foxglove front keep at most so
many idle clients of one address and cut a client that never reads; foxglove-sdk's own listener
takes no client but the front.

Each test fails on the code before: 256 idle local clients held every ``serve`` slot; a
``serve`` client that read nothing stayed connected while lines were dropped short of
``max_drops`` (a quiet server never reaches it); the front let any number of idle clients in;
and a plain connection to the SDK's listener got its WebSocket handshake, past the front."""

from __future__ import annotations

import asyncio
import base64
import errno
import json
import os
import select
import socket
import time

import pytest

from rfhoming.host.serve import ItemServer
from rfhoming.protocol.jsonable import from_dict

SAFETY_S = 60  # a hang guard on each wait, not a speed check


async def _client(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    assert json.loads(await asyncio.wait_for(reader.readline(), SAFETY_S))["kind"] == "hello"
    return reader, writer


async def _closed(reader: asyncio.StreamReader) -> list[dict]:
    """What the server sent before it closed the connection (read to EOF, bounded)."""
    try:
        rest = await asyncio.wait_for(reader.read(), SAFETY_S)
    except ConnectionError:
        rest = b""
    return [json.loads(line) for line in rest.splitlines()]


async def test_serve_keeps_at_most_max_idle_clients_of_one_address_and_never_one_that_spoke() -> None:
    server = ItemServer(max_idle=3)
    (address,) = await server.start("127.0.0.1", 0)
    port = int(address.rsplit(":", 1)[1])
    talker = await _client(port)
    talker[1].write(b"?VERSION;\r\n")
    assert json.loads(await asyncio.wait_for(talker[0].readline(), SAFETY_S))["kind"] == "version"
    idle = [await _client(port) for _ in range(3)]
    assert server.counters["disconnected_idle"] == 0
    for k in range(20):  # each new idle client closes the one idle longest, told why
        idle.append(await _client(port))
        said = await _closed(idle[k][0])
        assert said and said[-1]["kind"] == "error" and "sent no command" in said[-1]["message"]
        assert server.counters["disconnected_idle"] == k + 1 and len(server.clients) == 1 + 3
    talker[1].write(b"?VERSION;\r\n")  # the client that spoke is still served
    assert json.loads(await asyncio.wait_for(talker[0].readline(), SAFETY_S))["kind"] == "version"
    for _, writer in [talker, *idle]:
        writer.close()
    await server.close()


async def test_serve_cuts_a_client_that_takes_nothing_for_stall_s() -> None:
    """A client that never reads, on a server whose drops never reach ``max_drops``."""
    server = ItemServer(queue_lines=100_000, max_drops=10**9, stall_s=0.5)
    (address,) = await server.start("127.0.0.1", 0)
    _, writer = await _client(int(address.rsplit(":", 1)[1]))
    writer.transport.pause_reading()  # reads nothing from here on
    big = from_dict({"kind": "log_text", "node_id": 1, "seq": 0, "t_us": 0, "text": "y" * 2000})
    deadline = time.monotonic() + SAFETY_S
    while server.clients:  # lines until the kernel's buffers and its queue are full, then it stalls
        assert time.monotonic() < deadline, f"never cut: {server.counters}"
        server.publish("dev", 0.0, big)
        await asyncio.sleep(0.001)
    assert server.counters["disconnected_stalled"] == 1 and server.counters["disconnected_slow"] == 0
    writer.close()
    await server.close()


# -- the Foxglove front --------------------------------------------------------------------


def _upgrade(port: int) -> bytes:
    key = base64.b64encode(os.urandom(16)).decode()
    return (f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode()


def _handshake(port: int) -> socket.socket:
    """A WebSocket client of the view that has its 101 and sends nothing more."""
    return _handshake_and_rest(port)[0]


def _handshake_and_rest(port: int) -> tuple[socket.socket, bytes]:
    """:func:`_handshake`, and what the server sent after its 101 in the same reads."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S)
    sock.sendall(_upgrade(port))
    head = b""
    while b"\r\n\r\n" not in head:
        got = sock.recv(4096)
        assert got, f"closed during the handshake: {head!r}"
        head += got
    assert head.startswith(b"HTTP/1.1 101"), head
    return sock, head.split(b"\r\n\r\n", 1)[1]


def _until_status(sock: socket.socket, rest: bytes) -> dict:
    """Read the server's WebSocket frames (unmasked, RFC 6455 §5.2) until a status message."""
    def take(n: int) -> bytes:
        nonlocal rest
        while len(rest) < n:
            got = sock.recv(65536)
            assert got, "the view closed the connection"
            rest += got
        taken, rest = rest[:n], rest[n:]
        return taken

    while True:
        opcode, length = take(2)
        length &= 0x7F
        if length >= 126:
            length = int.from_bytes(take(2 if length == 126 else 8), "big")
        payload = take(length)
        if opcode == 0x81 and (message := json.loads(payload)).get("op") == "status":
            return message


def _masked_text(payload: bytes) -> bytes:
    """One WebSocket text frame as a client sends it (masked, RFC 6455 §5.3); payload < 126 bytes."""
    mask = os.urandom(4)
    return bytes([0x81, 0x80 | len(payload)]) + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def _cut(sock: socket.socket) -> bool:
    """True once the peer closed the connection (reads what it still sends first; bounded)."""
    deadline = time.monotonic() + SAFETY_S
    while time.monotonic() < deadline:
        try:
            if not sock.recv(65536):
                return True
        except ConnectionError:
            return True
        except TimeoutError:
            continue
    return False


@pytest.fixture
def view():
    pytest.importorskip("foxglove")
    from rfhoming.host.foxglove_view import FoxgloveView

    view = FoxgloveView(port=0)
    yield view
    view.close()


def test_the_front_keeps_at_most_max_idle_clients_of_one_address(view) -> None:
    from rfhoming.host.foxglove_front import MAX_IDLE

    talker, rest = _handshake_and_rest(view.front.port)
    talker.sendall(_masked_text(b'{"op":"subscribe","subscriptions":[{"id":1,"channelId":999999}]}'))
    _until_status(talker, rest)  # the SDK's answer (no such channel): the front passed it on, idle no more
    idle = [_handshake(view.front.port) for _ in range(MAX_IDLE)]
    for k in range(5):  # each new idle client closes the one idle longest
        idle.append(_handshake(view.front.port))
        assert _cut(idle[k]), f"idle client {k} still connected"
    assert view.front.counters["idle_closed"] == 5
    talker.settimeout(0.0)  # the client that spoke is still connected (nothing closed it)
    with pytest.raises(BlockingIOError):
        while talker.recv(65536):
            pass
    for sock in [talker, *idle]:
        sock.close()


def _md5_lockable() -> bool:
    """Whether this system takes a listener's TCP-MD5 key (Linux with CONFIG_TCP_MD5SIG, a
    container that allows it); where it does not, the view warns and stays open (no test)."""
    from rfhoming.host.loopback_key import NotLocked, lock

    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        try:
            lock(listener.getsockname()[1])
        except NotLocked:
            return False
        return True


needs_md5 = pytest.mark.skipif(not os.path.exists("/proc/net/netstat") or not _md5_lockable(),
                               reason="a kernel that takes TCP-MD5 keys (and counts their drops) is needed")


def _md5_drops() -> int:
    """Linux's count of TCP segments dropped for want of a TCP-MD5 signature."""
    with open("/proc/net/netstat") as table:
        lines = table.read().splitlines()
    for names, values in zip(lines[::2], lines[1::2], strict=True):
        if names.startswith("TcpExt:"):
            return int(dict(zip(names.split(), values.split(), strict=True))["TCPMD5NotFound"])
    raise AssertionError("no TcpExt line")


def _refused(port: int, source: str = "127.0.0.1") -> None:
    """A plain connection from ``source`` to 127.0.0.1:``port`` never opens: the kernel drops
    its SYN (and counts it)."""
    before = _md5_drops()
    direct = socket.socket()
    direct.setblocking(False)
    direct.bind((source, 0))
    assert direct.connect_ex(("127.0.0.1", port)) in (0, errno.EINPROGRESS)
    deadline = time.monotonic() + SAFETY_S
    while _md5_drops() == before:  # until the kernel has seen its SYN and dropped it
        _, writable, _ = select.select([], [direct], [], 0.05)
        if writable:
            error = direct.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            pytest.fail(f"a plain connection from {source} reached the listener directly (error {error})")
        assert time.monotonic() < deadline, "the kernel saw no SYN"
    _, writable, _ = select.select([], [direct], [], 0)
    assert not writable
    direct.close()


@needs_md5
def test_the_sdks_listener_takes_no_connection_but_the_fronts(view) -> None:
    """A plain connection to the SDK's port never opens, while the front's signed connections
    carry a client's handshake as before."""
    _refused(view.server.port)
    _handshake(view.front.port).close()  # through the front, as before


def _lan_address() -> str:
    """This machine's own address towards other machines (found by the route alone: nothing is
    sent), or the test is skipped."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("192.0.2.1", 9))
        except OSError:
            pytest.skip("this machine has no route off loopback")
        address = str(probe.getsockname()[0])
    if address.startswith("127."):
        pytest.skip("this machine has no address but loopback")
    return address


@needs_md5
def test_a_local_program_bound_to_the_lan_address_is_refused_too() -> None:
    """127.0.0.1 takes connections from this machine's own LAN address as well: a key asked only
    of 127.0.0.0/8 let such a program in."""
    from rfhoming.host.loopback_key import lock

    source = _lan_address()
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        assert lock(listener.getsockname()[1]) is not None
        _refused(listener.getsockname()[1], source)


@needs_md5
def test_a_connection_that_came_before_the_key_is_found() -> None:
    """The instant between the SDK's listen and its key: a connection made in it is looked for."""
    from rfhoming.host.loopback_key import ListenerExposed, keyed_socket, lock

    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        early = socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S)
        with pytest.raises(ListenerExposed, match=f"127.0.0.1:{port}"):
            lock(port)
        early.close()
    with socket.socket() as listener:  # and without one: only a keyed connection gets in
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        key = lock(listener.getsockname()[1])
        assert key is not None
        signed = keyed_socket(key)
        signed.setblocking(True)
        signed.settimeout(SAFETY_S)
        signed.connect(listener.getsockname())
        accepted, _ = listener.accept()
        accepted.close()
        signed.close()


def test_a_system_without_proc_leaves_the_listener_unlocked_and_says_so(monkeypatch) -> None:
    """No /proc/self/fd (a sandbox): the listener cannot be found, so lock() says so (the view
    warns with it) instead of raising an OSError out of the Foxglove view."""
    from rfhoming.host import loopback_key

    def no_proc(path: str) -> list[str]:
        raise FileNotFoundError(2, "No such file or directory", path)

    monkeypatch.setattr(loopback_key.os, "listdir", no_proc)
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        with pytest.raises(loopback_key.NotLocked, match=r"/proc/self/fd cannot be read \(No such file or directory\)"):
            loopback_key.lock(listener.getsockname()[1])
