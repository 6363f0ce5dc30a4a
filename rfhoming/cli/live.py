"""``--foxglove[=PORT]``: the live Foxglove view, as the run/demo/listen/serve commands offer it."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, TextIO

DEFAULT_PORT = 8765  # Foxglove's own default (rfhoming.host.foxglove_view.DEFAULT_PORT)
FOXGLOVE_HELP = (f"also serve a live view to Foxglove/Lichtblick on ws://127.0.0.1:PORT (default {DEFAULT_PORT}, "
                 "0 = any free port; in Foxglove open a WebSocket connection to it and import the layout "
                 "rfhoming/host/foxglove_layout.json; needs the foxglove extra)")


def add_foxglove_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--foxglove", nargs="?", const=DEFAULT_PORT, type=int, metavar="PORT", help=FOXGLOVE_HELP)


def start_foxglove(args: argparse.Namespace, command: str, out: TextIO = sys.stderr, host: str = "127.0.0.1") -> Any:
    """The view if --foxglove was given (its address printed as a JSON line on ``out``), else
    None; SystemExit(2) with a one-line reason when it cannot start."""
    if getattr(args, "foxglove", None) is None:
        return None
    try:
        from rfhoming.host.foxglove_view import FoxgloveView
    except ImportError as exc:
        print(f"rfhoming {command}: --foxglove needs the foxglove extra ({exc.name} is missing): "
              "pip install 'rfhoming[foxglove]'", file=sys.stderr)
        raise SystemExit(2) from None
    try:
        view = FoxgloveView(port=args.foxglove, host=host)
    except Exception as exc:  # foxglove-sdk raises its own error types for a busy port
        print(f"rfhoming {command}: cannot start the Foxglove server on port {args.foxglove}: {exc}; "
              "choose another with --foxglove=PORT", file=sys.stderr)
        raise SystemExit(2) from None
    print(json.dumps({"kind": "listening", "address": view.address, "protocol": "foxglove.websocket"}),
          file=out, flush=True)
    return view
