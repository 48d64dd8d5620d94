"""Files that travel as data: a folder packed into ``{relative path: bytes}`` and unpacked
on another machine, for Ray tasks that share no filesystem with the machine that sent them.

A bundle is unpacked once per machine into a folder named by its content's digest, so
tasks that share a scene or a policy write it once, and a changed file never reuses a
stale copy.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

from mjexplore.errors import UserInputError

Bundle = dict[str, bytes]
MAX_BYTES = 256 * 2**20  # What one task may carry; Ray's object store holds it once.
UNPACKED = "mjexplore-bundles"  # Under the system's temporary directory.


def pack_folder(folder: str | os.PathLike, max_bytes: int | None = MAX_BYTES) -> Bundle:
    """Every file under ``folder`` (recursively; links followed) as relative POSIX path ->
    content.

    Raises:
        UserInputError: the files weigh more than ``max_bytes`` (None: no bound).
    """
    folder = Path(folder)
    files: Bundle = {}
    total = 0
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        total += path.stat().st_size
        if max_bytes is not None and total > max_bytes:
            raise UserInputError(
                f"{str(folder)!r} holds more than {max_bytes / 2**20:.0f} MB of files, too much "
                "to send to each Ray worker: give the scene a folder of its own (its MJCF and "
                "the assets it needs).")
        files[path.relative_to(folder).as_posix()] = path.read_bytes()
    return files


def bundle_digest(files: Bundle) -> str:
    """The first 16 hex digits of the sha256 over the bundle's names and contents."""
    digest = hashlib.sha256()
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + len(files[name]).to_bytes(8, "little"))
        digest.update(files[name])
    return digest.hexdigest()[:16]


def unpack(files: Bundle, name: str, root: str | os.PathLike | None = None) -> Path:
    """The folder ``ROOT/DIGEST/NAME`` holding ``files`` (written now unless an earlier task
    on this machine wrote it; ``root`` None: the system's temporary directory).

    ``name`` keeps the folder's own name, which run folders and labels derive from.

    Raises:
        ValueError: a file name that is absolute or climbs out of the folder.
    """
    parent = Path(root or tempfile.gettempdir()) / UNPACKED / bundle_digest(files)
    folder = parent / name
    if folder.is_dir():
        return folder
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=parent))
    try:
        write_files(tmp, files)
        with contextlib.suppress(OSError):  # Another task on this machine was first.
            os.replace(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def write_files(folder: str | os.PathLike, files: Bundle) -> None:
    """Writes a bundle's files into the existing folder ``folder``.

    Raises:
        ValueError: a file name that is absolute or climbs out of the folder.
    """
    root = Path(folder).resolve()
    for relative, data in files.items():
        target = (root / relative).resolve()
        if Path(relative).is_absolute() or root not in target.parents:
            raise ValueError(f"bundle file {relative!r} lies outside its folder")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
