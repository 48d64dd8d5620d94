"""Atomic file and directory output: write to a temporary name, then rename.

A reader never sees a half-written file: either the old content or the new one. Outputs get
the usual permissions for the process's umask (not the temporary files' private ones).

:func:`check_output_folder` and :func:`check_output_file` refuse, before any work, an output
path that cannot be written (a file in the way, no permission, a read-only or virtual
filesystem such as ``/proc``), with a message that names the path and the fix.
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from mjexplore.errors import UserInputError

_UMASK = os.umask(0o022)
os.umask(_UMASK)


def give_usual_permissions(path: str | os.PathLike) -> None:
    """Sets a (temporary) file's or folder's mode to what the umask gives new ones."""
    os.chmod(path, (0o777 if Path(path).is_dir() else 0o666) & ~_UMASK)


def _nearest_existing(path: Path) -> Path:
    """``path`` or the nearest of its ancestors that exists."""
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


def _probe_writable(folder: Path, flag: str, path: Path) -> None:
    """Makes and removes a temporary folder in ``folder``: the one test that every
    filesystem answers truly (permissions, read-only mounts, /proc and /sys)."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".mjexplore-probe.", dir=folder))
    except OSError as exc:
        reasons: dict[int | None, str] = {
            errno.ENOENT: "it takes no new files: a virtual filesystem such as /proc?",
            errno.EROFS: "a read-only filesystem",
            errno.EACCES: "permission denied",
            errno.EPERM: "permission denied"}
        reason = reasons.get(exc.errno, exc.strerror or str(exc))
        raise UserInputError(f"{flag} {str(path)!r}: cannot write in {str(folder)!r} ({reason}): "
                             "choose a folder you can write to.") from None


def check_output_folder(path: str | os.PathLike, flag: str = "--out") -> Path:
    """Refuses an output folder that cannot be made or written, before any work is done.

    The folder may exist or not (then it and its missing parents are made later); the
    nearest existing folder above it must be a folder one can write in.

    Args:
        path: The output folder.
        flag: The option that named it, for messages (e.g. ``--out``).

    Returns:
        ``path`` as a Path.

    Raises:
        UserInputError: ``path`` is a file, a file stands where a folder above it should be,
            or the folder it would be made in cannot be written.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserInputError(f"{flag} {str(path)!r} is a file, not a folder: choose a new "
                             "folder name.")
    existing = _nearest_existing(path)
    if not existing.is_dir():
        raise UserInputError(f"{flag} {str(path)!r}: {str(existing)!r} is a file, so no folder "
                             "can be made below it: choose another path.")
    _probe_writable(existing, flag, path)
    return path


def foreign_entries(path: str | os.PathLike, ours: Iterable[str]) -> list[str]:
    """The names in the folder ``path`` (none if it does not exist) that match none of the
    shell patterns ``ours`` (a command's own outputs), sorted."""
    path = Path(path)
    if not path.is_dir():
        return []
    patterns = tuple(ours)
    return sorted(p.name for p in path.iterdir()
                  if not any(fnmatch.fnmatchcase(p.name, pattern) for pattern in patterns))


def refuse_foreign_files(path: str | os.PathLike, ours: Iterable[str], what: str,
                         flag: str = "--out") -> None:
    """Refuses an output folder that holds files other than the outputs of ``what`` (the
    shell patterns ``ours``): resuming into it would mix them in.

    Raises:
        UserInputError: naming up to three of the other files.
    """
    others = foreign_entries(path, ours)
    if others:
        named = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3
                                         else "")
        raise UserInputError(f"{flag} {str(path)!r} holds files that are not {what}'s outputs "
                             f"({named}): choose a new folder, or empty that one.")


