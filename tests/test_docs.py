"""Docs that run: every ```python and ```sh example in README.md and docs/*.md.

Rules, so that a reader can trust an example (docs/api.md says the same for users):
- ```python blocks of one file run in order in one fresh interpreter (later blocks see earlier
  names), in a scratch folder that holds ``tests``, ``bench`` and ``docs`` of this checkout.
- ```sh blocks run line by line in bash in that folder. ``$ CMD`` lines are followed by the
  output CMD must print (``...`` matches anything); other lines must just succeed. ``CMD &``
  starts CMD in the background (stopped at the end of the block).
- ``pip install`` lines must install this project (``.`` or ``'.[extra]'``); they are checked,
  not re-run: the suite runs on that installation. The test command itself (README) is checked
  to be the one .ci/run runs, not run inside itself.
- A comment line ``<!-- long-running -->`` right before a block: each command is judged by what it
  prints, not by a wall clock: the lines the doc shows after ``$ CMD``, else its first output (on
  stdout or stderr), each waited for up to TIMEOUT_S, or its successful end; it is then terminated
  (servers, campaigns, benchmarks: their results are checked by their own tests and recorded in
  docs/) and must not have printed a traceback.
- ``<!-- not-run: needs ... -->`` right before a block: not run, for what the machine cannot
  have (hardware, a cluster); the reason must say what is needed. ``<!-- needs-hardware -->``
  is short for ``not-run: needs hardware``.
- ``<!-- slow -->`` right before a block: run as usual, but only in the full suite (the quick
  loop ``-m "not slow"`` leaves it out); ``long-running`` blocks are slow too.
- ``<!-- needs: TOOL[, TOOL...] -->`` right before a block: run where every TOOL is on PATH,
  skipped with the reason where one is missing (tshark: .ci/run installs it; a laptop with
  only Python skips).
"""

from __future__ import annotations

import fnmatch
import os
import re
import selectors
import shlex
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest
import rigs

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"(?:^<!-- (?P<mark>[^>]*?) -->\n)?^```(?P<lang>python|sh)\n(?P<body>.*?)^```$", re.M | re.S)
TIMEOUT_S = 600.0  # a hang guard: a long example on a loaded machine is slow, not wrong


def blocks(path: Path) -> list[tuple[str, str, str, int]]:
    """(language, marker, body, line) of every runnable fence."""
    text = path.read_text()
    return [(m["lang"], m["mark"] or "", m["body"], text.count("\n", 0, m.start("body")) + 1)
            for m in FENCE.finditer(text)]


KIT = "/tmp/rfhoming-kit"
"""The link directory the docs' examples and shipped site files name; each example gets its own
(two test runs at once would otherwise swap each other's emulated boards)."""


def scratch(tmp_path: Path) -> Path:
    """A working directory like the repository's top, with its own kit link directory."""
    for name in ("tests", "bench"):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / "docs").mkdir()
    for entry in (ROOT / "docs").iterdir():
        if entry.name != "sites":
            (tmp_path / "docs" / entry.name).symlink_to(entry)
    (tmp_path / "docs" / "sites").mkdir()
    (tmp_path / "tmp").mkdir()
    for site in (ROOT / "docs" / "sites").iterdir():
        (tmp_path / "docs" / "sites" / site.name).write_text(site.read_text().replace(KIT, str(tmp_path / "kit")))
    return tmp_path


TMP_PATH = re.compile(r"(?<![\w/.-])/tmp/(rfhoming-kit(?![\w.-]))?")


def own_tmp(text: str, cwd: Path) -> str:
    """The example's /tmp paths (its kit directory among them) moved into its own directory, in one pass."""
    return TMP_PATH.sub(lambda m: f"{cwd}/kit" if m[1] else f"{cwd}/tmp/", text)


def env() -> dict[str, str]:
    """The examples' ``rfhoming`` is this interpreter's (its environment's scripts first on PATH), activated or not."""
    path = os.pathsep.join([sysconfig.get_path("scripts"), os.environ["PATH"]])
    return {**os.environ, "PATH": path, "PYTHONUNBUFFERED": "1", "COLUMNS": "100"}


def strip_comment(line: str) -> str:
    """A trailing `` # comment`` outside quotes goes."""
    cut = line.find(" #")
    while cut != -1:
        head = line[:cut]
        if head.count("'") % 2 == 0 and head.count('"') % 2 == 0:
            return head.rstrip()
        cut = line.find(" #", cut + 1)
    return line.rstrip()


def check_pip(line: str) -> None:
    words = shlex.split(line)
    valued = {"-c", "--constraint", "-r", "--requirement"}  # options whose value is a file, not a target
    targets = [w for k, w in enumerate(words[2:], 2) if not w.startswith("-") and words[k - 1] not in valued]
    assert words[:2] == ["pip", "install"] and targets and all(t == "." or t.startswith(".[") for t in targets), \
        f"an install example must install this project: {line}"


