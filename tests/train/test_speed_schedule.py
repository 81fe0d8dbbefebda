"""Coarse-to-fine training and training to a time budget: the downscaled frames keep the view,
every coarse stage runs, and a budgeted run ends at its budget with its schedule re-planned."""

from __future__ import annotations

import json

import pytest
import torch

from surgsplat.data.scene import Camera, Frame, load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.eval.run_metrics import EvalOptions, evaluate_run
from surgsplat.methods.registry import method_config
from surgsplat.methods.settings import TrainConfig
from surgsplat.render.render import render
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import CONFIG_FILE, Trainer


def held_frame(height: int = 40, width: int = 36) -> Frame:
    generator = torch.Generator().manual_seed(0)
    image = torch.rand(height, width, 3, generator=generator)
    depth = 10 + torch.rand(height, width, generator=generator)
    depth[:4, :4] = 0  # a block without depth
    depth[4, 4] = 0  # a block with one pixel missing
    tool = torch.zeros(height, width, dtype=torch.bool)
    tool[9, 9] = True  # one tool pixel makes its whole block tool
    fov = torch.ones(height, width, dtype=torch.bool)
    fov[-1, 0] = False
    K = torch.tensor([[50.0, 0, width / 2], [0, 52.0, height / 2], [0, 0, 1]])
    return Frame(3, 0.25, image, depth, False, Camera(K, torch.eye(4), width, height), tool, fov)


def test_a_downscaled_frame_averages_blocks_and_never_counts_a_tool_pixel_as_tissue():
    frame = held_frame(82, 73)
    small = frame.downscaled(4)
    assert (small.camera.width, small.camera.height) == (18, 20)
    assert small.image.shape == (20, 18, 3)
    torch.testing.assert_close(small.image[1, 2], frame.image[4:8, 8:12].mean(dim=(0, 1)),
                               rtol=0, atol=1e-6)
    assert small.depth[0, 0] == 0  # no pixel of the block has depth
    valid = frame.depth[4:8, 4:8]
    torch.testing.assert_close(small.depth[1, 1], valid[valid > 0].mean(), rtol=0, atol=1e-5)
    assert small.tool[2, 2] and int(small.tool.sum()) == 1
    assert int((~small.fov).sum()) == 0  # the pixel outside sits in the dropped remainder row
    assert not frame.downscaled(2).fov[-1, 0] and int((~frame.downscaled(2).fov).sum()) == 1
    assert not (small.tissue & small.tool).any()
    assert frame.downscaled(1) is frame


def test_a_downscaled_camera_sees_the_same_view():
    """A point projects to the same place in units of the image's size."""
    frame = held_frame(64, 48)
    small = frame.downscaled(2)
    point = torch.tensor([0.3, -0.2, 1.0])
    full = frame.camera.K @ point
    half = small.camera.K @ point
    torch.testing.assert_close(half[:2] / half[2], full[:2] / full[2] / 2, rtol=0, atol=1e-6)


def test_a_render_at_half_size_is_the_full_render_block_averaged():
    """The view of the downscaled camera agrees with the full-size view averaged over 2x2
    blocks, where the Gaussians are smooth at both sizes (2 % of the image range)."""
    generator = torch.Generator().manual_seed(1)
    count = 300
    means = torch.cat([torch.rand(count, 2, generator=generator) * 1.2 - 0.6,
                       2 + torch.rand(count, 1, generator=generator)], dim=1)
    scales = torch.full((count, 3), 0.12)
    quats = torch.tensor([1.0, 0, 0, 0]).expand(count, 4)
    opacities = torch.full((count,), 0.6)
    sh = torch.rand(count, 1, 3, generator=generator)
    frame = held_frame(64, 64)
    views = []
    for camera in (frame.camera, frame.downscaled(2).camera):
        views.append(render(means, scales, quats, opacities, sh, camera.K, camera.width,
                            camera.height, sh_degree=0).rgb)
    averaged = views[0].reshape(32, 2, 32, 2, 3).mean(dim=(1, 3))
    assert float((averaged - views[1]).abs().mean()) < 0.02


