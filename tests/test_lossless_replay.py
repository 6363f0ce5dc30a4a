"""A recording replays whole: every place a capture feeds a consumer waits for it, at any speed.

The capture is what a third-party logger gives: 60 s of four XPLR-AOA anchors' inbound bytes
only (no set-up exchange), three tags each heard at 20 Hz (the C209 tag's 50 ms advertising
interval, docs/protocol.md), one line per read as a port delivers them.
"""

from __future__ import annotations

import asyncio
import json
import math
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rigs
from stalls import reproducible

import rfhoming
import rfhoming.api
from rfhoming.host import site as sites
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.estimation.anchors3d import board_angles

RFHOMING = [sys.executable, "-m", "rfhoming"]
SITE = Path(__file__).resolve().parents[1] / "docs" / "sites" / "kit-room.toml"
SECONDS, RATE_HZ = 60.0, 20.0
PATHS = {  # kit-room's tags walked over the room at their heights
    "CCF9578E0D8A": lambda t: (6 + 4.5 * math.cos(t / 10), 3 + 2.2 * math.sin(t / 10), 1.0),
    "CCF9578E0D8B": lambda t: (2 + 8 * abs((t / 30) % 2 - 1), 1 + 4 * abs((t / 20) % 2 - 1), 0.5),
    "CCF9578E0D8C": lambda t: (6 + 4 * math.sin(t / 7), 3 + 2.2 * math.cos(t / 9), 1.2),
}
EVENTS = int(SECONDS * RATE_HZ) * len(PATHS) * 4


@pytest.fixture(scope="module")
def long_capture(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lossless") / "angles.pcapng"
    site = sites.load(SITE)
    rng = np.random.default_rng(7)
    writer = CaptureWriter(path)
    for a in site.anchors:
        writer.describe(a.name, kind="xplr-aoa")
    lines = []
    for k in range(int(SECONDS * RATE_HZ)):
        for i, (tag, at) in enumerate(PATHS.items()):
            for j, a in enumerate(site.anchors):
                t = k / RATE_HZ + i * 0.013 + j * 0.003 + rng.uniform(0, 0.002)
                az, el = board_angles(a.rotation().T @ (np.array(at(t)) - np.array(a.position)))
                az, el = az + rng.normal(0, 1.0), el + rng.normal(0, 2.0)
                line = f'+UUDF:{tag},-42,{round(az)},{round(el)},-43,37,"{a.id}","",{int(t * 1000)}\r\n'
                lines.append((1000.0 + t, a.name, line.encode()))
    for t, port, data in sorted(lines):
        writer.tap(port, "in", t, data)
    writer.close()
    return path


def _cli(*argv: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*RFHOMING, *argv], capture_output=True, text=True, timeout=timeout)


def _counters(stderr: str) -> list[dict]:
    return [json.loads(line) for line in stderr.splitlines() if line.startswith('{"kind": "counters"')]


def _whole(counters: list[dict]) -> None:
    """Four anchors, every angle decoded, none dropped on the way."""
    assert len(counters) == 4
    assert sum(c["decoder.angle"] for c in counters) == EVENTS
    assert all(c["queue_dropped"] == 0 for c in counters), [c["queue_dropped"] for c in counters]


@pytest.mark.slow  # end to end on 14,400 events: 15-40 s each on a shared machine
def test_locate_uses_every_event_of_a_long_capture_at_any_speed(long_capture):
    """Old code: anchor after anchor with nothing in between, so a handful of positions, and
    half of each anchor's events counted as dropped from its queue."""
    fast = _cli("locate", str(SITE), "--from", f"capture:{long_capture}")
    assert fast.returncode == 0, fast.stderr
    _whole(_counters(fast.stderr))
    summary = json.loads(fast.stdout.splitlines()[-1])
    assert summary["events"] == EVENTS and summary["late"] == 0 and summary["overflow"] == 0
    positions = fast.stdout.splitlines()[:-1]
    assert len(positions) >= 0.95 * SECONDS * 10 * len(PATHS)  # the site's 10 Hz for every tag
    paced = _cli("locate", str(SITE), "--from", f"capture:{long_capture},speed=50")
    assert paced.returncode == 0, paced.stderr
    assert reproducible(paced.stdout) == reproducible(fast.stdout)


@pytest.mark.slow
def test_locate_at_the_recorded_pace_prints_what_as_fast_as_possible_does(long_capture):
    fast = _cli("locate", str(SITE), "--from", f"capture:{long_capture},speed=0")
    paced = _cli("locate", str(SITE), "--from", f"capture:{long_capture},speed=1", timeout=300)
    assert fast.returncode == paced.returncode == 0, paced.stderr
    _whole(_counters(paced.stderr))
    assert reproducible(paced.stdout) == reproducible(fast.stdout)


@pytest.mark.slow  # end to end on 14,400 events: 15-40 s each on a shared machine
def test_self_calibration_takes_every_event_of_a_long_capture(long_capture):
    """Old code: each anchor's queue counted about half its events as dropped."""
    runs = [_cli("calibrate", str(SITE), "--self", "--from", f"capture:{long_capture}{speed}", "--dry-run", "--verbose")
            for speed in ("", ",speed=50")]
    for run in runs:
        assert run.returncode == 0, run.stderr
        _whole(_counters(run.stderr))
    assert runs[0].stdout == runs[1].stdout and runs[0].stdout.strip()


