"""Where a result came from: the git revision of the code that made it, and the hash of
the files (weights) it read."""

from __future__ import annotations

import hashlib
import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def git_revision() -> str:
    """The checked-out commit (with ``-dirty`` if there are uncommitted changes), or
    'unknown' outside a git checkout.

    A copy of a commit's files without its history (a container image, a cluster node)
    names its commit in the environment variable ``MJEXPLORE_GIT_REVISION``, which is then
    returned as it is, with ``-copy`` appended.
    """
    named = os.environ.get("MJEXPLORE_GIT_REVISION", "").strip()
    if named:
        return f"{named}-copy"
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True,
                             text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=REPO, capture_output=True, text=True, timeout=10).stdout
        return rev + ("-dirty" if dirty.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def file_sha256(path: str | os.PathLike) -> str:
    """The first 16 hex digits of a file's sha256: what run folders and reports name
    weights files by."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
