"""MP4 videos (H.264 through imageio-ffmpeg's bundled ffmpeg) and depth colour maps."""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np

from surgsplat.atomic import replacing


def write_video(path: Path, frames: Iterable[np.ndarray], fps: float = 15.0) -> int:
    """Write uint8 RGB frames [H, W, 3] (all the same size, H and W even) to an H.264 mp4,
    atomically (a stop part-way leaves the previous file, or none); returns the number of
    frames written."""
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        return 0
    count = 0
    with replacing(path) as tmp:
        height, width = first.shape[:2]
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p", macro_block_size=2, quality=8,
            output_params=["-loglevel", "error"])
        writer.send(None)
        try:
            for frame in itertools.chain([first], frames):
                writer.send(np.ascontiguousarray(frame, dtype=np.uint8))
                count += 1
        finally:
            writer.close()
    return count


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
