"""Metric families of the render against the scene's pictures: its images and depth maps, and
where a phantom has them, the tissue the tool hid, the highlights and the albedo and shading.

Image metrics exclude tool pixels in two named conventions (see image_metrics.py); depth error
is over tissue pixels with valid depth. What the tool hid is scored over the tool pixels (inside
the field of view) of each test frame, the render against the tissue-only image
(gt/tissue_images) and depth (gt/tissue_depth); a method that separates the tool is scored there
on its tissue-only render. Highlights are scored where the phantom marks them (gt/highlights);
the reflectance x illumination decomposition where it has gt/albedo (see decomposition.py).
"""

from __future__ import annotations

from pathlib import Path

import torch
from scipy.ndimage import distance_transform_edt

from surgsplat.data.layout import frame_stem
from surgsplat.data.never_seen import never_seen_pixels
from surgsplat.data.phantom.generate import HIGHLIGHTS_DIR, TISSUE_DEPTH_DIR, TISSUE_IMAGES_DIR
from surgsplat.data.scene import Frame, read_image, read_npy, read_tool_mask
from surgsplat.eval.decomposition import (CONVENTIONS as DECOMPOSITION_CONVENTIONS,
                                         DecompositionScores)
from surgsplat.eval.geometry_metrics import depth_rmse
from surgsplat.eval.image_metrics import psnr_tissue, psnr_zeroed, ssim_tissue, ssim_zeroed
from surgsplat.eval.lpips import load_lpips, lpips_distance
from surgsplat.eval.metric_family import EvalOptions, MetricFamily, FrameView
from surgsplat.model.channels import TOOL_PROBABILITY
from surgsplat.train.run import TrainedRun


class ImageFamily(MetricFamily):
    """psnr_*, ssim*, lpips of the render against the frame's image, tool pixels excluded."""

    name = "image"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.lpips_model, self.lpips_reason = load_lpips(options.alexnet_weights)

    def score(self, view: FrameView) -> dict[str, float]:
        pred, gt, tissue = view.rgb, view.frame.image, view.frame.tissue
        row = {"psnr_zeroed": psnr_zeroed(pred, gt, tissue),
               "psnr_tissue": psnr_tissue(pred, gt, tissue),
               "ssim": ssim_zeroed(pred, gt, tissue),
               "ssim_tissue": ssim_tissue(pred, gt, tissue)}
        if self.lpips_model is not None:
            row["lpips"] = lpips_distance(self.lpips_model, pred, gt, tissue)
        return row

    def unavailable(self) -> dict:
        if self.lpips_model is not None:
            return {}
        return {"lpips": None, "lpips_note": self.lpips_reason}

    def conventions(self) -> dict[str, str]:
        return {"psnr_zeroed": "tool pixels set to 0 in both images, mean over all pixels",
                "psnr_tissue": "mean squared error over tissue pixels only",
                "ssim": "as ssim_zeroed: tool pixels zeroed, SSIM map averaged over all pixels",
                "lpips": "AlexNet LPIPS v0.1, inputs scaled to [-1, 1], tool pixels zeroed"}


class DepthFamily(MetricFamily):
    """depth_rmse of the rendered depth against the frame's depth map."""

    name = "depth"

    def score(self, view: FrameView) -> dict[str, float]:
        frame = view.frame
        if frame.depth is None or not (frame.tissue & (frame.depth > 0)).any():
            return {}
        return {"depth_rmse": depth_rmse(view.render.depth, frame.depth, frame.tissue)}

    def conventions(self) -> dict[str, str]:
        return {"depth_rmse": "over tissue pixels with valid depth"}


class SpecularFamily(MetricFamily):
    """psnr_specular over the highlights the phantom marks, psnr_outside_highlights over the
    rest of the tissue: together they tell a method that misses the moving highlights from one
    that misses the tissue."""

    name = "specular"

    def score(self, view: FrameView) -> dict[str, float]:
        return specular_row(view.rgb, view.frame, view.run.scene.root)

    def conventions(self) -> dict[str, str]:
        return {"psnr_specular": "render vs image over the tissue pixels gt/highlights marks, "
                                 "frames with such pixels",
                "psnr_outside_highlights": "render vs image over the tissue pixels "
                                           "gt/highlights does not mark, frames with such "
                                           "pixels"}


