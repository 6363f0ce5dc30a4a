"""The serve protocol (docs/protocol.md, "serve: the JSON-lines protocol"), version 1.

In-process first: the hello, gpsd's commands and ours, watch filters, poll, error lines, device
states, bounds. Then two clients rfhoming did not write the protocol for: a gpsd-style client
written here from the documentation with a plain ``socket``, and gpsd's own Python client
(Debian's python3-gps), each against ``rfhoming serve`` on an emulated XPLR-AOA and base whose
link the test unplugs. Before protocol 1 the server had no version, ignored every command, sent
no error for garbage, fell silent through an unplug and sent the AT set-up chatter to everyone."""

from __future__ import annotations

import asyncio
import json
import random
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import rigs
from hypothesis import given, settings
from hypothesis import strategies as st

from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.emulator.threaded import EmulatorThread
from rfhoming.host.drivers.aoa import AoaDriver
from rfhoming.host.ports import HostPort
from rfhoming.host.drivers.serve_client import ServeDriver
from rfhoming.host.serve import (
    BACKLOG_LINES,
    CHATTER,
    MAX_COMMAND,
    MAX_LINE_COMMANDS,
    NOT_POLLED,
    READ_CHUNK,
    ItemServer,
    _Client,
)
from rfhoming.protocol.jsonable import as_dict, from_dict
from rfhoming.protocol.uconnect import UConnectDecoder

GOLDEN = Path(__file__).parent / "golden"
SAFETY_S = 60  # a hang guard on each wait, not a speed check
SESSION = list(UConnectDecoder().feed((GOLDEN / "xplr_aoa_session.raw").read_bytes()))
ANGLES = [i for i in SESSION if i.kind == "angle"]
TALK = [i for i in SESSION if i.kind in CHATTER]


def aoa_driver(name: str = "aoa") -> AoaDriver:
    """A driver whose state the test sets by hand (its port is never opened)."""
    return AoaDriver(HostPort(f"/dev/rfhoming-test-{name}", name=name))


