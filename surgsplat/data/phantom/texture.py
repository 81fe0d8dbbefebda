"""Procedural tissue albedo: pinkish-red tissue, fat patches and branching vessels.

The albedo is a raster over material coordinates (X, Y) in [-HALF_EXTENT_MM, HALF_EXTENT_MM]^2,
built once per seed at a texel size matched to the camera's pixel footprint and sampled
bilinearly. Vessels are random-walk trees drawn as tapering anti-aliased polylines; everything
is deterministic from the seed.
"""

from __future__ import annotations

import cv2
import numpy as np

from surgsplat.data.phantom.motion import smoothstep

HALF_EXTENT_MM = 100.0
"""The texture covers material coordinates [-100, 100] mm in X and Y."""
TISSUE_RGB = (np.array([0.80, 0.40, 0.38], np.float32), np.array([0.70, 0.26, 0.26], np.float32))
"""Pinkish and redder tissue albedo, mixed by low-frequency noise."""
FAT_RGB = np.array([0.90, 0.76, 0.42], np.float32)
"""Albedo of yellow fat patches."""
FAT_SHARE = 0.15
"""Approximate share of the tissue covered by fat."""
VESSEL_RGB = np.array([0.42, 0.06, 0.09], np.float32)
"""Albedo at the centre of a vessel."""
CUT_RGB = np.array([0.62, 0.12, 0.12], np.float32)
"""Albedo of the opened tissue inside a cut."""
VESSEL_STEP_MM = 1.0
"""Length of one random-walk step of a vessel."""
VESSEL_TURN_RAD = 0.12
"""Standard deviation of a vessel's change of heading per step."""
VESSEL_BRANCH_PROBABILITY = 0.06
"""Chance per step that a vessel spawns a thinner side branch."""
VESSEL_GENERATIONS = 3
"""Side branches of side branches stop after this many generations."""


class TissueTexture:
    """The albedo raster of one phantom; `texel_mm` is the raster's resolution."""

    def __init__(self, seed: int, texel_mm: float):
        rng = np.random.default_rng([seed, 2])
        self.texel_mm = float(texel_mm)
        size = int(np.ceil(2 * HALF_EXTENT_MM / self.texel_mm))
        tint = _smooth_noise(rng, size, cell_mm=25.0)
        mottle = _smooth_noise(rng, size, cell_mm=1.5)
        fat_noise = _smooth_noise(rng, size, cell_mm=18.0)
        fat = smoothstep((fat_noise - np.quantile(fat_noise[::8, ::8], 1.0 - FAT_SHARE)) / 0.08)
        pink, red = TISSUE_RGB
        albedo = pink + (red - pink) * tint[..., None]  # [S, S, 3]
        albedo *= np.float32(0.93) + np.float32(0.14) * mottle[..., None]
        albedo += (FAT_RGB - albedo) * (np.float32(0.75) * fat[..., None])
        vessels = self._vessel_coverage(rng, size)  # [S, S] in [0, 1]
        albedo += (VESSEL_RGB - albedo) * vessels[..., None]
        self.raster = albedo  # [S, S, 3] float32

    def _vessel_coverage(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Opacity [S, S] of the vessel trees, thin vessels fainter than thick ones."""
        coverage = np.zeros((size, size), dtype=np.uint8)  # OpenCV anti-aliases 8-bit images only
        segments = sorted(_vessel_segments(rng), key=lambda seg: seg[2])
        shift = 4  # cv2 draws at sub-texel precision: coordinates in 1 / 2^shift texel
        fixed = 1 << shift
        for start, end, width in segments:
            a = np.rint(self._texel_coordinates(start) * fixed).astype(np.int64)
            b = np.rint(self._texel_coordinates(end) * fixed).astype(np.int64)
            thickness = max(1, int(round(width / self.texel_mm)))
            opacity = 0.85 * min(1.0, 0.4 + 0.6 * width / 1.5) * min(1.0, width / self.texel_mm)
            cv2.line(coverage, tuple(int(v) for v in a), tuple(int(v) for v in b),
                     int(round(255 * opacity)), thickness, cv2.LINE_AA, shift)
        return cv2.GaussianBlur(coverage.astype(np.float32) / 255.0, (0, 0), sigmaX=0.7)

    def _texel_coordinates(self, mm: np.ndarray) -> np.ndarray:
        """Raster column (or row) coordinates of material coordinates, texel centres at integers."""
        return (mm + HALF_EXTENT_MM) / self.texel_mm - 0.5

    def sample(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Bilinear albedo [H, W, 3] float32 at material coordinates X, Y [H, W] mm."""
        col = self._texel_coordinates(X).astype(np.float32)
        row = self._texel_coordinates(Y).astype(np.float32)
        return cv2.remap(self.raster, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _smooth_noise(rng: np.random.Generator, size: int, cell_mm: float) -> np.ndarray:
    """Smooth value noise [size, size] in [0, 1] with features about `cell_mm` across: random
    values on a grid of 4 x 4 points per cell, blurred to one cell, bicubically upsampled."""
    cells = max(2, int(round(2 * HALF_EXTENT_MM / cell_mm)))
    coarse = rng.random((4 * cells + 1, 4 * cells + 1)).astype(np.float32)
    coarse = cv2.GaussianBlur(coarse, (0, 0), sigmaX=1.5, borderType=cv2.BORDER_REFLECT)
    fine = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
    low, high = fine.min(), fine.max()
    return (fine - low) / max(high - low, 1e-6)


def _vessel_segments(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Line segments (start [2] mm, end [2] mm, width mm) of the vessel trees."""
    roots = int(rng.integers(14, 20))
    stack = []
    for _ in range(roots):
        start = rng.uniform(-0.6 * HALF_EXTENT_MM, 0.6 * HALF_EXTENT_MM, 2)
        stack.append((start, rng.uniform(0, 2 * np.pi), rng.uniform(1.0, 1.8),
                      rng.uniform(80.0, 150.0), 0))
    segments = []
    while stack:
        point, heading, width, length, generation = stack.pop()
        steps = int(length / VESSEL_STEP_MM)
        for step in range(steps):
            heading += rng.normal(0.0, VESSEL_TURN_RAD)
            end = point + VESSEL_STEP_MM * np.array([np.cos(heading), np.sin(heading)])
            local_width = width * (1.0 - 0.4 * step / steps)
            segments.append((point, end, local_width))
            if generation < VESSEL_GENERATIONS and rng.random() < VESSEL_BRANCH_PROBABILITY:
                side = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.1)
                stack.append((end, heading + side, local_width * rng.uniform(0.5, 0.7),
                              length * rng.uniform(0.4, 0.6), generation + 1))
            point = end
            if np.abs(point).max() > HALF_EXTENT_MM:
                break
    return segments
