"""Output files that fail: say which file and what of it was kept, and leave no empty file.

A full disk or a vanished mount shows up as an OSError deep in a writer, with no file named;
the user needs to know which output it was and whether what is on disk is usable.
"""

from __future__ import annotations

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