class Peer:
    """An in-process client: lines as dicts, each wait bounded by SAFETY_S."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    @classmethod
    async def connect(cls, server: ItemServer) -> Peer:
        if not server._servers:
            await server.start("127.0.0.1", 0)
        port = server._servers[0].sockets[0].getsockname()[1]
        return cls(*await asyncio.open_connection("127.0.0.1", port))

    async def line(self) -> dict:
        raw = await asyncio.wait_for(self.reader.readline(), SAFETY_S)
        assert raw.endswith(b"\r\n"), raw  # gpsd ends its lines so
        return json.loads(raw)

    async def until(self, kind: str) -> list[dict]:
        """Lines up to and with the first of ``kind``."""
        got = [await self.line()]
        while got[-1]["kind"] != kind:
            got.append(await self.line())
        return got

    async def send(self, text: str | bytes) -> None:
        self.writer.write(text.encode() if isinstance(text, str) else text)
        await self.writer.drain()

    def close(self) -> None:
        self.writer.close()


async def test_hello_carries_the_protocol_version_and_each_device_with_its_state() -> None:
    aoa = aoa_driver()
    server = ItemServer(drivers=[aoa])
    peer = await Peer.connect(server)
    hello = await peer.line()
    assert hello["kind"] == "hello" and hello["class"] == "VERSION"
    assert hello["proto"] == {"major": 1, "minor": 0} and (hello["proto_major"], hello["proto_minor"]) == (1, 0)
    assert hello["release"] and hello["server"] == "rfhoming"
    assert hello["devices"] == [{"class": "DEVICE", "device": "aoa", "driver": "xplr-aoa",
                                 "path": "/dev/rfhoming-test-aoa", "state": "disconnected"}]
    assert hello["watch"] == {"kind": "watch", "class": "WATCH", "enable": True, "json": True, "chatter": False}
    peer.close()
    await server.close()


async def test_gpsd_commands_get_gpsd_replies() -> None:
    """gpsd_json(5): ?VERSION; ?DEVICES; ?WATCH=...; (DEVICES then WATCH) and ?POLL;, several on a line."""
    aoa = aoa_driver()
    server = ItemServer(drivers=[aoa])
    peer = await Peer.connect(server)
    await peer.line()
    await peer.send("?VERSION;\n")
    version = await peer.line()
    assert (version["class"], version["proto_major"], version["proto_minor"]) == ("VERSION", 1, 0)
    assert version["rev"] and version["release"]
    await peer.send('?WATCH={"enable":true,"json":true};?DEVICES;\r\n')
    devices, watch, again = await peer.line(), await peer.line(), await peer.line()
    assert devices["class"] == again["class"] == "DEVICES" and devices["devices"][0]["path"] == "/dev/rfhoming-test-aoa"
    assert watch["class"] == "WATCH" and watch["enable"] is True and watch["json"] is True
    server.publish("aoa", 1.0, ANGLES[0])
    assert (await peer.line())["kind"] == "angle"
    await peer.send("?POLL;\n")
    poll = await peer.line()
    assert poll["class"] == "POLL" and poll["time"].endswith("Z") and isinstance(poll["active"], int)
    assert [from_dict(i) for i in poll["items"]] == [ANGLES[0]]
    await peer.send('?WATCH={"enable":false};\n')
    assert (await peer.until("watch"))[-1]["enable"] is False
    server.publish("aoa", 2.0, ANGLES[1])
    await peer.send("?VERSION;\n")
    assert (await peer.line())["kind"] == "version"  # nothing came between: it no longer watches
    peer.close()
    await server.close()


async def test_watch_filters_by_device_and_kind_and_sends_chatter_only_when_asked() -> None:
    server = ItemServer(drivers=[aoa_driver("aoa"), aoa_driver("anchor")])
    default, chatty, picky = [await Peer.connect(server) for _ in range(3)]
    for peer in (default, chatty, picky):
        await peer.line()
    await chatty.send('{"cmd": "watch", "chatter": true}\n')
    assert (await chatty.until("watch"))[-1]["chatter"] is True
    await picky.send('{"cmd": "watch", "devices": ["/dev/rfhoming-test-aoa"], "kinds": ["angle"]}\n')
    # a path names the device too, as gpsd's "device" does
    watch = (await picky.until("watch"))[-1]
    assert watch["devices"] == ["aoa"] and watch["kinds"] == ["angle"]
    for item in SESSION:
        server.publish("aoa", 1.0, item)
        server.publish("anchor", 1.0, item)
    got = []
    for peer in (default, chatty, picky):
        await peer.send("?VERSION;\n")  # its answer comes after what was queued before
        got.append(await peer.until("version"))
        peer.close()
    await server.close()
    items = [[r for r in g if "n" in r] for g in got]
    assert {r["kind"] for r in items[0]}.isdisjoint(CHATTER) and len(items[0]) == 2 * (len(SESSION) - len(TALK))
    assert len(items[1]) == 2 * len(SESSION)
    assert {(r["device"], r["kind"]) for r in items[2]} == {("aoa", "angle")} and len(items[2]) == len(ANGLES)


async def test_poll_answers_the_latest_reading_of_each_kind_of_each_watched_device() -> None:
    server = ItemServer(drivers=[aoa_driver("aoa"), aoa_driver("anchor")])
    peer = await Peer.connect(server)
    await peer.line()
    await peer.send('{"cmd": "watch", "enable": false}\n')
    await peer.until("watch")
    await peer.send('{"cmd": "poll"}\n')
    assert (await peer.line())["items"] == []  # nothing read yet
    for k, item in enumerate(SESSION):
        server.publish("aoa" if k % 2 else "anchor", float(k), item)
    await peer.send('{"cmd": "poll"}\n')
    poll = await peer.line()
    latest = {(r["device"], r["kind"]): r for r in poll["items"]}
    readings = {("aoa" if k % 2 else "anchor", i.kind) for k, i in enumerate(SESSION) if i.kind not in NOT_POLLED}
    assert set(latest) == readings and ("aoa", "angle") in readings  # the chatter is no reading
    for (device, kind), record in latest.items():
        last = max(k for k, i in enumerate(SESSION) if i.kind == kind and (k % 2 == 1) == (device == "aoa"))
        assert record["t"] == float(last) and from_dict(record) == SESSION[last]
    await peer.send('{"cmd": "watch", "device": "anchor"}\n{"cmd": "poll"}\n')
    poll = (await peer.until("poll"))[-1]
    assert [r["device"] for r in poll["items"]] == ["anchor"]
    peer.close()
    await server.close()


BAD = [
    (b"hello there", "not a command"),
    (b"?FOO;", "unknown command ?FOO"),
    (b'{"cmd": "subscribe"}', "unknown command 'subscribe'"),
    (b'{"cmd": "watch", "enable": tru', "not JSON"),
    (b"[1, 2]", "not a command"),  # JSON, but no object
    (b'{"enable": true}', 'object with "cmd"'),
    (b'?WATCH={"enable":"yes"};', "enable is true or false"),
    (b'?WATCH={"enable":true,"nmea":true};', "nmea is not offered"),
    (b'?WATCH=[1];', "takes a JSON object"),
    (b'{"cmd": "watch", "devices": ["gps0"]}', "no device 'gps0'; the devices are aoa"),
    (b'{"cmd": "watch", "kinds": "angle"}', "kinds is a list"),
    (b'{"cmd": "watch", "colour": "red"}', "unknown field 'colour'"),
    (b"\xff\xfe?POLL;", "UTF-8"),
    (b"?" + b"W" * (MAX_COMMAND + 10), f"at most {MAX_COMMAND} bytes"),
    (b'{"cmd": "watch", "enable": ' + b"[" * 2000, "not JSON"),  # deeper than json's recursion limit
    (b"?WATCH=" + b"[" * 2000 + b";", "takes a JSON object"),
    (b"?POLL;" * (MAX_LINE_COMMANDS + 1), f"at most {MAX_LINE_COMMANDS} commands"),
]


async def test_what_is_not_understood_gets_an_error_line_and_the_connection_stays_up() -> None:
    server = ItemServer(drivers=[aoa_driver()])
    peer = await Peer.connect(server)
    await peer.line()
    for line, why in BAD:
        await peer.send(line + b"\n")
        error = await peer.line()
        assert (error["kind"], error["class"]) == ("error", "ERROR") and why in error["message"], (line, error)
    await peer.send('?WATCH={"enable":true,"pps":true,"scaled":false,"raw":0};\n')  # gpsd's harmless fields pass
    assert (await peer.until("watch"))[-1]["enable"] is True
    await peer.send("?VERSION;\n")
    assert (await peer.line())["kind"] == "version"
    assert server.counters["bad_commands"] == len(BAD) and server.counters["disconnected_input"] == 0
    peer.close()
    await server.close()


async def test_ten_kilobytes_of_garbage_get_a_bounded_number_of_error_lines() -> None:
    """A hostile client's 10 kB of garbage gets error lines, at most one per bad line and at most
    ERRORS_PENDING waiting at a time (the rest counted in ``suppressed``), nothing held."""
    server = ItemServer(drivers=[aoa_driver()])
    peer = await Peer.connect(server)
    await peer.line()
    garbage = random.Random(7).randbytes(10_000) + b"\n"
    bad_lines = sum(1 for line in garbage.split(b"\n")[:-1] if line.strip())
    await peer.send(garbage + b"?VERSION;\n")
    got = await peer.until("version")
    errors = [g for g in got if g["kind"] == "error"]
    assert errors and len(errors) <= bad_lines
    assert len(errors) + sum(e.get("suppressed", 0) for e in errors) == server.counters["bad_commands"]
    (client,) = server.clients
    assert client.partial == b"" and client.errors_waiting == 0 and len(client.queue) == 0
    assert client.unheard == sum(len(line) + 1 for line in garbage.split(b"\n")[:-1] if line.strip())
    assert not client.closed
    peer.close()
    await server.close()


class _Writer:
    def get_extra_info(self, name: str) -> tuple[str, int]:
        return ("127.0.0.1", 1)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([b"?POLL;", b'{"cmd": "version"}', b"junk", b"?NOPE;", b"",
                                 b"x" * (MAX_COMMAND + 1), b'?WATCH={"chatter":true};?DEVICES;']), max_size=12),
       st.lists(st.integers(1, 3 * MAX_COMMAND), max_size=8))
def test_command_lines_are_understood_alike_however_the_bytes_come(lines: list[bytes], cuts: list[int]) -> None:
    """A command is carried out, and garbage refused, the same in one piece or cut anywhere,
    and what a client has half sent is never more than a command line."""
    data = b"".join(line + b"\n" for line in lines)

    def outcome(chunks: list[bytes]) -> tuple:
        server = ItemServer(drivers=[aoa_driver()])
        client = _Client(_Writer(), 1000)
        for chunk in chunks:
            server._feed(client, chunk)
            assert len(client.partial) <= MAX_COMMAND
        return client.commands, client.errors, client.unheard, [json.loads(bytes(q))["kind"] for q in client.queue]

    points = sorted({c % (len(data) + 1) for c in cuts})
    pieces = [data[a:b] for a, b in zip([0, *points], [*points, len(data)])]
    assert outcome(pieces) == outcome([data])


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                    max_leaves=10)
WATCH_KEYS = st.sampled_from(["enable", "json", "devices", "device", "kinds", "chatter", "nmea", "raw", "pps", "x"])


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=120),
                 st.dictionaries(WATCH_KEYS, JSON, max_size=5).map(lambda d: b"?WATCH=" + json.dumps(d).encode() + b";"),
                 st.dictionaries(WATCH_KEYS, JSON, max_size=5).map(
                     lambda d: json.dumps({"cmd": "watch", **d}).encode()),
                 st.text(max_size=60).map(lambda t: ("?" + t).encode())))
def test_any_command_line_is_carried_out_or_refused_with_one_error_and_nothing_else(line: bytes) -> None:
    """Whatever a client sends, the server answers or refuses it in words; nothing escapes."""
    server = ItemServer(drivers=[aoa_driver()])
    client = _Client(_Writer(), 1000)
    understood = server._on_command_line(client, line)
    assert understood == (client.errors == 0) and client.errors <= 1
    kinds = [json.loads(bytes(q))["kind"] for q in client.queue]
    assert kinds == ["error"] if client.errors else set(kinds) <= {"devices", "watch", "poll", "version"}
    assert isinstance(client.watch.enable, bool) and (client.watch.devices is None or client.watch.devices <= {"aoa"})


async def test_device_states_follow_the_driver_through_set_up_reboot_and_unplug() -> None:
    aoa = aoa_driver()
    server = ItemServer(drivers=[aoa])
    peer = await Peer.connect(server)
    assert (await peer.line())["devices"][0]["state"] == "disconnected"

    async def state() -> str:
        line = await peer.line()
        assert line["kind"] == "device" and line["class"] == "DEVICE" and line["device"] == "aoa", line
        return line["state"]

    aoa.connected.set()
    aoa.state = "setting_up"
    assert await state() == "connected"
    aoa.state = "streaming"  # the AoA driver's word for set up
    assert await state() == "ready"
    server.publish("aoa", 1.0, ANGLES[0])
    assert await state() == "streaming"  # told before the first reading
    assert (await peer.line())["kind"] == "angle"
    server.publish("aoa", 1.1, ANGLES[1])
    assert (await peer.line())["kind"] == "angle"

    aoa.state = "setting_up"  # +STARTUP: the board rebooted
    assert await state() == "connected"
    aoa.state = "streaming"
    assert await state() == "ready"

    aoa.connected.clear()  # unplugged
    aoa.state = "disconnected"
    assert await state() == "disconnected"
    aoa.counters["reconnects"] += 1
    aoa.connected.set()
    aoa.state = "streaming"  # back and set up again before the server looked
    assert [await state() for _ in range(2)] == ["connected", "ready"]

    aoa.counters["reconnects"] += 1  # an unplug shorter than a look is still told
    assert [await state() for _ in range(3)] == ["disconnected", "connected", "ready"]
    peer.close()
    await server.close()


async def test_a_client_that_sends_nothing_gets_every_reading_as_before() -> None:
    server = ItemServer(drivers=[aoa_driver()])
    peer = await Peer.connect(server)
    await peer.line()
    readings = (ANGLES * 50)[:50]
    for k, item in enumerate(readings):
        server.publish("aoa", float(k), item)
    got = [await peer.line() for _ in range(50)]
    assert [from_dict(r) for r in got] == readings and [r["n"] for r in got] == list(range(1, 51))
    peer.close()
    await server.close()


async def test_a_client_that_sends_too_much_garbage_is_still_cut_off() -> None:
    server = ItemServer(drivers=[aoa_driver()], max_input=20_000)
    peer = await Peer.connect(server)
    await peer.line()
    for _ in range(100):
        try:
            await peer.send(b"junk\n" * 1000)
        except ConnectionError:
            break
        if server.counters["disconnected_input"]:
            break
    try:
        rest = await asyncio.wait_for(peer.reader.read(), SAFETY_S)
    except ConnectionError:
        rest = b""
    assert server.counters["disconnected_input"] == 1 and not server.clients
    lines = [json.loads(line) for line in rest.splitlines()]
    assert lines and all(r["kind"] == "error" for r in lines) and "disconnecting" in lines[-1]["message"]
    peer.close()
    await server.close()


class _Port:
    name = spec = "serve://test"
    counters: dict = {}

    def __init__(self) -> None:
        self.written = b""

    def write(self, data: bytes) -> None:
        self.written += data


async def test_serve_driver_asks_for_its_device_and_takes_protocol_lines_as_such() -> None:
    port = _Port()
    driver = ServeDriver(port, device="aoa")
    await driver.session()
    assert json.loads(port.written) == {"cmd": "watch", "devices": ["aoa"]}
    seen = []
    driver.listeners.append(lambda device, t, item: seen.append(item))
    server = ItemServer(drivers=[aoa_driver()])
    lines = [server._hello(), {"kind": "device", "class": "DEVICE", "device": "aoa", "state": "ready"},
             {"kind": "devices", "class": "DEVICES", "devices": []}, {"kind": "watch", "class": "WATCH"},
             {"kind": "poll", "class": "POLL", "items": []}, {"kind": "error", "class": "ERROR", "message": "x"},
             {"n": 1, "device": "aoa", "t": 1.0, **as_dict(ANGLES[0])},
             {"n": 2, "device": "other", "t": 1.0, **as_dict(ANGLES[0])}]
    driver.on_chunk(b"".join((json.dumps(r) + "\r\n").encode() for r in lines), 0.0)
    assert driver.counters["bad_lines"] == 0 and driver.counters["server_errors"] == 1
    assert driver.devices["aoa"]["state"] == "ready" and driver.hello["proto_major"] == 1
    assert seen == [ANGLES[0]]


async def test_error_lines_come_in_order_with_replies_and_items() -> None:
    """Before: waiting error lines were written ahead of the queue (version after the error)."""
    server = ItemServer(drivers=[aoa_driver()])
    peer = await Peer.connect(server)
    await peer.line()
    server.publish("aoa", 1.0, ANGLES[0])
    await peer.send("?VERSION;\n?NOPE;\n?DEVICES;\nhello?\n")
    got = [await peer.line() for _ in range(5)]
    assert [r["kind"] for r in got] == ["angle", "version", "error", "devices", "error"]
    assert "?NOPE" in got[2]["message"] and "not a command" in got[4]["message"]
    peer.close()
    await server.close()


async def test_a_client_that_half_closes_after_its_commands_gets_their_replies() -> None:
    """As ncat, ``nc -N`` and socat do: the commands, then shutdown(SHUT_WR). Before: the
    EOF dropped the client with its replies unsent."""
    server = ItemServer(drivers=[aoa_driver()])
    (address,) = await server.start("127.0.0.1", 0)
    loop = asyncio.get_running_loop()
    with socket.socket() as sock:
        sock.setblocking(False)
        await loop.sock_connect(sock, ("127.0.0.1", int(address.rsplit(":", 1)[1])))
        await loop.sock_sendall(sock, b"?VERSION;?DEVICES;\nnonsense\n")
        sock.shutdown(socket.SHUT_WR)
        data = b""
        while chunk := await asyncio.wait_for(loop.sock_recv(sock, 65536), SAFETY_S):
            data += chunk
    assert [json.loads(line)["kind"] for line in data.splitlines()] == ["hello", "version", "devices", "error"]
    assert not server.clients
    await server.close()


@pytest.mark.skipif(shutil.which("socat") is None, reason="needs socat (Debian's socat)")
async def test_socat_sending_its_input_then_eof_gets_the_replies() -> None:
    """The same with a client rfhoming did not write: socat ends its side after stdin's end."""
    server = ItemServer(drivers=[aoa_driver()])
    (address,) = await server.start("127.0.0.1", 0)
    socat = await asyncio.create_subprocess_exec("socat", "-", "TCP:" + address.removeprefix("tcp://"),
                                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    out, _ = await asyncio.wait_for(socat.communicate(b"?VERSION;?DEVICES;\n"), SAFETY_S)
    assert [json.loads(line)["kind"] for line in out.splitlines()] == ["hello", "version", "devices"]
    await server.close()


async def test_the_hello_is_counted_in_the_queue() -> None:
    """Before: the hello went round the queue's count, which sat at minus its length after."""
    server = ItemServer(drivers=[aoa_driver()])
    peer = await Peer.connect(server)
    await peer.line()
    (client,) = server.clients
    assert client.queued_bytes == 0 and not client.queue and client.sent == 1
    peer.close()
    await server.close()


class _CountingReader(asyncio.StreamReader):
    """A StreamReader that notes, at each read, how often another task has run."""

    def __init__(self, ticks: list[int]) -> None:
        super().__init__()
        self.ticks, self.at = ticks, []

    async def read(self, n: int = -1) -> bytes:
        self.at.append(self.ticks[0])
        return await super().read(n)


async def test_a_read_of_many_commands_lets_other_tasks_run_between_chunks() -> None:
    """StreamReader.read returns without yielding while its buffer holds data; before, a client
    that sent a lot held the loop (and so the devices) for all of it. Counted, not timed."""
    server = ItemServer(drivers=[aoa_driver()])
    client = _Client(_Writer(), 1000)
    ticks = [0]
    reader = _CountingReader(ticks)
    reader.feed_data(b"\n" * (8 * READ_CHUNK))  # blank lines: understood, and no replies to wait for
    task = asyncio.create_task(server._read_commands(client, reader))
    for _ in range(10_000):  # turns of the loop, a hang guard
        if len(reader.at) > 8:  # the ninth read waits for more
            break
        ticks[0] += 1
        await asyncio.sleep(0)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert len(reader.at) == 9 and all(b > a for a, b in zip(reader.at, reader.at[1:])), reader.at


async def test_commands_wait_while_the_clients_queue_is_full_of_replies() -> None:
    """Back-pressure: a client's commands are carried out only while its queue is short, so its
    replies come no faster than it takes them. Before: every command read was carried out at once."""
    server = ItemServer(drivers=[aoa_driver()])
    server.publish("aoa", 1.0, ANGLES[0])  # a reading for the polls to carry
    client = _Client(_Writer(), 1000)
    reader = asyncio.StreamReader()
    polls = 2000
    reader.feed_data(b"?POLL;\n" * polls)
    task = asyncio.create_task(server._read_commands(client, reader))
    for _ in range(100):  # turns of the loop: no I/O here, so far more than it takes to stop
        await asyncio.sleep(0)
    assert client.commands == len(client.queue) == BACKLOG_LINES + 1  # then it waits
    longest = 0
    for _ in range(100 * polls):  # the client takes its lines; the rest of its commands follow
        if client.commands == polls:
            break
        longest = max(longest, len(client.queue))
        if client.queue:
            server._take(client)
        await asyncio.sleep(0)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert client.commands == polls and longest <= BACKLOG_LINES + 1 and client.dropped_total == 0


async def test_a_reply_is_not_built_when_the_queue_has_no_room(monkeypatch) -> None:
    """Before: each poll's reply was encoded, then found not to fit and dropped."""
    from rfhoming.host import serve

    server = ItemServer(queue_lines=10, drivers=[aoa_driver()])
    server.publish("aoa", 1.0, ANGLES[0])
    client = _Client(_Writer(), 10)
    for _ in range(10):
        server._on_command_line(client, b"?VERSION;")
    built = []
    monkeypatch.setattr(serve, "_line", lambda record: built.append(record) or b"x\r\n")
    assert server._on_command_line(client, b"?POLL;?POLL;?DEVICES;")
    assert built == [] and client.dropped == 3 and client.commands == 13
    server._take(client)  # the dropped notice
    server._take(client)  # a line: room for one
    built.clear()
    server._on_command_line(client, b"?POLL;")
    assert [r["kind"] for r in built] == ["poll"]


def test_serve_driver_counts_a_device_list_that_is_no_list_as_a_bad_line() -> None:
    """Before: TypeError out of on_chunk for a hello or devices line whose devices is a number."""
    driver = ServeDriver(_Port())
    lines = [{"kind": "hello", "devices": 5}, {"kind": "devices", "devices": {"aoa": 1}},
             {"kind": "devices", "devices": "aoa"}, {"kind": "dropped", "count": "many"},
             {"kind": "dropped", "count": [1]}, {"kind": "devices", "devices": [{"device": "aoa", "state": "ready"}]}]
    driver.on_chunk(b"".join((json.dumps(r) + "\r\n").encode() for r in lines), 0.0)
    assert driver.counters["bad_lines"] == 5 and driver.counters["server_dropped"] == 0
    assert driver.devices == {"aoa": {"device": "aoa", "state": "ready"}} and driver.hello == {}


# -- against `rfhoming serve`, with clients rfhoming did not write the protocol for -----------------
@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[tuple[int, EmulatorThread]]:
    """``rfhoming serve`` on the emulated XPLR-AOA (named aoa) and base; its TCP port."""
    world = EmulatorThread(Emulator(load("s0-open", seed=3, target=(3.0, 2.0)), transport="pty", seed=3, speed=2.0,
                                    link_dir=tmp_path_factory.mktemp("kit")), SAFETY_S)
    try:
        with rigs.Child([*rigs.RFHOMING, "serve", f"xplr-aoa:{world.endpoints['aoa']['path']},name=aoa",
                         f"base:{world.endpoints['base']['path']},name=base", "--port", "0"]) as server:
            address = server.json_line(SAFETY_S, "the listening line")["address"]
            yield int(address.rsplit(":", 1)[1]), world
    finally:
        world.close()


class GpsdStyleClient:
    """A gpsd-style client from docs/protocol.md alone: a blocking socket, CR LF lines."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S)
        self.buffer = b""

    def send(self, line: str) -> None:
        self.sock.sendall(line.encode() + b"\n")

    def line(self) -> dict:
        while b"\r\n" not in self.buffer:
            data = self.sock.recv(65536)
            assert data, "the server closed the connection"
            self.buffer += data
            assert len(self.buffer) < 1 << 20, f"no CR LF line in {self.buffer[:200]!r}..."
        line, self.buffer = self.buffer.split(b"\r\n", 1)
        return json.loads(line)

    def until(self, test, what: str) -> list[dict]:
        got = [self.line()]
        deadline = time.monotonic() + SAFETY_S
        while not test(got[-1]):
            assert time.monotonic() < deadline, f"no {what} in {got[-5:]}"
            got.append(self.line())
        return got

    def close(self) -> None:
        self.sock.close()


@pytest.mark.slow
def test_a_gpsd_style_client_through_an_unplug(served) -> None:
    port, world = served
    client, chatty = GpsdStyleClient(port), GpsdStyleClient(port)
    try:
        hello = client.line()
        assert hello["class"] == "VERSION" and hello["proto_major"] == 1
        assert {d["device"]: d["driver"] for d in hello["devices"]} == {"aoa": "xplr-aoa", "base": "base"}
        chatty.line()
        chatty.send('{"cmd": "watch", "devices": ["aoa"], "kinds": [], "chatter": true}')
        client.send("?VERSION;")
        assert client.until(lambda r: r["kind"] == "version", "version")[-1]["proto_minor"] == 0
        client.send('?WATCH={"enable":true,"json":true,"device":"aoa"};')
        before = client.until(lambda r: r.get("class") == "WATCH", "watch reply")
        assert before[-2]["class"] == "DEVICES" and before[-1]["devices"] == ["aoa"]
        streaming = client.until(lambda r: r.get("state") == "streaming" or r.get("kind") == "angle", "angles")
        angles = client.until(lambda r: r["kind"] == "angle", "an angle")  # the AoA streams
        client.send("?POLL;")
        replies = client.until(lambda r: r["kind"] == "poll", "poll reply")
        poll = replies[-1]
        assert {i["device"] for i in poll["items"]} == {"aoa"} and poll["active"] >= 1
        last_seen = max(r["n"] for r in streaming + angles + replies if r.get("kind") == "angle")
        assert max(i["n"] for i in poll["items"] if i["kind"] == "angle") >= last_seen  # the latest
        client.send("this is not a command")
        assert "not a command" in client.until(lambda r: r["kind"] == "error", "error")[-1]["message"]

        link = world.emulator.device("aoa").link
        world.call(link.unplug())
        after = client.until(lambda r: r.get("state") == "disconnected", "disconnected")
        assert {r["device"] for r in after if "n" in r} <= {"aoa"}
        world.call(link.replug())
        back = client.until(lambda r: r.get("state") == "streaming", "streaming again")
        states = [r["state"] for r in back if r["kind"] == "device"]
        assert states == ["connected", "ready", "streaming"]
        assert not [r for r in before + streaming + angles + after + back if r["kind"] in CHATTER]
        client.until(lambda r: r["kind"] == "angle", "an angle after the replug")

        chatty.until(lambda r: r["kind"] == "watch", "its watch reply")
        talk = chatty.until(lambda r: r.get("state") == "streaming" and r["t"] >= back[-1]["t"], "chatter")
        kinds = {r["kind"] for r in talk if "n" in r}
        assert kinds and kinds <= CHATTER and {"echo", "final"} <= kinds  # the set-up dialogue, asked for
    finally:
        client.close()
        chatty.close()


GPS_CLIENT = r"""
import json, sys
from gps import gps, WATCH_ENABLE, WATCH_JSON
session = gps(host="127.0.0.1", port=int(sys.argv[1]), mode=WATCH_ENABLE | WATCH_JSON)
seen = []
for report in session:  # gpsd's standard loop, dispatching on class as its clients do
    if report['class'] == 'TPV':
        continue
    seen.append(report['class'])
    if {'ANGLE', 'ODOMETRY'} <= set(seen) and 'POLL' not in seen:  # ask once both kinds have come
        session.send("?POLL;")
    if report['class'] == 'POLL':
        break
print(json.dumps({"seen": seen, "version": dict(session.version.__dict__),
                  "poll": [i["device"] for i in report["items"]], "poll_classes": [i["class"] for i in report["items"]]}))
"""


def gpsd_python() -> str | None:
    """Debian's python3 with gpsd's own client module (python3-gps; .ci/run installs it)."""
    python = shutil.which("python3", path="/usr/bin")
    if python and subprocess.run([python, "-c", "import gps"], capture_output=True, timeout=120).returncode == 0:
        return python
    return None


@pytest.mark.slow
@pytest.mark.skipif(gpsd_python() is None, reason="needs python3-gps (gpsd's Python client) for /usr/bin/python3")
def test_gpsds_own_python_client_reads_the_server(served) -> None:
    port, _ = served
    done = subprocess.run([gpsd_python(), "-c", GPS_CLIENT, str(port)], capture_output=True, text=True,
                          timeout=SAFETY_S)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    seen = out["seen"]
    assert seen[0] == "VERSION" and seen[seen.index("DEVICES") + 1] == "WATCH"  # the hello; ?WATCH's replies
    assert out["version"]["proto_major"] == 1 and out["version"]["class"] == "VERSION"
    assert {"ANGLE", "ODOMETRY"} <= set(seen) and seen[-1] == "POLL" and set(out["poll"]) <= {"aoa", "base"}
    assert "ANGLE" in out["poll_classes"]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gpspipe") is None, reason="needs gpspipe (Debian's gpsd-clients)")
def test_gpspipe_prints_every_line_with_a_class(served) -> None:
    """gpsd's own ``gpspipe -w``: it watches in JSON and prints each line as it comes."""
    port, _ = served
    done = subprocess.run(["gpspipe", "-w", "-n", "60", f"127.0.0.1:{port}"], capture_output=True, text=True,
                          timeout=SAFETY_S)
    assert done.returncode == 0, done.stderr
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert len(lines) == 60 and all(isinstance(r.get("class"), str) and r["class"] for r in lines), \
        [r for r in lines if "class" not in r][:3]
    assert lines[0]["class"] == "VERSION" and {"DEVICES", "WATCH", "ANGLE", "ODOMETRY"} <= {r["class"] for r in lines}
    assert all(r["class"] == r["kind"].upper() for r in lines if "n" in r)  # an item's class is its kind
