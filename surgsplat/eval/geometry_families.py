"""Metric families of the reconstructed geometry against a phantom's ground truth.

On a phantom, geometry is measured against the ground-truth tissue mesh of each test frame
(gt/meshes/<frame>.ply, world frame) three ways: the reconstructed surface (the rendered depth
back-projected over tissue pixels with the frame's camera into the world frame), the exported
tissue mesh, and the deformed Gaussian centres; normals are measured against the ground-truth
camera-space normals (gt/normals/<frame>.npy). Point-to-surface metrics: see geometry_metrics.py.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from pathlib import Path

import numpy as np
import torch

from surgsplat.data.layout import frame_stem
from surgsplat.data.scene import Camera, Frame, read_npy
from surgsplat.eval.geometry_metrics import (GEOMETRY_KEYS, geometry_metrics, point_to_surface,
                                             sample_surface, weighted_mean_median)
from surgsplat.eval.metric_family import EvalOptions, MetricFamily, FrameView
from surgsplat.eval.normals import normal_angle_deg, surface_normals
from surgsplat.export.mesh import FrameMesh, MeshExtractor, coverage
from surgsplat.image.pinhole import backproject, inside_image, project_points
from surgsplat.model.capabilities import ToolMotion
from surgsplat.model.physics import ToolProxy
from surgsplat.train.run import TrainedRun

GEOMETRY_POINTS = 60_000
"""Reconstructed points per test frame used for geometry (a seeded subsample)."""


def gt_normals_path(scene_root: Path, index: int) -> Path:
    """The phantom's ground-truth camera-space normals of frame `index`."""
    return scene_root / "gt" / "normals" / f"{frame_stem(index)}.npy"


class GroundTruthMeshFamily(MetricFamily, ABC):
    """A family scored against the frame's gt mesh: with --geometry, on frames that have one."""

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.enabled = options.geometry

    def score(self, view: FrameView) -> dict[str, float]:
        if not self.enabled or view.gt_mesh is None:
            return {}
        return self.score_against_mesh(view)

    @abstractmethod
    def score_against_mesh(self, view: FrameView) -> dict[str, float]:
        """The family's values of a frame whose gt mesh is `view.gt_mesh`."""


class SurfaceFamily(GroundTruthMeshFamily):
    """chamfer_mm, p2s_*, fscore_1mm of the rendered depth's surface against the gt mesh."""

    name = "geometry"

    def score_against_mesh(self, view: FrameView) -> dict[str, float]:
        frame = view.seen
        return frame_geometry(view.render.depth, view.render.alpha, frame.tissue, frame.camera,
                              *view.gt_mesh, seed=frame.index)

    def conventions(self) -> dict[str, str]:
        return {"geometry": "rendered depth back-projected over tissue pixels with the frame's "
                            "camera into the world frame vs gt tissue mesh"}


class MeshFamily(MetricFamily):
    """mesh_* of the frame's exported tissue mesh against the gt mesh."""

    name = "mesh_geometry"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.meshes = MeshExtractor(run.model, background=run.background) \
            if options.geometry else None

    def score(self, view: FrameView) -> dict[str, float]:
        if self.meshes is None or view.gt_mesh is None:
            return {}
        return mesh_geometry(self.meshes.frame_mesh(view.frame), view.seen, *view.gt_mesh)

    def conventions(self) -> dict[str, str]:
        route = self.meshes.route if self.meshes else None
        return {"mesh_geometry": "mesh_*: the frame's exported tissue mesh (surgsplat export "
                                 f"--mesh; route {route}), area-sampled, vs gt tissue mesh; "
                                 "mesh_coverage: fraction of tissue pixels (one grid cell in "
                                 "from the mask border) the mesh covers; "
                                 "mesh_largest_hole_cells: largest uncovered region there, in "
                                 "grid cells"}


class GaussianCentresFamily(GroundTruthMeshFamily):
    """gaussians_p2s_*: the deformed tissue Gaussian centres against the gt mesh."""

    name = "gaussians_p2s"

    def score_against_mesh(self, view: FrameView) -> dict[str, float]:
        model = view.run.model
        state = view.state
        means, opacities = state.means, state.opacities
        tissue = model.tissue_members()
        if tissue is not None:
            means, opacities = means[tissue], opacities[tissue]
        return gaussian_geometry(means, opacities, view.seen, *view.gt_mesh,
                                 seed=view.frame.index)

    def conventions(self) -> dict[str, str]:
        return {"gaussians_p2s": "distance of every deformed Gaussian centre that projects "
                                 "inside the frame's field of view to the gt tissue mesh "
                                 "(the P2S of the Gaussian point cloud), whatever its "
                                 "opacity; tissue Gaussians only when a tool field marks some "
                                 "as tool; gaussians_p2s_weighted_mean_mm and _median_mm: the "
                                 "same distances weighted by each Gaussian's rendered opacity "
                                 "at the test frame (after every component, e.g. the SDF's "
                                 "bell), so a faded floater counts little; the median is the "
                                 "lower weighted median"}


class CollisionFamily(GroundTruthMeshFamily):
    """collision_fraction and collision_fraction_truth: the share of the reconstructed tissue,
    and of the true tissue surface, inside the tool's collision proxy (methods with one)."""

    name = "collision_truth"

    def score_against_mesh(self, view: FrameView) -> dict[str, float]:
        model = view.run.model
        motion, tissue = model.find(ToolMotion), model.tissue_members()
        if motion is None or tissue is None:
            return {}
        state = view.state
        proxy = motion.proxy(state, model.gaussians)
        if proxy is None:
            return {}
        truth = sample_surface(*view.gt_mesh, GEOMETRY_POINTS, seed=view.frame.index)
        return collision_fractions(proxy, {
            "collision_fraction": state.means[tissue],
            "collision_fraction_truth": torch.from_numpy(truth).to(state.means.dtype)},
            view.seen)

    def conventions(self) -> dict[str, str]:
        return {"collision_truth": "collision_fraction: share of the deformed tissue Gaussian "
                                   "centres seen in the field of view that lie inside the tool's "
                                   "collision proxy (as `collisions` counts them); "
                                   "collision_fraction_truth: the same test on area-uniform "
                                   "samples of the gt tissue mesh, what a perfect "
                                   "reconstruction would score against this tool proxy"}


