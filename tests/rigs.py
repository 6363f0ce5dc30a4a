"""Test rigs: rfhoming commands in child processes, read only with deadlines, always stopped.

Why one module: the suite starts ``rfhoming emulate`` (and ``serve``, ``capture``, ``run`` ...)
in many files, and a copy that reads a child's output without a deadline turns a silent child
into a 600 s hang, while one that forgets the stop leaves ptys and processes behind a failed
test. Here:

- :class:`Child` reads the child's stdout and stderr on threads, so :meth:`Child.line` waits
  at most its deadline and then fails the test naming the command and its last stderr lines;
- :meth:`Child.stop` ends a child however the test went: SIGINT (Ctrl-C: the command's own
  clean-up runs), then SIGTERM, then SIGKILL to its whole process group, waiting after each;
- :func:`emulate` starts ``rfhoming emulate SCENARIO ...`` and reads its endpoint lines;
- :func:`run` runs a command to its end with a timeout; past it the command's process group
  is killed and the test fails with the command line.

tests/conftest.py makes fixtures of these (``emulated``, ``spawn``, ``cli``) that stop every
child at the end of the test; module-scoped rigs use the context managers directly.
docs/testing.md shows how to write a test with them.
"""

from __future__ import annotations

import json
import os
import queue
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any, NoReturn

import pytest

RFHOMING = [sys.executable, "-m", "rfhoming"]
"""The command line of ``rfhoming``: this interpreter, so the worktree's package (PYTHONPATH) runs."""

LINE_S = 120.0
"""Default deadline for one line of a child: a hang guard for a loaded machine, not a speed check."""
RUN_S = 240.0
"""Default time for a command run to its end (a hang guard too)."""
STOP_WAITS_S = (30.0, 10.0, 10.0)
"""Waits after SIGINT, SIGTERM and SIGKILL."""
_EOF = object()


class Lines:
    """A child's text stream, read line by line on a daemon thread (so a read has a deadline)."""

    def __init__(self, stream: IO[str], name: str) -> None:
        self.seen: list[str] = []
        self._queue: queue.Queue[Any] = queue.Queue()
        self._thread = threading.Thread(target=self._pump, args=(stream,), name=name, daemon=True)
        self._thread.start()

    def _pump(self, stream: IO[str]) -> None:
        try:
            for line in iter(stream.readline, ""):
                self.seen.append(line)
                self._queue.put(line)
        except (OSError, ValueError):  # the pipe closed under the reader at the stop
            pass
        finally:
            self._queue.put(_EOF)

    def next(self, deadline_s: float) -> str | None:
        """The next line not taken yet; None at the end of the stream; raises queue.Empty past the deadline."""
        item = self._queue.get(timeout=deadline_s)
        if item is _EOF:
            self._queue.put(_EOF)  # the end stays the end for the next caller
            return None
        return item

    def rest(self, deadline_s: float) -> str:
        """Every line not taken yet, to the end of the stream (the child has ended)."""
        self._thread.join(deadline_s)
        taken = []
        try:
            while (line := self.next(0.0)) is not None:
                taken.append(line)
        except queue.Empty:  # the stream is still open (a grandchild holds it): what came so far
            pass
        return "".join(taken)

    def text(self) -> str:
        """Everything read so far, taken or not."""
        return "".join(self.seen)


