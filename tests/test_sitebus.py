"""The site bus: payloads, the batched engine against the per-tag reference, and the whole chain
against a real Mosquitto broker with mosquitto_sub (Debian's mosquitto-clients) as the independent
reader of what rfhoming publishes."""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rigs
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.emulator.site import SiteScenario, SiteScenarioError
from rfhoming.host.estimation.anchors3d import Degenerate, locate, make_ray, rotation
from rfhoming.host.estimation.batch import BatchLocator, fix_batch
from rfhoming.host.locate import Locator
from rfhoming.host.site import Anchor, Calibration, Site
from rfhoming.protocol import sitebus
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect.items import AngleEvent

from brokers import MOSQUITTO, SUB
from brokers import free_port as _free_port
from brokers import start as _start_broker

needs_broker = pytest.mark.skipif(not (MOSQUITTO and SUB), reason="mosquitto / mosquitto-clients not installed "
                                  "(.ci/run installs them)")
ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}


# -- payloads ---------------------------------------------------------------------------------------
def test_partition_is_crc32_mod_count() -> None:
    import zlib

    for tag in ("T00001", "CCF9578E0D8A", "x"):
        assert sitebus.partition(tag, 16) == zlib.crc32(tag.encode()) % 16


ids = st.text(st.characters(blacklist_characters="/+#\x00", blacklist_categories=("Cs",)), min_size=1, max_size=12)
"""Ids that are MQTT topic levels (a tag's is one, in its position topic): any other is refused."""
row = st.tuples(st.floats(0, 3000), ids, ids, st.integers(-90, 90), st.integers(-90, 90))


@given(st.lists(row, max_size=20), st.integers(0, 2**31), st.floats(-1e3, 1e3), st.floats(0, 2e9))
def test_angle_batch_round_trip(rows: list, seq: int, offset: float, base: float) -> None:
    """Any batch within the hour a batch may span (sitebus.MAX_SPAN_US), at any epoch time."""
    rows = [(base + t, *rest) for t, *rest in rows]
    back = sitebus.decode_angles(sitebus.encode_angles("gw01", seq, 1.7e9, offset, rows))
    assert back.gateway == "gw01" and back.seq == seq and back.offset_s == pytest.approx(offset, abs=1e-6)
    assert [(a, tag, az, el) for _, a, tag, az, el in back.events] == [(a, tag, az, el) for _, a, tag, az, el in rows]
    assert all(abs(t - r[0]) <= 1e-6 for (t, *_), r in zip(back.events, rows))


@given(st.binary(max_size=200))
def test_garbage_is_a_payload_error(data: bytes) -> None:
    try:
        sitebus.decode_angles(data)
    except sitebus.PayloadError:
        pass


def test_a_version_1_batch_is_still_read() -> None:
    """The row form gateways wrote before the columns (docs/protocol.md section 8)."""
    back = sitebus.decode_angles(b'{"v":1,"gw":"g","seq":4,"sent":10.5,"offset_s":0.1,'
                                 b'"events":[[10.0,"A1","T1",-12,30],[10.2,"A2","T1",3,4]]}')
    assert back.seq == 4 and back.events == [(10.0, "A1", "T1", -12.0, 30.0), (10.2, "A2", "T1", 3.0, 4.0)]


V2 = '"v":2,"gw":"g","seq":0,"sent":0,"offset_s":0,"anchors":["a"],"tags":["t"],"t0":0,'
V2_BAD = ['"i":[[0],[0],[0]],"ang":[[91],[0]]', '"i":[[0.5],[0],[0]],"ang":[[1],[0]]', '"i":[[0],[1],[0]],"ang":[[1],[0]]',
          '"i":[[0],[0],[-1]],"ang":[[1],[0]]', '"i":[[0],[true],[0]],"ang":[[1],[0]]', '"i":[[0,1],[0],[0]],"ang":[[1],[0]]',
          '"i":[[0],[0],[0]],"ang":[["1"],[0]]', '"i":[[0],[0],[0]],"ang":[[[1]],[0]]', '"i":[[0],[0],[0]],"ang":[[1],[NaN]]',
          '"i":[[0],[0],[0]],"ang":[[1]]', '"i":[[0],[0]],"ang":[[1],[0]]', '"i":[[0],[0],[0]],"ang":[[1],[true]]',
          # integers JSON allows and numpy (int64) or the worker's sums do not: each field bounded
          '"i":[[100000000000000000000000],[0],[0]],"ang":[[1],[0]]', '"i":[[-1],[0],[0]],"ang":[[1],[0]]',
          '"i":[[3600000000],[0],[0]],"ang":[[1],[0]]', '"i":[[0],[100000000000000000000000],[0]],"ang":[[1],[0]]',
          '"i":[[0],[0],[-100000000000000000000000]],"ang":[[1],[0]]']
V2_BAD_HEAD = [V2.replace('"seq":0', '"seq":9223372036854775808'), V2.replace('"seq":0', '"seq":-1'),
               V2.replace('"seq":0', '"seq":1.5'), V2.replace('"seq":0', '"seq":"1"'),
               V2.replace('"sent":0', '"sent":1e300'), V2.replace('"offset_s":0', '"offset_s":-1e11'),
               V2.replace('"t0":0', '"t0":1e300'), V2.replace('"sent":0', f'"sent":{"9" * 400}'),
               # numbers written as text or booleans: float() took them
               V2.replace('"sent":0', '"sent":"1e3"'), V2.replace('"offset_s":0', '"offset_s":true'),
               V2.replace('"t0":0', '"t0":"5"')]


@pytest.mark.parametrize("payload", [b"{}", b'{"v":1}', b'{"v":3,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[]}',
                                     b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[[0,"a","t",91,0]]}',
                                     b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[[0,1,"t",0,0]]}',
                                     b'{"v":1,"gw":"g","seq":0,"sent":"NaN","offset_s":0,"events":[]}',
                                     b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[["0","a","t",0,0]]}',
                                     b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[[0,"a","t","5",0]]}',
                                     b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[[0,"a","t",0,true]]}',
                                     *(("{" + V2 + bad + "}").encode() for bad in V2_BAD),
                                     *(("{" + head + V2_BAD[1].replace("0.5", "0") + "}").encode()
                                       for head in V2_BAD_HEAD),
                                     b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[[0,"a","t",0,0],'
                                     b'[1e300,"a","t",0,0]]}',
                                     ("{" + V2.replace('"t0":0', '"t0":Infinity') + V2_BAD[1].replace("0.5", "0")
                                      + "}").encode()])
def test_bad_batches_are_refused(payload: bytes) -> None:
    with pytest.raises(sitebus.PayloadError):
        sitebus.decode_angles(payload)


