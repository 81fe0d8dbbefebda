"""Disparity and depth from a rectified stereo pair with OpenCV's semi-global block matching.

Disparity maps are float32 [H, W] in pixels of the left image, with **0 = invalid** (no match,
failed left-right check, speckle, or outside the search range), the same "0 = unknown"
convention as depth maps on disk. The images must already be rectified: corresponding points
lie on the same row, and a point at disparity d in the left image is at column x - d in the right.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from surgsplat.errors import SurgsplatError

SGBM_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}
"""Names of OpenCV's SGBM aggregation modes (5, 3, 8 and 4 path directions)."""


@dataclass
class StereoConfig:
    """StereoSGBM parameters; defaults tuned on the SCARED sample (benchmarks/bench_stereo.py)."""

    min_disparity: int = 0
    """Smallest disparity searched, in pixels (>= 0: parallel rectified cameras)."""
    num_disparities: int = 128
    """Width of the disparity search range in pixels; a multiple of 16."""
    block_size: int = 7
    """Side of the matched block in pixels; odd."""
    p1_per_pixel: int = 8
    """Penalty for a disparity change of 1 between neighbours: P1 = this x channels x block_size^2."""
    p2_per_pixel: int = 96
    """Penalty for larger disparity jumps: P2 = this x channels x block_size^2 (> P1)."""
    uniqueness_ratio: int = 5
    """Percent by which the best match cost must beat the second best, else invalid."""
    speckle_window_size: int = 100
    """Largest connected blob (pixels) of similar disparity that is removed as speckle; 0 = off."""
    speckle_range: int = 2
    """Disparity variation (px) allowed inside one connected speckle blob."""
    disp12_max_diff: int = 1
    """Largest left-right consistency difference in pixels; -1 disables the check."""
    pre_filter_cap: int = 63
    """Clip of the x-derivative prefilter applied before matching."""
    mode: str = "sgbm_3way"
    """Aggregation mode: one of SGBM_MODES (sgbm, sgbm_3way, hh, hh4)."""
    pad_left: bool = True
    """Pad both images on the left by the search range (edge pixels repeated) so that the
    leftmost min_disparity + num_disparities columns also get disparities."""

    def validate(self) -> None:
        if self.min_disparity < 0:
            raise SurgsplatError(f"stereo min_disparity must be >= 0, got {self.min_disparity}")
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise SurgsplatError("stereo num_disparities must be a positive multiple of 16, "
                                 f"got {self.num_disparities}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise SurgsplatError(f"stereo block_size must be odd and >= 1, got {self.block_size}")
        if not 0 < self.p1_per_pixel < self.p2_per_pixel:
            raise SurgsplatError("stereo penalties must satisfy 0 < p1_per_pixel < p2_per_pixel, "
                                 f"got {self.p1_per_pixel} and {self.p2_per_pixel}")
        if self.mode not in SGBM_MODES:
            raise SurgsplatError(f"unknown stereo mode {self.mode!r}; expected one of "
                                 f"{', '.join(SGBM_MODES)}")


def stereo_disparity(left: np.ndarray, right: np.ndarray, config: StereoConfig) -> np.ndarray:
    """Disparity of `left` against `right` (uint8 [H, W, 3] RGB or [H, W] grey, rectified),
    as float32 [H, W] in pixels; 0 where no valid disparity was found."""
    config.validate()
    if left.shape != right.shape:
        raise SurgsplatError(f"stereo images differ in shape: left {left.shape}, right {right.shape}")
    channels = 1 if left.ndim == 2 else left.shape[2]
    area = channels * config.block_size ** 2
    matcher = cv2.StereoSGBM.create(
        minDisparity=config.min_disparity, numDisparities=config.num_disparities,
        blockSize=config.block_size, P1=config.p1_per_pixel * area,
        P2=config.p2_per_pixel * area, disp12MaxDiff=config.disp12_max_diff,
        preFilterCap=config.pre_filter_cap, uniquenessRatio=config.uniqueness_ratio,
        speckleWindowSize=config.speckle_window_size, speckleRange=config.speckle_range,
        mode=SGBM_MODES[config.mode])
    pad = config.min_disparity + config.num_disparities if config.pad_left else 0
    left, right = (cv2.copyMakeBorder(np.ascontiguousarray(image), 0, 0, pad, 0,
                                      cv2.BORDER_REPLICATE) for image in (left, right))
    fixed = matcher.compute(left, right)[:, pad:]  # [H, W] int16 in 1/16 px
    disparity = fixed.astype(np.float32) / cv2.StereoMatcher_DISP_SCALE
    # Invalid pixels come back as (min_disparity - 1); a zero disparity (infinitely far) is unusable.
    disparity[(disparity < config.min_disparity) | (disparity <= 0)] = 0.0
    return disparity


def fill_invalid(disparity: np.ndarray) -> np.ndarray:
    """`disparity` with every invalid (0) pixel set to the value of its nearest valid pixel
    (Euclidean distance); all zeros stay all zeros."""
    invalid = disparity <= 0  # [H, W]
    if invalid.all() or not invalid.any():
        return disparity.copy()
    rows, cols = ndimage.distance_transform_edt(invalid, return_distances=False,
                                                return_indices=True)
    return disparity[rows, cols]


def disparity_to_depth(disparity: np.ndarray, focal: float, baseline: float) -> np.ndarray:
    """Depth = focal x baseline / disparity as float32 [H, W] in the unit of `baseline`
    (focal and disparity in pixels); 0 where the disparity is invalid (<= 0)."""
    if focal <= 0 or baseline <= 0:
        raise SurgsplatError(f"focal and baseline must be positive, got {focal:g} and {baseline:g}")
    disparity = np.asarray(disparity, dtype=np.float32)
    depth = np.zeros_like(disparity)
    valid = disparity > 0
    depth[valid] = focal * baseline / disparity[valid]
    return depth
