"""Hostile input files through the commands a user runs: each refused with one line naming the file and
exit 2, never an internal error (issue 52, "Inputs without limits"; protocol/textfile.py)."""

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
