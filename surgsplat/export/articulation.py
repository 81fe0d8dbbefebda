"""A trained run's tool articulation (shaft + two revolute jaws), RUN/articulation.json.

The run's model gives the canonical tool (the Gaussians its components mark as tool,
`SplatModel.tool_members`) and one rigid pose per frame (its `tool_motion`, a capability a tool
field declares; `model.capabilities`). An articulated tool field has its own hinge and jaw
angles, which are written as they are. For a rigid one the jaws' own motion is estimated after
training (`model.articulation`) from each training frame's observed tool points: its tool-mask pixels back-projected with its depth, mapped
into the canonical tool frame by the inverse of the tool field's pose. Test frames are not used;
each jaw's angles are interpolated (linearly in frame index) between the frames that saw that
jaw, as are frames without enough tool in view; such frames take the shaft motion of the
estimated frames around them (interpolated).

articulation.json (world frame = the scene's, lengths in the scene's depth unit, degrees):
    units, frame, method: what the numbers are
    canonical: hinge_point, hinge_axis, forward, jaw_angles_deg of the canonical tool
    parts: number of tool Gaussians per part (shaft, jaw_a, jaw_b)
    geometry: shaft_radius, shaft_length, jaw_length, jaw_width (along the hinge),
              jaw_thickness, measured from the parts' Gaussians in the shaft frame
    limits_deg: [[min, max] per jaw] over the frames that saw the jaw
    frames: per frame index, shaft_to_world [4, 4] (origin at the hinge point, x forward,
            z hinge axis), hinge_point, hinge_axis, jaw_angles_deg [2], jaw_opening_deg,
            estimated (the frame's own observation gave its angles)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from surgsplat.atomic import write_text_atomic
from surgsplat.data.phantom.kinematics import hinge_frame
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.image.pinhole import backproject
from surgsplat.model.articulation import (JAW_A, JAW_B, PART_NAMES, SHAFT, Articulation,
                                          ArticulationOptions, Observation,
                                          estimate_articulation)
from surgsplat.model.capabilities import ToolMotion, required
from surgsplat.train.run import TrainedRun

ARTICULATION_FILE = "articulation.json"
MAX_CANONICAL_POINTS = 20000
"""At most this many tool Gaussians (a seeded subsample) enter the estimate."""
MAX_OBSERVED_POINTS = 8000
"""At most this many observed tool points per frame (a seeded subsample)."""
ESTIMATED_JOINTS = ("per training frame: a cylinder fitted to the back-projected tool pixels "
                    "(shaft axis, its front end the hinge point); the hinge axis's roll and "
                    "both jaw angles fitted jointly to the points ahead of it, with jaw "
                    "templates from the frame where the jaws are most open, tracked through "
                    "time")
"""articulation.json's `method` of a rigid tool field's run (estimated after training)."""
OWN_JOINTS = ("the articulated tool field's own hinge and per-frame jaw angles, trained with "
              "the model (estimated at set-up as for a rigid field, then optimised)")
"""articulation.json's `method` of an articulated tool field's run."""
MIN_OPACITY = 0.05
"""Tool Gaussians less opaque than this are left out."""


def tool_motion(run: TrainedRun) -> ToolMotion:
    """The run's rigid tool motion; SurgsplatError when its method has none."""
    return required(run.model.find(ToolMotion),
                    f"{run.run_dir}: method {run.config.name!r} has no tool field, so it has no "
                    "tool to articulate (train with a method that has a tool field; "
                    "`surgsplat methods` lists each method's components)")


def tool_pose(motion: ToolMotion, index: int) -> np.ndarray:
    """[4, 4] float64 the tool's pose of frame `index` (canonical tool -> world)."""
    rotvec, translation = motion.pose(index)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rotvec.detach().double().numpy()).as_matrix()
    pose[:3, 3] = translation.detach().double().numpy()
    return pose


def canonical_tool(run: TrainedRun) -> np.ndarray:
    """[K, 3] float64 canonical centres of the run's opaque tool Gaussians (seeded subsample)."""
    params = run.model.gaussians.params
    opaque = torch.sigmoid(params["opacity_logits"]) >= MIN_OPACITY
    tool = run.model.tool_members()
    tool = opaque & (torch.zeros_like(opaque) if tool is None else tool)
    points = params["means"][tool].detach().double().numpy()
    return _subsample(points, MAX_CANONICAL_POINTS, seed=0)


def observe(run: TrainedRun, motion: ToolMotion) -> list[Observation]:
    """The training frames' observed tool points in the canonical tool frame."""
    observations = []
    for frame in run.scene.train_frames:
        if frame.depth is None:
            raise SurgsplatError(f"{run.scene.root}: frame {frame.index} has no depth; the "
                                 "articulation is estimated from the tool's observed depth")
        mask = frame.tool & frame.fov & (frame.depth > 0)
        if int(mask.sum()) == 0:
            continue
        world = backproject(frame.depth, frame.camera.K, mask, frame.camera.camera_to_world)
        world = _subsample(world.double().numpy(), MAX_OBSERVED_POINTS, seed=frame.index)
        pose = tool_pose(motion, frame.index)
        observations.append(Observation(frame.index, (world - pose[:3, 3]) @ pose[:3, :3]))
    return observations


