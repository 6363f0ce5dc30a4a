"""The optional C accelerator (``protocol/_accel.c``), or ``None`` when it is not built.

The decoders are pure Python and complete on their own. Where pip could compile the
extension, three hot paths run in C instead: the CRC-16 (slice-by-8), splitting a chunk into
``+UUDF`` events, and splitting a chunk into COBS frames with their CRC checked. The C code only
takes the common case and hands everything else back to the Python decoder, so both paths
give the same items, drops and counters (tests/test_accel.py holds them to that).

Set ``RFHOMING_PURE_PYTHON=1`` to run without it. ``python -m rfhoming.protocol.accel`` says which one
is in use.
"""

from __future__ import annotations

import os
from types import ModuleType

PURE_ENV = "RFHOMING_PURE_PYTHON"


def _load() -> ModuleType | None:
    if os.environ.get(PURE_ENV, "") not in ("", "0"):
        return None
    try:
        from rfhoming.protocol import _accel
    except ImportError:
        return None
    return _accel


ACCEL: ModuleType | None = _load()


def describe() -> str:
    """One line for logs and benchmarks: which decoder implementation is in use."""
    if ACCEL is not None:
        return f"C accelerator ({ACCEL.__file__})"
    if os.environ.get(PURE_ENV, "") not in ("", "0"):
        return f"pure Python ({PURE_ENV} is set)"
    return "pure Python (protocol._accel not built; reinstall with a C compiler present)"


if __name__ == "__main__":
    print(describe())