HOSTILE = [b"[" * 1000, b"{" * 1000, b'{"v":2,"gw":' + b"[" * 5000, b"[" * 100_000 + b"]" * 100_000,
           b'{"v":2,"gw":"g","seq":' + b"9" * 10_000 + b"}", b'{"v":' + b"9" * 5000 + b"}",
           b'{"v":2,"gw":"g","seq":0,"sent":1e999}', b'{"v":true}', b'{"v":2.0}',
           b" " * (sitebus.MAX_PAYLOAD + 1),
           b'{"v":1,"gw":"g","seq":0,"sent":0,"offset_s":0,"events":[[0,"a",' + b"[" * 3000 + b"]]}",
           *(("{" + V2.replace('"tags":["t"]', f'"tags":[{json.dumps(bad)}]') + '"i":[[0],[0],[0]],"ang":[[1],[0]]}')
             .encode() for bad in ("a/b", "t+", "#", "", "t\x00", "\ud800", "x" * 257, 7)),
           ("{" + V2.replace('"gw":"g"', '"gw":["g"]') + '"i":[[0],[0],[0]],"ang":[[1],[0]]}').encode()]


@pytest.mark.parametrize("payload", HOSTILE, ids=range(len(HOSTILE)))
def test_deep_nesting_huge_numbers_and_unusable_ids_are_payload_errors(payload: bytes) -> None:
    """Anyone who can publish to the broker can send these; each must cost only itself. 1,000
    ``[`` made json.loads raise RecursionError (not caught: the worker died); a tag id with a
    wildcard or "/" passed and made the worker's publish of its position raise."""
    with pytest.raises(sitebus.PayloadError):
        sitebus.decode_angles(payload)


def test_a_dead_worker_moves_only_its_partitions() -> None:
    live = {"w1", "w2", "w3"}
    before = {p: sitebus.owner(p, live) for p in range(64)}
    assert set(before.values()) == live  # every worker gets some
    after = {p: sitebus.owner(p, live - {"w2"}) for p in range(64)}
    assert all(after[p] == before[p] for p in range(64) if before[p] != "w2")
    assert "w2" not in after.values()


def test_site_scenario_names() -> None:
    sc = SiteScenario.named("site-64x1000")
    assert len(sc.anchors) == 64 and len(sc.tags) == 1000 and len(sc.gateways) == 16
    with pytest.raises(SiteScenarioError):
        SiteScenario.named("site-2x5")


# -- the batched engine against the reference ---------------------------------------------------------
def _random_rays(rng: np.random.Generator, n: int, height: float | None) -> list:
    tag = rng.uniform([0, 0, 0.5], [20, 20, 2.0])
    if height is not None:
        tag[2] = height
    rays = []
    for i in range(n):
        origin = rng.uniform([0, 0, 2.5], [20, 20, 4.0])
        yaw, pitch = rng.uniform(0, 360), rng.uniform(-80, -20)
        rot = rotation(yaw, pitch)
        d = rot.T @ (tag - origin)
        if d[0] <= 0:  # behind the board: turn the board to face the tag
            rot = rotation(yaw + 180, pitch)
            d = rot.T @ (tag - origin)
        az = -np.degrees(np.arctan2(d[1], d[0])) + rng.normal(0, 3)
        el = np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1]))) + rng.normal(0, 3)
        if rng.random() < 0.1:
            az += 40  # a reflection now and then: the consensus path
        rays.append(make_ray(f"a{i}", origin, rot, float(np.clip(az, -90, 90)), float(np.clip(el, -90, 90)),
                             float(rng.uniform(1, 5))))
    return rays


@pytest.mark.parametrize("seed", range(5))
def test_fix_batch_equals_anchors3d_locate(seed: int) -> None:
    rng = np.random.default_rng(seed)
    sets = []
    for _ in range(200):
        height = float(rng.uniform(0.5, 2)) if rng.random() < 0.3 else None
        sets.append((_random_rays(rng, int(rng.integers(3, 9)), height), height))
    o = np.array([r.origin for rays, _ in sets for r in rays])
    u = np.array([r.direction for rays, _ in sets for r in rays])
    sig = np.array([r.sigma_rad for rays, _ in sets for r in rays])
    g = np.repeat(np.arange(len(sets)), [len(rays) for rays, _ in sets])
    heights = np.array([np.nan if h is None else h for _, h in sets])
    out = fix_batch(o, u, sig, g, heights)
    compared = 0
    for k, (rays, height) in enumerate(sets):
        try:
            ref = locate(rays, height=height)
        except Degenerate:
            assert not out.ok[k]
            continue
        if out.suspect[k]:
            continue  # handed to locate() itself by BatchLocator
        assert out.ok[k]
        np.testing.assert_allclose(out.points[k], ref.point, rtol=0, atol=1e-9)
        np.testing.assert_allclose(out.covariances[k], ref.covariance, rtol=1e-9, atol=1e-12)
        assert out.chi2[k] == pytest.approx(ref.chi2, rel=1e-9, abs=1e-12)
        compared += 1
    assert compared > 100


def _site(sc: SiteScenario) -> Site:
    return Site("w", tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg, angle_model="spherical")
                           for a in sc.anchors), sigma_deg=sc.sigma_deg, az_compression=0.0)  # the emulator's boards


def test_batch_locator_equals_the_per_tag_locator() -> None:
    """The same events into host/locate.py's Locator (fixes, no tracker) and into BatchLocator:
    the same tags fixed at the same tick, to rounding."""
    sc = SiteScenario(16, 60, seed=3, clock_spread_s=0.0)
    site = _site(sc)
    rows = sorted(r for rs in sc.events(10.0, 12.0).values() for r in rs)
    loc = Locator(site, track=False, reorder_s=0.0)
    ref = []
    for t, a, tag, az, el in rows:
        ref += loc.feed(bearing_of(t, AngleEvent(tag, -50, az, el, 0, 37, a, "", 0)))
    ref += loc.flush()
    batch = BatchLocator(site)
    batch.feed(rows)
    t = sorted({p.t for p in ref})[-3]
    mine = {f.tag: f for f in batch.tick(t)}
    theirs = {p.tag: p for p in ref if p.t == t}
    assert set(mine) == set(theirs) and len(mine) == 60
    for tag, p in theirs.items():
        np.testing.assert_allclose(mine[tag].fix.point, p.point, atol=1e-9)
        np.testing.assert_allclose(mine[tag].fix.covariance, p.covariance, atol=1e-12)
        assert mine[tag].fix.used == p.anchors and mine[tag].fix.rejected == p.rejected
    truth = sc.truth(t)
    err = [np.linalg.norm(f.fix.point - truth[int(tag[1:])]) for tag, f in mine.items()]
    assert np.median(err) < 0.5


