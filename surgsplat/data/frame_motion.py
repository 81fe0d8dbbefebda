"""Dense optical flow between video frames, and the part of it that the camera does not explain.

The flow is OpenCV's DIS (dense inverse search) on grey frames. The camera's motion, and the
tissue's as a whole, is modelled as one homography fitted by RANSAC to the flow on a grid of
pixels inside the field of view; the residual of the flow against it marks what moves on its
own (instruments, which move rigidly and differently from tissue and camera). Flow also carries
per-pixel maps from a neighbouring frame into this one (`warp_from`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from surgsplat.errors import SurgsplatError

DIS_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
               "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
"""DIS optical flow presets by name (speed against accuracy)."""


@dataclass
class MotionConfig:
    """How flow is computed and how the camera's motion is taken out of it."""

    preset: str = "fast"
    """DIS preset, one of DIS_PRESETS."""
    grid_px: int = 6
    """Spacing (working pixels) of the flow samples the global homography is fitted to."""
    ransac_px: float = 1.0
    """RANSAC inlier distance (working pixels) of the global homography."""
    floor_px: float = 0.5
    """Residual (working pixels) below which motion is flow noise; it also keeps the residual
    scale of a still frame from being ~0."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if self.preset not in DIS_PRESETS:
            raise SurgsplatError(f"auto masks: unknown flow preset {self.preset!r}; expected "
                                 f"one of {sorted(DIS_PRESETS)}")
        if self.grid_px < 1 or self.ransac_px <= 0 or self.floor_px <= 0:
            raise SurgsplatError("auto masks need grid_px >= 1 and positive ransac_px and "
                                 "floor_px")


class FlowEstimator:
    """Dense flow between grey frames of one size, with one reusable DIS instance."""

    def __init__(self, config: MotionConfig):
        self.config = config
        self._dis = cv2.DISOpticalFlow_create(DIS_PRESETS[config.preset])

    def flow(self, source: np.ndarray, target: np.ndarray) -> np.ndarray:
        """float32 [H, W, 2] (dx, dy): pixel x of grey uint8 `source` [H, W] is seen at
        x + flow(x) in `target` [H, W]."""
        return self._dis.calc(source, target, None)


def camera_residual(flow: np.ndarray, inside: np.ndarray, config: MotionConfig) -> np.ndarray:
    """Relative independent motion, float32 [H, W] >= 0: the distance (px) of flow [H, W, 2]
    from the homography fitted to it over `inside` (bool [H, W]), less `floor_px`, divided by
    the median such distance inside plus `floor_px`. About 0 for pixels that move with the
    camera (or the tissue as a whole); several units for independently moving parts."""
    height, width = inside.shape
    ys, xs = np.mgrid[0:height:config.grid_px, 0:width:config.grid_px]
    keep = inside[ys, xs]
    source = np.stack([xs[keep], ys[keep]], axis=-1).astype(np.float32)  # [K, 2]
    if len(source) < 8:
        return np.zeros((height, width), np.float32)
    target = source + flow[ys[keep], xs[keep]]
    homography, _ = cv2.findHomography(source, target, cv2.RANSAC, config.ransac_px)
    grid = np.stack(np.meshgrid(np.arange(width, dtype=np.float32),
                                np.arange(height, dtype=np.float32)), axis=-1)  # [H, W, 2]
    if homography is None:
        predicted = grid
    else:
        predicted = cv2.perspectiveTransform(grid.reshape(1, -1, 2), homography)
        predicted = predicted.reshape(height, width, 2)
    distance = np.linalg.norm(grid + flow - predicted, axis=-1)  # [H, W] px
    excess = np.maximum(distance - config.floor_px, 0.0)
    scale = float(np.median(distance[inside])) + config.floor_px
    return (excess / scale).astype(np.float32)


def warp_from(values: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """float32 [H, W]: a neighbour frame's per-pixel `values` [H, W] carried into this frame,
    by `flow` [H, W, 2] from this frame to the neighbour (bilinear, edges replicated)."""
    height, width = values.shape
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    return cv2.remap(values.astype(np.float32), xs + flow[..., 0], ys + flow[..., 1],
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
