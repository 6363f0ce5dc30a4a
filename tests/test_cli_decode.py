"""``rfhoming decode`` is the protocol layer's black-box interface; golden captures guard it."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from rfhoming.cli.main import build_parser, main
from rfhoming.protocol import devices

GOLDEN = Path(__file__).parent / "golden"
"""Each golden input ``NAME.raw`` has beside it ``NAME.jsonl``: a header of ``#`` lines naming its
``protocol:`` and saying where the bytes came from (``source:``), then exactly what ``rfhoming
decode`` prints for it. A new pair in the folder is a new test case."""
NAMES = sorted(p.stem for p in GOLDEN.glob("*.raw"))


def golden(name: str) -> tuple[dict[str, str], str]:
    """The header of ``NAME.jsonl`` (key -> text, continuation lines joined) and its expected output."""
    lines = (GOLDEN / f"{name}.jsonl").read_text().splitlines(keepends=True)
    header: dict[str, str] = {}
    key = ""
    while lines and lines[0].startswith("#"):
        text = lines.pop(0)[1:].strip()
        head, colon, rest = text.partition(":")
        if colon and head.isidentifier() and not text.startswith(" "):
            key = head
            header[key] = rest.strip()
        else:
            header[key] += " " + text
    return header, "".join(lines)


@pytest.mark.parametrize("name", NAMES)
def test_golden_captures_decode_as_recorded(name: str, capsys) -> None:
    header, expected = golden(name)
    assert main(["decode", "--protocol", header["protocol"], str(GOLDEN / f"{name}.raw")]) == 0
    assert capsys.readouterr().out == expected


def test_every_wire_protocol_has_golden_bytes_that_say_where_they_came_from() -> None:
    assert {p.stem for p in GOLDEN.glob("*.jsonl")} == set(NAMES)  # every input has its output, and back
    headers = {name: golden(name)[0] for name in NAMES}
    assert all(len(h.get("source", "")) > 40 for h in headers.values()), headers
    assert {devices.protocol(h["protocol"]).name for h in headers.values()} == set(devices.PROTOCOLS)


def test_counters_line_sums_every_item(capsys) -> None:
    main(["decode", "--protocol", "frames", str(GOLDEN / "rss_node_stream.raw")])
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    counters = lines[-1]
    assert counters.pop("kind") == "counters"
    assert sum(counters.values()) == len(lines) - 1
    assert counters["drop.torn"] == 1 and counters["odometry"] == 1


def test_stdin_and_installed_entry_point() -> None:
    raw = (GOLDEN / "xplr_aoa_session.raw").read_bytes()
    done = subprocess.run(
        [sys.executable, "-m", "rfhoming", "decode", "--protocol", "uconnect", "-"],
        input=raw, capture_output=True, check=True, timeout=60,
    )
    assert done.stdout.decode() == golden("xplr_aoa_session")[1]


def test_missing_file_is_a_clear_error(capsys, tmp_path) -> None:
    assert main(["decode", "--protocol", "frames", str(tmp_path / "nope.bin")]) == 2
    assert "cannot open" in capsys.readouterr().err


def test_help_teaches_with_examples(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["decode", "--help"])
    out = capsys.readouterr().out
    assert "examples:" in out and "uconnect" in out


def _actions(parser: argparse.ArgumentParser, path: str = "rfhoming"):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield f"{path} {name}", "(subcommand)", helps.get(name)
                yield from _actions(sub, f"{path} {name}")
        else:
            yield path, "/".join(action.option_strings) or action.dest, action.help


def test_every_subcommand_and_option_has_a_help_line() -> None:
    missing = [f"{where} {what}" for where, what, text in _actions(build_parser()) if not text]
    assert not missing, f"no help text: {missing}"


def test_version_is_the_installed_one() -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "--version"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == f"rfhoming {version('rfhoming')}"
