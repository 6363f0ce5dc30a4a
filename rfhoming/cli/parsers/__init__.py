"""The command line's argument parsers, one module per group of commands.

They import nothing heavy -- argparse and the argument types of :mod:`rfhoming.cli.args` -- so
that ``rfhoming --help`` and ``--version`` build every parser without loading a command. Each
parser's ``func`` imports its command's module (:mod:`rfhoming.cli.commands`) when it runs.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from importlib import import_module

Command = Callable[[argparse.Namespace], int]


def command(module: str, function: str = "run") -> Command:
    """A parser's ``func``: ``rfhoming.cli.commands.MODULE.FUNCTION``, imported when called."""
    def run(args: argparse.Namespace) -> int:
        found: Command = getattr(import_module(f"rfhoming.cli.commands.{module}"), function)
        return found(args)

    return run
