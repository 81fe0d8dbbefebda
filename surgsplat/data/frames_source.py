"""Frames of a video file or of a folder of images, read in order.

A folder's files are sorted naturally (frame_2 before frame_10); a name pattern picks one kind
of file from a folder holding several (e.g. "*_endo.png" beside "*_endo_mask.png"). Videos are
decoded with OpenCV (FFmpeg backend: mp4, avi, mov, mkv, ...).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from surgsplat.data.layout import name_numbers  # noqa: F401 (re-exported)
from surgsplat.data.layout import IMAGE_SUFFIXES, list_files, not_a_file_problem
from surgsplat.data.scene import native_stderr_to, read_image
from surgsplat.errors import DataError

PIPE_ADVICE = ("which can be read only once, but import reads a video several times; save the "
               "stream to a file and import that")
"""Why a pipe cannot be a source, and what to do instead."""


def list_frame_files(folder: Path, pattern: str | None, what: str = "frame") -> list[Path]:
    """Files of `folder` matching the glob `pattern` (default: any image file), sorted naturally
    (`list_files`, which names any entry of such a name that is not a file)."""
    if not folder.is_dir():
        raise DataError(folder, f"is not a folder of {what} images")
    files = list_files(folder, IMAGE_SUFFIXES, pattern)
    if not files:
        wanted = (f"image files ({', '.join(IMAGE_SUFFIXES)})" if pattern is None
                  else f"files matching {pattern!r}")
        raise DataError(folder, f"holds no {what} {wanted}")
    return files


def source_problem(path: Path) -> str:
    """Why `path`, neither a folder nor a regular file, cannot be a video or a folder of
    frames (`not_a_file_problem`, with advice for a pipe)."""
    if path.is_fifo():
        return f"{not_a_file_problem(path)}, {PIPE_ADVICE}"
    return f"{not_a_file_problem(path)}: expected a video file or a folder of frames"


class FrameSource:
    """An ordered sequence of uint8 RGB frames [H, W, 3] from a video file or an image folder."""

    def __init__(self, path: str | Path, pattern: str | None = None):
        self.path = Path(path)
        self.files: list[Path] | None = None  # the image files of a folder; None for a video
        if self.path.is_dir():
            self.files = list_frame_files(self.path, pattern)
            self.count = len(self.files)
        elif self.path.is_file():
            if self.path.suffix.lower() in IMAGE_SUFFIXES:
                raise DataError(self.path, "is a single image: expected a video file or a folder "
                                           "of frames")
            self.count = self._video_frame_count()
        else:
            raise DataError(self.path, source_problem(self.path))

    @property
    def is_video(self) -> bool:
        return self.files is None

    def frame_path(self, index: int) -> Path:
        """The file holding frame `index` (the video itself for a video), for messages."""
        return self.path if self.files is None else self.files[index]

    def frame_label(self, index: int) -> str:
        """A short name of frame `index`: its file name, or "frame <index>" of a video."""
        return f"frame {index}" if self.files is None else self.files[index].name

    def read(self, indices: Sequence[int]) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (index, uint8 RGB frame [H, W, 3]) for the ascending frame `indices`."""
        if any(b <= a for a, b in zip(indices, indices[1:])):
            raise ValueError("frame indices must be strictly increasing")
        if self.files is not None:
            for index in indices:
                yield index, read_image(self.files[index])
            return
        capture = self._open()
        try:
            position = 0
            for index in indices:
                while position < index:
                    self._grab(capture, position)
                    position += 1
                self._grab(capture, position)
                ok, bgr = self._named(capture.retrieve)
                if not ok:
                    raise DataError(self.path, f"cannot decode frame {position}")
                position += 1
                yield index, np.ascontiguousarray(bgr[..., ::-1])
        finally:
            capture.release()

    def _named(self, call: Callable, *args):
        """call(*args), with what the video decoder (FFmpeg inside OpenCV) prints passed on
        as a warning that names the video file."""
        printed: list[str] = []
        with native_stderr_to(printed):
            result = call(*args)
        if printed:
            warnings.warn(f"{self.path}: {' '.join(printed)}", stacklevel=3)
        return result

    def _open(self) -> cv2.VideoCapture:
        capture = self._named(cv2.VideoCapture, str(self.path))
        if not capture.isOpened():
            capture.release()
            raise DataError(self.path, "cannot be opened as a video (unknown format or corrupt)")
        return capture

    def _grab(self, capture: cv2.VideoCapture, position: int) -> None:
        if not self._named(capture.grab):
            raise DataError(self.path, f"ended after {position} frames although its header "
                                       f"says {self.count}; import fewer frames with --end "
                                       f"{position}")

    def _video_frame_count(self) -> int:
        capture = self._open()
        try:
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
            if count <= 0:  # no usable header: count by decoding
                count = 0
                while self._named(capture.grab):
                    count += 1
        finally:
            capture.release()
        if count == 0:
            raise DataError(self.path, "holds no video frames")
        return count
