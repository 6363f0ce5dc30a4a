"""How ``listen`` and ``replay`` print an item: a text line, or a JSON line with ``--json``."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any, TextIO

from rfhoming.protocol.jsonable import as_dict


def printer(json_lines: bool, out: TextIO = sys.stdout) -> Callable[[str, float, Any], None]:
    def show(device: str, t: float, item: Any) -> None:
        if json_lines:
            out.write(json.dumps({"device": device, "t": t, **as_dict(item)}) + "\n")
        else:
            fields = " ".join(f"{k}={v}" for k, v in as_dict(item).items() if k != "kind")
            out.write(f"{t:.6f} {device} {item.kind} {fields}\n")
        out.flush()

    return show
