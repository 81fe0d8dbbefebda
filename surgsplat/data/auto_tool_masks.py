"""Automatic tool masks for video without labels: a classical segmenter, no learned weights.

Cues (each measured relative to the frame itself, so that they carry over to other procedures,
light sources and white balances; all sizes are in pixels at the working width):

- *Colourless*: metal and black plastic reflect the light without tinting it, while tissue
  (liver, fat, gallbladder, bowel, pale fascia alike) is coloured. A pixel's colour is its
  CIELAB chroma over its lightness (a saturation, so that dark plastic is as colourless as
  grey metal), compared with the frame's median: log(median / saturation).
- *Structured*: instruments have sharp edges, grooves and specular streaks; tissue, pale tissue
  included, is smooth at this scale. Texture is the local mean of |Laplacian| of lightness,
  compared with the frame's median: log(texture / median).
- *Specular highlights* are bright, unsaturated, small blobs that move with the light, on
  tissue as on metal: they are told apart explicitly (near-clipped, unsaturated connected
  blobs smaller than `highlight_max_share` of the field of view) and carry no evidence of
  their own: their evidence is filled in from their surroundings, so that a highlight on a
  tool is tool and one on tissue is tissue. Large bright unsaturated areas (white insulation
  of a hook, gauze) are surfaces, not highlights, and are judged by the cues above.
- *Independent motion*: dense DIS flow to the neighbouring frames, against one homography
  fitted by RANSAC (the camera's motion and the tissue's as a whole); the residual, relative
  to the frame's median residual, marks parts that move on their own
  (`surgsplat.data.frame_motion`).
- *Temporal consistency*: each frame's appearance evidence is averaged with its neighbours'
  (`temporal_radius` frames each side), carried into the frame along the flow.
- *Region decisions*: the per-pixel log-odds (a weighted sum of the cues) grows regions by
  hysteresis; a region is a tool if its mean log-odds, plus a bonus if it enters from the
  border of the field of view (instruments come in from outside) and one if it is elongated
  (shafts), is positive. Small regions are dropped.
- *Edges at full size*: the mask, decided at the working size, is upsampled with a guided
  filter whose guide is the full-size frame, so that its boundary follows the frame's edges.

Per-frame confidence (0..1): the margin of the frame's decisions. Each candidate region's
decision margin is |2 sigmoid(region log-odds) - 1| (0 = a coin toss, 1 = certain); the frame's
confidence is their mean weighted by region area; a frame without candidate regions has
confidence 1 (no pixel came near being tool).

Tuning: the cue weights, bias, hysteresis thresholds, contrast window and opening were chosen
on CholecSeg8k frames 561-596 (a small grid search, pooled tool IoU 0.687) and scored on
frames 597-632 (0.669; benchmarks/bench_auto_masks.py reports both and every frame's IoU). The
motion weight was not fitted: on that clip the grasper moves with the camera and a fit gives
motion a negative weight, so it is kept a small positive cue for clips whose instruments move.
The surround of the local colour cue was then widened from 21 to 61 working pixels, on the
rule that it must be wider than the widest instrument, and checked on clips it was not tuned
on: the held-out frames (0.669 to 0.722), the phantoms' grey shaft (0.48 to 0.93; 0.33 to 0.88
on the high-variation phantom) and the tool-free SCARED frame (false alarms 1.3 % to 1.9 % of the
field of view); the tuning frames went from 0.687 to 0.659. The guided upsampling
(`edge_radius`, set to twice the working pixel, a rule, not a fit) then raised every clip by
0.01-0.02 (tuning 0.669, held-out 0.735, phantoms 0.945 and 0.902).
`contrast_floor` and `max_hollowness` were set on drawn frames (smooth tissue; a pale region's
rim), not on the clip.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from typing import TypeVar

import cv2
import numpy as np

from surgsplat.data.frame_motion import (FlowEstimator, MotionConfig, camera_residual,
                                         warp_from)
from surgsplat.errors import SurgsplatError

Item = TypeVar("Item")

CONFIDENCE_MEANING = ("0..1 per frame: area-weighted mean decision margin |2 sigmoid(log-odds) "
                      "- 1| of the candidate tool regions; 1 = no candidate region")
"""What a frame's confidence means, as scene.json records it."""


