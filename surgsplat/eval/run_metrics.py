"""Metrics of a trained run over its test frames (i % 8 == 1), as metrics.json holds them.

`evaluate_run` renders each test frame once and composes the registered metric families (see
metric_family.py for their contract): surgsplat's own (BUILT_IN_FAMILIES: the render against
the scene's pictures, render_families.py; geometry against a phantom's ground truth,
geometry_families.py; the metrics the method's components contribute, component_metrics.py;
the tool's articulation, articulation_metrics.py), then those that installed packages add
through the entry-point group `surgsplat.metric_families` (`surgsplat.plugins`). It writes no
file: the commands that own metrics.json write it (`surgsplat.pipeline`).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from importlib.metadata import EntryPoint

import numpy as np
from torch import Tensor

from surgsplat.eval.metric_family import EvalOptions, MetricFamily, FrameView
from surgsplat.losses.photometric import masked_l1
from surgsplat.model.capabilities import HeldOutPoses
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.plugins import load_extensions
from surgsplat.train.run import TrainedRun

__all__ = ["EvalOptions", "METRICS_FILE", "METRIC_FAMILIES", "evaluate_run", "frames_scored"]

METRICS_FILE = "metrics.json"
"""RUN/metrics.json: `evaluate_run`'s metrics with the run's method and scene."""
FAMILY_GROUP = "surgsplat.metric_families"
"""The entry-point group through which an installed package adds metric families (an entry
point's value is the family's class)."""
BUILT_IN_FAMILIES = tuple(
    EntryPoint(name, f"surgsplat.eval.{module}:{family}", FAMILY_GROUP) for name, module, family in (
        ("image", "render_families", "ImageFamily"), ("depth", "render_families", "DepthFamily"),
        ("specular", "render_families", "SpecularFamily"),
        ("occluded", "render_families", "OccludedFamily"),
        ("tool_edges", "render_families", "ToolEdgeFamily"),
        ("never_seen", "render_families", "NeverSeenFamily"),
        ("diagnostics", "component_metrics", "ComponentFamily"),
        ("geometry", "geometry_families", "SurfaceFamily"),
        ("mesh_geometry", "geometry_families", "MeshFamily"),
        ("gaussians_p2s", "geometry_families", "GaussianCentresFamily"),
        ("collision_truth", "geometry_families", "CollisionFamily"),
        ("normals", "geometry_families", "NormalsFamily"),
        ("decomposition", "render_families", "DecompositionFamily"),
        ("articulation", "articulation_metrics", "ArticulationFamily")))
"""surgsplat's own metric families, each named as its `MetricFamily.name`, in the order their
metrics appear in metrics.json."""
METRIC_FAMILIES, UNLOADABLE_FAMILIES = load_extensions(FAMILY_GROUP, BUILT_IN_FAMILIES,
                                                       MetricFamily)
"""Every metric family by entry-point name (its class), the built-in ones first; and the error
of each installed one that could not be loaded (`evaluate_run` notes them in metrics.json)."""
DEPTH_KEYS = ("depth_rmse", "depth_rmse_occluded", "depth_bias_near_tool",
              "depth_bias_away_from_tool", "tissue_depth_bias_near_tool", "depth_rmse_never_seen")
"""Metrics in the scene's depth unit, named with it when it is millimetres."""
CONVENTIONS = {
    "evaluated_on": "the frames every metric is over: test (held out, every 8th frame from 1) "
                    "or train (the frames the model was fitted to: a fit, not a measure of "
                    "generalisation); test_frames counts them",
    "frames_covered": "test frames each metric family averages over, fewer than test_frames "
                      "where the scene's ground truth (or what a metric needs: depth, tool "
                      "pixels, highlights) covers fewer: image (psnr_*, ssim*, lpips), "
                      "depth (depth_rmse), specular, occluded (*_occluded), tool_edges "
                      "(tool_probability_*, depth_bias_*), never_seen (*transparent_fraction, "
                      "*_never_seen), diagnostics "
                      "(the components' averages), geometry (chamfer_mm, p2s_*, fscore_1mm), "
                      "mesh_geometry (mesh_*), gaussians_p2s, normals, decomposition",
    "fps": "rendering the test frames, this machine",
    "peak_rss_mb": "peak resident memory of the training process",
}
"""Conventions of the metrics of the run as a whole."""


