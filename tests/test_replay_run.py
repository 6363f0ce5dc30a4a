"""A homing run replays from its capture: `rfhoming replay CAPTURE --run` runs the
recorded loop again on the recorded bytes and writes the live run log line for line -- for
every controller and every receiver, on runs made through ptys by the commands a user runs."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from stalls import reproducible

ROOT = Path(__file__).resolve().parent.parent


def rfhoming(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rfhoming", *args], capture_output=True, text=True, timeout=timeout)


def replayed(capture: Path, *extra: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    log = capture.parent / "replayed.jsonl"
    done = rfhoming("replay", str(capture), "--run", "--log", str(log), *extra)
    return done, log.read_text().splitlines() if log.exists() else []


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "receiver"), [
    ("s0-open", None),  # S0, XPLR-AOA
    ("s1-dock", None),  # S1, the station's XPLR-AOA
    ("s2-a", None),  # S2, the AT86RF212 node
    ("s3-arena", "esp32"),  # S3, rfhoming's ESP32 scanner
    ("s3-arena", "esp-at"),  # S3, ESP-AT
    ("s3-arena", "hci"),  # S3, a Bluetooth controller
])
def test_a_demo_run_replays_to_the_same_run_log(tmp_path: Path, scenario: str, receiver: str | None) -> None:
    # ideal radios: demo's status is the ground truth's (within 1 m of the target), replay's the loop's own
    # "arrived", and under the measured default S3 says it arrived 0.6-2.0 m off, either side of that metre
    demo = rfhoming("demo", "--scenario", scenario, *(["--receiver", receiver] if receiver else []), "--radio", "ideal",
                    "--json", "--out", str(tmp_path))
    assert demo.returncode in (0, 1), demo.stderr
    done, log = replayed(tmp_path / "capture.pcapng")
    assert done.returncode == demo.returncode, done.stderr
    summary = json.loads(done.stdout)
    assert summary["replay"] == {"diverged": 0, "unanswered": 0, "first_divergence": None}
    assert log == (tmp_path / "run.jsonl").read_text().splitlines()
    assert "set-up" not in done.stderr and "otherwise than the recording" not in done.stderr  # only the loop's own words


@pytest.mark.slow
def test_a_fixed_anchor_run_replays_to_the_same_run_log(tmp_path: Path, emulated) -> None:
    links = tmp_path / "links"
    links.mkdir()
    site = tmp_path / "site.toml"
    site.write_text(re.sub(r"/tmp/rfhoming-kit/", f"{links}/", (ROOT / "docs" / "sites" / "kit-home.toml").read_text()))
    (tmp_path / "robot.toml").write_text("[loop]\nodometry_wall_timeout_s = inf  # lockstep: wall time means nothing\n")
    with emulated("kit-home", "--pty", "--lockstep", "--seed", "2", link_dir=links):
        run = rfhoming("run", "--controller", "anchors", "--site", str(site), "--base", f"base:{links}/base",
                       "--config", str(tmp_path / "robot.toml"), "--capture", str(tmp_path / "run.pcapng"),
                       "--log", str(tmp_path / "run.jsonl"))
    assert run.returncode == 0, run.stderr
    done, log = replayed(tmp_path / "run.pcapng")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["replay"]["diverged"] == 0
    assert log == (tmp_path / "run.jsonl").read_text().splitlines()


@pytest.mark.slow
def test_another_config_on_the_same_capture_says_where_it_diverged(tmp_path: Path) -> None:
    demo = rfhoming("demo", "--json", "--out", str(tmp_path))
    assert demo.returncode == 0, demo.stderr
    other = tmp_path / "other.toml"
    other.write_text("[s0]\nv_max = 0.3\n")  # a slower robot: other commands from the first decision on
    done, log = replayed(tmp_path / "capture.pcapng", "--config", str(other))
    summary = json.loads(done.stdout)
    first = summary["replay"]["first_divergence"]
    assert first is not None and first["device"].endswith("base") and first["wrote"] != first["recorded"]
    assert "first wrote otherwise than the recording at t =" in done.stderr and done.stderr.count("\n") == 1
    assert log and log != (tmp_path / "run.jsonl").read_text().splitlines()  # it went on, from the recorded inputs


def test_a_capture_without_a_run_record_is_a_one_line_error(tmp_path: Path) -> None:
    from rfhoming.host.capture import CaptureWriter

    writer = CaptureWriter(tmp_path / "listen.pcapng")
    writer.describe("/dev/ttyUSB0", kind="xplr-aoa")
    writer.tap("/dev/ttyUSB0", "in", 1.0, b"+STARTUP\r\n")  # a capture is written once a port gave it a packet
    writer.close()
    done = rfhoming("replay", str(tmp_path / "listen.pcapng"), "--run")
    assert done.returncode == 2 and "holds no homing run's record" in done.stderr and done.stderr.count("\n") == 1


@pytest.mark.slow
def test_the_in_process_demo_gives_the_same_summary_for_the_same_seed(tmp_path: Path) -> None:
    runs = [rfhoming("demo", "--in-process", "--seed", "3", "--json", "--out", str(tmp_path / str(k))) for k in range(2)]
    summaries = [json.loads(r.stdout) for r in runs]
    for s in summaries:
        del s["files"]
    assert runs[0].returncode == 0 and summaries[0] == summaries[1]
    done, log = replayed(tmp_path / "0" / "capture.pcapng")
    assert json.loads(done.stdout)["replay"]["diverged"] == 0
    assert log == (tmp_path / "0" / "run.jsonl").read_text().splitlines()
    # the drivers alone: the board's +STARTUP waited in the in-process pipe when the host opened it, and
    # reaches the replayed driver before its first AT, as it did live (it once failed the set-up)
    drivers = rfhoming("replay", str(tmp_path / "0" / "capture.pcapng"), "--json")
    counters = {c["driver"]: c for c in map(json.loads, drivers.stdout.splitlines()) if c.get("kind") == "counters"}
    assert drivers.returncode == 0 and drivers.stderr == "", drivers.stderr
    assert all((c["diverged"], c["unanswered"]) == (0, 0) for c in counters.values()), counters
    assert counters["xplr-aoa"]["setups"] == 1 and counters["xplr-aoa"]["dialect"] is not None


@pytest.mark.slow
def test_a_run_takes_its_devices_from_a_capture_by_role(tmp_path: Path) -> None:
    """`run --aoa capture:F --base capture:F`: one device per role, no device= needed; the run
    log is the live one."""
    demo = rfhoming("demo", "--in-process", "--json", "--out", str(tmp_path))
    assert demo.returncode == 0, demo.stderr
    capture = tmp_path / "capture.pcapng"
    done = rfhoming("run", "--aoa", f"capture:{capture}", "--base", f"capture:{capture},device=base",
                    "--log", str(tmp_path / "again.jsonl"))
    assert done.returncode == 0, done.stderr
    assert reproducible((tmp_path / "again.jsonl").read_text()) == reproducible((tmp_path / "run.jsonl").read_text())
    wrong = rfhoming("run", "--aoa", f"capture:{capture},device=nope", "--base", f"capture:{capture}")
    assert wrong.returncode == 2 and "no device 'nope'" in wrong.stderr and "aoa" in wrong.stderr
    swapped = rfhoming("run", "--aoa", f"capture:{capture},device=base", "--base", f"capture:{capture}")
    assert swapped.returncode == 2 and "cannot be" in swapped.stderr and swapped.stderr.count("\n") == 1


@pytest.mark.slow
def test_a_run_with_spec_settings_replays_to_the_same_run_log(tmp_path: Path) -> None:
    """The run record keeps each device's spec: tags= (and scan settings) reach the replayed drivers."""
    demo = rfhoming("demo", "--in-process", "--json", "--out", str(tmp_path))
    assert demo.returncode == 0, demo.stderr
    capture = tmp_path / "capture.pcapng"
    run = rfhoming("run", "--aoa", f"capture:{capture},device=aoa", "--base", f"capture:{capture}", "--tag",
                   "CCF9578E0D8A", "--capture", str(tmp_path / "again.pcapng"), "--log", str(tmp_path / "again.jsonl"))
    assert run.returncode == 0, run.stderr
    done, log = replayed(tmp_path / "again.pcapng")
    assert json.loads(done.stdout)["replay"]["diverged"] == 0, done.stderr
    assert reproducible("\n".join(log)) == reproducible((tmp_path / "again.jsonl").read_text())
