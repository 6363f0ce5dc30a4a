"""``rfhoming config``: print the default config, or check a config file."""

from __future__ import annotations

import argparse

from rfhoming.host.homing.config import DEFAULT_TOML, load


def run(args: argparse.Namespace) -> int:
    if args.print_default:
        print(DEFAULT_TOML, end="")
        return 0
    load(args.check)
    print(f"{args.check}: OK")
    return 0
