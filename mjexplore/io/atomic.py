"""Atomic file and directory output: write to a temporary name, then rename.

A reader never sees a half-written file: either the old content or the new one. Outputs get
the usual permissions for the process's umask (not the temporary files' private ones).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from mjexplore.errors import UserInputError

_UMASK = os.umask(0o022)
os.umask(_UMASK)


def give_usual_permissions(path: str | os.PathLike) -> None:
    """Sets a (temporary) file's or folder's mode to what the umask gives new ones."""
    os.chmod(path, (0o777 if Path(path).is_dir() else 0o666) & ~_UMASK)


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
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        give_usual_permissions(tmp)
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if path.exists():
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        os.replace(path, old)
    os.replace(tmp, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
