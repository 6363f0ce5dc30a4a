"""``rfhoming decode``: raw device bytes to JSON lines."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from typing import BinaryIO

from rfhoming.protocol import devices
from rfhoming.protocol.jsonable import decoded_as_dict

READ_SIZE = 65536


def _chunks(stream: BinaryIO) -> Iterator[bytes]:
    while chunk := stream.read(READ_SIZE):
        yield chunk


def run(args: argparse.Namespace) -> int:
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
                out.write(json.dumps(decoded_as_dict(item)) + "\n")
        for item in getattr(decoder, "flush", list)():  # the text decoders hold a last unfinished line
            out.write(json.dumps(decoded_as_dict(item)) + "\n")
    out.write(json.dumps({"kind": "counters", **dict(sorted(decoder.counters.items()))}) + "\n")
    return 0
