"""Done-when of host I/O: `rfhoming listen` on the emulator's pty shows live angles, survives
an unplug/replug and a reboot, and `capture` + `replay` reproduce the same decoded records."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import serial

from rfhoming.protocol.uconnect import UConnectDecoder

RFHOMING = [sys.executable, "-m", "rfhoming"]


def lines(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


class Lines:
    """A child's JSON lines, read in a thread; every wait has a deadline (a hang guard only:
    what the test waits for is what the child printed, not how long it took)."""

    def __init__(self, proc: subprocess.Popen, deadline_s: float = 300.0) -> None:
        self.items: list[dict] = []
        self.end = time.monotonic() + deadline_s
        self._queue: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._pump, args=(proc.stdout,), daemon=True).start()

    def _pump(self, stream) -> None:
        for line in stream:
            self._queue.put(line)
        self._queue.put(None)

    def until(self, done) -> bool:
        """Read until ``done(items)`` or the end of the output; True if done."""
        while not done(self.items):
            left = self.end - time.monotonic()
            assert left > 0, f"a hang guard: {len(self.items)} lines, the last {self.items[-3:]}"
            line = self._queue.get(timeout=left)
            if line is None:
                return False
            if line.strip():
                self.items.append(json.loads(line))
        return True


def set_up_after_the_reboot(items: list[dict], angles: int = 50) -> bool:
    """The board's ``+STARTUP`` (the reboot), then its set-up's ``AT+UDFENABLE=1``, then ``angles`` angles."""
    boot = next((k for k, i in enumerate(items) if i["kind"] == "startup"), None)
    enable = None if boot is None else next(
        (k for k, i in enumerate(items[boot:], boot) if i["kind"] == "echo" and i["text"] == "AT+UDFENABLE=1"), None)
    return enable is not None and sum(i["kind"] == "angle" for i in items[enable:]) >= angles


@pytest.mark.slow
def test_listen_capture_replay_through_unplug_and_reboot(tmp_path: Path, emulated) -> None:
    """The unplug and the reboot follow the host: each once the board has sent 20,000 bytes (about
    7 s of angles) since the host's last command -- its set-up done, unless it stalled that long
    between two commands -- and capture runs until it has set the rebooted board up: a loaded
    machine only makes it slower."""
    capture, log = tmp_path / "run.pcapng", tmp_path / "capture.log"
    with emulated("s0-open", "--seed", "4", "--fault", "unplug@aoa:after_bytes=20000,for=1",
                  "--fault", "reboot@aoa:after_bytes=20000", link_dir=tmp_path) as emulator:
        endpoints = emulator.endpoints
        with open(log, "w") as stderr:
            proc = subprocess.Popen(
                [*RFHOMING, "capture", endpoints["aoa"]["path"], f"base:{endpoints['base']['path']}",
                 "-o", str(capture), "--show", "--json"], stdout=subprocess.PIPE, stderr=stderr, text=True)
        try:
            out = Lines(proc)
            assert out.until(set_up_after_the_reboot), log.read_text()
            proc.send_signal(signal.SIGINT)
            out.until(lambda items: False)  # to its end: the counters
            status = proc.wait(timeout=30)
        finally:
            proc.kill()
    assert status == 0, log.read_text()
    items = out.items
    counters = {c["device"]: c for c in items if c["kind"] == "counters"}
    aoa = counters[endpoints["aoa"]["path"]]
    assert aoa["disconnects"] == 1 and aoa["reconnects"] == 1 and aoa["reboots"] == 1
    assert aoa["state"] == "streaming" and aoa["setups"] == 3
    angles = [i for i in items if i["kind"] == "angle"]
    assert len(angles) > 200
    replay = subprocess.run([*RFHOMING, "replay", str(capture), "--json"], capture_output=True, text=True, timeout=60)
    assert replay.returncode == 0, replay.stderr
    replayed = lines(replay.stdout)
    for device in (endpoints["aoa"]["path"], endpoints["base"]["path"]):
        a = [i for i in items if i["device"] == device and i["kind"] != "counters"]
        b = [i for i in replayed if i["device"] == device and i["kind"] != "counters"]
        assert a == b and len(a) > 100
    tshark_like = subprocess.run([*RFHOMING, "replay", str(tmp_path / "missing.pcapng")], capture_output=True, text=True,
                                 timeout=60)
    assert tshark_like.returncode == 2 and "cannot read" in tshark_like.stderr


@pytest.mark.slow
def test_replay_serves_a_capture_on_ptys(tmp_path: Path, spawn) -> None:
    from rfhoming.protocol import pcapng

    data = b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869\r\n'
    blob = pcapng.section_header() + pcapng.interface("/dev/ttyACM0", "protocol=ublox-aoa", 147)
    blob += b"".join(pcapng.packet(0, 100.0 + 0.05 * k, data, pcapng.INBOUND) for k in range(20))
    (tmp_path / "c.pcapng").write_bytes(blob)
    links = tmp_path / "links"
    links.mkdir()
    server = spawn("replay", tmp_path / "c.pcapng", "--pty", "--link-dir", links)
    endpoint = server.json_line(what="the pty's endpoint")
    port = serial.Serial(endpoint["path"], 115200, timeout=0.1)
    got, end = b"", time.monotonic() + 3
    while time.monotonic() < end and got.count(b"+UUDF") < 15:
        got += port.read(4096)
    port.close()
    server.wait(timeout=10)
    assert sum(1 for i in UConnectDecoder().feed(got) if i.kind == "angle") >= 15
