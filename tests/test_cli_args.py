"""Command-line arguments that cannot work are refused by the parser -- exit 2 and the reason --
before any device is opened or emulator started: non-finite or negative numbers, a target that
is not X,Y, an output file that cannot be created."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from rfhoming.cli.main import build_parser
from rfhoming.demo import DemoError, start_emulator

RFHOMING = [sys.executable, "-m", "rfhoming"]
SITE = str(Path(__file__).resolve().parent.parent / "docs" / "sites" / "kit-room.toml")


@pytest.mark.parametrize("argv,message", [
    (["locate", SITE, "--duration", "nan"], "argument --duration: 'nan': expected a finite number"),
    (["locate", SITE, "--accel-psd", "nan"], "argument --accel-psd: 'nan': expected a finite number"),
    (["locate", SITE, "--rate", "0"], "argument --rate: '0': expected a number more than 0"),
    (["listen", "auto", "--duration", "-1"], "argument --duration: '-1': expected a number more than 0"),
    (["replay", "x.pcapng", "--speed", "inf"], "argument --speed: 'inf': expected a finite number"),
    (["emulate", "s0-open", "--duration", "x"], "argument --duration: 'x' is not a number"),
    (["emulate", "s0-open", "--target=1,nan"], "argument --target: '1,nan': expected X,Y in metres"),
    (["demo", "--target", "x"], "argument --target: 'x': expected X,Y in metres"),
    (["serve", "auto", "--queue", "0"], "argument --queue: '0': expected a whole number more than 0"),
    (["capture", "-o", "/proc/forbidden.pcapng", "/dev/ttyNOPE"], "argument -o/--output: cannot write /proc/forbidden"),
    (["run", "--log", "/no/such/folder/run.jsonl"], "argument --log: cannot write /no/such/folder/run.jsonl"),
])
def test_the_parser_refuses(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_a_writable_output_is_not_left_behind_by_the_check(tmp_path: Path) -> None:
    out = tmp_path / "run.pcapng"
    args = build_parser().parse_args(["capture", "-o", str(out), "/dev/ttyNOPE"])
    assert args.output == out and not out.exists()


def test_capture_to_a_forbidden_path_opens_no_device() -> None:
    done = subprocess.run([*RFHOMING, "capture", "-o", "/proc/forbidden.pcapng", "/dev/ttyNOPE"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "cannot write /proc/forbidden.pcapng" in done.stderr and "ttyNOPE" not in done.stderr.splitlines()[-1]


def test_an_emulator_that_does_not_start_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(DemoError, match=r"the emulator did not start: rfhoming emulate: no scenario 'nope'"):
        start_emulator("nope", 1, tmp_path / "truth.jsonl", tmp_path, None)