@dataclass
class AutoMaskConfig:
    """Parameters of the classical tool segmenter (defaults chosen on the tuning frames)."""

    work_width: int = 427
    """Frames are segmented at this width (pixels; the aspect ratio is kept), masks are
    returned at the frame's own size."""
    colour_weight: float = 2.0
    """Log-odds per e-fold of saturation below the frame's median."""
    local_colour_weight: float = 2.0
    """Log-odds per e-fold of chroma below the most coloured surroundings (closing over
    `surround_px`): instruments are less coloured than the tissue around them."""
    surround_px: int = 61
    """Side (working pixels) of the surroundings of the local colour cue; tools narrower than
    this stand out, so it is set wider than a close instrument's shaft (a seventh of the
    working width): at 21 the smooth middle of a wide shaft had no surroundings to differ
    from and was missed."""
    texture_weight: float = 3.0
    """Log-odds per e-fold of texture above the frame's median."""
    motion_weight: float = 0.25
    """Log-odds per unit of relative independent motion (frame_motion.camera_residual)."""
    motion_cap: float = 4.0
    """Relative independent motion above which the motion evidence stops growing."""
    bias: float = -6.0
    """Log-odds of a still pixel with the frame's median saturation and texture."""
    chroma_floor: float = 2.0
    """CIELAB chroma below which colour is not measured (sensor noise)."""
    lightness_floor: float = 5.0
    """CIELAB lightness (0..100) added to the local mean lightness that divides the local
    spread, so that sensor noise in black pixels does not read as contrast."""
    contrast_floor: float = 0.03
    """Local Weber contrast below which a frame's typical texture is taken as this (sensor
    noise): in a very smooth frame every tissue edge would otherwise read as structure."""
    texture_px: int = 3
    """Side (working pixels) of the box over which the local contrast is measured."""
    highlight_value: float = 0.9
    """Share of full scale of the brightest channel at or above which an unsaturated pixel
    may be specular."""
    highlight_saturation: float = 0.3
    """HSV saturation below which a bright pixel may be specular."""
    highlight_max_share: float = 0.003
    """Largest specular blob, as a share of the field of view; larger bright unsaturated
    areas are surfaces."""
    fill_px: int = 9
    """Side (working pixels) of the window whose valid pixels fill in the evidence of
    highlights and of the field of view's rim."""
    temporal_radius: int = 1
    """Frames on each side whose evidence is carried along the flow and averaged."""
    seed_logit: float = 1.0
    """Log-odds at which a pixel surely is tool (hysteresis high threshold)."""
    grow_logit: float = 0.0
    """Log-odds down to which a tool region grows (hysteresis low threshold)."""
    border_bonus: float = 1.0
    """Log-odds added to a region that touches the rim of the field of view."""
    elongation_bonus: float = 1.0
    """Log-odds added to a region at least `elongated` times longer than wide."""
    elongated: float = 3.0
    """Length over width (from the region's second moments) of a shaft-like region."""
    close_px: int = 9
    """Diameter (working pixels) of the closing that fills gaps in tool regions."""
    open_px: int = 7
    """Diameter (working pixels) of the opening that removes lines thinner than an
    instrument (fold edges, specular streaks on tissue)."""
    max_hollowness: float = 0.5
    """Regions whose area is below this share of their area with holes filled are rings
    around something else (the rim of pale tissue) and are not tools."""
    min_area_share: float = 0.002
    """Smallest tool region kept, as a share of the field of view."""
    edge_radius: float = 2.0
    """Radius, in working pixels, of the guided filter that snaps the mask, decided at the
    working size, to the edges of the full-size frame (0 = plain upsampling)."""
    edge_eps: float = 1e-3
    """Regularisation of that guided filter (grey levels 0..1 squared): edges weaker than its
    square root are smoothed over."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    """Optical flow and the camera's motion model."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if not self.grow_logit <= self.seed_logit:
            raise SurgsplatError(f"auto masks need grow_logit <= seed_logit, got "
                                 f"{self.grow_logit} and {self.seed_logit}")
        if self.work_width < 32 or self.texture_px < 1 or self.fill_px < 3 or self.close_px < 1:
            raise SurgsplatError("auto masks need work_width >= 32, texture_px >= 1, "
                                 "fill_px >= 3 and close_px >= 1")
        if (self.temporal_radius < 0 or self.elongated < 1 or self.lightness_floor <= 0
                or self.chroma_floor <= 0 or self.edge_radius < 0 or self.edge_eps <= 0):
            raise SurgsplatError("auto masks need temporal_radius >= 0, elongated >= 1, "
                                 "edge_radius >= 0 and positive lightness_floor, chroma_floor "
                                 "and edge_eps")
        if not (0 < self.highlight_value <= 1 and 0 < self.highlight_saturation <= 1
                and 0 <= self.highlight_max_share < 1 and 0 <= self.min_area_share < 1):
            raise SurgsplatError("auto masks need highlight_value and highlight_saturation in "
                                 "(0, 1] and highlight_max_share and min_area_share in [0, 1)")
        self.motion.validate()

    def describe(self) -> dict:
        """JSON-ready parameters for scene.json."""
        return asdict(self)


