"""How long each long-running command takes to end after SIGTERM or Ctrl-C (SIGINT), and whether
any process it started survives it (the target: all gone within 2 s). Each command is started,
waited for until it is doing its work (an endpoint printed, a run log begun, workers forked, a
broker connection made), then signalled; the time is until the command and every descendant
have exited.

    python bench/stop_bench.py --json            # every command, SIGTERM and SIGINT
    python bench/stop_bench.py --only demo,serve
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import psutil

from rfhoming.host.outputs import part_of

RFHOMING = [sys.executable, "-m", "rfhoming"]
READY_S = 180.0  # a hang guard for start-up on a loaded machine


def _until(condition: Callable[[], bool], what: str) -> None:
    end = time.monotonic() + READY_S
    while not condition():
        if time.monotonic() > end:
            raise RuntimeError(f"{what}: not ready after {READY_S:g} s")
        time.sleep(0.05)


def _begun(log: Path) -> bool:
    """A run log has its first record: while the run goes on it is LOG.part (host/outputs.py)."""
    part = part_of(log)
    return part.exists() and part.stat().st_size > 0


def _connected_to(pid: int, port: int) -> bool:
    try:
        return any(c.raddr and c.raddr.port == port for c in psutil.Process(pid).net_connections())
    except psutil.NoSuchProcess:
        return True


def _emulator(tmp: Path) -> tuple[subprocess.Popen, dict[str, str]]:
    proc = subprocess.Popen([*RFHOMING, "emulate", "s0-open", "--tcp"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    ends = {e["device"]: e["path"] for e in (json.loads(proc.stdout.readline()) for _ in range(2))}
    return proc, ends


def _broker(tmp: Path) -> tuple[subprocess.Popen, int]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    conf = tmp / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    exe = shutil.which("mosquitto", path=f"{os.environ.get('PATH', '')}:/usr/sbin")
    proc = subprocess.Popen([exe, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _until(lambda: _connected_to(os.getpid(), port) or _can_connect(port), "mosquitto")
    return proc, port


def _can_connect(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
        return True
    except OSError:
        return False


def case(name: str, tmp: Path) -> tuple[list[str], Callable[[subprocess.Popen], bool], list[subprocess.Popen]]:
    """The command, its readiness test and the helper processes it needs (stopped afterwards)."""
    if name == "emulate":
        return [*RFHOMING, "emulate", "s0-open", "--tcp"], lambda p: bool(p.stdout.readline()), []
    if name in ("serve", "listen", "run"):
        em, ends = _emulator(tmp)
        if name == "serve":
            return ([*RFHOMING, "serve", f"xplr-aoa:{ends['aoa']}", "--port", "0"],
                    lambda p: bool(p.stdout.readline()), [em])
        if name == "listen":
            return [*RFHOMING, "listen", f"xplr-aoa:{ends['aoa']}", "--json"], lambda p: bool(p.stdout.readline()), [em]
        log = tmp / f"run-{time.monotonic_ns()}.jsonl"
        return ([*RFHOMING, "run", "--aoa", f"xplr-aoa:{ends['aoa']}", "--base", f"base:{ends['base']}", "--log",
                 str(log)], lambda p: _begun(log), [em])
    if name == "demo":
        out = tmp / f"demo-{time.monotonic_ns()}"
        return ([*RFHOMING, "demo", "--speed", "1", "--out", str(out)], lambda p: _begun(out / "run.jsonl"), [])
    if name == "campaign":
        return ([*RFHOMING, "campaign", "s2-scenarios", "--workers", "2", "--quiet", "--out", str(tmp / "camp")],
                lambda p: len(psutil.Process(p.pid).children()) >= 2, [])
    broker, port = _broker(tmp)
    url = f"mqtt://127.0.0.1:{port}/4"
    if name == "gateway":
        return ([*RFHOMING, "gateway", "--emulate", "site-8x10", "--broker", url],
                lambda p: _connected_to(p.pid, port), [broker])
    if name == "locate":
        return ([*RFHOMING, "locate", "site-8x10", "--from", url], lambda p: _connected_to(p.pid, port), [broker])
    raise ValueError(name)


COMMANDS = ("emulate", "serve", "listen", "run", "demo", "campaign", "gateway", "locate")


def measure(name: str, sig: signal.Signals, tmp: Path) -> dict:
    argv, ready, helpers = case(name, tmp)
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=tmp)
    try:
        _until(lambda: proc.poll() is not None or ready(proc), name)
        family = [psutil.Process(proc.pid), *psutil.Process(proc.pid).children(recursive=True)]
        t0 = time.monotonic()
        proc.send_signal(sig)
        _, alive = psutil.wait_procs(family, timeout=30)
        took = time.monotonic() - t0
        return {"command": name, "signal": sig.name, "exit_s": round(took, 2), "processes": len(family),
                "survivors": len(alive), "returncode": getattr(family[0], "returncode", None)}
    finally:
        for p in [proc, *helpers]:
            if p.poll() is None:
                p.kill()
                p.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", help="comma-separated commands (default: all of " + ", ".join(COMMANDS) + ")")
    parser.add_argument("--json", action="store_true", help="one JSON line per measurement")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        for name in args.only.split(",") if args.only else COMMANDS:
            for sig in (signal.SIGTERM, signal.SIGINT):
                row = measure(name, sig, Path(folder))
                print(json.dumps(row) if args.json else
                      f"{name:9} {sig.name:7} ended in {row['exit_s']:5.2f} s, {row['processes']} process(es), "
                      f"{row['survivors']} left, rc {row['returncode']}", flush=True)


if __name__ == "__main__":
    main()
