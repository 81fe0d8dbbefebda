"""Relative depth of monocular endoscopic frames from near-light shading (shape from shading).

The endoscope's light sits at the camera, so a tissue point at distance r along its pixel ray,
with albedo rho and incidence angle theta between its normal and the ray, appears with
brightness

    I = E(t) * rho * cos(theta) / r^2        (E(t): the exposure of frame t)

With z-depth d = exp(l), pixel ray p = ((u - cx) / fx, (v - cy) / fy, 1) and g = (fx dl/du,
fy dl/dv) the slope of log depth per unit of p, the normal of the surface is proportional to
n = (-g_x, -g_y, 1 + p_x g_x + p_y g_y), n . p = 1, so cos(theta) = 1 / (|n| |p|) and r = d |p|:

    log I = log(E rho) - 2 l - 3 log|p| - log|n(g)|

(the perspective near-light model of Prados & Faugeras, light at the optical centre, 1/r^2
fall-off). Per frame:

1. The frame is linearised (display gamma), and pixels without usable shading are set aside:
   outside the field of view, tools, too dark, and specular highlights or clipped pixels (any
   channel near 255, with a small margin around them: the Lambertian model does not hold there).
2. Unknown albedo: with `albedo="chromaticity"`, the part of log I that a linear function of the
   pixel's chromaticity explains (over the frame's usable pixels) is taken as albedo and removed,
   so that e.g. yellow fat does not look closer than red liver only for being brighter; what
   varies without a colour change is kept as shading. `albedo="constant"` assumes one albedo.
   Thin texture (vessels) is removed by a median filter on log I.
3. The solve: log depth is a bicubic surface through a coarse grid of knots (`knots` across the
   width), fitted at a working width of `solve_width` pixels by L-BFGS to minimise the robust
   (Charbonnier) residual of log I against the model above, with log(E rho) a free constant,
   plus `smoothness` times the mean squared curvature of log depth between the knots. It runs
   coarse to fine over `levels` knot grids, each twice as fine as the one before, starting from
   a fronto-parallel plane.
   The model fixes the slopes of the surface, not its scale.
4. Exposure and the unknown scale: each frame's depth is scaled so that its median over the
   usable pixels is `median_depth`. This removes E(t) entirely; it also assumes the median
   distance to the tissue stays about the same over the clip.

The parameters were chosen on rendered surfaces (tests/import_/test_shading_depth.py: without
the curvature term a rendered sphere cap is recovered to 0.6 %, and `smoothness` is the largest
weight that keeps it near 1 %) and on the phantom (`surgsplat phantom`, linear frames, where the
curvature term absorbs texture and sheen); the real SCARED pair is held out
(`benchmarks/bench_shading_depth.py`). Known failure modes, which dominate on real frames, so
that `surgsplat import` leaves the prior off by default: albedo that changes without a change
of colour (dark organ against pale membrane of the same hue, blood), subsurface scattering, wide
specular sheen that is not clipped, and the light's own angular fall-off (vignetting) all read
as depth; the fitted surface then keeps little more than an overall tilt.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage, optimize
from torch import Tensor

from surgsplat.data.layout import MAX_DEPTH_MM, Intrinsics
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
    highlight_margin_px: float = 3.0
    """Margin (pixels at 854 wide) around clipped pixels also set aside (a highlight's halo)."""
    albedo: Literal["chromaticity", "constant"] = "chromaticity"
    """How the unknown albedo is handled (see the module docstring)."""
    texture_px: int = 7
    """Side (pixels at 854 wide) of the median filter on log brightness that removes vessels."""
    solve_width: int = 160
    """Width (pixels) of the image the surface is fitted to."""
    knots: int = 16
    """Knots of the log-depth surface across the width at the finest level."""
    levels: int = 3
    """Coarse-to-fine levels; each halves the knots of the next."""
    iterations: int = 50
    """L-BFGS iterations per level."""
    robust_scale: float = 0.1
    """Scale of the Charbonnier loss on the log-brightness residual (0.1: a 10 % misfit)."""
    smoothness: float = 0.001
    """Weight of the mean squared curvature of log depth (per unit of the pixel ray's slope);
    larger flattens curved tissue (a sphere cap), smaller lets texture through."""
    median_depth: float = 50.0
    """Median depth of every frame, in the scene's units (the unknown absolute scale)."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if not (0 < self.gamma < math.inf and 0 < self.robust_scale < math.inf
                and 0 < self.median_depth <= MAX_DEPTH_MM):
            raise SurgsplatError(f"shading depth needs positive finite gamma and robust_scale "
                                 f"and a median_depth in (0, {MAX_DEPTH_MM:g}], got "
                                 f"{self.gamma}, {self.robust_scale} and {self.median_depth}")
        if self.albedo not in ("chromaticity", "constant"):
            raise SurgsplatError(f"shading depth albedo must be 'chromaticity' or 'constant', "
                                 f"got {self.albedo!r}")
        if min(self.texture_px, self.levels, self.iterations) < 1 or self.solve_width < 8 \
                or self.knots < 2:
            raise SurgsplatError("shading depth needs texture_px, levels and iterations >= 1, "
                                 "solve_width >= 8 and knots >= 2")
        if self.smoothness < 0 or self.highlight_margin_px < 0:
            raise SurgsplatError("shading depth needs non-negative smoothness and "
                                 "highlight_margin_px")

    def describe(self) -> dict:
        """JSON-ready parameters for scene.json."""
        return asdict(self)


def _odd(size: float) -> int:
    return max(1, int(round(size)) | 1)


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


def _shading_log(image: np.ndarray, keep: np.ndarray,
                 config: ShadingDepthConfig) -> tuple[np.ndarray, np.ndarray]:
    """(log shading float64 [H, W] up to a constant, usable bool [H, W]) of a uint8 RGB frame:
    linearised, texture filtered, albedo removed; usable = kept pixels with shading."""
    scale = image.shape[1] / REFERENCE_WIDTH
    linear = (image.astype(np.float64) / 255.0) ** config.gamma  # [H, W, 3]
    light = linear.mean(-1)
    clipped = (image.max(-1) >= config.clip_level).astype(np.uint8)
    margin = _odd(2 * config.highlight_margin_px * scale + 1)
    clipped = cv2.dilate(clipped, np.ones((margin, margin), np.uint8)) > 0
    usable = keep & (light > config.dark_level) & ~clipped
    log_light = ndimage.median_filter(np.log(np.maximum(light, 1e-6)),
                                      size=_odd(config.texture_px * scale))
    if config.albedo == "chromaticity" and usable.any():
        log_light = log_light - _albedo_log(log_light, linear, usable)
    return log_light, usable


def _downsample(values: np.ndarray, usable: np.ndarray,
                width: int) -> tuple[np.ndarray, np.ndarray]:
    """Area average [h, w] of `values` [H, W] over the `usable` pixels (bool [H, W]) at `width`,
    and the bool [h, w] cells that are at least half usable."""
    height = max(2, round(usable.shape[0] * width / usable.shape[1]))
    cover = cv2.resize(usable.astype(np.float64), (width, height), interpolation=cv2.INTER_AREA)
    total = cv2.resize(np.where(usable, values, 0.0), (width, height),
                       interpolation=cv2.INTER_AREA)
    ok = cover >= 0.5
    return np.where(ok, total / np.maximum(cover, 1e-9), 0.0), ok


def _slope(log_depth: Tensor) -> tuple[Tensor, Tensor]:
    """Central differences [h, w] of log depth along columns and rows (one-sided at edges)."""
    dx = torch.cat([log_depth[:, 1:2] - log_depth[:, :1],
                    (log_depth[:, 2:] - log_depth[:, :-2]) / 2,
                    log_depth[:, -1:] - log_depth[:, -2:-1]], 1)
    dy = torch.cat([log_depth[1:2] - log_depth[:1], (log_depth[2:] - log_depth[:-2]) / 2,
                    log_depth[-1:] - log_depth[-2:-1]], 0)
    return dx, dy


def model_log_shading(log_depth: Tensor, intrinsics: Intrinsics) -> Tensor:
    """log(cos(theta) / r^2) [h, w] of the surface of z-depth exp(log_depth) [h, w] lit from the
    optical centre (see the module docstring), pixel centres at (u + 0.5, v + 0.5)."""
    height, width = log_depth.shape
    px = (torch.arange(width, dtype=log_depth.dtype) + 0.5 - intrinsics.cx) / intrinsics.fx
    py = (torch.arange(height, dtype=log_depth.dtype) + 0.5 - intrinsics.cy) / intrinsics.fy
    px, py = px[None, :], py[:, None]
    dx, dy = _slope(log_depth)
    gx, gy = intrinsics.fx * dx, intrinsics.fy * dy
    normal_sq = gx ** 2 + gy ** 2 + (1 + px * gx + py * gy) ** 2
    return -2 * log_depth - 1.5 * torch.log(1 + px ** 2 + py ** 2) - 0.5 * torch.log(normal_sq)


def _surface(knots: Tensor, height: int, width: int) -> Tensor:
    """Bicubic surface [height, width] through a knot grid [kh, kw] spanning the image."""
    return F.interpolate(knots[None, None], size=(height, width), mode="bicubic",
                         align_corners=True)[0, 0]


def _curvature(knots: Tensor, spacing_x: float, spacing_y: float) -> Tensor:
    """Mean squared second derivatives of the knot grid [kh, kw] with knot spacings in units of
    the pixel ray's slope (the thin-plate energy per knot)."""
    xx = (knots[:, 2:] - 2 * knots[:, 1:-1] + knots[:, :-2]) / spacing_x ** 2
    yy = (knots[2:] - 2 * knots[1:-1] + knots[:-2]) / spacing_y ** 2
    xy = (knots[1:, 1:] - knots[1:, :-1] - knots[:-1, 1:] + knots[:-1, :-1]) / (
        spacing_x * spacing_y)
    return sum((term ** 2).mean() for term in (xx, yy, xy, xy) if term.numel())


def _fit(log_light: np.ndarray, ok: np.ndarray, knots: Tensor, intrinsics: Intrinsics,
         config: ShadingDepthConfig) -> Tensor:
    """The knot grid [kh, kw] of log depth, from `knots`, that best explains the log shading
    [h, w] over the `ok` cells (bool [h, w]) of an image with `intrinsics` (L-BFGS on the knots
    and the constant log(E rho))."""
    height, width = ok.shape
    target = torch.from_numpy(log_light)
    weight = torch.from_numpy(ok).double() / float(ok.sum())
    spacing_x = width / intrinsics.fx / max(knots.shape[1] - 1, 1)
    spacing_y = height / intrinsics.fy / max(knots.shape[0] - 1, 1)
    scale = config.robust_scale

    def loss(flat: np.ndarray) -> tuple[float, np.ndarray]:
        variables = torch.from_numpy(flat).requires_grad_(True)
        grid, offset = variables[:-1].view(knots.shape), variables[-1]
        shading = model_log_shading(_surface(grid, height, width), intrinsics)
        residual = (target - shading - offset) / scale
        value = (scale ** 2 * (torch.sqrt(1 + residual ** 2) - 1) * weight).sum()
        value = value + config.smoothness * _curvature(grid, spacing_x, spacing_y)
        value.backward()
        return float(value.detach()), variables.grad.numpy()

    start = np.append(knots.numpy().ravel(), np.median(log_light[ok]))
    result = optimize.minimize(loss, start, jac=True, method="L-BFGS-B",
                               options={"maxiter": config.iterations})
    return torch.from_numpy(result.x[:-1]).view(knots.shape)


def shading_depth(image: np.ndarray, intrinsics: Intrinsics, exclude: np.ndarray | None,
                  config: ShadingDepthConfig) -> np.ndarray:
    """Relative z-depth float32 [H, W] of a uint8 RGB frame [H, W, 3], median `median_depth`
    over the pixels with shading; 0 where `exclude` (bool [H, W]: outside the view, tools) is
    True. All zeros when fewer than 1 % of the pixels have shading."""
    height, width = image.shape[:2]
    keep = np.ones((height, width), bool) if exclude is None else ~exclude
    log_light, usable = _shading_log(image, keep, config)
    small, ok = _downsample(log_light, usable, min(config.solve_width, width))
    if usable.mean() < 0.01 or not ok.any():
        return np.zeros((height, width), np.float32)
    small_intrinsics = intrinsics.scaled(ok.shape[1] / width, ok.shape[0] / height)
    knots = torch.zeros(2, 2, dtype=torch.float64)  # a fronto-parallel plane
    with torch.enable_grad():
        for level in reversed(range(config.levels)):
            across = max(2, round(config.knots / 2 ** level))
            down = max(2, round(across * height / width))
            knots = _fit(small, ok, _surface(knots, down, across), small_intrinsics, config)
    log_depth = _surface(knots, height, width).numpy()
    depth = np.exp(log_depth - np.median(log_depth[usable])) * config.median_depth
    depth[~keep] = 0.0
    return depth.astype(np.float32)
