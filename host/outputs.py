"""Output files: replaced whole, never truncated, and named when they fail.

Every file a command writes is written to ``NAME.part`` beside NAME and renamed over NAME when
it is done (:class:`Output`), so NAME always holds either what it held before or a whole new
file: a command that fails before its inputs gave it anything leaves NAME as it was and no
``.part``; a command killed outright (kill -9, a power cut) leaves NAME as it was and what it
had written in ``NAME.part``. A recording that grows while its command runs (a capture, a run
log, ``locate -o``'s lines) is ``NAME.part`` until the command ends: that is the file to follow
(``tail -f NAME.part``). :func:`os.replace` is the whole mechanism (atomic on POSIX and Windows
within one folder); the file is fsynced before it and the folder after it, so a power cut
leaves one or the other. No library: ``atomicwrites`` (1.4.1) is deprecated by its author, and
``safer`` renames a temporary file when a ``with`` block ends without an error but has no
stable name to follow and no stream that is kept once its inputs gave it something.

A write that fails (a full disk, a vanished mount) shows up as an OSError deep in a writer,
with no file named: :func:`failed` names the output and says what of it was kept.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import shlex
import stat
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from rfhoming.protocol.errors import Error

PART = ".part"
"""The suffix of an output being written (NAME.part): renamed to NAME when done."""


class WriteFailed(Error, OSError):
    """An output file could not be written; the message names it and what of it was kept."""


def part_of(path: Path | str) -> Path:
    """Where NAME is written until it is done: NAME.part beside it (beside its target, if NAME
    is a link to a file: the link stays)."""
    target = Path(path)
    with contextlib.suppress(OSError):
        if target.is_symlink() and target.is_file():
            target = target.resolve()
    return target.with_name(target.name + PART)


def written_in_place(path: Path | str) -> bool:
    """A device, a pipe or a terminal, or a name in /dev or /proc (``/dev/null``, ``/dev/stdout``
    even when it is a file the shell opened): written as it is, since it cannot be replaced (a
    rename would replace the device node, or the file under the shell's feet)."""
    if str(Path(path).absolute()).startswith(("/dev/", "/proc/")):
        return True
    try:
        return not stat.S_ISREG(os.stat(path).st_mode)
    except OSError:  # not there yet (or unreadable: opening it says why)
        return False


def check(path: Path | str) -> None:
    """Refuse, before anything is opened, an output that cannot be written: OSError (its
    strerror says why) or WriteFailed when NAME.part is there already."""
    check_all([path])


def check_all(paths: Iterable[Path | str]) -> None:
    """:func:`check` every output a command will write, before it starts: one WriteFailed names
    every NAME.part in the way (and the command that removes them), so that a user learns of
    them all at once, not one a run; the first other OSError as it is."""
    in_the_way: list[tuple[Path | str, Path]] = []
    for path in paths:
        if written_in_place(path):
            with open(path, "ab"):
                continue
        part = part_of(path)
        _refuse_read_only(part)
        try:
            with open(part, "xb"):
                pass
        except FileExistsError:
            in_the_way.append((path, part))
            continue
        os.unlink(part)
    if in_the_way:
        raise _busy(*in_the_way)


def _refuse_read_only(part: Path) -> None:
    """A file the user may not write is not replaced either (a rename needs only the folder)."""
    target = part.with_name(part.name[:-len(PART)])
    if target.exists() and not os.access(target, os.W_OK):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(target))


def _busy(*in_the_way: tuple[Path | str, Path]) -> WriteFailed:
    """NAME.part is there (one or several): what it may be, and the command that removes them."""
    parts = [str(part) for _path, part in in_the_way]
    names = ", ".join(str(path) for path, _part in in_the_way)
    them = "them" if len(parts) > 1 else "it"
    return WriteFailed(f"{', '.join(parts)} {'exist' if len(parts) > 1 else 'exists'}: another command is writing "
                       f"{names}, or one was killed while it did (what it wrote is in {them}); move {them} away or "
                       f"remove {them} (rm -- {' '.join(shlex.quote(p) for p in parts)}), then try again")


