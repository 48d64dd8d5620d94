"""H.264 MP4 writing (imageio-ffmpeg), atomic: frames go to a temporary file that is closed
and renamed into place when the writer closes, also on an exception or Ctrl-C."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import give_usual_permissions


class VideoWriter:
    """Writes RGB frames to an MP4.

    Args:
        path: Output ``.mp4``.
        fps: Frames per second of the video.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, path: str | os.PathLike, fps: float) -> None:
        try:
            import imageio.v2 as imageio
        except ImportError:
            raise UserInputError("video writing needs imageio and imageio-ffmpeg: "
                                 "pip install imageio imageio-ffmpeg.") from None
        if fps <= 0:
            raise UserInputError(f"video fps {fps} must be positive.")
        self.path = Path(path)
        if self.path.is_dir():
            raise UserInputError(f"{str(self.path)!r} is a folder: give the video a file name "
                                 "(e.g. video.mp4).")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=".mp4", prefix=f".{self.path.name}.",
                                   dir=self.path.parent)
        os.close(fd)
        self._tmp = Path(tmp)
        give_usual_permissions(self._tmp)
        self.fps = fps
        self.frames = 0
        self._writer = imageio.get_writer(self._tmp, format="FFMPEG", mode="I", fps=fps,
                                          codec="libx264", pixelformat="yuv420p",
                                          macro_block_size=2, quality=7,
                                          ffmpeg_log_level="error")
        self._closed = False

    def append(self, frame: np.ndarray) -> None:
        """Adds an (h, w, 3) uint8 RGB frame (even h and w)."""
        self._writer.append_data(np.ascontiguousarray(frame))
        self.frames += 1

    def close(self) -> None:
        """Finishes the file and moves it into place (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
            if self.frames:
                os.replace(self._tmp, self.path)
        finally:
            self._tmp.unlink(missing_ok=True)  # Gone already if it was moved into place.

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