@dataclass
class AutoMask:
    """The segmenter's answer for one frame."""

    mask: np.ndarray
    """bool [H, W] tool pixels at the frame's size."""
    confidence: float
    """0..1: area-weighted mean decision margin of the candidate regions (1 = none)."""


@dataclass
class _Frame:
    """One frame at the working size, with its appearance evidence."""

    grey: np.ndarray  # uint8 [h, w]
    evidence: np.ndarray  # float32 [h, w] appearance log-odds
    guide: np.ndarray  # float32 [H, W] the full-size frame's grey levels, 0..1


def _odd(size: float) -> int:
    return max(3, int(round(size)) | 1)


def _shrink(inside: np.ndarray, side: int) -> np.ndarray:
    """bool [h, w]: `inside` (bool [h, w]) eroded by a side x side square; the frame's own
    edges count as outside."""
    return cv2.erode(inside.astype(np.uint8), np.ones((side, side), np.uint8),
                     borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def _box_mean(values: np.ndarray, weights: np.ndarray, side: int) -> np.ndarray:
    """float32 [h, w]: mean of `values` [h, w] over a side x side box, weighted by `weights`
    [h, w] (normalised convolution; 0 where the box holds no weight)."""
    total = cv2.blur(weights, (side, side))
    return cv2.blur(values * weights, (side, side)) / np.maximum(total, 1e-6)


def specular_highlights(image: np.ndarray, inside: np.ndarray,
                        config: AutoMaskConfig) -> np.ndarray:
    """bool [h, w]: the small, bright, unsaturated blobs of uint8 RGB `image` [h, w, 3] inside
    the field of view `inside` (bool [h, w]), grown by one pixel to take their rims."""
    red, green, blue = (image[..., channel].astype(np.float32) for channel in range(3))
    brightest = np.maximum(np.maximum(red, green), blue)  # per channel: faster than max(-1)
    darkest = np.minimum(np.minimum(red, green), blue)
    saturation = (brightest - darkest) / np.maximum(brightest, 1.0)
    bright = ((brightest >= 255 * config.highlight_value)
              & (saturation < config.highlight_saturation) & inside).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(bright, connectivity=8)
    small = stats[:, cv2.CC_STAT_AREA] <= config.highlight_max_share * inside.sum()
    small[0] = False
    return cv2.dilate(small[labels].astype(np.uint8), np.ones((3, 3), np.uint8)) > 0


def appearance_evidence(image: np.ndarray, inside: np.ndarray,
                        config: AutoMaskConfig) -> np.ndarray:
    """float32 [h, w] tool log-odds of uint8 RGB `image` [h, w, 3] from colour and texture,
    inside `inside` (bool [h, w]; outside: very negative). Highlights and the field of view's
    rim take the evidence of their surroundings."""
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB).astype(np.float32)
    lightness = lab[..., 0] * (100.0 / 255.0)  # [h, w] CIELAB L*
    chroma = cv2.GaussianBlur(np.hypot(lab[..., 1] - 128.0, lab[..., 2] - 128.0), (0, 0), 1.0)
    highlights = specular_highlights(image, inside, config)
    rim = _odd(config.texture_px + 2)
    core = _shrink(inside, rim)
    valid = core & ~highlights
    if not valid.any():
        return np.full(inside.shape, -10.0, np.float32)
    weights, side = valid.astype(np.float32), _odd(config.texture_px)
    mean = _box_mean(lightness, weights, side)
    spread = np.sqrt(np.maximum(_box_mean(lightness ** 2, weights, side) - mean ** 2, 0.0))
    contrast = spread / (mean + config.lightness_floor)  # [h, w] local Weber contrast
    colour = np.log(max(float(np.median(chroma[valid])), config.chroma_floor)
                    / np.maximum(chroma, config.chroma_floor))
    typical = max(float(np.median(contrast[valid])), config.contrast_floor)
    structure = np.log(np.maximum(contrast, 1e-4) / typical)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (_odd(config.surround_px),) * 2)
    surround = cv2.morphologyEx(np.maximum(chroma, config.chroma_floor), cv2.MORPH_CLOSE, kernel)
    drop = np.log(surround / np.maximum(chroma, config.chroma_floor))  # >= 0
    evidence = (config.colour_weight * colour + config.local_colour_weight * drop
                + config.texture_weight * structure + config.bias)
    filled = _box_mean(evidence, valid.astype(np.float32), _odd(config.fill_px))
    evidence = np.where(valid, evidence, filled)
    evidence[~inside] = -10.0
    return evidence.astype(np.float32)


