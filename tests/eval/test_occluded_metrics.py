"""Occluded-tissue metrics: the render under the tool against the phantom's tissue-only truth."""

import math

import numpy as np
import torch

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom.generate import TISSUE_DEPTH_DIR, TISSUE_IMAGES_DIR
from surgsplat.data.scene import Frame, load_scene, read_image
from surgsplat.eval.render_families import occluded_row


def _frame_with_tool(scene):
    return max(scene.frames, key=lambda frame: int(frame.tool.sum()))


def test_the_hidden_tissue_itself_scores_perfectly(small_phantom):
    scene = load_scene(small_phantom)
    frame = _frame_with_tool(scene)
    stem = frame_stem(frame.index)
    truth = torch.from_numpy(read_image(small_phantom / TISSUE_IMAGES_DIR / f"{stem}.png")) / 255.0
    depth = torch.from_numpy(np.load(small_phantom / TISSUE_DEPTH_DIR / f"{stem}.npy"))
    row = occluded_row(truth, depth, frame, small_phantom)
    assert row["psnr_occluded"] == math.inf
    assert row["depth_rmse_occluded"] == 0.0


def test_the_frame_with_its_tool_scores_the_tool_against_the_tissue(small_phantom):
    """The observed image shows the tool where the truth shows tissue: a low PSNR, and the tool's
    depth (nearer than the tissue) gives an error of at least a millimetre."""
    scene = load_scene(small_phantom)
    frame = _frame_with_tool(scene)
    row = occluded_row(frame.image, frame.depth, frame, small_phantom)
    assert row["psnr_occluded"] < 25.0
    assert row["depth_rmse_occluded"] > 1.0


def test_frames_without_truth_or_tool_give_no_row(small_phantom, tmp_path):
    scene = load_scene(small_phantom)
    frame = _frame_with_tool(scene)
    assert occluded_row(frame.image, frame.depth, frame, tmp_path) == {}
    toolless = Frame(index=frame.index, time=frame.time, image=frame.image, depth=frame.depth,
                     is_test=frame.is_test, camera=frame.camera,
                     tool=torch.zeros_like(frame.tool), fov=frame.fov)
    assert occluded_row(toolless.image, toolless.depth, toolless, small_phantom) == {}
