"""`surgsplat refine-masks`: masks refined by a trained run on the small phantom whose masks were
spoiled as an automatic segmenter spoils them (the tool missed in two frames, a patch of tissue
marked in four): the missed tool comes back, the refined scene loads with scene.json saying
what changed, and a bad output folder is refused."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from surgsplat.data.scene import load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.methods.overrides import apply_values
from surgsplat.methods.registry import method_config
from surgsplat.pipeline.refine_masks import refine_masks
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import Trainer

MISSED = (8, 9)  # frames whose tool the spoiled masks miss
PATCH = (slice(90, 115), slice(15, 45))  # tissue marked as tool in frames 3-6


def masks_of(scene_dir: Path) -> list[np.ndarray]:
    return [cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127
            for path in sorted((scene_dir / "masks").glob("*.png"))]


def iou(mask: np.ndarray, truth: np.ndarray) -> float:
    union = (mask | truth).sum()
    return 1.0 if union == 0 else float((mask & truth).sum() / union)


@pytest.mark.slow
def test_refined_masks_find_the_missed_tool(small_phantom: Path, tmp_path: Path):
    spoiled = tmp_path / "spoiled"
    shutil.copytree(small_phantom, spoiled)
    truths = masks_of(small_phantom)
    for index, path in enumerate(sorted((spoiled / "masks").glob("*.png"))):
        mask = truths[index].astype(np.uint8) * 255
        if index in MISSED:
            mask[:] = 0
        if 3 <= index <= 6:
            mask[PATCH] = 255
        cv2.imwrite(str(path), mask)
    config = apply_values(method_config("deform3dgs"), {"train": {"iterations": 500}})
    Trainer(config, load_scene(spoiled), tmp_path / "run").fit()
    run = load_trained_run(tmp_path / "run")
    summary = refine_masks(run, tmp_path / "refined")
    refined, given = masks_of(tmp_path / "refined"), masks_of(spoiled)
    for index in MISSED:
        assert given[index].sum() == 0
        assert iou(refined[index], truths[index]) >= 0.7, index
    for index in range(12, len(truths)):  # frames far from the spoiled ones stay as they were
        assert iou(refined[index], given[index]) >= 0.9, index
    assert summary.frames_changed >= len(MISSED) and summary.added_share > 0
    assert len(load_scene(tmp_path / "refined").frames) == len(truths)
    meta = json.loads((tmp_path / "refined" / "scene.json").read_text())["extra"]
    assert meta["masks_refined"]["frames_changed"] == summary.frames_changed
    with pytest.raises(SurgsplatError, match="exists and is not empty"):
        refine_masks(run, tmp_path / "refined")