class Output:
    """NAME's new contents: :attr:`file` is NAME.part, renamed over NAME by :meth:`commit`.

    A whole file is written in a ``with`` block: committed when the block ends, discarded
    (NAME as it was) if it raises. A stream that grows as a command runs is *owned* once it
    holds something of the command's inputs (:meth:`own`; :meth:`write` owns it): its
    :meth:`close` renames it into place however the command ends, and removes it (NAME as it
    was) when the command ended before that."""

    def __init__(self, path: Path | str, *, binary: bool = False) -> None:
        self.path = Path(path)
        self.name = str(path)  # what the user named: error messages say it
        self.owned = False
        self._done = False
        self._abandoned = False  # a write failed: what is on disk is what there is
        self._target = self.path
        if written_in_place(self.path):
            self.part: Path | None = None
            self.file: IO[Any] = open(self.path, "wb" if binary else "w")
            return
        self.part = part_of(self.path)
        self._target = self.part.with_name(self.part.name[:-len(PART)])
        _refuse_read_only(self.part)
        try:
            self.file = open(self.part, "xb" if binary else "x")
        except FileExistsError:
            raise _busy((self.path, self.part)) from None
        with contextlib.suppress(OSError):  # a replaced file keeps its permissions
            os.chmod(self.part, stat.S_IMODE(os.stat(self._target).st_mode))

    def write(self, data: Any) -> int:
        """Write to the .part (text or bytes, as opened); the output is owned from now on."""
        self.owned = True
        written: int = self.file.write(data)
        return written

    def flush(self) -> None:
        self.file.flush()

    def own(self) -> None:
        """The output holds something of the command's inputs: it replaces NAME however the command ends."""
        self.owned = True

    def commit(self) -> None:
        """Flush, fsync and rename the .part over NAME (a write error: the .part goes, WriteFailed)."""
        if self._done:
            return
        self._done = True
        try:
            if not self.file.closed:
                self.file.flush()
                if self.part is not None:
                    os.fsync(self.file.fileno())
                self.file.close()
            if self.part is not None:
                os.replace(self.part, self._target)
                _sync_folder(self._target.parent)
        except OSError as exc:
            self._remove()
            raise WriteFailed(f"cannot write {self.name}: {exc.strerror or exc}; nothing of it is kept ({self.name} is "
                              "as it was)") from None

    def discard(self) -> None:
        """Close and remove the .part: NAME stays as it was."""
        if self._done:
            return
        self._done = True
        self._remove()

    def close(self) -> None:
        """Commit an owned output, discard one that holds nothing of the inputs (or, after a
        failed write, nothing at all: NAME is never replaced by an empty file)."""
        empty = self._abandoned and self.part is not None and not (self.part.is_file() and self.part.stat().st_size)
        if self.owned and not empty:
            self.commit()
        else:
            self.discard()

    def abandon(self) -> None:
        """A write failed: close the file (its buffer cannot be written either); :meth:`close`
        keeps what is on disk if the output is owned and that is not nothing."""
        self._abandoned = True
        with contextlib.suppress(OSError):
            self.file.close()

    def _remove(self) -> None:
        with contextlib.suppress(OSError):
            self.file.close()
        if self.part is not None:
            with contextlib.suppress(OSError):
                self.part.unlink()

    def __enter__(self) -> Output:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()


def _sync_folder(folder: Path) -> None:
    """The rename on disk too (POSIX: the folder's entry); where a folder cannot be opened, skipped."""
    with contextlib.suppress(OSError, AttributeError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def adopt(path: Path | str) -> bool:
    """NAME.part left by a writer of ours that is gone (a child process killed before it could
    rename it) renamed over NAME, as that writer's :meth:`Output.close` would have: what it
    wrote is the record of its run. True if there was one."""
    part = part_of(path)
    try:
        fd = os.open(part, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(part, part.with_name(part.name[:-len(PART)]))
    _sync_folder(part.parent)
    return True


def replace_text(path: Path | str, text: str) -> None:
    """NAME replaced by ``text`` in one step: its old contents or the new, never a torn file."""
    with Output(path) as out:
        out.write(text)


class Manifest:
    """Outputs replaced as one set: :meth:`start` removes ``NAME.manifest.json``, each output is then
    replaced whole (:class:`Output`), and :meth:`finish` writes the manifest last, naming every file of
    the set with its size and SHA-256. A reader that finds the manifest, and each file matching it, holds
    one run's set; after a kill between the first rename and the manifest there is no manifest, and the
    files may be two runs' (:func:`whole` says which)."""

    def __init__(self, path: Path | str, outputs: Iterable[Path | str]) -> None:
        self.path = Path(path)
        self.outputs = [Path(p) for p in outputs]

    def start(self) -> None:
        self.path.unlink(missing_ok=True)
        _sync_folder(self.path.parent)

    def finish(self, **about: Any) -> None:
        files = {p.name: {"bytes": p.stat().st_size, "sha256": _sha256(p)} for p in self.outputs}
        replace_text(self.path, json.dumps({**about, "files": files}, indent=1) + "\n")


def whole(manifest: Path | str) -> bool:
    """Whether ``manifest`` is there and every file it names, beside it, is the one it names."""
    path = Path(manifest)
    try:
        files = json.loads(path.read_text())["files"]
        return all(_sha256(path.with_name(name)) == f["sha256"] for name, f in files.items())
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def save_figure(figure: Any, path: Path | str, **savefig: Any) -> None:
    """A matplotlib figure saved to ``path`` whole (its format from the suffix, PNG without one):
    a plot that fails leaves the old figure."""
    with Output(path, binary=True) as out:
        figure.savefig(out.file, format=Path(path).suffix.lstrip(".") or "png", **savefig)


def failed(where: Output | Path | str, exc: OSError, kept: str) -> WriteFailed:
    """The error to raise for ``exc`` on an output; ``kept`` says what its bytes are good for
    when some were written and are kept. An :class:`Output` is abandoned (its file closed: what
    is on disk is kept at its close if it holds something of the inputs, else NAME stays as it
    was); an empty plain file is removed (:func:`remove_if_empty`)."""
    what = exc.strerror or str(exc)
    if isinstance(where, Output):
        where.abandon()
        name, written = where.name, where.part
        if written is not None:
            size = written.stat().st_size if written.is_file() else 0
            if not where.owned or not size:
                return WriteFailed(f"cannot write {name}: {what}; nothing of it is kept ({name} is as it was)")
            return WriteFailed(f"cannot write {name}: {what}; its {size} bytes are kept: {kept}")
    else:
        name = str(where)
    p = Path(name)
    if remove_if_empty(p):
        held = "nothing was written, and the empty file is removed"
    elif p.is_file():
        held = f"its {p.stat().st_size} bytes are kept: {kept}"
    else:
        held = "nothing of it is kept"
    return WriteFailed(f"cannot write {name}: {what}; {held}")


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

