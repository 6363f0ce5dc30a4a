"""Reading the user's text files (config, site, points, scenario, run log) so that bad bytes
give one line: which file, what is wrong with it, and where -- never a traceback.

Each caller passes its own :class:`~rfhoming.protocol.errors.Error` subclass, so the message
reaches the user through the same path as the file's other problems.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from rfhoming.protocol.errors import Error


def read_text(path: Path | str, what: str, error: type[Error]) -> str:
    """The file as UTF-8 text; ``error`` names it (``what``: "config", "site file" ...)."""
    try:
        return Path(path).read_bytes().decode("utf-8")
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} is not UTF-8 text (byte {exc.start} is 0x{exc.object[exc.start]:02x}): "
                    "save it as UTF-8") from None


def read_toml(path: Path | str, what: str, error: type[Error]) -> dict[str, Any]:
    """The file parsed as TOML; the error gives the line and column of a syntax error."""
    try:
        return tomllib.loads(read_text(path, what, error))
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None
