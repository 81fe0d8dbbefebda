"""A run's tool articulation against the phantom's true kinematics (gt/tool_kinematics.json).

Both files are in the scene's world frame and unit. Scored over the frames whose tool mask
shows the tool (at least MIN_TOOL_FRACTION of the pixels), whether the articulation estimated
that frame from its own observation or interpolated it (test frames always are):

- hinge_axis_error_deg: angle between the estimated and the true hinge axis, orientation-free
  (an axis and its negation are the same line), mean over those frames;
- hinge_offset_mm (in the scene's unit): distance of the true hinge point from the estimated
  hinge line, mean over those frames;
- jaw_angle_rmse_deg: RMSE of the two jaws' angles over those frames. An estimate names its
  jaws and orients its axis arbitrarily, so its angles are first negated when its axis points
  against the true one (in most frames) and its jaws matched to the true ones in the order
  that fits best (the same for all frames);
- jaw_opening_rmse_deg: RMSE of the angle between the jaws (free of both choices);
- jaw_angle_rmse_deg_test: jaw_angle_rmse_deg over the test frames among them;
- *_estimated: hinge_axis_error_deg, hinge_offset_mm and jaw_angle_rmse_deg over the frames
  estimated from their own observation (the others carry a neighbour's estimate).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from surgsplat.data.phantom.kinematics import TOOL_KINEMATICS_FILE
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.eval.metric_family import EvalOptions, MetricFamily
from surgsplat.export.articulation import articulate, read_articulation
from surgsplat.model.capabilities import ToolMotion
from surgsplat.train.run import TrainedRun

MIN_TOOL_FRACTION = 0.005
"""A frame shows the tool when its tool mask covers at least this fraction of its pixels."""


def read_tool_kinematics(scene_root: Path) -> dict | None:
    """The scene's gt/tool_kinematics.json, None when it has none."""
    path = Path(scene_root) / TOOL_KINEMATICS_FILE
    if not path.is_file():
        return None
    try:
        truth = json.loads(path.read_text())
        truth["frames"][0]["hinge_axis"]
    except (OSError, ValueError, KeyError, IndexError, TypeError) as err:
        raise DataError(path, f"is not readable tool kinematics ({err})") from None
    return truth


class ArticulationFamily(MetricFamily):
    """The metrics of the module docstring, when the scene has true tool kinematics and the run
    a tool field: RUN/articulation.json (written after training), estimated here without
    writing it when missing; an estimate that cannot be made gives a note instead."""

    name = "articulation"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.run = run

    def pooled(self) -> dict:
        run = self.run
        truth = read_tool_kinematics(run.scene.root)
        if truth is None or run.model.find(ToolMotion) is None:
            return {}
        estimate = read_articulation(run.run_dir)
        if estimate is None:
            try:
                estimate = articulate(run)
            except SurgsplatError as err:
                return {"articulation_note": str(err)}
        frames = [f.index for f in run.scene.frames
                  if float(f.tool.float().mean()) >= MIN_TOOL_FRACTION]
        return articulation_metrics(estimate, truth, frames,
                                    [f.index for f in run.scene.test_frames])

    def conventions(self) -> dict[str, str]:
        return {"articulation": "hinge_axis_error_deg (orientation-free, mean), "
                                "hinge_offset_mm, jaw_angle_rmse_deg (axis sign and jaw order "
                                "aligned to the truth), jaw_opening_rmse_deg: "
                                "RUN/articulation.json vs gt/tool_kinematics.json over all "
                                "frames whose tool mask covers >= 0.5% of the image "
                                "(jaw_angle_rmse_deg_test: the test frames among them; "
                                "*_estimated: the frames estimated from their own observation)"}


def articulation_metrics(estimate: dict, truth: dict, frames: list[int],
                         test_frames: list[int]) -> dict:
    """The metrics of the module docstring over `frames` (indices), `test_frames` a subset."""
    if len(estimate["frames"]) != len(truth["frames"]):
        raise DataError(Path(TOOL_KINEMATICS_FILE), f"has {len(truth['frames'])} frames, the "
                                                    f"articulation {len(estimate['frames'])}")
    if not frames:
        return {"articulation_frames": 0}
    got = [estimate["frames"][i] for i in frames]
    true = [truth["frames"][i] for i in frames]
    axes = np.array([f["hinge_axis"] for f in got])  # [F, 3]
    true_axes = np.array([f["hinge_axis"] for f in true])
    cosine = np.einsum("fi,fi->f", axes, true_axes)
    axis_error = np.degrees(np.arccos(np.clip(np.abs(cosine), 0.0, 1.0)))
    offsets = np.array([f["hinge_point_mm"] for f in true]) - np.array(
        [f["hinge_point"] for f in got])
    along = np.einsum("fi,fi->f", offsets, axes)
    offset = np.linalg.norm(offsets - along[:, None] * axes, axis=1)
    angles = np.array([f["jaw_angles_deg"] for f in got])  # [F, 2]
    true_angles = np.array([f["jaw_angles_deg"] for f in true])
    if np.median(cosine) < 0:
        angles = -angles
    if (_wrap(angles[:, ::-1] - true_angles) ** 2).sum() < (_wrap(angles - true_angles) ** 2).sum():
        angles = angles[:, ::-1]
    squared = _wrap(angles - true_angles) ** 2  # [F, 2]
    opening = np.abs(_wrap(angles[:, 1] - angles[:, 0]))
    true_opening = np.array([f["jaw_opening_deg"] for f in true])
    metrics = {
        "hinge_axis_error_deg": float(axis_error.mean()),
        "hinge_offset_mm": float(offset.mean()),
        "jaw_angle_rmse_deg": float(np.sqrt(squared.mean())),
        "jaw_opening_rmse_deg": float(np.sqrt(((opening - true_opening) ** 2).mean())),
        "articulation_frames": len(frames),
        "articulation_frames_estimated": int(sum(bool(f["estimated"]) for f in got)),
    }
    test = [k for k, i in enumerate(frames) if i in set(test_frames)]
    if test:
        metrics["jaw_angle_rmse_deg_test"] = float(np.sqrt(squared[test].mean()))
    estimated = [k for k, f in enumerate(got) if f["estimated"]]
    if estimated:
        metrics["hinge_axis_error_deg_estimated"] = float(axis_error[estimated].mean())
        metrics["hinge_offset_mm_estimated"] = float(offset[estimated].mean())
        metrics["jaw_angle_rmse_deg_estimated"] = float(np.sqrt(squared[estimated].mean()))
    return metrics


def _wrap(degrees: np.ndarray) -> np.ndarray:
    """Angle differences (degrees) wrapped into [-180, 180)."""
    return (degrees + 180.0) % 360.0 - 180.0
