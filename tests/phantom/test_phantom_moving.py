"""The moving-endoscope phantom: smooth known poses, per-frame camera-space depth and normals,
world-frame meshes that each frame's depth and camera land on."""

from pathlib import Path

import numpy as np
import pytest
import torch

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom import PRESETS, PhantomConfig, generate_phantom
from surgsplat.data.phantom.camera_path import camera_path
from surgsplat.data.phantom.raycast import NEAR_MM, intersect_surface
from surgsplat.data.phantom.scene import PhantomScene
from surgsplat.data.phantom.tool import intersect_tool
from surgsplat.data.ply import read_ply_mesh
from surgsplat.data.scene import load_scene, read_tool_mask
from surgsplat.errors import SurgsplatError
from surgsplat.eval.geometry_metrics import point_to_surface
from surgsplat.image.pinhole import backproject

SMALL = PRESETS["small"]
FRAMES = 16


@pytest.fixture(scope="module")
def moving(moving_phantom) -> Path:
    """PhantomConfig(camera="moving"): the session's phantom, which these tests only read."""
    return moving_phantom


@pytest.fixture(scope="module")
def scene() -> PhantomScene:
    return PhantomScene(SMALL.width, SMALL.height, SMALL.focal, FRAMES, "pulling", seed=0,
                        camera="moving")


def gt(root: Path, folder: str, index: int) -> np.ndarray:
    return np.load(root / "gt" / folder / f"{frame_stem(index)}.npy")


def rotation_deg(rotation: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1))))


def test_poses_are_known_smooth_and_a_few_mm_and_degrees(moving: Path):
    poses = np.load(moving / "gt" / "camera_poses.npy")
    assert poses.shape == (FRAMES, 4, 4) and poses.dtype == np.float64
    np.testing.assert_array_equal(poses[0], np.eye(4))  # the world is frame 0's camera
    loaded = load_scene(moving)
    assert loaded.has_moving_camera and loaded.meta.extra["camera"] == "moving"
    for frame, pose in zip(loaded.frames, poses):  # poses_bounds.npy holds the same poses
        torch.testing.assert_close(frame.camera.world_to_camera, torch.tensor(pose).float(),
                                   atol=1e-5, rtol=0)
    centres = np.stack([-p[:3, :3].T @ p[:3, 3] for p in poses])  # [N, 3] mm
    travel = np.linalg.norm(centres - centres[0], axis=1).max()
    turn = max(rotation_deg(p[:3, :3]) for p in poses)
    assert 2.0 < travel < 10.0 and 2.0 < turn < 10.0, (travel, turn)
    # Smooth: sampled every 1/400 of the clip, the centre moves < 0.05 mm per step, and its
    # second differences stay < 3e-3 mm; a velocity jump (a kink) of even 10 % of the top
    # speed would give a second difference of about 5e-3 mm.
    path = camera_path("moving")
    fine = np.stack([path.camera_to_world(t)[:3, 3] for t in np.linspace(0, 1, 401)])
    step = np.linalg.norm(np.diff(fine, axis=0), axis=1)
    bend = np.linalg.norm(np.diff(fine, 2, axis=0), axis=1)
    assert step.max() < 0.05 and bend.max() < 3e-3, (step.max(), bend.max())


def test_static_default_keeps_identity_poses(small_phantom: Path):
    poses = np.load(small_phantom / "gt" / "camera_poses.npy")
    np.testing.assert_array_equal(poses, np.tile(np.eye(4), (FRAMES, 1, 1)))
    assert not load_scene(small_phantom).has_moving_camera


def test_gt_depth_equals_a_recast(moving: Path, scene: PhantomScene):
    for index in (0, 7, 15):
        centre, directions = scene.world_rays(index)
        recast = intersect_surface(scene.surface, scene.time(index), centre, directions)
        # float32 storage of depths near 100 mm: about 4e-6 mm.
        np.testing.assert_allclose(gt(moving, "tissue_depth", index), recast, atol=1e-4, rtol=0)


