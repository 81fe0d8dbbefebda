"""The circular field of view of laparoscopic video: where the black border is not.

Laparoscopes image through a round optic, so each frame shows a bright disc (often clipped by
the top and bottom of the frame) on a black border that never changes. The border is found on
the per-pixel maximum brightness over many frames: tissue is bright in at least one frame, the
border never is. Dark pixels connected to the image edge form the border; a circle is fitted
to the edge of the remaining region (outliers trimmed), which also tolerates tissue that stays
dark near the rim and text overlays burnt into the border. When no circle fits (e.g. black bars
of a letterboxed video) the region itself is used; without a dark border the whole frame is in
view.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class FovConfig:
    """How the border is told from the view."""

    dark_level: int = 20
    """Max-over-frames brightness (0-255) at or below which a pixel may be border."""
    min_border_share: float = 0.02
    """Below this share of border pixels the video has no border: the whole frame is in view."""
    margin_px: float = 2.0
    """The fitted circle is shrunk by this many pixels (its rim is dim and blurred)."""
    max_fit_error: float = 0.01
    """Largest median distance of rim pixels from the fitted circle, as a share of its radius,
    for the circle to be used instead of the region."""
    min_inlier_share: float = 0.6
    """Smallest share of rim pixels the circle must explain (within the trimming tolerance)."""


@dataclass(frozen=True)
class FovEstimate:
    """The field of view and how it was found."""

    inside: np.ndarray  # [H, W] bool, True = inside the field of view
    kind: str  # "circle" (fitted), "region" (no circle fits) or "full" (no border)
    center: tuple[float, float] | None  # circle centre (x, y) in pixels, for kind "circle"
    radius: float | None  # circle radius in pixels (before the margin), for kind "circle"

    def describe(self) -> dict:
        """A JSON-ready summary for scene.json."""
        facts = {"kind": self.kind, "inside_share": round(float(self.inside.mean()), 4)}
        if self.kind == "circle":
            facts["center_xy"] = [round(v, 2) for v in self.center]
            facts["radius"] = round(self.radius, 2)
        return facts


def brightness(frame: np.ndarray) -> np.ndarray:
    """Per-pixel brightness uint8 [H, W] of a uint8 [H, W, 3] or [H, W] frame (max over channels)."""
    return frame.max(axis=2) if frame.ndim == 3 else frame


def estimate_fov(frames_or_stat_image: np.ndarray | Sequence[np.ndarray],
                 config: FovConfig | None = None) -> FovEstimate:
    """The field of view of a video from its frames or from a precomputed statistic image.

    Accepts a sequence of uint8 frames ([H, W, 3] or [H, W]), a 4-D stack [T, H, W, 3], or a
    single statistic image ([H, W] or [H, W, 3], e.g. the per-pixel maximum over frames).
    """
    config = config or FovConfig()
    stat = _max_brightness(frames_or_stat_image)  # [H, W] uint8
    height, width = stat.shape
    dark = (cv2.medianBlur(stat, 5) <= config.dark_level).astype(np.uint8)
    count, labels = cv2.connectedComponents(dark, connectivity=8)
    edge_labels = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    edge_labels = edge_labels[edge_labels > 0]
    outside = np.isin(labels, edge_labels)  # [H, W] dark and connected to the image edge
    if outside.mean() < config.min_border_share:
        return FovEstimate(np.ones((height, width), dtype=bool), "full", None, None)
    region = ~outside
    # Remove thin bridges and specks left by noise before taking the rim.
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    region = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
    circle = _fit_rim_circle(region, config)
    if circle is None:
        return FovEstimate(region, "region", None, None)
    (cx, cy), radius = circle
    ys, xs = np.mgrid[0:height, 0:width]
    inside = (xs - cx) ** 2 + (ys - cy) ** 2 <= (radius - config.margin_px) ** 2
    return FovEstimate(inside, "circle", (cx, cy), radius)


def circular_fov_mask(frames_or_stat_image: np.ndarray | Sequence[np.ndarray],
                      config: FovConfig | None = None) -> np.ndarray:
    """bool [H, W], True = inside the field of view (see `estimate_fov` for the inputs)."""
    return estimate_fov(frames_or_stat_image, config).inside


def _max_brightness(frames_or_stat_image: np.ndarray | Sequence[np.ndarray]) -> np.ndarray:
    if isinstance(frames_or_stat_image, np.ndarray):
        data = frames_or_stat_image
        if data.ndim == 2 or (data.ndim == 3 and data.shape[2] == 3):
            stat = brightness(data)
        elif data.ndim in (3, 4):
            stat = np.stack([brightness(frame) for frame in data]).max(axis=0)
        else:
            raise ValueError(f"expected an image or a stack of frames, got shape {data.shape}")
    else:
        if not frames_or_stat_image:
            raise ValueError("no frames to estimate the field of view from")
        stat = brightness(frames_or_stat_image[0])
        for frame in frames_or_stat_image[1:]:
            stat = np.maximum(stat, brightness(frame))
    if stat.dtype != np.uint8:
        raise ValueError(f"expected uint8 frames, got {stat.dtype}")
    return np.ascontiguousarray(stat)


def _fit_rim_circle(region: np.ndarray,
                    config: FovConfig) -> tuple[tuple[float, float], float] | None:
    """Circle ((cx, cy), r) through the rim of `region` (its pixels next to the border, not on
    the image edge), or None when the rim is not a circle."""
    height, width = region.shape
    eroded = cv2.erode(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    rim = region & ~eroded
    rim[[0, -1], :] = False
    rim[:, [0, -1]] = False
    ys, xs = np.nonzero(rim)
    if xs.size < 20:
        return None
    points = np.stack([xs, ys], axis=1).astype(np.float64)  # [P, 2]
    keep = np.ones(len(points), dtype=bool)
    for _ in range(5):
        center, radius = _algebraic_circle(points[keep])
        error = np.abs(np.linalg.norm(points - center, axis=1) - radius)  # [P]
        tolerance = max(2.0, 3.0 * float(np.median(error[keep])))
        new_keep = error <= tolerance
        if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    plausible = min(height, width) / 4 <= radius <= 2 * max(height, width)
    if (not plausible or keep.mean() < config.min_inlier_share
            or np.median(error[keep]) > config.max_fit_error * radius):
        return None
    return (float(center[0]), float(center[1])), float(radius)


def _algebraic_circle(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares circle through points [P, 2]: x^2 + y^2 + D x + E y + F = 0."""
    design = np.column_stack([points, np.ones(len(points))])  # [P, 3]
    target = -(points ** 2).sum(axis=1)
    (d, e, f), *_ = np.linalg.lstsq(design, target, rcond=None)
    center = np.array([-d / 2.0, -e / 2.0])
    return center, float(np.sqrt(max(center @ center - f, 0.0)))
