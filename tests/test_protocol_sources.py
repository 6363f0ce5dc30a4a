"""docs/protocol.md: every row of a device-behaviour table names its source or says *assumed*
(so a reader can check each one, and knows which are guesses), and every bracketed source it uses is listed on the page."""

from __future__ import annotations

import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"
BEHAVIOUR_SECTIONS = ("Line discipline", "The angle event", "Dialects", "Commands rfhoming sends",
                      "per firmware family", "The emulated board", "AT86RF212", "ESP-AT", "Bluetooth HCI")
"""Headings whose first table describes a device (the decoder's own tables are not device facts)."""
SOURCE = re.compile(r"\[[A-Z][A-Za-z0-9.-]*\]|Core Spec|esp-at|google/bumble|github\.com|UART|above|\*\*assumed\*\*")


def tables(text: str) -> list[tuple[str, list[str], list[list[str]]]]:
    """(heading, header cells, rows) of every markdown table."""
    out, heading, lines = [], "", text.split("\n")
    for i, line in enumerate(lines):
        if line.startswith("#"):
            heading = line
        if line.startswith("|") and i + 1 < len(lines) and lines[i + 1].startswith("|---"):
            rows, j = [], i + 2
            while j < len(lines) and lines[j].startswith("|"):
                rows.append(cells(lines[j]))
                j += 1
            out.append((heading, cells(line), rows))
    return out


def cells(line: str) -> list[str]:
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def test_every_device_table_has_a_source_column() -> None:
    found = {section: False for section in BEHAVIOUR_SECTIONS}
    for heading, header, _ in tables(DOC.read_text()):
        for section in BEHAVIOUR_SECTIONS:
            if section in heading and not found[section]:
                found[section] = True
                assert header[-1] == "source", f"{heading}: the first table has no source column: {header}"
    assert all(found.values()), [s for s, ok in found.items() if not ok]


def test_no_row_has_neither_a_source_nor_assumed() -> None:
    bad = []
    for heading, header, rows in tables(DOC.read_text()):
        if header[-1] != "source":
            continue
        for row in rows:
            if len(row) != len(header) or not SOURCE.search(row[-1]):
                bad.append(f"{heading}: {row[0]!r} -> {row[-1]!r}")
    assert not bad, "\n".join(bad)


def test_bracketed_sources_are_listed() -> None:
    text = DOC.read_text()
    tag = r"\[([A-Z][A-Za-z0-9]*(?:-[A-Za-z0-9.]+)*)\]"
    used = {re.sub(r"^ESPAT-.*", "ESPAT", t) for t in re.findall(tag, text)}
    definitions = [line for line in text.split("\n") if re.match(r"(- )?\[[A-Z]", line)]
    listed = {t for line in definitions for t in re.findall(tag, line)} | {"ESPAT"}  # [ESPAT-x]: one tag per version
    assert used <= listed, used - listed


def test_the_rule_catches_a_row_without_source(tmp_path: Path) -> None:
    """The check can fail: a row with an empty source cell is reported."""
    row = "| `AT+FOO` | `OK` | |"
    header = "| command | answer | source |\n|---|---|---|\n"
    (_, head, rows), = tables("### Commands rfhoming sends\n" + header + row)
    assert head[-1] == "source" and not SOURCE.search(rows[0][-1])
