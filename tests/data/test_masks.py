"""Tool masks (masks/) and the field-of-view mask (fov_mask.png) are kept apart on disk."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from surgsplat.data.layout import SceneMeta, SceneWriter
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError

H, W, N = 24, 32, 3


def disk() -> np.ndarray:
    """bool [H, W], a circular field of view clipped by the top and bottom rows."""
    ys, xs = np.mgrid[0:H, 0:W]
    return (xs - W / 2) ** 2 + (ys - H / 2) ** 2 <= 14.0 ** 2


def tool(index: int) -> np.ndarray:
    mask = np.zeros((H, W), dtype=bool)
    mask[8:14, 4 + 3 * index:12 + 3 * index] = True
    return mask


def write_scene(root: Path, fov: np.ndarray | None, tools: bool = True) -> Path:
    writer = SceneWriter(root, focal=30.0, meta=SceneMeta())
    for i in range(N):
        writer.add_frame(np.full((H, W, 3), 100, np.uint8), tool_mask=tool(i) if tools else None)
    if fov is not None:
        writer.set_fov(fov)
    return writer.finish()


def test_frame_exposes_tool_fov_and_tissue(tmp_path: Path):
    root = write_scene(tmp_path / "s", disk())
    stored = cv2.imread(str(root / "fov_mask.png"), cv2.IMREAD_UNCHANGED)
    assert stored.dtype == np.uint8 and set(np.unique(stored)) == {0, 255}
    scene = load_scene(root)
    assert scene.has_fov and scene.has_masks
    for i, frame in enumerate(scene.frames):
        assert frame.tool.dtype == frame.fov.dtype == frame.tissue.dtype == torch.bool
        assert np.array_equal(frame.tool.numpy(), tool(i))  # the tool alone, no border
        assert np.array_equal(frame.fov.numpy(), disk())
        assert np.array_equal(frame.tissue.numpy(), disk() & ~tool(i))


def test_without_fov_mask_every_pixel_is_in_view(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s", None))
    assert not scene.has_fov and not (tmp_path / "s" / "fov_mask.png").exists()
    assert all(bool(f.fov.all()) for f in scene.frames)
    assert np.array_equal(scene.frames[1].tissue.numpy(), ~tool(1))


def test_fov_without_tool_masks(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s", disk(), tools=False))
    assert scene.has_fov and not scene.has_masks
    assert not scene.frames[0].tool.any()
    assert np.array_equal(scene.frames[0].tissue.numpy(), disk())


def test_old_scene_with_the_border_in_masks_still_loads(tmp_path: Path):
    """Scenes imported before fov_mask.png hold the border as 255 in masks/."""
    writer = SceneWriter(tmp_path / "old", focal=30.0, meta=SceneMeta())
    for i in range(N):
        writer.add_frame(np.full((H, W, 3), 100, np.uint8), tool_mask=tool(i) | ~disk())
    scene = load_scene(writer.finish())
    assert not scene.has_fov
    assert np.array_equal(scene.frames[2].tissue.numpy(), disk() & ~tool(2))


def test_bad_fov_masks_name_the_file(tmp_path: Path):
    root = write_scene(tmp_path / "s", disk())
    cv2.imwrite(str(root / "fov_mask.png"), np.zeros((H, W), np.uint8))
    with pytest.raises(DataError, match="no pixel as inside the field of view") as info:
        load_scene(root)
    assert info.value.path.name == "fov_mask.png"
    cv2.imwrite(str(root / "fov_mask.png"), np.full((H + 1, W), 255, np.uint8))
    with pytest.raises(DataError, match=f"is {H + 1}x{W}") as info:
        load_scene(root)
    assert info.value.path.name == "fov_mask.png"
    inside = np.zeros((H, W), dtype=bool)
    inside[:, :2] = True  # only the first two columns in view ...
    cv2.imwrite(str(root / "fov_mask.png"), np.where(inside, 255, 0).astype(np.uint8))
    cv2.imwrite(str(root / "masks" / "000001.png"),  # ... and frame 1's tool covers them
                np.where(inside, 255, 0).astype(np.uint8))
    covered = r"every pixel inside the field of view \(fov_mask.png\) as tool"
    with pytest.raises(DataError, match=covered) as info:
        load_scene(root)
    assert info.value.path.name == "000001.png"
