"""A run of every preset stopped by Ctrl-C and resumed from its checkpoint ends where the same
run without the stop ends: the same Gaussians, the same component state, the same test render."""

from __future__ import annotations

import pytest
import torch

from surgsplat.data.scene import load_scene
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.trainer import CHECKPOINT, Trainer

ITERATIONS, STOP = 16, 8
"""Length of both runs and the iteration the first one is stopped at (densification every 4
steps and LumiState's second stage, from a third of the run, straddle the stop)."""


def short_config(name: str):
    config = method_config(name)
    config.train.iterations = ITERATIONS
    config.init.max_points = 1500
    config.densify.start = 0.0
    config.densify.every = 4
    return config


def rendered_test_frame(trainer: Trainer) -> torch.Tensor:
    frame = next(f for f in trainer.scene.frames if f.is_test)
    with torch.no_grad():
        return render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time)).rgb


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PRESETS))
def test_a_resumed_run_ends_where_the_uninterrupted_run_ends(name, small_phantom, tmp_path):
    """Tolerances: rtol 1e-4, atol 1e-5 on every parameter and buffer, 1e-4 on the render
    (float32 sums in another order after a reload)."""
    scene = load_scene(small_phantom)
    straight = Trainer(short_config(name), scene, tmp_path / "straight")
    straight.fit()

    stopped = Trainer(short_config(name), scene, tmp_path / "stopped")

    def interrupt(stats):
        if stats.iteration == STOP:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        stopped.fit(interrupt)
    resumed = Trainer(short_config(name), scene, tmp_path / "stopped")
    assert resumed.load(tmp_path / "stopped" / CHECKPOINT) is None
    assert resumed.iteration == STOP
    resumed.fit()
    expected = dict(straight.model.state_dict())
    actual = dict(resumed.model.state_dict())
    assert actual.keys() == expected.keys()
    for key, value in expected.items():
        torch.testing.assert_close(actual[key], value, rtol=1e-4, atol=1e-5, msg=key)
    torch.testing.assert_close(rendered_test_frame(resumed), rendered_test_frame(straight),
                               rtol=0, atol=1e-4)
