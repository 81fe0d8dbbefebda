"""Per-frame cameras: LLFF pose conversion, scene.json intrinsics, moving poses, bad input."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from surgsplat.data.layout import (Intrinsics, SceneMeta, SceneWriter, llff_from_world_to_camera,
                                   poses_bounds, world_to_camera_from_llff)
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError

H, W, N = 24, 32, 4


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q * np.linalg.det(q)  # det +1


def random_world_to_camera(rng: np.random.Generator) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = random_rotation(rng)
    pose[:3, 3] = rng.uniform(-20, 20, 3)
    return pose


def write_scene(root: Path, poses: list[np.ndarray] | None = None,
                intrinsics: Intrinsics | None = None, focal: float = 30.0) -> Path:
    writer = SceneWriter(root, focal=focal, meta=SceneMeta(depth_unit="mm", intrinsics=intrinsics))
    for i in range(N):
        writer.add_frame(np.full((H, W, 3), 40 * i, np.uint8), np.full((H, W), 50.0),
                         world_to_camera=None if poses is None else poses[i])
    return writer.finish()


def test_llff_block_of_a_known_camera():
    """A camera at LLFF world point c whose axes are down d, right r and backwards b sees the
    world point c - 10 b + 2 r + 3 d at OpenCV camera coordinates (2, 3, 10)."""
    d, r = np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    b = np.cross(d, r)  # (down, right, backwards) is right-handed
    c = np.array([5.0, -7.0, 2.0])
    block = np.column_stack([d, r, b, c])[None]  # [1, 3, 4] camera-to-world
    world_to_camera = world_to_camera_from_llff(block)[0]
    q = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])  # the documented world relabelling
    point = q @ (c - 10 * b + 2 * r + 3 * d)
    camera = world_to_camera[:3, :3] @ point + world_to_camera[:3, 3]
    np.testing.assert_allclose(camera, [2.0, 3.0, 10.0], atol=1e-12)
    np.testing.assert_allclose(world_to_camera[3], [0, 0, 0, 1], atol=0)


def test_identity_llff_block_is_the_identity_pose():
    """The EndoNeRF files' identity blocks mean a static camera whose frame is the world."""
    block = np.concatenate([np.eye(3), np.zeros((3, 1))], axis=1)[None]
    np.testing.assert_array_equal(world_to_camera_from_llff(block)[0], np.eye(4))
    row = poses_bounds(np.eye(4)[None], H, W, 30.0, 1.0, 2.0)[0]
    np.testing.assert_array_equal(row[:15].reshape(3, 5)[:, :4], block[0])


def test_llff_round_trip():
    rng = np.random.default_rng(0)
    poses = np.stack([random_world_to_camera(rng) for _ in range(20)])
    back = world_to_camera_from_llff(llff_from_world_to_camera(poses))
    np.testing.assert_allclose(back, poses, atol=1e-12)


def test_moving_poses_load_per_frame(tmp_path: Path):
    rng = np.random.default_rng(1)
    poses = [np.eye(4)] + [random_world_to_camera(rng) for _ in range(N - 1)]
    scene = load_scene(write_scene(tmp_path / "s", poses))
    assert scene.has_moving_camera
    assert scene.camera is scene.frames[0].camera
    for frame, pose in zip(scene.frames, poses):
        # float32 poses: about 1e-7 relative of translations up to 35 mm.
        torch.testing.assert_close(frame.camera.world_to_camera, torch.tensor(pose).float(),
                                   atol=1e-5, rtol=0)
        product = frame.camera.camera_to_world @ frame.camera.world_to_camera
        torch.testing.assert_close(product, torch.eye(4), atol=1e-5, rtol=0)


def test_static_scene_shares_one_camera(tmp_path: Path):
    scene = load_scene(write_scene(tmp_path / "s"))
    assert not scene.has_moving_camera
    assert all(frame.camera is scene.camera for frame in scene.frames)
    assert (scene.width, scene.height) == (W, H)
    assert (scene.camera.fx, scene.camera.fy, scene.camera.cx, scene.camera.cy) == (
        30.0, 30.0, W / 2, H / 2)


def test_scene_json_intrinsics(tmp_path: Path):
    intrinsics = Intrinsics(fx=30.0, fy=32.5, cx=17.25, cy=10.5)
    root = write_scene(tmp_path / "s", intrinsics=intrinsics)
    assert json.loads((root / "scene.json").read_text())["intrinsics"] == {
        "fx": 30.0, "fy": 32.5, "cx": 17.25, "cy": 10.5}
    camera = load_scene(root).frames[2].camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.focal) == (
        30.0, 32.5, 17.25, 10.5, 30.0)
    torch.testing.assert_close(camera.K, torch.tensor(
        [[30.0, 0, 17.25], [0, 32.5, 10.5], [0, 0, 1]]), atol=0, rtol=0)


def _expect_error(root: Path, fragment: str, name: str):
    with pytest.raises(DataError) as info:
        load_scene(root)
    assert fragment in str(info.value), str(info.value)
    assert info.value.path.name == name


@pytest.mark.parametrize("intrinsics,fragment", [
    ({"fx": 0.0, "fy": 30.0, "cx": 16.0, "cy": 12.0}, "must be positive"),
    ({"fx": 30.0, "fy": -1.0, "cx": 16.0, "cy": 12.0}, "must be positive"),
    ({"fx": 30.0, "fy": 30.0, "cx": 16.0}, "exactly the keys fx, fy, cx, cy"),
    ({"fx": 30.0, "fy": 30.0, "cx": 40.0, "cy": 12.0}, "outside the 32x24"),
])
def test_bad_intrinsics_name_scene_json(tmp_path: Path, intrinsics: dict, fragment: str):
    root = write_scene(tmp_path / "s")
    meta = json.loads((root / "scene.json").read_text())
    meta["intrinsics"] = intrinsics
    (root / "scene.json").write_text(json.dumps(meta))
    _expect_error(root, fragment, "scene.json")


def test_hwf_focal_must_agree_with_fx(tmp_path: Path):
    root = write_scene(tmp_path / "s", intrinsics=Intrinsics(30.0, 30.0, 16.0, 12.0))
    meta = json.loads((root / "scene.json").read_text())
    meta["intrinsics"]["fx"] = 35.0
    (root / "scene.json").write_text(json.dumps(meta))
    _expect_error(root, "disagrees with fx 35", "poses_bounds.npy")


@pytest.mark.parametrize("scale,fragment", [(1.1, "not a rotation"), (-1.0, "det -1")])
def test_poses_that_are_not_rotations(tmp_path: Path, scale: float, fragment: str):
    root = write_scene(tmp_path / "s")
    poses = np.load(root / "poses_bounds.npy")
    blocks = poses[:, :15].reshape(-1, 3, 5)
    blocks[2, :, :3] *= scale  # a scaled or mirrored frame 2
    np.save(root / "poses_bounds.npy", np.concatenate([blocks.reshape(-1, 15), poses[:, 15:]], 1))
    _expect_error(root, fragment, "poses_bounds.npy")
    _expect_error(root, "row 2", "poses_bounds.npy")
