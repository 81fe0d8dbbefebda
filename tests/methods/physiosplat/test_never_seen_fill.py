"""The tool field's fill of never-seen tissue on the small grasping phantom (the tool in every
frame): tissue Gaussians there, marked unobserved, close the tool-free view's hole, and the
`observed` channel tells them apart."""

import pytest
import torch
from scipy.ndimage import distance_transform_edt

from surgsplat.data.never_seen import never_seen_pixels
from surgsplat.data.scene import load_scene
from surgsplat.methods.overrides import apply_values
from surgsplat.methods.physiosplat.tool_field import OBSERVED_KEY, SEMANTIC_KEY
from surgsplat.methods.registry import method_config
from surgsplat.model.channels import OBSERVED
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.trainer import Trainer


def _tool_free(grasping_phantom, tmp_path, fill: bool):
    scene = load_scene(grasping_phantom)
    config = apply_values(method_config("physiosplat"),
                          {"train": {"iterations": 1},
                           "components": {"tool": {"fill_never_seen": fill}}})
    trainer = Trainer(config, scene, tmp_path / f"run-{fill}")
    frame = scene.test_frames[0]
    output = render_frame(trainer.model, frame.camera,
                          FrameTime(frame.index, frame.time, tissue_only=True))
    return trainer.model, output, never_seen_pixels(scene.train_frames)


@pytest.mark.slow
def test_never_seen_tissue_is_filled_marked_and_closes_the_hole(grasping_phantom, tmp_path):
    """Before training, measured: mean tool-free opacity over the never-seen pixels 0.15
    without the fill and 0.999 with it; bounds 0.3 and 0.95. Beyond 5 px of the filled pixels,
    the observed share of the opacity is above 0.95."""
    _, without, region = _tool_free(grasping_phantom, tmp_path, fill=False)
    model, filled, _ = _tool_free(grasping_phantom, tmp_path, fill=True)
    assert region is not None and region.sum() > 100
    assert float(without.alpha[region].mean()) < 0.3
    assert float(filled.alpha[region].mean()) > 0.95
    params = model.gaussians.params
    fill_rows = params[OBSERVED_KEY] == 0
    assert fill_rows.sum() > 20 and (params[SEMANTIC_KEY][fill_rows] > 0).all()  # tissue
    observed = filled.extras[OBSERVED][..., 0]
    assert float(observed[region].mean()) < 0.2
    beyond = torch.from_numpy(distance_transform_edt(~region.numpy()) > 5)
    seen = (filled.alpha > 0.9) & beyond
    assert float((observed[seen] / filled.alpha[seen]).mean()) > 0.95
    assert OBSERVED not in without.extras


@pytest.mark.slow
def test_tool_free_videos_show_the_observed_channel(grasping_phantom, tmp_path):
    from surgsplat.cli.render_videos import render_command

    scene = load_scene(grasping_phantom)
    config = apply_values(method_config("physiosplat"), {"train": {"iterations": 1}})
    Trainer(config, scene, tmp_path / "run").fit()
    render_command(tmp_path / "run", out=tmp_path / "videos", fps=5.0, tool_free=True)
    assert (tmp_path / "videos" / f"{OBSERVED}.mp4").stat().st_size > 0
