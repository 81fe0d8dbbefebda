"""Automatic tool masks: the classical segmenter on drawn frames and on real CholecSeg8k frames,
its temporal window, and `surgsplat import --auto-tool-masks`."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from surgsplat.data.auto_tool_masks import AutoMaskConfig, auto_tool_masks, windowed
from surgsplat.data.importer import ImportConfig, import_scene
from surgsplat.data.scene import load_scene
from surgsplat.data.tool_masks import read_tool_labels
from surgsplat.errors import SurgsplatError

HEIGHT, WIDTH = 120, 214


def tissue_frame(seed: int) -> np.ndarray:
    """uint8 RGB [H, W, 3]: reddish tissue with smooth shading and darker red vessels."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    light = 0.55 + 0.35 * (np.cos((xs - WIDTH / 2) / WIDTH * 2.0)
                           * np.cos((ys - HEIGHT / 2) / HEIGHT))
    frame = np.stack([200 * light, 80 * light, 70 * light], axis=-1)
    for _ in range(4):  # vessels
        row = rng.integers(10, HEIGHT - 10)
        cv2.line(frame, (0, int(row)), (WIDTH - 1, int(row + rng.integers(-30, 30))),
                 (120, 20, 25), 2)
    return np.clip(frame + rng.normal(0, 3, frame.shape), 0, 255).astype(np.uint8)


def with_tool(frame: np.ndarray, shift: int) -> tuple[np.ndarray, np.ndarray]:
    """The frame with a grey metal shaft (and a highlight on it) drawn in, and its mask."""
    mask = np.zeros(frame.shape[:2], np.uint8)
    cv2.line(mask, (120 + shift, 0), (40 + shift, 90), 1, 7)
    tool = frame.copy()
    tool[mask > 0] = (95, 95, 100)
    highlight = np.zeros_like(mask)
    cv2.line(highlight, (118 + shift, 2), (60 + shift, 67), 1, 2)
    tool[highlight > 0] = (250, 250, 250)
    return tool, mask.astype(bool)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return (a & b).sum() / max((a | b).sum(), 1)


def test_grey_shaft_on_tissue_is_found_and_tissue_alone_is_not():
    drawn = [with_tool(tissue_frame(i), 2 * i) for i in range(5)]
    masks = list(auto_tool_masks([frame for frame, _ in drawn], None))
    assert len(masks) == 5
    for mask, (_, truth) in zip(masks, drawn):
        # The highlight on the shaft is filled back in; averaging over the neighbours of a
        # moving shaft costs a little of its edge.
        assert iou(mask, truth) > 0.7
    empty = list(auto_tool_masks([tissue_frame(10 + i) for i in range(3)], None))
    assert all(mask.sum() == 0 for mask in empty)


def test_mask_stays_inside_the_field_of_view():
    frame, truth = with_tool(tissue_frame(0), 0)
    fov = np.zeros((HEIGHT, WIDTH), bool)
    fov[:, 80:] = True
    (mask,) = auto_tool_masks([frame], fov)
    assert mask.any() and not (mask & ~fov).any()


def test_windowed_gives_each_item_its_neighbours_in_order():
    assert list(windowed(range(4), 1)) == [(0, [0, 1]), (1, [0, 1, 2]), (2, [1, 2, 3]),
                                           (3, [2, 3])]
    assert list(windowed(range(2), 3)) == [(0, [0, 1]), (1, [0, 1])]
    assert list(windowed(range(3), 0)) == [(0, [0]), (1, [1]), (2, [2])]


def test_bad_thresholds_are_one_clear_error():
    with pytest.raises(SurgsplatError, match="grow_score <= seed_score"):
        list(auto_tool_masks([tissue_frame(0)], None, AutoMaskConfig(seed_score=0.2)))


@pytest.fixture
def tool_video(tmp_path: Path) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(4):
        frame, _ = with_tool(tissue_frame(i), 3 * i)
        cv2.imwrite(str(folder / f"frame_{i}.png"), frame[..., ::-1])
    return folder


def test_import_writes_automatic_masks_and_records_them(tool_video: Path, tmp_path: Path):
    out = import_scene(tool_video, tmp_path / "scene", ImportConfig(auto_tool_masks=True))
    scene = load_scene(out)
    assert scene.has_masks and len(scene.frames) == 4
    for i, frame in enumerate(scene.frames):
        _, truth = with_tool(tissue_frame(i), 3 * i)
        assert iou(frame.tool.numpy(), truth) > 0.6
    masks = json.loads((out / "scene.json").read_text())["extra"]["masks"]
    assert masks["automatic"] is True and masks["config"]["seed_score"] == 0.8


def test_auto_masks_and_given_masks_exclude_each_other(tool_video: Path, tmp_path: Path):
    with pytest.raises(SurgsplatError, match="either --masks or --auto-tool-masks"):
        import_scene(tool_video, tmp_path / "s",
                     ImportConfig(auto_tool_masks=True, masks=tool_video))


@pytest.mark.slow
def test_held_out_cholecseg8k_frames_reach_tool_iou_0_6(shared_data: Path):
    clip = shared_data / "cholecseg8k-clip"
    numbers = range(609, 621)  # inside the held-out half (597-632) of the clip
    frames = [cv2.imread(str(clip / f"frame_{n}_endo.png"))[..., ::-1].copy() for n in numbers]
    labels = [clip / f"frame_{n}_endo_watershed_mask.png" for n in numbers]
    tallies = np.zeros(3)
    for mask, label in zip(auto_tool_masks(frames, None), labels):
        truth = read_tool_labels(label, (31, 32))
        tallies += [(mask & truth).sum(), (mask & ~truth).sum(), (~mask & truth).sum()]
    tp, fp, fn = tallies
    assert tp / (tp + fp + fn) >= 0.6


@pytest.mark.slow
def test_cli_auto_masks_with_shading_depth(tool_video: Path, tmp_path: Path, cli,
                                           one_error_line):
    result = cli("import", str(tool_video), "--out", str(tmp_path / "s"), "--auto-tool-masks",
                 "--depth", "shading")
    assert result.returncode == 0, result.stderr
    assert "automatic" in result.stdout and "shading prior" in result.stdout
    scene = load_scene(tmp_path / "s")
    assert scene.has_masks and scene.has_depth
    assert all((frame.depth.numpy()[frame.tool.numpy()] == 0).all() for frame in scene.frames)
    result = cli("import", str(tool_video), "--out", str(tmp_path / "t"), "--depth", "sfm")
    assert "unknown --depth 'sfm'" in one_error_line(result)
