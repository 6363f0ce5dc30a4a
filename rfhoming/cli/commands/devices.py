"""``rfhoming devices``: the serial ports and what each seems to be."""

from __future__ import annotations

import argparse
import json

from rfhoming.host.discovery import candidates


def run(args: argparse.Namespace) -> int:
    found = candidates()
    if args.json:
        for c in found:
            print(json.dumps({"device": c.device, "kind": c.kind, "reason": c.reason, "description": c.description}))
        return 0
    if not found:
        print("no serial ports found. Plugged in? On Linux, dmesg shows what the kernel saw.")
    for c in found:
        print(f"{c.device:<20} {c.kind or '-':<10} {c.reason}  {c.description}")
    return 0
