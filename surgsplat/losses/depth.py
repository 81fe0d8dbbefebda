"""Depth losses against a measured depth map, over tissue pixels that have a measurement.

Depths are float [H, W] in the scene's depth unit (e.g. millimetres); a ground-truth depth of 0
means "no measurement". Masks are bool [H, W] with True = count the pixel (tissue). The losses
average over the counted pixels and are 0 when there is none.

`DepthLoss` is the component that applies one of them to the render's depth map (the expected
depth of the compositing, or the depth a component puts in its place, e.g. the unbiased depth of
planar Gaussians).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import torch
from torch import Tensor

from surgsplat.data.frame_memo import PerFrame
from surgsplat.image.depth import valid_depth_pixels
from surgsplat.losses.occlusion import OcclusionImportance
from surgsplat.model.component import Component, ComponentConfig, RenderContext, SetupContext
from surgsplat.model.phases import Phase


def _mean_over(errors: Tensor, valid: Tensor, weights: Tensor | None = None) -> Tensor:
    """Mean of errors [H, W] over the valid pixels, each multiplied by its weight if given."""
    counted = valid.to(errors.dtype)
    per_pixel = counted if weights is None else counted * weights
    return (errors * per_pixel).sum() / counted.sum().clamp_min(1.0)


def median_measured_depth(gt: Tensor, mask: Tensor) -> Tensor:
    """Scalar: the median of gt [H, W] over the masked pixels (bool [H, W]) with a measured
    (positive) depth; the unit the relative depth losses divide by. NaN when there is none."""
    return gt[mask & (gt > 0)].median()


def depth_l1(pred_depth: Tensor, gt: Tensor, mask: Tensor, weights: Tensor | None = None,
             reference: Tensor | None = None) -> Tensor:
    """Mean |pred - gt| over masked pixels with gt > 0, divided by the median measured depth of
    those pixels: unit-free (a relative depth error), so that one weight suits scenes in
    millimetres or metres; `weights` [H, W] weight each pixel's error (e.g. an occlusion
    importance map); `reference`: that median when the caller knows it (`median_measured_depth`)."""
    valid = valid_depth_pixels(pred_depth, gt, mask)
    if not valid.any():
        return (pred_depth * 0.0).sum()
    if reference is None:
        reference = median_measured_depth(gt, mask)
    return _mean_over((pred_depth - gt).abs(), valid, weights) / reference


def inverse_depth_l1(pred_depth: Tensor, gt: Tensor, mask: Tensor,
                     weights: Tensor | None = None, reference: Tensor | None = None) -> Tensor:
    """Mean |1/pred - 1/gt| over masked pixels with gt > 0 and pred > 0, times the median
    measured depth of the masked pixels with gt > 0 (`reference` when the caller knows it):
    unit-free (about the relative depth error), so that one weight suits scenes in millimetres
    or metres.

    Pixels the render leaves at depth 0 (nothing drawn) have no inverse depth and are skipped.
    """
    valid = valid_depth_pixels(pred_depth, gt, mask) & (pred_depth > 0)
    # Invalid pixels get depth 1 before inverting, so that no inf or nan enters the graph.
    safe_pred = torch.where(valid, pred_depth, torch.ones_like(pred_depth))
    safe_gt = torch.where(valid, gt, torch.ones_like(gt))
    if not valid.any():
        return (pred_depth * 0.0).sum()
    if reference is None:
        reference = median_measured_depth(gt, mask)
    return reference * _mean_over((1.0 / safe_pred - 1.0 / safe_gt).abs(), valid, weights)


def scale_invariant_depth_l1(pred_depth: Tensor, gt: Tensor, mask: Tensor,
                             weights: Tensor | None = None,
                             reference: Tensor | None = None) -> Tensor:
    """Mean |log pred - log gt - m| over masked pixels with gt > 0 and pred > 0, m the median
    of log pred - log gt there: blind to one unknown scale of the measured depth (e.g. a
    shading prior's), unit-free (about the relative depth error) and robust to outliers;
    `weights` [H, W] weight each pixel's error. `reference` is not used (m depends on the
    render)."""
    valid = valid_depth_pixels(pred_depth, gt, mask) & (pred_depth > 0)
    if not valid.any():
        return (pred_depth * 0.0).sum()
    # Invalid pixels get depth 1 before the log, so that no inf or nan enters the graph.
    log_ratio = (torch.log(torch.where(valid, pred_depth, torch.ones_like(pred_depth)))
                 - torch.log(torch.where(valid, gt, torch.ones_like(gt))))  # [H, W]
    return _mean_over((log_ratio - log_ratio[valid].median()).abs(), valid, weights)


FORMS = {"l1": depth_l1, "inverse_l1": inverse_depth_l1,
         "scale_invariant": scale_invariant_depth_l1}
"""The depth loss of each DepthLossConfig.form."""


@dataclass
class DepthLossConfig(ComponentConfig, kind="depth_loss"):
    """How the rendered depth is compared with the measured depth."""

    form: Literal["l1", "inverse_l1", "scale_invariant"] = "l1"
    """L1 on depth, L1 on inverse depth (disparity), or scale-invariant L1 on log depth
    (for relative depth such as `surgsplat import --depth shading`)."""
    occlusion_gamma: float = field(default=0.0, metadata={"range": "[0, inf)"})
    """gamma of the occlusion importance map weighting each pixel (`losses.occlusion`); 0 =
    every tissue pixel weighs 1."""
    tool_pixels: bool = False
    """Count the frame's tool pixels too (every pixel of the field of view): for models that
    render the tool (a tool field), whose tool Gaussians then learn the tool's measured depth.
    The tissue Gaussians learn nothing from those pixels when the tool field's gradient weights
    keep them out. The unit of the relative forms stays the tissue's median depth; the
    occlusion importance map (occlusion_gamma > 0) weighs the tool pixels 0."""

    def build(self) -> "DepthLoss":
        return DepthLoss(self)


class DepthLoss(Component):
    """Loss term "depth": the configured depth loss over the frame's tissue pixels (with
    `tool_pixels`, its field of view) with a measured depth; 0 for frames without depth."""
    phase = Phase.LOSS
    reads_time = False

    def __init__(self, config: DepthLossConfig):
        super().__init__()
        self.config = config
        self.importance = OcclusionImportance(config.occlusion_gamma)
        # the median measured depth of each frame's tissue: of the data alone, so found once per
        # frame (a boolean gather and a selection) rather than at every step
        self.reference = PerFrame(lambda frame: median_measured_depth(frame.depth, frame.tissue))

    def setup(self, context: SetupContext) -> None:
        self.importance.observe(context.frames)

    def loss_names(self) -> tuple[str, ...]:
        return ("depth",)

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        frame, output = context.frame, context.output
        if frame.depth is None:  # a constant: no backward through the depth map (~2 ms/step)
            return {"depth": output.depth.new_zeros(())}
        weights = self.importance.weights(frame) if self.config.occlusion_gamma > 0 else None
        counted = frame.fov if self.config.tool_pixels else frame.tissue
        return {"depth": FORMS[self.config.form](output.depth, frame.depth, counted,
                                                 weights, self.reference(frame))}
