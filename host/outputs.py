"""Output files that fail: say which file and what of it was kept, and leave no empty file.

A full disk or a vanished mount shows up as an OSError deep in a writer, with no file named;
the user needs to know which output it was and whether what is on disk is usable.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from rfhoming.protocol.errors import Error


class WriteFailed(Error, OSError):
    """An output file could not be written; the message names it and what of it was kept."""


def failed(path: Path | str, exc: OSError, kept: str) -> WriteFailed:
    """The error to raise for ``exc`` on ``path``; ``kept`` says what the file's bytes are good
    for when some were written (an empty file is removed: :func:`remove_if_empty`)."""
    what = exc.strerror or str(exc)
    p = Path(path)
    if remove_if_empty(p):
        held = "nothing was written, and the empty file is removed"
    elif p.is_file():
        held = f"its {p.stat().st_size} bytes are kept: {kept}"
    else:
        held = "nothing of it is kept"
    return WriteFailed(f"cannot write {path}: {what}; {held}")


def remove_if_empty(path: Path | str) -> bool:
    """Remove ``path`` if it is an empty regular file (never a device such as /dev/full); True if removed."""
    p = Path(path)
    try:
        if p.is_file() and p.stat().st_size == 0:
            p.unlink()
            return True
    except OSError:
        pass
    return False


def replace_text(path: Path | str, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all: a temporary file beside it, renamed over it
    (a reader never sees half a file; a failed write leaves the old one)."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, target)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise failed(target, exc, "what was there before is unchanged") from None
