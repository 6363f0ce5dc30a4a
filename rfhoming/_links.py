"""A checkout made without symlinks fails on import with one line saying what to set.

The layers are committed directory symlinks (``rfhoming/host -> ../host``; docs/architecture.md says
why). Git with ``core.symlinks=false`` -- Git for Windows' default -- writes each link as a small
text file holding its target, under which nothing imports; this names that instead of a bare
``No module named 'rfhoming.host'``. setup.py runs the same check before it builds.
"""

import os  # not pathlib: this runs on every import of rfhoming

LINKS = ("protocol", "firmware", "emulator", "host", "campaigns")
FIX = ("clone again with `git clone -c core.symlinks=true` (on Windows turn on Developer Mode first), "
       "or in this checkout run `git config core.symlinks true` then `git checkout -- rfhoming src`")


def unlinked(folder: str = os.path.dirname(__file__)) -> str | None:
    """The first of ``folder``'s layer links that git wrote as a plain file, or None."""
    for name in LINKS:
        path = os.path.join(folder, name)
        if os.path.isfile(path):  # a link's target is a folder; a wheel's copy or a zip is no file either
            return path
    return None


def check(folder: str = os.path.dirname(__file__)) -> None:
    """Raise ImportError naming the unlinked layer and the fix, if git checked one out as a file."""
    path = unlinked(folder)
    if path is not None:
        with open(path, encoding="utf-8", errors="replace") as file:
            target = file.read(200).strip()
        raise ImportError(f"{path} is a plain file holding {target!r}, not a symlink to that folder: "
                          f"this checkout was made with core.symlinks=false; {FIX}")