def working_size(size: tuple[int, int], config: AutoMaskConfig) -> tuple[int, int]:
    """(h, w) at which frames of size (H, W) are segmented: `work_width` wide (at most W),
    the aspect ratio kept."""
    height, width = size
    work = min(config.work_width, width)
    return max(1, round(height * work / width)), work


def analyse(image: np.ndarray, inside: np.ndarray, config: AutoMaskConfig) -> _Frame:
    """The working-size grey frame and appearance evidence of uint8 RGB `image` [H, W, 3];
    `inside` is the field of view at the working size (bool [h, w])."""
    height, width = inside.shape
    small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    return _Frame(cv2.cvtColor(small, cv2.COLOR_RGB2GRAY),
                  appearance_evidence(small, inside, config),
                  cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0)


def snap_to_edges(mask: np.ndarray, guide: np.ndarray, edge_radius: float,
                  edge_eps: float) -> np.ndarray:
    """bool [H, W]: the working-size mask (bool [h, w]) upsampled to the frame's size and, with
    a guided filter (He et al.: a local linear model of the mask in the grey levels `guide`,
    float32 [H, W] 0..1, regularised by `edge_eps`; radius `edge_radius` working pixels),
    aligned with the frame's own edges."""
    height, width = guide.shape
    soft = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_LINEAR)
    radius = round(edge_radius * width / mask.shape[1])
    if radius < 1:
        return soft > 0.5
    box = (2 * radius + 1,) * 2
    mean_guide, mean_soft = cv2.blur(guide, box), cv2.blur(soft, box)
    covariance = cv2.blur(guide * soft, box) - mean_guide * mean_soft
    variance = cv2.blur(guide * guide, box) - mean_guide * mean_guide
    slope = covariance / (variance + edge_eps)
    offset = mean_soft - slope * mean_guide
    return cv2.blur(slope, box) * guide + cv2.blur(offset, box) > 0.5


def _touches(region: np.ndarray, rim: np.ndarray) -> bool:
    return bool((region & rim).any())


def decide_regions(logit: np.ndarray, inside: np.ndarray,
                   config: AutoMaskConfig) -> tuple[np.ndarray, float]:
    """(bool [h, w] tool mask, confidence) from per-pixel tool log-odds [h, w] inside the
    field of view `inside` (bool [h, w])."""
    weak = ((logit >= config.grow_logit) & inside).astype(np.uint8)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_odd(config.close_px),) * 2)
    weak = cv2.morphologyEx(weak, cv2.MORPH_CLOSE, disc) & inside.astype(np.uint8)
    body = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (config.open_px,) * 2)
    weak = cv2.morphologyEx(weak, cv2.MORPH_OPEN, body)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(weak, connectivity=8)
    seeded = np.zeros(count, bool)
    seeded[np.unique(labels[(logit >= config.seed_logit) & inside])] = True
    rim = inside & ~_shrink(inside, 5)
    min_area = config.min_area_share * inside.sum()
    mask = np.zeros(inside.shape, bool)
    margins, areas = [], []
    for label in range(1, count):
        area = stats[label, cv2.CC_STAT_AREA]
        if not seeded[label] or area < min_area:
            continue
        x, y, w, h = stats[label, :4]
        region = labels[y:y + h, x:x + w] == label
        if area < config.max_hollowness * _filled_area(region):
            continue  # a ring around an area (the rim of pale tissue), not an instrument
        score = float(logit[y:y + h, x:x + w][region].mean())
        score += config.border_bonus * _touches(region, rim[y:y + h, x:x + w])
        score += config.elongation_bonus * (_elongation(region) >= config.elongated)
        margins.append(abs(2.0 / (1.0 + np.exp(-score)) - 1.0))
        areas.append(area)
        if score > 0:
            mask[y:y + h, x:x + w] |= region
    confidence = float(np.average(margins, weights=areas)) if areas else 1.0
    return mask, confidence