class OccludedFamily(MetricFamily):
    """psnr_occluded, depth_rmse_occluded: the tissue the tool hid."""

    name = "occluded"

    def score(self, view: FrameView) -> dict[str, float]:
        hidden = view.tissue_render
        return occluded_row(hidden.rgb.clamp(0, 1), hidden.depth, view.frame,
                            view.run.scene.root)

    def conventions(self) -> dict[str, str]:
        return {"psnr_occluded": "render vs gt/tissue_images over the tool pixels inside the "
                                 "field of view of each test frame (what the tool hid), frames "
                                 "with tool pixels",
                "depth_rmse_occluded": "render vs gt/tissue_depth over the same pixels",
                "occluded_render": "tissue-only render (tool left out) for methods that "
                                   "separate the tool, else the ordinary render"}


OPAQUE_ALPHA = 0.99
"""A pixel of the tool-free render is opaque at this accumulated opacity or more."""


class NeverSeenFamily(MetricFamily):
    """Whether the tool-free view has a hole, and what it shows where no training frame saw the
    tissue: tool_free_transparent_fraction (every model: the field-of-view pixels of the render
    of the tissue alone less than OPAQUE_ALPHA opaque; transparent_fraction, the same of the
    ordinary render, tells a hole from a render translucent everywhere) and
    tool_free_alpha_min; over the
    never-seen pixels, the field-of-view pixels that a tool covers in every training frame
    (static cameras only: elsewhere a pixel is not one place of the tissue),
    psnr_never_seen and depth_rmse_never_seen (against the phantom's tissue without the tool)
    and never_seen_fraction (of the field of view)."""

    name = "never_seen"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.region = never_seen_pixels(run.scene.train_frames)

    def score(self, view: FrameView) -> dict[str, float]:
        hidden, fov = view.tissue_render, view.frame.fov
        row = {"transparent_fraction": float((view.render.alpha[fov] < OPAQUE_ALPHA)
                                             .float().mean()),
               "tool_free_transparent_fraction": float((hidden.alpha[fov] < OPAQUE_ALPHA)
                                                       .float().mean()),
               "tool_free_alpha_min": float(hidden.alpha[fov].min())}
        if self.region is not None and self.region.shape == fov.shape and self.region.any():
            row["never_seen_fraction"] = float(self.region[fov].float().mean())
            scores = hidden_tissue_scores(hidden.rgb.clamp(0, 1), hidden.depth, view.frame,
                                          view.run.scene.root, self.region & fov)
            row.update({f"{name}_never_seen": value for name, value in scores.items()})
        return row

    def conventions(self) -> dict[str, str]:
        return {"transparent_fraction": "field-of-view pixels of the render less than "
                                        f"{OPAQUE_ALPHA} opaque",
                "tool_free_transparent_fraction": "field-of-view pixels of the tissue-only "
                                                  f"render less than {OPAQUE_ALPHA} opaque",
                "tool_free_alpha_min": "the least opacity of the tissue-only render in the "
                                       "field of view",
                "never_seen": "the field-of-view pixels a tool covers in every training frame "
                              "(static camera); psnr_never_seen and depth_rmse_never_seen: the "
                              "tissue-only render there against gt/tissue_images and "
                              "gt/tissue_depth"}


RING_DISTANCES_PX = (3, 10)
"""Distances from the tool mask at which the rendered tool probability is measured: the ring of
tissue pixels whose distance to the nearest tool pixel is within half a pixel of each."""
NEAR_TOOL_PX = 10.0
"""Tissue pixels within this distance of the tool mask are "near the tool"."""