def test_batch_locator_corrects_compression_as_the_per_tag_locator() -> None:
    """A site calibrated with |azimuth| compression (calibrate --self writes it): a worker's
    BatchLocator places the tags where locate's Locator does. Old code: BatchLocator applied
    each anchor's scale and bias but not its compression, so a worker's positions differed."""
    sc = SiteScenario(8, 20, seed=5, clock_spread_s=0.0)
    cal = Calibration(az_scale=1.05, az_bias_deg=2.0, az_compression=0.2)
    site = _site(sc)
    site = replace(site, anchors=tuple(replace(a, calibration=cal) for a in site.anchors))
    rows = sorted(r for rs in sc.events(10.0, 12.0).values() for r in rs)
    loc = Locator(site, track=False, reorder_s=0.0)
    ref = []
    for t, a, tag, az, el in rows:
        ref += loc.feed(bearing_of(t, AngleEvent(tag, -50, az, el, 0, 37, a, "", 0)))
    ref += loc.flush()
    batch = BatchLocator(site)
    batch.feed(rows)
    t = sorted({p.t for p in ref})[-3]
    mine = {f.tag: f for f in batch.tick(t)}
    theirs = {p.tag: p for p in ref if p.t == t}
    assert set(mine) == set(theirs) and len(mine) == 20
    for tag, p in theirs.items():
        np.testing.assert_allclose(mine[tag].fix.point, p.point, atol=1e-6)


# -- against a real broker -----------------------------------------------------------------------------
@pytest.fixture
def broker(tmp_path: Path):
    port = _free_port()
    proc = _start_broker(tmp_path, port)
    yield port
    proc.terminate()
    proc.wait(30)


