"""``rfhoming export``: a run's files -> an MCAP log of ROS 2 messages."""

from __future__ import annotations

import argparse
import json
import sys

from rfhoming.protocol.errors import Error

PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"


def run(args: argparse.Namespace) -> int:
    try:
        from rfhoming.host.export.recorder import export
    except ImportError as exc:
        print(f"rfhoming export: needs the ros extra ({exc.name} is missing): pip install 'rfhoming[ros]'",
              file=sys.stderr)
        return 2
    runlog, capture = args.run, args.capture
    try:
        with open(runlog, "rb") as f:
            if f.read(4) == PCAPNG_MAGIC:  # a capture given alone
                if capture is not None:
                    print("rfhoming export: give the run log first and the capture with --capture", file=sys.stderr)
                    return 2
                runlog, capture = None, runlog
        from rfhoming.host.homing.config import load

        summary = export(args.output, runlog=runlog, capture=capture, mounting=load(args.config).mounting)
    except (OSError, Error) as exc:
        print(f"rfhoming export: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"output": str(args.output), **summary}))
    return 0
