"""Reading safetensors files (tensors and their string metadata) without unpickling."""

from __future__ import annotations

import json
import os
from pathlib import Path

from mjexplore.errors import UserInputError


def read_tensor_file(path: str | os.PathLike, what: str, hint: str) -> tuple[dict, dict]:
    """The tensors and the ``__metadata__`` strings of a safetensors file.

    Args:
        path: The file.
        what: What the file should hold, for messages ("policy weights").
        hint: How to get a right one, appended to every message.

    Raises:
        UserInputError: unreadable, not a safetensors file, or truncated.
    """
    from safetensors import SafetensorError
    from safetensors.torch import load

    path = Path(path)
    try:
        blob = path.read_bytes()
    except OSError as exc:
        raise UserInputError(f"cannot read {what} {str(path)!r}: {exc.strerror}; {hint}") \
            from None
    try:
        tensors = load(blob)
        header_len = int.from_bytes(blob[:8], "little")
        meta = json.loads(blob[8:8 + header_len]).get("__metadata__", {})
    except (SafetensorError, ValueError, UnicodeDecodeError) as exc:
        raise UserInputError(f"{str(path)!r} is not a readable safetensors file ({exc}); "
                             f"{hint}") from None
    return tensors, meta