@pytest.mark.slow  # end to end on 14,400 events: 15-40 s each on a shared machine
def test_replay_prints_every_event_in_recorded_order(long_capture):
    """Old code: each device's whole recording in turn (a consumer merging them saw anchors
    minutes apart)."""
    fast = _cli("replay", str(long_capture), "--json")
    assert fast.returncode == 0, fast.stderr
    lines = [json.loads(line) for line in fast.stdout.splitlines()]
    angles = [line for line in lines if line.get("kind") == "angle"]
    assert len(angles) == EVENTS
    times = [a["t"] for a in angles]
    assert times == sorted(times)
    _whole([line for line in lines if line.get("kind") == "counters"])
    paced = _cli("replay", str(long_capture), "--json", "--speed", "50")
    assert [line for line in paced.stdout.splitlines() if '"kind": "angle"' in line] == \
        [line for line in fast.stdout.splitlines() if '"kind": "angle"' in line]


@pytest.mark.slow
def test_the_api_hands_a_slow_caller_every_event_of_a_capture(long_capture):
    """Old code: the capture ran ahead of the caller and the items past its queue were dropped."""
    got = []
    devices = rfhoming.open(f"capture:{long_capture}", kinds={"angle"})
    for n, item in enumerate(devices):
        got.append(item.t)
        if n % 2000 == 0:
            time.sleep(0.05)  # a caller busy now and then
    assert len(got) == EVENTS and devices.dropped == 0 and got == sorted(got)
    _whole(devices.health())

    async def slow_async() -> tuple[list[float], int]:
        seen = []
        stream = rfhoming.open(f"capture:{long_capture},speed=0", kinds={"angle"})
        async for item in stream:
            seen.append(item.t)
            if len(seen) % 3000 == 0:
                await asyncio.sleep(0.05)
        return seen, stream.dropped

    seen, dropped = asyncio.run(slow_async())
    assert seen == got and dropped == 0


MOSQUITTO = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None)
SUB = shutil.which("mosquitto_sub")


@pytest.mark.slow
@pytest.mark.skipif(not (MOSQUITTO and SUB), reason="mosquitto / mosquitto-clients not installed")
def test_a_gateway_on_a_capture_publishes_every_event(long_capture, tmp_path):
    """Old code: each anchor's queue counted about half its events as dropped. Mosquitto's own
    mosquitto_sub counts what reached the broker."""
    from test_sitebus import _free_port, _start_broker

    from rfhoming.protocol import sitebus

    port = _free_port()
    broker = _start_broker(tmp_path, port)
    try:
        sub = subprocess.Popen([SUB, "-h", "127.0.0.1", "-p", str(port), "-t", "rfhoming/kit-room/angles/#",
                                "-W", "120"], stdout=subprocess.PIPE, text=True)
        time.sleep(1.0)  # subscribed before the gateway publishes (no retained batches)
        gw = _cli("gateway", "--broker", f"mqtt://127.0.0.1:{port}", "--site", str(SITE),
                  "--device", f"capture:{long_capture}", "--flush", "0.2")
        assert gw.returncode == 0, gw.stderr
        _whole(_counters(gw.stderr))
        line = json.loads(gw.stdout.splitlines()[-1])
        assert line["events"] == EVENTS and line["dropped"] == 0
        batches: list[str] = []
        deadline = time.monotonic() + 120
        while len(batches) < line["published"] and time.monotonic() < deadline:
            batches.append(rigs.readline(sub, "stdout", max(0.0, deadline - time.monotonic())).strip())
        sub.terminate()
        heard = sum(len(sitebus.decode_angles(b.encode()).events) for b in batches if b)
        assert heard == EVENTS
    finally:
        broker.terminate()
        broker.wait(30)


def test_leaving_a_capture_early_ends_its_thread(tmp_path, monkeypatch):
    """A caller who stops reading while its queue is full (a recording waits for it, so it is
    full whenever the caller is the slower) must not leave the devices' thread blocked on that
    queue. Old code: the pump's blocking put of the end never returned; close() waited its 5 s,
    and the thread (with the capture open) was left behind for good."""
    monkeypatch.setattr(rfhoming.api, "QUEUE_SIZE", 20)
    path = tmp_path / "short.pcapng"
    writer = CaptureWriter(path)
    writer.describe("a", kind="xplr-aoa")
    for k in range(500):
        writer.tap("a", "in", 1000 + k * 0.01, f'+UUDF:CCF9578E0D8A,-42,{k % 90},10,-43,37,"A","",{k}\r\n'.encode())
    writer.close()
    devices = rfhoming.open(f"capture:{path}", kinds={"angle"})
    full = threading.Event()
    hand_over = devices._hand_over

    def watched(out, got):
        taken = hand_over(out, got)
        if not taken:
            full.set()  # the caller's queue is full: the recording waits for the caller
        return taken

    devices._hand_over = watched
    for _ in devices:
        assert full.wait(60), "the caller's queue never filled"
        break
    assert devices._thread is not None
    devices._thread.join(timeout=30)  # a generous bound: the fixed code ends at once
    assert not devices._thread.is_alive()
