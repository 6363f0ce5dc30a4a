"""``rfhoming`` command line: one subcommand per job, each with examples in its --help."""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from rfhoming import __version__
from rfhoming.cli.args import nonempty
from rfhoming.cli.export import add_parser as add_export_parser
from rfhoming.cli.io import add_parsers as add_io_parsers
from rfhoming.cli.io import configure_logging
from rfhoming.cli.locate import add_parser as add_locate_parsers
from rfhoming.cli.run import add_parsers as add_run_parsers
from rfhoming.cli.serve import add_parser as add_serve_parser
from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error
from rfhoming.protocol.jsonable import as_dict

READ_SIZE = 65536


def _chunks(stream: BinaryIO) -> Iterator[bytes]:
    while chunk := stream.read(READ_SIZE):
        yield chunk


def cmd_decode(args: argparse.Namespace) -> int:
    decoder = devices.load(devices.protocol(args.protocol).decoder)()
    try:
        stream = sys.stdin.buffer if args.file == "-" else open(args.file, "rb")
    except OSError as exc:
        print(f"rfhoming decode: cannot open {args.file}: {exc.strerror}", file=sys.stderr)
        return 2
    out = sys.stdout
    with stream:
        for chunk in _chunks(stream):
            for item in decoder.feed(chunk):
                out.write(json.dumps(as_dict(item)) + "\n")
        for item in decoder.flush():
            out.write(json.dumps(as_dict(item)) + "\n")
    out.write(json.dumps({"kind": "counters", **dict(sorted(decoder.counters.items()))}) + "\n")
    return 0


DECODE_HELP = """\
Decode raw bytes -- a file, a raw capture of a serial port, or stdin -- and print one JSON
object per decoded item: "kind" plus its fields, or kind "drop" with the reason. The last
line (kind "counters") counts every item kind and every drop reason.

examples:
  rfhoming decode --protocol uconnect board.log
  cat /dev/ttyACM0 | rfhoming decode --protocol uconnect -
  rfhoming decode --protocol frames node.bin | grep '"kind": "drop"'
"""


DISSECTOR_HELP = """\
Write a Wireshark/tshark Lua dissector for rfhoming's pcapng captures. It is generated from the
record declarations, so it always matches this version's decoder. Interfaces with link type
148 (binary records) are reassembled per direction, COBS-decoded, CRC-checked and shown field
by field, with drops marked by reason; link type 147 (XPLR-AOA text) shows as text lines.

examples:
  rfhoming dissector -o ~/.local/lib/wireshark/plugins/rfhoming.lua   # install for Wireshark
  rfhoming dissector -o rfhoming.lua && tshark -X lua_script:rfhoming.lua -r run.pcapng -O rfhoming
"""


def cmd_dissector(args: argparse.Namespace) -> int:
    from rfhoming.protocol.frames.wireshark import lua_dissector

    if args.output == "-":
        sys.stdout.write(lua_dissector())
        return 0
    try:
        path = Path(args.output).expanduser()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(lua_dissector())
    except OSError as exc:
        print(f"rfhoming dissector: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
        return 2
    print(f"wrote {path}", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rfhoming",
        description="Radio homing for mobile robots: device protocols, emulator and host stack.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an internal error (for a bug report)")
    parser.add_argument("--version", action="version", version=f"rfhoming {__version__}",
                        help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    decode = sub.add_parser(
        "decode",
        help="decode raw device bytes to JSON lines",
        description=DECODE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    decode.add_argument(
        "--protocol",
        required=True,
        choices=["uconnect", "frames", "ublox-aoa", "rss"],
        metavar="PROTOCOL",
        help="uconnect: XPLR-AOA u-connectLocate text; frames: rfhoming's COBS binary records (nodes and the "
        "robot base); the older names ublox-aoa and rss still work",
    )
    decode.add_argument("file", type=nonempty, nargs="?", default="-", help="input file, or - for stdin")
    decode.set_defaults(func=cmd_decode)
    dissector = sub.add_parser(
        "dissector",
        help="write the Wireshark Lua dissector for the binary records",
        description=DISSECTOR_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    dissector.add_argument("-o", "--output", type=nonempty, default="-", help="file to write (default: stdout)")
    dissector.set_defaults(func=cmd_dissector)
    add_run_parsers(sub)
    add_io_parsers(sub)
    add_locate_parsers(sub)
    _add_emulate(sub)
    _add_campaign(sub)
    _add_site(sub)
    add_export_parser(sub)
    add_serve_parser(sub)
    return parser


def _add_emulate(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """The emulator's command; the CLI is the one host module that may wire the emulator in."""
    from rfhoming.cli.emulate import add_parser

    add_parser(sub)


def _add_campaign(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Campaigns wire the emulator and the host together in-process (the campaigns package)."""
    from rfhoming.cli.campaign import add_parser

    add_parser(sub)


def _add_site(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """The site bus's gateway and worker (they wire the emulated site in, as the emulator's command)."""
    from rfhoming.cli.site import add_parsers

    add_parsers(sub)


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


def main(argv: list[str] | None = None) -> int:
    """Run one command. An rfhoming.Error (a port, a spec, a config, a file the user gave) or an
    OSError is one line and exit 2; anything else is a bug: one line saying so, exit 1, and
    the traceback with --debug. SIGTERM ends a command as Ctrl-C does, so that its clean-up runs
    and stops the children it started (its default action would leave them running)."""
    args = build_parser().parse_args(argv)
    configure_logging(args.verbose)
    before = signal.signal(signal.SIGTERM, _as_ctrl_c)
    try:
        code: int = args.func(args)
        return 128 + signal.SIGTERM if _terminated and code == 130 else code
    except BrokenPipeError:  # e.g. piped into head
        sys.stderr.close()
        return 0
    except Error as exc:
        print(f"rfhoming {args.command}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"rfhoming {args.command}: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rfhoming {args.command}: {'terminated' if _terminated else 'interrupted'}", file=sys.stderr)
        return 128 + signal.SIGTERM if _terminated else 130
    except Exception as exc:
        if args.debug:
            raise
        print(f"rfhoming {args.command}: internal error, a bug in rfhoming {__version__} ({type(exc).__name__}: "
              f"{exc}); please report it with the output of the same command run with --debug", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, before)


def serve_capture_on_ptys(args: argparse.Namespace) -> int:
    """``rfhoming replay --pty``: the emulator's pty links serve a recording."""
    import tempfile
    from pathlib import Path

    from rfhoming.emulator.playback import serve

    def warn(exc: Exception) -> None:
        print(f"rfhoming replay: {args.capture}: {exc}; serving what came before it (--partial)", file=sys.stderr)

    link_dir = args.link_dir or Path(tempfile.mkdtemp(prefix="rfhoming-replay-"))
    try:
        stats = asyncio.run(serve(args.capture, link_dir, speed=args.speed or 1.0, start_delay=args.start_delay,
                                  out=sys.stdout, partial=warn if args.partial else None))
    except (OSError, Error) as exc:
        print(f"rfhoming replay: cannot serve {args.capture}: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"kind": "counters", **stats}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
