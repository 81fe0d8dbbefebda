"""A scene in metres trains as the same scene in millimetres: loss weights and thresholds are
unit-free (relative depth errors, lengths as fractions of the scene extent or depth)."""

import json
import shutil

import numpy as np
import pytest
import torch

from surgsplat.data.scene import load_scene
from surgsplat.eval.image_metrics import psnr_tissue
from surgsplat.methods.registry import method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.trainer import Trainer

MM_PER_M = 1000.0


def in_metres(scene_dir, out):
    """A copy of the millimetre scene `scene_dir` in metres: camera translations, depth bounds
    and the stored depth's scale divided by 1000 (the images are the same)."""
    shutil.copytree(scene_dir, out)
    poses = np.load(out / "poses_bounds.npy")
    matrices = poses[:, :15].reshape(-1, 3, 5)
    matrices[:, :, 3] /= MM_PER_M
    poses[:, :15] = matrices.reshape(-1, 15)
    poses[:, 15:] /= MM_PER_M
    np.save(out / "poses_bounds.npy", poses)
    meta = json.loads((out / "scene.json").read_text())
    meta["depth_unit"], meta["depth_scale"] = "m", meta["depth_scale"] / MM_PER_M
    (out / "scene.json").write_text(json.dumps(meta))
    return out


def trained_test_psnr(scene_dir, method: str, run_dir) -> tuple[float, float]:
    """(mean PSNR over the test frames' tissue, mean depth error relative to the truth) after a
    short training run."""
    config = method_config(method)
    config.train.iterations = 150
    config.init.max_points = 3000
    scene = load_scene(scene_dir)
    trainer = Trainer(config, scene, run_dir)
    trainer.fit()
    psnrs, depth_errors = [], []
    with torch.no_grad():
        for frame in scene.test_frames:
            output = render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time))
            psnrs.append(psnr_tissue(output.rgb, frame.image, frame.tissue))
            valid = frame.tissue & (frame.depth > 0)
            depth_errors.append(float(((output.depth - frame.depth).abs()[valid]
                                       / frame.depth[valid]).mean()))
    return float(np.mean(psnrs)), float(np.mean(depth_errors))


@pytest.mark.slow
@pytest.mark.parametrize("method", ["deform3dgs", "endogsg", "physiosplat"])
def test_a_scene_in_metres_trains_like_the_scene_in_millimetres(small_phantom, tmp_path, method):
    """Same seed, same frames: the runs differ only by float rounding, so PSNR agrees within
    0.5 dB and the relative depth error within 20 % of itself (a unit mistake moves either by
    orders of magnitude)."""
    metres = in_metres(small_phantom, tmp_path / "metres")
    psnr_mm, depth_mm = trained_test_psnr(small_phantom, method, tmp_path / "run-mm")
    psnr_m, depth_m = trained_test_psnr(metres, method, tmp_path / "run-m")
    assert abs(psnr_m - psnr_mm) < 0.5
    assert abs(depth_m - depth_mm) < 0.2 * depth_mm + 1e-3
