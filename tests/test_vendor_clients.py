"""The emulated boards against programs rfhoming did not write: plain pyserial sessions that
follow the vendors' own bring-up, so a misreading the emulator and the drivers share cannot pass.

- XPLR-AOA: u-blox's clients stop the stream first (AoAController ``start()``: ``AT+UDFENABLE=0``
  "turn off everything while also checking that communication is working"; Door-Demo's Disable
  button), read identification, then ``AT+UDFENABLE=1`` and split each ``+UUDF`` line on commas,
  needing at least 9 fields (u-blox/XPLR-AOA-Door-Demo ``Form1.cs``, ``timerRxData_Tick``).
- ESP-AT: Espressif's "Bluetooth LE AT Examples": ``AT+BLEINIT=1``, ``AT+BLESCANPARAM=0,0,0,100,50``,
  ``AT+BLESCAN=1,3`` and the reports that follow, closed by ``+BLESCANDONE``.
- A board as other programs leave it: a door-demo derivative's "MAC filter" stores
  ``AT+UDFFILT=2,2,"<id>"``, ``AT&W``, ``AT+CPWROFF``; a board told not to stream at start
  (``AT+UDFCFG=3,0``, ``AT&W``, ``AT+CPWROFF``) is quiet -- rfhoming must report the one and find
  the other, and a receiver that never answers ends ``listen`` with exit 2.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rigs

serial = pytest.importorskip("serial")

RFHOMING = [sys.executable, "-m", "rfhoming"]


def emulate(tmp_path: Path, scenario: str, *args: str) -> tuple[rigs.World, dict[str, str]]:
    world = rigs.emulate(scenario, *args, "--seed", "1", link_dir=tmp_path)
    return world, {name: e.get("path") or e.get("url", "") for name, e in world.endpoints.items()}


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
        proc.stop()


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
        proc.stop()


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
        proc.stop()
    assert "AC:00:00:00:00:0" in out and "RSSI: -" in out and "UUID-16:FEAA" in out, out[-500:]


def session(path: str, *commands: bytes, baud: int = 115200) -> list[bytes]:
    """Send each command in turn and wait for its final code, as a terminal user would."""
    answers = []
    with serial.Serial(path, baud, timeout=0.2, rtscts=True) as port:
        for command in commands:
            port.write(command + b"\r")
            answers.append(read_until(port, b"OK\r\n" if command != b"AT+CPWROFF" else b"+STARTUP"))
    return answers


def rfhoming_until(args: list[str], wanted: str, stream: str = "stderr", timeout: float = 60) -> tuple[str, str]:
    """Run rfhoming until ``wanted`` appears on ``stream`` (a hang guard bounds it), then stop it."""
    with rigs.Child([*RFHOMING, *args]) as proc:
        proc.until(wanted, timeout, stream)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    return proc.output()


@pytest.mark.slow
def test_a_filter_stored_by_another_program_is_reported_then_cleared(tmp_path: Path) -> None:
    """The door-demo derivative's "MAC filter" order; then rfhoming without tags= says so, and
    tags=none clears it (AT+UDFFILT=2 reads back empty)."""
    proc, ports = emulate(tmp_path, "s0-open")
    try:
        session(ports["aoa"], b'AT+UDFFILT=2,2,"000000000000"', b"AT&W", b"AT+CPWROFF")
        _, err = rfhoming_until(["listen", f"xplr-aoa:{ports['aoa']}", "--duration", "60"], "stored tag filter")
        assert "lets only 000000000000 through" in err and "tags=none" in err
        out, _ = rfhoming_until(["listen", f"xplr-aoa:{ports['aoa']},tags=none", "--duration", "60"], " angle ",
                                stream="stdout")
        assert " angle " in out
        assert b"+UDFFILT:2\r\n" in session(ports["aoa"], b"AT+UDFFILT=2")[0]
    finally:
        proc.stop()


@pytest.mark.parametrize("spec", ["esp-at:{}", pytest.param("hci:serial:{},1000000", marks=pytest.mark.slow)])
def test_a_receiver_that_never_answers_ends_listen_with_exit_2(spec: str) -> None:
    """A port where nothing answers (a pty nobody serves): one line naming it, exit 2, long before
    --duration."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        done = subprocess.run([*RFHOMING, "listen", spec.format(path), "--duration", "120"],
                              capture_output=True, text=True, timeout=90)
    finally:
        os.close(master)
        os.close(slave)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2, done.stderr[-2000:]
    assert last.startswith("rfhoming listen:") and path in last and ("set-up failed" in last or "said nothing" in last)
    if spec.startswith("esp-at"):
        assert "AT UART" in last


@pytest.mark.slow
def test_probe_baud_finds_a_quiet_board_and_no_message_repeats_the_given_rate(tmp_path: Path) -> None:
    """A board told not to stream at start, at 115200; the host at 1,000,000."""
    proc, ports = emulate(tmp_path, "s0-open")
    try:
        session(ports["aoa"], b"AT+UDFENABLE=0", b"AT+UDFCFG=3,0", b"AT&W", b"AT+CPWROFF")
        done = subprocess.run([*RFHOMING, "listen", f"xplr-aoa:{ports['aoa']},baud=1000000", "--duration", "120"],
                              capture_output=True, text=True, timeout=90)
        assert done.returncode == 2 and "--probe-baud" in done.stderr, done.stderr[-2000:]
        assert "baud=1000000" not in done.stderr  # never suggest the rate the user gave
        out, err = rfhoming_until(["listen", f"xplr-aoa:{ports['aoa']},baud=1000000", "--probe-baud",
                                   "--duration", "60"], " angle ", stream="stdout")
        assert "answers at 115200 baud" in err and " angle " in out
    finally:
        proc.stop()


@pytest.mark.parametrize("dialect", ["1.0", "1.2", "2.x", "embed"])
def test_identification_strings_are_quoted(tmp_path: Path, dialect: str) -> None:
    """AT+GMM, AT+GMR, ATI9 answer quoted strings, as u-blox's C209 tag answers AT+GMM
    (c209-aoa-tag src/at_host.c), the only public firmware that answers it."""
    scenario = tmp_path / "s0.toml"
    preset = Path(__file__).resolve().parents[1] / "emulator" / "scenarios" / "s0-open.toml"
    scenario.write_text(preset.read_text().replace('dialect = "1.2"', f'dialect = "{dialect}"'))
    proc, ports = emulate(tmp_path, str(scenario))
    try:
        _, gmm, gmr, ati9 = session(ports["aoa"], b"AT+UDFENABLE=0", b"AT+GMM", b"AT+GMR", b"ATI9")
    finally:
        proc.stop()
    for answer in (gmm, gmr, ati9):
        info = [line for line in answer.split(b"\r\n") if line and not line.startswith((b"AT", b"OK", b"+UUDF"))]
        assert info and info[-1].startswith(b'"') and info[-1].endswith(b'"'), answer