class Child:
    """A command in a child process with its stdout and stderr read on threads; a context
    manager that stops it on exit. ``stdin=True`` gives the child a pipe (``self.proc.stdin``)."""

    def __init__(self, argv: Sequence[str], *, stdin: bool = False, env: dict[str, str] | None = None,
                 cwd: Path | str | None = None) -> None:
        self.argv = [str(a) for a in argv]
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=cwd,
                                     start_new_session=True)  # its own group: SIGKILL reaches its children too
        assert self.proc.stdout is not None and self.proc.stderr is not None
        self.out = Lines(self.proc.stdout, f"stdout of {self.argv[-1]}")
        self.err = Lines(self.proc.stderr, f"stderr of {self.argv[-1]}")

    @property
    def command(self) -> str:
        return shlex.join(self.argv)

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def fail(self, what: str) -> NoReturn:
        tail = "".join(self.err.seen[-15:])
        pytest.fail(f"`{self.command}`: {what}; its stderr ended with:\n{tail}", pytrace=False)

    def line(self, deadline_s: float = LINE_S, what: str = "a line") -> str:
        """The next stdout line; fails the test if none comes within ``deadline_s`` or the stream ends."""
        try:
            line = self.out.next(deadline_s)
        except queue.Empty:
            self.fail(f"waited {deadline_s:g} s for {what} on stdout: none came")
        if line is None:
            try:
                code: int | None = self.proc.wait(timeout=10)
                self.err._thread.join(10)  # its last words
            except subprocess.TimeoutExpired:  # it closed stdout and goes on
                code = None
            self.fail(f"stdout ended (exit code {code}) before {what}")
        return line

    def until(self, wanted: str, deadline_s: float = LINE_S, stream: str = "stdout") -> str | None:
        """Read ``stream`` (stdout or stderr) to the first line holding ``wanted``: that line, or None
        if the stream ended first; fails the test if neither happens within ``deadline_s``."""
        lines, end = (self.out if stream == "stdout" else self.err), time.monotonic() + deadline_s
        while True:
            try:
                line = lines.next(max(0.0, end - time.monotonic()))
            except queue.Empty:
                self.fail(f"waited {deadline_s:g} s for a line with {wanted!r} on {stream}: none came")
            if line is None or wanted in line:
                return line

    def json_line(self, deadline_s: float = LINE_S, what: str = "a JSON line") -> Any:
        return json.loads(self.line(deadline_s, what))

    def poll(self) -> int | None:
        return self.proc.poll()

    def send_signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)

    def wait(self, timeout: float = RUN_S) -> int:
        """The exit code; fails the test (the child is stopped after) if it does not end in ``timeout`` s."""
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.fail(f"did not end within {timeout:g} s")

    def stop(self, waits_s: Sequence[float] = STOP_WAITS_S) -> int:
        """SIGINT, then SIGTERM, then SIGKILL to its process group, each followed by its wait;
        the exit code (a negative signal number when a signal ended it unhandled)."""
        for sig, wait_s in zip((signal.SIGINT, signal.SIGTERM, signal.SIGKILL), waits_s):
            if self.proc.poll() is not None:
                break
            try:
                if sig == signal.SIGKILL:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                else:
                    self.proc.send_signal(sig)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(timeout=wait_s)
            except subprocess.TimeoutExpired:
                continue
        code = self.proc.wait(timeout=waits_s[-1])
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        return code

    def stdout(self, deadline_s: float = 30.0) -> str:
        """The stdout lines not taken yet, to its end (call once the child has ended)."""
        return self.out.rest(deadline_s)

    def output(self, deadline_s: float = 30.0) -> tuple[str, str]:
        """All of stdout and stderr, taken or not (call once the child has ended)."""
        for lines in (self.out, self.err):
            lines._thread.join(deadline_s)
        return self.out.text(), self.err.text()

    def stderr(self, deadline_s: float = 30.0) -> str:
        """All of stderr (call once the child has ended)."""
        self.err._thread.join(deadline_s)
        return self.err.text()

    def __enter__(self) -> Child:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class World(Child):
    """``rfhoming emulate``: its endpoints by device name, as it printed them."""

    endpoints: dict[str, dict[str, Any]]

    def path(self, device: str) -> str:
        return str(self.endpoints[device]["path"])

    @property
    def paths(self) -> dict[str, str]:
        return {name: str(e["path"]) for name, e in self.endpoints.items()}


def readline(proc: subprocess.Popen[str], stream: str = "stdout", deadline_s: float = LINE_S) -> str:
    """One line of a plain Popen's pipe, waited for at most ``deadline_s`` (a thread reads it):
    for children a test starts itself. Past the deadline the child is killed and the test fails
    naming it; '' at the end of the stream, as readline gives."""
    pipe = getattr(proc, stream)
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(pipe.readline()), daemon=True)
    reader.start()
    reader.join(deadline_s)
    if not got:
        proc.kill()
        argv = proc.args if isinstance(proc.args, str) else shlex.join(map(str, proc.args))
        pytest.fail(f"`{argv}`: no line on its {stream} within {deadline_s:g} s (killed)", pytrace=False)
    return got[0]


def device_count(scenario: str | Path) -> int:
    """How many endpoint lines ``emulate SCENARIO`` prints: one per device of the scenario."""
    from rfhoming.emulator.scenario import load

    return len(load(str(scenario)).devices)


def emulate(scenario: str | Path, *args: str, link_dir: Path | None = None, devices: int | None = None,
            deadline_s: float = LINE_S, argv0: Sequence[str] = RFHOMING,
            env: dict[str, str] | None = None) -> World:
    """Start ``rfhoming emulate SCENARIO ARGS`` (``--link-dir`` if given) and read one endpoint
    line per device (``devices``, else counted from the scenario), each within ``deadline_s``.
    Stop it with :meth:`Child.stop` or use it as a context manager (the fixture ``emulated`` does)."""
    argv = [*argv0, "emulate", str(scenario), *args]
    if link_dir is not None:
        argv += ["--link-dir", str(link_dir)]
    world = World(argv, env=env)
    try:
        count = device_count(scenario) if devices is None else devices
        lines = [world.json_line(deadline_s, f"endpoint line {k + 1} of {count}") for k in range(count)]
    except BaseException:
        world.stop()
        raise
    world.endpoints = {e["device"]: e for e in lines}
    return world


def run(*args: str | Path, timeout_s: float = RUN_S, input: str | bytes | None = None, text: bool = True,
        env: dict[str, str] | None = None, cwd: Path | str | None = None,
        argv0: Sequence[str] = RFHOMING) -> subprocess.CompletedProcess[Any]:
    """Run ``rfhoming ARGS`` (``argv0`` for another program) to its end: exit code, stdout and
    stderr. Past ``timeout_s`` its process group is killed and the test fails with the command."""
    argv = [*map(str, argv0), *map(str, args)]
    proc = subprocess.Popen(argv, stdin=subprocess.PIPE if input is not None else subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=text, env=env, cwd=cwd,
                            start_new_session=True)
    try:
        out, err = proc.communicate(input, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:  # a child of another group still holds its pipes
            err = ""
        tail = "\n".join(str(err or "").splitlines()[-15:])
        pytest.fail(f"`{shlex.join(argv)}` did not end within {timeout_s:g} s (killed); its stderr ended with:\n"
                    f"{tail}", pytrace=False)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)
