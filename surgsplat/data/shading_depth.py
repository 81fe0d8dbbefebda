"""Relative depth of monocular endoscopic frames from near-light shading.

The endoscope's light sits at the camera, so a tissue point at distance r along its pixel ray,
with albedo rho and incidence angle theta between its normal and the ray, appears with
brightness

    I = E(t) * rho * cos(theta) / r^2        (E(t): the exposure of frame t)

and so r = sqrt(E(t) * rho * cos(theta) / I). Per frame:

1. The frame is linearised (display gamma), and pixels without usable shading are set aside:
   outside the field of view, tools, too dark, and specular highlights or clipped pixels (any
   channel near 255: the Lambertian model does not hold there).
2. Unknown albedo: with `albedo="chromaticity"`, the part of log I that a linear function of the
   pixel's chromaticity explains (over the frame's usable pixels) is taken as albedo and removed,
   so that e.g. yellow fat does not look closer than red liver only for being brighter; what
   varies without a colour change is kept as shading. `albedo="constant"` assumes one albedo.
   Thin texture (vessels) is removed by a median filter on log I.
3. log r = (log rho - log I) / 2 is smoothed (after the set-aside pixels took the value of
   their nearest usable pixel) and converted to z-depth along each pixel's ray. cos(theta) is
   taken as 1: re-estimating it from the normals of the estimated depth (a fixed-point
   iteration) diverged on rendered surfaces and on the phantom, so a surface seen at a slant
   reads somewhat too far (2.8 % mean error on the bumpy plane tilted by about 10 degrees of
   tests/import_/test_shading_depth.py).
4. Exposure and the unknown scale: each frame's depth is scaled so that its median over the
   usable pixels is `median_depth`. This removes E(t) entirely; it also assumes the median
   distance to the tissue stays about the same over the clip (a camera that moves towards the
   tissue is not seen in the scale).

Known failure modes: specular highlights and clipped regions have no shading (they are left
out and filled from their surroundings); albedo changes that do not change the colour (e.g.
dark blood against tissue of the same hue) read as depth; the exposure normalisation assumes
a steady median distance.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import cv2
import numpy as np
from scipy import ndimage

from surgsplat.data.layout import Intrinsics
from surgsplat.errors import SurgsplatError

REFERENCE_WIDTH = 854
"""Frame width (pixels) at which the pixel sizes of ShadingDepthConfig hold."""


@dataclass
class ShadingDepthConfig:
    """Parameters of the near-light shading depth prior."""

    gamma: float = 2.2
    """Display gamma of the frames (1 = linear frames, e.g. the phantom's)."""
    dark_level: float = 0.01
    """Linear brightness (0..1, mean of the channels) below which a pixel has no shading."""
    clip_level: int = 250
    """A pixel with any 8-bit channel at or above this is clipped or specular: no shading."""
    albedo: Literal["chromaticity", "constant"] = "chromaticity"
    """How the unknown albedo is handled (see the module docstring)."""
    texture_px: int = 7
    """Side (pixels at 854 wide) of the median filter on log brightness that removes vessels."""
    smooth_px: float = 12.0
    """Sigma (pixels at 854 wide) of the Gaussian smoothing of log distance."""
    median_depth: float = 50.0
    """Median depth of every frame, in the scene's units (the unknown absolute scale)."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if self.gamma <= 0 or self.median_depth <= 0 or self.smooth_px <= 0:
            raise SurgsplatError("shading depth needs positive gamma, median_depth and smooth_px")
        if self.albedo not in ("chromaticity", "constant"):
            raise SurgsplatError(f"shading depth albedo must be 'chromaticity' or 'constant', "
                                 f"got {self.albedo!r}")
        if self.texture_px < 1:
            raise SurgsplatError("shading depth needs texture_px >= 1")

    def describe(self) -> dict:
        """JSON-ready parameters for scene.json."""
        return asdict(self)


def _odd(size: float) -> int:
    return max(1, int(round(size)) | 1)


def _ray_lengths(intrinsics: Intrinsics, height: int, width: int) -> np.ndarray:
    """|K^-1 [u + 0.5, v + 0.5, 1]| float64 [H, W]: distance per unit of z-depth."""
    u = (np.arange(width) + 0.5 - intrinsics.cx) / intrinsics.fx
    v = (np.arange(height) + 0.5 - intrinsics.cy) / intrinsics.fy
    return np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)


def _smooth(values: np.ndarray, usable: np.ndarray, sigma: float) -> np.ndarray:
    """`values` [H, W] Gaussian-smoothed after every pixel that is not `usable` (bool [H, W])
    took the value of its nearest usable pixel."""
    rows, cols = ndimage.distance_transform_edt(~usable, return_distances=False,
                                                return_indices=True)
    return cv2.GaussianBlur(values[rows, cols], (0, 0), sigma)


def _albedo_log(log_light: np.ndarray, linear: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """log albedo [H, W] up to a constant: the least-squares fit of log brightness on the
    pixel's chromaticity (r, g shares of the brightness) over the usable pixels."""
    total = linear.sum(-1).clip(1e-6)
    chroma = np.stack([linear[..., 0] / total, linear[..., 1] / total], axis=-1)  # [H, W, 2]
    design = np.concatenate([chroma[usable], np.ones((int(usable.sum()), 1))], axis=1)
    coefficients, *_ = np.linalg.lstsq(design, log_light[usable], rcond=None)
    albedo = chroma @ coefficients[:2]  # [H, W]
    low, high = np.percentile(albedo[usable], [1, 99])
    return np.clip(albedo, low, high)  # unusual colours (blood, tools left in) stay in range


def shading_depth(image: np.ndarray, intrinsics: Intrinsics, exclude: np.ndarray | None,
                  config: ShadingDepthConfig) -> np.ndarray:
    """Relative z-depth float32 [H, W] of a uint8 RGB frame [H, W, 3], median `median_depth`
    over the pixels with shading; 0 where `exclude` (bool [H, W]: outside the view, tools) is
    True. All zeros when fewer than 1 % of the pixels have shading."""
    height, width = image.shape[:2]
    scale = width / REFERENCE_WIDTH
    keep = np.ones((height, width), bool) if exclude is None else ~exclude
    linear = (image.astype(np.float64) / 255.0) ** config.gamma  # [H, W, 3]
    light = linear.mean(-1)
    usable = keep & (light > config.dark_level) & (image.max(-1) < config.clip_level)
    if usable.mean() < 0.01:
        return np.zeros((height, width), np.float32)
    log_light = ndimage.median_filter(np.log(np.maximum(light, 1e-6)),
                                      size=_odd(config.texture_px * scale))
    if config.albedo == "chromaticity":
        log_light = log_light - _albedo_log(log_light, linear, usable)
    log_distance = _smooth(-0.5 * log_light, usable, config.smooth_px * scale)
    depth = np.exp(log_distance) / _ray_lengths(intrinsics, height, width)  # [H, W]
    depth *= config.median_depth / np.median(depth[usable])
    depth[~keep] = 0.0
    return depth.astype(np.float32)
