"""References a maintainer can follow: no tracker numbers as reasons, no private notes as sources.

A bare issue number names no tracker and dates badly: the reason belongs where the number
stood. A fact from outside the repository cites its public source (docs/protocol.md's
"Sources", the datasets in docs/RESULTS.md) or is marked *assumed* there, never the notes
folder kept beside the checkout, which a clone does not have.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SUFFIXES = {".py", ".md", ".toml", ".c", ".h", ".txt", ".cfg", ".yml", ".yaml", ".sh", ".json", ".xml", ".msg"}
SKIP_DIRS = {"__pycache__", "node_modules", "build", "dist", "out"}
RULES = {
    "a tracker number as a reason": re.compile(r"\bissues?[ -]?#?[0-9]", re.I),  # with a space, a '#' or a '-'
    # the notes folder beside the checkout, by its path or by its files' names
    "a private note as a source": re.compile(r"(?:^|[^\w/.-])shared[/]|\.\./shared\b|\b(?:methods|protocols|style)[.]md\b"),
}
"""A URL such as github.com/OWNER/REPO/issues/3 names its tracker and passes."""


def texts(root: Path) -> list[Path]:
    """Code and docs under ``root``: no hidden or build folders, no venvs, links not followed
    (``rfhoming/host`` is ``host/`` again)."""
    found = []
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if (not d.startswith(".") or d == ".ci") and d not in SKIP_DIRS
                   and not d.endswith(".egg-info") and not (Path(folder, d) / "pyvenv.cfg").exists()]
        found += [Path(folder, f) for f in files if Path(f).suffix in SUFFIXES or f == "run"]
    return sorted(found)


def offences(root: Path) -> list[str]:
    """``path:line: rule: text`` for every line of ``root``'s code and docs that breaks a rule."""
    out = []
    for path in texts(root):
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            out += [f"{path.relative_to(root)}:{number}: {rule}: {line.strip()}"
                    for rule, pattern in RULES.items() if pattern.search(line)]
    return out


def test_code_and_docs_give_reasons_and_public_sources() -> None:
    found = offences(ROOT)  # this file too: its examples are split so that they do not match
    assert not found, "write the reason or cite the public source instead:\n" + "\n".join(found)


def test_the_check_finds_each_form(tmp_path: Path) -> None:
    """The check can fail: each form a mention took in this tree is caught, in code and in docs."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "notes.md").write_text(
        "## Estimation (issue" + " 5)\nsee Issue" + " #12 and (" + "issues" + " 7 and 16)\n"
        "the sign in shared" + "/protocols" + ".md\nreads .." + "/shared" + "/data by default\nas in methods" + ".md §S0\n"
        "fine: https://github.com/u-blox/c209-aoa-tag/issues/3 and a shared 2-core machine\n")
    (tmp_path / "mod.py").write_text('"""Why (S0 ' + 'issue' + ' 16): ...; the ' + 'issue' + '-2 speed targets."""\n')
    found = offences(tmp_path)
    assert [f.split(":")[1] for f in found] == ["1", "2", "3", "4", "5", "1"], found
    assert sum("tracker number" in f for f in found) == 3 and sum("private note" in f for f in found) == 3
