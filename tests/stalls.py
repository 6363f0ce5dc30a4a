"""What of a command's output the wall clock makes, left out where a test compares a run with
its replay or two speeds of one recording: the event loop's stall figures (a live run log's
``stall`` records and the summaries' ``loop_stall_ms_*``)."""

from __future__ import annotations

import json

STALL_KEYS = ("loop_stall_ms_max", "loop_stall_ms_p99")


def reproducible(text: str) -> list[str]:
    """``text``'s lines without stall records, and with the stall figures taken out of a summary."""
    out = []
    for line in text.splitlines():
        if '"kind": "stall"' in line:
            continue
        if "loop_stall_ms" in line:
            record = json.loads(line)
            for key in STALL_KEYS:
                record.pop(key, None)
            line = json.dumps(record)
        out.append(line)
    return out
