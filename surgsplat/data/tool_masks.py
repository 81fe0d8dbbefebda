"""Tool masks from user label images, paired with frames, and grown or shrunk for robustness
runs. The label images are read by `surgsplat.data.scene.read_tool_mask`, the one reader of
tool masks: a binary mask holds 0 (tissue) and one other value (tool), in one channel or
several; a class-ID mask (e.g. CholecSeg8k's watershed masks) holds one integer class per
pixel, in one channel or in three equal channels, and the classes listed as tool labels are
tool, all others tissue.

Mask files are paired with frames either by the numbers in their names (frame_561_endo.png and
frame_561_endo_watershed_mask.png share (561,)) or by sorted order.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import torch

from surgsplat.data.layout import name_numbers
from surgsplat.data.scene import Scene
from surgsplat.errors import DataError, SurgsplatError

MASK_MATCHES = ("auto", "number", "order")
"""How mask files are paired with frames: by the numbers in the names, by sorted order, or
"auto" (numbers for a folder of frames, order for a video)."""


def resolve_mask_match(mode: str, is_video: bool) -> str:
    """`mode` (one of MASK_MATCHES) with "auto" replaced by "order" or "number"."""
    if mode not in MASK_MATCHES:
        raise SurgsplatError(f"unknown mask matching {mode!r}; expected one of "
                             f"{', '.join(MASK_MATCHES)}")
    if mode == "auto":
        return "order" if is_video else "number"
    if mode == "number" and is_video:
        raise SurgsplatError("a video's frames have no file names: match masks by order")
    return mode


def match_masks(frame_files: list[Path] | None, frame_count: int, mask_files: list[Path],
                mode: str) -> list[Path | None]:
    """The mask file of each frame (None where a frame has none).

    frame_files: the frames' files, or None for a video; mode: "order" or "number" (see
    `resolve_mask_match`). Matching by order needs as many masks as frames; by number, each
    frame's and each mask's name numbers must be unique, and masks matching no frame are ignored.
    """
    mask_folder = mask_files[0].parent
    if mode == "order":
        if len(mask_files) != frame_count:
            raise DataError(mask_folder, f"holds {len(mask_files)} mask files but the source has "
                                         f"{frame_count} frames (masks are matched by sorted "
                                         "order)")
        return list(mask_files)
    masks_by_key = _unique_keys(mask_files, "masks")
    return [masks_by_key.get(key) for key in _unique_keys(frame_files, "frames")]  # frame order


def _unique_keys(files: list[Path], what: str) -> dict[tuple[int, ...], Path]:
    by_key: dict[tuple[int, ...], Path] = {}
    for path in files:
        key = name_numbers(path)
        if key in by_key:
            option = "--mask-pattern" if what == "masks" else "--pattern"
            raise DataError(path.parent, f"{what} {by_key[key].name} and {path.name} carry the "
                                         f"same numbers {key}, so masks cannot be matched by "
                                         f"number; select one kind of file with {option} or "
                                         "match by order")
        by_key[key] = path
    return by_key


def offset_tool_masks(scene: Scene, pixels: int) -> Scene:
    """`scene` with every training frame's tool mask grown (pixels > 0) or shrunk (pixels < 0)
    by |pixels| with a (2 |pixels| + 1)-pixel square kernel: imperfect segmentation, for
    mask-robustness runs. Test frames keep their masks, so metrics see the true ones."""
    if pixels == 0:
        return scene
    kernel = np.ones((2 * abs(pixels) + 1,) * 2, np.uint8)
    change = cv2.dilate if pixels > 0 else cv2.erode
    frames = []
    for frame in scene.frames:
        if not frame.is_test:
            tool = change(frame.tool.numpy().astype(np.uint8), kernel)
            frame = frame.with_tool(torch.from_numpy(tool.astype(bool)))
        frames.append(frame)
    return dataclasses.replace(scene, frames=frames)
