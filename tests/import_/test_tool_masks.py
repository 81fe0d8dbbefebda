"""Label images to tool masks, and pairing masks with frames."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from surgsplat.data.scene import read_tool_mask
from surgsplat.data.tool_masks import match_masks, resolve_mask_match
from surgsplat.errors import DataError, SurgsplatError


def write(path: Path, image: np.ndarray) -> Path:
    cv2.imwrite(str(path), image)
    return path


def test_class_id_masks_with_equal_channels(tmp_path: Path):
    ids = np.array([[11, 31], [32, 50]], np.uint8)
    path = write(tmp_path / "m.png", np.repeat(ids[..., None], 3, axis=2))
    assert read_tool_mask(path, (31, 32)).tolist() == [[False, True], [True, False]]


def test_colour_coded_mask_is_refused(tmp_path: Path):
    path = write(tmp_path / "c.png", np.array([[[0, 0, 255], [255, 0, 0]]], np.uint8))
    with pytest.raises(DataError, match="colour-coded"):
        read_tool_mask(path, (31,))


def test_binary_masks_any_nonzero_is_tool(tmp_path: Path):
    path = write(tmp_path / "b.png", np.array([[0, 1], [1, 0]], np.uint8))
    assert read_tool_mask(path, None).tolist() == [[False, True], [True, False]]


def test_class_ids_without_tool_labels_are_refused(tmp_path: Path):
    path = write(tmp_path / "ids.png", np.array([[11, 31, 50]], np.uint8))
    with pytest.raises(DataError, match="--tool-labels"):
        read_tool_mask(path, None)


def test_match_by_number_and_order():
    frames = [Path(f"frame_{n}_endo.png") for n in (2, 10, 11)]
    masks = [Path(f"m/frame_{n}_endo_watershed_mask.png") for n in (10, 2, 99)]
    assert match_masks(frames, 3, masks, "number") == [masks[1], masks[0], None]
    assert match_masks(frames, 3, masks, "order") == masks
    with pytest.raises(DataError, match="holds 2 mask files but the source has 3"):
        match_masks(frames, 3, masks[:2], "order")
    twins = [Path("m/frame_2_endo_mask.png"), Path("m/frame_2_endo_watershed_mask.png")]
    with pytest.raises(DataError, match="same numbers"):
        match_masks(frames, 3, twins, "number")


def test_auto_match_depends_on_source_kind():
    assert resolve_mask_match("auto", is_video=True) == "order"
    assert resolve_mask_match("auto", is_video=False) == "number"
    with pytest.raises(SurgsplatError):
        resolve_mask_match("number", is_video=True)
