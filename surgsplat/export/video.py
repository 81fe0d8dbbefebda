"""MP4 videos (H.264 through imageio-ffmpeg's bundled ffmpeg) and depth colour maps."""

from __future__ import annotations

import errno
import os
import subprocess
import tempfile
from contextlib import ExitStack
from fractions import Fraction
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np

from surgsplat.atomic import replacing
from surgsplat.errors import SurgsplatError

CRF = 10
"""x264 constant rate factor of the videos (0 lossless .. 51 worst)."""
SYSTEM_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EIO)
"""Operating-system errors that ffmpeg names in its messages and surgsplat reports as such."""


def ffmpeg_command(path: Path, width: int, height: int, fps: float) -> list[str]:
    """ffmpeg reading raw RGB frames of `width` x `height` on its standard input and writing
    them to `path` as H.264 (yuv420p) at `fps`; it prints errors only."""
    return [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error",
            "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
            "-r", str(Fraction(fps).limit_denominator()), "-i", "-", "-an",
            "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", str(CRF), str(path)]


def encoding_error(path: Path, status: int, messages: str) -> Exception:
    """What a failed ffmpeg run writing `path` means: the OSError naming `path` when ffmpeg's
    `messages` name one of SYSTEM_ERRORS (a full disk, say), else a SurgsplatError quoting
    ffmpeg's last message and exit status."""
    for code in SYSTEM_ERRORS:
        if os.strerror(code) in messages:
            return OSError(code, os.strerror(code), str(path))
    last = next((line.strip() for line in reversed(messages.splitlines()) if line.strip()),
                "no message")
    return SurgsplatError(f"{path}: ffmpeg could not write the video (exit status {status}: "
                          f"{last})")


class VideoWriter:
    """An H.264 mp4 written frame by frame (uint8 RGB [H, W, 3], all the same size, H and W
    even), atomically: inside `with`, frames go to ffmpeg, which writes a temporary file; it
    replaces `path` only when the block ends normally, ffmpeg exits with status 0 and the file
    holds data, and is removed otherwise, leaving an existing `path` as it was. A failed encode
    raises encoding_error (an OSError naming `path` for a full disk). At least one frame must be
    added."""

    def __init__(self, path: Path, fps: float = 15.0):
        self.path = Path(path)
        self.fps = fps
        self.count = 0
        self._stack = ExitStack()
        self._tmp: Path | None = None
        self._messages = None  # ffmpeg's standard error, a temporary file
        self._ffmpeg: subprocess.Popen | None = None

    def __enter__(self) -> "VideoWriter":
        self._tmp = self._stack.enter_context(replacing(self.path))
        self._messages = self._stack.enter_context(tempfile.TemporaryFile())
        return self

    def add(self, frame: np.ndarray) -> None:
        if self._ffmpeg is None:
            height, width = frame.shape[:2]
            self._ffmpeg = subprocess.Popen(
                ffmpeg_command(self._tmp, width, height, self.fps), stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL, stderr=self._messages,
                process_group=0)  # Ctrl-C stops surgsplat, which then stops ffmpeg
            self._stack.push(self._stop_ffmpeg)  # before replacing() takes the file
        try:
            self._ffmpeg.stdin.write(np.ascontiguousarray(frame, dtype=np.uint8))
        except BrokenPipeError:  # ffmpeg stopped reading: it failed
            raise self._failure(self._ffmpeg.wait()) from None
        self.count += 1

    def _stop_ffmpeg(self, exc_type, exc, traceback) -> bool:
        """Exit function: let ffmpeg finish the file (kill it when the block failed), then
        raise encoding_error unless it exited with status 0 and wrote data."""
        if exc_type is not None:
            self._ffmpeg.kill()
        try:
            self._ffmpeg.stdin.close()
        except BrokenPipeError:
            pass  # ffmpeg exited early; its status says why
        status = self._ffmpeg.wait()
        if exc_type is None and (status != 0 or not self._tmp.is_file()
                                 or self._tmp.stat().st_size == 0):
            raise self._failure(status)
        return False

    def _failure(self, status: int) -> Exception:
        """encoding_error of this video, with what ffmpeg printed."""
        self._messages.seek(0)
        return encoding_error(self.path, status, self._messages.read().decode(errors="replace"))

    def __exit__(self, *exc) -> bool:
        return self._stack.__exit__(*exc)


def even_size(image: np.ndarray) -> np.ndarray:
    """Crop the last row/column if needed so both sides are even (yuv420p needs it)."""
    height, width = image.shape[:2]
    return image[: height - height % 2, : width - width % 2]


def colorize_depth(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """[H, W] depth -> uint8 RGB [H, W, 3], turbo colour map over [near, far]; 0 = black."""
    scaled = np.clip((depth - near) / max(far - near, 1e-9), 0.0, 1.0)
    coloured = cv2.applyColorMap((255 * (1.0 - scaled)).astype(np.uint8), cv2.COLORMAP_TURBO)
    coloured = coloured[..., ::-1].copy()
    coloured[depth <= 0] = 0
    return coloured


def colorize_normals(normals: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Unit camera-space normals [H, W, 3] (OpenCV axes, facing away from the camera) -> uint8
    RGB [H, W, 3] in the usual normal-map colours: the normal turned towards the viewer in
    x-right, y-up, z-to-viewer axes, mapped from [-1, 1] to [0, 1]; a surface facing the camera
    is (0.5, 0.5, 1) blue. Invalid pixels are black."""
    display = normals * np.array([-1.0, 1.0, 1.0], dtype=normals.dtype)
    coloured = to_uint8((display + 1.0) * 0.5)
    coloured[~valid] = 0
    return coloured


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float RGB in [0, 1] -> uint8."""
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