def _sub(port: int, topic: str, count: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([SUB, "-h", "127.0.0.1", "-p", str(port), "-t", topic, "-C", str(count), "-v",
                             "-W", "120", *extra], stdout=subprocess.PIPE, text=True)


@needs_broker
def test_gateway_batches_read_by_mosquitto_sub(broker: int) -> None:
    from rfhoming.host.sitebus import Broker, Gateway, Publisher

    sub = _sub(broker, "rfhoming/s1/angles/#", 2)
    time.sleep(0.5)  # mosquitto_sub subscribing; the gateway below repeats until it is heard
    pub = Publisher(Broker("127.0.0.1", broker, False, 4), "gw-test")
    assert pub.connected.wait(30)
    gw = Gateway(pub, "s1", "gw07", 4, offset_s=0.25)
    deadline = time.monotonic() + 120
    while sub.poll() is None and time.monotonic() < deadline:
        gw.add(100.0, "A1", "T00001", -12, 30)
        gw.flush(100.5)
        time.sleep(0.1)
    out, _ = sub.communicate(timeout=60)
    pub.close()
    lines = out.splitlines()
    assert len(lines) == 2
    topic, payload = lines[0].split(" ", 1)
    assert topic == f"rfhoming/s1/angles/{sitebus.partition('T00001', 4)}"
    body = json.loads(payload)
    assert body["v"] == 2 and body["gw"] == "gw07" and body["offset_s"] == 0.25 and body["sent"] == 100.5
    assert (body["anchors"], body["tags"], body["t0"], body["i"], body["ang"]) == (
        ["A1"], ["T00001"], 100.0, [[0], [0], [0]], [[-12], [30]])
    assert json.loads(lines[1].split(" ", 1)[1])["seq"] == body["seq"] + 1


def test_a_driver_listener_feeds_the_gateway() -> None:
    from rfhoming.host.sitebus import Gateway

    class Sink:
        def __init__(self) -> None:
            self.sent: list[tuple[str, bytes]] = []

        def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> None:
            self.sent.append((topic, payload))

    sink = Sink()
    gw = Gateway(sink, "s1", "gw00", 8)  # type: ignore[arg-type]
    gw.on_bearing(bearing_of(12.5, AngleEvent("T1", -50, 20, -5, 0, 37, "A9", "", 0)))
    gw.flush(13.0)
    (topic, payload), = sink.sent
    assert topic == f"rfhoming/s1/angles/{sitebus.partition('T1', 8)}"
    assert sitebus.decode_angles(payload).events == [(12.5, "A9", "T1", 20.0, -5.0)]


@needs_broker
def test_publisher_buffers_boundedly_while_the_broker_is_away(tmp_path: Path) -> None:
    """No broker: five retained messages into a buffer of three; the broker comes; the newest three
    reach it in order (mosquitto_sub reads the retained ones), the two oldest were dropped, counted."""
    from rfhoming.host.sitebus import Broker, Publisher

    port = _free_port()
    pub = Publisher(Broker("127.0.0.1", port, False, None), "gw-away", buffer=3)
    for i in range(5):
        pub.publish(f"t/{i}", f"m{i}".encode(), retain=True)
    assert pub.counters["dropped"] == 2 and not pub.connected.is_set()
    proc = _start_broker(tmp_path, port)
    try:
        assert pub.connected.wait(120)
        deadline = time.monotonic() + 60
        while pub.counters["published"] < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        sub = _sub(port, "t/#", 3)
        out, _ = sub.communicate(timeout=120)
        assert sorted(out.splitlines()) == ["t/2 m2", "t/3 m3", "t/4 m4"]
        assert pub.counters == {**pub.counters, "published": 3, "dropped": 2, "connects": 1}
    finally:
        pub.close()
        proc.terminate()
        proc.wait(30)


@needs_broker
def test_a_serviced_publisher_reconnects_and_sends_what_it_buffered(tmp_path: Path) -> None:
    """threaded=False (a worker's, the emulated gateways'): no broker, three retained messages
    buffered; the owner's loop keeps calling service(), which tries the broker again with back-off;
    the broker comes, the connection is made and the three go out in order (mosquitto_sub reads them)."""
    from rfhoming.host.sitebus import Broker, Publisher

    port = _free_port()
    pub = Publisher(Broker("127.0.0.1", port, False, None), "gw-serviced", threaded=False)
    for i in range(3):
        pub.publish(f"s/{i}", f"m{i}".encode(), retain=True)
    for _ in range(3):
        pub.service(0.05)  # refused: nothing listens
    assert not pub.connected.is_set() and pub.counters["buffered"] == 3
    proc = _start_broker(tmp_path, port)
    try:
        assert pub.wait_connected(120)
        deadline = time.monotonic() + 60  # a hang guard
        while (pub.counters["published"] < 3 or pub.client.want_write()) and time.monotonic() < deadline:
            pub.service(0.05)
        out, _ = _sub(port, "s/#", 3).communicate(timeout=120)
        assert sorted(out.splitlines()) == ["s/0 m0", "s/1 m1", "s/2 m2"]
        assert pub.counters["connects"] == 1 and pub.counters["dropped"] == 0
    finally:
        pub.close()
        proc.terminate()
        proc.wait(30)


@needs_broker
def test_a_refusal_while_connected_does_not_stall_the_publisher(broker: int) -> None:
    """paho refuses a publish when it has seen the socket go before on_disconnect ran: the message
    is buffered, and the next publish sends it first (it used to wait for a reconnect that need not
    come, and every later message queued behind it)."""
    from types import SimpleNamespace

    import paho.mqtt.client as mqtt

    from rfhoming.host.sitebus import Broker, Publisher

    pub = Publisher(Broker("127.0.0.1", broker, False, None), "gw-refused")
    try:
        assert pub.connected.wait(120)
        real = pub.client.publish
        pub.client.publish = lambda *a, **k: SimpleNamespace(rc=mqtt.MQTT_ERR_NO_CONN)  # type: ignore[method-assign]
        pub.publish("t/0", b"m0", retain=True)
        pub.client.publish = real  # type: ignore[method-assign]
        assert pub.counters["buffered"] == 1 and pub.connected.is_set()
        pub.publish("t/1", b"m1", retain=True)
        assert pub.counters["published"] == 2
        out, _ = _sub(broker, "t/#", 2).communicate(timeout=120)
        assert sorted(out.splitlines()) == ["t/0 m0", "t/1 m1"]
    finally:
        pub.close()


def _cli(log: Path, *args: str) -> subprocess.Popen:
    """One rfhoming command, its info log kept in ``log`` for the failure message."""
    return subprocess.Popen([sys.executable, "-m", "rfhoming.cli.main", "-v", *args], env=ENV,
                            stdout=subprocess.PIPE, stderr=log.open("w"), text=True)


def _lines(stream, out: queue.Queue) -> None:
    for line in stream:
        out.put(line)
    out.put(None)


SETTLE_S = 0.25
"""Site time after the second worker's first position before the split is counted: five ticks at
20 Hz, for positions made under the one-worker assignment to drain (a loaded CI run saw some)."""
FAILOVER_DEADLINE_S = 240.0
"""Wall seconds for the whole test, a hang guard: idle it takes 2 s, loaded 15 s."""


@pytest.mark.slow
@needs_broker
def test_two_workers_split_the_site_and_one_takes_over_when_the_other_dies(broker: int, tmp_path: Path) -> None:
    """Emulated gateways -> Mosquitto -> two locate workers -> mosquitto_sub. Each worker publishes
    its partitions' tags; after w1 is killed (SIGKILL: its will tells w2), w2 publishes every tag
    either had located (a tag in a corner that fewer than three anchors see is located by neither)."""
    url = f"mqtt://127.0.0.1:{broker}/8"
    site = "site-16x40"
    logs = {name: tmp_path / f"{name}.log" for name in ("w1", "w2", "gw")}
    w1 = _cli(logs["w1"], "locate", site, "--from", url, "--id", "w1", "--rate", "20")
    w2 = _cli(logs["w2"], "locate", site, "--from", url, "--id", "w2", "--rate", "20", "--duration", "600")
    sub = subprocess.Popen([SUB, "-h", "127.0.0.1", "-p", str(broker), "-t", f"rfhoming/{site}/positions/#",
                            "-W", "600"], stdout=subprocess.PIPE, text=True)
    gw = _cli(logs["gw"], "gateway", "--emulate", site, "--broker", url, "--duration", "600")
    procs = {"gw": gw, "w2": w2, "sub": sub, "w1": w1}
    lines: queue.Queue = queue.Queue()
    assert sub.stdout is not None
    threading.Thread(target=_lines, args=(sub.stdout, lines), daemon=True).start()
    tags = set(SiteScenario.named(site).tags)
    by: dict[str, set[str]] = {"w1": set(), "w2": set()}
    after_kill: set[str] = set()
    killed_at_t = None
    first_w2_of_w1_tags = None
    w1_tags_last_t = None
    seen: dict[str, float] = {}  # each worker's first position, in site time
    split: dict[str, set[str]] = {"w1": set(), "w2": set()}  # once both are up and have heard of each other
    count = 0
    stopped = "the deadline"
    deadline = time.monotonic() + FAILOVER_DEADLINE_S
    try:
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = lines.get(timeout=left)
            except queue.Empty:
                break
            if line is None:
                stopped = "mosquitto_sub's end"
                break
            count += 1
            p = json.loads(line)
            seen.setdefault(p["worker"], p["t"])
            if killed_at_t is None:
                by[p["worker"]].add(p["tag"])
                if len(seen) == 2 and p["t"] >= max(seen.values()) + SETTLE_S:
                    split[p["worker"]].add(p["tag"])  # before, the first worker owned every partition
                if len(split["w1"]) >= 3 and len(split["w2"]) >= 3:  # both at work on their own partitions
                    w1.send_signal(signal.SIGKILL)
                    w1.wait(60)
                    killed_at_t = p["t"]
                continue
            if p["worker"] == "w1":
                w1_tags_last_t = p["t"]  # already on its way when w1 died
                continue
            if p["tag"] in by["w1"] and first_w2_of_w1_tags is None:
                first_w2_of_w1_tags = p["t"]
            after_kill.add(p["tag"])
            if after_kill >= by["w1"] | by["w2"]:
                stopped = ""
                break
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.terminate()
        for proc in procs.values():
            proc.wait(60)
    if stopped:
        health = {n: procs[n].communicate(timeout=30)[0].strip()[-600:] for n in ("w1", "w2", "gw")}
        tails = {n: logs[n].read_text()[-1500:] for n in logs}
        pytest.fail(f"stopped at {stopped} after {count} positions: first positions {seen}, split "
                    f"{ {k: len(v) for k, v in split.items()} }, killed at {killed_at_t}, still missing after the "
                    f"kill {sorted((by['w1'] | by['w2']) - after_kill)}; exit codes "
                    f"{ {n: p.returncode for n, p in procs.items()} }; health {health}; logs {tails}")
    assert split["w1"] and split["w2"] and not split["w1"] & split["w2"], "a tag located by both: partitions not split"
    assert by["w1"] <= tags
    last = w1_tags_last_t or killed_at_t
    assert first_w2_of_w1_tags is not None and last is not None
    print(f"handover: w2's first position of a w1 tag came {first_w2_of_w1_tags - last:.2f} s of site time "
          f"({(first_w2_of_w1_tags - last) * 20:.0f} ticks at 20 Hz) after w1's last")


def test_batch_tracker_equals_the_per_tag_tracker() -> None:
    """Locator(tracker="cv") and BatchLocator(track=True), tick after tick on the same events.
    cv: the batch engine's one tracker; Locator's track check, consensus restart, noise scale and
    FLOOR_M belong to its angles and ekf trackers only (docs/estimation.md, "Guards")."""
    sc = SiteScenario(16, 40, seed=5, clock_spread_s=0.0)
    site = _site(sc)
    rows = sorted(r for rs in sc.events(10.0, 13.0).values() for r in rs)
    loc = Locator(site, track=True, tracker="cv", reorder_s=0.0)
    ref = []
    for t, a, tag, az, el in rows:
        ref += loc.feed(bearing_of(t, AngleEvent(tag, -50, az, el, 0, 37, a, "", 0)))
    batch = BatchLocator(site, track=True)
    ticks = sorted({p.t for p in ref})
    i = 0
    compared = 0
    for t in ticks:
        j = i
        while j < len(rows) and rows[j][0] < t:
            j += 1
        batch.feed(rows[i:j])
        i = j
        mine = {f.tag: f for f in batch.tick(t)}
        theirs = {p.tag: p for p in ref if p.t == t}
        assert set(mine) == set(theirs)
        for tag, p in theirs.items():
            np.testing.assert_allclose(mine[tag].fix.point, p.point, atol=1e-8)
            np.testing.assert_allclose(mine[tag].fix.covariance, p.covariance, atol=1e-10)
            compared += 1
    assert compared > 40 * 20


def test_only_new_fixes_the_tags_that_spoke_with_the_same_answer() -> None:
    sc = SiteScenario(16, 30, seed=7, clock_spread_s=0.0)
    rows = sorted(r for rs in sc.events(10.0, 11.0).values() for r in rs)
    every, new = BatchLocator(_site(sc)), BatchLocator(_site(sc))  # fixes (a tracker fed the same fix twice moves)
    for k in range(1, 21):  # 20 Hz ticks, 10 Hz tags: each tag is new at about every other tick
        t = 10.0 + k * 0.05
        chunk = [r for r in rows if t - 0.05 <= r[0] < t]
        every.feed(chunk)
        new.feed(chunk)
        a = {f.tag: f for f in every.tick(t) if f.new}
        b = {f.tag: f for f in new.tick(t, only_new=True)}
        assert set(a) == set(b) and all(f.new for f in b.values())
        for tag in a:
            np.testing.assert_allclose(a[tag].fix.point, b[tag].fix.point, atol=1e-6)


@pytest.mark.parametrize("extra", [["--smooth"], ["--tracker", "ekf"], ["--from", "capture:x.pcapng"], ["-o", "x.jsonl"]])
def test_locate_from_a_broker_refuses_what_a_worker_does_not_do(extra: list[str], tmp_path: Path) -> None:
    """``locate --from mqtt://`` is the site worker: options of the one-machine locate that it does
    not honour are a one-line error, exit 2, before any connection."""
    proc = subprocess.run([sys.executable, "-m", "rfhoming.cli.main", "locate", "site-16x40", "--from",
                           "mqtt://127.0.0.1:1/8", *extra], env=ENV, cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "site worker" in proc.stderr


KIT_ROOM = Path(__file__).resolve().parents[1] / "docs" / "sites" / "kit-room.toml"
STILL_TAGS = {"[2.0, 1.5]": "[2.0, 1.5]", "[0.7, 0.7]": "[6.0, 3.0]", "[4.0, 5.3]": "[8.0, 2.0]"}
"""kit-room's three tags at rest, each 1.5 m or more from a wall."""


def still_kit_room(folder: Path) -> Path:
    """The kit-room scenario with its tags standing still: a fix of a walking tag from angles the
    gateway read late (a loaded machine) lands where the tag was, up to a wall's width away; a
    still tag's does not, so the test checks the chain, not how fast the machine reads."""
    text = (Path(__file__).resolve().parents[1] / "emulator" / "scenarios" / "kit-room.toml").read_text()
    lines = [line for line in text.splitlines() if not line.startswith(("path =", "speed ="))]
    text = "\n".join(lines) + "\n"
    for walking, still in STILL_TAGS.items():
        assert f"position = {walking}" in text
        text = text.replace(f"position = {walking}", f"position = {still}")
    (folder / "kit-room.toml").write_text(text)
    return folder / "kit-room.toml"


@pytest.mark.slow
@needs_broker
def test_a_gateway_of_real_anchors_to_a_worker(broker: int, tmp_path: Path) -> None:
    """Emulated XPLR-AOA anchors behind ptys (``rfhoming emulate kit-room``, as tests/test_locate.py
    starts them) -> ``rfhoming gateway --site`` (the normal drivers) -> Mosquitto -> ``rfhoming
    locate --from mqtt://`` -> mosquitto_sub reads positions of the room's tags (standing still),
    inside the room."""
    links = tmp_path / "links"
    links.mkdir()
    site = tmp_path / "site.toml"
    site.write_text(KIT_ROOM.read_text().replace("/tmp/rfhoming-kit/", f"{links}/"))
    emulator = rigs.emulate(still_kit_room(tmp_path), "--seed", "1", link_dir=links, env=ENV,
                            argv0=[sys.executable, "-m", "rfhoming.cli.main"], devices=4)  # one line per anchor
    url = f"mqtt://127.0.0.1:{broker}/4"
    procs: dict[str, subprocess.Popen | rigs.Child] = {"emulator": emulator}
    try:
        sub = procs["sub"] = _sub(broker, "rfhoming/kit-room/positions/#", 30, "-W", "240")
        procs["worker"] = _cli(tmp_path / "worker.log", "locate", str(site), "--from", url, "--id", "w1")
        procs["gateway"] = _cli(tmp_path / "gateway.log", "gateway", "--site", str(site), "--broker", url,
                                "--name", "gw-kit")
        out, _ = sub.communicate(timeout=300)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs.values():
            proc.wait(60)
    positions = [json.loads(line.split(" ", 1)[1]) for line in out.splitlines()]
    assert len(positions) == 30, (tmp_path / "gateway.log").read_text()[-2000:]
    assert {p["tag"] for p in positions} <= {"CCF9578E0D8A", "CCF9578E0D8B", "CCF9578E0D8C"}
    assert all(0 <= p["x"] <= 12 and 0 <= p["y"] <= 6 and p["worker"] == "w1" for p in positions[10:]), \
        [(p["tag"], p["x"], p["y"], p["worker"]) for p in positions]
    gateway = json.loads(procs["gateway"].communicate(timeout=30)[0].strip().splitlines()[-1])  # type: ignore[union-attr]
    assert gateway["kind"] == "gateway" and gateway["name"] == "gw-kit" and gateway["events"] > 0


# -- bounds: bad batches, a refused login, a slow broker, a full engine ----------------------------------
def _worker(sc: SiteScenario):
    from rfhoming.host.sitebus import Broker, Worker

    # not connected: nothing is sent until service() (threaded=False), _drain is all that runs here
    return Worker(_site(sc), Broker("127.0.0.1", 1, False, None), worker_id="w", partitions=1)


def _batches(sc: SiteScenario, dt_us: int) -> list[bytes]:
    """Two good batches of two events each and, between them, one whose second time is ``dt_us``."""
    a = sc.anchors[0].id
    good = [(10.0, a, "T1", 5, 5), (10.01, a, "T2", 5, 5)]
    bad = json.loads(sitebus.encode_angles("g", 1, 10.0, 0.0, good))
    bad["i"][0][1] = dt_us
    return [sitebus.encode_angles("g", 0, 10.0, 0.0, good), json.dumps(bad).encode(),
            sitebus.encode_angles("g", 2, 10.0, 0.0, good)]


def test_a_bad_batch_costs_the_worker_only_itself() -> None:
    """dt_us = 10**23 is valid JSON: the decoder refuses it (it used to pass it, and np.fromiter's
    OverflowError killed the worker with every batch of that drain)."""
    sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
    worker = _worker(sc)
    worker._inbox.extend((10.0, "rfhoming/w/angles/0", p) for p in _batches(sc, 10**23))
    worker._drain()
    assert worker.counters["bad_payload"] == 1 and worker.counters["batches"] == 2
    assert worker.counters["events"] == 4 and worker.engine.counters["events"] == 4


def test_a_batch_the_decoder_passes_but_numpy_refuses_is_counted_not_raised(monkeypatch) -> None:
    """Defence in depth: with the decoder's bound lifted, 10**23 reaches the drain's np.fromiter;
    the drain feeds the batches one by one and drops only the one that fails."""
    monkeypatch.setattr(sitebus, "MAX_SPAN_US", 10**30, raising=False)
    sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
    worker = _worker(sc)
    worker._inbox.extend((10.0, "rfhoming/w/angles/0", p) for p in _batches(sc, 10**23))
    worker._drain()
    assert worker.counters["batches"] == 3 and worker.counters["bad_payload"] == 1
    assert worker.counters["unfed"] == 1 and worker.engine.counters["events"] == 4


def test_a_stream_of_new_gateway_names_does_not_grow_the_worker(monkeypatch) -> None:
    """A gateway name is whatever a batch says: a worker keeps the clock offset and sequence
    numbers of MAX_GATEWAYS at most, forgetting the one heard from least lately (counted), and
    still takes every batch. Old code: one entry per name ever seen, without end (about 5 kB
    of offset samples each: a million names of garbage, gigabytes)."""
    import rfhoming.host.sitebus as bus

    monkeypatch.setattr(bus, "MAX_GATEWAYS", 8, raising=False)
    sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
    worker = _worker(sc)
    a = sc.anchors[0].id
    worker._inbox.extend((10.0, "rfhoming/w/angles/0", sitebus.encode_angles(f"gw{k}", 0, 10.0, 0.0,
                                                                             [(10.0, a, "T1", 5, 5)]))
                         for k in range(50))
    worker._drain()
    assert worker.counters["batches"] == 50 and worker.engine.counters["events"] == 50
    assert len(worker._min_delay) <= 8 and len(worker._seq) <= 8
    assert list(worker._min_delay) == [f"gw{k}" for k in range(42, 50)]  # the most lately heard kept
    assert worker.counters["gateways_forgotten"] == 42


class _UnavailableBroker:
    """A broker of our own that answers every CONNECT with CONNACK 3, "Server unavailable" (MQTT
    3.1.1 section 3.2.2.3: the one refusal a broker may lift by itself; Mosquitto never sends it)."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:  # closed
                return
            with conn:
                conn.settimeout(30)
                try:
                    conn.recv(4096)  # the CONNECT
                    conn.sendall(bytes([0x20, 0x02, 0x00, 0x03]))
                    conn.recv(4096)  # until the client closes
                except OSError:
                    pass

    def close(self) -> None:
        self.server.close()


def test_a_broker_unavailable_for_now_is_tried_again_with_back_off(caplog: pytest.LogCaptureFixture) -> None:
    """CONNACK 3 ("Server unavailable"): a serviced publisher on a clock that stands still tries
    once, however often it is serviced, and again only when the clock reaches 0.1 s doubling to
    5 s after the last try (it used to reset the delay on each TCP connect and try at every
    service(): thousands of logins a second). The first refusal is logged, the rest counted."""
    from rfhoming.host.sitebus import RECONNECT_MAX_S, RECONNECT_MIN_S, Broker, Publisher

    fake = _UnavailableBroker()
    now = [0.0]
    pub = Publisher(Broker("127.0.0.1", fake.port, False, None), "gw-unavailable", threaded=False,
                    clock=lambda: now[0])
    attempts: list[float] = []
    reconnect = pub.client.reconnect

    def counted() -> object:
        attempts.append(now[0])
        return reconnect()

    pub.client.reconnect = counted  # type: ignore[method-assign]
    caplog.set_level("DEBUG", logger="rfhoming.host.sitebus")
    try:
        due, delay = 0.0, RECONNECT_MIN_S
        for k in range(8):
            deadline = time.monotonic() + 60  # a hang guard: the broker's answer to try k
            while pub.counters["refused"] <= k and time.monotonic() < deadline:
                pub.service(0.01)
            assert pub.counters["refused"] == k + 1 and len(attempts) == k + 1 and attempts[-1] == due
            for stand in (due, due + delay * 0.99):  # the clock stands, then almost reaches the next try
                now[0] = stand
                for _ in range(20):
                    pub.service(0.0)
                assert len(attempts) == k + 1
            due += delay
            now[0] = due
            delay = min(RECONNECT_MAX_S, 2 * delay)
        gaps = [round(b - a, 6) for a, b in zip(attempts, attempts[1:])]
        assert gaps == [0.1, 0.2, 0.4, 0.8, 1.6, 3.2, 5.0]
        assert pub.counters["connects"] == 0 and not pub.connected.is_set() and pub.failure is None
        warned = [r for r in caplog.records if r.levelname == "WARNING" and "refused" in r.getMessage()]
        assert len(warned) == 1
    finally:
        pub.close()
        fake.close()


@needs_broker
def test_paho_holds_no_more_than_the_buffer_for_a_slow_broker(tmp_path: Path) -> None:
    """paho bounds only QoS > 0 (max_queued_messages); its QoS 0 packets wait in Client._out_packet
    without a bound while a broker reads slower than we publish. Mosquitto stopped (SIGSTOP) after
    the connection: the kernel's socket buffers fill, then paho holds at most ``buffer`` packets, the
    publisher's own buffer the next ``buffer`` (the oldest dropped, counted); Mosquitto continued,
    everything not dropped reaches it (mosquitto_sub reads the retained topics)."""
    from rfhoming.host.sitebus import Broker, Publisher

    port = _free_port()
    proc = _start_broker(tmp_path, port)
    pub = Publisher(Broker("127.0.0.1", port, False, None), "gw-slow", buffer=4, threaded=False)
    payload = b"x" * 500_000
    try:
        assert pub.wait_connected(120)
        proc.send_signal(signal.SIGSTOP)
        sent = 0
        while pub.counters["dropped"] < 2 and sent < 80:  # the kernel takes a few MB first
            pub.publish(f"big/{sent}", payload, retain=True)
            sent += 1
            assert len(pub.client._out_packet) <= 4
        assert pub.counters["dropped"] == 2 and pub.counters["buffered"] == 6
        proc.send_signal(signal.SIGCONT)
        deadline = time.monotonic() + 120  # a hang guard
        while (pub.counters["published"] < sent - 2 or pub.client.want_write()) and time.monotonic() < deadline:
            pub.service(0.05)
        assert pub.counters["published"] == sent - 2
        out, _ = _sub(port, "big/#", sent - 2, "-F", "%t").communicate(timeout=120)
        got = set(out.split())
        assert len(got) == sent - 2 and f"big/{sent - 1}" in got and "big/0" in got
    finally:
        proc.send_signal(signal.SIGCONT)
        pub.close()
        proc.terminate()
        proc.wait(30)


def test_tags_are_bounded_once_the_pairs_are_full(monkeypatch) -> None:
    """MAX_PAIRS bounds the tags too: a new tag becomes a row only with a pair (one the pair limit
    refuses used to become a row anyway, its height, report time and tracker row with it)."""
    from rfhoming.host.estimation import batch

    monkeypatch.setattr(batch, "MAX_PAIRS", 3)
    sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
    loc = BatchLocator(_site(sc), track=True)
    a0, a1 = sc.anchors[0].id, sc.anchors[1].id
    loc.feed([(10.0, a, f"T{k}", 5, 5) for k in range(6) for a in (a0, a1)])  # T0 both, T1 one of its two
    assert loc.tags == ["T0", "T1"] and len(loc._heights) == len(loc._reported) == 2
    assert loc.counters["overflow"] == 9 and loc.counters["events"] == 3
    loc.feed([(10.1, a0, "T9", 5, 5), (10.1, a0, "T0", 6, 6), (10.1, a0, "T0", 7, 7)])  # full: old pairs only
    assert loc.tags == ["T0", "T1"] and len(loc.tracker.t) <= 2 and loc.counters["overflow"] == 10
    assert loc.counters["events"] == 5
    loc.tick(10.2)  # the rows and the pairs agree


# -- the broker away, killed and back; hostile messages; names; self-describing positions ------------------
def test_a_worker_without_a_broker_runs_warns_and_closes(caplog: pytest.LogCaptureFixture) -> None:
    """No broker at the URL: the worker runs, says so once as a warning, and close() returns (it
    raised paho's RuntimeError "The client is not currently connected", so --duration and Ctrl-C
    ended in exit 1 and no counters)."""
    from rfhoming.host.sitebus import Broker, Worker

    sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
    caplog.set_level("WARNING", logger="rfhoming.host.sitebus")
    worker = Worker(_site(sc), Broker("127.0.0.1", _free_port(), False, None), worker_id="w", partitions=1)
    stop = threading.Event()
    tries = 0
    reconnect = worker.pub.client.reconnect

    def counted() -> object:  # stop after a few tries, whatever the machine's speed
        nonlocal tries
        tries += 1
        if tries >= 3:
            stop.set()
        return reconnect()

    worker.pub.client.reconnect = counted  # type: ignore[method-assign]
    worker.run(stop=stop)
    worker.close()
    health = worker.health()
    assert health["mqtt_connects"] == 0 and health["mqtt_published"] == 0
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len([m for m in warned if "not reachable" in m]) == 1, warned


@pytest.mark.parametrize("url", ["mqtt://h/0", "mqtt://h/1025", "mqtt://h/1000000000", "mqtt://h:0/8", "mqtt://h/-1",
                                 "mqtt://h/٣", "mqtt://h/8?qos=1", "mqtt://h/8#x", "mqtt://a..b/8", "mqtt://h:99999/8"])
def test_broker_urls_the_site_bus_cannot_use_are_refused(url: str) -> None:
    from rfhoming.host.sitebus import Broker, BrokerError

    with pytest.raises(BrokerError):
        Broker.parse(url)


def test_broker_urls_the_site_bus_can_use() -> None:
    from rfhoming.host.sitebus import Broker

    assert Broker.parse("mqtt://h/1024").partitions == 1024
    assert Broker.parse("mqtts://u:p@h").port == 8883 and Broker.parse("h:1884/8/").port == 1884


@pytest.mark.parametrize("args", [["locate", "site-16x40", "--from", "mqtt://127.0.0.1:1/0"],
                                  ["locate", "site-16x40", "--from", "mqtt://127.0.0.1:1/1000000000"],
                                  ["locate", "site-16x40", "--from", "mqtt://127.0.0.1:1/8", "--id", "a/#"],
                                  ["locate", "site-16x40", "--from", "mqtt://127.0.0.1:1/8", "--id", ""],
                                  ["gateway", "--emulate", "site-16x40", "--broker", "mqtt://127.0.0.1:1/0"],
                                  ["gateway", "--emulate", "site-16x40", "--broker", "mqtt://127.0.0.1:1/8",
                                   "--site-name", "a/+/#"],
                                  ["gateway", "--device", "xplr-aoa:/dev/null", "--site-name", "s",
                                   "--name", "gw+1", "--broker", "mqtt://127.0.0.1:1/8"]],
                         ids=["partitions-0", "partitions-1e9", "id-wildcard", "id-empty", "gw-partitions-0",
                              "site-wildcard", "gw-name-wildcard"])
def test_site_bus_names_and_partitions_are_refused_in_one_line(args: list[str], tmp_path: Path) -> None:
    """A partition count of 0 (accepted, exit 0), of 10^9 (a worker hashing a billion partitions:
    a hang), a name with MQTT's wildcards or level separator (a publish paho refuses: exit 1):
    refused by the parser (its usage, then one error line naming it), exit 2, before any connection."""
    proc = subprocess.run([sys.executable, "-m", "rfhoming.cli.main", *args, "--duration", "1"], env=ENV, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.splitlines()[-1].startswith(f"rfhoming {args[0]}: error:")


def _last_json(proc: subprocess.Popen) -> dict:
    out, _ = proc.communicate(timeout=30)  # the process has ended: what it printed
    return json.loads(out.strip().splitlines()[-1])


def _wait_for(path: Path, text: str, count: int = 1, timeout: float = 120) -> None:
    """Until ``text`` is in the log ``count`` times (a hang guard, not a speed check)."""
    deadline = time.monotonic() + timeout
    while path.read_text().count(text) < count:
        assert time.monotonic() < deadline, f"{text!r} x{count} not in {path.name}: {path.read_text()[-1500:]}"
        time.sleep(0.05)


def _positions(port: int, site: str, count: int) -> list[dict]:
    out, _ = _sub(port, f"rfhoming/{site}/positions/#", count).communicate(timeout=300)
    return [json.loads(line.split(" ", 1)[1]) for line in out.splitlines()]


@pytest.mark.slow
@needs_broker
def test_workers_and_gateways_survive_a_hostile_message_and_a_broker_killed_and_restarted(tmp_path: Path) -> None:
    """A worker and an emulated gateway started with no broker: each warns and runs. Mosquitto
    starts: positions (mosquitto_sub). 1,000 ``[`` and other hostile messages on every angle topic
    (mosquitto_pub): counted in bad_payload, warned once, positions go on. Mosquitto SIGKILLed:
    each warns; restarted on the same port: positions again. Killed again, both stopped with
    SIGINT while it is away: exit 0, each prints its counters. (Before: the gateway gave no
    warning; the hostile message ended the worker with exit 1; a stop with no broker was exit 1
    with no counters.)"""
    port, site = _free_port(), "site-16x40"
    url = f"mqtt://127.0.0.1:{port}/4"
    logs = {name: tmp_path / f"{name}.log" for name in ("worker", "gateway")}
    procs = {"worker": _cli(logs["worker"], "locate", site, "--from", url, "--id", "w1", "--rate", "20"),
             "gateway": _cli(logs["gateway"], "gateway", "--emulate", site, "--broker", url)}
    broker = None
    try:
        for log in logs.values():
            _wait_for(log, "not reachable")
        broker = _start_broker(tmp_path, port)
        assert len(_positions(port, site, 20)) == 20
        pub = shutil.which("mosquitto_pub") or "mosquitto_pub"
        for payload in (b"[" * 1000, b'{"v":2,"seq":' + b"9" * 5000 + b"}", b'{"v":1e999}'):
            for part in range(4):
                subprocess.run([pub, "-h", "127.0.0.1", "-p", str(port), "-t", f"rfhoming/{site}/angles/{part}",
                                "-s"], input=payload, check=True, timeout=60)
        _wait_for(logs["worker"], "not an angle batch")
        assert len(_positions(port, site, 20)) == 20  # published after the hostile messages
        for restart in (True, False):
            broker.kill()
            broker.wait(30)
            for log in logs.values():
                _wait_for(log, "lost the MQTT broker", 1 if restart else 2)
            if restart:
                broker = _start_broker(tmp_path, port)
                # both back (the first "reached" was at the start): the worker's positions alone do
                # not say so, since it sends what it buffered while the broker was away, and a
                # gateway still in its back-off when the broker goes again is never "lost" twice
                for log in logs.values():
                    _wait_for(log, "reached after", 2)
                assert len(_positions(port, site, 20)) == 20
        for proc in procs.values():
            proc.send_signal(signal.SIGINT)
        codes = {name: proc.wait(60) for name, proc in procs.items()}
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(30)
        if broker is not None and broker.poll() is None:
            broker.kill()
            broker.wait(30)
    assert codes == {"worker": 0, "gateway": 0}, {n: log.read_text()[-1500:] for n, log in logs.items()}
    worker, gateway = _last_json(procs["worker"]), _last_json(procs["gateway"])
    assert worker["kind"] == "worker" and worker["bad_payload"] >= 12 and worker["positions"] > 0
    assert worker["mqtt_connects"] == 2 and gateway["connects"] == 2 and gateway["published"] > 0
    warned = [line for line in logs["worker"].read_text().splitlines() if "not an angle batch" in line]
    assert len(warned) == 1 and "WARNING" in warned[0]


@pytest.mark.slow
@pytest.mark.parametrize("args", [["locate", "site-16x40", "--from", "URL", "--duration", "2"],
                                  ["gateway", "--emulate", "site-16x40", "--broker", "URL", "--duration", "2"]],
                         ids=["worker", "gateway"])
def test_with_no_broker_a_worker_or_gateway_warns_and_ends_at_duration_with_its_counters(
        args: list[str], tmp_path: Path) -> None:
    """Nothing listens at the broker's port: exit 0 at --duration, a warning that nothing is
    published, the counters line (the worker ended in exit 1 without counters; the gateway waited
    10 s for the broker first and said nothing)."""
    url = f"mqtt://127.0.0.1:{_free_port()}/4"
    proc = subprocess.run([sys.executable, "-m", "rfhoming.cli.main", *[url if a == "URL" else a for a in args]],
                          env=ENV, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "WARNING" in proc.stderr and "not reachable" in proc.stderr and "nothing is published" in proc.stderr
    counters = json.loads(proc.stdout.strip().splitlines()[-1])
    assert counters["kind"] in ("worker", "gateways")
    assert counters.get("published", counters.get("mqtt_published")) == 0


POSITION_SCHEMA = Path(__file__).resolve().parents[1] / "docs" / "schemas" / "position.schema.json"


def _schema_validator():
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads(POSITION_SCHEMA.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema, format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER)


def test_the_position_payload_matches_its_schema_and_says_what_it_is() -> None:
    """The codec's own output against docs/schemas/position.schema.json (the published one:
    below, through Mosquitto); and the schema refuses version 1's payload (no site, frame, units)."""
    validator = _schema_validator()
    body = json.loads(sitebus.position_payload("hall", 1796148054.5, "T1", np.array([1.0, 2.0, 0.9]), np.eye(3) * 0.01,
                                               ["A1", "A2"], ["A3"], 0.75, "w1", latency_s=0.05))
    validator.validate(body)
    assert (body["site"], body["frame"], body["time"], body["units"]["x"]) == (
        "hall", "map", "2026-12-01T18:00:54.500000Z", "m")
    old = {"v": 1, "t": 1796148054.5, "tag": "T1", "x": 1.0, "y": 2.0, "z": 0.9, "cov": [[0.0] * 3] * 3,
           "anchors": ["a001"], "rejected": [], "quality": 0.75, "worker": "w1"}
    assert not validator.is_valid(old)


def test_locate_names_the_quality_as_the_site_bus_does() -> None:
    from rfhoming.host.locate import Position

    line = Position(1.0, "T1", np.zeros(3), np.eye(3), ("a",), (), True, 0.5).as_dict()
    assert line["chi2_per_dof"] == 0.5 and "rms" not in line


@pytest.mark.slow
@needs_broker
def test_positions_read_by_mosquitto_sub_match_the_schema(broker: int, tmp_path: Path) -> None:
    """Emulated gateways -> Mosquitto -> a worker -> mosquitto_sub: every position it reads is valid
    against docs/schemas/position.schema.json, names its site, the map frame and the same time
    twice, and names its anchors by the ids the angle batches carry (it named them a001, the
    batches A00001)."""
    from datetime import datetime

    validator = _schema_validator()
    site, url = "site-16x40", f"mqtt://127.0.0.1:{broker}/4"
    procs = [_cli(tmp_path / "worker.log", "locate", site, "--from", url, "--id", "w1", "--rate", "20"),
             _cli(tmp_path / "gateway.log", "gateway", "--emulate", site, "--broker", url)]
    try:
        batches, _ = _sub(broker, f"rfhoming/{site}/angles/#", 20).communicate(timeout=300)
        positions = _positions(broker, site, 40)
    finally:
        for proc in procs:
            proc.send_signal(signal.SIGINT)
        for proc in procs:
            proc.wait(60)
    batch_anchors = {a for line in batches.splitlines() for a in json.loads(line.split(" ", 1)[1])["anchors"]}
    assert len(positions) == 40
    for p in positions:
        errors = [e.message for e in validator.iter_errors(p)]
        assert not errors, (errors, p)
        assert p["site"] == site and p["frame"] == "map" and p["worker"] == "w1"
        assert datetime.fromisoformat(p["time"].replace("Z", "+00:00")).timestamp() == pytest.approx(p["t"], abs=1e-6)
        assert set(p["anchors"]) <= set(SiteScenario.named(site).anchor_ids)
    assert {a for p in positions for a in p["anchors"]} & batch_anchors
