"""Writing a path the user named, safely: every command that writes one goes through here.

* :func:`check_regular_file`: a path that exists must be a regular file (symbolic links
  followed), never a device node, a FIFO, a socket or a folder;
* :func:`check_folder_target`: a folder of new files must be a folder, or not exist yet below
  a folder that takes new entries (tried for real: permission bits do not bind root);
* :func:`check_file_target`: both, for a file and the folder it goes into;
* :func:`atomic_write`: the file written to a unique temporary file in the target's folder,
  renamed onto the target at the end (through a symbolic link: onto the file it points to,
  the link kept); the temporary file never stays behind, also on error.

Each refusal is one line (what, where, how to fix) raised as a :class:`UserError` (the
caller's room's subclass where it passes one). This module sits at the bottom of the house
and imports nothing from nutribench but :mod:`nutribench.errors`.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from nutribench.errors import UserError


class WriteError(UserError):
    """A path a command was asked to write that cannot be written (one line)."""


_KINDS = (
    (stat.S_ISREG, "a file"),
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str:
    """What a path of ``st_mode`` ``mode`` is, in words ("a FIFO (named pipe)", "a character
    device", ...): for the one line of a writer or a reader that refuses it."""
    return next((word for test, word in _KINDS if test(mode)), "not a regular file")


def _label(path: Path, what: str) -> str:
    return f"{what} {path}" if what else str(path)


def _stat(path: Path) -> os.stat_result | None:
    """``os.stat(path)`` (links followed); None where nothing is there (or a dangling link)."""
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None


def check_regular_file(
    path: Path | str,
    what: str = "",
    error: type[UserError] = WriteError,
    hint: str = "give the path of a regular file or of a new one",
) -> None:
    """Refuse ``path`` if it exists and is not a regular file (after symbolic links): a device
    node, a FIFO, a socket or a folder is never replaced, truncated or read as a file. The line
    ends with ``hint`` (what to do)."""
    found = _stat(Path(path))
    if found is not None and not stat.S_ISREG(found.st_mode):
        raise error(f"{_label(Path(path), what)}: is {file_kind(found.st_mode)}, not a regular file: {hint}")


def check_folder_target(
    folder: Path | str, what: str = "", error: type[UserError] = WriteError, hint: str = "give a folder for the files"
) -> None:
    """Refuse ``folder`` (to hold new files) if it, or the nearest part of it that exists, is
    not a folder, or that folder refuses a new entry (a temporary folder made there and removed
    again). A folder that does not exist yet is made by the writer."""
    if why := _folder_problem(Path(folder)):
        raise error(f"{_label(Path(folder), what)}: {why}: {hint}")


def check_tensorboard(folder: Path) -> None:
    """``--tensorboard FOLDER``: a UserError (one line) when the tensorboard package is missing
    or ``folder`` cannot be a writable folder; the folder itself is created by the runs."""
    import importlib.util

    if importlib.util.find_spec("tensorboard") is None:
        raise UserError("--tensorboard needs the tensorboard package: pip install 'nutribench[tensorboard]'")
    check_folder_target(folder, "--tensorboard", UserError, "give a folder for the TensorBoard events")


def check_file_target(path: Path | str, what: str = "", error: type[UserError] = WriteError) -> None:
    """Refuse a file to write that exists and is not a regular file (:func:`check_regular_file`),
    or whose real folder cannot take it (as :func:`check_folder_target` would)."""
    check_regular_file(path, what, error)
    if why := _folder_problem(Path(os.path.realpath(path)).parent):
        raise error(f"{_label(Path(path), what)}: its folder {why}: give a path in a folder that takes new files")


def _folder_problem(folder: Path) -> str | None:
    """Why ``folder`` cannot take new files, or None."""
    found = next((p for p in (folder, *folder.absolute().parents) if _stat(p) is not None), None)
    if found is None:
        return None
    mode = os.stat(found).st_mode
    if not stat.S_ISDIR(mode):
        return f"{'is' if found == folder else f'lies in {found}, which is'} {file_kind(mode)}, not a folder"
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".nutribench-probe-", dir=found))
    except OSError as e:
        return f"cannot have new files in {found} ({e.strerror or e})"
    return None


def _mode_for(target: Path) -> int:
    """The permission bits the written file gets: the replaced file's, or what the umask gives a new one."""
    found = _stat(target)
    if found is not None:
        return stat.S_IMODE(found.st_mode)
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextmanager
def atomic_write(
    path: Path | str, what: str = "", error: type[UserError] = WriteError, hint: str = "give another path"
) -> Iterator[Path]:
    """Yield a unique temporary path in the folder of ``path`` (named ``.<name>.XXXX.tmp<suffix>``,
    the target's suffix kept for writers that go by it), then rename it onto ``path``; its
    folders are made first. ``path`` is checked first (:func:`check_file_target`); through a
    symbolic link the file it points to is replaced and the link kept. The temporary file is
    removed whatever happens; an OSError on the way is one line (``error``, ending in ``hint``)
    and ``path`` is left as it was."""
    path = Path(path)
    check_file_target(path, what, error)
    target = Path(os.path.realpath(path))
    tmp: Path | None = None
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=f".tmp{target.suffix}")
        tmp = Path(name)
        try:
            os.fchmod(fd, _mode_for(target))
        finally:
            os.close(fd)
        yield tmp
        os.replace(tmp, target)
    except OSError as e:
        raise error(f"{what + ': ' if what else ''}cannot write {path}: {e.strerror or e}: {hint}") from None
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
