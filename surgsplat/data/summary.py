"""A scene's summary: the facts `surgsplat info` prints and `demo` shows."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from surgsplat.data.layout import META_FILE
from surgsplat.data.scene import Scene
from surgsplat.errors import DataError


@dataclass(frozen=True)
class SceneSummary:
    """What a researcher wants to know about a scene before training on it."""

    root: str
    num_frames: int
    width: int
    height: int
    focal_px: float  # fx
    fy_px: float
    principal_point_px: tuple[float, float]  # (cx, cy), pixel centres at +0.5
    moving_camera: bool
    camera_travel: float  # largest distance of a camera centre from frame 0's, scene unit
    num_train: int
    num_test: int
    test_indices: list[int]
    depth_unit: str
    depth_min: float | None  # over valid (> 0) tissue pixels of all frames; None without depth
    depth_max: float | None
    depth_valid_share: float | None  # share of tissue pixels with depth > 0
    tool_share_mean: float  # mean share of tool pixels per frame (masks/)
    tool_share_max: float
    fov_share: float  # share of pixels inside the field of view (1.0 without fov_mask.png)
    has_masks: bool
    tool_mask_confidence: list[float] | None = None  # per frame, automatic masks only (0..1)
    sfm_registered: int | None = None  # frames registered by SfM; None = poses not from SfM
    sfm_interpolated: list[int] | None = None  # frames whose pose is interpolated (SfM only)


def mask_confidence(scene: Scene) -> list[float] | None:
    """Per-frame confidence of automatic tool masks from scene.json (extra.masks.confidence),
    None when the scene has none; raises DataError unless it is one number in [0, 1] per
    frame."""
    masks = scene.meta.extra.get("masks")
    if not isinstance(masks, dict) or "confidence" not in masks:
        return None
    values = masks["confidence"]
    if not (isinstance(values, list) and len(values) == len(scene.frames) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 1
            for v in values)):
        raise DataError(scene.root / META_FILE, f"extra.masks.confidence must list one number "
                                                f"in [0, 1] per frame ({len(scene.frames)})")
    return [float(v) for v in values]


def sfm_frames(scene: Scene) -> tuple[int, list[int]] | None:
    """(registered count, indices of the interpolated frames) of poses from structure from
    motion (scene.json extra.poses), None for other poses; raises DataError unless the
    interpolated frames are distinct frame indices and the counts add up."""
    poses = scene.meta.extra.get("poses")
    if not isinstance(poses, dict) or poses.get("source") != "sfm":
        return None
    count = len(scene.frames)
    registered, interpolated = poses.get("registered"), poses.get("interpolated")
    if not (isinstance(interpolated, list) and all(
            isinstance(i, int) and not isinstance(i, bool) and 0 <= i < count
            for i in interpolated) and len(set(interpolated)) == len(interpolated)
            and isinstance(registered, int) and registered + len(interpolated) == count):
        raise DataError(scene.root / META_FILE, f"extra.poses must give registered (an integer) "
                                                f"and interpolated (distinct frame indices in "
                                                f"0..{count - 1}) adding up to {count} frames")
    return registered, sorted(interpolated)


def summarise(scene: Scene) -> SceneSummary:
    tool_shares = torch.tensor([f.tool.float().mean().item() for f in scene.frames])
    depth_min = depth_max = valid_share = None
    if scene.has_depth:
        valid_counts = tissue_counts = 0
        lows, highs = [], []
        for frame in scene.frames:
            values = frame.depth[frame.tissue]
            values = values[values > 0]
            valid_counts += values.numel()
            tissue_counts += int(frame.tissue.sum())
            if values.numel():
                lows.append(values.min().item())
                highs.append(values.max().item())
        depth_min = min(lows) if lows else None
        depth_max = max(highs) if highs else None
        valid_share = valid_counts / max(tissue_counts, 1)
    camera = scene.camera
    sfm = sfm_frames(scene)
    centres = torch.stack([f.camera.camera_to_world[:3, 3] for f in scene.frames])  # [N, 3]
    return SceneSummary(
        root=str(scene.root), num_frames=len(scene.frames), width=scene.width,
        height=scene.height, focal_px=camera.fx, fy_px=camera.fy,
        principal_point_px=(camera.cx, camera.cy), moving_camera=scene.has_moving_camera,
        camera_travel=float((centres - centres[0]).norm(dim=1).max()),
        num_train=len(scene.train_frames), num_test=len(scene.test_frames),
        test_indices=[f.index for f in scene.test_frames], depth_unit=scene.depth_unit,
        depth_min=depth_min, depth_max=depth_max, depth_valid_share=valid_share,
        tool_share_mean=float(tool_shares.mean()), tool_share_max=float(tool_shares.max()),
        fov_share=float(scene.frames[0].fov.float().mean()), has_masks=scene.has_masks,
        tool_mask_confidence=mask_confidence(scene),
        sfm_registered=None if sfm is None else sfm[0],
        sfm_interpolated=None if sfm is None else sfm[1])


def format_summary(summary: SceneSummary) -> list[tuple[str, str]]:
    """(label, value) rows for a table."""
    rows = [
        ("scene", summary.root),
        ("frames", f"{summary.num_frames} ({summary.num_train} train, {summary.num_test} test: "
                   f"i % 8 == 1 -> {summary.test_indices})"),
        ("size", f"{summary.width} x {summary.height} px (W x H)"),
        ("intrinsics", f"fx {summary.focal_px:.2f}, fy {summary.fy_px:.2f}, principal point "
                       f"({summary.principal_point_px[0]:.2f}, "
                       f"{summary.principal_point_px[1]:.2f}) px"),
        ("camera", f"moving, centre travels up to {summary.camera_travel:.3g} "
                   f"{summary.depth_unit}" if summary.moving_camera else "static"),
        ("field of view", f"{100 * summary.fov_share:.1f}% of pixels inside"),
    ]
    if summary.depth_min is None:
        rows.append(("depth", "none (monocular)"))
    else:
        rows.append(("depth", f"{summary.depth_min:.2f} .. {summary.depth_max:.2f} "
                              f"{summary.depth_unit}, valid on "
                              f"{100 * summary.depth_valid_share:.1f}% of tissue pixels"))
    if summary.has_masks:
        rows.append(("tool", f"mean {100 * summary.tool_share_mean:.1f}% of pixels, "
                             f"max {100 * summary.tool_share_max:.1f}%"))
    else:
        rows.append(("tool", "no tool masks"))
    confidence = summary.tool_mask_confidence
    if confidence is not None:
        lowest = min(range(len(confidence)), key=confidence.__getitem__)
        rows.append(("tool mask confidence", f"mean {sum(confidence) / len(confidence):.2f}, "
                                             f"lowest {confidence[lowest]:.2f} (frame {lowest})"))
    if summary.sfm_interpolated is not None:
        flagged = summary.sfm_interpolated
        rows.append(("SfM poses", f"{summary.sfm_registered} of {summary.num_frames} frames "
                                  "registered" + (f"; interpolated: frames {flagged}" if flagged
                                                  else "")))
    return rows