class NormalsFamily(MetricFamily):
    """normal_error_deg_*: rendered (or rendered-depth) normals against the gt normals, pooled
    over the tissue pixels of every test frame."""

    name = "normals"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.enabled = options.geometry
        self.angles: list[torch.Tensor] = []  # [M] per covered frame, degrees
        self.source: str | None = None  # "rendered" or "depth"

    def score(self, view: FrameView) -> dict[str, float]:
        path = gt_normals_path(view.run.scene.root, view.frame.index)
        if self.enabled and path.is_file():
            normals, valid, self.source = surface_normals(view.render, view.frame.camera.K)
            truth = torch.from_numpy(read_npy(path))
            self.angles.append(normal_angle_deg(normals, truth, valid & view.frame.tissue))
        return {}

    def pooled(self) -> dict:
        if not self.angles:
            return {}
        pooled = torch.cat(self.angles)
        return {"normal_error_deg_mean": float(pooled.mean()),
                "normal_error_deg_median": float(pooled.median()),
                "normal_source": self.source}

    def pooled_frames(self) -> int:
        return len(self.angles)

    def conventions(self) -> dict[str, str]:
        return {"normal_error_deg": "angle between rendered (or rendered-depth) and gt normals, "
                                    "orientation-free, pooled over the tissue pixels of all "
                                    "test frames"}


def frame_geometry(depth: torch.Tensor, alpha: torch.Tensor, tissue: torch.Tensor,
                   camera: Camera, gt_vertices: np.ndarray, gt_faces: np.ndarray,
                   seed: int) -> dict[str, float]:
    """Geometry metrics of one frame's reconstructed tissue surface against its gt mesh: the
    depth [H, W] rendered from `camera`, back-projected into the world frame of the mesh."""
    surface = tissue & (alpha > 0.5)
    points = backproject(depth, camera.K, surface, camera.camera_to_world).numpy()
    metrics = geometry_metrics(_subsample(points, seed), gt_vertices, gt_faces, seed=seed)
    return {key: metrics[key] for key in GEOMETRY_KEYS}


def mesh_geometry(mesh: FrameMesh, frame: Frame, gt_vertices: np.ndarray,
                  gt_faces: np.ndarray) -> dict[str, float]:
    """mesh_* metrics of one frame's extracted mesh against its gt mesh (see conventions)."""
    covered, largest_hole = coverage(mesh, frame)
    row = {"mesh_coverage": covered, "mesh_largest_hole_cells": largest_hole}
    if len(mesh.faces):
        points = sample_surface(mesh.vertices, mesh.faces, GEOMETRY_POINTS, seed=frame.index)
        metrics = geometry_metrics(points, gt_vertices, gt_faces, seed=frame.index)
        row.update({f"mesh_{key}": metrics[key] for key in GEOMETRY_KEYS})
    return row


def seen_in_frame(points: torch.Tensor, frame: Frame) -> torch.Tensor:
    """[P] bool: the world points [P, 3] that project inside `frame`'s field of view."""
    camera = frame.camera
    pixel, z = project_points(points, camera.K, camera.world_to_camera)
    seen = inside_image(pixel, z, camera.width, camera.height)
    seen[seen.clone()] = frame.fov[pixel[seen, 1], pixel[seen, 0]]
    return seen


def collision_fractions(proxy: ToolProxy, points: dict[str, torch.Tensor],
                        frame: Frame) -> dict[str, float]:
    """For each named set of world points [P, 3]: the share of those seen in `frame`'s field of
    view that lie inside `proxy` (no entry when none is seen)."""
    row = {}
    for key, world in points.items():
        seen = seen_in_frame(world, frame)
        if seen.any():
            row[key] = float((proxy.sdf(world[seen], 1.0) < 0).float().mean())
    return row


def gaussian_geometry(means: torch.Tensor, opacities: torch.Tensor, frame: Frame,
                      gt_vertices: np.ndarray, gt_faces: np.ndarray,
                      seed: int) -> dict[str, float]:
    """gaussians_p2s_* of the deformed centres [N, 3] seen inside `frame`'s field of view, plain
    and weighted by their rendered opacities [N] (see the conventions)."""
    seen = seen_in_frame(means, frame)
    if not seen.any():
        return {}
    rows = _subsample(seen.nonzero()[:, 0].numpy(), seed)
    distance = point_to_surface(means[rows].numpy(), gt_vertices, gt_faces)
    row = {"gaussians_p2s_mean_mm": float(distance.mean()),
           "gaussians_p2s_median_mm": float(np.median(distance)),
           "gaussians_p2s_p95_mm": float(np.percentile(distance, 95))}
    weights = opacities[rows].numpy()
    if weights.sum() > 0:
        mean, median = weighted_mean_median(distance, weights)
        row.update(gaussians_p2s_weighted_mean_mm=mean, gaussians_p2s_weighted_median_mm=median)
    return row


def _subsample(points: np.ndarray, seed: int) -> np.ndarray:
    """At most GEOMETRY_POINTS rows of points [N, ...], a seeded random choice."""
    if len(points) <= GEOMETRY_POINTS:
        return points
    keep = np.random.default_rng(seed).choice(len(points), GEOMETRY_POINTS, replace=False)
    return points[keep]
