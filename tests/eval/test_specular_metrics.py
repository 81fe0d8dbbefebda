"""Highlight metrics: psnr_specular over the phantom's marked highlights, psnr_outside_highlights
over the rest of the tissue."""

import math

import torch

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom.generate import HIGHLIGHTS_DIR
from surgsplat.data.scene import load_scene, read_tool_mask
from surgsplat.eval.render_families import specular_row


def _frame_with_highlight(scene, root):
    def marked(frame):
        path = root / HIGHLIGHTS_DIR / f"{frame_stem(frame.index)}.png"
        return int((frame.tissue & torch.from_numpy(read_tool_mask(path))).sum())
    return max(scene.frames, key=marked)


def test_a_render_that_misses_only_the_highlights_loses_only_psnr_specular(small_phantom):
    scene = load_scene(small_phantom)
    frame = _frame_with_highlight(scene, small_phantom)
    path = small_phantom / HIGHLIGHTS_DIR / f"{frame_stem(frame.index)}.png"
    highlight = torch.from_numpy(read_tool_mask(path))
    assert specular_row(frame.image, frame, small_phantom) == {
        "psnr_specular": math.inf, "psnr_outside_highlights": math.inf}
    dulled = torch.where(highlight[..., None], frame.image * 0.5, frame.image)
    row = specular_row(dulled, frame, small_phantom)
    assert row["psnr_specular"] < 20.0  # half of a bright highlight is missing
    assert row["psnr_outside_highlights"] == math.inf


def test_a_scene_without_marked_highlights_gives_no_row(small_phantom, tmp_path):
    frame = load_scene(small_phantom).frames[0]
    assert specular_row(frame.image, frame, tmp_path) == {}
