"""Initial point clouds: back-projection, occlusion filling, motion fusion, monocular plane."""

from pathlib import Path

import numpy as np
import pytest
import torch

from surgsplat.data.layout import SceneMeta, SceneWriter
from surgsplat.data.scene import load_scene
from surgsplat.model.gaussians import GaussianConfig, GaussianModel, SH_C0
from surgsplat.model.init_points import InitConfig, initial_points

H, W, FOCAL = 32, 40, 40.0


def write_scene(root: Path, frames: int = 6, with_depth: bool = True, moving: bool = False) -> Path:
    """A flat wall at 50 mm; a tool covers columns 0..9 in frame 0 only; optionally a patch
    (rows 20..27, cols 20..27) moves 5 mm closer from frame 1 on."""
    writer = SceneWriter(root, focal=FOCAL, meta=SceneMeta(depth_unit="mm"))
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    for i in range(frames):
        depth = np.full((H, W), 50.0)
        image = texture.copy()
        if moving and i > 0:
            depth[20:28, 20:28] = 45.0
            image[20:28, 20:28] = 255
        tool = np.zeros((H, W), dtype=bool)
        if i == 0:
            tool[:, :10] = True
        writer.add_frame(image, depth if with_depth else None, tool)
    return writer.finish()


def test_frame0_back_projection_lies_on_the_wall(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s"))
    cloud = initial_points(scene, InitConfig(fusion="none", pixel_stride=1, max_points=10**6))
    assert cloud.means.shape[0] == H * (W - 10)  # the tool hides 10 columns in frame 0
    assert torch.allclose(cloud.means[:, 2], torch.tensor(50.0), atol=0.01)


def test_occlusion_filling_adds_the_pixels_behind_the_tool(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s"))
    cloud = initial_points(scene, InitConfig(fusion="mapf", pixel_stride=1, max_points=10**6))
    assert cloud.means.shape[0] == H * W  # frame 1 fills the 10 columns once, no duplicates
    x_min = float(cloud.means[:, 0].min())
    assert x_min == pytest.approx((0.5 - W / 2) / FOCAL * 50.0, abs=0.01)


@pytest.mark.parametrize("fusion", ["mapf", "mogf"])
def test_motion_fusion_adds_points_of_the_moving_patch(tmp_path: Path, fusion: str):
    scene = load_scene(write_scene(tmp_path / "s", frames=8, moving=True))
    still = initial_points(load_scene(write_scene(tmp_path / "still", frames=8)),
                           InitConfig(fusion=fusion, pixel_stride=1, max_points=10**6))
    cloud = initial_points(scene, InitConfig(fusion=fusion, pixel_stride=1, max_points=10**6))
    moved = cloud.means[(cloud.means[:, 2] - 45.0).abs() < 0.01]
    assert still.means.shape[0] == H * W
    assert moved.shape[0] >= 32  # at least half the 8x8 patch joins at its moved depth


def test_subsampling_cap_is_deterministic(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s"))
    config = InitConfig(pixel_stride=1, max_points=100, seed=3)
    first, second = initial_points(scene, config), initial_points(scene, config)
    assert first.means.shape == (100, 3) and torch.equal(first.means, second.means)


def test_monocular_scene_initialises_on_a_plane(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s", with_depth=False))
    cloud = initial_points(scene, InitConfig(pixel_stride=2, monocular_depth=70.0))
    assert torch.allclose(cloud.means[:, 2], torch.tensor(70.0))


def test_gaussians_from_points_have_knn_scales_and_colours(tmp_path: Path):
    grid = torch.stack(torch.meshgrid(torch.arange(10.0), torch.arange(10.0), indexing="ij"), -1)
    points = torch.cat([grid.reshape(-1, 2), torch.zeros(100, 1)], dim=1)
    colors = torch.rand(100, 3)
    model = GaussianModel.from_points(points, colors, GaussianConfig(sh_degree=2,
                                                                     init_scale_factor=1.0),
                                      {"extra": torch.zeros(100, 7)})
    # Interior grid points: the 3 nearest neighbours are at distance 1.
    assert torch.allclose(model.params["log_scales"][55].exp(), torch.ones(3), atol=1e-5)
    assert torch.allclose(model.params["sh_dc"] * SH_C0 + 0.5, colors, atol=1e-6)
    assert model.params["sh_rest"].shape == (100, 8, 3)
    assert set(model.attributes) == {"extra"}