def matches(expected: list[str], got: list[str]) -> bool:
    pattern = "\n".join(expected).replace("[", "[[]").replace("...", "*")
    return fnmatch.fnmatchcase("\n".join(got).strip(), pattern.strip())


def printed(proc: subprocess.Popen[str], deadline_s: float) -> bool:
    """Whether ``proc`` prints something (stdout or stderr: left unread in its pipes) or ends within the deadline."""
    with selectors.DefaultSelector() as pipes:
        for pipe in (proc.stdout, proc.stderr):
            assert pipe is not None
            pipes.register(pipe, selectors.EVENT_READ)
        return bool(pipes.select(deadline_s)) or proc.poll() is not None


def run_sh(body: str, cwd: Path, long: bool) -> None:
    lines = body.splitlines()
    background: list[subprocess.Popen] = []
    try:
        i = 0
        while i < len(lines):
            raw = lines[i]
            i += 1
            shown = raw.startswith("$ ")
            command = own_tmp(strip_comment(raw[2:] if shown else raw), cwd)
            expected = []
            if shown:
                while i < len(lines) and not lines[i].startswith("$ "):
                    expected.append(lines[i])
                    i += 1
            if not command.strip():
                continue
            if command.startswith("pip install"):
                for part in command.split("&&"):
                    if part.strip().startswith("pip install"):
                        check_pip(part.strip())
                rest = "&&".join(p for p in command.split("&&") if not p.strip().startswith("pip install")).strip()
                if rest == "python -m pytest":  # the test command: .ci/run runs it verbatim (not run inside itself)
                    assert command in (ROOT / ".ci" / "run").read_text(), f".ci/run must run {raw!r} as written"
                    continue
                command = rest
                if not command:
                    continue
            if command.endswith("&") or long:
                proc = subprocess.Popen(["bash", "-c", f"exec {command.rstrip('&')}"], cwd=cwd, env=env(), text=True,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
                background.append(proc)
                got = [rigs.readline(proc, "stdout", TIMEOUT_S).rstrip("\n") for _ in expected]
                assert matches(expected, got), f"{command!r} printed {got}, the doc shows {expected}"
                if command.endswith("&"):
                    continue
                assert expected or printed(proc, TIMEOUT_S), f"{command!r} printed nothing within {TIMEOUT_S:g} s"
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGTERM)
                out, err = proc.communicate(timeout=60)
                assert proc.returncode in (0, -signal.SIGTERM, 128 + signal.SIGTERM) and "Traceback" not in err, \
                    f"{command!r} failed ({proc.returncode}): {err[-2000:]}"
                continue
            done = subprocess.run(["bash", "-c", f"set -o pipefail; {command}"], cwd=cwd, env=env(), text=True,
                                  capture_output=True, timeout=TIMEOUT_S)
            assert done.returncode == 0, f"{command!r} failed ({done.returncode}): {done.stderr[-2000:]}"
            if expected:
                got = done.stdout.splitlines()
                assert matches(expected, got), f"{command!r} printed {got[:5]}..., the doc shows {expected}"
    finally:
        for proc in background:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.communicate(timeout=30)


def skip_reason(mark: str) -> str | None:
    """Why a block marked ``mark`` does not run here, or None if it runs."""
    if mark == "needs-hardware":
        return "needs hardware"
    if mark.startswith("not-run:"):
        assert re.match(r"not-run: needs \w+", mark), f"say what the example needs: {mark}"
        return mark
    if mark.startswith("needs:"):
        tools = [t.strip() for t in mark.removeprefix("needs:").split(",")]
        assert all(tools), f"name the tools: <!-- {mark} -->"
        missing = [t for t in tools if shutil.which(t) is None]
        return f"needs {', '.join(missing)}, which is not installed" if missing else None
    assert mark in ("", "long-running", "slow"), f"unknown marker <!-- {mark} -->"
    return None


CASES = [pytest.param(doc, k, id=f"{doc.relative_to(ROOT)}:{b[3]}",
                      marks=[pytest.mark.slow] if b[1] in ("long-running", "slow") else [])
         for doc in DOCS for k, b in enumerate(blocks(doc)) if b[0] == "sh"]


@pytest.mark.parametrize("doc,index", CASES)
def test_sh_example_runs(doc: Path, index: int, tmp_path: Path) -> None:
    _, mark, body, _ = blocks(doc)[index]
    reason = skip_reason(mark)
    if reason is not None:
        pytest.skip(reason)
    run_sh(body, scratch(tmp_path), long=mark == "long-running")


PY_DOCS = [doc for doc in DOCS if any(b[0] == "python" for b in blocks(doc))]


