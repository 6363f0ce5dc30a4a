"""The test rigs (tests/rigs.py, fixtures in tests/conftest.py) keep their promises: a silent
child fails the test at its deadline naming the command, every child is stopped however it
behaves, a command past its timeout is killed with its children, and no test file reads a
child's output without a deadline."""

from __future__ import annotations

import ast
import signal
import sys
import time
from pathlib import Path

import pytest
import rigs

PYTHON = [sys.executable, "-c"]
SILENT = "import time; time.sleep(600)"
STUBBORN = """\
import signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
print("ready", flush=True)
time.sleep(600)
"""


def alive(pid: int) -> bool:
    """Running: a zombie (killed, not yet reaped by init) counts as ended."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_a_silent_child_fails_the_test_at_its_deadline_naming_the_command() -> None:
    with rigs.Child([*PYTHON, SILENT]) as child:
        with pytest.raises(pytest.fail.Exception, match=r"time.sleep\(600\).*waited 0.5 s for the first line on stdout: none came"):
            child.line(0.5, "the first line")
    assert child.returncode is not None  # the with stopped it


def test_a_child_that_ends_before_its_line_fails_at_once_with_its_stderr() -> None:
    with rigs.Child([*PYTHON, "import sys; sys.exit('no devices here')"]) as child:
        with pytest.raises(pytest.fail.Exception, match=r"(?s)stdout ended \(exit code 1\) before an endpoint line.*no devices here"):
            child.line(60, "an endpoint line")


def test_stop_ends_a_child_that_ignores_sigint_and_sigterm(spawn) -> None:
    child = spawn(STUBBORN, argv0=PYTHON)
    assert child.line(60) == "ready\n"  # its handlers are in place
    assert child.stop(waits_s=(0.2, 0.2, 30)) == -signal.SIGKILL


@pytest.mark.slow
def test_run_kills_a_command_past_its_timeout_with_its_children_and_names_it(tmp_path: Path) -> None:
    """The grandchild is in the command's process group: SIGKILL reaches it too."""
    pid_file = tmp_path / "grandchild.pid"
    parent = (f"import subprocess, sys, time; p = subprocess.Popen([sys.executable, '-c', {SILENT!r}]); "
              f"open({str(pid_file)!r}, 'w').write(str(p.pid)); time.sleep(600)")
    with pytest.raises(pytest.fail.Exception, match=r"did not end within 10 s \(killed\)"):
        rigs.run(parent, argv0=PYTHON, timeout_s=10)
    if pid_file.exists():  # the parent had started the grandchild when its time was up
        grandchild = int(pid_file.read_text())
        end = time.monotonic() + 60  # a hang guard: init reaps it
        while alive(grandchild) and time.monotonic() < end:
            time.sleep(0.05)
        assert not alive(grandchild)


def test_cli_returns_code_stdout_and_stderr(cli) -> None:
    done = cli("decode", "--protocol", "nonsense", timeout_s=120)
    assert done.returncode == 2 and done.stdout == "" and "invalid choice: 'nonsense'" in done.stderr


def test_an_emulated_world_gives_its_endpoints_and_ends_on_ctrl_c(emulated) -> None:
    world = emulated("s0-open", "--tcp", "--seed", "1")
    assert set(world.endpoints) == {"aoa", "base"} and world.path("aoa").startswith("socket://127.0.0.1:")
    assert world.stop() == 0  # SIGINT was enough: its own clean-up ran
    assert world.stop() == 0  # and stopping again (as the fixture does after the test) is harmless


# -- no read of a child's output without a deadline ---------------------------------------------
UNBOUNDED_CALLS = ("subprocess.run", "subprocess.check_output", "subprocess.check_call", "subprocess.call")
PIPE_READS = (".stdout.readline", ".stdout.read", ".stdout.readlines", ".stderr.readline", ".stderr.read",
              ".stderr.readlines")


def unbounded_reads(source: str) -> list[str]:
    """Reads of a child's output with no deadline in ``source``: a run/communicate without
    ``timeout=``, readline/read on a child's pipe, a for loop over one. Calls awaited inside
    ``asyncio.timeout``/``asyncio.wait_for`` have their deadline outside and are not counted."""
    tree = ast.parse(source)
    guarded: set[int] = set()
    for node in ast.walk(tree):
        scopes = []
        if isinstance(node, ast.AsyncWith) and any("timeout" in ast.unparse(i.context_expr) for i in node.items):
            scopes = node.body
        elif isinstance(node, ast.Call) and ast.unparse(node.func).endswith("wait_for"):
            scopes = node.args[:1]
        guarded |= {id(n) for scope in scopes for n in ast.walk(scope)}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and id(node) not in guarded:
            name = ast.unparse(node.func)
            keywords = {k.arg for k in node.keywords}
            if name in UNBOUNDED_CALLS and "timeout" not in keywords:
                found.append(f"{node.lineno}: {name}(...) without timeout=")
            elif name.endswith(".communicate") and "timeout" not in keywords and len(node.args) < 2:
                found.append(f"{node.lineno}: {name}() without timeout=")
            elif name.endswith(PIPE_READS):
                found.append(f"{node.lineno}: {name}() on a child's pipe")
        if isinstance(node, ast.For) and ast.unparse(node.iter).endswith((".stdout", ".stderr")):
            found.append(f"{node.lineno}: for ... in {ast.unparse(node.iter)}")
    return found


def test_the_guard_finds_each_kind_of_unbounded_read() -> None:
    source = """
done = subprocess.run(["rfhoming", "listen"], capture_output=True)
line = proc.stdout.readline()
out, err = proc.communicate()
for line in proc.stderr:
    pass
ok = subprocess.run(["rfhoming", "listen"], capture_output=True, timeout=60)
ok, _ = proc.communicate(timeout=60)
async def f():
    async with asyncio.timeout(60):
        await proc.communicate()
    await asyncio.wait_for(proc.communicate(), 60)
"""
    assert sorted(int(f.split(":")[0]) for f in unbounded_reads(source)) == [2, 3, 4, 5]


def test_no_test_reads_a_childs_output_without_a_deadline() -> None:
    """tests/rigs.py's readers run on threads with deadlines; everything else goes through them
    or passes ``timeout=`` (a silent child then fails the test instead of hanging it 600 s)."""
    here = Path(__file__).parent
    found = {p.name: unbounded_reads(p.read_text()) for p in sorted(here.glob("*.py")) if p.name != "rigs.py"}
    found = {name: reads for name, reads in found.items() if reads}
    assert not found, (f"reads without a deadline (use tests/rigs.py: Child.line, rigs.readline, rigs.run, "
                       f"or pass timeout=): {found}")
