"""The command line starts light: the parsers load no command, and a command loads only what it
uses (its speed is bench/startup_bench.py's, not a test's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

GOLDEN = Path(__file__).resolve().parent / "golden" / "xplr_aoa_session.raw"

LOADED = """\
import contextlib, io, json, sys
from rfhoming.cli.main import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps(sorted(sys.modules)), file=sys.stderr)
"""


def loaded_by(*argv: str) -> set[str]:
    """The modules a command (run in a fresh interpreter) had loaded when it ended."""
    done = subprocess.run([sys.executable, "-c", LOADED, *argv], capture_output=True, text=True, timeout=120)
    return set(json.loads(done.stderr.strip().splitlines()[-1]))


@pytest.mark.parametrize("argv", [("--version",), ("--help",), ("decode", "--protocol", "uconnect", str(GOLDEN))])
def test_version_help_and_decode_load_no_numerics_and_no_other_command(argv: tuple[str, ...]) -> None:
    modules = loaded_by(*argv)
    assert not {"scipy", "numpy"} & modules, argv
    commands = {m for m in modules if m.startswith("rfhoming.cli.commands.")}
    assert commands <= {"rfhoming.cli.commands.decode"}, commands


def test_replay_loads_no_scipy(tmp_path: Path) -> None:
    """``replay`` of a capture (a bad one: it stops at once) loads the drivers, not the fitters."""
    bad = tmp_path / "bad.pcapng"
    bad.write_bytes(b"not a capture")
    modules = loaded_by("replay", str(bad), "--json")
    assert "rfhoming.cli.commands.replay" in modules and "scipy" not in modules


def test_the_parsers_names_match_the_library() -> None:
    """What the light parsers name so as not to load the library is what the library holds."""
    from rfhoming.cli.parsers import common, decode, emulate, io, serve
    from rfhoming.emulator import scenario
    from rfhoming.protocol import devices, radio_profile
    from rfhoming.host import serve as server
    from rfhoming.host.homing.assembly import METHODS

    assert io.CONTROLLERS == tuple(METHODS)
    assert (serve.QUEUE_LINES, serve.MAX_IDLE, serve.STALL_S) == (server.QUEUE_LINES, server.MAX_IDLE, server.STALL_S)
    assert emulate.BLE_RECEIVERS == scenario.BLE_RECEIVERS
    assert emulate.presets() == scenario.presets()
    assert common.KINDS == tuple(devices.KINDS)
    assert common.RADIOS == radio_profile.RADIOS
    assert decode.PROTOCOLS == tuple(name for p in devices.PROTOCOLS.values() for name in (p.name, *p.aliases))


ENDING = """\
import atexit, gc, os, runpy, sys
atexit.register(lambda: os.write(2, b"frozen at exit: %d\\n" % gc.get_freeze_count()))  # runs last
sys.argv = ["rfhoming", *sys.argv[1:]]
runpy.run_module("rfhoming", run_name="__main__")
"""


def test_the_process_ends_after_its_clean_up_without_the_collectors_teardown_passes() -> None:
    """``python -m rfhoming`` runs every atexit handler and keeps the command's exit code, and
    what it loaded is frozen by then: the garbage collector's passes over it while the
    interpreter tears down were most of a command's exit after Ctrl-C (docs/BENCHMARKS.md)."""
    done = subprocess.run([sys.executable, "-c", ENDING, "decode", "--protocol", "uconnect", "/no/such/file"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "/no/such/file" in done.stderr, done.stderr
    frozen = int(done.stderr.rsplit("frozen at exit: ", 1)[1].split()[0])
    assert frozen > 1000, done.stderr
