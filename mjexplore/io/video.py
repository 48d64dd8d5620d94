"""H.264 MP4 writing (imageio-ffmpeg), atomic: frames go to a temporary file that is closed
and renamed into place when the writer closes, also on an exception or Ctrl-C, provided it is
a finished MP4 (see :func:`finished_mp4`); a file the encoder failed on is removed, never left
under the real name."""

from __future__ import annotations

import errno
import os
import struct
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

    Attributes:
        frames: Frames appended so far.
        written: Whether :meth:`close` moved a finished file to ``path``.

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
        self._failed = False
        self._interrupted = False
        self.written = False

    def append(self, frame: np.ndarray) -> None:
        """Adds an (h, w, 3) uint8 RGB frame (even h and w).

        Raises:
            OSError: the encoder (ffmpeg) stopped (it prints its reason on stderr); the file
                is then removed when the writer closes.
        """
        try:
            self._writer.append_data(np.ascontiguousarray(frame))
        except Exception as exc:
            self._failed = True
            raise OSError(errno.EIO, "the video encoder (ffmpeg) stopped (its messages, if "
                          "any, are above)", str(self.path)) from exc
        except BaseException:
            self._interrupted = True  # Ctrl-C in the encoder's pipe may have stopped it.
            raise
        self.frames += 1

    def close(self) -> None:
        """Finishes the file and moves it into place (idempotent); ``written`` tells whether
        it did. Nothing is written without frames, after the encoder failed, or when the file
        is not a finished MP4 (then removed).

        Raises:
            OSError: the encoder left an unfinished file without failing or being interrupted
                before.
        """
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
            if self.frames and not self._failed:
                if finished_mp4(self._tmp):
                    os.replace(self._tmp, self.path)
                    self.written = True
                elif not self._interrupted:
                    raise OSError(errno.EIO, "the video encoder (ffmpeg) left an unfinished "
                                  "file, removed", str(self.path))
        finally:
            self._tmp.unlink(missing_ok=True)  # Gone already if it was moved into place.

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def finished_mp4(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a finished MP4: its top-level boxes fill the file exactly and one
    of them is the index (``moov``), which ffmpeg writes last, on closing. A file cut short,
    or whose encoder was killed, fails that and plays nowhere."""
    size = os.path.getsize(path)
    pos, index = 0, False
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(16)
            if len(head) < 8:
                return False
            length, kind = struct.unpack(">I4s", head[:8])
            if length == 1 and len(head) == 16:  # A 64-bit size follows.
                length = struct.unpack(">Q", head[8:])[0]
            elif length == 0:  # The box runs to the end of the file.
                length = size - pos
            if length < 8:
                return False
            index |= kind == b"moov"
            pos += length
    return index and pos == size
