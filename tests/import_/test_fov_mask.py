"""The circular field of view is found from the black border, robustly."""

import numpy as np

from surgsplat.data.fov_mask import circular_fov_mask, estimate_fov

from .conftest import CENTER, HEIGHT, RADIUS, WIDTH, endoscope_frames, view_disk


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_circle_found_from_frames():
    estimate = estimate_fov(endoscope_frames())
    assert estimate.kind == "circle"
    assert np.allclose(estimate.center, CENTER, atol=1.0)  # px
    assert abs(estimate.radius - RADIUS) < 1.0  # px
    assert iou(estimate.inside, view_disk()) > 0.9  # the 2 px margin costs ~10 % at this size
    assert not (estimate.inside & ~view_disk()).any()  # never inside where the border is


def test_dark_tissue_at_the_rim_stays_inside():
    frames = endoscope_frames()
    for frame in frames:
        frame[26:38, 8:20] = 0  # a cavity that is black in every frame, touching the rim
    inside = circular_fov_mask(np.stack(frames))
    assert inside[32, 14]  # the circle fit keeps it in view
    assert iou(inside, view_disk()) > 0.9


def test_no_border_means_whole_frame():
    frames = np.random.default_rng(1).integers(40, 255, (3, HEIGHT, WIDTH, 3), dtype=np.uint8)
    estimate = estimate_fov(frames)
    assert estimate.kind == "full" and estimate.inside.all()


def test_letterbox_bars_use_the_region():
    stat = np.full((HEIGHT, WIDTH), 200, np.uint8)  # a statistic image: bars on top and bottom
    stat[:8] = stat[-8:] = 0
    estimate = estimate_fov(stat)
    assert estimate.kind == "region"
    assert not estimate.inside[:8].any() and estimate.inside[10:-10].all()
