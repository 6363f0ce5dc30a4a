"""``rfhoming devices``: the serial ports and what each seems to be; ``--kinds``: the device
kinds and what each reports."""

from __future__ import annotations

import argparse
import json
from typing import Any

from rfhoming.host.discovery import candidates
from rfhoming.protocol.devices import KINDS, Reports

ANGLES_FILE = Reports("bearings as written, elevation and RSSI where given (docs/usage.md, \"An angles file\")", (-180.0, 180.0), elevation=True,
                      rssi=True, rate="as written")
"""``--from angles:FILE``: any board's bearings; elevation and RSSI where the file gives them."""


def run(args: argparse.Namespace) -> int:
    if args.kinds:
        return _kinds(args.json)
    found = candidates()
    if args.json:
        for c in found:
            print(json.dumps({"device": c.device, "kind": c.kind, "reason": c.reason, "description": c.description}))
        return 0
    if not found:
        print("no serial ports found. Plugged in? On Linux, dmesg shows what the kernel saw.")
    for c in found:
        print(f"{c.device:<20} {c.kind or '-':<10} {c.reason}  {c.description}")
    print("what each kind reports: rfhoming devices --kinds")
    return 0


def _kinds(as_json: bool) -> int:
    rows = [(k.name, k.title, k.reports) for k in KINDS.values()] + [("angles", "an angles file (--from angles:FILE)",
                                                                      ANGLES_FILE)]
    for name, title, r in rows:
        fields: dict[str, Any] = {"kind": name, "title": title, "reports": r.readings}
        if r.azimuth_deg is not None:
            fields.update(azimuth_deg=list(r.azimuth_deg), elevation=r.elevation)
        if r.rssi:
            fields["rssi"] = True
        if r.rate:
            fields["rate"] = r.rate
        if as_json:
            print(json.dumps(fields))
            continue
        angles = (f"; azimuth {r.azimuth_deg[0]:g}..{r.azimuth_deg[1]:g} deg, elevation "
                  f"{'yes' if r.elevation else 'no'}" if r.azimuth_deg is not None else "")
        print(f"{name:<10} {r.readings}{angles}{'; RSSI' if r.rssi else ''}" + (f"; {r.rate}" if r.rate else ""))
    return 0
