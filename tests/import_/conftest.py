"""Tiny generated endoscopic videos for the import tests."""

from pathlib import Path

import cv2
import numpy as np
import pytest

HEIGHT, WIDTH, FRAMES = 64, 96, 10
CENTER, RADIUS = (48.0, 32.0), 40.0  # the circular view, clipped by the top and bottom rows


def view_disk() -> np.ndarray:
    """bool [H, W], True inside the synthetic circular field of view."""
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    return (xs - CENTER[0]) ** 2 + (ys - CENTER[1]) ** 2 <= RADIUS ** 2


def tool_box(index: int) -> np.ndarray:
    """bool [H, W], the synthetic tool of frame `index`: a box moving right."""
    tool = np.zeros((HEIGHT, WIDTH), dtype=bool)
    tool[20:40, 20 + 3 * index:36 + 3 * index] = True
    return tool


def endoscope_frames(seed: int = 0) -> list[np.ndarray]:
    """FRAMES uint8 RGB frames [H, W, 3]: bright noisy tissue in a disk on a black border."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(FRAMES):
        tissue = rng.integers(80, 255, size=(HEIGHT, WIDTH, 3), dtype=np.uint8)
        frames.append(np.where(view_disk()[..., None], tissue, 0).astype(np.uint8))
    return frames


@pytest.fixture
def video(tmp_path: Path) -> Path:
    """An MJPG .avi of the endoscope frames."""
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (WIDTH, HEIGHT))
    for frame in endoscope_frames():
        writer.write(frame[..., ::-1])
    writer.release()
    return path


@pytest.fixture
def mask_folder(tmp_path: Path) -> Path:
    """Binary tool masks (255 = tool) mask_0.png .. mask_9.png, one per video frame."""
    folder = tmp_path / "masks"
    folder.mkdir()
    for i in range(FRAMES):
        cv2.imwrite(str(folder / f"mask_{i}.png"), tool_box(i).astype(np.uint8) * 255)
    return folder
