"""Tool masks refined by a trained reconstruction (`surgsplat refine-masks RUN --out SCENE`).

A deforming-tissue model trained on a clip explains the tissue. What it persistently fails to
explain, and what moves on its own, is tool; tissue that was masked but that it explains well
(it learned that tissue from the frames where it showed) is tissue. Per frame:

- *Residual*: |tissue-only render - frame| (mean over the channels), as a robust z-score over
  the frame's unmasked field of view: z = (r - median) / (1.4826 MAD). "Persistently": the
  smaller of this frame's z and the larger of the neighbouring frames', carried into this
  frame by the flow.
- *Independent motion*: the DIS flow to a neighbouring frame against one homography of the
  whole view (`data.frame_motion.camera_residual`), in units of the frame's median.
- *Decision*: an unmasked pixel becomes tool where z > `tool_z` and it moves on its own
  (motion > `tool_motion`) or a neighbouring frame's mask, carried by the flow, covers it (the
  tool was missed in this frame only); a masked pixel becomes tissue where z < `tissue_z`. The thresholds are statistical conventions (three
  robust standard deviations; more motion than the median), not fitted to a clip. Regions
  smaller than `min_area_share` of the view are dropped, and the mask is snapped to the
  frame's edges (`auto_tool_masks.snap_to_edges`).

The refined scene is a copy of the run's scene with the new masks/ and, in scene.json, what
changed; training again on it is the second pass.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from surgsplat.data.auto_tool_masks import AutoMaskConfig, snap_to_edges
from surgsplat.data.frame_motion import FlowEstimator, MotionConfig, camera_residual, warp_from
from surgsplat.data.layout import META_FILE, MASKS_DIR, SceneMeta, frame_stem, write_image
from surgsplat.errors import SurgsplatError
from surgsplat.export.mask_preview import PREVIEW_FILE
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.run import TrainedRun


@dataclass
class RefineConfig:
    """When a pixel's mask changes."""

    tool_z: float = 3.0
    """Robust z-score of the residual above which an unexplained, moving pixel becomes tool."""
    tissue_z: float = 1.0
    """Robust z-score of the residual below which a masked pixel becomes tissue."""
    tool_motion: float = 1.0
    """Independent motion (units of the frame's median) above which a pixel moves on its own."""
    min_area_share: float = 0.002
    """Smallest region added or removed, as a share of the field of view."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if not self.tissue_z < self.tool_z or self.tool_motion < 0:
            raise SurgsplatError("refine-masks needs tissue_z < tool_z and tool_motion >= 0")
        if not 0 <= self.min_area_share < 1:
            raise SurgsplatError("refine-masks needs min_area_share in [0, 1)")


@dataclass
class _Observed:
    """One frame as the refinement sees it."""

    grey: np.ndarray  # uint8 [H, W]
    z: np.ndarray  # float32 [H, W] robust z-score of the tissue render's residual
    tool: np.ndarray  # bool [H, W] the given mask
    fov: np.ndarray  # bool [H, W]


def _observe(run: TrainedRun, index: int) -> _Observed:
    frame = run.scene.frames[index]
    with torch.no_grad():
        out = render_frame(run.model, frame.camera,
                           FrameTime(frame.index, frame.time, tissue_only=True), run.background)
    image = frame.image.numpy()
    residual = np.abs(out.rgb.numpy() - image).mean(axis=-1)  # [H, W]
    tool, fov = frame.tool.numpy(), frame.fov.numpy()
    tissue = fov & ~tool
    sample = residual[tissue] if tissue.any() else residual[fov]
    median = float(np.median(sample))
    spread = 1.4826 * float(np.median(np.abs(sample - median))) + 1e-6
    grey = cv2.cvtColor((image * 255.0 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    return _Observed(grey, ((residual - median) / spread).astype(np.float32), tool, fov)


def _regions(mask: np.ndarray, least: float) -> np.ndarray:
    """bool: the 8-connected components of `mask` of at least `least` pixels."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8),
                                                               connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= least
    keep[0] = False
    return keep[labels]


def refined_mask(current: _Observed, neighbours: list[_Observed], flows: FlowEstimator,
                 motion: MotionConfig, config: RefineConfig) -> np.ndarray:
    """bool [H, W]: `current`'s mask refined against its neighbouring frames (one or two)."""
    carried_z, carried_tool, moving = [], np.zeros_like(current.tool), np.zeros_like(current.tool)
    for neighbour in neighbours:
        flow = flows.flow(current.grey, neighbour.grey)  # this frame -> the neighbour
        carried_z.append(warp_from(neighbour.z, flow))
        carried_tool |= warp_from(neighbour.tool.astype(np.float32), flow) > 0.5
        moving |= camera_residual(flow, current.fov, motion) > config.tool_motion
    persistent = np.minimum(current.z, np.maximum.reduce(carried_z))
    least = config.min_area_share * current.fov.sum()
    unexplained = current.fov & ~current.tool & (persistent > config.tool_z)
    added = _regions(unexplained & (moving | carried_tool), least)
    removed = _regions(current.tool & (persistent < config.tissue_z), least)
    return (current.tool | added) & ~removed


@dataclass
class RefineSummary:
    """What the refinement changed, over the clip (shares of the field of view's pixels)."""

    added_share: float
    removed_share: float
    frames_changed: int

    def describe(self) -> dict:
        return asdict(self)


def refine_masks(run: TrainedRun, out_dir: Path, config: RefineConfig | None = None,
                 progress: Callable[[int, int], None] | None = None) -> RefineSummary:
    """Write the run's scene, with its masks refined by the run's tissue model, to `out_dir`
    (new or empty); `progress(done, total)` after each frame."""
    config = config or RefineConfig()
    config.validate()
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise SurgsplatError(f"{out_dir}: exists and is not empty; give a new folder")
    source = run.scene.root
    shutil.copytree(source, out_dir, dirs_exist_ok=True,  # the old masks and their preview
                    ignore=shutil.ignore_patterns(MASKS_DIR, PREVIEW_FILE))
    (out_dir / MASKS_DIR).mkdir()
    motion, edges = MotionConfig(), AutoMaskConfig()
    flows = FlowEstimator(motion)
    frames = run.scene.frames
    added = removed = changed = pixels = 0
    previous, current = None, _observe(run, 0)
    for index in range(len(frames)):
        following = _observe(run, index + 1) if index + 1 < len(frames) else None
        neighbours = [frame for frame in (previous, following) if frame is not None]
        mask = (refined_mask(current, neighbours, flows, motion, config) if neighbours
                else current.tool)
        if not np.array_equal(mask, current.tool):
            guide = current.grey.astype(np.float32) / 255.0
            mask = snap_to_edges(mask, guide, edges.edge_radius, edges.edge_eps) & current.fov
        added += int((mask & ~current.tool).sum())
        removed += int((current.tool & ~mask).sum())
        changed += int(not np.array_equal(mask, current.tool))
        pixels += int(current.fov.sum())
        write_image(out_dir / MASKS_DIR / f"{frame_stem(index)}.png",
                    mask.astype(np.uint8) * 255)
        previous, current = current, following
        if progress is not None:
            progress(index + 1, len(frames))
    summary = RefineSummary(added / max(pixels, 1), removed / max(pixels, 1), changed)
    meta = SceneMeta.read(out_dir / META_FILE)
    meta.extra["masks_refined"] = {"run": str(Path(run.run_dir).resolve()),
                                   "source_scene": str(Path(source).resolve()),
                                   "config": asdict(config), **summary.describe()}
    meta.write(out_dir / META_FILE)
    return summary
