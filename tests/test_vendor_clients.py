"""The emulated boards against programs rfhoming did not write: plain pyserial sessions that
follow the vendors' own bring-up (issue 23, "Independent checks").

- XPLR-AOA: u-blox's clients stop the stream first (AoAController ``start()``: ``AT+UDFENABLE=0``
  "turn off everything while also checking that communication is working"; Door-Demo's Disable
  button), read identification, then ``AT+UDFENABLE=1`` and split each ``+UUDF`` line on commas,
  needing at least 9 fields (u-blox/XPLR-AOA-Door-Demo ``Form1.cs``, ``timerRxData_Tick``).
- ESP-AT: Espressif's "Bluetooth LE AT Examples": ``AT+BLEINIT=1``, ``AT+BLESCANPARAM=0,0,0,100,50``,
  ``AT+BLESCAN=1,3`` and the reports that follow, closed by ``+BLESCANDONE``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

serial = pytest.importorskip("serial")

RFHOMING = [sys.executable, "-m", "rfhoming"]


def emulate(tmp_path: Path, *args: str) -> tuple[subprocess.Popen, dict[str, str]]:
    proc = subprocess.Popen([*RFHOMING, "emulate", *args, "--seed", "1", "--link-dir", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    endpoints: dict[str, str] = {}
    for line in proc.stdout:
        if not line.startswith("{"):
            break
        entry = json.loads(line)
        endpoints[entry["device"]] = entry.get("path") or entry.get("url", "")
        if len(endpoints) >= 2:
            break
    return proc, endpoints


def read_until(port: serial.Serial, token: bytes, timeout: float = 10.0) -> bytes:
    """Everything read until ``token`` (a hang guard, not a speed requirement)."""
    data = b""
    deadline = time.monotonic() + timeout
    while token not in data:
        assert time.monotonic() < deadline, data[-300:]
        data += port.read(port.in_waiting or 1)
    return data


def test_ublox_bring_up_with_plain_pyserial(tmp_path: Path) -> None:
    proc, ports = emulate(tmp_path, "s0-open")
    try:
        with serial.Serial(ports["aoa"], 115200, timeout=0.2, rtscts=True) as port:
            port.write(b"AT+UDFENABLE=0\r")
            read_until(port, b"OK\r\n")
            port.write(b"AT+GMM\r")
            assert b"OK\r\n" in read_until(port, b"OK\r\n")
            port.write(b"AT+UDFENABLE=1\r")
            read_until(port, b"OK\r\n")
            lines = read_until(port, b"\r\n", 10) + read_until(port, b"+UUDF:", 10)
            lines += read_until(port, b"\r\n", 10)
        uudf = lines[lines.index(b"+UUDF:"):].split(b"\r\n")[0].decode()
        param = uudf.split(",")
        assert len(param) >= 9  # the Door-Demo's check
        assert -90 <= int(param[2]) <= 90 and param[6].strip('"')  # azimuth, anchor id
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.slow
def test_espressif_ble_scan_example_with_plain_pyserial(tmp_path: Path) -> None:
    """The "Bluetooth LE AT Examples" scan: init the client role, set the example's scan
    parameters, scan 3 s, read the reports and +BLESCANDONE (the emulated board is ESP-AT 3.2)."""
    proc, ports = emulate(tmp_path, "s3-arena", "--receiver", "esp-at")
    try:
        with serial.Serial(ports["ble"], 115200, timeout=0.2) as port:
            port.write(b"AT+BLEINIT=1\r\n")
            read_until(port, b"OK\r\n")
            port.write(b"AT+BLESCANPARAM=0,0,0,100,50\r\n")
            read_until(port, b"OK\r\n")
            port.write(b"AT+BLESCAN=1,3\r\n")
            out = read_until(port, b"+BLESCANDONE", 30)
        reports = [line for line in out.decode().split("\r\n") if line.startswith("+BLESCAN:")]
        assert reports
        addr, rssi, adv, _rsp, addr_type = reports[0][len("+BLESCAN:"):].split(",")
        assert addr.startswith('"') and -100 < int(rssi) < 0 and bytes.fromhex(adv) and addr_type in "0123"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.slow
def test_bumble_scan_app_against_the_emulated_controller(tmp_path: Path) -> None:
    """bumble's own ``bumble-scan`` (its Host and Device bring-up, not rfhoming's) hears the
    emulated beacons through the emulated controller."""
    import shutil

    scan = shutil.which("bumble-scan")
    if scan is None:
        pytest.skip("bumble-scan is not installed (pip install 'rfhoming[hci]')")
    proc, ports = emulate(tmp_path, "s3-arena", "--receiver", "hci")
    try:
        try:
            done = subprocess.run([scan, "--passive", "--filter-duplicates", "false", f"serial:{ports['ble']},1000000"],
                                  capture_output=True, text=True, timeout=8)
            out = done.stdout
        except subprocess.TimeoutExpired as expired:  # it scans until stopped
            out = (expired.stdout or b"").decode() if isinstance(expired.stdout, bytes) else (expired.stdout or "")
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert "AC:00:00:00:00:0" in out and "RSSI: -" in out and "UUID-16:FEAA" in out, out[-500:]