def evaluate_run(run: TrainedRun, options: EvalOptions,
                 progress: Callable[[int, int], None] | None = None) -> dict:
    """All metrics of `run` as a JSON-ready dict (means over the frames `options` name, the
    test frames by default); `progress(done, total)` is called after each frame."""
    frames = options.frames_of(run)
    background = run.background
    if options.frames == "test":
        fit_test_poses(run, background)
    families = [family(run, options) for family in METRIC_FAMILIES.values()]
    rows: dict[str, list[float]] = {}  # metric -> its value at each frame that has it
    covered: Counter[str] = Counter()  # test frames scored, per family
    render_seconds = 0.0
    for done, frame in enumerate(frames, start=1):
        started = time.perf_counter()
        output = render_frame(run.model, frame.camera, FrameTime(frame.index, frame.time),
                              background)
        render_seconds += time.perf_counter() - started
        view = FrameView(run, frame, output, background)
        for family in families:
            values = family.score(view)
            for key, value in values.items():
                rows.setdefault(key, []).append(value)
            if values:
                covered[family.name] += 1
        if progress:
            progress(done, len(frames))

    covered.update({family.name: family.pooled_frames() for family in families})
    metrics: dict = {"evaluated_on": options.frames, "test_frames": len(frames),
                     "iteration": run.iteration,
                     "frames_covered": {family: count for family, count in covered.items()
                                        if count}}
    metrics.update({key: float(np.mean(values)) for key, values in rows.items()})
    for family in families:
        metrics.update(family.pooled())
    name_depth_unit(metrics, run.scene.depth_unit)
    for family in families:
        metrics.update(family.unavailable())
    if UNLOADABLE_FAMILIES:
        metrics["metric_families_not_loaded"] = dict(UNLOADABLE_FAMILIES)
    metrics["fps"] = len(frames) / render_seconds if render_seconds > 0 else None
    metrics["train_seconds"] = run.train_seconds
    metrics["budget_seconds"] = run.config.train.budget_seconds or None  # None: trained to --iters
    metrics["num_gaussians"] = run.model.gaussians.num_gaussians
    metrics["peak_rss_mb"] = run.peak_rss_mb
    metrics["conventions"] = {key: text for family in families
                              for key, text in family.conventions().items()} | CONVENTIONS
    return metrics


def frames_scored(metrics: dict) -> str:
    """Which frames a metrics.json's metrics are over, with their count: "test (2)" or
    "train (14)" (see CONVENTIONS["evaluated_on"]); one written before metrics said which is
    over the test frames, the only ones scored then."""
    return f"{metrics.get('evaluated_on', 'test')} ({metrics.get('test_frames', '?')})"


def fit_test_poses(run: TrainedRun, background: Tensor) -> None:
    """Fit the pose correction of every test frame to its tissue pixels (L1 of the render),
    the model frozen, when the method offers it (`HeldOutPoses`, e.g. camera_refine)."""
    poses = run.model.find(HeldOutPoses)
    if poses is None:
        return
    for frame in run.scene.test_frames:
        when = FrameTime(frame.index, frame.time)

        def loss(frame=frame, when=when) -> Tensor:
            camera = run.model.camera_at(frame.camera, when)
            rgb = run.model.render(camera, when, background)[0].rgb
            return masked_l1(rgb, frame.image, frame.tissue)

        poses.fit_held_out(frame.index, frame.time, loss)


def name_depth_unit(metrics: dict, unit: str) -> None:
    """Name the depth metrics present with the scene's unit (depth_rmse -> depth_rmse_mm) and
    state it (depth_unit); in place."""
    for key in DEPTH_KEYS:
        if key in metrics:
            metrics[f"{key}_{unit}" if unit == "mm" else key] = metrics.pop(key)
            metrics["depth_unit"] = unit
