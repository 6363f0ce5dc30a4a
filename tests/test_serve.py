"""``rfhoming serve``: one owner of an emulated XPLR-AOA, many clients.

Two clients that read get identical, gap-free streams while a third that stops reading is cut
off (told so) and the other two go on; ``serve://HOST:PORT`` works as a port spec."""

from __future__ import annotations

import json
import signal
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import rigs
from hypothesis import given

from rfhoming.host import portspec
from rfhoming.host.drivers.serve_client import ServeDriver
from rfhoming.host.session import open_drivers
from rfhoming.protocol.frames import FrameDecoder
from rfhoming.protocol.jsonable import as_dict, from_dict
from rfhoming.protocol.uconnect import UConnectDecoder
from strategies import records

GOLDEN = Path(__file__).parent / "golden"
ITEMS = 2500  # per reading client
SAFETY_S = 120  # a bound on each blocking read, so a broken server fails the test instead of hanging it


def start(*args: str) -> rigs.Child:
    return rigs.Child([*rigs.RFHOMING, *args])


@contextmanager
def serving_emulated_aoa(queue: int) -> Iterator[tuple[int, rigs.Child]]:
    with rigs.emulate("s0-open", "--tcp", "--speed", "10", "--seed", "3") as emulator:
        aoa = next(e for e in emulator.endpoints.values() if e["type"] == "xplr-aoa")
        with start("serve", f"xplr-aoa:{aoa['url']}", "--port", "0", "--queue", str(queue), "--foxglove=0") as server:
            first, second = (server.json_line(SAFETY_S) for _ in range(2))
            assert first["kind"] == "listening" and first["address"].startswith("tcp://127.0.0.1:")  # loopback by default
            assert second["kind"] == "listening" and second["address"].startswith("ws://127.0.0.1:")  # Foxglove too
            yield int(first["address"].rsplit(":", 1)[1]), server


def read_lines(sock: socket.socket, want: int | None, after: str | None = None) -> list[dict]:
    """Lines until ``want`` items have come (None: until the server closes); ``after``: items
    after the first line of that kind."""
    sock.settimeout(SAFETY_S)
    got, partial = [], b""

    def items() -> int:
        start = next((k for k, r in enumerate(got) if r["kind"] == after), len(got)) if after else 0
        return sum(1 for r in got[start:] if "n" in r)

    while want is None or items() < want:
        data = sock.recv(65536)
        if not data:
            break
        *lines, partial = (partial + data).split(b"\n")
        got += [json.loads(line) for line in lines]
    return got


