"""Automatic tool masks for video without labels: a classical segmenter, no learned weights.

Surgical instruments are grey metal or black plastic, while tissue under the endoscope's white
light is red, pink or yellow. Per frame, each pixel's *greyness* is scored in CIELAB: its chroma
(sqrt(a*^2 + b*^2)) is low in absolute terms, and lower than that of its surroundings (a
black top-hat of the chroma, which favours the thin, elongated shape of a shaft over large pale
or shadowed tissue areas). Dark pixels (no usable colour) and bright ones (specular
highlights, on wet tissue as on metal, and pale tissue such as the gallbladder) score nothing by
themselves; a highlight on a tool is taken back in by the closing that fills holes in the mask.

Temporal consistency: the score of a frame is averaged with its neighbours' (`temporal_radius`
frames on each side), so a tool that stays for a few frames is kept and single-frame flickers
of tissue are not. The averaged score is thresholded with hysteresis: pixels above `seed_score`
start regions that grow into connected pixels above `grow_score`. Regions smaller than
`min_area_share` of the field of view are dropped.

The thresholds were chosen on CholecSeg8k frames 561-596 and are scored on frames 597-632
(benchmarks/bench_auto_masks.py).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass
from typing import TypeVar

import cv2
import numpy as np

from surgsplat.errors import SurgsplatError

Item = TypeVar("Item")


@dataclass
class AutoMaskConfig:
    """Parameters of the classical tool segmenter (defaults chosen on the tuning frames)."""

    chroma_scale: float = 30.0
    """CIELAB chroma (0..~130) at which the absolute greyness term reaches 0."""
    tophat_px: int = 41
    """Side (pixels at 854x480, scaled with the frame width) of the square structuring element
    of the chroma black top-hat: tools thinner than this stand out."""
    tophat_scale: float = 15.0
    """Chroma drop below the surroundings at which the top-hat term reaches 1."""
    dark_level: float = 6.0
    """CIELAB lightness (0..100) below which a pixel has no usable colour and scores 0."""
    max_lightness: float = 50.0
    """CIELAB lightness above which a pixel scores 0: specular highlights and pale tissue
    (gallbladder, fascia) are brighter than the grey metal under the same light."""
    temporal_radius: int = 1
    """Frames on each side whose scores are averaged with the frame's own."""
    seed_score: float = 0.8
    """Averaged score at which a pixel surely is tool (hysteresis high threshold)."""
    grow_score: float = 0.3
    """Averaged score down to which a tool region grows (hysteresis low threshold)."""
    close_px: int = 17
    """Diameter (pixels at 854x480) of the closing that fills highlights and gaps in tools."""
    min_area_share: float = 0.002
    """Smallest tool region kept, as a share of the field of view."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if not 0 < self.grow_score <= self.seed_score <= 1:
            raise SurgsplatError(f"auto masks need 0 < grow_score <= seed_score <= 1, got "
                                 f"{self.grow_score} and {self.seed_score}")
        if self.temporal_radius < 0 or self.tophat_px < 3 or self.close_px < 1:
            raise SurgsplatError("auto masks need temporal_radius >= 0, tophat_px >= 3 and "
                                 "close_px >= 1")
        if self.chroma_scale <= 0 or self.tophat_scale <= 0 or not 0 <= self.min_area_share < 1:
            raise SurgsplatError("auto masks need positive chroma_scale and tophat_scale and "
                                 "min_area_share in [0, 1)")

    def describe(self) -> dict:
        """JSON-ready parameters for scene.json."""
        return asdict(self)


REFERENCE_WIDTH = 854
"""Frame width (pixels) at which the pixel sizes of AutoMaskConfig hold."""


def _odd(size: float) -> int:
    return max(3, int(round(size)) | 1)


def tool_score(image: np.ndarray, config: AutoMaskConfig) -> np.ndarray:
    """Per-pixel tool likelihood float32 [H, W] in [0, 1] of a uint8 RGB frame [H, W, 3]."""
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB).astype(np.float32)  # [H, W, 3], L in 0..255
    lightness = lab[..., 0] * (100.0 / 255.0)  # [H, W] CIELAB L*
    chroma = np.hypot(lab[..., 1] - 128.0, lab[..., 2] - 128.0)  # [H, W]
    scale = image.shape[1] / REFERENCE_WIDTH
    side = _odd(config.tophat_px * scale)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (side, side))
    drop = cv2.morphologyEx(chroma, cv2.MORPH_BLACKHAT, kernel)  # [H, W] >= 0
    grey = np.clip(1.0 - chroma / config.chroma_scale, 0.0, 1.0)
    local = np.clip(drop / config.tophat_scale, 0.0, 1.0)
    score = np.sqrt(grey * local)
    colourless = (lightness < config.dark_level) | (lightness > config.max_lightness)
    score[colourless] = 0.0
    return score.astype(np.float32)


def tool_mask(scores: list[np.ndarray], fov: np.ndarray | None,
              config: AutoMaskConfig) -> np.ndarray:
    """bool [H, W] tool mask of a frame from its own and its neighbours' scores ([H, W] each),
    inside the field of view `fov` (bool [H, W], None = whole frame)."""
    score = np.mean(scores, axis=0)  # [H, W]
    height, width = score.shape
    inside = np.ones((height, width), bool) if fov is None else fov
    weak = ((score >= config.grow_score) & inside).astype(np.uint8)
    count, labels = cv2.connectedComponents(weak, connectivity=8)
    seeded = np.zeros(count, bool)
    seeded[np.unique(labels[(score >= config.seed_score) & inside])] = True
    seeded[0] = False
    mask = seeded[labels].astype(np.uint8)
    diameter = _odd(config.close_px * width / REFERENCE_WIDTH)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter, diameter))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, disc)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    big = stats[:, cv2.CC_STAT_AREA] >= config.min_area_share * inside.sum()
    big[0] = False
    return big[labels] & inside


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


def auto_tool_masks(frames: Iterable[np.ndarray], fov: np.ndarray | None,
                    config: AutoMaskConfig | None = None) -> Iterator[np.ndarray]:
    """bool [H, W] tool masks of uint8 RGB frames [H, W, 3], in order, holding only
    2 * temporal_radius + 1 score maps at a time."""
    config = config or AutoMaskConfig()
    config.validate()
    scores = (tool_score(frame, config) for frame in frames)
    for _, window in windowed(scores, config.temporal_radius):
        yield tool_mask(window, fov, config)