def test_depth_backprojected_with_the_frames_camera_lands_on_its_world_mesh(moving: Path):
    loaded = load_scene(moving)
    everywhere = torch.ones(SMALL.height, SMALL.width, dtype=torch.bool)
    for index in (0, 5, 9, 15):
        camera = loaded.frames[index].camera
        depth = torch.from_numpy(gt(moving, "tissue_depth", index)).double()
        vertices, faces = read_ply_mesh(moving / "gt" / "meshes" / f"{frame_stem(index)}.ply")
        points = backproject(depth, camera.K.double(), everywhere,
                             camera.camera_to_world.double()).numpy()  # [H * W, 3] world
        distance = point_to_surface(points, vertices, faces)
        # The mesh is the surface sampled every 4 px, linear in between: < 0.1 mm everywhere,
        # and its vertices (the pixels of the grid) to float32 precision.
        assert distance.max() < 0.1, (index, distance.max())
        on_grid = distance.reshape(SMALL.height, SMALL.width)[::SMALL.mesh_step, ::SMALL.mesh_step]
        assert on_grid.max() < 1e-4, (index, on_grid.max())
        if index:  # frame 0's camera misplaces a later frame's depth by over a millimetre
            wrong = backproject(depth, camera.K.double(), everywhere,
                                loaded.frames[0].camera.camera_to_world.double()).numpy()
            assert np.median(point_to_surface(wrong, vertices, faces)) > 1.0


def test_tissue_hit_is_the_first_along_each_moving_ray(scene: PhantomScene):
    """The residual of the ray-surface equation is negative at 48 depths in front of every 3rd
    pixel's hit, so the moving camera's rays stay in the ray caster's regime."""
    for index in range(0, FRAMES, 3):
        centre, directions = scene.world_rays(index)
        directions = directions[::3, ::3]
        t = scene.time(index)
        hit = intersect_surface(scene.surface, t, centre, directions)
        for fraction in np.linspace(0.0, 0.999, 48):
            s = NEAR_MM + fraction * (hit - NEAR_MM)
            point = centre + s[..., None] * directions
            residual = point[..., 2] - scene.surface.height(point[..., 0], point[..., 1], t)
            assert (residual < 1e-4).all()


def test_normals_are_camera_space_and_match_the_depth(moving: Path, scene: PhantomScene):
    rays = np.stack([scene.xn, scene.yn, np.ones_like(scene.xn)], axis=-1)  # [H, W, 3]
    for index in (6, 15):
        normals = gt(moving, "normals", index).astype(np.float64)
        assert (np.einsum("hwi,hwi->hw", normals, rays) < 0).all()  # facing the camera
        points = gt(moving, "tissue_depth", index)[..., None] * rays
        from_depth = np.cross(points[1:-1, 2:] - points[1:-1, :-2],
                              points[2:, 1:-1] - points[:-2, 1:-1])
        from_depth /= -np.linalg.norm(from_depth, axis=-1, keepdims=True)
        cos = np.einsum("hwi,hwi->hw", from_depth, normals[1:-1, 1:-1])
        angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        assert np.median(angle) < 0.1 and np.percentile(angle, 99) < 0.5  # degrees


def test_tool_mask_is_where_the_tool_is_nearer(moving: Path, scene: PhantomScene):
    saw_tool = False
    for index in range(FRAMES):
        hit = intersect_tool(scene.geometry, scene.camera_tool_pose(index), scene.xn, scene.yn)
        tool = read_tool_mask(moving / "masks" / f"{frame_stem(index)}.png")
        np.testing.assert_array_equal(tool, hit.depth < gt(moving, "tissue_depth", index))
        saw_tool |= bool(tool.any())
    assert saw_tool


def test_unknown_camera_names_the_valid_ones(tmp_path: Path):
    with pytest.raises(SurgsplatError, match="valid cameras: static, moving"):
        generate_phantom(PhantomConfig(camera="shaky"), tmp_path / "x")