class ToolEdgeFamily(MetricFamily):
    """How sharply the tool's rendered edge follows the mask, and whether the tissue next to the
    tool has the depth of the tissue elsewhere: tool_probability_inside, tool_probability_3px,
    tool_probability_10px (models rendering the TOOL_PROBABILITY channel); depth_bias_near_tool
    and depth_bias_away_from_tool of the render (every model, scenes with depth), and
    tissue_depth_bias_near_tool of the tissue alone (models that separate the tool); frames with
    tool pixels."""

    name = "tool_edges"

    def score(self, view: FrameView) -> dict[str, float]:
        frame = view.frame
        if not frame.tool.any():
            return {}
        distance = torch.from_numpy(distance_transform_edt(~frame.tool.numpy())).float()
        row = {}
        probability = view.render.extras.get(TOOL_PROBABILITY)
        if probability is not None:
            probability = probability[..., 0]
            row["tool_probability_inside"] = float(probability[frame.tool].mean())
            for ring in RING_DISTANCES_PX:
                pixels = frame.tissue & ((distance - ring).abs() <= 0.5)
                if pixels.any():
                    row[f"tool_probability_{ring}px"] = float(probability[pixels].mean())
        if frame.depth is not None:
            error = view.render.depth - frame.depth
            valid = frame.tissue & (frame.depth > 0)
            near = valid & (distance <= NEAR_TOOL_PX)
            for key, pixels in (("depth_bias_near_tool", near),
                                ("depth_bias_away_from_tool", valid & (distance > NEAR_TOOL_PX))):
                if pixels.any():
                    row[key] = float(error[pixels].mean())
            if view.run.model.separates_tool and near.any():
                tissue_error = view.tissue_render.depth - frame.depth
                row["tissue_depth_bias_near_tool"] = float(tissue_error[near].mean())
        return row

    def conventions(self) -> dict[str, str]:
        rings = ", ".join(f"{ring}px" for ring in RING_DISTANCES_PX)
        return {"tool_probability": "the rendered tool probability, mean over the tool mask "
                                    "(inside) and over the rings of tissue pixels at "
                                    f"{rings} (within half a pixel) from it, frames with tool "
                                    "pixels",
                "depth_bias": "rendered minus the frame's depth (positive: too deep), mean over "
                              "the tissue pixels with depth within "
                              f"{NEAR_TOOL_PX:g} px of the tool mask (near_tool) and beyond "
                              "(away_from_tool), frames with tool pixels; tissue_depth_bias: "
                              "the same near the tool, of the tissue-only render"}


class DecompositionFamily(MetricFamily):
    """reflectance_error, r_var, shading_error over every test frame with gt/albedo."""

    name = "decomposition"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.scores = DecompositionScores()

    def score(self, view: FrameView) -> dict[str, float]:
        self.scores.add(view.frame, view.render.extras, view.render.rgb, view.run.scene.root)
        return {}

    def pooled(self) -> dict:
        return self.scores.metrics()

    def pooled_frames(self) -> int:
        return len(self.scores.reflectance)

    def conventions(self) -> dict[str, str]:
        return dict(DECOMPOSITION_CONVENTIONS)


def occluded_row(rgb: torch.Tensor, depth: torch.Tensor, frame: Frame,
                 scene_root: Path) -> dict[str, float]:
    """psnr_occluded and depth_rmse_occluded of one frame: the render rgb [H, W, 3] and depth
    [H, W] over the frame's tool pixels inside the FOV, against the tissue the tool hid. Empty
    when the scene has no gt/tissue_images for the frame or the frame shows no tool."""
    scores = hidden_tissue_scores(rgb, depth, frame, scene_root, frame.tool & frame.fov)
    return {f"{name}_occluded": value for name, value in scores.items()}


def hidden_tissue_scores(rgb: torch.Tensor, depth: torch.Tensor, frame: Frame, scene_root: Path,
                         pixels: torch.Tensor) -> dict[str, float]:
    """"psnr" and "depth_rmse" of the render rgb [H, W, 3] and depth [H, W] over `pixels`
    [H, W] bool against the phantom's tissue without the tool (gt/tissue_images,
    gt/tissue_depth); empty without the image or any pixel, no depth_rmse without the depth."""
    image_path = scene_root / TISSUE_IMAGES_DIR / f"{frame_stem(frame.index)}.png"
    if not image_path.is_file() or not pixels.any():
        return {}
    truth = torch.from_numpy(read_image(image_path)).float() / 255.0
    row = {"psnr": psnr_tissue(rgb, truth, pixels)}
    depth_path = scene_root / TISSUE_DEPTH_DIR / f"{frame_stem(frame.index)}.npy"
    if depth_path.is_file():
        truth_depth = torch.from_numpy(read_npy(depth_path))
        if (pixels & (truth_depth > 0)).any():
            row["depth_rmse"] = depth_rmse(depth, truth_depth, pixels)
    return row


def specular_row(pred: torch.Tensor, frame: Frame, scene_root: Path) -> dict[str, float]:
    """psnr_specular and psnr_outside_highlights of one frame: the render [H, W, 3] over the
    tissue pixels the phantom marks as highlight (gt/highlights) and over the other tissue
    pixels; each left out when it has no pixels, both without the file."""
    path = scene_root / HIGHLIGHTS_DIR / f"{frame_stem(frame.index)}.png"
    if not path.is_file():
        return {}
    marked = torch.from_numpy(read_tool_mask(path))  # 255 = marked
    regions = {"psnr_specular": frame.tissue & marked,
               "psnr_outside_highlights": frame.tissue & ~marked}
    return {name: psnr_tissue(pred, frame.image, pixels) for name, pixels in regions.items()
            if pixels.any()}
