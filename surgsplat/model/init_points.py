"""Initial point cloud of the canonical Gaussians, from the scene's depth maps.

Frame 0's tissue pixels are back-projected; what frame 0 cannot give is filled from later
frames, by one of two fusions: motion-aware point fusion ("mapf") or Mixture-of-Gaussians
background fusion ("mogf"):

- occlusion filling (both): pixels hidden by the tool in frame 0 are taken from the first later
  frame where they are tissue with valid depth;
- motion: "mapf" adds pixels of later frames whose depth moved by more than a threshold from
  frame 0; "mogf" instead learns a MOG2 background model over frames 1..N-1, applies it to
  frame 0, and adds the later-frame pixels of the foreground (moving) region it finds.

Without depth (monocular video) the points are the scene's structure-from-motion points
(sparse_points.ply, written by `surgsplat import --poses sfm`) when it has them, else they lie
on a fronto-parallel plane at a chosen distance.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
import torch
from torch import Tensor

from surgsplat.data.scene import Frame, Scene
from surgsplat.data.sparse_points import read_sparse_points
from surgsplat.errors import DataError
from surgsplat.image.pinhole import backproject


@dataclass
class InitConfig:
    """How the initial point cloud is built."""

    fusion: Literal["none", "mapf", "mogf"] = "mapf"
    """Which later-frame pixels join frame 0: none, motion-aware fusion, or MOG2 fusion."""
    pixel_stride: int = field(default=2, metadata={"range": "[1, inf)"})
    """Use every stride-th pixel in x and y."""
    max_points: int = field(default=40_000, metadata={"range": "[4, inf)"})
    """Random subsample to at most this many points (seeded)."""
    motion_threshold: float = field(default=0.01, metadata={"range": "[0, inf)"})
    """Fusion "mapf": depth change, as a fraction of the pixel's first depth, that marks it as
    moving (unit-free: 1 mm at the phantom's 90 mm)."""
    mog_var_threshold: float = field(default=16.0, metadata={"range": "[0, inf)"})
    """Fusion "mogf": MOG2 variance threshold (OpenCV's varThreshold)."""
    monocular_depth: float = field(default=50.0, metadata={"range": "(0, inf)"})
    """Scenes without depth: distance of the initial plane, in scene units."""
    sparse_points: bool = True
    """Scenes without depth: start from the scene's structure-from-motion points when it has
    them (instead of the plane)."""
    seed: int = field(default=0, metadata={"range": "[0, 4294967295]"})
    """Seed of the subsampling."""
    max_fusion_frames: int = field(default=256, metadata={"range": "[1, inf)"})
    """Fusion looks at no more than this many training frames: every one of a shorter clip,
    else this many evenly spaced from the first, so that start-up time and memory do not grow
    with the length of the clip."""


@dataclass
class PointCloud:
    means: Tensor  # [M, 3] world-frame positions, scene units
    colors: Tensor  # [M, 3] RGB in [0, 1]


def _stride_mask(height: int, width: int, stride: int) -> Tensor:
    mask = torch.zeros(height, width, dtype=torch.bool)
    mask[::stride, ::stride] = True
    return mask


def _mog_motion_mask(frames: list[Frame], var_threshold: float) -> Tensor:
    """[H, W] bool: MOG2 foreground of frame 0 under a background learnt on frames 1..N-1."""
    subtractor = cv2.createBackgroundSubtractorMOG2(history=len(frames), varThreshold=var_threshold,
                                                    detectShadows=False)
    for frame in frames[1:]:
        subtractor.apply(_as_uint8(frame), learningRate=-1)
    foreground = subtractor.apply(_as_uint8(frames[0]), learningRate=0)
    return torch.from_numpy(foreground > 0)


def _as_uint8(frame: Frame) -> np.ndarray:
    """[H, W, 3] uint8 RGB of `frame`."""
    return (frame.image.numpy() * 255).astype(np.uint8)


def fusion_frames(frames: list[Frame], limit: int) -> list[Frame]:
    """`frames` when there are at most `limit`, else `limit` of them evenly spaced, the first
    included."""
    if len(frames) <= limit:
        return frames
    picks = torch.linspace(0, len(frames) - 1, max(limit, 1)).round().long().unique()
    return [frames[int(i)] for i in picks]


def _selected_pixels(scene: Scene, config: InitConfig) -> list[tuple[Frame, Tensor]]:
    """(frame, [H, W] bool) pairs of the pixels that become points."""
    frames = fusion_frames(scene.train_frames, config.max_fusion_frames)
    first = frames[0]
    stride = _stride_mask(scene.height, scene.width, config.pixel_stride)
    first_depth = first.depth  # [H, W]
    first_valid = first.tissue & (first_depth > 0) & stride
    chosen = [(first, first_valid)]
    if config.fusion == "none":
        return chosen
    covered = first_valid.clone()
    motion = None
    if config.fusion == "mogf":
        motion = _mog_motion_mask(frames, config.mog_var_threshold)
    for frame in frames[1:]:
        frame_valid = frame.tissue & (frame.depth > 0) & stride
        new = frame_valid & ~covered
        if config.fusion == "mapf":
            moved = (frame.depth - first_depth).abs() > config.motion_threshold * first_depth
            new |= frame_valid & moved & first_valid
        else:
            new |= frame_valid & motion
        covered |= new
        if new.any():
            chosen.append((frame, new))
    return chosen


def initial_points(scene: Scene, config: InitConfig) -> PointCloud:
    """The initial point cloud of `scene` (train frames only), at most config.max_points."""
    if scene.has_depth:
        means, colors = [], []
        for frame, mask in _selected_pixels(scene, config):
            camera = frame.camera
            means.append(backproject(frame.depth, camera.K, mask, camera.camera_to_world))
            colors.append(frame.image[mask & (frame.depth > 0)])
        points, rgb = torch.cat(means), torch.cat(colors)
    elif config.sparse_points and (sparse := read_sparse_points(scene.root)) is not None:
        points, rgb = (torch.from_numpy(array) for array in sparse)
    else:
        first = scene.train_frames[0]
        mask = first.tissue & _stride_mask(scene.height, scene.width, config.pixel_stride)
        plane = torch.full(mask.shape, config.monocular_depth)
        camera = first.camera
        points = backproject(plane, camera.K, mask, camera.camera_to_world)
        rgb = first.image[mask]
    if points.shape[0] == 0:
        raise DataError(scene.root, "no tissue pixel with valid depth to initialise Gaussians from")
    if points.shape[0] > config.max_points:
        generator = torch.Generator().manual_seed(config.seed)
        keep = torch.randperm(points.shape[0], generator=generator)[: config.max_points]
        points, rgb = points[keep], rgb[keep]
    return PointCloud(means=points.contiguous(), colors=rgb.contiguous())