@pytest.mark.slow
def test_two_readers_get_identical_streams_while_a_stalled_client_is_dropped() -> None:
    with serving_emulated_aoa(queue=300) as (port, server):
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.connect(("127.0.0.1", port))
        hello = json.loads(stalled.makefile("rb").readline())
        assert hello["kind"] == "hello" and hello["devices"]
        # ... and from here on it reads nothing

        streams: list[list[dict]] = [[], []]

        def reader(i: int) -> None:
            with socket.socket() as sock:
                # the kernel holds a whole run for it: a loaded machine slows this thread, and a slow
                # reader that keeps reading must not be taken for the stalled one
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
                sock.connect(("127.0.0.1", port))
                sock.sendall(b'{"cmd": "watch", "chatter": true}\n')  # every item, the set-up dialogue too
                streams[i] = read_lines(sock, ITEMS, after="watch")

        threads = [threading.Thread(target=reader, args=(i,)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        stalled_lines = read_lines(stalled, None)  # now it reads: what was in flight, then the end
        stalled.close()
        server.send_signal(signal.SIGINT)
        server.wait(timeout=30)
        out = server.stdout()

    # from the watch reply on, every item (before it, the default watch leaves the chatter out)
    items = [[r for r in s[next(k for k, r in enumerate(s) if r["kind"] == "watch"):] if "n" in r] for s in streams]
    for stream, its in zip(streams, items):
        assert len(its) >= ITEMS
        assert not [r for r in stream if r["kind"] == "dropped"]
        ns = [r["n"] for r in its]
        assert ns == list(range(ns[0], ns[0] + len(ns)))  # gap-free
        assert {r["kind"] for r in its} >= {"angle"}
    common = {r["n"]: r for r in items[0]}.keys() & {r["n"]: r for r in items[1]}.keys()
    assert len(common) >= ITEMS // 2
    by_n = [{r["n"]: r for r in its} for its in items]
    assert [by_n[0][n] for n in sorted(common)] == [by_n[1][n] for n in sorted(common)]

    last = stalled_lines[-1]
    assert last["kind"] == "dropped" and "disconnected" in last and last["total"] >= 300
    stalled_ns = [r["n"] for r in stalled_lines if "n" in r]
    assert max(stalled_ns) < max(r["n"] for r in items[0])  # cut off while the others went on
    summary = [json.loads(line) for line in out.splitlines() if line.strip()]
    health = next(s for s in summary if s["kind"] == "server")
    assert health["disconnected_slow"] == 1 and health["clients"] == 3


async def test_serve_port_spec_and_a_client_driver() -> None:
    spec = portspec.parse("serve://127.0.0.1:2948,device=aoa")
    assert (spec.kind, spec.where, spec.settings) == ("serve", "//127.0.0.1:2948", {"device": "aoa"})
    (driver,) = await open_drivers([spec])
    assert isinstance(driver, ServeDriver) and driver.port.spec == "socket://127.0.0.1:2948"
    with pytest.raises(portspec.PortSpecError, match="serve://HOST:PORT"):
        await open_drivers(["serve:nowhere"])


def test_serve_driver_rebuilds_items_and_counts_bad_lines() -> None:
    driver = ServeDriver(_NoPort())
    seen = []
    driver.listeners.append(lambda device, t, item: seen.append((device, t, item)))
    items = list(UConnectDecoder().feed((GOLDEN / "xplr_aoa_session.raw").read_bytes()))
    lines = [json.dumps({"n": i, "device": "aoa", "t": float(i), **as_dict(item)}) for i, item in enumerate(items)]
    data = ("\n".join([json.dumps({"kind": "hello"}), "not json", *lines,
                       json.dumps({"kind": "dropped", "count": 7, "total": 7})]) + "\n").encode()
    for k in range(0, len(data), 97):  # arbitrary chunking
        driver.on_chunk(data[k:k + 97], 0.0)
    assert [item for _, _, item in seen] == items
    assert driver.counters["bad_lines"] == 1 and driver.counters["server_dropped"] == 7
    assert len(driver.out) == sum(1 for i in items if i.kind == "angle")


@given(records)
def test_every_record_survives_the_json_form(record) -> None:
    assert from_dict(json.loads(json.dumps(as_dict(record)))) == record


def test_every_golden_item_survives_the_json_form() -> None:
    raw = (GOLDEN / "rss_node_stream.raw").read_bytes()
    items = list(FrameDecoder().feed(raw)) + list(UConnectDecoder().feed((GOLDEN / "xplr_aoa_session.raw").read_bytes()))
    assert len({i.kind for i in items}) > 8
    for item in items:
        assert from_dict(json.loads(json.dumps(as_dict(item)))) == item
    with pytest.raises(ValueError, match="unknown item kind"):
        from_dict({"kind": "nonsense"})


class _NoPort:
    name = spec = "serve://test"
    counters: dict = {}


@pytest.mark.slow
def test_the_homing_loop_and_a_viewer_share_one_xplr_aoa(emulated, spawn) -> None:
    emulator = emulated("s0-open", "--tcp", "--speed", "4", "--seed", "1")
    urls = {e["type"]: e["url"] for e in emulator.endpoints.values()}
    server = spawn("serve", f"xplr-aoa:{urls['xplr-aoa']}", "--port", "0")
    port = server.json_line(SAFETY_S)["address"].rsplit(":", 1)[1]
    with socket.create_connection(("127.0.0.1", int(port))) as viewer:
        run = spawn("run", "--aoa", f"serve://127.0.0.1:{port}", "--base", f"base:{urls['base']}")
        seen = read_lines(viewer, 200)
        run.wait(timeout=SAFETY_S)
        out, err = run.stdout(), run.stderr()
    assert run.returncode == 0, err
    assert json.loads(out)["arrived"] is True
    assert sum(1 for r in seen if r["kind"] == "angle") > 100


# -- hostile clients: what a client sends or refuses to read is bounded ------------------------
async def _connect(server):
    import asyncio

    (address,) = await server.start("127.0.0.1", 0)
    reader, writer = await asyncio.open_connection("127.0.0.1", int(address.rsplit(":", 1)[1]))
    assert json.loads(await reader.readline())["kind"] == "hello"
    return reader, writer


async def test_a_client_that_sends_too_much_gets_one_error_line_and_is_cut_off() -> None:
    """Before: the server read every byte a client sent, to EOF, and kept them all."""
    import asyncio

    from rfhoming.host.serve import ItemServer

    server = ItemServer(max_input=64 * 1024)
    reader, writer = await _connect(server)
    try:
        for _ in range(256):  # 16 MiB in 64 KiB writes, until the server closes its side
            writer.write(b"x" * 65536)
            await writer.drain()
            await asyncio.sleep(0)
            if reader.at_eof() or server.counters["disconnected_input"]:
                break
        rest = await asyncio.wait_for(reader.read(), 10)
    except ConnectionError:
        rest = b""
    finally:
        writer.close()
    assert server.counters["disconnected_input"] == 1 and not server.clients
    lines = [json.loads(line) for line in rest.splitlines()]  # the over-long line's error, then the cut-off
    assert {r["kind"] for r in lines} == {"error"} and "disconnecting" in lines[-1]["message"]
    await server.close()


async def test_a_never_reading_client_is_held_to_its_queue_and_cut_off() -> None:
    import asyncio

    from rfhoming.host.serve import QUEUE_BYTES, ItemServer

    server = ItemServer(queue_lines=100_000, max_drops=5000)
    _, writer = await _connect(server)
    (client,) = server.clients
    big = {"kind": "log_text", "node_id": 1, "seq": 0, "t_us": 0, "text": "y" * 2000}
    for _ in range(20_000):  # 40 MB of lines, none of them read
        server.publish("dev", 0.0, from_dict(big))
        assert client.queued_bytes <= QUEUE_BYTES
        await asyncio.sleep(0)
    assert server.counters["disconnected_slow"] == 1 and not server.clients and not client.queue
    writer.close()
    await server.close()


async def test_connections_past_max_clients_are_refused_with_a_line() -> None:
    import asyncio

    from rfhoming.host.serve import ItemServer

    server = ItemServer(max_clients=1)
    _, first = await _connect(server)
    port = int(first.get_extra_info("peername")[1])
    reader, second = await asyncio.open_connection("127.0.0.1", port)
    line = json.loads(await asyncio.wait_for(reader.readline(), 10))
    assert line["kind"] == "error" and "too many clients" in line["message"]
    assert server.counters["refused"] == 1 and len(server.clients) == 1
    first.close()
    second.close()
    await server.close()
