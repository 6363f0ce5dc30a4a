"""Hostile input files through the commands a user runs: each refused with one line naming the file and
exit 2, never an internal error (the house review of 2026-12, "Inputs without limits"; protocol/textfile.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from rfhoming.protocol.textfile import MAX_BYTES, MAX_DEPTH

ROOT = Path(__file__).resolve().parent.parent
PROFILE = ROOT / "protocol" / "profiles" / "measured.toml"
DEEP = "a = " + "[" * 100_000 + "]" * 100_000 + "\n"


def refused(done: Any, *expected: str) -> str:
    """The one line the command printed, after checking it exited 2 with no traceback."""
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-2000:]
    assert "internal error" not in lines[0] and "Traceback" not in done.stderr
    for text in expected:
        assert text in lines[0], lines[0]
    return str(lines[0])


@pytest.mark.parametrize("command", [
    ("emulate", "s0-house", "--radio", "{}"),
    ("campaign", "s0-house", "--radio", "{}"),
    ("config", "--check", "{}"),
    ("locate", "{}", "--from", "capture:none.pcapng"),
    ("emulate", "{}"),
], ids=["profile", "campaign-radio", "config", "site", "scenario"])
@pytest.mark.parametrize("content,expected", [
    (DEEP, f"more than {MAX_DEPTH} deep"),
    ("a = " + "{b = " * 40 + "1" + "}" * 40 + "\n", f"more than {MAX_DEPTH} deep"),
    ("# padding\n" * (MAX_BYTES // 10 + 1), f"larger than {MAX_BYTES:,} bytes"),
], ids=["arrays-1e5-deep", "tables-40-deep", "over-1MiB"])
def test_a_toml_file_too_deep_or_too_large_is_refused_in_one_line(
        cli: Callable[..., Any], tmp_path: Path, command: tuple[str, ...], content: str, expected: str) -> None:
    path = tmp_path / "hostile.toml"
    path.write_text(content)
    done = cli(*(part.format(path) for part in command), timeout_s=120)
    refused(done, str(path), expected)


def test_a_400_digit_number_in_a_profile_is_refused_naming_its_key(cli: Callable[..., Any], tmp_path: Path) -> None:
    text = PROFILE.read_text()
    assert "\nbias_deg = " in text
    head, tail = text.split("\nbias_deg = ", 1)
    path = tmp_path / "huge.toml"
    path.write_text(head + "\nbias_deg = " + "9" * 400 + "\n" + tail.split("\n", 1)[1])
    refused(cli("emulate", "s0-house", "--radio", str(path), timeout_s=120), str(path), "bias_deg = 999", "expected a number")


def test_a_400_digit_number_in_a_config_is_refused_naming_its_key(cli: Callable[..., Any], tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text("[calibration]\np0_dbm = -" + "9" * 400 + "\n")
    refused(cli("config", "--check", str(path), timeout_s=120), "p0_dbm", "expected a number")


WALK = ("1670598717410,NaN,240,480", "1670598719949,NaN,240,360", "1670598722480,1670598723480,240,240",
        "1670598724965,NaN,360,120")  # the layout of girolami_xplr_aoa/ground_truth/*.csv: ms, ms, cm, cm


def rows(*replace: tuple[int, str]) -> str:
    """WALK with row ``index`` replaced (or, past its end, appended)."""
    lines = list(WALK)
    for index, row in replace:
        lines[index:index + 1] = [row]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("content,expected", [
    (rows((3, "1670598724965,NaN,1000000000000,120")).encode(), "row 4: the waypoint (1e+10, 1.2) m is more than 100 km"),
    (rows((3, "1670598724965,NaN,4800,120")).encode(), "row 4: the waypoint (48, 1.2) m lies outside the site"),
    (rows((4, f"{1670598724965 + 10**15},NaN,240,120")).encode(), "row 5: arrives 1e+12 s after the previous time"),
    (rows((3, WALK[0])).encode(), "row 4: arrives before the previous"),
    (("arrival_ms,leave_ms,x_cm,y_cm\n" + rows()).encode("utf-16"), "is not UTF-8 text (line 1, byte 0 is 0xff)"),
    (rows().encode("utf-16-le"), "line 1 holds a NUL byte: UTF-16?"),
    (("arrivée_ms,leave_ms,x_cm,y_cm\n" + rows()).encode("latin-1"), "is not UTF-8 text (line 1, byte 5 is 0xe9)"),
    ("".join(f"{1670598717410 + 100 * i},NaN,240,120\n" for i in range(10**6)).encode(), "larger than 1,048,576 bytes"),
    ("".join(f"{1670598717410 + 100 * i},NaN,240,120\n" for i in range(10_001)).encode(), "row 10001: more than 10,000"),
], ids=["1e10-m", "outside-site", "1e15-ms-later", "backwards", "utf-16", "utf-16-no-bom", "latin-1", "1e6-rows",
        "10001-rows"])
def test_a_bad_ground_truth_file_is_refused_naming_its_row(
        cli: Callable[..., Any], tmp_path: Path, content: bytes, expected: str) -> None:
    """radio-fit reads every --truth before any recording (the 2026-12 field report: a mistyped waypoint fitted a -47 deg curve)."""
    truth = tmp_path / "walk.csv"
    truth.write_bytes(content)
    done = cli("radio-fit", str(ROOT / "docs" / "sites" / "kit-room.toml"), "--from", "capture:none.pcapng",
               "--truth", str(truth), "-o", str(tmp_path / "out.toml"), timeout_s=120)
    refused(done, str(truth), expected)
    assert not (tmp_path / "out.toml").exists()


def test_a_byte_order_mark_is_no_row(tmp_path: Path) -> None:
    from rfhoming.host.groundtruth import load_waypoints

    truth = tmp_path / "walk.csv"
    truth.write_bytes(("\ufeff" + rows()).encode())
    assert len(load_waypoints(truth).waypoints) == 4


@pytest.mark.parametrize("rate,burst,fix", [(0.99, 1.0, "at least 99"), (0.6, 1.0, "at least 1.5")])
def test_a_loss_rate_its_bursts_cannot_give_is_refused(
        cli: Callable[..., Any], tmp_path: Path, rate: float, burst: float, fix: str) -> None:
    """A two-state chain with runs of mean B loses at most B / (B + 1): the emulator capped 0.99 at 0.53."""
    text = PROFILE.read_text()
    head, tail = text.split("\n[aoa.missing]\n", 1)
    path = tmp_path / "lossy.toml"
    path.write_text(f"{head}\n[aoa.missing]\nrate_low = 0.0\nrate_high = {rate}\nburst_events = {burst}\n"
                    + tail[tail.index("\n["):])
    refused(cli("emulate", "s0-house", "--radio", str(path), timeout_s=120), str(path), "[aoa.missing]",
            "lose at most 0.5 of the events", f"set burst_events to {fix}")


def test_a_loss_rate_within_its_bursts_is_honoured() -> None:
    """Asked 0.9 in runs of 9 (the most such runs give), the board loses 0.9."""
    import numpy as np

    from rfhoming.emulator.aoa_error import MeasuredAoa
    from rfhoming.protocol.radio_profile import AoaProfile, Missing

    profile = AoaProfile(missing=Missing(rate_low=0.9, rate_high=0.9, burst_events=9.0))
    board = MeasuredAoa(profile, "A1", np.random.default_rng(3), room_seed=1)
    pose = (0.0, 0.0, 0.0, 0.0)
    lost = sum(board.report("T", k * 0.1, 10.0, 5.0, pose, pose) is None for k in range(40_000))
    assert lost / 40_000 == pytest.approx(0.9, abs=0.01)


@pytest.mark.parametrize("mode,warned", [(0o644, True), (0o640, True), (0o600, False), (0o400, False)])
def test_a_password_file_others_can_read_is_warned_of_once(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, mode: int, warned: bool) -> None:
    """As ssh does for a private key: one line naming the file, its mode and the fix; the login goes on."""
    from rfhoming.host.sitebus import Broker

    path = tmp_path / "w1.pass"
    path.write_text("secret\n")
    path.chmod(mode)
    with caplog.at_level("WARNING", logger="rfhoming.host.sitebus"):
        broker = Broker.parse("mqtt://w1@127.0.0.1/8").login(str(path))
    assert broker.password == "secret"
    said = [r.getMessage() for r in caplog.records]
    assert said == ([f"--password-file {path} can be read by other users (mode {mode:03o}): chmod 600 {path}"]
                    if warned else []), said
