"""PhysioSplat end to end on the small phantom: tool Gaussians from the tool pixels' depth
(through the contract's `initial_points` hook), training, metrics from the tool-free render,
tool-free videos; the mask-robustness option; the phantom's highlight masks."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
import torch

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom.generate import HIGHLIGHTS_DIR
from surgsplat.data.scene import load_scene
from surgsplat.data.tool_masks import offset_tool_masks
from surgsplat.errors import SurgsplatError
from surgsplat.eval.run_metrics import EvalOptions, evaluate_run
from surgsplat.export.articulation import articulate
from surgsplat.methods.overrides import apply_values
from surgsplat.methods.registry import method_config
from surgsplat.methods.physiosplat.tool_field import SEMANTIC_KEY
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import Trainer


@pytest.mark.slow
def test_physiosplat_trains_scores_the_tool_free_render_and_writes_its_videos(
        small_phantom, tmp_path):
    from surgsplat.cli.render_videos import render_command
    from surgsplat.pipeline.render import write_run_videos

    scene = load_scene(small_phantom)
    config = apply_values(method_config("physiosplat"), {"train": {"iterations": 12}})
    trainer = Trainer(config, scene, tmp_path / "run")
    logits = trainer.model.gaussians.params[SEMANTIC_KEY]
    tool_field = trainer.model.components["tool"]
    assert 50 < int((logits < 0).sum()) <= 4000  # tool Gaussians from the tool pixels
    assert tool_field.seen.any() and not tool_field.seen.all()  # the tool enters the view
    trainer.fit()
    run = load_trained_run(tmp_path / "run")
    assert run.model.separates_tool
    metrics = evaluate_run(run, EvalOptions(geometry=False))
    for key in ("psnr_occluded", "depth_rmse_occluded_mm", "psnr_specular", "collisions",
                "arap_strain_mean"):
        assert np.isfinite(metrics[key]), key
    paths = write_run_videos(run, tmp_path / "tool_free", fps=5.0, tissue_only=True)
    assert all(path.stat().st_size > 0 for path in paths)

    other = apply_values(method_config("endogaussian"), {"train": {"iterations": 1}})
    Trainer(other, scene, tmp_path / "plain").fit()
    with pytest.raises(SurgsplatError, match="--tool-free: .* has no tool field"):
        render_command(tmp_path / "plain", tool_free=True)
    with pytest.raises(SurgsplatError, match="has no tool field, so it has no tool to articulate"):
        articulate(load_trained_run(tmp_path / "plain"))


def test_tool_mask_offset_grows_and_shrinks_training_masks_only(small_phantom):
    scene = load_scene(small_phantom)
    frame = max(scene.train_frames, key=lambda f: int(f.tool.sum()))
    test = max(scene.test_frames, key=lambda f: int(f.tool.sum()))
    grown = {f.index: f for f in offset_tool_masks(scene, 3).frames}
    shrunk = {f.index: f for f in offset_tool_masks(scene, -1).frames}
    assert grown[frame.index].tool.sum() > frame.tool.sum()
    assert (grown[frame.index].tool | ~frame.tool).all()  # contains the original
    assert shrunk[frame.index].tool.sum() < frame.tool.sum()
    assert torch.equal(grown[frame.index].tissue, grown[frame.index].fov & ~grown[frame.index].tool)
    assert torch.equal(grown[test.index].tool, test.tool)
    assert offset_tool_masks(scene, 0) is scene
    assert dataclasses.replace(method_config("physiosplat").train).tool_mask_offset_px == 0


def test_phantom_marks_the_tissue_highlights(small_phantom):
    scene = load_scene(small_phantom)
    frame = scene.frames[0]
    mask = cv2.imread(str(small_phantom / HIGHLIGHTS_DIR / f"{frame_stem(0)}.png"),
                      cv2.IMREAD_UNCHANGED) > 0
    mask = torch.from_numpy(mask) & frame.tissue
    assert 0 < int(mask.sum()) < 0.2 * mask.numel()
    brightness = frame.image.mean(dim=-1)
    assert brightness[mask].mean() > brightness[frame.tissue & ~mask].mean() + 0.1