@pytest.mark.slow
@pytest.mark.parametrize("doc", PY_DOCS, ids=[str(d.relative_to(ROOT)) for d in PY_DOCS])
def test_python_examples_run(doc: Path, tmp_path: Path) -> None:
    python = [b for b in blocks(doc) if b[0] == "python"]
    for _, mark, _, line in python:
        assert mark != "long-running", f"{doc.name}:{line}: <!-- long-running --> is for ```sh blocks"
    runnable = [b for b in python if skip_reason(b[1]) is None]
    cwd = scratch(tmp_path)
    script = own_tmp("\n".join(body for _, _, body, _ in runnable), cwd)
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-c", script], cwd=cwd, env=env(), text=True,
                          capture_output=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, f"{doc.name}'s examples failed after {time.monotonic() - started:.1f} s:\n{done.stderr[-3000:]}"


def test_every_doc_example_is_run_or_says_what_it_needs() -> None:
    """A fence the runner does not know (```bash, ```console) would silently escape it."""
    for doc in DOCS:
        for lang in re.findall(r"^```(\w+)", doc.read_text(), re.M):
            assert lang in ("python", "sh", "text", "toml", "json", "lua", "c"), \
                f"{doc.name}: ```{lang} examples are not run; use ```sh or ```python (or ```text for output)"


def test_needs_marker_skips_only_where_a_tool_is_missing() -> None:
    """``<!-- needs: tshark -->`` runs on CI (tshark installed) and skips on a bare machine."""
    assert skip_reason("needs: sh") is None
    assert skip_reason("needs: sh, rfhoming-no-such-tool") == "needs rfhoming-no-such-tool, which is not installed"
    with pytest.raises(AssertionError, match="unknown marker"):
        skip_reason("need: tshark")


# -- the examples in each command's --help ---------------------------------------------------
HELP_EXAMPLE = re.compile(r"^ {2,}(?P<line>(?:mkdir|cat|rfhoming) .*)$", re.M)
RUN_HELP_EXAMPLES = {"locate"}
"""Commands whose --help examples run here as written (against the emulator): the one whose
example failed on a fresh machine. The others open hardware, run campaigns or serve forever;
they are parsed, which catches a renamed option, a bad value or a missing argument."""


def help_examples() -> list[tuple[str, str]]:
    """(command, example line) of every subcommand's --help."""
    import argparse

    from rfhoming.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return [(name, m["line"]) for name, p in sub.choices.items()
            for m in HELP_EXAMPLE.finditer(f"{p.description or ''}\n{p.epilog or ''}")]


def rfhoming_calls(line: str) -> list[list[str]]:
    """The argument lists of each ``rfhoming ...`` in an example line (pipes, &&, & and a
    trailing comment or parenthesised remark taken off)."""
    line = re.sub(r"\s{2,}\(.*\)$", "", strip_comment(line))
    calls = []
    for part in re.split(r"\s*(?:&&|\||&|;|\{|\})\s*", line):
        words = shlex.split(part) if part.strip() else []
        if words and words[0] == "rfhoming":
            calls.append(words[1:])
    return calls


def test_every_help_example_parses(tmp_path: Path, monkeypatch) -> None:
    from rfhoming.cli.main import build_parser

    monkeypatch.chdir(tmp_path)  # output files are tried (and removed) here
    examples = help_examples()
    assert len(examples) > 40 and {c for c, _ in examples} >= {"run", "demo", "locate", "listen", "emulate"}
    for command, line in examples:
        for argv in rfhoming_calls(line):
            try:
                build_parser().parse_args(argv)
            except SystemExit as exc:
                pytest.fail(f"rfhoming {command} --help example does not parse: {line} (exit {exc.code})")


@pytest.mark.slow
def test_help_examples_that_need_no_hardware_run(tmp_path: Path) -> None:
    link_dir = tmp_path / "kit"
    site = tmp_path / "docs" / "sites" / "kit-room.toml"
    site.parent.mkdir(parents=True)
    site.write_text((ROOT / "docs" / "sites" / "kit-room.toml").read_text().replace("/tmp/rfhoming-kit", str(link_dir)))
    ran = 0
    for command, line in help_examples():
        if command not in RUN_HELP_EXAMPLES or "/tmp/rfhoming-kit" not in line:
            continue
        ran += line.startswith("rfhoming emulate")
        done = subprocess.run(["bash", "-c", line.replace("/tmp/rfhoming-kit", str(link_dir))], cwd=tmp_path,
                              env=env(), capture_output=True, text=True, timeout=TIMEOUT_S)
        assert done.returncode == 0, f"{line}\n{done.stderr[-2000:]}"
        if line.startswith("rfhoming emulate"):
            assert '"kind": "position"' in done.stdout and '"kind": "summary"' in done.stdout, done.stdout[-500:]
    assert ran == 1