def articulate(run: TrainedRun,
               options: ArticulationOptions = ArticulationOptions()) -> dict:
    """The run's articulation.json content (see the module docstring)."""
    motion = tool_motion(run)
    poses = [tool_pose(motion, i) for i in range(len(run.scene.frames))]
    own = motion.articulation(run.model.gaussians)
    if own is not None:
        return describe(own, poses, run.scene.depth_unit, OWN_JOINTS)
    canonical = canonical_tool(run)
    try:
        estimate = estimate_articulation(canonical, observe(run, motion), options)
    except ValueError as err:
        raise SurgsplatError(f"{run.run_dir}: cannot articulate the tool: {err}") from None
    return describe(estimate, poses, run.scene.depth_unit, ESTIMATED_JOINTS)


def describe(estimate: Articulation, poses: list[np.ndarray], unit: str, method: str) -> dict:
    """JSON-ready articulation of every frame (poses: the tool field's, one per frame)."""
    frame = hinge_frame(estimate.forward, estimate.axis, estimate.hinge_point)  # canonical
    estimated = list(estimate.frames)
    records = []
    for index, pose in enumerate(poses):
        shaft_to_world = pose @ estimate.shaft_motion_at(index) @ frame
        angles = [float(angle) for angle in estimate.jaw_angles_at(index)]
        records.append({"index": index, "shaft_to_world": shaft_to_world.tolist(),
                        "hinge_point": shaft_to_world[:3, 3].tolist(),
                        "hinge_axis": shaft_to_world[:3, 2].tolist(),
                        "jaw_angles_deg": angles,
                        "jaw_opening_deg": abs((angles[1] - angles[0] + 180.0) % 360.0 - 180.0),
                        "estimated": index in estimated})
    return {
        "units": {"length": unit, "angle": "deg"},
        "frame": "world (the scene's); canonical: the tool field's canonical tool",
        "method": method,
        "canonical": {"hinge_point": estimate.hinge_point.tolist(),
                      "hinge_axis": estimate.axis.tolist(),
                      "forward": estimate.forward.tolist(),
                      "jaw_angles_deg": estimate.canonical_jaw_deg.tolist()},
        "parts": {name: int((estimate.labels == part).sum())
                  for part, name in enumerate(PART_NAMES)},
        "geometry": part_geometry(estimate, frame),
        "limits_deg": [[float(estimate.jaw_angles_deg[estimate.jaw_observed[:, j], j].min()),
                        float(estimate.jaw_angles_deg[estimate.jaw_observed[:, j], j].max())]
                       for j in range(2)],
        "frames": records,
    }


def part_geometry(estimate: Articulation, frame: np.ndarray) -> dict:
    """Sizes of the parts (scene units) from their points in the shaft frame: the shaft's
    radius (median distance from its axis, the x axis) and seen length; each jaw, turned back
    to angle 0, measured along x (95th percentile), z (width) and y (thickness) as 5-95
    percentile spans (at least a tenth of the jaw's length)."""
    local = (estimate.points - frame[:3, 3]) @ frame[:3, :3]
    shaft = local[estimate.labels == SHAFT]
    lengths, widths, thicknesses = [], [], []
    for j, part in enumerate((JAW_A, JAW_B)):
        turn = Rotation.from_rotvec(np.radians(-estimate.canonical_jaw_deg[j]) * np.array(
            [0.0, 0.0, 1.0]))
        jaw = turn.apply(local[estimate.labels == part])
        length = float(np.quantile(jaw[:, 0], 0.95))
        lengths.append(length)
        span = np.quantile(jaw, 0.95, axis=0) - np.quantile(jaw, 0.05, axis=0)
        widths.append(max(float(span[2]), 0.1 * length))
        thicknesses.append(max(float(span[1]), 0.1 * length))
    return {"shaft_radius": float(np.median(np.linalg.norm(shaft[:, 1:], axis=1))),
            "shaft_length": float(max(-shaft[:, 0].min(), 1e-3)),
            "jaw_length": float(np.mean(lengths)), "jaw_width": float(np.mean(widths)),
            "jaw_thickness": float(np.mean(thicknesses))}


def write_articulation(run_dir: Path, articulation: dict) -> Path:
    """Write RUN/articulation.json atomically; its path."""
    path = Path(run_dir) / ARTICULATION_FILE
    write_text_atomic(path, json.dumps(articulation, indent=1) + "\n")
    return path


def read_articulation(run_dir: Path) -> dict | None:
    """RUN/articulation.json, None when the run has none; DataError when it is unreadable or
    lacks its keys."""
    path = Path(run_dir) / ARTICULATION_FILE
    if not path.is_file():
        return None
    try:
        articulation = json.loads(path.read_text())
        for key in ("canonical", "geometry", "limits_deg", "frames"):
            articulation[key]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DataError(path, f"is not a readable articulation ({err}); delete it and run "
                              "`surgsplat articulate RUN` again") from None
    return articulation


def _subsample(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    """At most `count` rows of points [N, 3], a seeded random subset."""
    if points.shape[0] <= count:
        return points
    keep = np.random.default_rng(seed).choice(points.shape[0], count, replace=False)
    return points[np.sort(keep)]
