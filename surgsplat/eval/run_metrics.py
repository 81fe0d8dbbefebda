"""Metrics of a trained run over its test frames (i % 8 == 1), written to RUN/metrics.json.

Image metrics exclude tool pixels in two named conventions (see image_metrics.py); depth error
is over tissue pixels with valid depth; on a phantom, geometry is measured against the
ground-truth tissue mesh of each test frame (gt/meshes/<frame>.ply, world frame), using the
reconstructed surface: the rendered depth back-projected over tissue pixels with the frame's
camera into the world frame; and normals against the ground-truth camera-space normals
(gt/normals/<frame>.npy). What the tool hid is scored where the phantom has it: over the tool
pixels (inside the field of view) of each test frame, the render against the tissue-only image
(gt/tissue_images) and depth (gt/tissue_depth); a method that separates the tool is scored there
on its tissue-only render. Highlights are scored where the phantom marks them
(gt/highlights), and the components' diagnostics (e.g. tool collisions) join the metrics. Where
the phantom has gt/albedo (and gt/shading), the reflectance x illumination decomposition is
scored (see decomposition.py).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from surgsplat.data.ply import read_ply_mesh
from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom.generate import HIGHLIGHTS_DIR, TISSUE_DEPTH_DIR, TISSUE_IMAGES_DIR
from surgsplat.data.scene import Camera, Frame, read_image, read_npy, read_tool_mask
from surgsplat.eval.geometry_metrics import (depth_rmse, geometry_metrics, point_to_surface,
                                             sample_surface, weighted_mean_median)
from surgsplat.eval.decomposition import (CONVENTIONS as DECOMPOSITION_CONVENTIONS,
                                         DecompositionScores)
from surgsplat.eval.image_metrics import psnr_tissue, psnr_zeroed, ssim_tissue, ssim_zeroed
from surgsplat.eval.lpips import LPIPS, load_lpips, lpips_distance
from surgsplat.eval.normals import normal_angle_deg, surface_normals
from surgsplat.eval.articulation_metrics import (MIN_TOOL_FRACTION, articulation_metrics,
                                                 read_tool_kinematics)
from surgsplat.errors import SurgsplatError
from surgsplat.export.articulation import articulate, read_articulation, write_articulation
from surgsplat.export.mesh import FrameMesh, MeshExtractor, coverage
from surgsplat.image.pinhole import backproject, inside_image, project_points
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.model.physics import tissue_members
from surgsplat.train.run import TrainedRun

GEOMETRY_KEYS = ("chamfer_mm", "p2s_mean_mm", "p2s_median_mm", "p2s_p95_mm", "fscore_1mm")
"""Geometry of the rendered depth back-projected (no prefix), of the exported mesh (`mesh_`)."""
GEOMETRY_POINTS = 60_000
"""Reconstructed points per test frame used for geometry (a seeded subsample)."""


@dataclass
class EvalOptions:
    """What `evaluate_run` measures."""

    alexnet_weights: Path | None = None
    """torchvision AlexNet checkpoint for LPIPS (default: env var / torch hub cache)."""
    geometry: bool = True
    """Measure geometry against gt/ meshes when the scene has them."""


def mesh_path(scene_root: Path, index: int) -> Path:
    return scene_root / "gt" / "meshes" / f"{frame_stem(index)}.ply"


def normals_path(scene_root: Path, index: int) -> Path:
    return scene_root / "gt" / "normals" / f"{frame_stem(index)}.npy"


def evaluate_run(run: TrainedRun, options: EvalOptions,
                 progress: Callable[[int, int], None] | None = None) -> dict:
    """All metrics of `run` as a JSON-ready dict (means over test frames); `progress(done,
    total)` is called after each test frame."""
    scene = run.scene
    frames = scene.test_frames
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    lpips_model, lpips_reason = load_lpips(options.alexnet_weights)
    rows: dict[str, list[float]] = {}
    angles: list[torch.Tensor] = []
    normal_source = None
    render_seconds = 0.0
    meshes = MeshExtractor(run.model, background=background) if options.geometry else None
    decomposition = DecompositionScores()
    summed: dict[str, float] = {}  # diagnostics summed over the test frames (counts stay int)
    covered: Counter[str] = Counter()  # test frames scored, per metric family
    for frame in frames:
        started = time.perf_counter()
        out = render_frame(run.model, frame.camera, FrameTime(frame.index, frame.time), background)
        render_seconds += time.perf_counter() - started
        pred = out.rgb.clamp(0, 1)
        row: dict[str, float] = {}
        add_family(row, covered, "image", image_row(pred, frame.image, frame.tissue, lpips_model))
        if frame.depth is not None:
            valid = frame.tissue & (frame.depth > 0)
            if valid.any():
                add_family(row, covered, "depth",
                           {"depth_rmse": depth_rmse(out.depth, frame.depth, frame.tissue)})
        add_family(row, covered, "specular", specular_row(pred, frame, scene.root))
        hidden = out
        if run.model.separates_tool:
            hidden = render_frame(run.model, frame.camera,
                                  FrameTime(frame.index, frame.time, tissue_only=True), background)
        add_family(row, covered, "occluded",
                   occluded_row(hidden.rgb.clamp(0, 1), hidden.depth, frame, scene.root))
        diagnostics = run.model.diagnostics(FrameTime(frame.index, frame.time))
        add_family(row, covered, "diagnostics", diagnostics.averaged)
        for key, value in diagnostics.summed.items():
            summed[key] = summed.get(key, 0) + value
        decomposition.add(frame, out.extras, out.rgb, scene.root)
        gt_mesh = mesh_path(scene.root, frame.index)
        if options.geometry and gt_mesh.is_file():
            gt_vertices, gt_faces = read_ply_mesh(gt_mesh)
            add_family(row, covered, "geometry",
                       frame_geometry(out.depth, out.alpha, frame.tissue, frame.camera,
                                      gt_vertices, gt_faces, seed=frame.index))
            add_family(row, covered, "mesh_geometry",
                       mesh_geometry(meshes.frame_mesh(frame), frame, gt_vertices, gt_faces))
            state = run.model.state_at(FrameTime(frame.index, frame.time))
            means, opacities = state.means.detach(), state.opacities.detach()
            tissue = tissue_members(run.model.gaussians.params)
            if tissue is not None:
                means, opacities = means[tissue], opacities[tissue]
            add_family(row, covered, "gaussians_p2s",
                       gaussian_geometry(means, opacities, frame, gt_vertices, gt_faces,
                                         seed=frame.index))
        gt_normals = normals_path(scene.root, frame.index)
        if options.geometry and gt_normals.is_file():
            normals, valid, normal_source = surface_normals(out, frame.camera.K)
            truth = torch.from_numpy(read_npy(gt_normals))
            angles.append(normal_angle_deg(normals, truth, valid & frame.tissue))
        for key, value in row.items():
            rows.setdefault(key, []).append(value)
        if progress:
            progress(len(rows["psnr_tissue"]), len(frames))

    covered.update(normals=len(angles), decomposition=len(decomposition.reflectance))
    metrics: dict = {"test_frames": len(frames), "iteration": run.iteration,
                     "frames_covered": {family: count for family, count in covered.items()
                                        if count}}
    for key, values in rows.items():
        metrics[key] = float(np.mean(values))
    metrics.update(summed)
    if angles:
        pooled = torch.cat(angles)
        metrics["normal_error_deg_mean"] = float(pooled.mean())
        metrics["normal_error_deg_median"] = float(pooled.median())
        metrics["normal_source"] = normal_source
    metrics.update(decomposition.metrics())
    metrics.update(articulation_row(run))
    unit = scene.depth_unit
    for key in ("depth_rmse", "depth_rmse_occluded"):
        if key in metrics:
            metrics[f"{key}_{unit}" if unit == "mm" else key] = metrics.pop(key)
            metrics["depth_unit"] = unit
    if lpips_model is None:
        metrics["lpips"] = None
        metrics["lpips_note"] = lpips_reason
    metrics["fps"] = len(frames) / render_seconds if render_seconds > 0 else None
    metrics["train_seconds"] = run.train_seconds
    metrics["num_gaussians"] = run.model.gaussians.num_gaussians
    metrics["peak_rss_mb"] = run.peak_rss_mb
    metrics["conventions"] = {
        "psnr_zeroed": "tool pixels set to 0 in both images, mean over all pixels",
        "psnr_tissue": "mean squared error over tissue pixels only",
        "ssim": "as ssim_zeroed: tool pixels zeroed, SSIM map averaged over all pixels",
        "lpips": "AlexNet LPIPS v0.1, inputs scaled to [-1, 1], tool pixels zeroed",
        "depth_rmse": "over tissue pixels with valid depth",
        "psnr_occluded": "render vs gt/tissue_images over the tool pixels inside the field of "
                         "view of each test frame (what the tool hid), frames with tool pixels",
        "depth_rmse_occluded": "render vs gt/tissue_depth over the same pixels",
        "occluded_render": "tissue-only render (tool left out) for methods that separate the "
                           "tool, else the ordinary render",
        "psnr_specular": "render vs image over the tissue pixels gt/highlights marks, frames "
                         "with such pixels",
        "collisions": "tissue Gaussians inside the convex hull of the tool Gaussians, summed "
                      "over test frames (methods with a tool field)",
        "arap_strain_mean": "Eq. 4 ARAP strain per tissue Gaussian over its canonical 16 "
                            "nearest neighbours, scene units squared, mean over test frames",
        "geometry": "rendered depth back-projected over tissue pixels with the frame's camera "
                    "into the world frame vs gt tissue mesh",
        "mesh_geometry": "mesh_*: the frame's exported tissue mesh (surgsplat export --mesh; "
                         f"route {meshes.route if meshes else None}), area-sampled, vs gt tissue "
                         "mesh; mesh_coverage: fraction of tissue pixels (one grid cell in from "
                         "the mask border) the mesh covers; mesh_largest_hole_cells: largest "
                         "uncovered region there, in grid cells",
        "gaussians_p2s": "distance of every deformed Gaussian centre that projects inside the "
                         "frame's field of view to the gt tissue mesh (Endo-GSG's P2S of the "
                         "Gaussian point cloud), whatever its opacity; tissue Gaussians only "
                         "when a tool field marks some as tool; gaussians_p2s_weighted_mean_mm "
                         "and _median_mm: the same distances weighted by each Gaussian's "
                         "rendered opacity at the test frame (after every component, e.g. the "
                         "SDF's bell), so a faded floater counts little; the median is the lower "
                         "weighted median",
        "articulation": "hinge_axis_error_deg (orientation-free, mean), hinge_offset_mm, "
                        "jaw_angle_rmse_deg (axis sign and jaw order aligned to the truth), "
                        "jaw_opening_rmse_deg: RUN/articulation.json vs gt/tool_kinematics.json "
                        "over all frames whose tool mask covers >= 0.5% of the image "
                        "(jaw_angle_rmse_deg_test: the test frames among them; *_estimated: "
                        "the frames estimated from their own observation)",
        "normal_error_deg": "angle between rendered (or rendered-depth) and gt normals, "
                            "orientation-free, pooled over the tissue pixels of all test frames",
        "frames_covered": "test frames each metric family averages over, fewer than test_frames "
                          "where the scene's ground truth (or what a metric needs: depth, tool "
                          "pixels, highlights) covers fewer: image (psnr_*, ssim*, lpips), "
                          "depth (depth_rmse), specular, occluded (*_occluded), diagnostics "
                          "(the components' averages), geometry (chamfer_mm, p2s_*, fscore_1mm), "
                          "mesh_geometry (mesh_*), gaussians_p2s, normals, decomposition",
        "fps": "rendering the test frames, this machine",
        "peak_rss_mb": "peak resident memory of the training process",
        **DECOMPOSITION_CONVENTIONS,
    }
    return metrics


def add_family(row: dict[str, float], covered: Counter[str], family: str,
               values: dict[str, float]) -> None:
    """Add one frame's `values` of metric `family` to its `row`; the frame counts as covered by
    the family when there are any."""
    row.update(values)
    if values:
        covered[family] += 1


def articulation_row(run: TrainedRun) -> dict:
    """Hinge and jaw-angle errors (see articulation_metrics.py) when the scene has true tool
    kinematics and the run a tool field; RUN/articulation.json is estimated and written when
    missing; an estimate that cannot be made gives a note instead."""
    truth = read_tool_kinematics(run.scene.root)
    if truth is None or not run.model.separates_tool:
        return {}
    estimate = read_articulation(run.run_dir)
    if estimate is None:
        try:
            estimate = articulate(run)
        except SurgsplatError as err:
            return {"articulation_note": str(err)}
        write_articulation(run.run_dir, estimate)
    frames = [f.index for f in run.scene.frames if float(f.tool.float().mean())
              >= MIN_TOOL_FRACTION]
    return articulation_metrics(estimate, truth, frames,
                                [f.index for f in run.scene.test_frames])


def image_row(pred: torch.Tensor, gt: torch.Tensor, tissue: torch.Tensor,
              lpips_model: LPIPS | None) -> dict[str, float]:
    row = {"psnr_zeroed": psnr_zeroed(pred, gt, tissue),
           "psnr_tissue": psnr_tissue(pred, gt, tissue),
           "ssim": ssim_zeroed(pred, gt, tissue),
           "ssim_tissue": ssim_tissue(pred, gt, tissue)}
    if lpips_model is not None:
        row["lpips"] = lpips_distance(lpips_model, pred, gt, tissue)
    return row


def occluded_row(rgb: torch.Tensor, depth: torch.Tensor, frame: Frame,
                 scene_root: Path) -> dict[str, float]:
    """psnr_occluded and depth_rmse_occluded of one frame: the render rgb [H, W, 3] and depth
    [H, W] over the frame's tool pixels inside the FOV, against the tissue the tool hid. Empty
    when the scene has no gt/tissue_images for the frame or the frame shows no tool."""
    image_path = scene_root / TISSUE_IMAGES_DIR / f"{frame_stem(frame.index)}.png"
    occluded = frame.tool & frame.fov
    if not image_path.is_file() or not occluded.any():
        return {}
    truth = torch.from_numpy(read_image(image_path)).float() / 255.0
    row = {"psnr_occluded": psnr_tissue(rgb, truth, occluded)}
    depth_path = scene_root / TISSUE_DEPTH_DIR / f"{frame_stem(frame.index)}.npy"
    if depth_path.is_file():
        truth_depth = torch.from_numpy(read_npy(depth_path))
        if (occluded & (truth_depth > 0)).any():
            row["depth_rmse_occluded"] = depth_rmse(depth, truth_depth, occluded)
    return row


def specular_row(pred: torch.Tensor, frame: Frame, scene_root: Path) -> dict[str, float]:
    """psnr_specular of one frame: the render [H, W, 3] over the tissue pixels the phantom marks
    as highlight (gt/highlights); empty without the file or such pixels."""
    path = scene_root / HIGHLIGHTS_DIR / f"{frame_stem(frame.index)}.png"
    if not path.is_file():
        return {}
    highlight = frame.tissue & torch.from_numpy(read_tool_mask(path))  # 255 = marked
    return {"psnr_specular": psnr_tissue(pred, frame.image, highlight)} if highlight.any() else {}


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


def gaussian_geometry(means: torch.Tensor, opacities: torch.Tensor, frame: Frame,
                      gt_vertices: np.ndarray, gt_faces: np.ndarray,
                      seed: int) -> dict[str, float]:
    """gaussians_p2s_* of the deformed centres [N, 3] seen inside `frame`'s field of view, plain
    and weighted by their rendered opacities [N] (see the conventions)."""
    camera = frame.camera
    pixel, z = project_points(means, camera.K, camera.world_to_camera)
    seen = inside_image(pixel, z, camera.width, camera.height)
    seen[seen.clone()] = frame.fov[pixel[seen, 1], pixel[seen, 0]]
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
