"""`import_scene` and `surgsplat import`: video / frames + masks (+ stereo) to a loadable scene."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from surgsplat.data.importer import DISPARITY_DIR, DISPARITY_STEPS, ImportConfig, import_scene
from surgsplat.data.scene import load_scene, read_tool_mask
from surgsplat.errors import DataError, SurgsplatError

from .conftest import FRAMES, HEIGHT, WIDTH, endoscope_frames, tool_box, view_disk
from .test_stereo import SHIFT, textured_pair


def test_video_with_masks_and_fov(video: Path, mask_folder: Path, tmp_path: Path):
    stages = []
    out = import_scene(video, tmp_path / "scene", ImportConfig(masks=mask_folder),
                       progress=lambda stage, done, total: stages.append((stage, done, total)))
    scene = load_scene(out)
    assert len(scene.frames) == FRAMES and scene.has_masks and not scene.has_depth
    assert (scene.camera.width, scene.camera.height) == (WIDTH, HEIGHT)
    # Default focal: 70 degree horizontal field of view.
    assert scene.camera.focal == pytest.approx(WIDTH / 2 / np.tan(np.radians(35)), rel=1e-6)
    assert scene.has_fov
    fov = cv2.imread(str(out / "fov_mask.png"), cv2.IMREAD_UNCHANGED) == 255
    assert not fov[~view_disk()].any() and fov[view_disk()].mean() > 0.85  # the margin eats the rim
    for i, frame in enumerate(scene.frames):
        # masks/ holds the tool alone; the border is in fov_mask.png, kept apart.
        stored = read_tool_mask(out / "masks" / f"{i:06d}.png")
        assert np.array_equal(stored, tool_box(i)) and np.array_equal(frame.tool.numpy(), stored)
        assert np.array_equal(frame.fov.numpy(), fov)
        tissue = frame.tissue.numpy()
        assert np.array_equal(tissue, fov & ~tool_box(i))
    assert ("import", FRAMES, FRAMES) in stages and stages[0][0] == "field of view"
    extra = json.loads((out / "scene.json").read_text())["extra"]
    assert extra["fov_mask"]["kind"] == "circle" and extra["masks"]["matched_by"] == "order"
    assert "assumed" in extra["camera_source"]


def test_range_stride_resize_without_fov(video: Path, tmp_path: Path):
    config = ImportConfig(start=1, end=9, stride=3, resize=(48, 32), focal=100.0, fov_mask=False)
    scene = load_scene(import_scene(video, tmp_path / "s", config))
    assert len(scene.frames) == 3  # source frames 1, 4, 7
    assert (scene.camera.width, scene.camera.height) == (48, 32)
    assert scene.camera.focal == pytest.approx(50.0)  # scaled with the width
    assert not scene.has_masks  # no masks given, no border searched
    truth = cv2.resize(endoscope_frames()[4], (48, 32), interpolation=cv2.INTER_AREA)
    assert np.abs(scene.frames[1].image.numpy() * 255 - truth).mean() < 25  # MJPG loss


def test_frame_folder_with_class_id_masks_matched_by_number(tmp_path: Path):
    frames, masks = tmp_path / "frames", tmp_path / "masks"
    frames.mkdir()
    masks.mkdir()
    labels = np.full((HEIGHT, WIDTH), 21, np.uint8)  # liver
    labels[10:20, 10:30] = 31  # grasper
    labels[40:50, 50:70] = 32  # hook
    for n in (9, 10, 11):
        cv2.imwrite(str(frames / f"img_{n}.png"), np.full((HEIGHT, WIDTH, 3), 120, np.uint8))
        cv2.imwrite(str(masks / f"img_{n}_labels.png"), np.repeat(labels[..., None], 3, axis=2))
    cv2.imwrite(str(masks / "img_12_labels.png"), labels)  # no such frame: ignored
    config = ImportConfig(masks=masks, tool_labels=(31, 32), scale=0.5)
    scene = load_scene(import_scene(frames, tmp_path / "s", config))
    assert len(scene.frames) == 3 and scene.frames[0].image.shape == (HEIGHT // 2, WIDTH // 2, 3)
    tool = ~scene.frames[2].tissue.numpy()
    expected = cv2.resize(np.isin(labels, (31, 32)).astype(np.uint8), (WIDTH // 2, HEIGHT // 2),
                          interpolation=cv2.INTER_NEAREST).astype(bool)
    assert np.array_equal(tool, expected)  # no border in these frames: only the tools


def test_missing_mask_is_an_error_unless_allowed(video: Path, mask_folder: Path, tmp_path: Path):
    frames, masks = tmp_path / "frames", tmp_path / "frame_masks"
    frames.mkdir()
    masks.mkdir()
    for i, image in enumerate(endoscope_frames()[:4]):
        cv2.imwrite(str(frames / f"f{i}.png"), image)
        if i != 2:
            cv2.imwrite(str(masks / f"f{i}.png"), tool_box(i).astype(np.uint8) * 255)
    with pytest.raises(DataError, match="no mask for f2.png.*--allow-missing-masks"):
        import_scene(frames, tmp_path / "a", ImportConfig(masks=masks))
    out = import_scene(frames, tmp_path / "b", ImportConfig(masks=masks, allow_missing_masks=True))
    assert len(load_scene(out).frames) == 3
    extra = json.loads((out / "scene.json").read_text())["extra"]
    assert extra["dropped_without_mask"] == ["f2.png"]


def test_errors_name_the_problem(video: Path, mask_folder: Path, tmp_path: Path):
    with pytest.raises(DataError, match="does not exist") as err:
        import_scene(tmp_path / "nope.mp4", tmp_path / "o1", ImportConfig())
    assert err.value.path == tmp_path / "nope.mp4"
    (mask_folder / "mask_10.png").write_bytes((mask_folder / "mask_0.png").read_bytes())
    with pytest.raises(DataError, match="holds 11 mask files but the source has 10"):
        import_scene(video, tmp_path / "o2", ImportConfig(masks=mask_folder))
    (mask_folder / "mask_10.png").unlink()
    cv2.imwrite(str(mask_folder / "mask_3.png"), np.zeros((HEIGHT + 1, WIDTH), np.uint8))
    with pytest.raises(DataError, match=r"is 96x65 \(WxH\) but the first frame is 96x64") as err:
        import_scene(video, tmp_path / "o3", ImportConfig(masks=mask_folder))
    assert err.value.path == mask_folder / "mask_3.png"
    assert not (tmp_path / "o3").exists()  # the partial output was removed
    with pytest.raises(SurgsplatError, match="selects no frame"):
        import_scene(video, tmp_path / "o4", ImportConfig(start=50))
    with pytest.raises(SurgsplatError, match="aspect ratio"):
        import_scene(video, tmp_path / "o5", ImportConfig(resize=(50, 50)))
    with pytest.raises(SurgsplatError, match="--focal"):
        import_scene(video, tmp_path / "o6", ImportConfig(right=video, baseline=4.0))
    (tmp_path / "o7").mkdir()
    (tmp_path / "o7" / "old.txt").write_text("earlier work")
    with pytest.raises(SurgsplatError, match="not empty"):
        import_scene(video, tmp_path / "o7", ImportConfig())


def test_stereo_import_writes_depth_or_disparity(tmp_path: Path):
    left_dir, right_dir = tmp_path / "left", tmp_path / "right"
    left_dir.mkdir()
    right_dir.mkdir()
    for i in range(3):
        left, right = textured_pair()
        cv2.imwrite(str(left_dir / f"{i}.png"), left[..., ::-1])
        cv2.imwrite(str(right_dir / f"{i}.png"), right[..., ::-1])
    stereo = dict(right=right_dir, focal=300.0, fov_mask=False)
    scene = load_scene(import_scene(left_dir, tmp_path / "d", ImportConfig(baseline=4.0, **stereo)))
    assert scene.has_depth and scene.depth_unit == "mm"
    depth = scene.frames[0].depth.numpy()[:, SHIFT + 4:]
    valid = depth > 0
    assert valid.mean() > 0.9
    expected = 300.0 * 4.0 / SHIFT  # 100 mm
    # 1 px of disparity at 12 px is ~8 %; the 16-bit PNG step is ~0.02 mm.
    assert np.abs(depth[valid] - expected).max() < 0.09 * expected
    out = import_scene(left_dir, tmp_path / "p", ImportConfig(disparity_only=True, **stereo))
    stored = cv2.imread(str(out / DISPARITY_DIR / "000000.png"), cv2.IMREAD_UNCHANGED)
    disparity = stored[:, SHIFT + 4:].astype(np.float32) / DISPARITY_STEPS
    assert stored.dtype == np.uint16
    assert np.median(disparity[disparity > 0]) == pytest.approx(SHIFT, abs=0.5)  # px
    assert not load_scene(out).has_depth


def test_cli_import_prints_summary_and_one_line_errors(video: Path, mask_folder: Path,
                                                      tmp_path: Path, cli):
    result = cli("import", str(video), "--out", str(tmp_path / "s"), "--masks",
                 str(mask_folder), "--stride", "2")
    assert result.returncode == 0, result.stderr
    assert "scene summary" in result.stdout and "circle" in result.stdout
    assert len(load_scene(tmp_path / "s").frames) == 5
    result = cli("import", str(video), "--out", str(tmp_path / "t"), "--tool-labels", "a,b",
                 "--masks", str(mask_folder))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "comma-separated integers" in result.stderr


def test_real_cholecseg8k_clip(shared_data: Path, tmp_path: Path):
    clip = shared_data / "cholecseg8k-clip"
    config = ImportConfig(pattern="*_endo.png", masks=clip,
                          mask_pattern="*_endo_watershed_mask.png", tool_labels=(31, 32),
                          start=69, allow_missing_masks=True)
    out = import_scene(clip, tmp_path / "chole", config)
    scene = load_scene(out)
    extra = json.loads((out / "scene.json").read_text())["extra"]
    assert extra["source_frames"] == [f"frame_{n}_endo.png" for n in (630, 631, 632)]
    assert extra["dropped_without_mask"] == ["frame_633_endo.png"]  # the one frame without mask
    assert len(scene.frames) == 3 and (scene.camera.width, scene.camera.height) == (854, 480)
    labels = cv2.imread(str(clip / "frame_632_endo_watershed_mask.png"))[..., 0]
    tools = np.isin(labels, (31, 32))
    frame = scene.frames[2]
    # masks/ holds exactly the tool classes; the black border lives in fov_mask.png alone.
    assert np.array_equal(read_tool_mask(out / "masks" / "000002.png"), tools)
    assert np.array_equal(frame.tool.numpy(), tools)
    assert scene.has_fov and extra["fov_mask"]["kind"] == "circle"
    in_view = labels != 50  # CholecSeg8k's own "outside the view" class
    fov = frame.fov.numpy()
    assert (fov & in_view).sum() / (fov | in_view).sum() > 0.97  # FOV IoU
    assert np.array_equal(frame.tissue.numpy(), fov & ~tools)
