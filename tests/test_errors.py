"""One error root: every error a user can cause is an rfhoming.Error, which the command line
turns into one line and exit 2; anything else is a bug: one line saying so, exit 1, and the
traceback only with --debug."""

from __future__ import annotations

import argparse

import pytest

import rfhoming
from rfhoming.campaigns.runner import CampaignError
from rfhoming.cli import main as cli
from rfhoming.emulator.faults import FaultError
from rfhoming.emulator.scenario import ScenarioError
from rfhoming.host.calibration import CalibrationError
from rfhoming.host.homing.config import ConfigError
from rfhoming.host.ports import Disconnected, PortError
from rfhoming.host.portspec import PortSpecError
from rfhoming.host.site import SiteError
from rfhoming.host.supervise import DeviceNotReady
from rfhoming.protocol.devices import UnknownKind
from rfhoming.protocol.pcapng import CaptureFormatError

USER_ERRORS = (CampaignError, FaultError, ScenarioError, CalibrationError, ConfigError, Disconnected, PortError,
               PortSpecError, SiteError, DeviceNotReady, UnknownKind, CaptureFormatError)


@pytest.mark.parametrize("error", USER_ERRORS, ids=lambda e: e.__name__)
def test_every_user_facing_error_has_the_one_root(error: type) -> None:
    assert issubclass(error, rfhoming.Error)


def test_every_error_class_of_ours_is_under_the_root_or_internal() -> None:
    """Walks every rfhoming module's exception classes: each user-facing one is an rfhoming.Error;
    the few that are not are control flow inside a layer (listed, so a new one is a decision)."""
    import importlib
    import pkgutil

    internal = {"EndOfInput", "CommandFailed", "Degenerate", "AtSyntaxError", "BadText",  # each becomes a drop or a retry
                "NotLocked"}  # the Foxglove view's warning: its listener stays open to local programs
    found = set()
    for info in pkgutil.walk_packages(rfhoming.__path__, "rfhoming."):
        if info.name.startswith(("rfhoming.__main__", "rfhoming.host.export", "rfhoming.host.foxglove")):
            continue
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            if isinstance(value, type) and issubclass(value, Exception) and value.__module__ == info.name:
                found.add(value)
    strays = sorted(c.__name__ for c in found if not issubclass(c, rfhoming.Error) and c.__name__ not in internal)
    assert not strays, strays


def _with_command(monkeypatch, raising: BaseException) -> None:
    def command(args: argparse.Namespace) -> int:
        raise raising

    real = cli.build_parser

    def parser() -> argparse.ArgumentParser:
        p = real()
        sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
        sub.add_parser("boom").set_defaults(func=command)
        return p

    monkeypatch.setattr(cli, "build_parser", parser)


def test_a_user_error_is_one_line_and_exit_2(monkeypatch, capsys) -> None:
    _with_command(monkeypatch, PortError("no device at /dev/ttyUSB9: is it plugged in?"))
    assert cli.main(["boom"]) == 2
    err = capsys.readouterr().err
    assert err == "rfhoming boom: no device at /dev/ttyUSB9: is it plugged in?\n"


def test_a_bug_is_one_line_saying_so_and_exit_1(monkeypatch, capsys) -> None:
    _with_command(monkeypatch, ValueError("a bug's ValueError is not a usage error"))
    assert cli.main(["boom"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bug" in err and "--debug" in err and "Traceback" not in err


def test_debug_shows_the_traceback_of_a_bug(monkeypatch) -> None:
    _with_command(monkeypatch, KeyError("deep inside"))
    with pytest.raises(KeyError, match="deep inside"):
        cli.main(["--debug", "boom"])


def test_a_ctrl_c_python_drops_in_a_finaliser_still_ends_the_command() -> None:
    """A KeyboardInterrupt raised where Python cannot raise it (a finaliser, a fork hook: a
    campaign's pool forking a worker as SIGTERM came) is only printed, and the command went on
    to its end; main's unraisable hook raises it again in the main thread."""
    import sys
    import time

    class Drops:
        def __del__(self) -> None:
            raise KeyboardInterrupt

    before = sys.unraisablehook
    sys.unraisablehook = cli._redeliver
    try:
        with pytest.raises(KeyboardInterrupt):
            Drops()  # dropped at once: its __del__'s KeyboardInterrupt is unraisable
            for _ in range(1000):  # the redelivered interrupt comes at the next bytecode check
                time.sleep(0.001)
    finally:
        sys.unraisablehook = before
