"""What no training frame saw (NeverSeenFamily): the never-seen pixels of a static camera, none
for a moving one, and the tool-free render's transparency and scores there. Exact values on
synthetic frames."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom.generate import TISSUE_DEPTH_DIR, TISSUE_IMAGES_DIR
from surgsplat.data.scene import Camera, Frame
from surgsplat.data.never_seen import never_seen_pixels
from surgsplat.eval.render_families import NeverSeenFamily

H, W = 20, 30


def frame(index: int, first_tool_column: int, shift: float = 0.0) -> Frame:
    """A frame whose tool covers the columns from `first_tool_column` on, seen by a camera
    shifted by `shift` along x."""
    tool = torch.zeros(H, W, dtype=torch.bool)
    tool[:, first_tool_column:] = True
    pose = torch.eye(4)
    pose[0, 3] = shift
    camera = Camera(K=torch.eye(3), world_to_camera=pose, width=W, height=H)
    return Frame(index=index, time=index / 4, image=torch.zeros(H, W, 3), depth=None,
                 is_test=False, camera=camera, tool=tool, fov=torch.ones(H, W, dtype=torch.bool))


def test_never_seen_pixels_are_the_tool_of_every_frame_of_a_static_camera():
    region = never_seen_pixels([frame(0, 20), frame(2, 25), frame(3, 22)])
    assert region[:, 25:].all() and not region[:, :25].any()
    assert never_seen_pixels([frame(0, 20), frame(2, 25, shift=1.0)]) is None
    assert never_seen_pixels([]) is None


def test_the_tool_free_render_is_scored_over_the_never_seen_pixels(tmp_path):
    (tmp_path / TISSUE_IMAGES_DIR).mkdir(parents=True)
    (tmp_path / TISSUE_DEPTH_DIR).mkdir(parents=True)
    truth = np.full((H, W, 3), 128, np.uint8)
    cv2.imwrite(str(tmp_path / TISSUE_IMAGES_DIR / f"{frame_stem(1)}.png"), truth)
    np.save(tmp_path / TISSUE_DEPTH_DIR / f"{frame_stem(1)}.npy", np.full((H, W), 50.0, np.float32))
    train = [frame(0, 20), frame(2, 25)]
    run = SimpleNamespace(scene=SimpleNamespace(train_frames=train, root=tmp_path))
    family = NeverSeenFamily(run, options=None)
    rgb = torch.full((H, W, 3), 128 / 255)
    rgb[:, 25:] += 0.1  # the never-seen columns 0.1 off: PSNR 20 dB there
    alpha = torch.ones(H, W)
    alpha[:4, 27:] = 0.5  # a hole in the tool-free render: 12 of 600 pixels
    depth = torch.full((H, W), 50.0)
    depth[:, 25:] += 2.0
    hidden = SimpleNamespace(rgb=rgb, alpha=alpha, depth=depth)
    test = frame(1, 22)
    view = SimpleNamespace(frame=test, run=run, tissue_render=hidden,
                           render=SimpleNamespace(alpha=torch.ones(H, W)))
    row = family.score(view)
    assert row["transparent_fraction"] == 0.0
    assert row["tool_free_transparent_fraction"] == pytest.approx(12 / 600)
    assert row["tool_free_alpha_min"] == pytest.approx(0.5)
    assert row["never_seen_fraction"] == pytest.approx(5 / 30)
    assert row["psnr_never_seen"] == pytest.approx(20.0, abs=1e-3)
    assert row["depth_rmse_never_seen"] == pytest.approx(2.0, abs=1e-5)
