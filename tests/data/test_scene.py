"""Scene loading: round trip through SceneWriter, the real EndoNeRF camera files, bad input."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from surgsplat.data.layout import SceneMeta, SceneWriter
from surgsplat.data.scene import is_test_index, load_scene
from surgsplat.data.summary import summarise
from surgsplat.errors import DataError

H, W, N, FOCAL = 24, 32, 10, 30.0


def synthetic_frames(seed: int = 0):
    """N frames: random images, depth 40..80 mm, a tool blob in the top-left corner."""
    rng = np.random.default_rng(seed)
    for i in range(N):
        image = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
        depth = rng.uniform(40.0, 80.0, size=(H, W))
        tool = np.zeros((H, W), dtype=bool)
        tool[: 4 + i % 3, : 6] = True
        yield image, depth, tool


@pytest.fixture
def scene_dir(tmp_path: Path) -> Path:
    writer = SceneWriter(tmp_path / "scene", focal=FOCAL, meta=SceneMeta(depth_unit="mm"))
    for image, depth, tool in synthetic_frames():
        writer.add_frame(image, depth, tool)
    return writer.finish()


def test_round_trip_preserves_frames(scene_dir: Path):
    scene = load_scene(scene_dir)
    assert len(scene.frames) == N and scene.has_depth and scene.has_masks
    assert scene.depth_unit == "mm"
    for frame, (image, depth, tool) in zip(scene.frames, synthetic_frames()):
        assert frame.image.shape == (H, W, 3) and frame.image.dtype == torch.float32
        assert torch.equal((frame.image * 255).round().to(torch.uint8), torch.from_numpy(image))
        # 16-bit PNG depth at 0.01 mm per step: rounding error at most half a step.
        assert np.abs(frame.depth.numpy() - depth).max() <= 0.005 + 1e-4
        assert torch.equal(frame.tissue, torch.from_numpy(~tool))
        assert frame.time == pytest.approx(frame.index / N)
        assert frame.is_test == (frame.index % 8 == 1)
    K = scene.camera.K
    assert K[0, 0] == FOCAL and K[1, 1] == FOCAL and K[0, 2] == W / 2 and K[1, 2] == H / 2
    assert torch.equal(scene.camera.world_to_camera, torch.eye(4))
    assert [f.index for f in scene.test_frames] == [1, 9]
    assert scene.near == pytest.approx(40.0, abs=0.1) and scene.far == pytest.approx(80.0, abs=0.1)


def test_summary_reports_split_depth_and_tool_share(scene_dir: Path):
    summary = summarise(load_scene(scene_dir))
    assert (summary.num_frames, summary.num_train, summary.num_test) == (N, 8, 2)
    assert 40.0 <= summary.depth_min < summary.depth_max <= 80.0
    expected_tool = np.mean([(4 + i % 3) * 6 / (H * W) for i in range(N)])
    assert summary.tool_share_mean == pytest.approx(expected_tool, rel=1e-5)


def test_monocular_scene_without_depth_or_masks_loads(tmp_path: Path):
    writer = SceneWriter(tmp_path / "mono", focal=FOCAL, meta=SceneMeta())
    for image, _, _ in synthetic_frames():
        writer.add_frame(image)
    scene = load_scene(writer.finish())
    assert not scene.has_depth and not scene.has_masks
    assert all(f.depth is None and bool(f.tissue.all()) for f in scene.frames)


def test_split_rule():
    assert [i for i in range(20) if is_test_index(i)] == [1, 9, 17]


@pytest.mark.parametrize("name,frames", [("pulling_soft_tissues", 63),
                                         ("cutting_tissues_twice", 156)])
def test_real_endonerf_camera_files(shared_data: Path, tmp_path: Path, name: str, frames: int):
    poses = shared_data / "endonerf-poses" / f"{name}_poses_bounds.npy"
    scene_dir = tmp_path / name
    (scene_dir / "images").mkdir(parents=True)
    (scene_dir / "poses_bounds.npy").write_bytes(poses.read_bytes())
    blank = np.zeros((512, 640, 3), dtype=np.uint8)
    for i in range(frames):
        cv2.imwrite(str(scene_dir / "images" / f"frame-{i:06d}.color.png"), blank)
    scene = load_scene(scene_dir)
    assert len(scene.frames) == frames
    assert (scene.camera.width, scene.camera.height) == (640, 512)
    assert scene.camera.focal == pytest.approx(569.4682, abs=1e-3)
    assert float(scene.camera.K[0, 2]) == 320.0 and float(scene.camera.K[1, 2]) == 256.0


# ---- bad input: each case must name the offending file ----

def _expect_error(root: Path, fragment: str, name_part: str):
    with pytest.raises(DataError) as info:
        load_scene(root)
    assert fragment in str(info.value)
    assert name_part in str(info.value.path)


def test_missing_folder_and_images(tmp_path: Path):
    _expect_error(tmp_path / "nowhere", "not a folder", "nowhere")
    (tmp_path / "empty").mkdir()
    _expect_error(tmp_path / "empty", "missing", "images")


def test_frame_count_mismatch(scene_dir: Path):
    sorted((scene_dir / "depth").iterdir())[-1].unlink()
    _expect_error(scene_dir, "holds 9 files", "depth")


def test_mask_count_mismatch(scene_dir: Path):
    sorted((scene_dir / "masks").iterdir())[0].unlink()
    _expect_error(scene_dir, "holds 9 files", "masks")


def test_poses_row_mismatch_and_shape(scene_dir: Path):
    poses = np.load(scene_dir / "poses_bounds.npy")
    np.save(scene_dir / "poses_bounds.npy", poses[:-1])
    _expect_error(scene_dir, "has 9 rows", "poses_bounds.npy")
    np.save(scene_dir / "poses_bounds.npy", poses[:, :15])
    _expect_error(scene_dir, "expected shape [N, 17]", "poses_bounds.npy")
    (scene_dir / "poses_bounds.npy").unlink()
    _expect_error(scene_dir, "missing", "poses_bounds.npy")


def test_poses_size_disagreeing_with_images(scene_dir: Path):
    poses = np.load(scene_dir / "poses_bounds.npy")
    poses[:, 4] = 99  # H of the hwf column
    np.save(scene_dir / "poses_bounds.npy", poses)
    _expect_error(scene_dir, "99x32", "poses_bounds.npy")


def test_image_size_mismatch(scene_dir: Path):
    path = sorted((scene_dir / "images").iterdir())[3]
    cv2.imwrite(str(path), np.zeros((H + 2, W, 3), dtype=np.uint8))
    _expect_error(scene_dir, f"is {H + 2}x{W}", path.name)


def test_corrupt_image(scene_dir: Path):
    path = sorted((scene_dir / "images").iterdir())[5]
    path.write_bytes(b"not a png at all")
    _expect_error(scene_dir, "cannot be read as an image", path.name)


@pytest.mark.parametrize("bad,fragment", [(np.nan, "NaN or infinite"), (np.inf, "NaN or infinite"),
                                          (-1.0, "negative")])
def test_bad_depth_values(scene_dir: Path, bad: float, fragment: str):
    for path in (scene_dir / "depth").iterdir():
        path.unlink()
    for i in range(N):
        depth = np.full((H, W), 50.0, dtype=np.float32)
        if i == 2:
            depth[3, 4] = bad
        np.save(scene_dir / "depth" / f"{i:06d}.npy", depth)
    _expect_error(scene_dir, fragment, "000002.npy")


def test_depth_of_wrong_shape(scene_dir: Path):
    for path in (scene_dir / "depth").iterdir():
        path.unlink()
    for i in range(N):
        np.save(scene_dir / "depth" / f"{i:06d}.npy", np.ones((2, H, W), dtype=np.float32))
    _expect_error(scene_dir, "single-channel", "000000.npy")


def test_all_tool_mask(scene_dir: Path):
    path = sorted((scene_dir / "masks").iterdir())[4]
    cv2.imwrite(str(path), np.full((H, W), 255, dtype=np.uint8))
    _expect_error(scene_dir, "every pixel as tool", path.name)


def test_corrupt_scene_json(scene_dir: Path):
    (scene_dir / "scene.json").write_text("{broken")
    _expect_error(scene_dir, "JSON", "scene.json")
    (scene_dir / "scene.json").write_text(json.dumps({"depth_scale": -2}))
    _expect_error(scene_dir, "positive", "scene.json")


def test_depth_scale_override(scene_dir: Path):
    scene = load_scene(scene_dir, depth_scale=0.02)
    reference = load_scene(scene_dir)
    assert torch.allclose(scene.frames[0].depth, 2 * reference.frames[0].depth)
