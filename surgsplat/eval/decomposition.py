"""Reflectance x illumination decomposition metrics against a phantom's truth (gt/albedo,
gt/shading), over the tissue pixels of the test frames.

Retinex is defined only up to scale, so every comparison first fits one least-squares scale per
channel over the whole clip (all test frames at once), s_c = sum(p t) / sum(p p), and measures
the scaled prediction s_c p against the truth t:

- reflectance_error: the RMSE of s_c R_t against the albedo, over the tissue pixels of all test
  frames and the 3 channels;
- r_var: at each pixel that is tissue in every test frame, the variance over the test frames of
  the scaled reflectance's deviation from the albedo, s_c R_t - A_t, averaged over those pixels
  and the channels. It is the time-varying part of the reflectance's error: illumination that
  leaks into the reflectance raises it, while the tissue's own motion under the pixel (which
  changes the albedo there too) cancels;
- shading_error: the same scaled RMSE of the illumination map L_t against gt/shading (one
  channel).

A method decomposes when a component renders the standard decomposition channels
(`model.channels.REFLECTANCE`, `ILLUMINATION`). A method without a decomposition is scored as the
naive baseline: its rendered colour as the reflectance and a constant illumination map.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom.generate import ALBEDO_DIR, SHADING_DIR
from surgsplat.data.scene import Frame, read_image, read_npy
from surgsplat.model.channels import ILLUMINATION, REFLECTANCE

CONVENTIONS = {
    "reflectance_error": "RMSE of the rendered reflectance (rendered colour for methods without "
                         "one) against gt/albedo over the tissue pixels of all test frames, after "
                         "one least-squares scale per channel over the clip",
    "r_var": "variance over the test frames of (scaled reflectance - albedo) at each pixel that "
             "is tissue in every test frame, mean over those pixels and channels",
    "shading_error": "RMSE of the illumination map (constant for methods without one) against "
                     "gt/shading over the tissue pixels of all test frames, after one "
                     "least-squares scale over the clip",
}


def least_squares_scale(pred: Tensor, truth: Tensor) -> Tensor:
    """[C] per-channel s minimising sum (s pred - truth)^2 over pred, truth [M, C]."""
    return (pred * truth).sum(0) / (pred * pred).sum(0).clamp_min(1e-12)


def scale_invariant_rmse(pred: Tensor, truth: Tensor) -> float:
    """RMSE of pred [M, C] against truth [M, C] after `least_squares_scale` per channel."""
    scale = least_squares_scale(pred, truth)
    return float(((pred * scale - truth) ** 2).mean().sqrt())


@dataclass
class DecompositionScores:
    """The test frames' reflectance, illumination and truth, gathered one frame at a time."""

    reflectance: list[Tensor] = field(default_factory=list)  # [H, W, 3] per frame
    albedo: list[Tensor] = field(default_factory=list)  # [H, W, 3]
    illumination: list[Tensor] = field(default_factory=list)  # [H, W]
    shading: list[Tensor] = field(default_factory=list)  # [H, W], frames with gt/shading
    tissue: list[Tensor] = field(default_factory=list)  # [H, W] bool
    decomposed: bool = False  # whether the method renders a reflectance channel

    def add(self, frame: Frame, extras: dict[str, Tensor], rgb: Tensor, scene_root: Path) -> None:
        """Gather one test frame (render channels `extras`, colour `rgb` [H, W, 3]) when the
        scene has its gt/albedo."""
        albedo_path = scene_root / ALBEDO_DIR / f"{frame_stem(frame.index)}.png"
        if not albedo_path.is_file():
            return
        self.decomposed = REFLECTANCE in extras
        self.reflectance.append(extras.get(REFLECTANCE, rgb).double())
        self.albedo.append(torch.from_numpy(read_image(albedo_path)).double() / 255.0)
        illumination = extras.get(ILLUMINATION)
        self.illumination.append(torch.ones(rgb.shape[:2], dtype=torch.float64)
                                 if illumination is None else illumination[..., 0].double())
        shading_path = scene_root / SHADING_DIR / f"{frame_stem(frame.index)}.npy"
        if shading_path.is_file():
            self.shading.append(torch.from_numpy(read_npy(shading_path)).double())
        self.tissue.append(frame.tissue)

    def metrics(self) -> dict[str, float | str]:
        """reflectance_error, r_var and (with gt/shading for every frame) shading_error; empty
        without frames."""
        if not self.reflectance:
            return {}
        reflectance, albedo = torch.stack(self.reflectance), torch.stack(self.albedo)  # [T, H, W, 3]
        tissue = torch.stack(self.tissue)  # [T, H, W]
        scale = least_squares_scale(reflectance[tissue], albedo[tissue])  # [3]
        result: dict[str, float | str] = {
            "reflectance_error": scale_invariant_rmse(reflectance[tissue], albedo[tissue]),
            "decomposition_source": "reflectance channel" if self.decomposed
            else "rendered colour (no decomposition)"}
        always = tissue.all(dim=0)  # [H, W]
        if always.any() and len(self.reflectance) > 1:
            deviation = reflectance[:, always] * scale - albedo[:, always]  # [T, P, 3]
            result["r_var"] = float(deviation.var(dim=0, unbiased=False).mean())
        if len(self.shading) == len(self.illumination):
            illumination, shading = torch.stack(self.illumination), torch.stack(self.shading)
            result["shading_error"] = scale_invariant_rmse(illumination[tissue][:, None],
                                                           shading[tissue][:, None])
        return result

