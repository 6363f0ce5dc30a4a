"""``rfhoming`` command line: one subcommand per job, each with examples in its --help.

The parsers (rfhoming.cli.parsers) are light; a command's module (rfhoming.cli.commands) is
imported only when that command runs, so ``rfhoming --version`` loads no command and ``decode``
only the decoders."""

from __future__ import annotations

import _thread
import argparse
import gc
import logging
import signal
import sys
from typing import Any, NoReturn, cast

from rfhoming.cli.parsers import campaign, decode, emulate, export, gateway, io, locate, run, serve
from rfhoming.protocol.credentials import redact
from rfhoming.protocol.errors import Error


class _Version(argparse._VersionAction):
    """--version, with the version read only when asked for (rfhoming.__version__ is lazy)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        self.version = f"rfhoming {_installed()}"
        super().__call__(parser, namespace, values, option_string)


def _installed() -> str:
    from rfhoming import __version__

    return __version__


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose error (the usage, then one line echoing what was wrong) never
    shows a URL's password; the subcommands' parsers are of this class too."""

    def error(self, message: str) -> NoReturn:
        super().error(redact(message))


class _Redacting(logging.Formatter):
    """Log lines with every URL's password hidden, whoever logged them."""

    def format(self, record: logging.LogRecord) -> str:
        return redact(super().format(record))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="rfhoming",
        description="Radio homing for mobile robots: device protocols, emulator and host stack.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an internal error (for a bug report)")
    parser.add_argument("--version", action=_Version, help="print the installed version and exit")
    sub = cast("argparse._SubParsersAction[argparse.ArgumentParser]",  # of _Parser, which the parsers need not know
               parser.add_subparsers(dest="command", required=True, metavar="COMMAND"))
    decode.add_parsers(sub)
    run.add_parsers(sub)
    io.add_parsers(sub)
    locate.add_parsers(sub)
    emulate.add_parser(sub)
    campaign.add_parser(sub)
    gateway.add_parser(sub)
    export.add_parser(sub)
    serve.add_parser(sub)
    return parser


def configure_logging(verbose: int) -> None:
    level = logging.WARNING - 10 * verbose
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Redacting("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=level, handlers=[handler])


_terminated = False
"""SIGTERM came: the command then ends with 128 + SIGTERM, as a shell reports a process it ended."""


def _as_ctrl_c(signum: int, frame: object) -> None:
    """SIGTERM handled as SIGINT is: inside asyncio.run, its handler cancels the main task (which
    nothing can swallow, unlike a KeyboardInterrupt raised in a finaliser); elsewhere Python's
    raises KeyboardInterrupt. Where SIGINT is ignored (a background job), KeyboardInterrupt."""
    global _terminated
    _terminated = True
    if signal.getsignal(signal.SIGINT) in (signal.SIG_IGN, signal.SIG_DFL, None):
        raise KeyboardInterrupt
    signal.raise_signal(signal.SIGINT)


def _redeliver(unraisable: sys.UnraisableHookArgs) -> None:
    """A Ctrl-C or SIGTERM whose KeyboardInterrupt landed in a finaliser or a fork hook (a
    campaign's pool forking a worker) is dropped by Python with a printed traceback, and the
    command went on to its end: it is raised again in the main thread instead."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):  # from another thread: raised here, it would be dropped again
        _thread.start_new_thread(_thread.interrupt_main, ())
        return
    sys.__unraisablehook__(unraisable)


def main(argv: list[str] | None = None) -> int:
    """Run one command. An rfhoming.Error (a port, a spec, a config, a file the user gave) or an
    OSError is one line and exit 2; anything else is a bug: one line saying so, exit 1, and
    the traceback with --debug. SIGTERM ends a command as Ctrl-C does, so that its clean-up runs
    and stops the children it started (its default action would leave them running)."""
    args = build_parser().parse_args(argv)
    configure_logging(args.verbose)
    before = signal.signal(signal.SIGTERM, _as_ctrl_c)
    hook, sys.unraisablehook = sys.unraisablehook, _redeliver
    try:
        code: int = args.func(args)
        return 128 + signal.SIGTERM if _terminated and code == 130 else code
    except BrokenPipeError:  # e.g. piped into head
        sys.stderr.close()
        return 0
    except Error as exc:
        print(redact(f"rfhoming {args.command}: {exc}"), file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(redact(f"rfhoming {args.command}: {where}{exc.strerror or exc}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rfhoming {args.command}: {'terminated' if _terminated else 'interrupted'}", file=sys.stderr)
        return 128 + signal.SIGTERM if _terminated else 130
    except Exception as exc:
        if args.debug:
            raise
        print(redact(f"rfhoming {args.command}: internal error, a bug in rfhoming {_installed()} "
                     f"({type(exc).__name__}: {exc}); please report it with the output of the same command run "
                     "with --debug"), file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, before)
        sys.unraisablehook = hook


def entry() -> NoReturn:
    """The ``rfhoming`` process: :func:`main`, then its exit. Every explicit clean-up still runs
    (the command's own, atexit's, the threads' joins; files are closed explicitly, not left to
    the collector: cyclic garbage older than the young generations is not finalised at exit);
    only the garbage collector's passes over all
    that was loaded (numpy, scipy, the commands' modules) while the interpreter tears down are
    spared, by freezing it after a collection of the young generations (what the clean-up just
    dropped): they were ~0.17 of the teardown's ~0.2 CPU seconds, the most of a command's
    exit after Ctrl-C or SIGTERM (docs/BENCHMARKS.md, "Stopping")."""
    code = main()
    gc.collect(1)
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    entry()