def check_output_file(path: str | os.PathLike, flag: str,
                      suffixes: Iterable[str] | None = None) -> Path:
    """Refuses an output file that cannot be written, before any work is done: its folder
    must exist (nothing is made outside what was asked) and take new files, the path must
    not be a folder, and its suffix must be one of ``suffixes`` (lower case, with the dot)
    when they are given.

    Raises:
        UserInputError: any of those, with the fix.
    """
    path = Path(path)
    if suffixes is not None:
        suffixes = tuple(suffixes)
        if path.suffix.lower() not in suffixes:
            raise UserInputError(f"{flag} {str(path)!r}: give a file ending in "
                                 f"{' or '.join(suffixes)} (the format written).")
    if path.is_dir():
        raise UserInputError(f"{flag} {str(path)!r} is a folder: give a file name.")
    parent = path.parent
    if not parent.exists():
        raise UserInputError(f"{flag} {str(path)!r}: the folder {str(parent)!r} does not exist: "
                             "create it first, or choose a path in an existing folder.")
    if not parent.is_dir():
        raise UserInputError(f"{flag} {str(path)!r}: {str(parent)!r} is a file, not a folder: "
                             "choose another path.")
    _probe_writable(parent, flag, path)
    return path


def make_folders(path: Path) -> list[Path]:
    """Makes ``path`` and its missing parents; returns those it made, deepest first (see
    :func:`remove_made_folders`)."""
    made = []
    probe = path
    while not probe.exists() and probe.parent != probe:
        made.append(probe)
        probe = probe.parent
    path.mkdir(parents=True, exist_ok=True)
    return made


def remove_made_folders(made: list[Path]) -> None:
    """Removes the folders :func:`make_folders` made, deepest first, as far as they are
    empty: a failed command leaves nothing behind."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            return


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Writes ``data`` to ``path`` through a temporary file in the same folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        give_usual_permissions(tmp)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Writes UTF-8 ``text`` to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def _folder_beside(path: Path) -> tuple[Path, list[Path]]:
    """A new temporary folder beside ``path`` (named after it, hidden) and the parent folders
    made for it (:func:`make_folders`; none are left if it cannot be made)."""
    made = make_folders(path.parent)
    try:
        return Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp",
                                     dir=path.parent)), made
    except BaseException:
        remove_made_folders(made)
        raise


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, marker: str) -> Iterator[Path]:
    """Yields a temporary folder that replaces ``path`` as a whole when the block succeeds.

    If the block raises, the temporary folder is removed and ``path`` is left untouched.
    An existing ``path`` is replaced only after the new content is complete, and only if
    it is empty or an earlier output of the same kind (it holds ``marker``, a file every
    such output has): a folder of other files is refused before the block runs.

    Raises:
        UserInputError: ``path`` is a file, a filesystem root, or a folder of other files.
    """
    path = Path(path).resolve()
    if path.parent == path:
        raise UserInputError(f"{str(path)!r} cannot be an output folder: choose a new folder.")
    if path.exists() and not path.is_dir():
        raise UserInputError(f"{str(path)!r} is a file, not an output folder: choose a new "
                             "folder name.")
    if path.is_dir() and any(path.iterdir()) and not (path / marker).is_file():
        raise UserInputError(
            f"{str(path)!r} already holds other files (no {marker}, so it is not an earlier "
            "output of this command, which would be replaced): choose a new folder, or "
            "empty that one.")
    check_output_folder(path, "output folder")
    if path.exists():
        _probe_writable(path.parent, "output folder", path)  # The new one is made beside it.
    tmp, made = _folder_beside(path)
    try:
        give_usual_permissions(tmp)
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_made_folders(made)
        raise
    old = None
    if path.exists():
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        os.replace(path, old)
    os.replace(tmp, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged_files(folder: str | os.PathLike) -> Iterator[Path]:
    """Yields a temporary folder beside ``folder`` whose files move into ``folder`` (made if
    missing; files of the same names replaced, others kept) when the block succeeds; if it
    raises, they are removed and ``folder`` is left as it was.
    """
    folder = Path(folder)
    tmp, made = _folder_beside(folder)
    try:
        yield tmp
        folder.mkdir(exist_ok=True)
        for path in tmp.iterdir():
            give_usual_permissions(path)
            os.replace(path, folder / path.name)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_made_folders(made)
        raise
    shutil.rmtree(tmp, ignore_errors=True)