def _filled_area(region: np.ndarray) -> int:
    """Pixels of a bool region [h, w] with its holes filled."""
    outside = np.pad(~region, 1, constant_values=True).astype(np.uint8)
    cv2.floodFill(outside, None, (0, 0), 2)
    return int((outside[1:-1, 1:-1] != 2).sum())


def _elongation(region: np.ndarray) -> float:
    """Length over width of a bool region [h, w] from its second moments."""
    moments = cv2.moments(region.astype(np.uint8), binaryImage=True)
    if moments["m00"] == 0:
        return 1.0
    a, b, c = moments["mu20"], moments["mu11"], moments["mu02"]
    spread = np.sqrt(4 * b * b + (a - c) ** 2)
    return float(np.sqrt((a + c + spread) / max(a + c - spread, 1e-6)))


def windowed(items: Iterable[Item], radius: int) -> Iterator[tuple[Item, list[Item]]]:
    """(item, its window) for each item in order; the window holds the item and up to `radius`
    neighbours on each side (fewer at the ends). At most 2 * radius + 1 items are held."""
    window: deque[Item] = deque()
    center = 0  # position in `window` of the next item to yield
    for item in items:
        window.append(item)
        if len(window) - 1 - center >= radius:
            yield window[center], list(window)
            if center >= radius:
                window.popleft()
            else:
                center += 1
    while center < len(window):
        yield window[center], list(window)
        if center >= radius:
            window.popleft()
        else:
            center += 1


def _fused_logit(centre: _Frame, window: list[_Frame], inside: np.ndarray,
                 flows: FlowEstimator, config: AutoMaskConfig) -> np.ndarray:
    """float32 [h, w]: the centre frame's appearance evidence averaged with its neighbours'
    (carried along the flow), plus the evidence of independent motion."""
    evidence, motion = [centre.evidence], []
    for other in window:
        if other is centre:
            continue
        flow = flows.flow(centre.grey, other.grey)  # [h, w, 2]
        evidence.append(warp_from(other.evidence, flow))
        motion.append(camera_residual(flow, inside, config.motion))
    logit = np.mean(evidence, axis=0)
    if motion:
        moving = np.minimum(np.mean(motion, axis=0), config.motion_cap)
        logit = logit + config.motion_weight * moving
    return logit


def auto_tool_masks(frames: Iterable[np.ndarray], fov: np.ndarray | None,
                    config: AutoMaskConfig | None = None) -> Iterator[AutoMask]:
    """Tool masks and confidences of uint8 RGB frames [H, W, 3] of one video, in order, inside
    the field of view `fov` (bool [H, W], None = whole frame); holds only
    2 * temporal_radius + 1 frames' working maps at a time."""
    config = config or AutoMaskConfig()
    config.validate()
    flows = FlowEstimator(config.motion)
    inside: np.ndarray | None = None

    def analysed() -> Iterator[_Frame]:
        nonlocal inside
        for image in frames:
            if inside is None:
                height, width = working_size(image.shape[:2], config)
                full = np.ones(image.shape[:2], bool) if fov is None else fov
                inside = cv2.resize(full.astype(np.uint8), (width, height),
                                    interpolation=cv2.INTER_NEAREST) > 0
            yield analyse(image, inside, config)

    for centre, window in windowed(analysed(), config.temporal_radius):
        assert inside is not None
        mask, confidence = decide_regions(_fused_logit(centre, window, inside, flows, config),
                                          inside, config)
        full = snap_to_edges(mask, centre.guide, config.edge_radius, config.edge_eps)
        if fov is not None:
            full &= fov
        yield AutoMask(full, confidence)
