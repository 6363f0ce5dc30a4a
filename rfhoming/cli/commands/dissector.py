"""``rfhoming dissector``: the Wireshark Lua dissector for the binary records."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rfhoming.host.outputs import WriteFailed, replace_text
from rfhoming.protocol.frames.wireshark import lua_dissector


def run(args: argparse.Namespace) -> int:
    if args.output == "-":
        sys.stdout.write(lua_dissector())
        return 0
    try:
        path = Path(args.output).expanduser()
        path.parent.mkdir(parents=True, exist_ok=True)
        replace_text(path, lua_dissector())
    except WriteFailed as exc:  # its .part is there, or the write failed: the message says which, and what is kept
        print(f"rfhoming dissector: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"rfhoming dissector: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
        return 2
    print(f"wrote {path}", file=sys.stderr)
    return 0