def test_a_factor_that_leaves_under_one_tile_is_refused():
    with pytest.raises(SurgsplatError, match="under the 16x16 minimum"):
        held_frame().downscaled(4)


@pytest.mark.parametrize("factor, fraction, expected", [
    (4, 0.3, {4: (1, 150), 2: (151, 300), 1: (301, 1000)}),
    (8, 0.3, {8: (1, 100), 4: (101, 200), 2: (201, 300), 1: (301, 1000)}),
    (1, 0.3, {1: (1, 1000)}),
    (4, 0.0, {1: (1, 1000)}),
])
def test_every_coarse_stage_runs_for_its_share_of_the_run(factor, fraction, expected):
    train = TrainConfig(iterations=1000, coarse_factor=factor, coarse_fraction=fraction)
    stages: dict[int, list[int]] = {}
    for iteration in range(1, 1001):
        stages.setdefault(train.downscale_at(iteration), []).append(iteration)
    assert {f: (steps[0], steps[-1]) for f, steps in stages.items()} == expected


def test_a_coarse_factor_that_is_not_a_power_of_two_is_refused(small_phantom, tmp_path):
    config = method_config("deform3dgs")
    config.train.coarse_factor = 3
    with pytest.raises(SurgsplatError, match="train.coarse_factor: 3 is not a power of 2"):
        Trainer(config, load_scene(small_phantom), tmp_path / "run")


def test_coarse_to_fine_training_renders_each_stage_at_its_size(small_phantom, tmp_path):
    config = method_config("deform3dgs")
    config.train.iterations = 12
    config.init.max_points = 2000
    config.train.coarse_fraction, config.train.coarse_factor = 0.5, 4
    config.densify.start = 0.0
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    sizes, gathered = [], []
    for _ in range(12):
        trainer.step()
        sizes.append(trainer._downscale_factor)
        gathered.append(float(trainer.strategy.visible_count.sum()))
    assert sizes == [4, 4, 4, 2, 2, 2, 1, 1, 1, 1, 1, 1]
    assert not trainer._downscaled  # nothing held once at full size
    # densification's statistics come from the full-size steps only
    assert gathered[:6] == [0.0] * 6 and 0 < gathered[6] < gathered[7]  # window ends at 8


def test_a_budgeted_run_ends_at_its_budget_with_its_length_recorded(small_phantom, tmp_path):
    config = method_config("deform3dgs")
    config.init.max_points = 2000
    config.train.budget_seconds = 3.0
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    trainer.fit()
    assert 2.5 <= trainer.elapsed <= 3.5
    assert trainer.iteration == trainer.config.train.iterations != 3000
    saved = json.loads((tmp_path / "run" / CONFIG_FILE).read_text())
    assert saved["train"]["iterations"] == trainer.iteration
    assert saved["train"]["budget_seconds"] == 3.0
    # the densification window was re-referred to the run's length
    first, last = trainer.config.densify.window(trainer.iteration)
    assert (trainer.strategy.first, trainer.strategy.last) == (first, last)
    metrics = evaluate_run(load_trained_run(tmp_path / "run"), EvalOptions(geometry=False))
    assert metrics["budget_seconds"] == 3.0 and metrics["iteration"] == trainer.iteration


def test_a_run_to_a_number_of_iterations_states_no_budget(small_phantom, tmp_path):
    config = method_config("deform3dgs")
    config.init.max_points = 2000
    config.train.iterations = 5
    Trainer(config, load_scene(small_phantom), tmp_path / "run").fit()
    metrics = evaluate_run(load_trained_run(tmp_path / "run"), EvalOptions(geometry=False))
    assert metrics["budget_seconds"] is None and metrics["iteration"] == 5


def test_budget_and_iters_are_refused_together(cli, small_phantom, tmp_path, one_error_line):
    result = cli("train", "--data", str(small_phantom), "--out", str(tmp_path / "run"),
                 "--budget", "5", "--iters", "10")
    assert result.returncode == 2
    assert "--iters 10 and --budget 5 each set the run's length" in one_error_line(result)
