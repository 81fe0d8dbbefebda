"""MP4 videos (H.264 through imageio-ffmpeg's bundled ffmpeg) and depth colour maps."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np

from surgsplat.atomic import replacing


class VideoWriter:
    """An H.264 mp4 written frame by frame (uint8 RGB [H, W, 3], all the same size, H and W
    even), atomically: inside `with`, frames go to a temporary file that replaces `path` when
    the block ends normally and is removed otherwise. At least one frame must be added."""

    def __init__(self, path: Path, fps: float = 15.0):
        self.path = Path(path)
        self.fps = fps
        self.count = 0
        self._stack = ExitStack()
        self._tmp: Path | None = None
        self._writer = None

    def __enter__(self) -> "VideoWriter":
        self._tmp = self._stack.enter_context(replacing(self.path))
        return self

    def add(self, frame: np.ndarray) -> None:
        if self._writer is None:
            height, width = frame.shape[:2]
            self._writer = imageio_ffmpeg.write_frames(
                str(self._tmp), (width, height), fps=self.fps, codec="libx264",
                pix_fmt_in="rgb24", pix_fmt_out="yuv420p", macro_block_size=2, quality=8,
                output_params=["-loglevel", "error"])
            self._writer.send(None)
            self._stack.callback(self._writer.close)  # before replacing() takes the file
        self._writer.send(np.ascontiguousarray(frame, dtype=np.uint8))
        self.count += 1

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
