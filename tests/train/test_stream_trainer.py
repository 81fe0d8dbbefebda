"""StreamTrainer: a scene that grows frame by frame, and its time axis."""

from __future__ import annotations

import time

import torch

from surgsplat.data.scene import load_scene
from surgsplat.methods.registry import method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.stream import StreamConfig, StreamTrainer
from surgsplat.train.trainer import psnr_from_mse


def test_time_axis_doubles_then_fits_the_frames_that_came(small_phantom, tmp_path):
    """Set up for 4 frames, a stream of 10 doubles its horizon to 8 then 16 (frame i at
    i / 16); `finish` retimes it to the 10 frames (i / 10), and the model renders each frame
    as before (the curves retimed exactly, the exposure's knots resampled: PSNR between the
    renders > 40 dB)."""
    scene = load_scene(small_phantom)
    frames = scene.frames[:10]
    config = method_config("deform3dgs")
    config.init.max_points = 2000
    grown = type(scene)(root=scene.root, frames=[frames[0]], meta=scene.meta, near=scene.near,
                        far=scene.far, has_depth=True, has_masks=True, has_fov=False)
    trainer = StreamTrainer(config, grown, tmp_path / "run", 4, StreamConfig(),
                            time.monotonic())
    for frame in frames[1:]:
        trainer.integrate(frame, time.monotonic())
        for _ in range(3):
            trainer.step()
    assert trainer.horizon == 16
    assert [frame.time for frame in trainer.scene.frames] == [i / 16 for i in range(10)]

    def renders() -> list[torch.Tensor]:
        with torch.no_grad():
            return [render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time),
                                 trainer.background).rgb for frame in trainer.scene.frames]

    before = renders()
    trainer.finish()
    assert trainer.horizon == 10
    assert [frame.time for frame in trainer.scene.frames] == [i / 10 for i in range(10)]
    for old, new in zip(before, renders()):
        assert psnr_from_mse(float((old - new).square().mean())) > 40.0
    assert all(record.psnr_final is not None for record in trainer.records.values())
    trained = [trainer.records[i] for i in range(10) if not frames[i].is_test]
    assert all(record.trained_at is not None and record.psnr_arrival is not None
               for record in trained)
